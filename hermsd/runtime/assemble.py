"""The composition root: a daemon's parts built from its config and the state directory,
handed to the loop (`Daemon`), which builds none of them itself.

Every daemon is made here: `hermsd run` and `simulate` (`cli/run.py`, `sim/world.py`), the
scenarios (`sim/scenario.py`) and tune (`cli/tune.py`, `commissioning/`); replay re-runs the
law with the same part-makers (`runtime/build.py`).
"""

from __future__ import annotations

from collections.abc import Callable

from hermsd.config.file import ConfigFile
from hermsd.config.schema import Config
from hermsd.control.element2 import SlowElement
from hermsd.control.learning import LearnedModel, ModelStore
from hermsd.control.reach import ReachWatch
from hermsd.hardware.current_sense import CurrentSense
from hermsd.hardware.outputs import Outputs
from hermsd.hardware.pump_sense import PumpSense
from hermsd.hardware.sensors.base import Sensor
from hermsd.program.driver import ProgramDriver
from hermsd.program.store import ProgressStore
from hermsd.runtime import build
from hermsd.runtime.clock import Clock
from hermsd.runtime.daemon import Daemon
from hermsd.runtime.mash_control import coil_prior, mash_control
from hermsd.runtime.notify import Notifier
from hermsd.runtime.parts import Parts, Recorder
from hermsd.runtime.saver import Saver
from hermsd.safety.latches import LatchStore
from hermsd.safety.limits import MeasuredTun
from hermsd.safety.supervisor import Supervisor


def assemble(
    config: Config,
    clock: Clock,
    sensor: Sensor,
    outputs: Outputs,
    *,
    recorder: Recorder | None = None,
    notifier: Notifier | None = None,
    on_status: Callable[[str], None] | None = None,
    config_file: ConfigFile | None = None,
    latches: LatchStore | None = None,
    models: ModelStore | None = None,
    tun_model: MeasuredTun | None = None,
    saver: Saver | None = None,
    mash_sensor: Sensor | None = None,
    coil_sensor: Sensor | None = None,
    pump_sense: PumpSense | None = None,
    current_sense: CurrentSense | None = None,
) -> Daemon:
    """A daemon for `config` on `sensor` and `outputs` (and the mash's and the coil outlet's
    sensors, the pump's sense and the element's current input, when fitted), its parts built
    here (with what `models` holds of the tun) and handed to the loop."""
    stored: LearnedModel | None = None
    problem: str | None = None
    if models is not None:
        stored, problem = build.stored_model(models, config)
    choice = build.model_in_force(stored, config)
    model = choice.model
    measured = build.measured_tun(config, stored, tun_model)
    e2 = config.element2
    outer = None
    if mash_sensor is not None:
        alone = models.load_coil() if models is not None else None
        outer = mash_control(config, model, coil_prior(config, stored, alone))
    element2 = SlowElement(outputs.element2, e2.min_on, e2.min_off) if outputs.element2 else None
    parts = Parts(
        config=config,
        clock=clock,
        sensor=sensor,
        outputs=outputs,
        recorder=recorder,
        notifier=notifier,
        on_status=on_status,
        config_file=config_file,
        latches=latches,
        models=models,
        tun_model=tun_model,
        saver=saver if saver is not None else Saver(),
        stored_model=stored,
        model_problem=problem,
        model_choice=choice,
        supervisor=Supervisor(build.safety_limits(config, measured)),
        controller=build.control_law(config, model),
        learner=build.learner(config, model),
        planner=build.planner(config, model),
        element2=element2,
        element_watch=build.element_watch(config) if element2 is not None else None,
        reach=ReachWatch(),
        program=ProgramDriver(
            ProgressStore(latches.directory) if latches is not None else None,
            getattr(clock, "zone", None),  # a simulated clock's local time; else the system's
            config.control.period,
        ),
        mash_sensor=mash_sensor,
        coil_sensor=coil_sensor,
        pump_sense=pump_sense,
        mash_control=outer,
        current_sense=current_sense,
    )
    return Daemon(parts)
