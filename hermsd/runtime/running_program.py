"""The mash program in the loop (`hermsd.program`): started, commanded and stepped at a period
boundary, its events logged and alerted, its setpoints kept below the cut-out."""

from __future__ import annotations

import dataclasses
import logging

from hermsd.config import rules
from hermsd.config import schema as config_module
from hermsd.control import predictive
from hermsd.control.factory import full_power_share
from hermsd.log.topics import PROGRAM_TOPIC
from hermsd.program.model import Program, config_warnings
from hermsd.program.readiness import Tun
from hermsd.program.runner import ProgramEvent
from hermsd.runtime.loop_state import LoopState


class RunningProgram(LoopState):
    """The Daemon's mash program (applied at once: called at a period boundary)."""

    def program_problems(self, program: Program) -> list[str]:
        """Why `program` cannot start now ('key: what is wrong' lines); [] when it can."""
        problems = self.program.problems(program)
        if self.mode != "auto":
            problems.append("control.mode: a program runs in auto mode (`hermsd set mode auto`)")
        running = dataclasses.replace(
            self.config, control=dataclasses.replace(self.config.control, setpoint=self.setpoint)
        )
        for index, step in enumerate(program.steps):
            for problem in rules.runtime_problems(running, {"control.setpoint": step.setpoint}):
                problems.append(f"steps[{index}].setpoint: {problem.split(': ', 1)[-1]}")
        return problems

    def start_program(self, program: Program, ready_by: str | None, t: float) -> None:
        """Start `program` (program_problems first: this raises runner.Refused); warn of what
        the config cannot do of it (`config_warnings`)."""
        self.program.start(
            program,
            ready_by,
            setpoint=self.setpoint,
            wall_ns=self.clock.wall_ns(),
            pv=self._pv,
            tun=self._program_tun(),
        )
        for warning in config_warnings(program, self.config):
            self._event(logging.WARNING, f"program {program.name!r}: {warning}", t)

    def _program_tun(self) -> Tun:
        """What a `ready_by` heat-up plans with: the model in force, and what it rests on;
        the controller's prediction only while one runs (it walks the whole dead time)."""
        return Tun(
            self.model,
            full_power_share(self.config),
            self.model_choice.measured is not None,
            predictive.heat_up_fit(self.controller),
            predictive.predicted_pv(self.controller)
            if self.program.readiness is not None
            else None,
            predictive.noise_scale(self.controller),
        )

    def program_command(self, action: str, t: float, step: int | None = None) -> None:
        """next, pause, resume, stop or confirm (runner.Refused when it does not apply);
        `step`: the index of the step a confirm or next is for (None: the current one)."""
        if action == "stop":
            self._keep_after_below_cut_out(t)
        after = self.program.command(action, self._pv, step)
        self._program_pump()
        if after is not None:
            self.setpoint = after
            self._event(logging.INFO, f"setpoint {after:.2f} °C (the program stopped)", t)

    def _program_period(self, t: float, pv: float | None, applied: float, full: bool) -> bool:
        """Take the program's setpoint for this period; True: it keeps the heater off.
        `applied`: the heat's duty in the period just ended (%; with two elements, of both);
        `full`: that period was full power (`config.full_power`)."""
        wall_ns = self.clock.wall_ns()
        tun = self._program_tun()
        mash = self.mash_reading()
        setpoint, events = self.program.period(t, pv, wall_ns, tun, applied, full, mash)
        for event in events:
            self._program_event(event, t)
        self._program_pump()
        news = self.program.store_news()
        if news is not None:
            self._event(logging.ERROR if news[0] else logging.INFO, news[1], t)
        if not self.program.active:
            return False
        if self._stop_program_over_cut_out(setpoint, t):  # an edit lowered the cut-out
            return False
        if setpoint is None:
            self.setpoint = self.program.target  # shown, not heated to: the heater stays off
            return True
        self.setpoint = setpoint
        return False

    def _stop_program_over_cut_out(self, in_force: float | None, t: float) -> bool:
        """Stop the program (as `program stop`) when its step's setpoint or the setpoint in
        force (`in_force`, a ramp's; None: the step's) is not below safety.max_temp."""
        max_temp = self.config.safety.max_temp
        target = self.program.target
        if target >= max_temp:
            why = f"its step's setpoint {target:g} °C"
        elif in_force is not None and in_force >= max_temp:
            why = f"its setpoint in force {in_force:g} °C"
        else:
            return False
        self._event(
            logging.WARNING,
            f"program stopped: {why} is not below safety.max_temp ({max_temp:g} °C)",
            t,
        )
        self.program_command("stop", t)
        for event in self.program.take_events():
            self._program_event(event, t)
        return True

    def _keep_after_below_cut_out(self, t: float) -> None:
        """The setpoint a program returns to must be below safety.max_temp: else the file's."""
        after, max_temp = self.program.after, self.config.safety.max_temp
        if after is None or after < max_temp:
            return
        self.program.after = self.config.control.setpoint
        self._event(
            logging.WARNING,
            f"setpoint {after:g} °C for when the program stops is not below safety.max_temp "
            f"({max_temp:g} °C): the file's {self.config.control.setpoint:g} °C instead",
            t,
        )

    def _program_event(self, event: ProgramEvent, t: float) -> None:
        if self.recorder is not None:
            fields = dataclasses.asdict(event)
            fields.pop("text")
            self.recorder.write(
                PROGRAM_TOPIC, self.clock.wall_ns(), {"t": t, **fields, "program": event.program}
            )
        self._event(logging.WARNING if event.event == "late" else logging.INFO, event.text, t)
        if event.event in config_module.PROGRAM_ALERT_EVENTS:
            self._alert(event.event, event.text, t, event.name or "")
