"""What the loop's parts in their own modules (`reloading.py`, `running_program.py`,
`latch_keeping.py`, `mash_side.py`, `reporting.py`) share with the `Daemon` they make up: its
state, and the steps of its own they call. Declared here, set and defined by the Daemon."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

from hermsd.config.file import ConfigFile
from hermsd.config.schema import Config
from hermsd.control import pid
from hermsd.control.element2 import SlowElement
from hermsd.control.learning import LearnedModel, Learner
from hermsd.control.reach import ReachWatch, Said
from hermsd.control.watches import HeatUpFit
from hermsd.hardware.outputs import Outputs
from hermsd.hardware.ssr import TimeProportionalPlanner
from hermsd.program.driver import ProgramDriver
from hermsd.program.runner import MashReading
from hermsd.runtime.alerts import Alerts
from hermsd.runtime.build import ModelChoice
from hermsd.runtime.clock import Clock
from hermsd.runtime.notify import Notifier
from hermsd.runtime.parts import Recorder
from hermsd.runtime.saver import Saver
from hermsd.safety.element_watch import ElementWatch
from hermsd.safety.latches import LatchStore
from hermsd.safety.limits import MeasuredTun
from hermsd.safety.supervisor import Supervisor


class LoopState:
    """The Daemon's state and steps, as its parts in other modules see them."""

    config: Config
    clock: Clock
    outputs: Outputs
    config_file: ConfigFile | None
    notifier: Notifier | None
    recorder: Recorder | None
    latches: LatchStore | None
    saver: Saver
    alerts: Alerts
    supervisor: Supervisor
    controller: pid.Controller
    model: pid.PlantModel
    model_choice: ModelChoice
    planner: TimeProportionalPlanner
    element2: SlowElement | None
    element_watch: ElementWatch | None
    reach: ReachWatch
    program: ProgramDriver
    setpoint: float
    mode: str
    manual_output: float
    output: float
    _pv: float | None
    _held: bool
    _resume_output: float
    _pending: list[Callable[[float], None]]
    _learner: Learner
    _heat_up_seen: HeatUpFit | None
    _limits_fit: HeatUpFit | None
    _limits_dead: frozenset[int]
    _pulsing: bool
    _reloaded_at: float
    _stored_model: LearnedModel | None
    _learned_since: LearnedModel | None
    _reload_requested: bool
    _config_problem: str | None
    _saved_latches: list[str]
    _tried_latches: list[str]
    _latch_failing: str | None
    _latch_retry_at: float
    _latches_handed_at: float
    _latch_slow: bool
    _latched_wall_ns: dict[str, int]
    _latched_messages: dict[str, str]

    if TYPE_CHECKING:  # defined by the Daemon, or by another of its parts

        def _event(self, level: int, message: str, t: float) -> None: ...

        def _alert(self, event: str, message: str, t: float, kind: str = "") -> None: ...

        def _drain_alarms(self, t: float) -> None: ...

        def _apply_setpoint(self, celsius: float, t: float) -> None: ...

        def _apply_manual(self, output: float | None, t: float) -> None: ...

        def _apply_auto(self, t: float) -> None: ...

        def _apply_reset(self, t: float, kinds: list[str] | None = None) -> None: ...

        def _measured_tun(self, config: Config) -> MeasuredTun | None: ...

        def _reprogram_sensor(self, t: float) -> None: ...

        def _record_config(self, reason: str, t: float) -> None: ...

        def _remake_mash_control(self, config: Config) -> None: ...

        def _say_reach(self, said: Said | None, t: float) -> None: ...

        def _save_latches(self, t: float) -> None: ...

        def _take_saves(self, t: float) -> None: ...

        def _keep_after_below_cut_out(self, t: float) -> None: ...

        def _stop_program_over_cut_out(self, in_force: float | None, t: float) -> bool: ...

        def program_command(self, action: str, t: float, step: int | None = None) -> None: ...

        def mash_reading(self) -> MashReading | None: ...

        def _program_pump(self) -> None: ...
