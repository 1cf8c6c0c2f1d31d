"""Deadlines on an injected clock: no drift, skip-ahead after overruns, wall clock ignored."""

from __future__ import annotations

import pytest

from hermsd.runtime.scheduler import LatenessStats, Scheduler, percentile
from hermsd.sim.clock import VirtualClock


def test_deadlines_are_origin_plus_k_periods_without_drift() -> None:
    clock = VirtualClock(start=1000.0)
    sched = Scheduler(clock)
    seen: list[float] = []
    # 0.1 is not exact in binary: adding it up 100,000 times drifts by ~1e-9 s per step.
    sched.every("tick", 0.1, lambda deadline, now: seen.append(deadline), origin=1000.0)
    sched.run(until=1000.0 + 10_000.0)
    assert len(seen) == 100_000
    for k in (0, 1, 99_999):
        assert seen[k] == 1000.0 + k * 0.1


def test_overrun_skips_ahead_without_a_burst() -> None:
    clock = VirtualClock()
    sched = Scheduler(clock)
    seen: list[float] = []

    def work(deadline: float, now: float) -> None:
        seen.append(now)
        if len(seen) == 3:
            clock.advance(12.0)  # a stall of more than two periods

    task = sched.every("control", 5.0, work, origin=0.0)
    sched.run(until=40.0)
    # Run at 0, 5, 10 (stalls to 22); 15 and 20 are skipped, the next is on the grid at 25.
    assert seen == [0.0, 5.0, 10.0, 25.0, 30.0, 35.0]
    assert task.overruns == 2
    assert task.lateness.worst == 0.0  # every run started on time; the stall was inside one


def test_lateness_is_measured_against_the_deadline() -> None:
    clock = VirtualClock()
    sched = Scheduler(clock)
    task = sched.every("control", 5.0, lambda d, n: None, origin=0.0)
    sched.every("slow", 7.0, lambda d, n: clock.advance(0.5), origin=3.0, priority=-1)
    sched.run(until=100.0)
    assert task.lateness.worst == pytest.approx(0.5)


def test_timers_fire_at_their_exact_time_and_can_be_cancelled() -> None:
    clock = VirtualClock()
    sched = Scheduler(clock)
    fired: list[tuple[float, float]] = []
    sched.at(1.2345, lambda when, now: fired.append((when, now)))
    cancelled = sched.at(2.0, lambda when, now: fired.append((when, now)))
    cancelled.cancel()
    sched.run(until=10.0)
    assert fired == [(1.2345, 1.2345)]


def test_equal_times_run_in_priority_order() -> None:
    clock = VirtualClock()
    sched = Scheduler(clock)
    order: list[str] = []
    sched.every("window", 5.0, lambda d, n: order.append("window"), origin=0.0, priority=2)
    sched.every("control", 5.0, lambda d, n: order.append("control"), origin=0.0, priority=1)
    sched.at(0.0, lambda d, n: order.append("edge"))
    sched.run(until=1.0)
    assert order == ["control", "window", "edge"]


def test_wall_clock_jumps_move_nothing() -> None:
    class JumpingClock(VirtualClock):
        """Wall time jumps a day forward and an hour back (NTP on a Pi without an RTC)."""

        def wall_ns(self) -> int:
            jump = 86_400 if self.monotonic() > 10 else 0
            jump -= 3600 if self.monotonic() > 20 else 0
            return super().wall_ns() + jump * 1_000_000_000

    plain, jumping = VirtualClock(), JumpingClock()
    runs: dict[str, list[float]] = {"plain": [], "jumping": []}
    for name, clock in (("plain", plain), ("jumping", jumping)):
        sched = Scheduler(clock)
        sched.every("c", 5.0, lambda d, n, name=name: runs[name].append(n), origin=0.0)
        sched.run(until=60.0)
    assert runs["plain"] == runs["jumping"] == [5.0 * k for k in range(12)]


def test_stop_ends_the_run() -> None:
    clock = VirtualClock()
    sched = Scheduler(clock)
    count = []

    def work(deadline: float, now: float) -> None:
        count.append(now)
        if len(count) == 4:
            sched.stop()

    sched.every("c", 1.0, work, origin=0.0)
    sched.run()
    assert count == [0.0, 1.0, 2.0, 3.0]


def test_percentiles_are_nearest_rank() -> None:
    # Nearest rank: p50 of 1..100 is the 50th value, p99 the 99th.
    values = [float(v) for v in range(1, 101)]
    assert percentile(values, 50) == 50.0
    assert percentile(values, 99) == 99.0
    stats = LatenessStats()
    assert stats.summary() == (0.0, 0.0, 0.0)
    for v in reversed(values):
        stats.add(v / 1000)
    assert stats.summary() == (0.05, 0.099, 0.1)
