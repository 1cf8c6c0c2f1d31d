"""How well a run held its setpoint: one set of definitions for the simulator and for replay.

Samples are one per control period: time, setpoint, temperature, output. Each sample stands
for the time up to the next one (the last for as long as the one before it). `disturbances`
are the times the tun was upset from outside (water added, setpoint changed, a fault
injected): "settled" means in band for good before the first of them, "recovered" means back
in band for good after the last of them. Time in band counts from the first sample in the
band: the heat-up before it is no failure to hold.

When the temperature entered the band for good (settle, recovery) is interpolated linearly
between the last sample outside the band and the first inside it: the physical minimums
these times are compared with are crossing times too (`hermsd.sim.scenario.time_to_band`
interpolates on a 1 s grid), and the temperature is continuous, so the interpolation errs
only by the curve's bend within one period, where the first sample inside reads the entry
up to a whole period late. The hold, which counts samples, starts at that first sample.
"""

from __future__ import annotations

import bisect
import itertools
import math
from dataclasses import dataclass
from typing import Any

BAND = 0.5  # °C either side of the setpoint that counts as holding it

# What each report measures on, said in it: the two differ by the LM92's 0.0625 °C steps and
# by the period's averaging, so the same day gives `simulate` and `replay` other overshoots.
SIMULATED_TEMPERATURE = (
    "the simulated sensor's exact temperature at each period (no noise, no LM92 steps; "
    "pv_overshoot_c: on the daemon's PV, as replay measures it)"
)
LOGGED_TEMPERATURE = "the logged PV (the mean of each period's LM92 readings)"


@dataclass(frozen=True, slots=True)
class Sample:
    t: float
    setpoint: float
    temp: float
    output: float


@dataclass(frozen=True, slots=True)
class Metrics:
    overshoot_c: float
    overshoots: int  # rises above the band after reaching the setpoint from below
    settle_s: float | None
    recovery_s: float | None
    in_band_fraction: float | None  # of the samples while holding (see _hold_intervals)
    in_band_s: float  # time in the band, from the first sample in it
    since_band_s: float  # time from the first sample in the band to the end
    iae: float
    max_output_jump: float
    hold_s: float
    max_temp_c: float
    mean_output: float
    edges_per_hour: float | None
    heatup_overshoot_c: float = 0.0  # above the setpoint before the first disturbance
    upset_overshoot_c: float | None = None  # after the last disturbance's trough
    last_hour_p2p_c: float | None = None  # peak to peak over the last hour, if all of it held
    held_in_band_pct: float | None = None  # from first in band, recoveries from upsets aside


def in_band_for_good(samples: list[Sample], start: float, end: float) -> float | None:
    """The time from which every sample in [start, end) is within the band; None if never."""
    entered: float | None = None
    for s in samples:
        if s.t < start:
            continue
        if s.t >= end:
            break
        if abs(s.temp - s.setpoint) <= BAND:
            if entered is None:
                entered = s.t
        else:
            entered = None
    return entered


def entered_band(samples: list[Sample], start: float, end: float) -> float | None:
    """When the temperature entered the band for good in [start, end): between the sample
    before `in_band_for_good`'s and it, interpolated (see the module's note)."""
    first = in_band_for_good(samples, start, end)
    if first is None:
        return None
    index = bisect.bisect_left(samples, first, key=lambda s: s.t)
    return _band_entry(samples[index - 1] if index else None, samples[index], start)


def _band_entry(outside: Sample | None, inside: Sample, start: float) -> float:
    """When the temperature crossed into the band between `outside` (the sample before
    `inside`, if any) and `inside`: where the straight line between them meets the band's
    edge it came in by. In the band already before `start` (or nothing before): `start`,
    or the first sample if it is later."""
    if outside is None:
        return inside.t
    before = outside.temp - outside.setpoint
    if abs(before) <= BAND:
        return start
    after = inside.temp - inside.setpoint
    edge = -BAND if before < 0 else BAND
    return max(start, outside.t + (inside.t - outside.t) * (edge - before) / (after - before))


def compute(
    samples: list[Sample],
    disturbances: list[float],
    end: float,
    edges: list[float] | None = None,
) -> Metrics:
    """Metrics of a run from t = samples[0].t to `end`; `edges` are the SSR's switching times."""
    if not samples:
        return Metrics(0.0, 0, None, None, None, 0.0, 0.0, 0.0, 0.0, 0.0, float("nan"), 0.0, None)
    t0 = samples[0].t
    dts = [b.t - a.t for a, b in itertools.pairwise(samples)]
    dts.append(dts[-1] if dts else 0.0)
    first_disturbance = min(disturbances, default=end)
    settled_at = in_band_for_good(samples, t0, first_disturbance)
    last = max(disturbances, default=None)
    recovered_at = in_band_for_good(samples, last, end) if last is not None else None
    settle_s = _since(entered_band(samples, t0, first_disturbance), t0)
    recovery_s = None if last is None else _since(entered_band(samples, last, end), last)

    # Overshoot counts only once the temperature has been at or below the setpoint of its
    # segment: cooling down after a setpoint step down is not overshoot.
    overshoot = 0.0
    overshoots = 0
    iae = 0.0
    in_band_s = since_band_s = 0.0
    reached = band_reached = above = armed = False
    segment_sp: float | None = None
    for s, dt in zip(samples, dts, strict=True):
        if s.setpoint != segment_sp:
            segment_sp, armed = s.setpoint, False
        error = s.temp - s.setpoint
        armed = armed or error <= 0
        if armed:
            overshoot = max(overshoot, error)
            overshoots += error > BAND and not above
        above = error > BAND
        reached = reached or error >= 0
        if reached:
            iae += abs(error) * dt
        inside = abs(error) <= BAND
        band_reached = band_reached or inside
        if band_reached:
            since_band_s += dt
            in_band_s += dt if inside else 0.0

    hold = _hold_intervals(samples, settled_at, disturbances, recovered_at, end)
    in_hold = [i for i, s in enumerate(samples) if _inside(s.t, hold)]
    hold_s = sum(b - a for a, b in hold)
    in_band = (
        sum(1 for i in in_hold if abs(samples[i].temp - samples[i].setpoint) <= BAND) / len(in_hold)
        if in_hold
        else None
    )
    jumps = [
        abs(samples[i].output - samples[i - 1].output)
        for i in in_hold
        if i > 0 and _inside(samples[i - 1].t, hold)
    ]
    last_hour = [samples[i].temp for i in in_hold if samples[i].t >= end - 3600.0]
    first_in = next((s.t for s in samples if abs(s.temp - s.setpoint) <= BAND), None)
    holding = _hold_intervals(samples, first_in, disturbances, None, end)
    held = [(s, dt) for s, dt in zip(samples, dts, strict=True) if _inside(s.t, holding)]
    held_s = sum(dt for _, dt in held)
    held_in_s = sum(dt for s, dt in held if abs(s.temp - s.setpoint) <= BAND)
    held_last_hour = bool(hold) and hold[-1][0] <= end - 3600.0 and hold[-1][1] >= end
    return Metrics(
        overshoot_c=overshoot,
        overshoots=overshoots,
        settle_s=settle_s,
        recovery_s=recovery_s,
        in_band_fraction=in_band,
        in_band_s=in_band_s,
        since_band_s=since_band_s,
        iae=iae,
        max_output_jump=max(jumps, default=0.0),
        hold_s=hold_s,
        max_temp_c=max(s.temp for s in samples),
        mean_output=sum(s.output * dt for s, dt in zip(samples, dts, strict=True))
        / max(sum(dts), 1e-9),
        edges_per_hour=None if edges is None else _edges_per_hour(edges, samples, hold),
        heatup_overshoot_c=_overshoot([s for s in samples if s.t < first_disturbance]),
        upset_overshoot_c=_upset_overshoot(samples, last),
        last_hour_p2p_c=max(last_hour) - min(last_hour) if held_last_hour else None,
        held_in_band_pct=100.0 * held_in_s / held_s if held_s > 0 else None,
    )


def _since(t: float | None, start: float) -> float | None:
    return None if t is None else t - start


def _overshoot(samples: list[Sample]) -> float:
    """How far above its setpoint the temperature rose, once it had been at or below it."""
    overshoot = 0.0
    armed = False
    for s in samples:
        armed = armed or s.temp <= s.setpoint
        if armed:
            overshoot = max(overshoot, s.temp - s.setpoint)
    return overshoot


def _upset_overshoot(samples: list[Sample], disturbance: float | None) -> float | None:
    """Overshoot on the way back from a disturbance: above the setpoint after the lowest
    point that followed it (before the trough the sensor may still show the old water)."""
    if disturbance is None:
        return None
    after = [s for s in samples if s.t >= disturbance]
    if not after:
        return None
    trough = min(range(len(after)), key=lambda i: after[i].temp - after[i].setpoint)
    return _overshoot(after[trough:])


def report(metrics: Metrics) -> dict[str, Any]:
    """The metrics as `hermsd simulate` and `hermsd replay` print them, rounded for reading."""
    m = metrics
    return {
        "overshoot_c": round(m.overshoot_c, 4),
        "overshoots": m.overshoots,
        "settle_s": None if m.settle_s is None else round(m.settle_s, 1),
        "recovery_s": None if m.recovery_s is None else round(m.recovery_s, 1),
        "in_band_fraction": m.in_band_fraction,
        "in_band_s": round(m.in_band_s, 1),
        "in_band_pct": round(100.0 * m.in_band_s / m.since_band_s, 2) if m.since_band_s else None,
        "iae": round(m.iae, 2),
        "max_output_jump": round(m.max_output_jump, 3),
        "ssr_edges_per_hour": None if m.edges_per_hour is None else round(m.edges_per_hour, 1),
        "max_temp_c": None if math.isnan(m.max_temp_c) else round(m.max_temp_c, 3),
        "mean_output": round(m.mean_output, 2),
        "heatup_overshoot_c": round(m.heatup_overshoot_c, 4),
        "upset_overshoot_c": None if m.upset_overshoot_c is None else round(m.upset_overshoot_c, 4),
        "last_hour_p2p_c": None if m.last_hour_p2p_c is None else round(m.last_hour_p2p_c, 4),
        "held_in_band_pct": None if m.held_in_band_pct is None else round(m.held_in_band_pct, 2),
    }


def _hold_intervals(
    samples: list[Sample],
    settled_at: float | None,
    disturbances: list[float],
    recovered_at: float | None,
    end: float,
) -> list[tuple[float, float]]:
    """When the loop was holding: settled and not recovering from a disturbance."""
    if settled_at is None:
        return []
    marks = sorted(d for d in disturbances if d > settled_at)
    intervals: list[tuple[float, float]] = []
    start = settled_at
    for i, d in enumerate(marks):
        intervals.append((start, d))
        nxt = marks[i + 1] if i + 1 < len(marks) else end
        back = in_band_for_good(samples, d, nxt)
        if back is None:
            start = nxt
            continue
        start = back
    if start < end:
        intervals.append((start, end))
    return [(a, b) for a, b in intervals if b > a]


def _edges_per_hour(
    edges: list[float], samples: list[Sample], hold: list[tuple[float, float]]
) -> float | None:
    """SSR edges an hour over the hold, counted in whole control periods: a hold's ends fall
    mid-period, and a part of a period holds its one edge in less than a period's time, so
    counting to the ends reads up to two edges too many (720.4/h on a 5 h hold at 720)."""
    times = [s.t for s in samples]
    whole = []
    for a, b in hold:
        first = bisect.bisect_left(times, a)  # the first period boundary in the hold
        last = bisect.bisect_right(times, b) - 1  # the last
        if first < last:
            whole.append((times[first], times[last]))
    span = sum(b - a for a, b in whole)
    return sum(1 for e in edges if _inside(e, whole)) * 3600.0 / span if span > 0 else None


def _inside(t: float, intervals: list[tuple[float, float]]) -> bool:
    return any(a <= t < b for a, b in intervals)
