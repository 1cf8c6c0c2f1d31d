"""The run metrics on hand-made samples, each figure worked out by hand."""

from __future__ import annotations

import pytest

from hermsd.metrics import Sample, compute, report


def samples(setpoints: list[float], temps: list[float], step: float = 10.0) -> list[Sample]:
    pairs = zip(setpoints, temps, strict=True)
    return [Sample(i * step, sp, t, 0.0) for i, (sp, t) in enumerate(pairs)]


def test_time_in_band_overshoots_and_iae_from_the_first_sample_in_band() -> None:
    temps = [64.0, 65.6, 66.2, 66.7, 66.3, 65.4, 66.0, 66.8, 66.1]
    m = compute(samples([66.0] * len(temps), temps), [], 90.0)
    # In band from 65.6 (t = 10) on: 8 samples of 10 s, of which 66.7, 65.4 and 66.8 are out.
    assert m.since_band_s == 80.0
    assert m.in_band_s == 50.0
    assert report(m)["in_band_pct"] == 62.5
    # Above the band twice (66.7, then 66.8 after coming back); the larger is 0.8 °C.
    assert m.overshoots == 2
    assert m.overshoot_c == pytest.approx(0.8)
    # IAE from the first sample at or above the setpoint (66.2):
    # (0.2 + 0.7 + 0.3 + 0.6 + 0.0 + 0.8 + 0.1)·10 s.
    assert m.iae == pytest.approx(27.0)


def test_cooling_to_a_lower_setpoint_is_no_overshoot() -> None:
    setpoints = [66.0, 66.0, 60.0, 60.0, 60.0, 60.0, 60.0]
    temps = [66.0, 66.1, 65.0, 62.0, 59.9, 60.9, 60.2]
    m = compute(samples(setpoints, temps), [20.0], 70.0)
    # 65 and 62 are above the new setpoint on the way down; only 60.9, after 59.9, counts.
    assert m.overshoots == 1
    assert m.overshoot_c == pytest.approx(0.9)


def test_heatup_and_upset_overshoots_are_told_apart() -> None:
    # Heat-up to 66.2 (0.2 over), water at t = 40 s: the sensor still shows 66.1 (the old
    # water), dips to 63.0, comes back 0.3 over (66.3), then holds.
    temps = [60.0, 65.8, 66.2, 66.0, 66.1, 64.0, 63.0, 65.0, 66.3, 66.1, 66.0]
    m = compute(samples([66.0] * len(temps), temps), [40.0], 110.0)
    assert m.heatup_overshoot_c == pytest.approx(0.2)
    assert m.upset_overshoot_c == pytest.approx(0.3)
    assert m.overshoot_c == pytest.approx(0.3)
    assert compute(samples([66.0] * 3, [60.0, 66.4, 66.0]), [], 30.0).upset_overshoot_c is None


def test_last_hour_peak_to_peak_needs_the_whole_last_hour_held() -> None:
    # One sample a minute for 2 h, in band from the start: the last hour swings 65.9 .. 66.15.
    temps = [66.0] * 60 + [65.9, 66.15] * 30
    m = compute(samples([66.0] * 120, temps, step=60.0), [], 7200.0)
    assert m.last_hour_p2p_c == pytest.approx(0.25)
    # Out of the band 40 min before the end: the hold does not cover the last hour.
    temps[-40] = 67.0
    m = compute(samples([66.0] * 120, temps, step=60.0), [], 7200.0)
    assert m.last_hour_p2p_c is None


def test_held_in_band_counts_from_first_entering_and_leaves_out_the_recovery() -> None:
    # 10 s samples: in band at t = 10, out above at t = 30 (66.6), water at t = 50 takes it
    # out until t = 80; then in. Counted: t = 10..40 and 80..100, 60 s of which 10 s out.
    temps = [64.0, 65.6, 66.3, 66.6, 66.2, 66.0, 64.0, 65.0, 65.7, 66.0]
    m = compute(samples([66.0] * len(temps), temps), [50.0], 100.0)
    assert m.held_in_band_pct == pytest.approx(100.0 * 50.0 / 60.0)
    assert report(m)["held_in_band_pct"] == pytest.approx(83.33)


def test_settle_is_the_band_entry_interpolated_between_the_samples_that_straddle_it() -> None:
    # A ramp of 0.012 °C/s from 60 °C to 66 °C, sampled every 5 s, crosses 65.5 °C at
    # 5.5 / 0.012 = 458.33 s, as the physical minimum finds it; the first sample in the band
    # (460 s) would read it 1.67 s late.
    ramp = [Sample(5.0 * i, 66.0, min(66.0, 60.0 + 0.06 * i), 100.0) for i in range(120)]
    assert compute(ramp, [], 600.0).settle_s == pytest.approx(458.33, abs=0.01)
    # In band at t = 10 (65.6), out above at t = 20 (66.7), back in at t = 30 (66.3): in for
    # good from where the line 66.7 → 66.3 meets 66.5, halfway, at t = 25.
    temps = [64.0, 65.6, 66.7, 66.3, 66.0, 66.1]
    assert compute(samples([66.0] * len(temps), temps), [], 60.0).settle_s == pytest.approx(25.0)
    # Cooling to a lower setpoint enters by the upper edge: 60.9 → 60.3 meets 60.5 two thirds
    # of the way, at t = 26.67.
    m = compute(samples([60.0] * 5, [66.0, 62.0, 60.9, 60.3, 60.1]), [], 50.0)
    assert m.settle_s == pytest.approx(26.667, abs=0.001)


def test_recovery_is_the_band_entry_interpolated_and_never_before_the_water() -> None:
    # Water at t = 40: the sensor still shows 66.0, dips to 65.0, comes back through 65.4
    # (t = 70) and 65.9 (t = 80); the line meets 65.5 a fifth of the way, at t = 72: 32 s.
    temps = [66.0, 66.0, 66.0, 66.0, 66.0, 65.2, 65.0, 65.4, 65.9, 66.0, 66.0]
    m = compute(samples([66.0] * len(temps), temps), [40.0], 110.0)
    assert m.recovery_s == pytest.approx(32.0)
    assert report(m)["recovery_s"] == 32.0
    # The hold, which counts samples, resumes at the first sample back in: 0..40, 80..110 s.
    assert m.hold_s == pytest.approx(40.0 + 30.0)
    # An upset at t = 45 between 65.4 (t = 40) and 65.9 (t = 50): the line meets 65.5 at
    # t = 42, before the upset, so it is back at once: recovery 0 s.
    temps = [64.0, 64.5, 65.0, 65.2, 65.4, 65.9, 66.0]
    m = compute(samples([66.0] * len(temps), temps), [45.0], 70.0)
    assert m.recovery_s == 0.0


def test_edges_are_counted_in_whole_periods_of_the_hold() -> None:
    # A planner at its limit: one edge in every 5 s window (pulses alternate ends), 720/h.
    # The water enters the band for good at 2.5 s (interpolated between 67 °C at 0 s and
    # 66 °C at 5 s), so the hold runs from 2.5 s to the end at 3603 s; counted to its ends
    # it holds the edges at 2.5 s and 3602.5 s, 721 in 3600.5 s: 720.9/h. In the whole
    # periods from 5 s to 3600 s: 719 edges in 3595 s, 720.0/h.
    samples = [Sample(5.0 * i, 66.0, 66.0, 50.0) for i in range(721)]
    samples[0] = Sample(0.0, 66.0, 67.0, 50.0)
    edges = [2.5 + 5.0 * k for k in range(721)]
    metrics = compute(samples, [], 3603.0, edges)
    assert metrics.edges_per_hour == pytest.approx(720.0)
