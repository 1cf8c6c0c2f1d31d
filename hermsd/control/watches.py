"""The predictive controller's watches of its own climb: the heat-up's fit (the tun's rate
and dead time, measured at full power) and a recovery's, after water was added."""

from __future__ import annotations

from dataclasses import dataclass

from hermsd.control.pid import (
    FIT_FROM,
    FIT_TO,
    MAX_DEAD_TIME,
    RATE_BAND,
    RECOVERY_FIT_PERIODS,
    RECOVERY_FIT_SPAN,
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

    __slots__ = ("n", "st", "stt", "stx", "sx")

    def __init__(self) -> None:
        self.n = 0
        self.st = self.sx = self.stt = self.stx = 0.0

    def add(self, t: float, x: float) -> None:
        self.n += 1
        self.st += t
        self.sx += x
        self.stt += t * t
        self.stx += t * x

    def slope(self) -> float | None:
        """dx/dt, or None on fewer than 4 points (too few to tell noise from slope)."""
        spread = self.n * self.stt - self.st * self.st
        if self.n < 4 or spread <= 0.0:
            return None
        return (self.n * self.stx - self.st * self.sx) / spread


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


class _HeatUpWatch(_RampWatch):
    """Measures the rate and the dead time on a full-power step from a steady PV.

    The PV's rise above pv0 is fitted by a line between FIT_FROM and FIT_TO °C of rise (least
    squares over the periods there): its slope is the rate, and where it crosses pv0 is the
    dead time (for a delay D plus a sensor lag τs the ramp's asymptote crosses at D + τs,
    which is the dead time a predictor wants for a ramp).
    """

    __slots__ = ("_du", "_pv0")

    def __init__(self) -> None:
        super().__init__()
        self._pv0 = self._du = 0.0

    def arm(self, pv0: float, step: float) -> None:
        self._start()
        self._pv0, self._du = pv0, step

    def add(self, pv: float, ts: float, loss: float, model_rate: float) -> HeatUpFit | None:
        """One more full-power period; the fit once the PV has risen FIT_TO °C."""
        self._n += 1
        rise = pv - self._pv0
        if rise < FIT_FROM:
            return None
        line = self._line
        if rise <= FIT_TO:
            line.add((self._n - 0.5) * ts, rise)  # the PV is the mean over the period just ended
            return None
        self.active = False
        span = self._n * ts
        slope = line.slope()
        if slope is None:
            why = f"too few periods ({line.n}) between the rises"
            return HeatUpFit(model_rate, 0.0, why, span)
        if slope <= 0.0:
            return HeatUpFit(model_rate, 0.0, "the PV did not rise", span)
        crossing = (line.st - line.sx / slope) / line.n  # mean t − mean rise / slope
        mid_rise = line.sx / line.n
        rate = (slope + loss * mid_rise) * 100.0 / self._du
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
