"""What one daemon runs with, handed to the loop (`Daemon`) by the composition root
(`runtime/assemble.py`): the loop builds none of its parts itself."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

from hermsd.config.file import ConfigFile
from hermsd.config.schema import Config
from hermsd.control import pid
from hermsd.control.element2 import SlowElement
from hermsd.control.learning import LearnedModel, Learner, ModelStore
from hermsd.control.reach import ReachWatch
from hermsd.hardware.current_sense import CurrentSense
from hermsd.hardware.outputs import Outputs
from hermsd.hardware.pump_sense import PumpSense
from hermsd.hardware.sensors.base import Sensor
from hermsd.hardware.ssr import TimeProportionalPlanner
from hermsd.program.driver import ProgramDriver
from hermsd.runtime.build import ModelChoice
from hermsd.runtime.clock import Clock
from hermsd.runtime.mash_control import MashControl
from hermsd.runtime.notify import Notifier
from hermsd.runtime.saver import Saver
from hermsd.safety.element_watch import ElementWatch
from hermsd.safety.latches import LatchStore
from hermsd.safety.limits import MeasuredTun
from hermsd.safety.supervisor import Supervisor


class Recorder(Protocol):
    """Where records go (the MCAP recorder); `write` never blocks."""

    def write(self, topic: str, log_time_ns: int, message: dict[str, Any]) -> None: ...


@dataclass(slots=True)
class Parts:
    """What one tun's loop runs with: the devices and stores handed in, and what was built
    from the config and the state directory."""

    config: Config
    clock: Clock
    sensor: Sensor
    outputs: Outputs
    recorder: Recorder | None
    notifier: Notifier | None
    on_status: Callable[[str], None] | None
    config_file: ConfigFile | None
    latches: LatchStore | None
    models: ModelStore | None
    tun_model: MeasuredTun | None  # the tun as measured, given: the supervisor's limits
    saver: Saver  # latches and model, off the loop
    stored_model: LearnedModel | None  # what the state directory holds, if this tun's
    model_problem: str | None  # why a stored model was ignored: said in the log at start
    model_choice: ModelChoice
    supervisor: Supervisor
    controller: pid.Controller
    learner: Learner
    planner: TimeProportionalPlanner
    element2: SlowElement | None
    element_watch: ElementWatch | None
    reach: ReachWatch  # says when full power cannot reach the setpoint
    program: ProgramDriver
    mash_sensor: Sensor | None = None  # the sensors beside the HLT's (runtime/mash_side.py)
    coil_sensor: Sensor | None = None
    pump_sense: PumpSense | None = None  # a pump hermsd does not switch, seen running
    mash_control: MashControl | None = None  # the HERMS's outer loop, with a mash sensor
    current_sense: CurrentSense | None = None  # the SSR's element's current (current_side.py)
