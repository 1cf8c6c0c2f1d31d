"""The predictive controller's watches of its own climb: the heat-up's fit (the tun's rate
and dead time, measured at full power) and a recovery's, after water was added, the part of
that water's drop the sensor has yet to show (`_PourGap`), and whether the recovery still
rises over the heat's way to the sensor (`_RecoveryStall`)."""

from __future__ import annotations

import bisect
import itertools
import math
from collections import deque
from dataclasses import dataclass

from hermsd.control.linsys import solve
from hermsd.control.pid import (
    BEND_TOLERANCE,
    BIAS_INNOVATION_CLIP,
    COLDEST_POUR,
    FILL_ROUNDS,
    FIT_FROM,
    FIT_SPAN,
    MAX_DEAD_TIME,
    MOVE_FROM,
    PULSE_ROOM_SPAN,
    PULSE_SETTLE_S,
    RATE_BAND,
    RECOVERY_FIT_PERIODS,
    RECOVERY_FIT_SPAN,
    ROOM_ROUNDS,
    SENSOR_LSB,
    STEADY_BAND,
)
from hermsd.safety.limits import DEAD_TIME_MAX, SENSOR_LAG_MAX


@dataclass(frozen=True, slots=True)
class HeatUpFit:
    """What one full-power heat-up showed: the rate (°C/s at 100 %) and the dead time (s),
    or why it was refused."""

    rate: float
    dead_time: float
    refused: str | None = None
    span: float = 0.0  # s from the step to full power until the fit: the data it rests on
    lag: float = 0.0  # s of the dead time that is the sensor's first-order lag (0: not told)


def checked(
    rate: float, dead_time: float, model_rate: float, span: float, lag: float = 0.0
) -> HeatUpFit:
    """A measured rate and dead time as a fit, refused (and why) where no tun the model may
    be has them: a wrong step, a dry or half-empty tun, another tun than the model's."""
    if not RATE_BAND[0] * model_rate <= rate <= RATE_BAND[1] * model_rate:
        why = f"rate {rate:.3g} °C/s is not within ¼–4× the model's {model_rate:.3g}"
        return HeatUpFit(rate, dead_time, why, span)
    if not 0.0 <= dead_time <= MAX_DEAD_TIME:
        why = f"dead time {dead_time:.0f} s is not within 0–{MAX_DEAD_TIME:g} s"
        return HeatUpFit(rate, dead_time, why, span)
    return HeatUpFit(rate, dead_time, None, span, min(lag, dead_time))


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

    def _line_slope(self) -> float | None:
        """The least-squares dx/dt, or None where every t is the same."""
        spread = self.n * self.stt - self.st * self.st
        return None if spread <= 0.0 else (self.n * self.stx - self.st * self.sx) / spread

    def slope(self) -> float | None:
        """dx/dt, or None on fewer than 4 points (too few to tell noise from slope)."""
        return self._line_slope() if self.n >= 4 else None

    def slope_sd(self, least_sd: float) -> float | None:
        """The slope's standard error from the points' scatter about the line, each point's
        sd taken as at least `least_sd` (a few points of a staircase may lie on a line), or
        None where there is no slope."""
        scatter = self.scatter() if self.slope() is not None else None
        if scatter is None:
            return None
        spread_t = self.stt - self.st * self.st / self.n
        return math.sqrt(max(scatter, least_sd * least_sd) / spread_t)

    def scatter(self) -> float | None:
        """The points' variance about their line (n − 2 degrees of freedom), or None on
        fewer than 3 points or a single t."""
        n = self.n
        slope = self._line_slope() if n >= 3 else None
        if slope is None:
            return None
        spread_t = self.stt - self.st * self.st / n
        return max(0.0, self.sxx - self.sx * self.sx / n - slope * slope * spread_t) / (n - 2)


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


HEAT_SHOWS_S = DEAD_TIME_MAX + SENSOR_LAG_MAX
"""s within which full power's heat shows at the sensor on any tun the limits allow for."""
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

    def integral(self, ts: float) -> float:
        """°C·s: the rise summed over its periods (each `ts` long)."""
        return self._sums[-1][1] * ts

    def since(self, after: float) -> tuple[list[float], list[float]]:
        """The times and rises of the points with t > after."""
        first = bisect.bisect_right(self._times, after)
        sums = self._sums
        rises = [sums[i + 1][1] - sums[i][1] for i in range(first, len(self._times))]
        return self._times[first:], rises

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
    kept from where it moves (MOVE_FROM on), and the fit is taken once the later half has
    risen FIT_SPAN °C and its two quarters rise at one slope (within BEND_TOLERANCE): the
    whole rise fitted to the lag's own curve (`through_lag`) gives the rate, the dead time
    D + τs (where the ramp's asymptote crosses pv0, what a predictor wants for a ramp) and
    τs (docs/heat-up-fit.md). A step that ends before is `ended`."""

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

    @property
    def moved(self) -> bool:
        """Whether the PV has begun to rise (MOVE_FROM)."""
        return self._moved_at is not None

    def reach(self, ts: float) -> tuple[float, float, float, _Rise]:
        """(pv0, the step's size in %, s it has run, its rise so far): what a pulse cut here
        starts from (`_PulseWatch`)."""
        return self._pv0, self._du, self._n * ts, self._rise

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
        assert self._moved_at is not None  # a fit comes only once the PV has moved
        lagged = through_lag(*self._rise.since(self._moved_at - 1e-9), loss)
        if lagged is not None:
            climb, crossing, lag = lagged
            return checked(climb * 100.0 / self._du, crossing, model_rate, span, lag)
        mid_rise = line.sx / line.n
        climb = slope + loss * mid_rise  # °C/s the step adds, before the loss takes its share
        # The loss bends the ramp down as it rises: its tangent at mid_rise crosses pv0
        # loss·mid_rise²/(2·slope·climb) early (docs/heat-up-fit.md).
        bent = loss * mid_rise * mid_rise / (2.0 * slope * climb)
        crossing = (line.st - line.sx / slope) / line.n + bent  # mean t − mean rise / slope
        return checked(climb * 100.0 / self._du, crossing, model_rate, span)


def loss_added_back(
    times: list[float],
    rises: list[float],
    loss: float,
    warm: float = 0.0,
    start: tuple[float, float] | None = None,
) -> list[float]:
    """The rise with what the losses took on the way added back, y = r + loss·∫(warm + r) dt
    (trapezoids): the heat's arrival at the sensor. From `start` (t, r), by default the
    first point; `warm` K above the room where the rise starts (0 from a steady start, where
    the duty held those losses)."""
    t_last, r_last = start if start is not None else (times[0], rises[0])
    lost = 0.0
    ys: list[float] = []
    for t, r in zip(times, rises, strict=True):
        lost += (t - t_last) * (warm + 0.5 * (r + r_last))
        ys.append(r + loss * lost)
        t_last, r_last = t, r
    return ys


def through_lag(
    times: list[float], rises: list[float], loss: float
) -> tuple[float, float, float] | None:
    """(the step's climb in °C/s, where its ramp's asymptote crosses the start in s, the lag
    in s) from a rise seen through a first-order sensor lag after a delay, or None where the
    points do not show a lag (fewer than 8, or a lag < 0 or a climb ≤ 0 fitted: noise on a
    straight ramp).

    The integral method: the rise y with the loss added back (y = r + loss·∫r, the loss
    taken on the water's rise above a steady start) obeys τ·y' + y = R·(t − D) exactly, so
    integrated twice over [t₀, t], with T = t − t₀,

        ∬y = R·T³/6 + R·(t₀ − D)·T²/2 − τ·∫y + τ·y₀·T

    linear in R, R·(t₀ − D), τ and τ·y₀, fitted by least squares over the whole rise, bend
    and all. Integrated once, τ multiplied y itself, whose noise (a sensor's, 0.02 °C a
    period) read the dead time a quarter short and the lag two fifths short on a bend of
    350 s; under two integrals the noise is averaged out (docs/heat-up-fit.md). Fitted in
    units of the rise's span, so that its powers stay near one. The asymptote crosses the
    start at D + τ."""
    n = len(times)
    if n < 8:
        return None
    t0 = times[0]
    span = times[-1] - t0
    rows: list[tuple[float, float, float, float, float]] = []
    targets: list[float] = []
    ys = loss_added_back(times, rises, loss)
    once = twice = 0.0  # ∫y and ∬y from t₀ (trapezoids, in units of the span)
    y_last = ys[0]
    for i, y in enumerate(ys):
        if i:
            step = (times[i] - times[i - 1]) / span
            before = once
            once += 0.5 * step * (y + y_last)
            twice += 0.5 * step * (once + before)
        y_last = y
        s = (times[i] - t0) / span
        rows.append((s * s * s / 6.0, 0.5 * s * s, -once, s, 1.0))
        targets.append(twice)
    normal = [[math.fsum(row[j] * row[k] for row in rows) for k in range(5)] for j in range(5)]
    rhs = [math.fsum(row[j] * x for row, x in zip(rows, targets, strict=True)) for j in range(5)]
    try:
        cubic, square, lag_share, *_ = (v.real for v in solve(normal, rhs))
    except ValueError:
        return None
    climb, lag = cubic / span, lag_share * span
    if climb <= 0.0 or lag < 0.0:
        return None
    return climb, t0 - square / climb + lag, lag


class _PulseWatch:
    """A measured pulse of full power: it ran (or will run) `on_s` from a steady `pv0` with
    nothing on before, then the heat stays off (or sends a `tail`, whose rise is taken off
    the PV) and the PV is followed until it settles.
    The heat delivered is then all at the sensor: the rise (the model's loss added back)
    over `on_s` is the rate, and the mean time of the rise's arrival, less `on_s`/2, the
    dead time (delay and lag alike: docs/heat-up-fit.md); the spread of that arrival, the
    lag (`arrival`). `elapsed`: s of it already run (a heat-up cut short), with `rise`
    its rise over them."""

    __slots__ = (
        "_du",
        "_last",
        "_least_rise",
        "_mark",
        "_marked_at",
        "_on",
        "_pv0",
        "_rise",
        "_t",
        "_tail",
        "_tail_climb",
        "_tail_end",
        "room",
    )

    def __init__(
        self,
        pv0: float,
        du: float,
        on_s: float,
        elapsed: float = 0.0,
        rise: _Rise | None = None,
        tail: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> None:
        self._pv0, self._du, self._on = pv0, du, on_s
        self._t = elapsed
        # (share of `du`, delay s, lag s): the heat sent after the on-time, until `stop`,
        # for the losses while the pulse's heat arrives, and what it arrives through. The
        # rise it adds by the model's rate is taken off the PV, so the pulse measures as
        # one with the heat off.
        self._tail, self._tail_end, self._tail_climb = tail, math.inf, 0.0
        self._rise = rise or _Rise()
        # °C the PV must have risen before it may count as settled (`expect`).
        self._least_rise = 0.0
        self._mark, self._marked_at = pv0, on_s
        self._last = -math.inf
        # °C: the room the settled PV's fall showed (None: not measured), once it settled.
        self.room: float | None = None

    def expect(self, rate: float) -> None:
        """The model's rate (°C/s at 100 %): the PV must have risen a quarter of what it
        says the pulse gives before it may count as settled."""
        self._least_rise = 0.25 * rate * self._du / 100.0 * self._on
        self._tail_climb = rate * self._du / 100.0 * self._tail[0]

    def duty(self, ts: float) -> float:
        """The share of the next period the pulse's heat is on (the tail's share counted)."""
        on = min(max((self._on - self._t) / ts, 0.0), 1.0)
        if self._t + ts <= self._on or self._t >= self._tail_end:
            return on
        return on + (1.0 - on) * self._tail[0]

    def stop(self) -> None:
        """The heat ends now, the tail's too (the setpoint moved, or the PV came near it):
        the pulse is what ran. Once the heat is already off, nothing: the wait for it goes
        on as it was."""
        if self._t < self._on:
            self._on = self._t
            self._marked_at = min(self._marked_at, self._on)
        self._tail_end = min(self._tail_end, self._t)

    def _tail_arrived(self, t: float) -> float:
        """s of the tail's heat at the sensor by `t`: each second of it a delay late, then
        through the sensor's first-order lag."""
        if not self._tail[0]:
            return 0.0
        _, delay, lag = self._tail
        return _lagged_seconds(t - self._on - delay, lag) - _lagged_seconds(
            t - self._tail_end - delay, lag
        )

    def add(
        self, pv: float, ts: float, loss: float, ambient: float, model_rate: float
    ) -> HeatUpFit | None:
        """One more period of the pulse; the measurement once the PV has settled after it
        (or, past MAX_DEAD_TIME, why there is none)."""
        self._t += ts
        t = self._t - 0.5 * ts
        sent = self._tail_climb * self._tail_arrived(t)
        rise = pv - sent - self._pv0
        fell, self._last = self._last - pv, pv
        if fell > STEADY_BAND:
            why = f"the PV fell {fell:.2f} °C in a period while the pulse's heat arrived"
            return HeatUpFit(model_rate, 0.0, why, self._t)
        self._rise.add(t, rise)
        if pv - sent > self._mark + 2.0 * SENSOR_LSB:
            self._mark, self._marked_at = pv - sent, t
        waited = t - self._on
        if t > HEAT_SHOWS_S and self._mark - self._pv0 < MOVE_FROM:
            why = f"the PV did not rise in {t:.0f} s after the pulse began: no heat showed"
            return HeatUpFit(model_rate, 0.0, why, self._t)
        if waited <= 0.0:
            return None
        if waited > MAX_DEAD_TIME:
            why = f"the PV had not settled {waited:.0f} s after full power was cut"
            return HeatUpFit(model_rate, 0.0, why, self._t)
        if self._on <= 0.0:
            return HeatUpFit(model_rate, 0.0, "the pulse was stopped before it ran", self._t)
        if self._mark - self._pv0 < self._least_rise or rise <= 0.0:
            return None
        # The rise's arrival so far: ∫t·dr = t·r − ∫r dt, its mean t − ∫r dt / r; less the
        # pulse's own middle, the delay and the lag (read early by the losses: the wait's
        # measure, not the fit's). A lag's tail still to come climbs at its slope times the
        # lag: under 2 LSB once 2 LSB took longer than delay and lag together.
        integral = self._rise.integral(ts)
        if t - self._marked_at < max(PULSE_SETTLE_S, t - integral / rise - 0.5 * self._on):
            return None
        # All the pulse's heat has reached the sensor, and the water falls as the tun loses
        # heat to its room: that fall places the room (a model's room 20 K off misjudges
        # 20 K of loss), and the room the loss added back, which the arrival rests on.
        times, rises = self._rise.since(-math.inf)
        model_room, rate = ambient, model_rate
        for _ in range(FILL_ROUNDS):
            # The day's fill scales the loss as it scales the rate (UA/P is the tun's own).
            fill_loss = loss * rate / model_rate
            dead_time, lag = arrival(times, rises, self._on, fill_loss, self._pv0 - ambient)
            for _ in range(ROOM_ROUNDS):
                room = self._water_room(t, lag, fill_loss)
                if room is None:
                    break
                self.room = ambient = min(max(room, model_room - PULSE_ROOM_SPAN), pv)
                warm = self._pv0 - ambient
                dead_time, lag = arrival(times, rises, self._on, fill_loss, warm)
            # What the losses took on the way is added back.
            lost = fill_loss * ((self._pv0 - ambient) * t + integral)
            heated = self._on + self._tail[0] * self._tail_arrived(t)
            rate = (rise + sent + lost) / heated * 100.0 / self._du
        return checked(rate, dead_time, model_rate, self._t, lag)

    def _water_room(self, t: float, lag: float, loss: float) -> float | None:
        """°C: the room the water's fall places, from the PV's last rise (`_marked_at`) to
        `t`; None where that stretch is shorter than two PULSE_SETTLE_S windows. The water
        is the sensor plus its lag times its slope (τ·s' = w − s) and falls by the loss
        alone: over the stretch w_b − w_a = −loss·∫(w − room), so a tail still to come,
        which the PV's slope alone reads as a warm room, is counted (docs/heat-up-fit.md)."""
        start = self._marked_at
        if loss <= 0.0 or t - start < 2.0 * PULSE_SETTLE_S:
            return None
        first = self._rise.line(start, start + PULSE_SETTLE_S)
        last = self._rise.line(t - PULSE_SETTLE_S, t)
        slopes = first.slope(), last.slope()
        if slopes[0] is None or slopes[1] is None:
            return None
        t_a, t_b = first.st / first.n, last.st / last.n
        r_a, r_b = first.sx / first.n, last.sx / last.n
        between = self._rise.line(t_a, t_b)
        if between.n == 0:
            return None
        fell = (r_b - r_a) * (1.0 + loss * lag) + lag * (slopes[1] - slopes[0])
        # The water the loss acts on holds the tail's heat too.
        water = between.sx / between.n + self._tail_climb * self._tail_arrived(0.5 * (t_a + t_b))
        return self._pv0 + water + fell / (loss * (t_b - t_a))


def _lagged_seconds(x: float, lag: float) -> float:
    """s of a step begun `x` s ago that a first-order lag has passed (0 before it began)."""
    if x <= 0.0:
        return 0.0
    return x - lag * -math.expm1(-x / lag) if lag > 0.0 else x


def arrival(
    times: list[float], rises: list[float], on_s: float, loss: float, warm: float
) -> tuple[float, float]:
    """(the dead time s, the first-order sensor lag s of it, 0 if none) a pulse's rise
    shows: `rises` °C at `times` s from the pulse's start, full power for its first `on_s`
    s, from `warm` K above the room.

    With the loss added back (as in `through_lag`) the rise is the heat's arrival at the
    sensor: the on-time shifted by the delay and the lag and spread by the lag, so its mean
    time is on_s/2 + the dead time, and its times' variance the on-time's (on_s²/12) and the
    lag's (τ²), a delay adding none. On the PV itself the losses take the late arrivals
    off, and the mean reads early (docs/heat-up-fit.md)."""
    weight = first = second = 0.0
    t_last = y_last = 0.0
    for t, y in zip(times, loss_added_back(times, rises, loss, warm, (0.0, 0.0)), strict=True):
        arrived, middle = y - y_last, 0.5 * (t + t_last)
        weight += arrived
        first += arrived * middle
        second += arrived * middle * middle
        t_last, y_last = t, y
    if weight <= 0.0:
        return 0.0, 0.0
    mean = first / weight
    spread = second / weight - mean * mean - on_s * on_s / 12.0
    return mean - 0.5 * on_s, math.sqrt(spread) if spread > 0.0 else 0.0


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


TRUSTED_SHARE = 0.5
"""The share of a pour's drop shown from which its course is taken whole (`_PourGap`): the
noise on it at most doubled."""
GAP_GONE = 1e-3
"""°C: a pour's drop still unseen below this is shown (a thousandth of the LM92's step)."""


class _RecoveryStall:
    """A recovery from cold water, from its drop until the water is back at the setpoint
    (`active`), and its PVs over the last two of the heat's ways to the sensor (the dead
    time and the lag): its landing creeps up as its heat arrives, which a minute's reading
    behind noise takes for a stall, and one missing heat does not."""

    __slots__ = ("active", "pvs")

    def __init__(self) -> None:
        self.active = False
        self.pvs: deque[float] = deque()

    def start(self) -> None:
        """Cold water's drop: the recovery's ways are judged from its end."""
        self.active = True
        self.pvs.clear()

    def end(self) -> None:
        self.active = False
        self.pvs.clear()

    def add(self, pv: float, way: int) -> None:
        """One period's PV of the recovery; `way` periods of the heat's way kept twice."""
        pvs = self.pvs
        pvs.append(pv)
        while len(pvs) > 2 * way:
            pvs.popleft()

    def stalled(self, way: int, least: int) -> bool:
        """Whether the PVs' mean over the last `way` periods, or half of those kept where
        fewer (at least `least`), is no higher than over as many before."""
        pvs = self.pvs
        way = min(way, len(pvs) // 2)
        if way < least:
            return False
        end = len(pvs)
        now = sum(itertools.islice(pvs, end - way, end))
        return now <= sum(itertools.islice(pvs, end - 2 * way, end - way))


class _PourGap:
    """Cold water poured in mixes at once; a sensor of first-order lag L shows the drop D
    as D·(1 − e^(−t/L)), so the PV still has D·e^(−t/L) to fall when it turns to rise
    under the heat. While the drop is followed, D is what the PV lies under the model's
    pour-free course over the share shown, but no more than its fall from where it held
    over that share (`bound`: heat that shows only lessens the fall), and only until the
    model's heat sent since begins to lift that course (a little early on a fast tun, it
    would have the drop degrees deeper: population tun 97, 0.48 °C over); from then on the
    model takes each period's part of the rest as the water's own change (the prediction
    counts what is left), so the law neither cuts full power while the water is still
    degrees short nor the bias learns the tail as heat missing."""

    __slots__ = ("bound", "drop", "following", "free", "periods", "start")

    def __init__(self, free: float) -> None:
        self.free = self.start = free  # °C: the PV by the model without the pour
        self.drop = 0.0  # °C the water fell, as the PV's course says so far
        self.bound = 0.0  # °C: the most the fall says, from half the drop shown on
        self.periods = 1  # since the pour, which came within the period that showed it
        self.following = True

    def unseen(self, fade: float) -> float:
        """°C of the drop the sensor has yet to show (fade: e^(−Ts/L)); while followed, in
        proportion to the share shown up to TRUSTED_SHARE: early on the course is mostly
        noise over a small share, and a law (or a contactor's minimum on-time) that took
        it whole sent heat for a drop that was not there."""
        rest = fade**self.periods
        return self.drop * rest * (self._trusted(rest) if self.following else 1.0)

    @staticmethod
    def _trusted(rest: float) -> float:
        return min(1.0, (1.0 - rest) / TRUSTED_SHARE)

    def settle(self, fade: float) -> None:
        """The drop is all followed: as much of it is taken as is trusted now."""
        self.drop *= self._trusted(fade**self.periods)
        self.following = False

    def seen(self, pv: float, fade: float, held: float) -> None:
        """The drop the PV shows so far, over the share of it a lag lets show; `held`: the
        PV before the pour (the water no colder than the coldest pour)."""
        if not self.following:
            return
        share = 1.0 - fade**self.periods
        fall = max(held - pv, 0.0) / share
        if share >= TRUSTED_SHARE:  # the running most once the noise is at most doubled
            self.bound = fall = max(self.bound, fall)
        if self.free - self.start > BIAS_INNOVATION_CLIP:
            return  # the model's heat arrives: a little early, it would deepen the drop
        course = max(self.free - pv, 0.0) / share
        self.drop = min(course, fall, max(held - COLDEST_POUR, 0.0))

    def advance(self, drift: float, fade: float) -> float:
        """One period on: the model's `drift` joins the pour-free course while the drop is
        followed; after, the °C of the drop the sensor shows this period."""
        before = self.unseen(fade)
        self.periods += 1
        if self.following:
            self.free += drift
            return 0.0
        return before - self.unseen(fade)
