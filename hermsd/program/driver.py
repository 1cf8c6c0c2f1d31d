"""The daemon's side of a mash program: the runner, its stored progress, local time.

The loop calls `period` once a control period, before the controller steps; it answers with
the setpoint the program asks for (None: a `ready_by` program waits, the heater stays off).
Commands are applied at once (the loop calls them at a period boundary). Everything that
happened comes back as events for the log, the program topic and the alerts.

The setpoint rule: a program owns the setpoint from its start until it is stopped (when done,
it holds the last step's setpoint). Meanwhile `hermsd set setpoint` is refused, and an edit
of `control.setpoint` in the config file does not move the setpoint: it is kept, and the
setpoint returns to it when the program stops. Without such an edit the setpoint returns to
the one in force before the program started.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import logging
from dataclasses import dataclass, field
from typing import Any

from hermsd.metrics import BAND
from hermsd.program.model import READY_BY, Program
from hermsd.program.readiness import Readiness, Tun
from hermsd.program.runner import MashReading, ProgramEvent, Refused, Runner, reach_s
from hermsd.program.store import SAVE_EVERY_S, ProgressStore, ProgressWriter, stale_reason
from hermsd.safety.latches import StateError

log = logging.getLogger("hermsd")


def next_local_time(wall_ns: int, hh_mm: str, zone: dt.tzinfo | None) -> int:
    """The next wall-clock time (ns) after `wall_ns` whose local time is `hh_mm`.

    `zone` None: the system's local time (with its daylight saving rules)."""
    match = READY_BY.fullmatch(hh_mm)
    if match is None:
        raise ValueError(f"ready_by {hh_mm!r} is not a local time (HH:MM, e.g. 06:30)")
    now = dt.datetime.fromtimestamp(wall_ns / 1e9, zone)
    due = now.replace(hour=int(match["hour"]), minute=int(match["minute"]), second=0, microsecond=0)
    if due <= now:
        due = (due.replace(tzinfo=None) + dt.timedelta(days=1)).replace(tzinfo=due.tzinfo)
    return round(due.timestamp() * 1e9)


def local_iso(wall_ns: int, zone: dt.tzinfo | None) -> str:
    """`wall_ns` as local time, ISO 8601 with its offset, to the second."""
    moment = dt.datetime.fromtimestamp(wall_ns / 1e9, zone)
    return (moment if zone is not None else moment.astimezone()).isoformat(timespec="seconds")


@dataclass(slots=True)
class ProgramDriver:
    """The program the daemon runs (if any), kept in `store` (None: nowhere)."""

    store: ProgressStore | None
    zone: dt.tzinfo | None  # local time's zone; None: the system's
    period_s: float
    runner: Runner | None = None
    after: float | None = None  # the setpoint to return to when the program stops
    readiness: Readiness | None = None  # a `ready_by` heat-up until its first step is reached
    _events: list[ProgramEvent] = field(default_factory=list)
    _writer: ProgressWriter | None = None
    _started_at_ns: int = 0  # names the stored program its progress records belong to
    _saved: tuple[int, str, bool, bool] | None = None  # what the last record handed over said
    _saved_t: float = 0.0
    _failure_said: str | None = None
    _rest_in_s: float | None = None  # the last period's `rest_in`

    def __post_init__(self) -> None:
        if self.store is not None:
            self._writer = ProgressWriter(self.store)

    @property
    def active(self) -> bool:
        return self.runner is not None

    @property
    def starts_at_ns(self) -> int | None:
        """While scheduled: when the heat-up is due to start (None: not known yet)."""
        return None if self.readiness is None else self.readiness.starts_at_ns

    @property
    def target(self) -> float:
        """The current step's setpoint (a scheduled program's first step)."""
        assert self.runner is not None
        return self.runner.step.setpoint

    # -- start, restore, commands -------------------------------------------------------

    def restore(self, setpoint: float, wall_ns: int) -> str | None:
        """Take up the stored program, if any and recent; what to say in the log (or None).

        One that had finished, whose ready-by time has passed or that was saved too long
        ago is set aside (`program.json.stale`): the daemon runs on `setpoint` instead."""
        if self.store is None:
            return None
        try:
            stored = self.store.load()
        except StateError as error:
            return f"program progress not resumed: {error}; {self._set_aside()}; " + (
                f"the setpoint is {setpoint:g} °C"
            )
        if stored is None:
            return None
        program, progress, _saved_at, started_at, _boot = stored
        ready = progress.ready_at_ns
        ready_text = "" if ready is None else local_iso(ready, self.zone)
        stale = stale_reason(stored, wall_ns, ready_text, self.store.boot)
        if stale is not None:
            return (
                f"program {program.name!r} not resumed: {stale}; {self._set_aside()}; "
                f"the setpoint is {setpoint:g} °C"
            )
        self.runner = Runner(program, progress, max_step_s=2.0 * self.period_s)
        self.after, self._started_at_ns, self._saved = setpoint, started_at, None
        if ready is not None:  # measured again: what was measured before is gone
            first = program.steps[0].setpoint
            phase = "scheduled" if progress.phase == "scheduled" else "climbing"
            if progress.setpoint == first and phase == "climbing":
                phase = "released"
            self.readiness = Readiness(first, ready, self._clock_text, phase=phase)
        runner = self.runner
        left = runner.time_left_s()
        where = f"step {progress.index + 1}/{len(program.steps)} {runner.step.name!r}, " + (
            f"{left:.0f} s of its hold left" if left is not None else runner.state
        )
        return f"program {program.name!r} resumed after a restart at {where}"

    def _set_aside(self) -> str:
        """The stored program's files kept beside as `….stale`, for the brewer to read; said."""
        assert self.store is not None
        try:
            return f"kept as {self.store.set_aside()}"
        except OSError as error:
            return f"setting it aside failed: {error}"

    def problems(self, program: Program) -> list[str]:
        """Why `program` cannot start now, beyond its own checks; [] when it can."""
        if self.runner is not None:
            return [f"program {self.runner.program.name!r} runs (`hermsd program stop` first)"]
        return []

    def start(
        self,
        program: Program,
        ready_by: str | None,
        *,
        setpoint: float,
        wall_ns: int,
        pv: float | None,
        tun: Tun,
    ) -> None:
        """Start `program` (ready by `ready_by`, else at once), from the current PV."""
        if self.runner is not None:
            raise Refused(self.problems(program)[0])
        when = ready_by or program.ready_by
        ready_at = None if when is None else next_local_time(wall_ns, when, self.zone)
        runner = Runner.start(program, max_step_s=2.0 * self.period_s, ready_at_ns=ready_at)
        self.runner, self.after = runner, setpoint
        self._started_at_ns, self._saved = wall_ns, None
        if self._writer is not None:
            self._writer.program(program, wall_ns)
        events = runner.take_events()
        if ready_at is not None:
            first = program.steps[0]
            readiness = Readiness(first.setpoint, ready_at, self._clock_text)
            self.readiness = readiness
            lead_s = None if pv is None else readiness.lead_s(pv, tun)
            if lead_s is not None:
                readiness.starts_at_ns = max(wall_ns, ready_at - round(lead_s * 1e9))
            start = (
                f"heating starts at {self._clock_text(readiness.starts_at_ns)}, "
                f"to wait at {readiness.wait_at:g} °C"
                if readiness.starts_at_ns is not None
                else "heating starts when the tun's model says (no PV yet)"
            )
            events = [
                dataclasses.replace(
                    event,
                    text=f"{event.text}; {start} to be at {first.setpoint:g} °C by "
                    f"{local_iso(ready_at, self.zone)}",
                )
                for event in events
            ]
        self._events.extend(events)

    def command(self, action: str, pv: float | None, step: int | None = None) -> float | None:
        """Apply next, pause, resume, stop or confirm (Refused when it does not apply);
        `step`: the index of the step a confirm or next is for (None: the current one).

        Returns the setpoint to go back to when the program stopped, else None."""
        runner = self.runner
        if runner is None:
            raise Refused(f"no program runs ({action} has nothing to act on)")
        runner.command(action, pv, step)
        self._events.extend(runner.take_events())
        if action != "stop":
            return None
        self.runner, self.readiness = None, None
        if self._writer is not None:
            self._writer.clear()
        return self.after

    def take_events(self) -> list[ProgramEvent]:
        """The events not yet handed over (a program stopped between periods)."""
        events, self._events = self._events, []
        return events

    def check(self, action: str, step: int | None = None) -> str | None:
        if self.runner is None:
            return f"no program runs ({action} has nothing to act on)"
        return self.runner.check(action, step)

    # -- each period ------------------------------------------------------------------

    def period(
        self,
        t: float,
        pv: float | None,
        wall_ns: int,
        tun: Tun,
        applied: float,
        full: bool,
        mash: MashReading | None = None,
    ) -> tuple[float | None, list[ProgramEvent]]:
        """The program's setpoint for this period (None: keep the heater off), and events.

        `applied`: the duty the elements were driven at in the period just ended (%, of their
        total); `full`: that was full power (hermsd.control.reach.FullPower); `mash`: the
        mash's reading (None: no mash sensor). The heat-up of `ready_by` is the HLT's (its
        first step is the strike water's): it is judged on the PV whatever `mash` says."""
        runner = self.runner
        if runner is None:
            return None, self.take_events()
        ready_setpoint = None
        readiness = self.readiness
        if readiness is not None:
            ready_setpoint = readiness.period(t, wall_ns, pv, applied, full, tun)
            for kind, text in readiness.take_events():
                runner.say(kind, text)
        runner.period(t, pv, ready_setpoint, mash)
        self._rest_in_s = rest_in(runner, pv, tun, mash)
        if runner.progress.ready_at_ns is None:
            self.readiness = None  # reached, skipped or stopped: the heat-up is over
        self._events.extend(runner.take_events())
        self._save(runner, t, wall_ns)
        return runner.setpoint, self.take_events()

    def pump_step(self) -> tuple[int, int, bool] | None:
        """The current step's index, its pump timer's turns so far, and whether it runs the
        pump now (None: no program runs)."""
        runner = self.runner
        if runner is None:
            return None
        return runner.progress.index, runner.pump_turns(), runner.pump

    def _clock_text(self, wall_ns: int) -> str:
        """A wall-clock time as the brewer reads it in a message: local, to the second."""
        return local_iso(wall_ns, self.zone)[11:19]

    def _save(self, runner: Runner, t: float, wall_ns: int) -> None:
        """Hand the progress to the writer when it matters: a new step, phase, pause or
        reached at once; the hold's time (and a ramp's position) at most once a minute."""
        if self._writer is None:
            return
        p = runner.progress
        mark = (p.index, p.phase, p.paused, p.reached)
        if mark == self._saved and t - self._saved_t < SAVE_EVERY_S:
            return
        self._writer.progress(dataclasses.replace(p), self._started_at_ns, wall_ns)
        self._saved, self._saved_t = mark, t

    def _clear(self) -> None:
        assert self.store is not None
        try:
            self.store.clear()
        except OSError as error:
            log.error("removing the program's progress failed: %s", error)

    def store_news(self) -> tuple[bool, str] | None:
        """A change in whether the progress can be saved: (failing, what to log), or None."""
        failure = None if self._writer is None else self._writer.failure
        if failure == self._failure_said:
            return None
        self._failure_said = failure
        if failure is None:
            return False, "the program's progress is saved again"
        return (
            True,
            f"saving the program's progress failed (a restart may not resume it): {failure}",
        )

    def flush(self, timeout: float | None = None) -> bool:
        """Wait for the writes handed over (False: `timeout` passed first)."""
        return self._writer is None or self._writer.flush(timeout)

    def close(self, timeout: float) -> bool:
        """Finish the writes handed over (at most `timeout` s): the daemon stops."""
        return self._writer is None or self._writer.close(timeout)

    # -- what it says -----------------------------------------------------------------

    def status(self, wall_ns: int) -> dict[str, Any] | None:
        """The `program` field of the status reply (None: no program runs)."""
        runner = self.runner
        if runner is None:
            return None
        step, progress = runner.step, runner.progress
        late = None if self.readiness is None else self.readiness.late_until_ns
        return {
            "name": runner.program.name,
            "state": runner.state,
            "step": {"index": progress.index, "name": step.name, "setpoint": step.setpoint},
            "steps": len(runner.program.steps),
            "time_left_s": runner.time_left_s(),
            "next": runner.next_name(),
            "message": step.confirm if progress.phase == "waiting" else None,
            "starts_at": None
            if self.starts_at_ns is None
            else local_iso(self.starts_at_ns, self.zone),
            "late_until": None if late is None else local_iso(late, self.zone),
            "late": None if self.readiness is None else self.readiness.late,
            "rest_in_s": self._rest_in_s if runner.state == "heating" else None,
            "save_failed": self._failure_said,
        }

    def record_fields(self) -> dict[str, Any]:
        """The period record's step fields."""
        runner = self.runner
        if runner is None:
            return {"step": None, "step_index": None, "step_left_s": None, "next_step": None}
        return {
            "step": runner.step.name,
            "step_index": runner.progress.index,
            "step_left_s": runner.time_left_s(),
            "next_step": runner.next_name(),
        }

    def status_words(self, wall_ns: int) -> str:
        """For the status line: 'Saccharification 42m left', '… waits: Mash in'."""
        runner = self.runner
        if runner is None:
            return ""
        words = self._progress_words()
        readiness = self.readiness
        if readiness is not None and readiness.late is not None:
            late = readiness.late_until_ns
            words += ", LATE: " + (
                "cannot reach it" if late is None else f"ready at {self._clock_text(late)[:5]}"
            )
        if self._failure_said is not None:
            words += ", progress NOT SAVED"
        return words

    def _progress_words(self) -> str:
        runner = self.runner
        assert runner is not None
        step, state = runner.step.name, runner.state
        left = runner.time_left_s()
        if self.starts_at_ns is not None:  # scheduled, or a climb waiting
            return (
                f"program scheduled, heating from {local_iso(self.starts_at_ns, self.zone)[11:16]}"
            )
        if state == "waiting":
            return f"{step} waits: {runner.step.confirm}"
        if state == "holding" and left is not None:
            return f"{step} {left / 60.0:.0f} min left"
        return f"{step} {state}"


def rest_in(runner: Runner, pv: float | None, tun: Tun, mash: MashReading | None) -> float | None:
    """s until the water reaches the step's band by the tun's model, at full power up to a
    warmer step or with the heater off down to a cooler one (72 → 64 °C); None while the
    program heads for no band, when the model settles short of it, during a `ready_by`
    heat-up (which says its own times) and for a step timed on the mash (the HLT's model
    does not tell the mash's temperature)."""
    heading = runner.state == "heating" and runner.progress.ready_at_ns is None
    if not heading or pv is None or runner.on_mash(mash):
        return None
    target = runner.step.setpoint
    if abs(pv - target) <= BAND:
        return 0.0
    if pv < target:
        return reach_s(tun.model, tun.max_output, pv, target - BAND)
    return reach_s(tun.model, 0.0, pv, target + BAND)
