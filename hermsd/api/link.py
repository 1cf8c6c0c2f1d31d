"""What the control loop does with the control socket, at each period boundary.

`at_boundary` runs before the period's queued operator actions: it takes the commands the
server thread has parsed, checks each against the running config as strictly as the file is
checked (`config.runtime_problems`: a clear error, nothing applied), and hands the valid ones
to the daemon's own operator actions, logged as coming from the socket. `period` runs after
the period's record is made: it publishes the snapshot `status` is served from, adds the
period to the history ring (`history.py`, for `history`) and answers the commands of this
boundary.

Runtime changes and the config file (one rule): a `set` overrides the running value until
the config file's same key is next edited; an edit of that key wins, being the newer intent.
`set mode` covers `control.mode` and `control.manual_output` together. Until then `status`
shows each value set at runtime that differs from the file's (`runtime`). The one exception
is the config's own rule: an edit that puts `safety.max_temp` at or below a runtime setpoint
brings back the file's setpoint (logged), and one that lowers `control.max_output` below a
runtime manual output lowers it to the limit, as for the file's own values.

A mash program owns the setpoint while it runs (hermsd/program/driver.py): `set setpoint` is
refused until it is stopped, and an edit of `control.setpoint` then is what it returns to.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

from hermsd.api.history import HistoryRing, capacity_for, encode_row, page_line
from hermsd.api.protocol import (
    STARTING,
    STEP_ACTIONS,
    VERSION,
    Command,
    History,
    ProgramAction,
    ProgramStart,
    ResetAlarms,
    SetMode,
    SetPump,
    SetSetpoint,
    describe,
    encode,
    error_reply,
)
from hermsd.api.server import Pending
from hermsd.config import read, rules
from hermsd.config.schema import Config
from hermsd.control.learning import LearnedModel
from hermsd.control.pid import PlantModel
from hermsd.control.reach import short_words
from hermsd.program.runner import Refused
from hermsd.runtime.daemon import Daemon
from hermsd.runtime.mash_side import pump_refusal
from hermsd.runtime.period import PeriodRecord
from hermsd.safety.element_watch import no_heat_words
from hermsd.safety.limits import SafetyLimits, format_limits
from hermsd.safety.reset_outcome import reset_outcome

SOURCE = "control socket"
SEEN_S = 1.0
"""Seconds a step is current before a confirm or next that names none may end it: less is
no time to read it, so such a command was meant for the step before (`LoopLink.arrived`)."""
STEPS_KEPT = 8  # step changes remembered for `arrived`: far more than one SEEN_S holds
RUNTIME_KEYS = ("control.setpoint", "control.mode", "control.manual_output")


class CommandSource(Protocol):
    """Where the commands come from: the `ControlServer`."""

    def take(self) -> list[Pending]: ...

    def wake(self) -> None: ...


@dataclass(frozen=True, slots=True)
class Snapshot:
    """References to what one period left (all immutable): cheap for the loop to make."""

    record: PeriodRecord
    tun: str
    manual_output: float
    limits: SafetyLimits
    model: PlantModel  # the controller's model of the tun, in force
    model_from: str  # where that model came from: learned, measured (hermsd tune) or prior
    learned: LearnedModel | None
    config: Config
    runtime: frozenset[str]
    program: dict[str, Any] | None  # the status reply's `program`
    reasons: dict[str, str]  # each active alarm's message (made for this snapshot alone)
    latches_not_saved: str | None = None  # why the latched alarms' save failed, while it does
    log_failing: str | None = None  # why the log cannot be written, while it cannot
    roles: dict[str, dict[str, object] | None] | None = None  # `mash`, `coil` as status has
    current: dict[str, Any] | None = None  # the element-current input's, as status has it


def status_warnings(
    no_heat: list[int] | None,
    latches_not_saved: str | None,
    short: str | None = None,
    *,
    progress_not_saved: str | None = None,
    log_failing: str | None = None,
    sensor_faults: tuple[str, ...] = (),
) -> list[str]:
    """What the brewer should know that holds no heater off, in words: one place for the
    command line, the web page and MQTT to take them from. `short`: the reach warning's;
    `progress_not_saved`: why the mash program's progress cannot be saved; `sensor_faults`:
    the faults of the sensors beside the HLT's (the mash's, the coil outlet's), in words."""
    warnings = [f"{no_heat_words(element)} (docs/two-elements.md)" for element in no_heat or []]
    if short is not None:
        warnings.append(short)
    if latches_not_saved is not None:
        warnings.append(
            f"latched alarms not saved (tried again until they are): {latches_not_saved}"
        )
    if progress_not_saved is not None:
        warnings.append(
            f"program progress not saved (a restart may not resume it): {progress_not_saved}"
        )
    if log_failing is not None:
        warnings.append(f"log failing (control goes on, this brew is not recorded): {log_failing}")
    warnings.extend(sensor_faults)
    return warnings


class LoopLink:
    """Connects a daemon to a control server (`attach` it, then start the server)."""

    def __init__(self, daemon: Daemon, now: Callable[[], float] = time.monotonic) -> None:
        """`now`: the real clock the people and programs that send commands live by (s)."""
        self.daemon = daemon
        self._now = now
        # When (`now`) each program step became the current one, the latest last; None: no
        # program. Replaced whole by the loop, read by the server thread.
        self._steps: tuple[tuple[float, int | None], ...] = ()
        self.server: CommandSource | None = None
        self._snapshot: Snapshot | None = None
        self._encoded: tuple[Snapshot, bytes] | None = None
        self._encode_lock = threading.Lock()
        self._answering: list[Pending] = []
        self._latched_before: dict[int, list[str]] = {}  # a reset's pending: what was latched
        self._runtime: set[str] = set()  # keys set at runtime since the file last changed them
        self._config = daemon.config
        self._period = daemon.config.control.period  # fixed until a restart
        self.history = HistoryRing(capacity_for(self._period))

    def attach(self, server: CommandSource) -> None:
        self.server = server
        self.daemon.control = self
        self.daemon.listeners.append(self)

    # -- on the loop ----------------------------------------------------------------------

    def at_boundary(self, t: float) -> None:
        """Check and queue this boundary's commands (before the daemon applies its queue)."""
        if self.server is None:
            return
        for pending in self.server.take():
            problems = self._problems(pending.command)
            if isinstance(pending.command, ResetAlarms):
                self._latched_before[id(pending)] = self.daemon.supervisor.latched
            if not problems:
                try:
                    self._apply(pending.command, t)
                except Refused as error:  # checked above; a program's state said it again
                    problems = [str(error)]
            if problems:
                pending.reply = error_reply(f"refused, nothing changed: {'; '.join(problems)}")
            self._answering.append(pending)

    def period(self, record: PeriodRecord) -> None:
        """Publish what this period left, and answer the commands it applied."""
        daemon = self.daemon
        if daemon.config is not self._config:  # a file edit: its changed keys win
            self._runtime -= set(read.differences(self._config, daemon.config))
            self._config = daemon.config
        self._snapshot = Snapshot(
            record,
            daemon.config.tun.name,
            daemon.manual_output,
            daemon.supervisor.limits,
            daemon.model,
            daemon.model_choice.source,
            daemon.learned_model,
            daemon.config,
            frozenset(self._runtime),
            daemon.program.status(daemon.clock.wall_ns()),
            daemon.supervisor.reasons(),
            daemon.latches_not_saved,
            daemon.log_failing,
            daemon.role_status(),
            daemon.current_status(),
        )
        self.history.append(*encode_row(record))
        program = self._snapshot.program
        step = None if program is None else program["step"]["index"]
        if not self._steps or self._steps[-1][1] != step:
            self._steps = (*self._steps[-(STEPS_KEPT - 1) :], (self._now(), step))
        if self._answering:
            reply = None
            for pending in self._answering:
                if pending.reply is None:
                    reply = reply or self._status_message(self._snapshot)
                    pending.reply = self._reset_reply(pending, reply)
            self._answering = []
            self._latched_before.clear()
            if self.server is not None:
                self.server.wake()

    def _reset_reply(self, pending: Pending, status: dict[str, Any]) -> dict[str, Any]:
        """The status, and for a reset what it cleared and what stands and why."""
        command = pending.command
        if not isinstance(command, ResetAlarms) or self._snapshot is None:
            return status
        outcome = reset_outcome(
            command.kinds,
            self._latched_before.get(id(pending), []),
            self._snapshot.reasons,
            self._snapshot.limits,
        )
        return {**status, "reset": outcome.as_reply()}

    def alarm(self, alarm: object) -> None:
        """Alarms show in the next snapshot's record."""

    def _problems(self, command: Command) -> list[str]:
        daemon = self.daemon
        changes: dict[str, object]
        if isinstance(command, ProgramStart):
            return daemon.program_problems(command.program)
        if isinstance(command, ProgramAction):
            why = daemon.program.check(command.action, command.step)
            return [] if why is None else [why]
        if isinstance(command, SetPump):
            return [] if daemon.pump_fitted else [pump_refusal(daemon.config)]
        if isinstance(command, SetSetpoint) and daemon.program.active:
            return [
                "control.setpoint: a mash program sets the setpoint while it runs "
                "(`hermsd program stop` ends it; `hermsd program pause` holds its setpoint)"
            ]
        if isinstance(command, SetSetpoint):
            changes = {"control.setpoint": command.celsius}
        elif isinstance(command, SetMode):
            changes = {"control.mode": command.mode}
            if command.output is not None:
                changes["control.manual_output"] = command.output
        else:
            return []
        control = dataclasses.replace(
            daemon.config.control,
            setpoint=daemon.setpoint,
            mode=daemon.mode,
            manual_output=daemon.manual_output,
        )
        running = dataclasses.replace(daemon.config, control=control)
        return rules.runtime_problems(running, changes)

    def _apply(self, command: Command, t: float) -> None:
        daemon = self.daemon
        if isinstance(command, ProgramStart):
            daemon.start_program(command.program, command.ready_by, t)
        daemon.operator_action(f"{describe(command)} (from the {SOURCE})", t)
        if isinstance(command, ProgramAction):  # what it brings is logged after it
            daemon.program_command(command.action, t, command.step)
        if isinstance(command, ProgramStart | ProgramAction):
            return
        if isinstance(command, SetSetpoint):
            daemon.set_setpoint(command.celsius)
            self._runtime.add("control.setpoint")
        elif isinstance(command, ResetAlarms):
            daemon.reset_alarms(None if command.kinds is None else list(command.kinds))
        elif isinstance(command, SetPump):
            daemon.set_pump(command.on, f"by the operator (from the {SOURCE})")
        elif command.mode == "manual":
            daemon.set_manual(command.output)
            self._runtime.update(("control.mode", "control.manual_output"))
        else:
            daemon.set_auto()
            self._runtime.add("control.mode")

    # -- on the server thread -------------------------------------------------------------

    def status_line(self) -> bytes:
        """The encoded status reply, made once per snapshot however often it is asked for."""
        with self._encode_lock:
            snapshot = self._snapshot
            if snapshot is None:
                return encode(error_reply(STARTING))
            if self._encoded is None or self._encoded[0] is not snapshot:
                self._encoded = (snapshot, encode(self._status_message(snapshot)))
            return self._encoded[1]

    def arrived(self, command: Command) -> Command:
        """A confirm or next that names no step, for the step that was current SEEN_S before
        it arrived: the step the sender can have seen. A second one sent with the first (two
        terminals, a double tap) must not end the step the first one brought, which nobody
        has read yet; one for that step is refused, to be sent again when meant."""
        if (
            not isinstance(command, ProgramAction)
            or command.action not in STEP_ACTIONS
            or command.step is not None
            or not self._steps
        ):
            return command
        seen = self._now() - SEEN_S
        steps = self._steps
        step = next((index for when, index in reversed(steps) if when <= seen), steps[0][1])
        return command if step is None else dataclasses.replace(command, step=step)

    def history_line(self, request: History) -> bytes:
        """A page of the history (rows after `request.since`), encoded."""
        rows, more = self.history.page(request.since, request.limit)
        return page_line(rows, more, self._period)

    @staticmethod
    def _status_message(snapshot: Snapshot) -> dict[str, Any]:
        record = snapshot.record
        running = {
            "control.setpoint": record.setpoint,
            "control.mode": record.mode,
            "control.manual_output": snapshot.manual_output,
        }
        model, learned = snapshot.model, snapshot.learned
        return {
            "v": VERSION,
            "ok": True,
            "tun": snapshot.tun,
            "t": record.t,
            "pv": record.pv,
            "setpoint": record.setpoint,
            "output": record.output,
            "output2": record.u2,
            "applied": record.applied,
            "mode": record.mode,
            "manual_output": snapshot.manual_output,
            "state": record.state,
            "alarms": list(record.alarms),
            "alarm_reasons": snapshot.reasons,
            "latches_not_saved": snapshot.latches_not_saved,
            "log_failing": snapshot.log_failing,
            "no_heat": record.no_heat,
            "warnings": status_warnings(
                record.no_heat,
                snapshot.latches_not_saved,
                None
                if record.ceiling is None
                else short_words(
                    record.ceiling, record.setpoint, snapshot.config.control.max_output
                ),
                progress_not_saved=None
                if snapshot.program is None
                else snapshot.program.get("save_failed"),
                log_failing=snapshot.log_failing,
                sensor_faults=role_faults(snapshot.roles) + current_warnings(snapshot.current),
            ),
            "heater_allowed": record.heater_allowed,
            "setpoint_limits": setpoint_limits(snapshot.config),
            "limits": format_limits(snapshot.limits, record.setpoint),
            "model": {
                "gain": model.gain,
                "tau": model.tau,
                "dead_time": model.dead_time,
                "ambient": model.ambient,
                "from": snapshot.model_from,
            },
            "learned": None
            if learned is None
            else {
                "rate_c_per_min": learned.rate * 60.0,
                "loss_per_s": learned.loss,
                "dead_time": learned.dead_time,
                "ambient": learned.ambient,
                "litres": learned.litres,
                "learned_at_ns": learned.wall_ns,
                "text": learned.describe(),
            },
            "runtime": {
                key: {"running": running[key], "file": read.value_at(snapshot.config, key)}
                for key in RUNTIME_KEYS
                if key in snapshot.runtime and running[key] != read.value_at(snapshot.config, key)
            },
            "program": snapshot.program,
            **(snapshot.roles or {"mash": None, "coil": None}),
            "pump": record.pump,
            "pump_switched": snapshot.config.pump.backend != "none",
            "current": snapshot.current,
        }


def setpoint_limits(config: Config) -> dict[str, float]:
    """The setpoints the daemon takes: from `min` to `max` °C and `below` the cut-out
    (safety.max_temp), as its running config checks them (the thermostat card's range)."""
    low, high = read.key_range("control.setpoint")
    return {"min": low, "max": high, "below": config.safety.max_temp}


def current_warnings(current: dict[str, Any] | None) -> tuple[str, ...]:
    """The status's warning of the element-current input: its fault, or no current ever seen
    (its verdicts off meanwhile); none while it judges or where none is fitted."""
    warning = None if current is None else current.get("warning")
    return (warning,) if isinstance(warning, str) else ()


def role_faults(roles: dict[str, dict[str, object] | None] | None) -> tuple[str, ...]:
    """The status's warnings of the sensors beside the HLT's: 'mash sensor fault: …', and
    what the mash's says besides (the no-flow sign)."""
    faults = tuple(
        f"{role} sensor fault (the HLT is held as before): {status['fault']}"
        for role, status in (roles or {}).items()
        if status is not None and status["fault"] is not None
    )
    mash = (roles or {}).get("mash")
    warning = None if mash is None else mash.get("warning")
    return faults if not isinstance(warning, str) else (*faults, warning)
