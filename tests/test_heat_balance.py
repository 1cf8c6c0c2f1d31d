"""The heat balance's verdicts on a dead element, worked by hand on straight-line PVs.

A straight line's slopes have no error, so every margin is the noise floor over a window:
0.1 °C in 300 s, 3.33e-4 °C/s.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

from hermsd.safety.heat_balance import Bounds, HeatBalance

PER_DUTY = 1e-4  # °C/s per % of duty: the weakest element's
FASTEST_LOSS = 0.01  # °C/s
PERIOD = 5.0
LEAST_FALL = 0.25 / 300.0  # the output watch's steady fall, °C/s
STALL_DROP = 1e-3  # °C/s a ramp at full output may slow with the element working
LOSS_PER_K = 1e-5  # °C/s per °C the losses may grow
HOLD_DUTY = 10.0  # % the day's hold measured: the climb's least is then its own 10 %


def bounds(
    loss_duty: float,
    dead_time: float = 0.0,
    hold_duty: float | None = HOLD_DUTY,
    per_duty: float = PER_DUTY,
    any_fall_duty: float | None = None,
) -> Bounds:
    return Bounds(
        dead_time,
        per_duty,
        loss_duty,
        LEAST_FALL,
        FASTEST_LOSS,
        full_duty=100.0,
        stall_drop=STALL_DROP,
        heat_memory=dead_time,
        loss_per_k=LOSS_PER_K,
        hold_duty=hold_duty,
        any_fall_duty=any_fall_duty,
    )


def first_verdict(
    duty: Callable[[float], float],
    rate: Callable[[float], float],
    loss_duty: float,
    *,
    until: float = 3600.0,
    dead_time: float = 0.0,
    poured_at: float | None = None,
    hold_duty: float | None = HOLD_DUTY,
    per_duty: float = PER_DUTY,
    any_fall_duty: float | None = None,
) -> float | None:
    """When the balance first reports, fed every period from 0 s: the duty (%) switched at
    each time, and the PV's slope (°C/s) over each period."""
    balance, t, pv = HeatBalance(), 0.0, 66.0
    while t <= until:
        if poured_at is not None and t == poured_at:
            balance.poured(t)
        judged = bounds(loss_duty, dead_time, hold_duty, per_duty, any_fall_duty)
        verdict = balance.period(t, pv, duty(t), judged)
        if verdict is not None:
            return t
        t += PERIOD
        pv += rate(t) * PERIOD
    return None


def test_the_level_judges_a_fall_with_more_duty_than_the_largest_losses_need() -> None:
    # At 50 %, over the 20 % that beats the largest losses, the water may not fall: a fall
    # steeper than the output watch's (0.25 °C in 300 s; beyond the margin of 3.33e-4 °C/s)
    # is a dead element's. Judged from 2 windows (600 s) in, reported once it has lasted 60 s.
    assert first_verdict(lambda t: 50.0, lambda t: -LEAST_FALL - 1e-5, 20.0) == 660.0
    assert first_verdict(lambda t: 50.0, lambda t: -LEAST_FALL + 1e-5, 20.0) is None
    # A rise, however slow, is left to the output's own watch (the least rise at 80 %).
    assert first_verdict(lambda t: 50.0, lambda t: 1e-5, 20.0) is None
    # At 15 %, under the 20 % that beats the largest losses, a fall is no verdict.
    assert first_verdict(lambda t: 15.0, lambda t: -5e-3, 20.0) is None


def test_at_a_duty_beyond_what_the_day_allows_any_fall_out_of_the_noise_is_judged() -> None:
    # A slow fall, 5e-4 °C/s: beyond the margin (3.33e-4 °C/s), short of the output watch's
    # steady fall (8.33e-4 °C/s). At 100 %, over the 90 % that beats three times the day's
    # hold's losses and a lid off, a working element cannot let the water fall at all:
    # reported as the steep fall is, from 2 windows in and after 60 s, at 660 s.
    def slow(t: float) -> float:
        return -5e-4

    assert first_verdict(lambda t: 100.0, slow, 60.0, any_fall_duty=90.0) == 660.0
    # Under that duty (losses tripled since the hold may outweigh 50 %), or with no hold
    # measured (no bound), the slow fall is no verdict; under the margin, none either.
    assert first_verdict(lambda t: 50.0, slow, 20.0, any_fall_duty=90.0) is None
    assert first_verdict(lambda t: 100.0, slow, 60.0) is None
    assert first_verdict(lambda t: 100.0, lambda t: -3e-4, 60.0, any_fall_duty=90.0) is None


def test_a_fall_that_decays_is_water_poured_not_a_dead_element() -> None:
    # At 50 %, a fall of 0.03 °C/s that halves each 100 s (cold water through the sensor's
    # lag): steeper than 0.25 °C in 300 s until 517 s, a window's mean slope until some
    # 690 s, but each window's slope is well above the one before it (were that not judged,
    # the verdict would come at 660 s).
    def decaying(t: float) -> float:
        return -0.03 * math.pow(0.5, t / 100.0)

    assert first_verdict(lambda t: 50.0, decaying, 20.0) is None


def test_a_climb_that_the_slope_does_not_follow_is_a_dead_element() -> None:
    # The duty steps from 20 to 50 % at 600 s with the water falling on at 1e-3 °C/s; the
    # level cannot judge (80 % of losses). The later window's mean climbs 30 % × (t − 600)
    # / 300 s, and a gain of 0 is below half the weakest heat of it less the margin,
    # ½·1e-4·climb − 3.33e-4, from a climb of 6.7 %: the climb's own least, 10 %, at
    # 700 s, reported at 760 s.
    def step(t: float) -> float:
        return 20.0 if t <= 600.0 else 50.0

    assert first_verdict(step, lambda t: -1e-3, 80.0) == 760.0


def test_a_smaller_climb_is_judged_where_its_heat_stands_out_of_the_noise() -> None:
    # A strong element on little water: 5e-4 °C/s per % at its weakest. Half the weakest heat
    # of a climb of c % is 2.5e-4·c °C/s, 1.5 times the margin (3.33e-4) from c = 2 %. The
    # duty steps from 20 to 27 % at 600 s with the water falling on at 1e-3 °C/s (a hold of
    # 3 %: half of it, 1.5 %, asks less): the later window's mean climbs 7 % × (t − 600) /
    # 300 s, 2.1 % at 690 s, reported at 750 s. The weak element's 1e-4 °C/s per % shows
    # only from 10 %, the climb's own least, which 7 % never reaches.
    def step(t: float) -> float:
        return 20.0 if t <= 600.0 else 27.0

    def falling(t: float) -> float:
        return -1e-3

    assert first_verdict(step, falling, 80.0, hold_duty=3.0, per_duty=5e-4) == 750.0
    assert first_verdict(step, falling, 80.0, hold_duty=3.0) is None


def test_a_climb_is_judged_only_with_the_water_falling() -> None:
    # A heat-up started at 600 s behind a dead time longer than the limits': the duty steps
    # from 0 to 100 % and the water has not begun to rise. The slope gained nothing of
    # ½·1e-4·100 °C/s, but the water does not fall either: no dead element's.
    def start(t: float) -> float:
        return 0.0 if t <= 600.0 else 100.0

    assert first_verdict(start, lambda t: 0.0, 80.0) is None


def test_a_climb_the_slope_follows_is_a_working_element() -> None:
    # The duty ramps 0.05 %/s from 600 s: 15 % a window. A slope that gains k·1e-4 per % of
    # it is dead below k = (½·1e-4·15 − 3.33e-4) / (1e-4·15) = 0.278, and each window's
    # halves differ by k·1e-4·0.05·150 s, steady within the margin up to k = 0.44.
    def ramp(t: float) -> float:
        return min(80.0, 20.0 + 0.05 * max(0.0, t - 600.0))

    def slope(k: float) -> Callable[[float], float]:
        return lambda t: -1e-3 + k * PER_DUTY * (ramp(t) - 20.0)

    assert first_verdict(ramp, slope(0.0), 80.0) is not None
    assert first_verdict(ramp, slope(0.2), 80.0) is not None
    assert first_verdict(ramp, slope(0.35), 80.0) is None


def test_a_climb_under_half_the_hold_duty_may_be_answering_losses_that_ramp() -> None:
    # From a hold at 40 %, the losses ramp up and the output climbs 0.05 %/s from 600 s to
    # answer them: 15 % a window, the slope's gain nil, the water falling 1e-3 °C/s behind.
    # A dead element's climb looks the same; one under half the hold's duty (20 %) is not
    # judged. Before the hold is measured, the least duty kept stands for it: 40 % too.
    def ramp(t: float) -> float:
        return min(90.0, 40.0 + 0.05 * max(0.0, t - 600.0))

    assert first_verdict(ramp, lambda t: -1e-3, 95.0, hold_duty=40.0) is None
    assert first_verdict(ramp, lambda t: -1e-3, 95.0, hold_duty=None) is None
    # From a hold of 20 %, half of it is under the 10 % the climb needs anyway: judged.
    assert first_verdict(ramp, lambda t: -1e-3, 95.0, hold_duty=20.0) is not None


def slow_climb(hold: float) -> Callable[[float], float]:
    """A law climbing from `hold` % at 0.02 %/s from 600 s: 6 % a window."""
    return lambda t: hold + 0.02 * max(0.0, t - 600.0)


def test_a_slow_climb_is_judged_against_the_window_two_back() -> None:
    # From a hold of 4 %, the law climbs 6 % a window with the water falling on at 1e-3
    # °C/s. A window apart, 6 % is under the climb's 10 %, and half its weakest heat,
    # 3e-4 °C/s, under 1.5 times the margin (5e-4): never judged so. Two and three windows
    # apart the climb reaches 10 %, past 2 (3) × half the hold, and the slope's gain is nil,
    # under ½·1e-4·10 − 3.33e-4. The windows' duty means, on the periods' samples: at 1250 s
    # the later one's, (950, 1250] s, is 4 + 0.02 × (1102.5 − 600) = 14.05 %; the one three
    # before it, (50, 350] s, 4 %: 10.05 % (two before, (350, 650] s, 4 + 0.1 × (1 + … + 10)
    # / 60 = 4.09 %: 9.96 %; at 1245 s, 13.95 − 4 = 9.95 %). Reported 60 s later.
    assert first_verdict(slow_climb(4.0), lambda t: -1e-3, 80.0, hold_duty=4.0) == 1310.0


def test_a_slow_climb_under_half_the_hold_duty_a_window_is_not_judged_across_windows() -> None:
    # The same pace from a hold of 13 %: 6 % a window is under half of it (6.5 %), so it may
    # be losses that ramp up, answered; across two and three windows the climb must beat
    # half the hold as many times over, and never does.
    assert first_verdict(slow_climb(13.0), lambda t: -1e-3, 80.0, hold_duty=13.0) is None


def test_a_slow_climb_is_judged_across_windows_only_past_a_step_of_the_losses() -> None:
    # Steady on 4 % until a lid comes off at 900 s: the water falls at 1e-3 °C/s from then,
    # and the law climbs 6 % a window from 960 s, its heat matched by losses that grow on
    # (beyond the climb's bound, as a dead element's looks). Against the window three back,
    # before the step (its slope nil), the climb reaches 10 % at 1610 s (the later window's
    # mean 4 + 0.02 × (1462.5 − 960) = 14.05 %): were the windows between not asked to be
    # alike, it would be reported at 1670 s. The window that
    # holds the step has halves unalike until the step lies within its first minute or so
    # (a half that falls over its last 60 % slopes ×0.65 of the fall, 3.5e-4 °C/s off, past
    # the margin), from some 1740 s on; then the climb is judged as on any dead element.
    def climb(t: float) -> float:
        return 4.0 + 0.02 * max(0.0, t - 960.0)

    def fall(t: float) -> float:
        return -1e-3 if t > 900.0 else 0.0

    assert first_verdict(climb, fall, 80.0, hold_duty=4.0, until=1735.0) is None
    assert first_verdict(climb, fall, 80.0, hold_duty=4.0, until=1900.0) is not None


def test_losses_that_step_up_as_the_output_climbs_are_not_a_dead_element() -> None:
    # A lid taken off at 900 s: the water, steady on 20 %, falls at 4e-3 °C/s, and the
    # output climbs 0.05 %/s from 960 s to answer it, its heat showing in full (1e-4 per %).
    # The windows that straddle the step see the slope fall as the duty climbs; each has
    # halves unalike, so no climb is judged (else one would be, at 1375 s), and the windows
    # after it see the heat.
    def answer(t: float) -> float:
        return min(80.0, 20.0 + 0.05 * max(0.0, t - 960.0))

    def slope(t: float) -> float:
        return (-4e-3 if t > 900.0 else 0.0) + PER_DUTY * (answer(t) - 20.0)

    assert first_verdict(answer, slope, 80.0) is None


def test_water_poured_in_defers_the_verdict_by_two_windows_and_a_settling() -> None:
    # The level's dead element of the first test, water poured at 300 s: judged from 300 +
    # 600 + 300 s (two windows, no dead time, the settling), reported 60 s later.
    assert first_verdict(lambda t: 50.0, lambda t: -1e-3, 20.0, poured_at=300.0) == 1260.0


def test_the_duty_is_taken_the_dead_time_before_the_pv() -> None:
    # The climb's dead element with 150 s of dead time: the duty is judged at a third, two
    # thirds and all of it earlier, and all must agree; the last sees the climb latest,
    # 150 s after the PV's time: 760 + 150 s.
    def step(t: float) -> float:
        return 20.0 if t <= 600.0 else 50.0

    assert first_verdict(step, lambda t: -1e-3, 80.0, dead_time=150.0) == 910.0


def test_a_ramp_at_full_output_that_stops_is_a_dead_element() -> None:
    # A heat-up at 100 % rising 5e-3 °C/s whose element dies at 1200 s, 150 s of dead
    # time: the water then cools at 1e-4 °C/s, too slowly for the level. From 1500 s the
    # later window is all after the death (its halves alike: before, the kink unsettles
    # them), and until 1650 s the earlier, the dead time before it, all before: a drop of
    # 5.1e-3 °C/s against 1e-3 + 1e-5 × the PV's rise between the windows' means (under
    # the 2.25 °C of 450 s at 5e-3 °C/s), plus the margin of 3.33e-4. Told once it has
    # lasted 60 s: by 1560 s, and
    # not before three quarters of the later window lie past the death (a kink in its first
    # half widens the halves' margin by its own residuals).
    def ramp(t: float) -> float:
        return 5e-3 if t <= 1200.0 else -1e-4

    found = first_verdict(lambda t: 100.0, ramp, 80.0, dead_time=150.0)
    assert found is not None and 1200.0 + 0.75 * 300.0 + 60.0 <= found <= 1500.0 + 60.0
    # Not at 95 %, where the output is not at its limit (and the slow fall is below the
    # level's least): nothing is said of a stop there.
    assert first_verdict(lambda t: 95.0, ramp, 80.0, dead_time=150.0) is None


def test_a_death_in_the_landings_cut_is_judged_against_the_ramp_before_it() -> None:
    # The heat-up at 100 % rising 5e-3 °C/s, 150 s of dead time; the law cuts to 50 % at
    # 1200 s to land, and climbs back to 100 % at 1320 s. The ramps at the limit end at
    # 1195 s (the duty at it over the window and the dead time before: 450 s); the element
    # dies at 1250 s and the water cools at 1e-4 °C/s. The later window is at the limit
    # again, its heat and the dead time's all sent there, once t − 450 s passes the cut's
    # last period (1315 s): at 1765 s, against the ramp to 1195 s (570 s before, within
    # RAMP_AGE_S): a drop of 5.1e-3 °C/s, over 1e-3 + 1e-5 × the PV's rise between the
    # windows' means (1.0 °C) + 3.33e-4. Told 60 s on, at 1825 s. A stall that needed the
    # limit throughout both windows and the dead times (900 s) never told it: by 2215 s, its
    # earlier window lay past the death too.
    def duty(t: float) -> float:
        return 50.0 if 1200.0 <= t < 1320.0 else 100.0

    def dies(t: float) -> float:
        return 5e-3 if t <= 1250.0 else -1e-4

    assert first_verdict(duty, dies, 80.0, dead_time=150.0) == 1825.0

    # Alive, its slope follows the duty the dead time later (half the heat in the cut, less
    # the losses): the ramp at the limit resumes where it was, and nothing is said.
    def alive(t: float) -> float:
        return 5.1e-3 * duty(t - 150.0) / 100.0 - 1e-4

    assert first_verdict(duty, alive, 80.0, dead_time=150.0, until=5400.0) is None


def test_a_ramp_under_a_power_limit_lowered_is_no_stall() -> None:
    # The ramp at 100 % (5e-3 °C/s), and the brewer lowers the limit to 40 % at 1800 s: the
    # duty stands at the new limit and the water rises at 5.1e-3·0.4 − 1e-4 = 1.94e-3 °C/s,
    # less than half the ramp and slower by more than the 1.33e-3 allowed. Its slope is no
    # element's stop: a ramp at 100 % is no measure of one at 40 %.
    balance, t, pv = HeatBalance(), 0.0, 66.0
    while t <= 5400.0:
        limit = 40.0 if t >= 1800.0 else 100.0
        judged = dataclasses.replace(bounds(80.0, dead_time=150.0), full_duty=limit)
        assert balance.period(t, pv, limit, judged) is None, t
        t += PERIOD
        pv += (5.1e-3 * limit / 100.0 - 1e-4) * PERIOD


def test_a_ramp_that_bends_as_its_losses_grow_is_a_working_element() -> None:
    # A weak tun's ramp at 100 %: its slope falls by the largest growth of the losses,
    # 1e-5 per °C it rises, from 1.5e-3 °C/s, and the mains sag at 1800 s, a step of 0.9 of
    # the 1e-3 °C/s allowed: less than half the ramp is left, but that is no stop (without
    # the allowance, a verdict).
    pv_rise = [0.0]

    def slope(t: float) -> float:
        rate = 1.5e-3 - LOSS_PER_K * pv_rise[0] - (0.9 * STALL_DROP if t > 1800.0 else 0.0)
        pv_rise[0] += rate * PERIOD
        return rate

    assert first_verdict(lambda t: 100.0, slope, 80.0) is None


def test_cold_water_poured_into_a_heat_up_is_not_a_stop() -> None:
    # 100 % throughout, the ramp 5e-3 °C/s, 10 °C of cold water at 1200 s seen through a
    # 60 s lag (the PV falling 10/60·e^(−t/60) °C/s on top): the fall is faster than any
    # loss, and the pour is told (`poured`), so nothing is judged until two windows, the
    # dead time and the settling after it; the ramp then goes on as before.
    def slope(t: float) -> float:
        after = t - 1200.0
        return 5e-3 - (10.0 / 60.0 * math.exp(-after / 60.0) if after > 0.0 else 0.0)

    assert first_verdict(lambda t: 100.0, slope, 80.0, poured_at=1200.0) is None


def test_clearing_starts_the_windows_again() -> None:
    balance, pv = HeatBalance(), 66.0
    for k in range(300):
        t = k * PERIOD
        if t == 500.0:
            balance.clear()
        found = balance.period(t, pv, 50.0, bounds(20.0))
        if found is not None:
            # 600 s of windows from the clearing at 500 s, and 60 s to confirm
            assert t == 1160.0
            assert "output at 50 %" in found.message
            return
        pv -= 1e-3 * PERIOD
    raise AssertionError("no verdict")
