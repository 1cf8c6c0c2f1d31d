"""The predictive controller's watches of its own climb: the heat-up's fit (the tun's rate
and dead time, measured at full power) and a recovery's, after water was added."""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

from hermsd.control.pid import (
    BEND_TOLERANCE,
    FIT_FROM,
    FIT_SPAN,
    MAX_DEAD_TIME,
    MOVE_FROM,
    RATE_BAND,
    RECOVERY_FIT_PERIODS,
    RECOVERY_FIT_SPAN,
    SENSOR_LSB,
)


@dataclass(frozen=True, slots=True)
class HeatUpFit:
    """What one full-power heat-up showed: the rate (°C/s at 100 %) and the dead time (s),
    or why it was refused."""

    rate: float
    dead_time: float
    refused: str | None = None
    span: float = 0.0  # s from the step to full power until the fit: the data it rests on


class LineFit:
    """Least squares of a line through (t, x) points, kept as running sums."""

    __slots__ = ("n", "st", "stt", "stx", "sx", "sxx")

    def __init__(self) -> None:
        self.n = 0
        self.st = self.sx = self.stt = self.stx = self.sxx = 0.0

    def add(self, t: float, x: float) -> None:
        self.n += 1
        self.st += t
        self.sx += x
        self.stt += t * t
        self.stx += t * x
        self.sxx += x * x

    def slope(self) -> float | None:
        """dx/dt, or None on fewer than 4 points (too few to tell noise from slope)."""
        spread = self.n * self.stt - self.st * self.st
        if self.n < 4 or spread <= 0.0:
            return None
        return (self.n * self.stx - self.st * self.sx) / spread

    def slope_sd(self, least_sd: float) -> float | None:
        """The slope's standard error from the points' scatter about the line, each point's
        sd taken as at least `least_sd` (a few points of a staircase may lie on a line), or
        None where there is no slope."""
        slope = self.slope()
        if slope is None:
            return None
        n = self.n
        spread_t = self.stt - self.st * self.st / n
        scatter = max(0.0, self.sxx - self.sx * self.sx / n - slope * slope * spread_t)
        return math.sqrt(max(scatter / (n - 2), least_sd * least_sd) / spread_t)


class _RampWatch:
    """A line fit over one full-power run, armed when the run starts."""

    __slots__ = ("_line", "_n", "active")

    def __init__(self) -> None:
        self.active = False
        self._n = 0
        self._line = LineFit()

    def _start(self) -> None:
        self.active = True
        self._n = 0
        self._line = LineFit()


LSB_SD = SENSOR_LSB / math.sqrt(12.0)
"""°C: the sd of rounding to an LSB, the least scatter a period's PV is taken to have."""
QUARTER_PERIODS = 6
"""Periods a quarter of a heat-up's rise holds at least before its slope is compared: on
four, rounding alone moved a lag's bend to look straight (a 1.2× bend read as 1.04)."""


class _Rise:
    """The (t, rise) points of one ramp as running sums, so that a line over any stretch of
    them costs the same however long the ramp has run."""

    __slots__ = ("_sums", "_times")

    def __init__(self) -> None:
        self._times: list[float] = []
        self._sums: list[tuple[float, ...]] = [(0.0,) * 5]

    def add(self, t: float, rise: float) -> None:
        st, sx, stt, stx, sxx = self._sums[-1]
        self._times.append(t)
        self._sums.append((st + t, sx + rise, stt + t * t, stx + t * rise, sxx + rise * rise))

    def line(self, after: float, until: float) -> LineFit:
        """The line over the points with after < t ≤ until."""
        first = bisect.bisect_right(self._times, after)
        last = bisect.bisect_right(self._times, until)
        line = LineFit()
        line.n = last - first
        sums = [b - a for a, b in zip(self._sums[first], self._sums[last], strict=True)]
        line.st, line.sx, line.stt, line.stx, line.sxx = sums
        return line


class _HeatUpWatch(_RampWatch):
    """Measures the rate and the dead time on a full-power step from a steady PV.

    Behind a delay D and a sensor lag τs the PV's rise bends into a ramp only a few τs after
    it starts to move; a line inside the bend reads the rate low and the dead time short,
    and limits tightened on such a rate call a normal heat-up a shorted SSR. So the rise is
    kept from where it moves (MOVE_FROM on), and the fit is taken on its later half once that
    half has risen FIT_SPAN °C and its two quarters rise at one slope (within
    BEND_TOLERANCE): for a first-order lag the later half then reads the rate within 6 %
    (docs/heat-up-fit.md). Its slope is the rate; where it crosses pv0 is the dead time,
    D + τs, which is what a predictor wants for a ramp. A step that ends before is `ended`.
    """

    __slots__ = ("_bent", "_du", "_moved_at", "_pv0", "_rise", "_top", "least")

    def __init__(self) -> None:
        super().__init__()
        self._pv0 = self._du = self._top = 0.0
        self._bent = False  # the last look found the later half still bending
        self._moved_at: float | None = None
        self._rise = _Rise()
        # (rate, dead time) the ramp so far shows at least, before any fit (`_least`).
        self.least: tuple[float, float] | None = None

    def arm(self, pv0: float, step: float) -> None:
        self._start()
        self._pv0, self._du, self._top = pv0, step, 0.0
        self._bent = False
        self._moved_at = None
        self._rise = _Rise()
        self.least = None

    def add(self, pv: float, ts: float, loss: float, model_rate: float) -> HeatUpFit | None:
        """One more full-power period; the fit once the ramp is straight."""
        self._n += 1
        rise = pv - self._pv0
        t = (self._n - 0.5) * ts  # the PV is the mean over the period just ended
        if self._moved_at is None:
            if rise < MOVE_FROM:
                return None
            self._moved_at = t
        self._rise.add(t, rise)
        self._top = max(self._top, rise)
        ramp = self._rise
        half = 0.5 * (t - self._moved_at)
        later = ramp.line(t - half, t)
        self.least = self._least(later)
        third, fourth = ramp.line(t - half, t - 0.5 * half), ramp.line(t - 0.5 * half, t)
        slope, third_slope, fourth_slope = later.slope(), third.slope(), fourth.slope()
        sds = (third.slope_sd(LSB_SD), fourth.slope_sd(LSB_SD))
        if min(third.n, fourth.n) < QUARTER_PERIODS:
            return None  # too few periods in a quarter yet
        if slope is None or third_slope is None or fourth_slope is None or None in sds:
            return None
        if slope <= 0.0 or third_slope <= 0.0:
            return None
        if slope * half < FIT_SPAN or math.hypot(*(sd or 0.0 for sd in sds)) > (
            0.5 * BEND_TOLERANCE * third_slope
        ):
            return None  # too little rise yet to tell a bend from the noise
        self._bent = fourth_slope > (1.0 + BEND_TOLERANCE) * third_slope
        if self._bent:
            return None
        self.active = False
        # Straight from where it moved (no lag to speak of): the whole rise, lower down the
        # ramp, where a loss the model has wrong bends it less.
        earlier = ramp.line(self._moved_at - ts, t - half).slope()
        if earlier is not None and earlier * (1.0 + BEND_TOLERANCE) >= slope:
            later = ramp.line(self._moved_at - ts, t)
            slope = later.slope() or slope
        return self._fit(later, slope, loss, model_rate, self._n * ts)

    def _least(self, later: LineFit) -> tuple[float, float] | None:
        """What the later half's line proves of the tun however it bends: its slope less two
        standard errors (°C/s at 100 %) and where it crosses pv0 less two of that (s). In a
        lag's bend both climb towards the rate and D + τs from below (docs/heat-up-fit.md)."""
        slope, sd = later.slope(), later.slope_sd(LSB_SD)
        if slope is None or sd is None or later.n < 2 * QUARTER_PERIODS or slope <= 2.0 * sd:
            return None
        n = later.n
        mean_t, mean_rise = later.st / n, later.sx / n
        crossing = mean_t - mean_rise / slope
        scatter = max(
            later.sxx / n
            - mean_rise * mean_rise
            - slope * slope * (later.stt / n - mean_t * mean_t),
            LSB_SD * LSB_SD,
        )
        crossing_sd = math.hypot(math.sqrt(scatter / n) / slope, (mean_t - crossing) * sd / slope)
        return (slope - 2.0 * sd) * 100.0 / self._du, crossing - 2.0 * crossing_sd

    def ended(self, ts: float, model_rate: float) -> HeatUpFit | None:
        """Full power ended before a fit: why no rate was taken where the ramp had risen far
        enough and was still bending (else None: too short a step to judge)."""
        was = self.active
        self.active = False
        if not (was and self._bent):
            return None
        why = (
            f"the PV still bent after {self._top:.1f} °C of rise at full power "
            "(a slow sensor on a fast tun): its rate was not measured"
        )
        return HeatUpFit(model_rate, 0.0, why, self._n * ts)

    def _fit(
        self, line: LineFit, slope: float, loss: float, model_rate: float, span: float
    ) -> HeatUpFit:
        mid_rise = line.sx / line.n
        climb = slope + loss * mid_rise  # °C/s the step adds, before the loss takes its share
        # The loss bends the ramp down as it rises: its tangent at mid_rise crosses pv0
        # loss·mid_rise²/(2·slope·climb) early (docs/heat-up-fit.md).
        bent = loss * mid_rise * mid_rise / (2.0 * slope * climb)
        crossing = (line.st - line.sx / slope) / line.n + bent  # mean t − mean rise / slope
        rate = climb * 100.0 / self._du
        if not RATE_BAND[0] * model_rate <= rate <= RATE_BAND[1] * model_rate:
            why = f"rate {rate:.3g} °C/s is not within ¼–4× the model's {model_rate:.3g}"
            return HeatUpFit(rate, crossing, why, span)
        if not 0.0 <= crossing <= MAX_DEAD_TIME:
            why = f"dead time {crossing:.0f} s is not within 0–{MAX_DEAD_TIME:g} s"
            return HeatUpFit(rate, crossing, why, span)
        return HeatUpFit(rate, crossing, None, span)


class _RecoveryWatch(_RampWatch):
    """Re-measures the rate on a full-power run that did not start from a steady PV (cold
    water in the hold): added water lowers the rate in proportion to the heat capacity, and
    a predictor that keeps the old rate leaves full power too early and creeps up the rest.

    The PV's rise above its lowest point in the run is fitted by a line between FIT_FROM and
    FIT_FROM + RECOVERY_FIT_SPAN °C of rise (past the dip's bend, and early enough that full
    power still runs when the new rate is taken), and where that span holds fewer than the
    periods asked (`RECOVERY_FIT_PERIODS`, a fast tun), refitted over each later full-power
    period too, up to those or the cut. Relative to the hold at the setpoint sp
    with duty u_h, dx/dt = rate·(100 − u_h)/100 − loss·(x − sp): a fill other than the
    model's scales rate and heat flows alike, so u_h, which the bias made exact in the hold,
    stays, and the model's ambient (a guess) does not enter. The dead time is not measured:
    the dip hides where the ramp starts.
    """

    __slots__ = ("_hold", "_low")

    def __init__(self) -> None:
        super().__init__()
        self._hold = self._low = 0.0

    def arm(self, pv: float, hold: float) -> None:
        self._start()
        self._hold, self._low = hold, pv

    def add(self, pv: float, ts: float, sp: float, loss: float) -> tuple[float, float] | None:
        """One more full-power period; once the PV has risen FIT_FROM + RECOVERY_FIT_SPAN °C
        from its lowest, the rate (°C/s at 100 %) and the line's PV a period ago (where the
        estimate stands before this period's step), or None. While the line holds fewer than
        RECOVERY_FIT_PERIODS points, each further full-power period adds its PV and gives the
        line anew."""
        self._n += 1
        line = self._line
        if line.n == 0 and pv < self._low + FIT_FROM:
            self._low = min(self._low, pv)
            return None
        past = pv > self._low + FIT_FROM + RECOVERY_FIT_SPAN
        if not past or line.n < RECOVERY_FIT_PERIODS:
            line.add((self._n - 0.5) * ts, pv)
        if not past:
            return None
        self.active = line.n < RECOVERY_FIT_PERIODS
        slope = line.slope()
        if slope is None or slope <= 0.0:
            return None
        mean = line.sx / line.n
        before = mean + slope * ((self._n - 1.5) * ts - line.st / line.n)
        return (slope + loss * (mean - sp)) * 100.0 / (100.0 - self._hold), before
