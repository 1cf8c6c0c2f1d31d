"""An element that does not heat, judged from the heat balance over a window of the day.

The supervisor's watch from the output alone (`Supervisor._check_heater`) waits until the
output has stood at or above what beats the largest losses; a law that answers a dead
element slowly, or pulses it, keeps it waiting. The balance is judged on whatever the
output did, by two bounds that hold for any working element (docs/heat-balance.md):

- the level: over `WINDOW_S`, with the duty's mean (taken the dead time earlier) at or
  above h, the duty that beats the largest losses the limits allow, a working element does
  not let the PV fall (by the output watch's steady fall, 0.25 °C in 300 s, or more; by any
  fall out of the noise where the duty beats `LOSS_GROWTH` times the day's hold's losses
  and an open surface's evaporation), and a dead one lets it fall at its losses, as
  steeply as in the window before (water poured in shows through the sensor's lag as a
  fall that decays: that is no verdict). The output's own watch judges the same from a
  duty that stays at h; this one from its mean, whatever the law did with it;
- the climb: where the mean duty rose from one window to the next by `CLIMB` %, or less
  where the weakest heating of that climb shows as `SIGNAL_SHARE` times the margin two slopes
  must differ by (a strong element on little water: a few %), and by at least `RAMP_SHARE`
  of the day's hold duty (before the hold is measured, of the
  least duty kept): twice what answering losses that ramp up by a quarter of themselves in
  a window takes (×2 in 20 minutes, without a step),
  the later's slope rose by at least `CLIMB_SHARE` of what the weakest element makes of
  that climb (the limits' weakest rise per % of duty times it), the losses the same in
  both; a dead element's slope stays where it was, the water falling at its losses. Judged
  only where each window's halves have the same slope: losses that step up within one (a
  lid taken off, which the output then climbs to answer) are not the same in both. A law
  that climbs slowly (a small hold's) is judged against the window up to `CLIMB_WINDOWS`
  back too, every window between alike, the climb's least share of the hold that many
  times over: the same pace of climb, with more of its heat to show;
- the stall: with the output at its limit (a heat-up), the PV's slope over the last window
  fell from the ramp measured at that limit a dead time before it by more than the mains'
  sag, a lid taken off and the losses' growth with the water's rise allow: a working
  element's ramp only bends as its losses grow, a dead one's stops at once (each window's
  halves alike: warm water poured in steps the PV). Judged whatever the losses are (a lidded
  tun in a warm room falls too slowly for the level), so a heat-up's death is told from the
  ramp the day has measured, not from the fall; and a death in the landing, where the law
  cut back and then climbed to its limit again, from the last ramp before the cut that the
  window before it confirmed (within `RAMP_AGE_S`).

Each is judged with the duty taken at each of `DEAD_TIME_FACTORS` of the dead time, and
a finding needs all of them (a dead time misjudged makes a changing duty's heat look
missing at one of them, not at all), beyond `MARGIN_SE` standard errors of the slopes
(and `NOISE_FLOOR` over the window), for `CONFIRM_S`. Pure, fed once a control period.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from dataclasses import dataclass
from operator import attrgetter, itemgetter

from hermsd.safety.limits import NOISE_FLOOR

WINDOW_S = 300.0
"""s of PV each slope is fitted over: with 0.06 °C of noise on each of 60 periods' PV, the
slope's standard error is 0.06·√(12/60)/300 = 9e-5 °C/s, and four of them are the 0.1 °C
over the window that the margin never goes below."""
CLIMB = 10.0
"""% of duty the mean must have risen from one window to the next for the climb's verdict…"""
SIGNAL_SHARE = 1.5
"""… or less, down to where `CLIMB_SHARE` of the weakest heating of the climb is this many
times the margin two slopes must differ by: a climb whose missing heat stands out of the noise
(docs/heat-balance.md, "The climb")."""
RAMP_SHARE = 0.5
"""… and the share of the hold's duty it must have risen by: losses that ramp up by a
quarter of themselves in a window are answered by a quarter of that duty, and the law may
lag (docs/heat-balance.md, "The climb"; bench/loss_steps.py's ramps)."""
CLIMB_SHARE = 0.5
"""… and the part of the weakest heating of that climb the slope must have gained."""
CLIMB_WINDOWS = 3
"""Windows back the climb may be judged from: a climb of a few % a window, whose heat a
window apart is lost in the noise, shows across three with the same pace asked of it
(docs/heat-balance.md, "The climb")."""
DEAD_TIME_FACTORS = (1.0 / 3.0, 2.0 / 3.0, 1.0)
"""Of the limits' dead time (1.5× the fitted one once measured: 0.5, 1 and 1.5× it)."""
MARGIN_SE = 4.0
"""Standard errors of the slope (from the window's own residuals) a finding must clear."""
CONFIRM_S = 60.0
"""s a finding must last."""
FULL_SLACK = 1.0
"""% of duty under the output's limit still counted at it (the planner's rounding)."""
LOSS_GROWTH = 3.0
"""Times the day's hold's losses may grow on a normal day (a colder room, a draught: the
largest step of bench/loss_steps.py) for the level to ask of a fall only that it stand out
of the noise, at a duty that beats that and an open surface's evaporation
(`Bounds.any_fall_duty`; docs/heat-balance.md, "The level")."""
SETTLE_S = 300.0
"""s after water poured in (and the dead time) before a window may start: the sensor's lag
still bends its fall."""
RAMP_AGE_S = 1800.0
"""s: the oldest ramp at full output the stall compares a window with (the landing's cut
between them); older, a room or a draught may have changed (docs/heat-balance.md, "The
stall")."""


@dataclass(frozen=True, slots=True)
class Slope:
    """A PV's least-squares slope over a window and its standard error."""

    rate: float  # °C/s
    error: float  # its standard error, °C/s


@dataclass(frozen=True, slots=True)
class Bounds:
    """What the limits say of the tun at this period's PV."""

    dead_time: float  # s the element's heat takes to show at the sensor, at most
    per_duty: float  # °C/s: the weakest rise per % of duty
    loss_duty: float  # %: the duty that beats the largest losses the limits allow
    least_fall: float  # °C/s: the least fall the level judges (the output watch's)
    fastest_loss: float  # °C/s: the fastest the water cools with no heat (faster: a pour)
    full_duty: float  # %: the output's limit, at which the stall judges
    stall_drop: float  # °C/s: the most a ramp at that limit slows with the element working
    heat_memory: float  # s within which the heat sent shows at the sensor, lag and all
    loss_per_k: float  # °C/s per °C: the most the losses grow as the water rises
    hold_duty: float | None  # %: the day's hold's mean duty (None: not measured yet)
    any_fall_duty: float | None  # %: from it any fall is judged (LOSS_GROWTH; None: no hold)


@dataclass(frozen=True, slots=True)
class BalanceVerdict:
    """Heat missing by the balance: what the alarm's message and values say."""

    message: str
    values: dict[str, float]


class HeatBalance:
    """The last two windows of (t, PV, duty) and the verdict on them."""

    def __init__(self) -> None:
        self._samples: deque[tuple[float, float, float]] = deque()
        self._ramps: deque[_Ramp] = deque()
        self._off_limit_at: float | None = None  # the last period the duty left the limit
        self._poured_at: float | None = None
        self._since: float | None = None

    def clear(self) -> None:
        """Nothing before now is judged (the heater was off, or a HERMS coil may draw)."""
        self._samples.clear()
        self._ramps.clear()
        self._off_limit_at = None
        self._since = None

    def poured(self, t: float) -> None:
        """Water was poured in at `t`: its fall is no loss, and the ramps before it were
        another water's."""
        self._poured_at = t
        self._ramps.clear()

    def period(self, t: float, pv: float, applied: float, bounds: Bounds) -> BalanceVerdict | None:
        """One period: the PV, the duty as switched (%) and what the limits say now. Returns
        the verdict once it has lasted `CONFIRM_S`."""
        samples = self._samples
        samples.append((t, pv, applied))
        if not _at_full(applied, bounds.full_duty):
            self._off_limit_at = t
        reach = (CLIMB_WINDOWS + 1) * WINDOW_S + 2.0 * bounds.dead_time
        while len(samples) > 1 and t - samples[1][0] >= reach:
            samples.popleft()  # the oldest kept is the first at or beyond the reach
        finding = self._finding(t, bounds)
        if finding is None:
            self._since = None
            return None
        if self._since is None:
            self._since = t
        return finding if t - self._since >= CONFIRM_S else None

    def _finding(self, t: float, bounds: Bounds) -> BalanceVerdict | None:
        dead_time, per_duty = bounds.dead_time, bounds.per_duty
        samples = self._samples
        if t - samples[0][0] < 2.0 * WINDOW_S + dead_time - 1e-9:
            return None
        poured = self._poured_at
        if poured is not None and t - poured < 2.0 * WINDOW_S + dead_time + SETTLE_S:
            return None
        later, earlier = self._window(t), self._window(t - WINDOW_S)
        if later is None or earlier is None:
            return None
        floor = NOISE_FLOOR / WINDOW_S
        margin = max(MARGIN_SE * later.error, floor)
        self._note_ramp(t, later, bounds, floor)
        stalled = self._stall(t, later, bounds, floor)
        if stalled is not None:
            return stalled
        gain = later.rate - earlier.rate
        steady = _gap_margin(later, earlier, floor)
        # The level's fall, as steep as the window before's (not the decaying fall of water
        # poured in); the climb's windows each with alike halves: no step of the losses
        # within either (a lid taken off, which the output then climbs to answer, makes the
        # slope fall within a window, and across their boundary).
        falls = -margin > later.rate >= -bounds.fastest_loss - margin and gain <= steady
        steep = later.rate < -bounds.least_fall
        both_steady = all(_steady(w, floor) for w in (later, earlier))
        held = bounds.hold_duty
        if held is None:  # the hold not measured: the least duty of the last two windows
            # and twice the dead time (and the period before), from before a climb
            held = self._least_duty(t - 2.0 * (WINDOW_S + dead_time))
        found: BalanceVerdict | None = None
        for factor in DEAD_TIME_FACTORS:
            shift = factor * dead_time
            duty = self._mean_duty(t - WINDOW_S - shift, t - shift)
            duty_before = self._mean_duty(t - 2 * WINDOW_S - shift, t - WINDOW_S - shift)
            if duty is None or duty_before is None:
                return None
            climb = duty - duty_before
            any_fall = bounds.any_fall_duty is not None and duty >= bounds.any_fall_duty
            level = falls and duty >= bounds.loss_duty and (steep or any_fall)
            climbed = (
                both_steady
                and _heat_missing(climb, 1, held, gain, steady, per_duty)
                and later.rate < -margin
            )
            if not (level or climbed):
                return self._climb_across(t, later, bounds, held, margin)
            if factor == 1.0:
                found = _verdict(duty, duty_before, later, earlier, per_duty, level, 1)
        return found

    def _climb_across(
        self, t: float, later: _Window, bounds: Bounds, held: float, margin: float
    ) -> BalanceVerdict | None:
        """The climb judged from the window `gap` windows before the later (2 …
        `CLIMB_WINDOWS`): every window from it to the later with alike halves and a slope
        alike to the next's (no step of the losses between them), the duty's mean risen by
        `RAMP_SHARE` of the hold's `gap` times over (losses that ramp up are answered at
        the same pace as a window apart), and the rest as a window apart."""
        floor = NOISE_FLOOR / WINDOW_S
        if not (later.rate < -margin and _steady(later, floor)):
            return None
        dead_time, poured = bounds.dead_time, self._poured_at
        newer = later
        for gap in range(1, CLIMB_WINDOWS + 1):
            span = (gap + 1) * WINDOW_S + dead_time
            if t - self._samples[0][0] < span - 1e-9:
                return None
            if poured is not None and t - poured < span + SETTLE_S:
                return None
            earlier = self._window(t - gap * WINDOW_S)
            if earlier is None or not _steady(earlier, floor):
                return None
            if abs(newer.rate - earlier.rate) > _gap_margin(newer, earlier, floor):
                return None
            newer = earlier
            if gap > 1 and (found := self._climbed_from(t, gap, later, earlier, bounds, held)):
                return found
        return None

    def _climbed_from(
        self, t: float, gap: int, later: _Window, earlier: _Window, bounds: Bounds, held: float
    ) -> BalanceVerdict | None:
        """The climb's verdict on the later window against `earlier`, `gap` windows before
        it, at each of `DEAD_TIME_FACTORS` of the dead time."""
        floor = NOISE_FLOOR / WINDOW_S
        gain = later.rate - earlier.rate
        steady = _gap_margin(later, earlier, floor)
        found: BalanceVerdict | None = None
        for factor in DEAD_TIME_FACTORS:
            shift = factor * bounds.dead_time
            duty = self._mean_duty(t - WINDOW_S - shift, t - shift)
            back = t - gap * WINDOW_S - shift
            duty_before = self._mean_duty(back - WINDOW_S, back)
            if duty is None or duty_before is None:
                return None
            if not _heat_missing(duty - duty_before, gap, held, gain, steady, bounds.per_duty):
                return None
            if factor == 1.0:
                found = _verdict(duty, duty_before, later, earlier, bounds.per_duty, False, gap)
        return found

    def _at_limit(self, since: float, bounds: Bounds) -> bool:
        """Whether the duty stood at the output's limit from `since` on (within the
        planner's rounding: not above it, where the limit was lowered since), and the samples
        reach back that far."""
        samples, limit = self._samples, bounds.full_duty
        return samples[0][0] <= since + 1e-9 and all(
            _at_full(applied, limit) for s, _, applied in samples if s > since
        )

    def _note_ramp(self, t: float, later: _Window, bounds: Bounds, floor: float) -> None:
        """Keep the window to `t` as a ramp at the limit, where the duty stood there for it
        and the dead time before (all the heat it shows, but a lag's tail, is at the limit)
        and its halves are alike; confirmed where the ramp a window before rose alike (a
        window with a step in it, warm water poured in, may pass its halves' test on the
        residuals the step adds; of two windows that do not overlap, a step tilts one only)."""
        ramps = self._ramps
        while ramps and t - ramps[0].end > RAMP_AGE_S:
            ramps.popleft()
        if not (_steady(later, floor) and self._at_limit(t - WINDOW_S - bounds.dead_time, bounds)):
            return
        before = self._ramp_ending(t - WINDOW_S, t - self._samples[-2][0])
        confirmed = before is not None and abs(later.rate - before.slope.rate) <= _gap_margin(
            later, before.slope, floor
        )
        ramps.append(_Ramp(t, later, self._mean_pv(t), bounds.full_duty, confirmed))

    def _last_ramp_by(self, end: float) -> _Ramp | None:
        """The last ramp kept whose window ended at or before `end`."""
        ramps = self._ramps
        i = bisect.bisect_right(ramps, end + 1e-9, key=attrgetter("end")) - 1
        return ramps[i] if i >= 0 else None

    def _ramp_ending(self, end: float, period: float) -> _Ramp | None:
        """The ramp kept whose window ended in the period to `end`, if any."""
        ramp = self._last_ramp_by(end)
        return ramp if ramp is not None and ramp.end > end - period + 1e-9 else None

    def _stall(
        self, t: float, later: _Window, bounds: Bounds, floor: float
    ) -> BalanceVerdict | None:
        """The ramp at full output that stopped: the later window at the limit, and its slope
        below that of the ramp a window and a dead time before it by more than `bounds` allow
        for a working element, the PV's rise between them counted in the losses' growth. Where
        the duty left the limit since (the landing's cut), below the last confirmed ramp
        before the cut, the later window's heat all the limit's (at it for the heat's memory
        before)."""
        ramps, samples = self._ramps, self._samples
        if not ramps or ramps[-1].end < t - 1e-9:
            return None  # the later window is no ramp at the limit (or has halves unalike)
        reach = WINDOW_S + bounds.dead_time
        limit = bounds.full_duty  # a ramp at another limit (the brewer's, changed) is no measure
        # At the limit throughout: the ramp a reach before, as it stood (none: a step there).
        ramp = self._ramp_ending(t - reach, t - samples[-2][0])
        if ramp is None:
            # The duty left the limit since the last ramp a reach before (the landing's cut):
            # the last confirmed ramp before the cut, the later window's heat all the limit's.
            cut = self._off_limit_at
            last = self._last_ramp_by(t - reach)
            if cut is None or last is None or last.end > cut:
                return None
            if not self._at_limit(t - WINDOW_S - bounds.heat_memory, bounds):
                return None
            ramp = next((r for r in reversed(ramps) if r.end <= cut and r.confirmed), None)
        if ramp is None or ramp.limit != limit:
            return None
        earlier = ramp.slope
        # The losses over each window are those at its mean PV: they grew by the rise between.
        rise = self._mean_pv(t) - ramp.mean_pv
        allowed = bounds.stall_drop + bounds.loss_per_k * max(rise, 0.0)
        steady = _gap_margin(later, earlier, floor)
        drop = earlier.rate - later.rate
        # Half the ramp gone, too: a weak tun's ramp bends towards its ceiling, never stops.
        if drop <= allowed + steady or later.rate > earlier.rate / 2.0:
            return None
        if later.rate < -bounds.fastest_loss - steady:
            return None  # faster than any loss: water poured in (`poured` waits after it)
        per_min = 60.0
        return BalanceVerdict(
            f"output at its limit ({bounds.full_duty:.0f} %), but the PV's rise went "
            f"{earlier.rate * per_min:+.2f} → {later.rate * per_min:+.2f} °C/min in "
            f"{t - ramp.end + WINDOW_S:.0f} s, more "
            f"slowing than the mains, a lid taken off and the losses allow "
            f"({allowed * per_min:.2f} °C/min)",
            {
                "mean_output": bounds.full_duty,
                "rate_c_per_min": later.rate * per_min,
                "rate_before_c_per_min": earlier.rate * per_min,
            },
        )

    def _window(self, end: float) -> _Window | None:
        """The PV's slope over the `WINDOW_S` to `end`, and over each half of it."""
        points = [(s, p) for s, p, _ in self._samples if end - WINDOW_S < s <= end]
        middle = end - WINDOW_S / 2.0
        whole = pv_slope(points)
        first = pv_slope([(s, p) for s, p in points if s <= middle])
        second = pv_slope([(s, p) for s, p in points if s > middle])
        if whole is None or first is None or second is None:
            return None
        return _Window(whole.rate, whole.error, first, second)

    def _mean_pv(self, end: float) -> float:
        """The PV's mean over the `WINDOW_S` to `end` (a window `_window` has fitted)."""
        pvs = [p for s, p, _ in self._samples if end - WINDOW_S < s <= end]
        return sum(pvs) / len(pvs)

    def _least_duty(self, since: float) -> float:
        """The least duty from `since` on, and of the period before it (the samples as two
        windows and twice the dead time kept them, before the climb looked further back)."""
        samples = self._samples
        first = max(0, bisect.bisect_right(samples, since, key=itemgetter(0)) - 1)
        return min(samples[i][2] for i in range(first, len(samples)))

    def _mean_duty(self, start: float, end: float) -> float | None:
        duties = [a for s, _, a in self._samples if start < s <= end]
        return sum(duties) / len(duties) if duties else None


@dataclass(frozen=True, slots=True)
class _Window(Slope):
    first: Slope  # over the window's first half
    second: Slope  # … and its second


@dataclass(frozen=True, slots=True)
class _Ramp:
    """A window whose heat was all sent at the output's limit."""

    end: float  # s
    slope: _Window
    mean_pv: float  # °C
    limit: float  # % the output's limit stood at
    confirmed: bool  # the ramp a window before rose alike


def _heat_missing(
    climb: float, gap: int, held: float, gain: float, steady: float, per_duty: float
) -> bool:
    """The climb's verdict: the duty's mean rose by `climb` % from the window `gap` windows
    before (at least `RAMP_SHARE` of the hold's duty `held` a window: not losses that ramp
    up, answered; `CLIMB`, or less where its weakest heat stands out of the noise `steady`),
    and the slope's `gain` fell short of `CLIMB_SHARE` of that heat by more than the noise."""
    heat = CLIMB_SHARE * per_duty * climb  # °C/s of it a working element shows
    return (
        climb >= gap * RAMP_SHARE * held
        and (climb >= CLIMB or heat >= SIGNAL_SHARE * steady)
        and gain < heat - steady
    )


def _at_full(applied: float, limit: float) -> bool:
    """Whether a period's duty stood at the output's `limit` (within `FULL_SLACK`)."""
    return abs(applied - limit) <= FULL_SLACK


def _steady(window: _Window, floor: float) -> bool:
    """Whether the PV's slope is the same in both halves of `window`, within the noise."""
    gap = window.second.rate - window.first.rate
    return abs(gap) <= _gap_margin(window.first, window.second, floor)


def _gap_margin(one: Slope, other: Slope, floor: float) -> float:
    """°C/s two slopes must differ by to differ beyond their noise: `MARGIN_SE` standard
    errors of the difference, never under `floor`."""
    return max(MARGIN_SE * math.hypot(one.error, other.error), floor)


def pv_slope(points: list[tuple[float, float]]) -> Slope | None:
    """The least-squares slope of the PV over `points` and its standard error, about the
    points' own means: exact on any clock (the control side's running sums, `LineFit`, lose
    the slope's digits to t² once t is large, and the safety package leans on no control
    code)."""
    n = len(points)
    if n < 4:
        return None
    t_mean = sum(t for t, _ in points) / n
    pv_mean = sum(p for _, p in points) / n
    spread = sum((t - t_mean) ** 2 for t, _ in points)
    if spread <= 0.0:
        return None
    rate = sum((t - t_mean) * (p - pv_mean) for t, p in points) / spread
    residuals = sum((p - pv_mean - rate * (t - t_mean)) ** 2 for t, p in points)
    return Slope(rate, math.sqrt(residuals / (n - 2) / spread))


def _verdict(
    duty: float,
    duty_before: float,
    later: Slope,
    earlier: Slope,
    per_duty: float,
    level: bool,
    gap: int,
) -> BalanceVerdict:
    per_min = 60.0
    if level:
        message = (
            f"output at {duty:.0f} % on average over {WINDOW_S:.0f} s (its heat due at the "
            "sensor by now), more than the largest losses need, but the PV fell "
            f"{-later.rate * per_min:.2f} °C/min"
        )
    else:
        message = (
            f"output climbed from {duty_before:.0f} to {duty:.0f} % on average over "
            f"{(gap + 1) * WINDOW_S:.0f} s, worth at least "
            f"{CLIMB_SHARE * per_duty * (duty - duty_before) * per_min:.2f} °C/min more, but "
            f"the PV's slope went {earlier.rate * per_min:+.2f} → "
            f"{later.rate * per_min:+.2f} °C/min"
        )
    return BalanceVerdict(
        message,
        {
            "mean_output": duty,
            "rate_c_per_min": later.rate * per_min,
            "rate_before_c_per_min": earlier.rate * per_min,
        },
    )
