"""Where full power levels the water out, and a warning when that is short of the setpoint.

At full power the water rises at a rate that falls as the losses grow with its temperature.
Taken as falling linearly, dx/dt = rate − slope·(x − x0), the rise stops at x0 + rate/slope:
the tun's ceiling. The line is exact for a lidded tun (its losses are linear in the
temperature); an open pot's evaporation grows faster higher up, so a line through two rates
measured lower down falls too slowly there and puts the ceiling too high. That errs on the
safe side for the warning below: late, never false. A `ready_by` heat-up times its last
approach with the same line (hermsd.program.readiness).

`ReachWatch` says, during a full-power heat-up, when full power surely cannot bring the water
to the setpoint (nothing is switched off: the element works; the tun is too weak for the
water in it). It measures the rise rate at full power over blocks of MEASURE_S and draws the
line through the rates of the upper half of the climb, all measured on this tun that day:
the config's model knows nothing of an open pot's evaporation or of today's fill. Per
control period it adds one point to a running line fit (O(1), under a microsecond); once a
block (10 min) it fits the line through the block rates it keeps (60 after a 12 h climb:
some 20 µs on a desktop core).
"""

from __future__ import annotations

import math
import statistics
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import NamedTuple

from hermsd.control.pid import SENSOR_LSB
from hermsd.control.watches import LineFit
from hermsd.metrics import BAND

SLACK = 0.5
"""%-points under an element's full-power duty that a period's applied duty may lie and still
count as full: a window's on-time is whole mains half-cycles (0.2 % of a 5 s window), the
remainder carried to the next window."""
MEASURE_S = 600.0
"""The span of PV that a rate (and a `ready_by` wait's holding duty) is measured over: with
sensor noise of 0.03 °C on the LM92's 0.0625 °C steps (a period's mean of 5 readings: about
0.02 °C) a line over 120 periods has a slope error near 1e-5 °C/s, a hundredth of a weak
tun's rise at half-way."""
RISE_FROM_S = 300.0
"""A full-power run's PV counts from twice the dead time after its start, and no earlier than
this: before, it still shows what the water did before full power (a heat-up from rest bends
up over about a dead time, the sensor's lag and the well's)."""

MARGIN_C = 1.0
"""°C under the setpoint the ceiling must be to be said. On lidded tuns, where the line is
exact and only the noise moves it, single estimates past half-way stray by up to 0.9 °C from
the truth (bench/reach.py's near misses: 65.93 °C at least for a ceiling of 66.5 °C); and a
ceiling within a degree of the setpoint depends on what a day changes (a draught, the lid
lifted, the room), nothing for the brewer to act on before the water shows it."""
SURE_BLOCKS = 3
"""Estimates in a row, each that far short, before it is said: one block can be moved by a
disturbance that the noise does not account for (a stir, the lid lifted for a look, a sensor
knocked); three span half an hour of full power that all say the same."""
HALF_WAY = 0.5
"""The share of the way from the run's start to the setpoint (or to the ceiling, if lower)
that the water must have risen before an estimate counts: lower, the rates lie far below the
ceiling and the line through them is extrapolated further than it was measured (a rate's
error then weighs r0/(r0 − r) times more, r0 the rate at the oldest point)."""
ANCHOR_SHARE = 0.5
"""The rates the line is drawn through: those measured from this share of the way from the
run's start to the newest one. As far back as possible for a small error (on the bench's
lidded tuns whose ceiling lies 0.5 to 2 °C above the setpoint, the lowest estimate stays
0.6 to 0.8 °C under the truth; a line through two rates only came within 0.06 °C of the
setpoint − MARGIN_C), as near as possible so that an open pot's steepening losses bend the
line little (it puts their ceiling too high, by some 0.1 × the distance still to go)."""

DROP_C = 4 * SENSOR_LSB
"""°C (4 LSB) below the run's highest PV that ends it: at full power the water only rises
(a period's mean of five readings never falls that far by noise), so such a fall is cold
water or an element that fails, after which the rates measured before are of another tun."""

MAX_POINTS = 144
"""Blocks a run keeps at most: a day's (the lowest go first, the line is drawn higher up)."""

PREFIX = "full power levels the water out"
"""How every event of the warning begins (replay finds them by it)."""


@dataclass(frozen=True, slots=True)
class FullPower:
    """The duties that are full power on a tun: what its controller gives each element when
    it asks for the most it may. `duty1`: the SSR's element, % (control.max_output; less where
    that limits both elements' total, hermsd.control.element2.PowerSplit). `on2`: the second element
    on (or, never switched on under the limit, off) through the whole period; None: none
    fitted. The second element is switched in whole periods (its contactor's minimum times):
    a period it spends off, its min_off say, while the SSR's element is at its limit is the
    SSR's power alone, not full power, and a rise measured in it is of another tun."""

    duty1: float
    on2: bool | None = None

    def reached(self, applied: float, switched2: float | None) -> bool:
        """Whether a period ran at full power: the SSR's element at `applied` % and the second
        element switched on for `switched2` % of it (None: none fitted)."""
        if applied < self.duty1 - SLACK:
            return False
        if self.on2 is None:
            return True
        if switched2 is None:
            return False
        return switched2 >= 100.0 - SLACK if self.on2 else switched2 <= SLACK


def rise_s(x0: float, x1: float, rate: float, slope: float) -> float | None:
    """Seconds of full power from `x0` to `x1` °C when the rise rate is `rate` °C/s at x0 and
    falls by `slope` (1/s) per °C above it, dx/dt = rate − slope·(x − x0):
    t = ln(rate / (rate − slope·(x1 − x0))) / slope. None: the rise stops short of x1, or
    does not start (a rate measured at or below zero: the loop must not divide by it)."""
    if x1 <= x0:
        return 0.0
    if rate <= 0.0:
        return None
    end = rate - slope * (x1 - x0)
    if end <= 0.0:
        return None
    if slope <= 0.0:
        return (x1 - x0) / rate
    return math.log(rate / end) / slope


@dataclass(frozen=True, slots=True)
class Rise:
    """The full-power rise near the top, as best known: `rate` °C/s at `pv`, `slope` 1/s less
    per °C higher, `dead_time` s before a new full power shows, and what it rests on."""

    pv: float
    rate: float
    slope: float
    dead_time: float
    basis: str

    def need_s(self, pv: float, to: float, heating: bool) -> float | None:
        """From `pv` to `to` at full power (`heating`: it runs already, no dead time)."""
        rise = rise_s(pv, to, self.rate - self.slope * (pv - self.pv), self.slope)
        return None if rise is None else rise + (0.0 if heating else self.dead_time)

    def ceiling(self) -> float:
        """Where full power would hold the water (°C), by this line."""
        return math.inf if self.slope <= 0.0 else self.pv + self.rate / self.slope


MEASURED = "the rise rates measured at full power"


def measured_rise(points: Sequence[tuple[float, float]]) -> Rise:
    """The rise at the newest of (°C, °C/s) points measured on one full-power run: its rate,
    and how fast the rate falls with the temperature by least squares through all of them
    (a rate that does not fall: slope 0, no ceiling)."""
    x, rate = points[-1]
    temperatures = [p[0] for p in points]
    if min(temperatures) == max(temperatures):  # one point, or all at one PV: no slope to tell
        return Rise(x, rate, 0.0, 0.0, MEASURED)
    falls = statistics.linear_regression(temperatures, [p[1] for p in points]).slope
    return Rise(x, rate, max(0.0, -falls), 0.0, MEASURED)


def short_words(ceiling: float, setpoint: float, max_output: float = 100.0) -> str:
    """The warning, in the brewer's words (`max_output`: the power limit full power is)."""
    if max_output < 100.0:
        return (
            f"{PREFIX} near {ceiling:.1f} °C at the power limit of {max_output:g} % "
            f"(control.max_output), {setpoint - ceiling:.1f} °C short of the setpoint "
            f"{setpoint:g} °C: raise the limit, put the lid on, or heat less water"
        )
    return (
        f"{PREFIX} near {ceiling:.1f} °C, {setpoint - ceiling:.1f} °C short of the setpoint "
        f"{setpoint:g} °C: put the lid on, heat less water, or add power"
    )


class Said(NamedTuple):
    """An event of the warning: raised (True) or cleared, and its words."""

    raised: bool
    message: str


class ReachWatch:
    """Says when full power surely levels the water out below the setpoint; non-latching.

    Fed once a control period. A run is the periods in a row at full power in auto with
    nothing held; its rates are measured over blocks of MEASURE_S past RISE_FROM_S (and two
    dead times) from its start. Raised once SURE_BLOCKS estimates in a row, each past
    HALF_WAY, put the ceiling MARGIN_C under the setpoint; cleared when the setpoint no longer
    is (changed to one the ceiling is not that far under) or the water reaches the band.
    `ceiling` is the level it names meanwhile (the latest such estimate), else None.

    The same watch serves the mash of a HERMS, whose "full power" is the HLT held at its
    most (`hermsd.runtime.mash_control`): `prefix`, `what` and `words` name the vessel and
    say what the brewer can do (default: the HLT's own, `short_words`).
    """

    def __init__(
        self,
        prefix: str = PREFIX,
        what: str = "the water",
        words: Callable[[float, float, float], str] = short_words,
    ) -> None:
        self.ceiling: float | None = None
        self._prefix, self._what, self._words = prefix, what, words
        self._paused = False  # the run stands still (`period`'s `paused`) until full again
        self._run_since: float | None = None
        self._start_pv = self._top_pv = 0.0
        self._block = LineFit()
        self._block_t0 = 0.0
        # (mean PV, rate) of the run's blocks, a day's at most (a run stalled at its ceiling)
        self._points: deque[tuple[float, float]] = deque(maxlen=MAX_POINTS)
        self._sure = 0

    def period(
        self,
        t: float,
        setpoint: float,
        pv: float | None,
        full: bool,
        dead_time: float,
        full_at: float = 100.0,
        *,
        paused: bool = False,
    ) -> Said | None:
        """One period: `full` — the elements ran at full power (`FullPower`; `full_at`, what
        full power is: the limit control.max_output, %, for the water; the HLT's most, °C,
        for a mash) through the period just ended, in auto, nothing held. What to say,
        if anything. `paused` (with `full` False): a break the run goes on after (a pump
        timer's stop): the block under way is dropped, the blocks before kept, and the rise
        counted again from RISE_FROM_S after full power returns."""
        said = self._cleared(setpoint, pv)
        if not full or pv is None:
            if paused and self._run_since is not None:
                self._paused, self._block = True, LineFit()
            else:
                self._end_run()
            return said
        if self._paused:
            self._paused, self._run_since, self._top_pv = False, t, pv
        if self._run_since is not None and pv < self._top_pv - DROP_C:
            self._end_run()  # cold water (or a dying element): not the same rise any more
        if self._run_since is None:
            self._run_since, self._start_pv, self._top_pv = t, pv, pv
        self._top_pv = max(self._top_pv, pv)
        if t - self._run_since < max(2.0 * dead_time, RISE_FROM_S):
            return said
        block = self._block
        if block.n and t - self._block_t0 >= MEASURE_S:
            rate = block.slope()
            if rate is not None:
                said = self._judge((block.sx / block.n, rate), setpoint, full_at) or said
            self._block = block = LineFit()
        if not block.n:
            self._block_t0 = t
        block.add(t - self._block_t0, pv)
        return said

    def restart(self, why: str = "full power changed") -> Said | None:
        """Full power changed (a reload of control.max_output, a second element; for the
        mash, a new rest and with it the HLT's most): measured afresh, and what was said of
        the old one cleared."""
        self._end_run()
        if self.ceiling is None:
            return None
        self.ceiling = None
        return Said(False, f"{self._prefix} elsewhere now: {why}, measured afresh")

    def _end_run(self) -> None:
        self._run_since, self._paused = None, False
        self._block = LineFit()
        self._points.clear()
        self._sure = 0

    def _cleared(self, setpoint: float, pv: float | None) -> Said | None:
        ceiling = self.ceiling
        if ceiling is None:
            return None
        if ceiling >= setpoint - MARGIN_C:
            self.ceiling = None
            return Said(False, f"{self._prefix} near {ceiling:.1f} °C, enough for {setpoint:g} °C")
        if pv is not None and pv >= setpoint - BAND:
            self.ceiling = None
            return Said(False, f"{self._prefix} higher than said: {self._what} reached the band")
        return None

    def _judge(self, point: tuple[float, float], setpoint: float, full_at: float) -> Said | None:
        """A block's (mean PV, rate) in: the ceiling through it and those from ANCHOR_SHARE of
        the climb up, judged."""
        points = self._points
        x, start = point[0], self._start_pv
        if x <= start:
            self._sure = 0  # no rise yet (a run begun where the water levels out): no line
            return None
        points.append(point)
        while points[0][0] < start + ANCHOR_SHARE * (x - start):
            points.popleft()  # below the share for this one, and for any higher one after it
        ceiling = measured_rise(points).ceiling()
        half_way = start + HALF_WAY * (min(setpoint, ceiling) - start)
        if x < half_way or ceiling >= setpoint - MARGIN_C:
            self._sure = 0
            return None
        self._sure += 1
        if self._sure < SURE_BLOCKS:
            return None
        raised = self.ceiling is None
        self.ceiling = ceiling
        return Said(True, self._words(ceiling, setpoint, full_at)) if raised else None
