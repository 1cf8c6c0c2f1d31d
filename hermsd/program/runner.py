"""The mash program as a pure state machine: time and temperature in, setpoint and events out.

Nothing here reads a clock. The daemon calls `Runner.period` once a control period with the
period's monotonic time, its PV and (while a `ready_by` program waits) the heat-up time the
tun's model gives from that PV; operator commands are methods. The rules:

- A step starts by moving the setpoint to its own: at once, or by its `ramp` (°C/min, from
  the previous step's setpoint, or from the PV for the first step). It is *reached* at the
  first period whose PV is within ±BAND of the step's setpoint (after the ramp).
- The hold counts, from then on, the time of every period whose PV is within ±BAND of the
  setpoint, while the program is not paused: time out of the band, paused, with no PV (a
  sensor fault), or while the daemon was not running (a crash, a restart) does not count.
  So a rest is always its full length at temperature, and a restart resumes it with the time
  left it had when its progress was last stored (at each step or phase change, and at most a
  minute apart: a crash can lengthen a rest by a minute, never shorten it).
- At the end of the hold a step with `confirm` waits, holding its setpoint, for `confirm()`;
  a step held "until told" holds until `next()`. After the last step the program is done and
  goes on holding the last setpoint until it is stopped.
- Pause: the setpoint stays where it is (a ramp stops), the hold time stops; resume goes on.
- On the mash: with a mash sensor fitted (`MashReading`), a step on the mash (from the step
  after the first step's "Mash in" wait, else from the first) is reached, and its hold counts,
  by the mash's latest good reading instead of the PV: the mash lags the HLT by tens of
  minutes. A mash sensor's fault counts as a missing PV does (the hold stops), said when it
  begins (`no_mash`) and ends (`mash_again`). The steps before the mash is in (the strike
  water) are timed on the HLT's PV, as is every step without a mash sensor.
- `ready_by`: the program is *scheduled* (no setpoint: the daemon keeps the heater off) until
  the daemon says it is due (`hermsd.program.readiness`); until the first step is reached its
  setpoint is then the one the daemon hands in each period (a waiting temperature under the
  step's, then the step's own when the last approach is released).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from hermsd.control.pid import PlantModel
from hermsd.metrics import BAND
from hermsd.program.model import Program, Step, mash_in_index, pump_wanted

PHASES = ("pending", "scheduled", "heating", "ramping", "holding", "waiting", "done")
"""`pending`: started, its first step begins at the next period (with that period's PV)."""
ACTIONS = ("next", "pause", "resume", "stop")


@dataclass(frozen=True, slots=True)
class MashReading:
    """A period's mash, from a fitted mash sensor: its latest good reading (None: a fault)."""

    celsius: float | None


class Refused(ValueError):
    """A command that does not apply in the program's state; the message says why."""


@dataclass(frozen=True, slots=True)
class ProgramEvent:
    """One program event, as the log's /hermsd/program topic keeps it (plus its words)."""

    event: str
    program: str
    step: int | None
    name: str | None
    setpoint: float | None
    message: str | None
    text: str


@dataclass(slots=True)
class Progress:
    """Where a program is: all a restart needs to go on (kept in the state directory)."""

    index: int = 0
    phase: str = "heating"
    paused: bool = False
    reached: bool = False
    held_s: float = 0.0
    setpoint: float | None = None  # the program's setpoint in force (a ramp's position)
    ready_at_ns: int | None = None  # scheduled: wall-clock time the first step is due (ns)
    events: list[ProgramEvent] = field(default_factory=list)  # since last taken


def heat_up_s(model: PlantModel, output: float, pv: float, target: float) -> float | None:
    """Seconds of `output` % from now until the sensor reads `target` or more, by the FOPTD
    model (None: the model never gets there); 0 when it does already."""
    return 0.0 if pv >= target else reach_s(model, output, pv, target)


def reach_s(model: PlantModel, output: float, pv: float, target: float) -> float | None:
    """Seconds of `output` % from now until the sensor, rising or falling, reads `target`, by
    the FOPTD model (None: the model settles short of it). The sensor follows y(t) = Ta + K·u
    + e^(−t/τ)·(y0 − Ta − K·u·e^(θ/τ)) once the dead time θ has passed."""
    if pv == target:
        return 0.0
    gain_u = model.gain * output
    reach = model.ambient + gain_u - target
    start = gain_u * math.exp(model.dead_time / model.tau) - (pv - model.ambient)
    if pv > target:  # a fall: both below zero when the model settles below the target
        reach, start = -reach, -start
    if reach <= 0.0 or start <= 0.0:
        return None
    return max(model.dead_time, model.tau * math.log(start / reach))


class Runner:
    """One program's progress, driven period by period."""

    def __init__(self, program: Program, progress: Progress, *, max_step_s: float) -> None:
        self.program = program
        self.progress = progress
        self._max_step_s = max_step_s  # the most one period may count (a stalled loop: less)
        self._last_t: float | None = None  # nothing counts from before a restart
        self._mash_lost = False  # a step on the mash has no mash reading (said once)
        # s since the step began, for its pump timer: not kept over a restart, where the
        # timer begins again with the pump running.
        self._step_s = 0.0

    @classmethod
    def start(
        cls, program: Program, *, max_step_s: float, ready_at_ns: int | None = None
    ) -> Runner:
        """A new run: scheduled until `ready_at_ns` is near, else heating from the next period."""
        runner = cls(program, Progress(), max_step_s=max_step_s)
        p = runner.progress
        what = f"program {program.name!r} started ({len(program.steps)} steps)"
        runner._emit("started", what, step=None)
        if ready_at_ns is not None:
            p.phase, p.ready_at_ns = "scheduled", ready_at_ns
        else:
            p.phase = "pending"
        return runner

    # -- what it says -------------------------------------------------------------------

    @property
    def step(self) -> Step:
        return self.program.steps[min(self.progress.index, len(self.program.steps) - 1)]

    @property
    def state(self) -> str:
        """One of scheduled, heating, ramping, holding, waiting, paused, done."""
        p = self.progress
        return "paused" if p.paused else ("heating" if p.phase == "pending" else p.phase)

    @property
    def setpoint(self) -> float | None:
        """The setpoint the program asks for now; None while scheduled or while a `ready_by`
        heat-up waits (heater off)."""
        return self.progress.setpoint

    def time_left_s(self) -> float | None:
        """Of this step's hold; None until reached, or when held until told."""
        p = self.progress
        if p.phase == "waiting":
            return 0.0
        if p.phase != "holding" or not p.reached or self.step.hold is None:
            return None
        return max(0.0, self.step.hold - p.held_s)

    @property
    def pump(self) -> bool:
        """Whether the current step runs the pump now (`model.pump_wanted`, and its timer's
        running part); off while scheduled."""
        return self._pump_wanted() and self.pump_turns() % 2 == 0

    def _pump_wanted(self) -> bool:
        p = self.progress
        return p.phase not in ("scheduled", "pending") and pump_wanted(self.program, p.index)

    def _timer(self) -> tuple[float, float, float] | None:
        """The step's pump timer, (every, running s of each, s into the current cycle);
        None without one, or on a step that does not run the pump."""
        timer = self.step.pump_timer
        if timer is None or not self._pump_wanted():
            return None
        every, stop = timer
        return every, every - stop, self._step_s % every

    def pump_turns(self) -> int:
        """How often the step's pump timer has switched the pump since the step began (even:
        it runs); 0 without a timer."""
        timer = self._timer()
        if timer is None:
            return 0
        every, runs, into = timer
        return 2 * int(self._step_s // every) + (1 if into >= runs else 0)

    def pump_turn_in(self) -> float | None:
        """s until the step's pump timer next switches the pump, if the step lasts (None:
        no timer, or a step that does not run the pump)."""
        timer = self._timer()
        if timer is None:
            return None
        every, runs, into = timer
        return runs - into if into < runs else every - into

    def on_mash(self, mash: MashReading | None) -> bool:
        """Whether the current step is timed on the mash (a sensor fitted, the mash in)."""
        return mash is not None and self.progress.index >= mash_in_index(self.program)

    def next_name(self) -> str | None:
        index = self.progress.index + 1
        done = self.progress.phase == "done"
        return None if done or index >= len(self.program.steps) else self.program.steps[index].name

    def take_events(self) -> list[ProgramEvent]:
        events, self.progress.events = self.progress.events, []
        return events

    # -- one control period -------------------------------------------------------------

    def period(
        self,
        t: float,
        pv: float | None,
        ready_setpoint: float | None = None,
        mash: MashReading | None = None,
    ) -> None:
        """Advance by one period at `t` with its PV. `ready_setpoint`: while a `ready_by`
        program has not reached its first step, the setpoint its heat-up asks for (None
        while scheduled: not due yet). `mash`: the mash's reading (None: no mash sensor)."""
        dt = 0.0 if self._last_t is None else min(max(0.0, t - self._last_t), self._max_step_s)
        self._last_t = t
        p = self.progress
        self._step_s += dt  # a pump timer runs on through a pause and after the last step
        if p.paused or p.phase == "done":
            return
        if p.phase == "scheduled":
            assert p.ready_at_ns is not None
            if ready_setpoint is None:
                return
            self._begin(0, self._timed(pv, mash))
        elif p.phase == "pending":
            self._begin(0, self._timed(pv, mash))
        step = self.step
        if p.phase == "ramping":
            assert p.setpoint is not None
            assert step.ramp is not None
            move = step.ramp / 60.0 * dt
            gap = step.setpoint - p.setpoint
            if abs(gap) <= move:
                p.setpoint, p.phase = step.setpoint, "heating"
            else:
                p.setpoint += math.copysign(move, gap)
        timed = self._timed(pv, mash)
        in_band = timed is not None and abs(timed - step.setpoint) <= BAND
        if self.on_mash(mash):
            self._say_mash(mash)
        if p.phase == "heating" and p.ready_at_ns is not None:
            p.setpoint = ready_setpoint  # None: the heat-up waits, heater off
        if p.phase == "heating" and in_band:
            p.phase, p.reached, p.ready_at_ns = "holding", True, None
            p.setpoint = step.setpoint
            hold = "until told" if step.hold is None else _duration(step.hold)
            where = " in the mash" if self.on_mash(mash) else ""
            self._emit(
                "step_reached",
                f"step {step.name!r} reached {step.setpoint:g} °C{where}; holding {hold}",
            )
        elif p.phase == "holding" and in_band:
            p.held_s += dt
        if p.phase == "holding" and step.hold is not None and p.held_s >= step.hold:
            self._emit("step_done", f"step {step.name!r} done: held {_duration(p.held_s)}")
            if step.confirm is not None:
                p.phase = "waiting"
                self._emit(
                    "waiting",
                    f"step {step.name!r} waits for the brewer: {step.confirm} "
                    "(`hermsd confirm` when done)",
                    message=step.confirm,
                )
            else:
                self._advance(pv)

    def _timed(self, pv: float | None, mash: MashReading | None) -> float | None:
        """The temperature the current step is timed on: the mash's, else the PV."""
        return mash.celsius if mash is not None and self.on_mash(mash) else pv

    def _say_mash(self, mash: MashReading | None) -> None:
        """Say when a step on the mash loses its mash reading (its hold stops) and regains it."""
        celsius = None if mash is None else mash.celsius
        lost = celsius is None
        if lost == self._mash_lost or self.progress.phase not in ("heating", "holding"):
            return
        self._mash_lost = lost
        name = self.step.name
        if celsius is None:
            self._emit(
                "no_mash",
                f"step {name!r}: no mash reading: its hold's time stops until the mash "
                "sensor reads again",
            )
        else:
            self._emit("mash_again", f"step {name!r}: the mash reads {celsius:.2f} °C again")

    def _begin(self, index: int, pv: float | None) -> None:
        """Start step `index`: its setpoint at once, or a ramp from where the setpoint is."""
        p = self.progress
        if index > 0 or self.step.ramp is not None:
            p.ready_at_ns = None  # only the first step is timed, and only without a ramp
        p.index, p.reached, p.held_s = index, False, 0.0
        self._step_s = 0.0
        step = self.step
        origin = p.setpoint if p.setpoint is not None else pv
        if step.ramp is not None and origin is not None and origin != step.setpoint:
            p.phase, p.setpoint = "ramping", origin
            how = f"ramping at {step.ramp:g} °C/min from {origin:.1f} °C"
        else:
            p.phase, p.setpoint = "heating", step.setpoint
            how = "at once"
        hold = "until told" if step.hold is None else _duration(step.hold)
        self._emit(
            "step_started",
            f"step {index + 1}/{len(self.program.steps)} {step.name!r}: {step.setpoint:g} °C "
            f"({how}), hold {hold}",
        )

    def _advance(self, pv: float | None) -> None:
        p = self.progress
        if p.index + 1 >= len(self.program.steps):
            p.phase = "done"
            self._emit(
                "finished",
                f"program {self.program.name!r} finished; holding {p.setpoint:g} °C "
                "until `hermsd program stop`",
                step=None,
            )
            return
        self._begin(p.index + 1, pv)

    # -- commands -----------------------------------------------------------------------

    def check(self, action: str, step: int | None = None) -> str | None:
        """Why `action` (next, pause, resume, stop, confirm) does not apply now; None if it does.

        `step`: the index of the step a confirm or next means to end (None: the current one);
        another step is refused, so that a second confirm or next sent for the same step
        does not end the one after it, unseen."""
        p = self.progress
        if action == "stop":
            return None
        if step is not None and step != p.index:
            now = self.program.steps[p.index]
            return (
                f"{action} was for step {step + 1}, which is not the current one "
                f"(step {p.index + 1}/{len(self.program.steps)} {now.name!r} is {self.state}; "
                "look at the status and send it again for that step if meant)"
            )
        if p.phase == "done":
            return (
                f"the program is done (`hermsd program stop` ends it; {action} has nothing to do)"
            )
        if action == "resume":
            return None if p.paused else f"the program is not paused (it is {self.state})"
        if p.paused:
            return f"the program is paused (`hermsd program resume` first; {action} waits)"
        if p.phase in ("scheduled", "pending") and action in ("next", "pause"):
            return (
                "the program has not started heating yet (`hermsd program stop` cancels it; "
                "start it again without --ready-by to heat now)"
            )
        if action == "confirm" and p.phase != "waiting":
            return f"nothing waits for a confirmation (the step is {self.state})"
        return None

    def command(self, action: str, pv: float | None, for_step: int | None = None) -> None:
        """Apply `action` (a confirm or next: to step `for_step`, None: the current);
        Refused (changing nothing) when it does not apply now."""
        why = self.check(action, for_step)
        if why is not None:
            raise Refused(why)
        p = self.progress
        step = self.step
        if action == "pause":
            p.paused = True
            self._emit(
                "paused", f"program paused at step {step.name!r}: setpoint held, hold time stopped"
            )
        elif action == "resume":
            p.paused = False
            self._emit("resumed", f"program resumed at step {step.name!r}")
        elif action == "confirm":
            self._emit(
                "confirmed", f"step {step.name!r} confirmed: {step.confirm}", message=step.confirm
            )
            self._advance(pv)
        elif action == "next":
            self._emit("skipped", f"step {step.name!r} ended by `program next`")
            self._advance(pv)
        else:
            self._emit("stopped", f"program {self.program.name!r} stopped", step=None)

    def say(self, event: str, text: str) -> None:
        """An event of the current step from outside the runner (a `ready_by` heat-up's),
        its words logged as its message too, so that replay can say what was decided."""
        self._emit(event, text, message=text)

    def _emit(
        self, event: str, text: str, *, step: bool | int | None = True, message: str | None = None
    ) -> None:
        p = self.progress
        index = p.index if step is True else None
        self.progress.events.append(
            ProgramEvent(
                event,
                self.program.name,
                index,
                None if index is None else self.program.steps[index].name,
                None if index is None else self.program.steps[index].setpoint,
                message,
                text,
            )
        )


def _duration(seconds: float) -> str:
    """90 s → '1m30s', 3600 → '1h'."""
    whole = round(seconds)
    hours, rest = divmod(whole, 3600)
    minutes, secs = divmod(rest, 60)
    parts = [f"{v}{u}" for v, u in ((hours, "h"), (minutes, "m"), (secs, "s")) if v]
    return "".join(parts) or "0s"
