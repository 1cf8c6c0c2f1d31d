"""When to heat so that a `ready_by` program's first step is reached at the time asked for.

The tun's model (the config's prior, or what was learned) is good enough to say roughly when
to start heating, not when to the minute the water will be in the band: what it knows least
are the losses near the top (an open pot's evaporation grows steeply there) and the dead
time. So the heat-up is done in two parts, the second timed by measurements taken close to
where it runs:

1. *Climb*: from `starts_at` (the model's full-power time from the water's temperature,
   MARGIN and FILL_MARGIN longer, plus WAIT_S) the setpoint is the waiting temperature,
   WAIT_BELOW under the step's, and the controller holds the water there. Once the
   controller has measured the element's rate on the climb, a climb that started early for
   that rate stops for a while, heater off (FILL_MARGIN). On the way up, the full-power rise rate
   is measured (a line through the PV over the last MEASURE_S of one full-power run); while
   waiting, the losses there (the element's full-power rate times the mean duty that holds
   the water, less what the water stored meanwhile).
2. *Release*: every period, the time one full-power approach needs from the PV to the band's
   lower edge is worked out from the best of those measurements (the dead time, unless full
   power runs already, then the rise, slowed as the losses grow with the temperature); once
   it reaches the time left, the setpoint becomes the step's.

When the approach would end more than LATE_S after the time asked for (a tun too weak, or a
program started too late), a `late` event says until when it needs, and again whenever that
slips RESAY_S further; the latest estimate stays in the status meanwhile. After the release
the approach is judged again every period until the water reaches the band, from what is
under way (`_approaching`): the full-power line while full power runs, its dead time counted
from when it began; else, where the heat already sent brings the water into the band (the
controller's prediction), the sooner of the water's own rise over the last MIN_SPAN_S (a
straight line lands sooner than the lag's tail; no later than heating again from where the
water is) and a dead time after full power last ran (by which its heat has arrived): late
only where both say so; where it does not (or nothing predicts it, or that heat has arrived
and the water does not rise), a dead time and the line from where that heat leaves the water
(the controller holds off, or must heat again). Nothing here reads a clock: time comes in
with every period.
"""

from __future__ import annotations

import dataclasses
import statistics
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from hermsd.control.learning import WATER_SPAN_S, water_came
from hermsd.control.pid import PlantModel
from hermsd.control.reach import MEASURE_S, RISE_FROM_S, Rise
from hermsd.control.watches import HeatUpFit
from hermsd.metrics import BAND
from hermsd.program.runner import heat_up_s

SCHEDULE_EVENTS = ("climb", "release", "late")
"""The program events a ready_by schedule logs: what it decided, and why."""
WAIT_BELOW = 2.0
"""°C under the first step's setpoint where the water waits: holding it never enters the band
(a hold's wobble is well under the 1.5 °C between), and the approach from it is short enough
that the losses change little on the way (1.5 °C)."""
WAIT_S = 900.0
"""The wait planned at the waiting temperature: time for the hold to settle and be measured."""
MARGIN_PRIOR = 0.45
"""How much longer than the config's prior the climb is planned: the prior knows nothing of an
open pot's evaporation, which makes a heat-up up to 1.4× its time on the bench's tuns."""
MARGIN_MEASURED = 0.1
"""The same for a model measured on this tun (learned, or `hermsd tune`)."""
FILL_MARGIN = 0.25
"""Further margin of the climb's start, until the controller has measured the element's rate
on it: the model knows the config's (or the learned) fill, which changes every brew day.
Once the rate is measured, a climb that started early for it stops, the heater off (while
the water is still low, where it loses little), until the model, taken at the measured
rate, says to go on."""
MIN_STOP_S = 600.0
"""A climb that started early by less than this goes on: a stop would save nothing worth a
restart of the heat-up (and of its measurements)."""
MIN_SPAN_S = 120.0
"""A rate is taken from no shorter a span (noise and the LM92's 0.0625 °C steps)."""
SETTLE_S = 300.0
"""After the water first reaches the waiting temperature, before its holding duty counts."""
LATE_S = 120.0
"""Later than the time asked for by more than this: the `late` warning."""
CLIMB_SHARE = 0.5
"""The share of the way from the start to the waiting temperature the climb's rate must be
measured beyond before it is taken for the top: lower down, the losses it rests on (the
element's rate less the measured one) are small against the error of either, and a line
through them from the start says little of the top."""
RESAY_S = 600.0
"""A `late` estimate that slipped this much further than the last one said is said again."""
NEVER = 2**63 - 1
"""A `late` that said the step is never reached (a time no estimate comes to)."""


MODEL = "the tun's model"
CLIMBED = "the rate measured on the way up"
HELD = "the losses measured at the waiting temperature"
RISING = "the water's rise now"
SENT = "the heat already sent arriving within the dead time"


@dataclass(frozen=True, slots=True)
class Tun:
    """What the daemon knows of the tun in a period."""

    model: PlantModel
    max_output: float  # % of the model's power (both elements') full power gives
    measured: bool  # the model was measured on this tun (else the config's prior)
    fit: HeatUpFit | None  # the controller's last heat-up measurement, if any
    ahead: float | None = None  # the PV once the heat already sent arrives (predictive's)
    noise: float = 1.0  # the readings' scatter over the bench's (`predictive.noise_scale`)

    def gross_rate(self) -> float:
        """°C/s at full power without losses: the heat-up's measurement, else the model's."""
        fit = self.fit
        rate = fit.rate if fit is not None and fit.refused is None else self.model.rate
        return rate * self.max_output / 100.0

    def dead_time(self) -> float:
        return known_dead_time(self.model, self.fit)


def known_dead_time(model: PlantModel, fit: HeatUpFit | None) -> float:
    """s before a new full power shows: the controller's last heat-up measurement (`fit`),
    unless refused, else the model's (the reach watch's too, in the daemon and in replay)."""
    return fit.dead_time if fit is not None and fit.refused is None else model.dead_time


def _line(points: list[tuple[float, float]]) -> tuple[float, float] | None:
    """(mean x, slope) of a least-squares line through (t, x) points spanning MIN_SPAN_S."""
    if len(points) < 4 or points[-1][0] - points[0][0] < MIN_SPAN_S:
        return None
    ts, xs = [p[0] for p in points], [p[1] for p in points]
    return statistics.fmean(xs), statistics.linear_regression(ts, xs).slope


class Readiness:
    """One `ready_by` heat-up, period by period: the setpoint it asks for and what it says.

    `clock_text` turns a wall-clock time (ns) into the local time the brewer reads."""

    def __init__(
        self,
        target: float,
        ready_at_ns: int,
        clock_text: Callable[[int], str],
        *,
        phase: str = "scheduled",
    ) -> None:
        self.target = target
        self.wait_at = target - WAIT_BELOW
        self.ready_at_ns = ready_at_ns
        self.phase = phase  # scheduled, climbing, waiting (at wait_at), released
        self.starts_at_ns: int | None = None  # while scheduled: when the climb is due
        self.late_until_ns: int | None = None  # the latest estimate, while it is late
        self.late: str | None = None  # why it is late, while it is (the latest estimate)
        self._clock_text = clock_text
        self._events: list[tuple[str, str]] = []
        self._said_until: int | None = None  # what the last `late` said (NEVER: never)
        self._start_pv: float | None = None
        self._run: deque[tuple[float, float]] = deque()  # this full-power run's PV
        self._full: deque[tuple[float, float]] = deque()  # its last WATER_SPAN_S, from the start
        self._run_since: float | None = None
        self._climb: tuple[float, float] | None = None  # (mean PV, rate) of the last run
        self._arrived: float | None = None  # t the waiting temperature was first reached
        self._hold: deque[tuple[float, float, float]] = deque()  # (t, pv, applied) there
        self._held: deque[tuple[float, float]] = deque()  # (t, pv) there, the last minute
        self._fit_before: HeatUpFit | None = None  # the controller's fit before the climb
        self._fit: HeatUpFit | None = None  # its first on the climb (from the water at rest)
        self._paused = False  # the climb waits, heater off (it started early)
        self._paused_once = phase != "scheduled"  # a climb taken up after a restart goes on
        self._approach: deque[tuple[float, float]] = deque()  # (t, pv) since the release
        self._full_until: float | None = None  # t full power last ran, since the release

    def take_events(self) -> list[tuple[str, str]]:
        """(kind, text) of what happened since last taken: `climb`, `release`, `late`."""
        events, self._events = self._events, []
        return events

    def lead_s(self, pv: float, tun: Tun, fitted: bool = False) -> float | None:
        """How long before the time asked for the climb starts: the model's full-power time
        to the band, MARGIN (and FILL_MARGIN) longer, plus WAIT_S; when the model never gets
        to the band, its time to the waiting temperature and WAIT_S more for the rest (None:
        it never gets there either). A water below the model's room stood in a colder one:
        that room is taken (more losses, an earlier start). `fitted`: the controller's fit
        (`tun.fit`) was taken on this climb: the model at its rate (another fill scales the
        heat capacity, so τ, not K) and dead time, without FILL_MARGIN."""
        model = dataclasses.replace(tun.model, ambient=min(tun.model.ambient, pv))
        fill = FILL_MARGIN
        if fitted and tun.fit is not None:
            tau = 100.0 * model.gain / tun.fit.rate
            model, fill = dataclasses.replace(model, tau=tau, dead_time=tun.fit.dead_time), 0.0
        climb = heat_up_s(model, tun.max_output, pv, self.wait_at)
        if climb is None:
            return None
        full = heat_up_s(model, tun.max_output, pv, self.target - BAND)
        heat = climb + WAIT_S if full is None else full
        margin = MARGIN_MEASURED if tun.measured else MARGIN_PRIOR
        return (1.0 + margin + fill) * heat + WAIT_S

    def period(
        self, t: float, wall_ns: int, pv: float | None, applied: float, full: bool, tun: Tun
    ) -> float | None:
        """The setpoint for this period (None: keep the heater off, not yet due). `applied`:
        the elements' duty in the period just ended (% of their total); `full`: that was full
        power (hermsd.control.reach.FullPower: with two elements, each at its own)."""
        if pv is None:  # nothing to judge by: as before
            return self._setpoint()
        if self.phase == "scheduled":
            lead = self.lead_s(pv, tun)
            due = wall_ns if lead is None else self.ready_at_ns - round(lead * 1e9)
            self.starts_at_ns = due
            if wall_ns < due:
                return None
            self.phase, self.starts_at_ns = "climbing", None
            self._fit_before = tun.fit
            rise = self.rise(pv, tun)  # too late already by the model: said at once
            need = rise.need_s(pv, self.target - BAND, heating=False)
            if need is not None:
                self._judge_late(wall_ns, need, rise)
        if self._start_pv is None:
            self._start_pv = pv
        fit = tun.fit
        if self._fit is None and fit is not None and fit is not self._fit_before:
            self._fit = fit if fit.refused is None else None
        if self._fit is not None:  # a later one (after a pause) starts from a cooling water
            tun = dataclasses.replace(tun, fit=self._fit)
        if self.phase == "climbing":
            self._hold_back(wall_ns, pv, tun)
        if self.phase != "released":
            self._measure(t, pv, applied, full, tun)
            rise = self.rise(pv, tun)
            heating = self._run_since is not None and t - self._run_since >= rise.dead_time
            need = rise.need_s(pv, self.target - BAND, heating)
            if self._due(wall_ns, pv, need, rise):
                self._release(pv, rise, need, wall_ns)
            elif rise.basis == HELD or (rise.basis == CLIMBED and need is not None):
                self._judge_late(wall_ns, need, rise)  # "never" by the climb: too far a guess
        else:
            self._approaching(t, wall_ns, pv, full, tun)
        return self._setpoint()

    def _approaching(self, t: float, wall_ns: int, pv: float, full: bool, tun: Tun) -> None:
        """After the release: when the water reaches the band, judged again each period
        from what is under way (the module's text), until it does."""
        edge = self.target - BAND
        if pv >= edge:
            self.late_until_ns = self.late = None
            return
        recent = self._approach
        recent.append((t, pv))
        while t - recent[0][0] > MIN_SPAN_S:
            recent.popleft()
        # The full-power run under way (`_measure`'s until the release, which goes on with it).
        self._run_since = (t if self._run_since is None else self._run_since) if full else None
        self._full_until = t if full else self._full_until
        rise = self.rise(pv, tun)
        dead = rise.dead_time
        ahead = pv if tun.ahead is None else tun.ahead
        line = _line(list(recent))
        slope = 0.0 if line is None else line[1]
        rising = (edge - pv) / slope if slope > 0.0 else None
        by = Rise(pv, slope, 0.0, 0.0, RISING)
        again = rise.need_s(pv, edge, heating=False)  # heated again from here: the longest
        if rising is not None and again is not None and again < rising:
            rising, by = again, rise
        sent = None if self._full_until is None else self._full_until + dead - t
        if self._run_since is not None:
            on_s = t - self._run_since
            need = rise.need_s(pv, edge, heating=on_s >= dead)
            if need is not None and on_s < dead:
                need -= on_s
        elif ahead < edge or (rising is None and (sent is None or sent < 0.0)):
            need = rise.need_s(ahead if ahead < edge else pv, edge, heating=False)
        elif rising is not None and (sent is None or sent < 0.0 or rising < sent):
            need, rise = rising, by
        else:
            need, rise = sent, Rise(pv, rise.rate, rise.slope, dead, SENT)
        self._judge_late(wall_ns, need, rise)

    def _hold_back(self, wall_ns: int, pv: float, tun: Tun) -> None:
        """Once the controller measured the element's rate on this climb, stop it (heater
        off) while, at that rate, it started early (by MIN_STOP_S at least): only in its
        lower half, once, and not after a restart (the climb's start is not known then)."""
        fit = self._fit
        if fit is None:
            return  # not measured on this climb (yet)
        start = self._start_pv if self._start_pv is not None else pv
        low = pv <= start + 0.5 * (self.wait_at - start)
        if self._paused_once or not (self._paused or low):
            return
        lead = self.lead_s(pv, tun, fitted=True)
        due = self.ready_at_ns if lead is None else self.ready_at_ns - round(lead * 1e9)
        if wall_ns >= due:
            if self._paused:
                self._paused, self._paused_once, self.starts_at_ns = False, True, None
                self._events.append(("climb", f"climbing on from {pv:.2f} °C"))
            return
        if not self._paused and due - wall_ns < round(MIN_STOP_S * 1e9):
            return
        self.starts_at_ns = due
        if not self._paused:
            self._paused = True
            self._events.append(
                (
                    "climb",
                    f"climb stopped at {pv:.2f} °C, heater off until {self._clock_text(due)}: "
                    f"at the rate the element showed ({fit.rate * 60.0:.3f} °C/min at full "
                    "power) it started early",
                )
            )

    def _due(self, wall_ns: int, pv: float, need: float | None, rise: Rise) -> bool:
        """Whether the approach must start now: on the last stretch under the waiting
        temperature or above it (below, full power runs anyway, and an early estimate
        rests on a rate far from the top), when the time it needs is all that is left. A
        rise that never gets there: at once when the losses at the top were measured, else
        (the water still climbs at full power) when the time asked for has come."""
        if need is None:
            return rise.basis == HELD or wall_ns >= self.ready_at_ns
        near = pv >= self.wait_at - WAIT_BELOW
        return near and wall_ns + round(need * 1e9) >= self.ready_at_ns

    def _setpoint(self) -> float | None:
        if self.phase == "scheduled" or self._paused:
            return None
        return self.target if self.phase == "released" else self.wait_at

    def _measure(self, t: float, pv: float, applied: float, full: bool, tun: Tun) -> None:
        """The full-power run's PV (past a dead time and more from its start, where the rise
        is the element's) and, at the waiting temperature, the PV and the duty that hold it."""
        if full:
            recent = self._full
            recent.append((t, pv))
            while t - recent[0][0] > WATER_SPAN_S:
                recent.popleft()
            if self._run_since is None or water_came((x for _, x in recent), pv, tun.noise):
                # Water poured in: the rise from here is a recovery's, and a line across the
                # fall is no rate (a 10 L top-up mid-climb read as "cannot reach" seven times).
                self._run_since = t
                self._run.clear()
                recent.clear()
                recent.append((t, pv))
            if t - self._run_since >= max(2.0 * tun.dead_time(), RISE_FROM_S):
                self._run.append((t, pv))
                while t - self._run[0][0] > MEASURE_S:
                    self._run.popleft()
                self._climb = _line(list(self._run)) or self._climb
        else:
            self._run_since = None
            self._full.clear()
        if self._arrived is not None and self._water_came(t, pv, tun.noise):
            self._arrived = None  # what holds the water now is a recovery, not the losses
            self._hold.clear()
            self._held.clear()
        if self._arrived is None and pv >= self.wait_at - BAND:
            self._arrived = t
            self.phase = "waiting"
        if self._arrived is not None and t - self._arrived >= SETTLE_S:
            self._hold.append((t, pv, applied))
            while t - self._hold[0][0] > MEASURE_S:
                self._hold.popleft()

    def _water_came(self, t: float, pv: float, noise: float) -> bool:
        """Whether the waiting water fell `noise` × WATER_FALL below its highest PV of the last
        WATER_SPAN_S: water poured in (the HLT topped up), and the hold is measured anew
        once the water is back at the waiting temperature and settled, as the learner's is."""
        held = self._held
        held.append((t, pv))
        while t - held[0][0] > WATER_SPAN_S:
            held.popleft()
        return water_came((x for _, x in held), pv, noise)

    def rise(self, pv: float, tun: Tun) -> Rise:
        """The full-power rise near the top, from the best measurement there is: the waiting
        temperature's losses, else the climb's rate, else the model (at `pv`)."""
        gross, dead = tun.gross_rate(), tun.dead_time()
        start = self._start_pv if self._start_pv is not None else pv
        room = min(tun.model.ambient, start)  # where the losses start from, at the highest
        climb = self._climb
        held = _line([(t, x) for t, x, _ in self._hold])
        if held is not None and self._hold[-1][0] - self._hold[0][0] >= MEASURE_S - 1.0:
            at, stored = held
            duty = statistics.fmean(u for _, _, u in self._hold)
            loss = gross * duty / tun.max_output - stored  # °C/s the tun loses at `at`
            if climb is not None and at - climb[0] >= 1.0:  # how fast it grows: a secant
                slope = (loss - (gross - climb[1])) / (at - climb[0])
            else:  # a loss that grows from the room's temperature (a restart: no climb)
                slope = loss / max(1.0, at - room)
            return Rise(at, gross - loss, max(0.0, slope), dead, HELD)
        if climb is not None and climb[0] - start >= CLIMB_SHARE * (self.wait_at - start):
            at, rate = climb
            slope = max(0.0, gross - rate) / max(1.0, at - room)
            return Rise(at, rate, slope, dead, CLIMBED)
        slope = 1.0 / tun.model.tau
        rate = gross - slope * (pv - room)
        return Rise(pv, rate, slope, dead, MODEL)

    def _release(self, pv: float, rise: Rise, need: float | None, wall_ns: int) -> None:
        self.phase = "released"
        at = None if need is None else wall_ns + round(need * 1e9)
        rate = rise.rate - rise.slope * (pv - rise.pv)
        self._events.append(
            (
                "release",
                f"full power for {self.target:g} °C from {pv:.2f} °C: a rise of "
                f"{rate * 60.0:.3f} °C/min here, {rise.slope * 60.0:.4f} °C/min slower per "
                f"°C higher, {rise.dead_time:.0f} s dead time ({rise.basis}); expected "
                + ("never" if at is None else self._clock_text(at)),
            )
        )
        self._judge_late(wall_ns, need, rise)

    def _judge_late(self, wall_ns: int, need: float | None, rise: Rise) -> None:
        """Say when the step cannot be reached by the time asked for, and again whenever
        the estimate slips RESAY_S further (one below the top is a guess that may); keep the
        latest estimate meanwhile."""
        goal = f"cannot reach {self.target:g} °C by {self._clock_text(self.ready_at_ns)}"
        if need is None:
            self.late_until_ns, until = None, NEVER
            why = f"{goal}: full power holds about {rise.ceiling():.1f} °C at most ({rise.basis})"
        else:
            until = wall_ns + round(need * 1e9)
            if until <= self.ready_at_ns + round(LATE_S * 1e9):
                self.late_until_ns = self.late = None
                return
            self.late_until_ns = until
            about = "" if rise.basis == HELD else "about "
            why = f"{goal}: needs until {about}{self._clock_text(until)} ({rise.basis})"
        self.late = why
        said = self._said_until
        if said is None or (said != NEVER and until >= said + round(RESAY_S * 1e9)):
            self._said_until = until
            self._events.append(("late", why))
