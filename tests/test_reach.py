"""Where full power levels the water out, and the warning when that is short of the setpoint.

Golden values come from the physics by hand: at full power a first-order tun approaches its
ceiling c as x(t) = c − (c − x0)·e^(−t/τ), so its rise rate is (c − x)/τ, a line in x that
is zero at c; over any block of the same length the mean and the fitted slope of such an
approach keep that proportion (each block is the first one scaled by e^(−Δt/τ)), so the line
through the blocks' rates crosses zero at c exactly. The water passes half of the way to c
at τ·ln 2.
"""

from __future__ import annotations

import math
import random
from pathlib import Path

import pytest
from test_control import Inbox, status_of
from test_reload import Events

from hermsd.api.link import LoopLink
from hermsd.config import schema as config_module
from hermsd.control.reach import (
    MARGIN_C,
    MEASURE_S,
    RISE_FROM_S,
    SURE_BLOCKS,
    ReachWatch,
    Said,
    measured_rise,
    short_words,
)
from hermsd.log import reader, replay
from hermsd.runtime.assemble import assemble
from hermsd.runtime.saver import Saver
from hermsd.sim import scenario
from hermsd.sim.clock import VirtualClock
from hermsd.sim.scenario import Event, Scenario, effective_config
from hermsd.sim.tuns import TunSpec
from hermsd.sim.world import build_world

PERIOD = 5.0
TAU = 10000.0
START = 12.0


def approach(ceiling: float, t: float) -> float:
    return ceiling - (ceiling - START) * math.exp(-t / TAU)


def feed(
    watch: ReachWatch, ceiling: float, until: float, setpoint: float = 66.0
) -> list[tuple[float, Said]]:
    """Full power on an exact first-order approach to `ceiling`, no noise; what was said."""
    said = []
    t = PERIOD
    while t <= until:
        news = watch.period(t, setpoint, approach(ceiling, t), True, 100.0)
        if news is not None:
            said.append((t, news))
        t += PERIOD
    return said


def test_the_rise_through_measured_rates_names_the_ceiling_worked_by_hand() -> None:
    # 0.003, 0.002, 0.001 °C/s at 30, 35, 40 °C: 2e-4 per s less per °C, zero at 45 °C.
    rise = measured_rise([(30.0, 0.003), (35.0, 0.002), (40.0, 0.001)])
    assert rise.slope == pytest.approx(2e-4)
    assert rise.ceiling() == pytest.approx(45.0)
    # A rate that does not fall: no ceiling, never a division by zero.
    assert measured_rise([(30.0, 0.001), (40.0, 0.002)]).ceiling() == math.inf
    assert measured_rise([(30.0, 0.001)]).ceiling() == math.inf


def test_an_exact_first_order_approach_is_said_with_its_ceiling() -> None:
    watch = ReachWatch()
    said = feed(watch, 55.0, 6 * 3600.0)
    assert len(said) == 1 and said[0][1].raised
    assert watch.ceiling == pytest.approx(55.0, abs=1e-6)
    assert said[0][1].message == short_words(watch.ceiling, 66.0)
    assert "near 55.0 °C, 11.0 °C short of the setpoint 66 °C" in said[0][1].message
    # Not before half of the way to the ceiling (τ·ln 2) and SURE_BLOCKS blocks measured
    # past it; no later than the run's settling, the block in progress and those blocks.
    half = TAU * math.log(2.0)
    assert half + (SURE_BLOCKS - 1) * MEASURE_S <= said[0][0]
    assert said[0][0] <= half + RISE_FROM_S + (SURE_BLOCKS + 1) * MEASURE_S


def test_nothing_is_said_when_the_ceiling_is_above_the_setpoint_or_within_the_margin() -> None:
    assert feed(ReachWatch(), 68.0, 12 * 3600.0) == []  # reaches 66 °C, slowly
    assert feed(ReachWatch(), 66.0 - MARGIN_C + 0.01, 12 * 3600.0) == []


def test_it_clears_when_the_setpoint_comes_under_the_ceiling_and_says_so() -> None:
    watch = ReachWatch()
    t = feed(watch, 55.0, 6 * 3600.0)[0][0]
    assert watch.period(t + PERIOD, 60.0, 50.0, True, 100.0) is None  # still short of 60
    cleared = watch.period(t + 2 * PERIOD, 54.0, 50.0, True, 100.0)  # 55 ≥ 54 − 1
    assert cleared is not None and not cleared.raised and watch.ceiling is None
    assert "enough for 54 °C" in cleared.message


def test_it_clears_when_the_water_reaches_the_band() -> None:
    watch = ReachWatch()
    t = feed(watch, 55.0, 6 * 3600.0)[0][0]
    cleared = watch.period(t + PERIOD, 66.0, 65.5, False, 100.0)  # the lid went on, say
    assert cleared is not None and not cleared.raised and watch.ceiling is None


def test_another_full_power_clears_it_and_measures_afresh() -> None:
    watch = ReachWatch()
    t = feed(watch, 55.0, 6 * 3600.0)[0][0]
    cleared = watch.restart()  # control.max_output reloaded, say
    assert cleared is not None and not cleared.raised and watch.ceiling is None
    assert watch.period(t + PERIOD, 66.0, approach(55.0, t + PERIOD), True, 100.0) is None
    assert watch.restart() is None  # nothing said: nothing to clear


def test_a_paused_run_keeps_its_blocks_where_a_stop_starts_them_again() -> None:
    """A pump timer's stop pauses the mash's run: the blocks before it count, the one under
    way is dropped and the rise waits RISE_FROM_S again, so the same exact approach is said
    with the same ceiling, at most that wait and a block later; a stop that is no pause ends
    the run, which starts again from below half-way (at τ·ln 2 = 6931 s the water is half-way
    to the ceiling, and three blocks past it are sure by 8705 s without a stop)."""
    ceiling, stop = 55.0, (7800.0, 7920.0)

    def run(paused: bool) -> tuple[ReachWatch, list[float]]:
        watch, said, t = ReachWatch(), [], PERIOD
        while t <= 6 * 3600.0:
            full = not stop[0] <= t < stop[1]
            news = watch.period(t, 66.0, approach(ceiling, t), full, 100.0, paused=paused)
            if news is not None:
                said.append(t)
            t += PERIOD
        return watch, said

    plain = feed(ReachWatch(), ceiling, 6 * 3600.0)[0][0]
    assert stop[1] < plain
    watch, said = run(paused=True)
    assert len(said) == 1 and plain < said[0] <= plain + RISE_FROM_S + MEASURE_S
    assert watch.ceiling == pytest.approx(ceiling, abs=1e-6)
    _, ended = run(paused=False)  # a new run, half-way from where it starts: far later
    assert len(ended) == 1 and ended[0] > said[0] + 3600.0


def test_cold_water_in_the_run_starts_its_measurement_again() -> None:
    # The same approach, but the water drops 3 °C an hour in: the rates before it are of
    # another start, and the run is measured afresh from the drop (later than without it).
    watch, t, said = ReachWatch(), PERIOD, None
    while said is None and t < 8 * 3600.0:
        pv = approach(55.0, t) - (3.0 if t >= 3600.0 else 0.0)
        said = watch.period(t, 66.0, pv, True, 100.0)
        t += PERIOD
    without = feed(ReachWatch(), 55.0, 6 * 3600.0)[0][0]
    assert said is not None and t > without


def test_a_run_that_starts_where_the_water_levels_out_says_nothing_and_never_fails() -> None:
    """A restart at the ceiling (the daemon's, an alarm's, a setpoint dip's): the run's start
    is the top, the LM92's steps leave blocks at one mean PV, and PV may sit just under the
    start. Nothing to draw a line through; and never an exception into the loop."""
    rng = random.Random(7)
    shapes = {
        "flat on one step": lambda t: 60.0625,
        "one step up, then flat under it": lambda t: 60.125 if t < 60.0 else 60.0625,
        "creeping down": lambda t: 60.0 - t * 1e-5,
        "noise on the steps": lambda t: math.floor((60.0 + rng.gauss(0.0, 0.03)) * 16) / 16,
    }
    for name, pv in shapes.items():
        watch = ReachWatch()
        said = [watch.period(t, 66.0, pv(t), True, 100.0) for t in range(5, 12 * 3600, 5)]
        if name == "noise on the steps":
            # Noise lifts some blocks over the start: a line, and the truth named, or nothing.
            assert watch.ceiling is None or abs(watch.ceiling - 60.0) < MARGIN_C, name
            continue
        assert said.count(None) == len(said), name
        assert watch.ceiling is None, name


def test_under_a_power_limit_the_limit_is_named() -> None:
    watch, t, said = ReachWatch(), PERIOD, None
    while said is None and t < 8 * 3600.0:
        said = watch.period(t, 66.0, approach(55.0, t), True, 100.0, full_at=50.0)
        t += PERIOD
    assert said is not None and said.raised
    assert "at the power limit of 50 % (control.max_output)" in said.message
    assert "raise the limit" in said.message
    assert said.message == short_words(55.0 if watch.ceiling is None else watch.ceiling, 66.0, 50.0)


def test_a_setpoint_lowered_under_the_water_clears_as_enough_not_as_wrong() -> None:
    watch = ReachWatch()
    t = feed(watch, 55.0, 6 * 3600.0)[0][0]
    cleared = watch.period(t + PERIOD, 40.0, 54.9, False, 100.0)  # in the band of nothing
    assert cleared is not None and "enough for 40 °C" in cleared.message


# -- through the daemon ---------------------------------------------------------------------

WEAK = TunSpec("weak 30 L", 30, 922, 3.0, 30, 5, 20)
"""UA = 17.76·3·(30/90)^⅔ = 25.6 W/K: 922 W holds 20 + 922/25.6 = 56.0 °C at most; its
τ = 30·4186/25.6 = 4905 s puts half of the way there at τ·ln 2 = 3400 s."""


def test_a_weak_tun_is_said_through_the_daemon_in_the_status_and_cleared() -> None:
    day = Scenario(name=WEAK.name, duration=9000.0, plant=WEAK.plant(), setpoint=66.0)
    config = effective_config(WEAK.config(config_module.DEFAULT), day)
    clock = VirtualClock()
    world = build_world(config, clock, day.plant)
    events = Events()
    daemon = assemble(
        config, clock, world.sensor, world.outputs, recorder=events, saver=Saver(threaded=False)
    )
    daemon.listeners.append(events)
    LoopLink(daemon).attach(Inbox())
    # Bound: half-way (3400 s), the run's settling (2 dead times, 300 s at least: the model's
    # dead time is under 300 s), the block in progress and SURE_BLOCKS more.
    bound = 3400.0 + 600.0 + (SURE_BLOCKS + 1) * MEASURE_S
    daemon.run(until=bound)
    said = [m for m in events.logged() if m.startswith("full power levels")]
    assert len(said) == 1 and "short of the setpoint 66 °C" in said[0]
    ceiling = daemon.reach.ceiling
    assert ceiling is not None and abs(ceiling - 56.0) < MARGIN_C
    assert events.periods[-1].ceiling == ceiling  # logged in the period record
    assert status_of(daemon)["warnings"] == [short_words(ceiling, 66.0)]
    assert f"full power levels the water out near {ceiling:.1f} °C" in daemon.status_text()
    daemon.set_setpoint(52.0)
    daemon.run(until=bound + 2 * PERIOD)
    assert status_of(daemon)["warnings"] == []
    assert "levels the water out" not in daemon.status_text()
    cleared = f"full power levels the water out near {ceiling:.1f} °C, enough for 52 °C"
    assert cleared in events.logged()
    daemon.shutdown()


def test_replay_shows_when_it_was_said(tmp_path: Path) -> None:
    day = Scenario(name=WEAK.name, duration=6600.0, plant=WEAK.plant(), setpoint=66.0)
    scenario.run(day, WEAK.config(config_module.DEFAULT), log_dir=tmp_path)
    summary = replay.summarise(reader.load(sorted(tmp_path.glob("*.mcap"))))
    said = summary["reach"]
    assert len(said) == 1 and said[0]["message"].startswith("full power levels the water out")
    assert 3400.0 < said[0]["at_s"] < 6600.0  # past half-way (see the test above)


def test_manual_full_output_is_no_full_power_heat_up_to_judge() -> None:
    # The same weak tun, the brewer at 100 % by hand: the setpoint is not the loop's to reach,
    # so nothing is said (the auto day above says it by 6600 s).
    day = Scenario(
        name=WEAK.name,
        duration=6600.0,
        plant=WEAK.plant(),
        setpoint=66.0,
        events=(Event(0.0, "mode", "manual"), Event(0.0, "output", 100.0)),
    )
    result = scenario.run(day, WEAK.config(config_module.DEFAULT), keep_records=True)
    assert result.records[-1].mode == "manual" and result.records[-1].applied == 100.0
    assert all(r.ceiling is None for r in result.records)
