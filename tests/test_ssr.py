"""The time-proportional planner and the output guards."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hermsd.hardware.ssr import GuardedSwitch, TimeProportionalPlanner, cut, relay_board_frame
from hermsd.sim.clock import VirtualClock

HALF_CYCLE_50HZ = 0.01  # s: one half-cycle of 50 Hz mains


class RecordingSwitch:
    def __init__(self) -> None:
        self.calls: list[bool] = []
        self.closed = False

    def set(self, on: bool) -> None:
        self.calls.append(on)

    def close(self) -> None:
        self.closed = True


def test_on_times_are_whole_half_cycles() -> None:
    planner = TimeProportionalPlanner(5.0, 50)
    for k in range(200):
        plan = planner.plan(5.0 * k, 27.3)
        slots = plan.on_time / HALF_CYCLE_50HZ
        assert slots == pytest.approx(round(slots), abs=1e-9)
        # The window has 500 half-cycles; applied is exactly the on-time's share.
        assert plan.applied == pytest.approx(round(slots) / 500 * 100)


def test_sixty_hertz_grid() -> None:
    planner = TimeProportionalPlanner(5.0, 60)
    plan = planner.plan(0.0, 50.0)
    # 5 s of 60 Hz mains is 600 half-cycles of 1/120 s; half of them is 2.5 s exactly.
    assert plan.on_time == pytest.approx(2.5)


def test_average_duty_is_exact_over_many_windows() -> None:
    # 27.33 % of 500 half-cycles is 136.65: no single window can deliver it, the carry must.
    planner = TimeProportionalPlanner(5.0, 50, min_on=0.05, min_off=0.05)
    plans = [planner.plan(5.0 * k, 27.33) for k in range(1000)]
    delivered = sum(p.on_time for p in plans)
    assert delivered / (5.0 * 1000) * 100 == pytest.approx(27.33, abs=0.01 / 1000 * 100)


def test_minimum_on_and_off_times_are_respected_and_carried() -> None:
    planner = TimeProportionalPlanner(5.0, 50, min_on=0.5, min_off=0.5)
    # 2 % of 5 s is 0.1 s, below the 0.5 s minimum: most windows deliver nothing, and every
    # fifth delivers 0.5 s, so the average is still 2 %.
    plans = [planner.plan(5.0 * k, 2.0) for k in range(100)]
    for plan in plans:
        assert plan.on_time == 0 or plan.on_time >= 0.5 - 1e-9
    assert sum(p.on_time for p in plans) == pytest.approx(0.02 * 500, abs=0.5)
    high = [planner.plan(5.0 * k, 98.0) for k in range(100)]
    for plan in high:
        off = plan.length - plan.on_time
        assert off == 0 or off >= 0.5 - 1e-9
    assert sum(p.on_time for p in high) == pytest.approx(0.98 * 500, abs=0.5)


@pytest.mark.parametrize("duty", [0.0, 100.0])
def test_full_and_zero_duty_have_no_edges_inside_the_window(duty: float) -> None:
    planner = TimeProportionalPlanner(5.0, 50)
    for k in range(10):
        plan = planner.plan(5.0 * k, duty)
        start, end = 5.0 * k, 5.0 * k + 5.0
        if duty == 0.0:
            assert plan.on_time == 0 and not plan.is_on(start)
        else:
            assert (plan.on_at, plan.off_at) == (start, end)
        assert plan.applied == duty


def test_pulses_of_neighbouring_windows_join() -> None:
    planner = TimeProportionalPlanner(5.0, 50)
    first, second = planner.plan(0.0, 30.0), planner.plan(5.0, 30.0)
    # The first window's pulse ends at its end, the second's starts at its start: one pulse.
    assert first.off_at == 5.0 and second.on_at == 5.0


def test_a_band_lets_runs_span_windows_at_a_low_duty() -> None:
    """20 % of 500 half-cycles is 100 a window; a band of 1.25 s is 125. By hand: off while
    the debt stays ≤ 125 (100 owed), then at the second window's end all but the band
    (200 − 125 = 75 half-cycles), then from the next window's start until 125 is given ahead
    (225 + 125 = 350); then two windows off (−25, 75 owed), and 175 − 125 = 50 at the third's
    end, and 350 again: a 4-s pulse every 20 s, two edges in four windows instead of four."""
    planner = TimeProportionalPlanner(5.0, 50, band=1.25)
    plans = [planner.plan(5.0 * k, 20.0) for k in range(11)]
    on = [round(p.on_time / HALF_CYCLE_50HZ) for p in plans]
    assert on == [0, 75, 350, 0, 0, 50, 350, 0, 0, 50, 350]
    assert (plans[1].off_at, plans[2].on_at) == (10.0, 10.0)  # one pulse across the boundary
    assert sum(on) == 11 * 100 + 125  # all asked, and the band given ahead as a run ends


def test_a_band_mirrors_at_a_high_duty() -> None:
    """90 %: 450 a window. From on with nothing owed, whole windows while a window leaves
    less than 125 given ahead (−50, −100), then 475 and off; from off, the pulse at the end
    gives all but the band (325 − 125 = 200); on for five whole windows (125 − 50 each,
    down to −125), then 450 and 200 again: a 3.5-s gap every 35 s."""
    planner = TimeProportionalPlanner(5.0, 50, band=1.25)
    planner.plan(0.0, 100.0)  # the heat-up: on, nothing owed
    on = [round(planner.plan(5.0 * k, 90.0).on_time / HALF_CYCLE_50HZ) for k in range(1, 12)]
    assert on == [500, 500, 475, 200, 500, 500, 500, 500, 500, 450, 200]


@settings(max_examples=100, deadline=None)
@given(duty=st.floats(min_value=0.5, max_value=99.5), band=st.floats(min_value=0, max_value=5))
def test_a_band_keeps_the_mean_and_one_edge_a_window(duty: float, band: float) -> None:
    """Whatever the band, the heat given is what was asked to within the band and a window,
    and no window switches the SSR twice."""
    planner = TimeProportionalPlanner(5.0, 50, min_on=0.02, min_off=0.02, band=band)
    plans = [planner.plan(5.0 * k, duty) for k in range(400)]
    given_s = sum(p.on_time for p in plans)
    assert abs(given_s - duty / 100 * 5.0 * 400) <= band + 5.0 + 1e-6
    for p in plans:
        start, end = p.start, p.start + p.length
        assert p.on_time == 0 or p.on_at == start or p.off_at == end


def test_a_band_forgets_its_carry_at_full_or_no_power() -> None:
    """At 0 or 100 % the band's carry is forgotten, not deferred: a heat-up's first window
    tells the controller 100 %, the step it measures the tun by."""
    planner = TimeProportionalPlanner(5.0, 50, band=1.25)
    carried = [planner.plan(5.0 * k, 20.0).deferred for k in range(2)]
    assert carried == [1.0, 0.25]  # 100 owed, then 200 − 75 = 125: half-cycles of 10 ms
    full = planner.plan(10.0, 100.0)
    assert (full.deferred, full.applied) == (0.0, 100.0)
    assert planner.plan(15.0, 0.0).deferred == 0.0


def test_a_band_wider_than_the_window_is_refused() -> None:
    with pytest.raises(ValueError, match="band"):
        TimeProportionalPlanner(5.0, 50, band=5.5)


def test_cut_reports_what_was_delivered() -> None:
    planner = TimeProportionalPlanner(5.0, 50)
    planner.plan(0.0, 50.0)  # skip to an odd window: on-time at the start
    plan = planner.plan(5.0, 50.0)
    assert (plan.on_at, plan.off_at) == (5.0, 7.5)
    half = cut(plan, 6.0)
    assert half.off_at == 6.0 and half.applied == pytest.approx(20.0)
    assert cut(plan, 9.0) == plan
    before = cut(planner.plan(10.0, 50.0), 11.0)  # even window: pulse at the end, not begun
    assert before.on_time == 0.0 and before.applied == 0.0


@settings(max_examples=200, deadline=None)
@given(duty=st.floats(min_value=0, max_value=100), window=st.sampled_from([1.0, 5.0, 10.0]))
def test_plan_stays_inside_its_window(duty: float, window: float) -> None:
    planner = TimeProportionalPlanner(window, 50, min_on=0.02, min_off=0.02)
    for k in range(5):
        plan = planner.plan(window * k, duty)
        assert window * k <= plan.on_at <= plan.off_at <= window * (k + 1) + 1e-9
        assert 0.0 <= plan.applied <= 100.0


def test_bad_planner_arguments_are_refused() -> None:
    with pytest.raises(ValueError, match="mains_hz"):
        TimeProportionalPlanner(5.0, 55)
    with pytest.raises(ValueError, match="min_on"):
        TimeProportionalPlanner(1.0, 50, min_on=0.6, min_off=0.6)
    with pytest.raises(ValueError, match="duty"):
        TimeProportionalPlanner(5.0).plan(0.0, 101.0)


def test_guarded_switch_starts_off_and_counts_edges() -> None:
    clock = VirtualClock()
    inner = RecordingSwitch()
    guard = GuardedSwitch(inner, clock.monotonic, timeout=10.0)
    assert inner.calls == [False]
    guard.set(True)
    guard.set(True)
    guard.set(False)
    assert inner.calls == [False, True, False]
    assert guard.edges == 2


def test_a_switch_that_can_lose_a_command_is_told_off_again_while_off() -> None:
    class LossyLine(RecordingSwitch):
        repeat_off_s = 10.0  # as a relay board says of its frames

    clock = VirtualClock()
    inner = LossyLine()
    guard = GuardedSwitch(inner, clock.monotonic, timeout=30.0)
    guard.set(True)
    clock.advance(5.0)
    guard.set(False)  # this frame is lost on the way: the relay stays closed
    for _ in range(4):  # the loop refreshes its off every 5 s
        clock.advance(5.0)
        guard.set(False)
    assert inner.calls == [False, True, False, False, False]  # off again at 15 s and 25 s
    assert guard.edges == 2  # said again is no edge
    plain = RecordingSwitch()  # a GPIO or RTS level holds itself: nothing repeated
    held = GuardedSwitch(plain, clock.monotonic, timeout=30.0)
    clock.advance(60.0)
    held.set(False)
    assert plain.calls == [False]


def test_dead_man_turns_the_output_off_after_two_windows_of_silence() -> None:
    clock = VirtualClock()
    inner = RecordingSwitch()
    guard = GuardedSwitch(inner, clock.monotonic, timeout=10.0)
    guard.set(True)
    clock.advance(9.9)
    assert not guard.check() and guard.state
    guard.set(True)  # a refresh
    clock.advance(10.0)
    assert not guard.check()
    clock.advance(0.1)
    assert guard.check()
    assert inner.calls[-1] is False and not guard.state and guard.tripped == 1


def test_close_turns_off_even_when_releasing_fails() -> None:
    class Failing(RecordingSwitch):
        def close(self) -> None:
            raise OSError(5, "gone")

    clock = VirtualClock()
    inner = Failing()
    guard = GuardedSwitch(inner, clock.monotonic, timeout=10.0)
    guard.set(True)
    with pytest.raises(OSError, match="gone"):
        guard.close()
    assert inner.calls[-1] is False


def test_relay_board_frames_match_the_board_protocol() -> None:
    # The boards' documented frames for channel 1: A0 01 01 A2 (on) and A0 01 00 A1 (off).
    assert relay_board_frame(1, True) == bytes.fromhex("A00101A2")
    assert relay_board_frame(1, False) == bytes.fromhex("A00100A1")
    assert relay_board_frame(2, True) == bytes.fromhex("A00201A3")
    with pytest.raises(ValueError, match="channel"):
        relay_board_frame(0, True)


def test_a_window_after_one_fully_on_starts_on_and_spends_one_edge() -> None:
    # 50 %, then 100 % (cold water), then 98.8 %: the line is on as the third window opens,
    # so its pulse starts it and only its end is an edge. A fixed alternation put this pulse
    # at the window's end: off at 10.0 s and on again 0.06 s later, two edges.
    planner = TimeProportionalPlanner(5.0, 50, min_on=0.02, min_off=0.02)
    planner.plan(0.0, 50.0)  # the pulse ends the window: on at 2.5 s until 5.0 s
    full = planner.plan(5.0, 100.0)
    assert (full.on_at, full.off_at) == (5.0, 10.0)
    after = planner.plan(10.0, 98.8)
    assert after.on_at == 10.0  # on since 5.0 s: no edge at 10.0 s
    assert after.off_at == pytest.approx(10.0 + 0.988 * 5.0, abs=0.01)
    following = planner.plan(15.0, 98.8)
    assert following.off_at == 20.0  # off since the last one's end: its pulse ends this one


def test_a_gap_leaves_a_full_window_off_for_the_minimum_off_time_at_one_end() -> None:
    """A current input's proof that the SSR opens: 100 % with a gap is 500 − 19 half-cycles
    on (96.2 %), off for the last 0.19 s after a window that ended on, and the full window
    after it starts on at its start (two edges in all); a band's run fully on at under 100 %
    is cut the same, what it withholds owed; no minimum off time, no gap to leave."""
    planner = TimeProportionalPlanner(5.0, 50, min_on=0.19, min_off=0.19)
    planner.plan(0.0, 100.0)
    proof = planner.plan(5.0, 100.0, gap=True)
    assert (proof.on_at, proof.off_at, proof.applied) == (5.0, pytest.approx(9.81), 96.2)
    after = planner.plan(10.0, 100.0)
    assert (after.on_at, after.off_at) == (10.0, 15.0)
    banded = TimeProportionalPlanner(5.0, 50, min_on=0.19, min_off=0.19, band=1.0)
    banded.plan(0.0, 100.0)
    run = banded.plan(5.0, 99.0, gap=True)  # 495 owed, plus the band: a full window asked
    assert run.on_time == pytest.approx(4.81)
    assert run.deferred == pytest.approx(0.14)  # 495 − 481 half-cycles owed
    plain = TimeProportionalPlanner(5.0, 50)
    plain.plan(0.0, 100.0)
    assert plain.plan(5.0, 100.0, gap=True).applied == 100.0


def test_no_window_spends_more_than_one_edge_through_full_and_empty_windows() -> None:
    planner = TimeProportionalPlanner(5.0, 50, min_on=0.02, min_off=0.02)
    duties = [40.0, 60.0, 100.0, 100.0, 70.0, 30.0, 0.0, 0.0, 50.0, 50.0, 100.0, 20.0]
    line = False
    per_window = []
    for k, duty in enumerate(duties):
        plan = planner.plan(5.0 * k, duty)
        edges = 0
        for i in range(5000):  # the line as the plan drives it, every millisecond
            state = plan.is_on(5.0 * k + 0.001 * i)
            edges += state != line
            line = state
        per_window.append(edges)
    # By hand: on (ends on), off, on (full, from off), none, off, on, off (empty, from on),
    # none, on, off, on (full, from off), off.
    assert per_window == [1, 1, 1, 0, 1, 1, 1, 0, 1, 1, 1, 1]


def _water_swing(planner: TimeProportionalPlanner, duty: float, rate: float) -> float:
    """The water's highest less its lowest over 400 windows at `duty`, heated at `rate` °C/s
    while the SSR is on and losing the mean (rate·duty) all along (linear between edges)."""
    water, seen = 0.0, []
    for k in range(400):
        plan = planner.plan(5.0 * k, duty)
        loss = rate * duty / 100.0
        for span, on in (
            (plan.on_at - plan.start, False),
            (plan.off_at - plan.on_at, True),
            (plan.start + plan.length - plan.off_at, False),
        ):
            water += (rate if on else 0.0) * span - loss * span
            seen.append(water)
    steady = seen[60:]  # past the first windows, where the carry starts from nothing
    return max(steady) - min(steady)


@pytest.mark.parametrize("band", [0.0, 1.25, 5.0])
@pytest.mark.parametrize("duty", [5.0, 20.0, 37.0, 50.0, 63.0, 90.0])
def test_the_water_swings_no_more_than_the_planner_says(duty: float, band: float) -> None:
    """Integrated edge by edge, the water never swings more than `swing` says: the band's
    2·r·B and a joined pulse's r·W/2 at its worst."""
    planner = TimeProportionalPlanner(5.0, 50, min_on=0.02, min_off=0.02, band=band)
    assert _water_swing(planner, duty, 0.01) <= planner.swing(0.01) + 1e-9


def test_without_a_band_the_swing_at_half_power_is_a_joined_pulse() -> None:
    """At 50 % two windows' halves join: 5 s on, 5 s off, the water up r·(1 − ½)·5 s =
    0.01·2.5 = 0.025 °C, r·W/2 itself."""
    planner = TimeProportionalPlanner(5.0, 50)
    assert planner.swing(0.01) == pytest.approx(0.025, abs=1e-12)
    assert _water_swing(planner, 50.0, 0.01) == pytest.approx(0.025, abs=1e-9)


def test_a_pulse_at_once_starts_its_window_and_the_next_joins_the_one_after() -> None:
    """30 % after a window that ended off: at once, on 0–1.5 s (not 3.5–5 s); that window
    then ends off, so the next one's pulse ends it (8.5–10 s), joining the one after's."""
    planner = TimeProportionalPlanner(5.0, 50)
    first = planner.plan(0.0, 30.0, at_once=True)
    assert (first.on_at, first.off_at, first.applied) == (0.0, 1.5, 30.0)
    second, third = planner.plan(5.0, 30.0), planner.plan(10.0, 30.0)
    assert (second.on_at, second.off_at) == (8.5, 10.0)
    assert (third.on_at, third.off_at) == (10.0, 11.5)
    plain = TimeProportionalPlanner(5.0, 50).plan(0.0, 30.0)
    assert (plain.on_at, plain.off_at) == (3.5, 5.0)
