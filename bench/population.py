"""hermsd and PIDHerms on a population of drawn tuns (a benchmark, not a test).

The family of hermsd/sim/tuns.py is twelve tuns picked by hand; here each tun is drawn from
`random.Random(seed)` (seeds 1…N), from these distributions:

- litres configured: log-uniform 20–200 L; the water on the day: ×½–×2 of it (log-uniform);
- element: log-uniform 1–12 kW; on two elements (a quarter of the tuns) 2/5.5 of it on the
  SSR and the rest on a contactor, as bench/faults.py's two-element days;
- UA: ×0.4–2 (log-uniform) of a lidded pot's of the water's volume (hermsd/sim/tuns.py);
  the lid off on a third of the tuns (evaporation on top, as the simulator has it);
- transport delay 10–300 s, sensor lag 0–150 s, room 0–35 °C, sensor noise sd
  0–0.06 °C (all uniform); the sensor an LM92, a DS18B20 or a MAX31865 (a third each).

A draw whose element cannot take the day's water into the band within 3 h at full power
(the water comes at 4 h) or hold 66 °C at 80 % of its power is drawn again from the same
generator (`Population.redrawn` counts it): weak tuns are bench/reach.py's concern.

Each tun runs the brew day of bench/robustness.py (room → 66 °C, a tenth of the water's
volume of 15 °C water at 4 h, 6 h) through the real daemon: hermsd's day 1 with the shipped
config (only `tun.litres` and the watts set, and the lid), day 2 from the state day 1 left,
and CraftBeerPi's PIDHerms (seed 001's ITAE-load set). Beside them, on each tun's water
alone, the least recovery any controller can show with the water itself within day 2's
after-water overshoot (`landing_ratio`): where it exceeds ×1.02, the two goals cannot both
be met but by heating the water past it behind the sensor's lag; the same for
the heat-up's settle and overshoot (`settle_landing_ratio`, against ×1.01). `--faults`
instead runs, on each tun, a shorted SSR (with a contactor) in the hold at 5 h and a dead
element at a drawn point of the day; `--faults --current` the same days with the element's
current input fitted (`current.kind: sim`, docs/current.md). Prints Markdown; `--write` puts it into
bench/RESULTS.md.

    uv run --group bench python bench/population.py [--tuns 200] [--jobs 2] [--write]
    uv run --group bench python bench/population.py --faults [--tuns 50] [--jobs 2] [--write]
    uv run --group bench python bench/population.py --faults --current [--tuns 40] [--write]

`--minutes M` stops after M minutes with the tuns done (a prefix of the seeds); `--keep FILE`
appends each tun's figures to FILE as they come, and `--from FILE` makes the tables from them.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import itertools
import json
import math
import multiprocessing
import random
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import sections  # bench/sections.py, beside this file
from faults import two_elements  # bench/faults.py, beside this file
from robustness import (  # bench/robustness.py, beside this file
    AHEAD_KEYS,
    CBPI,
    DAY_1,
    DAY_2,
    DAY_2_GOALS,
    SENSOR_KINDS,
    SHIPPED,
    Goals,
    behind,
    controller_days,
    missed,
    said_falsely,
    with_sensor,
)

from hermsd.config import read
from hermsd.config.schema import Config
from hermsd.metrics import BAND
from hermsd.safety.current_watch import CONFIRM_SAMPLES, Sample
from hermsd.sim import hlt, scenario
from hermsd.sim import tun_faults as tf
from hermsd.sim.scenario import Event
from hermsd.sim.tuns import TunSpec

SETPOINT = 66.0
HEATUP_LIMIT_S = 3 * 3600.0
HOLD_LIMIT = 0.8
TWO_ELEMENT_SHARE = 0.25
LID_OFF_SHARE = 1.0 / 3.0
P2P = "p-p last hour"
HOUR_S = 3600.0
"""s: the day's last hour, over which day 1's p-p is measured."""
DAY_1_GOALS: Goals = (
    ("heatup_overshoot_c", 0.3, "overshoot"),
    ("upset_overshoot_c", 0.3, "overshoot after water"),
    ("last_hour_p2p_c", 0.15, P2P),
)
"""Day 1's goals on the population: the hold's peak to peak up to 0.15 °C (noise to
0.06 °C), not the family's 0.1 °C."""
MEASURES = (
    ("heatup_overshoot_c", "overshoot °C", 3),
    ("upset_overshoot_c", "after water °C", 3),
    ("settle_ratio", "settle ×min", 4),
    ("recovery_ratio", "recovery ×min", 4),
    ("max_output_jump", "jump %", 1),
    ("held_in_band_pct", "in band %", 2),
    ("last_hour_p2p_c", "p-p last h °C", 3),
    ("ssr_edges_per_hour", "edges/h", 0),
)
DEAD_GOAL_S = 20 * 60.0
SHORT_MARGIN_S = 180.0
"""A shorted SSR: told within the dead time and 3 minutes, the water no higher than 66.5 °C
plus what full power adds in that time."""


@dataclass(frozen=True, slots=True)
class PopTun:
    """One drawn tun: `spec` as configured (its litres), the day's water ×`fill`."""

    seed: int
    spec: TunSpec
    fill: float
    two_elements: bool
    noise_c: float
    kind: str
    dead_at_s: float  # when its element dies on the faults' day

    @property
    def water(self) -> TunSpec:
        """The tun with the day's water in it (UA grows with the wetted area)."""
        return dataclasses.replace(self.spec, litres=self.spec.litres * self.fill)

    def words(self) -> str:
        s = self.spec
        elements = "two elements" if self.two_elements else "one element"
        return (
            f"{s.litres:.0f} L ×{self.fill:.2f}, {s.element_watts / 1000:.1f} kW {elements}, "
            f"UA ×{s.ua_factor:.2f}, delay {s.transport_delay_s:.0f} s, lag "
            f"{s.sensor_lag_s:.0f} s, lid {'off' if s.lid_off else 'on'}, room "
            f"{s.ambient_c:.0f} °C, noise {self.noise_c:.3f} °C, {self.kind}"
        )

    def day(self) -> scenario.Scenario:
        """The brew day with the day's water, its noise and its sensor noise's seed."""
        day = self.water.brew_day(noise_c=self.noise_c, seed=self.seed)
        day = dataclasses.replace(day, name=f"tun {self.seed}")
        return two_elements(self.spec, day) if self.two_elements else day

    def config(self) -> Config:
        return with_sensor(self.spec.config(read.load(SHIPPED)), self.kind)

    def plant(self, **start: float) -> hlt.PhysicalPlant:
        """The day's tun as the simulator builds it, for the physical bounds (`start`: its
        `start_c` and `start_s`, if not the room's and 0 s)."""
        plant = self.water.plant()  # both elements' watts on one: full power is both
        params = {k: v for k, v in plant.items() if k in hlt.plant_parameters("physical")}
        return hlt.PhysicalPlant(**{**params, **start})

    def losses_w(self, water_c: float = SETPOINT) -> float:
        """What the day's water loses at `water_c`: walls, and evaporation with the lid off."""
        water = self.water
        loss = water.ua_w_per_k * (water_c - water.ambient_c)
        if water.lid_off:
            surface = hlt.pot_surface_m2(water.litres)
            loss += hlt.evaporation_w(water_c, water.ambient_c, surface)
        return loss


LANDING_OVERSHOOT_C = 0.1
"""Day 2's overshoot goal after the water: what `landing_ratio` lands within."""
BISECTIONS = 12
"""Halvings of the cut's time: to 1/4096 of the least recovery (a tenth of a second)."""
CONTROL_PERIOD_S = read.load(SHIPPED).control.period
"""s: the shipped control period, over which the holding duty's pulse is spread."""


def _hold_edges(start: float, hold: float) -> Iterator[tuple[float, bool]]:
    """The SSR's edges that give `hold` (a part of full power) from `start` s on, one pulse
    at the start of each control period."""
    for k in itertools.count():
        edge = start + k * CONTROL_PERIOD_S
        yield edge, hold > 0.0
        if hold < 1.0:
            yield edge + hold * CONTROL_PERIOD_S, False


def _recovery_with_cut(
    start: hlt.PhysicalPlant, cut: float, settle: float, hold: float
) -> tuple[float | None, float]:
    """Full power from 0 s (the water's instant, or the day's start) until `cut` s, then
    `hold` of it (what holds the setpoint): when the sensor (without noise) first reaches the
    band's lower edge (again), and the water's highest until `settle` s past the cut (the
    heat in flight has landed and the lag shown it; −inf if the sensor never got back)."""
    plant = copy.deepcopy(start)
    plant.set_heater(True, 0.0)
    edges = _hold_edges(cut, hold)
    when, on = next(edges)
    t, sensor = 0.0, plant.temperature(0.0)
    crossed, peak = None, -math.inf
    edge = SETPOINT - BAND
    while t < HEATUP_LIMIT_S:
        t += 1.0
        while when <= t:
            plant.set_heater(on, when)
            when, on = next(edges)
        now = plant.temperature(t)
        peak = max(peak, plant.water_temperature(t))
        if crossed is None and sensor < edge <= now:
            crossed = t - 1.0 + (edge - sensor) / (now - sensor)
            if t < cut:
                return crossed, math.inf  # the least recovery: full power on into the band
        if crossed is not None and t > cut + settle:
            break
        sensor = now
    return crossed, -math.inf if crossed is None else peak


def landing_ratio(tun: PopTun) -> float | None:
    """The least recovery any controller can show on the tun's water without the water
    going LANDING_OVERSHOOT_C over the setpoint, × the least recovery (full power on from
    the water): full power from the water's own instant, then what holds the setpoint, from
    the latest cut that keeps the water's peak within it (the heat as early as it can come,
    and the water then kept where it landed: nothing brings the sensor back sooner without
    more heat in the water). From the water held at 66 °C (its holding duty's heat in
    flight), the tenth of 15 °C water in; None where full power does not reach the band
    within 3 h. Day 2's recovery ≤ ×1.02 and its after-water overshoot ≤ 0.1 °C can both be
    met with the water itself within 0.1 °C only where this is ≤ 1.02: behind a slow sensor
    a sooner recovery needs the water over it, which the lagging sensor does not show."""
    before = _settle_s(tun)
    start = tun.plant(start_c=SETPOINT, start_s=-before)
    for when, on in _hold_edges(-before, _holding(tun)):
        if when >= 0.0:
            break
        start.set_heater(on, when)
    start.add_water(tun.water.litres / 10.0, 15.0, 0.0)
    return _least_within(start, tun)


def settle_landing_ratio(tun: PopTun) -> float | None:
    """`landing_ratio` for the day's heat-up: the least settle any controller can show from
    the day's start without the water going LANDING_OVERSHOOT_C over the setpoint, × the
    least settle (full power on into the band, the `physical_min_s` settles are judged
    against). Day 2's settle ≤ ×1.01 and its heat-up overshoot ≤ 0.1 °C can both be met
    only where this is ≤ 1.01: a fast tun behind a long delay and lag has tens of degrees
    in flight at full power, and the least settle lands them past the band."""
    return _least_within(tun.plant(), tun)


def _settle_s(tun: PopTun) -> float:
    """s in which the heat in flight lands and the sensor's lag shows it (to e^−5)."""
    water = tun.water
    return water.transport_delay_s + 5.0 * water.sensor_lag_s + 60.0


def _holding(tun: PopTun) -> float:
    """The part of full power that holds the day's water at the setpoint."""
    return tun.losses_w(SETPOINT) / tun.water.element_watts


def _least_within(start: hlt.PhysicalPlant, tun: PopTun) -> float | None:
    """From `start` (0 s), the earliest the sensor is back in the band with the water's peak
    within LANDING_OVERSHOOT_C of the setpoint (full power, then the holding duty from the
    latest cut, by bisection) over the earliest at full power on; 1.0 where full power on
    keeps within it, None where it never reaches the band within HEATUP_LIMIT_S or no cut
    keeps within it."""
    settle, hold = _settle_s(tun), _holding(tun)
    least, _ = _recovery_with_cut(start, math.inf, settle, hold)
    if least is None:
        return None
    early, late = 0.0, least
    landed: float | None = None
    if _recovery_with_cut(start, late, settle, hold)[1] <= SETPOINT + LANDING_OVERSHOOT_C:
        return 1.0
    for _ in range(BISECTIONS):
        cut = (early + late) / 2.0
        crossed, peak = _recovery_with_cut(start, cut, settle, hold)
        if peak <= SETPOINT + LANDING_OVERSHOOT_C:
            early, landed = cut, crossed
        else:
            late = cut
    return None if landed is None else landed / least


def _log_uniform(rng: random.Random, low: float, high: float) -> float:
    return math.exp(rng.uniform(math.log(low), math.log(high)))


def _draw_once(seed: int, rng: random.Random) -> PopTun:
    spec = TunSpec(
        name=f"tun {seed}",
        litres=round(_log_uniform(rng, 20.0, 200.0), 1),
        element_watts=round(_log_uniform(rng, 1000.0, 12000.0), -1),
        ua_factor=_log_uniform(rng, 0.4, 2.0),
        transport_delay_s=round(rng.uniform(10.0, 300.0)),
        sensor_lag_s=round(rng.uniform(0.0, 150.0)),
        ambient_c=round(rng.uniform(0.0, 35.0), 1),
        lid_off=rng.random() < LID_OFF_SHARE,
    )
    return PopTun(
        seed=seed,
        spec=spec,
        fill=_log_uniform(rng, 0.5, 2.0),
        two_elements=rng.random() < TWO_ELEMENT_SHARE,
        noise_c=rng.uniform(0.0, 0.06),
        kind=rng.choice(SENSOR_KINDS),
        dead_at_s=round(rng.uniform(0.5 * 3600.0, 5.5 * 3600.0)),
    )


def feasible(tun: PopTun) -> bool:
    """Full power takes the day's water into the band within 3 h and holds 66 °C at 80 %."""
    if tun.losses_w() > HOLD_LIMIT * tun.spec.element_watts:
        return False
    # `plant` puts both elements' watts on its one: full power is both
    return (
        scenario.time_to_band(tun.plant(), 0.0, SETPOINT, HEATUP_LIMIT_S, element2=False)
        is not None
    )


@dataclass(frozen=True, slots=True)
class Population:
    tuns: tuple[PopTun, ...]
    redrawn: int


def draw(seed: int) -> tuple[PopTun, int]:
    """Tun `seed`, and how many draws before it were redrawn as unable to hold or reach."""
    rng = random.Random(seed)
    redrawn = 0
    while not feasible(tun := _draw_once(seed, rng)):
        redrawn += 1
    return tun, redrawn


def population(count: int) -> Population:
    drawn = [draw(seed) for seed in range(1, count + 1)]
    return Population(tuple(t for t, _ in drawn), sum(n for _, n in drawn))


# The brew days ----------------------------------------------------------------------------


def days_of(tun: PopTun, keep_records: bool = False) -> dict[str, scenario.Result]:
    """hermsd's day 1 and day 2 and PIDHerms' on the tun (bench/robustness.py's days)."""
    return controller_days(tun.day(), tun.config(), peers=(CBPI,), keep_records=keep_records)


def _summaries(seed: int) -> dict[str, dict[str, Any]]:
    tun, _ = draw(seed)
    return {label: result.summary for label, result in days_of(tun).items()}


def _on_pool(
    work: Callable[[int], Any], count: int, jobs: int, minutes: float, keep: Path | None
) -> dict[int, Any]:
    """`work` on tuns 1…`count` in order on `jobs` processes, until all are done or
    `minutes` have passed: the tuns done by then (a prefix of 1…count, so no kind of tun is
    favoured), each also appended to `keep` (a JSON line) as it comes."""
    deadline = time.monotonic() + 60.0 * minutes
    found: dict[int, Any] = {}
    with multiprocessing.get_context("fork").Pool(jobs) as pool:
        results = pool.imap(work, range(1, count + 1), chunksize=1)
        for seed in range(1, count + 1):
            left = None if math.isinf(deadline) else max(deadline - time.monotonic(), 0.001)
            try:
                found[seed] = results.next(timeout=left)
            except multiprocessing.TimeoutError:
                break
            if keep is not None:
                with keep.open("a", encoding="utf-8") as file:
                    file.write(json.dumps({"seed": seed, "found": found[seed]}) + "\n")
        pool.terminate()
    return found


def _cell(value: Any, digits: int) -> str:
    return "–" if value is None else f"{value:.{digits}f}"


def excess(summary: dict[str, Any], label: str) -> float:
    """How far the day is from its goals: its worst measure over its limit (1 on the limit;
    a missing measure, an alarm or time out of the band counts as infinitely far)."""
    if said_falsely(summary) or summary["held_in_band_pct"] != 100.0:
        return math.inf
    goals = DAY_2_GOALS if label == DAY_2 else DAY_1_GOALS
    ratios = [math.inf if summary[key] is None else summary[key] / limit for key, limit, _ in goals]
    return max(ratios)


def missed_goals(summary: dict[str, Any], label: str) -> list[str]:
    """The population's goals `summary` misses (day 2's for day 2, day 1's for the rest)."""
    return missed(summary, label, DAY_1_GOALS)


def pass_rates(found: dict[int, dict[str, dict[str, Any]]], label: str) -> list[str]:
    goals = DAY_2_GOALS if label == DAY_2 else DAY_1_GOALS
    names = [what for _, _, what in goals] + ["in band", "alarms"]
    n = len(found)
    rows = []
    for what in names:
        kept = sum(what not in missed_goals(days[label], label) for days in found.values())
        rows.append(f"{what} {kept}/{n} ({100.0 * kept / n:.1f} %)")
    every = sum(not missed_goals(days[label], label) for days in found.values())
    rows.append(f"**all {every}/{n} ({100.0 * every / n:.1f} %)**")
    return rows


def contactor_ripple(tun: PopTun) -> float | None:
    """The least peak to peak (°C) the sensor can show over the day's last hour where the
    SSR's element alone cannot keep the water in the band and the contactor's alone
    overshoots it, or None where the hold need not switch the contactor. Closed for its
    least time with the SSR off, the water rises by the least any close lifts it, least
    where the losses are most: the band's top and beyond it by that rise (what the sensor's
    lag may hide); open with the SSR full, it falls back (over the least open time, the SSR
    then under full). A longer close, or the SSR on in it, only lifts it more; the sensor's
    first-order lag smooths the cycle. Or no close in the hour: the water sags at the SSR's
    full power, least at the band's foot and below it by that sag."""
    if not tun.two_elements:
        return None
    day, element2 = tun.day(), read.load(SHIPPED).element2
    ssr_w = float(day.plant["element_watts"])
    contactor_w = float(day.plant["element2_watts"])
    top, foot = SETPOINT + BAND, SETPOINT - BAND
    if not (tun.losses_w(foot) > ssr_w and tun.losses_w(top) < contactor_w):
        return None
    last_hour = day.duration - HOUR_S
    poured = sum(
        float(e.value["litres"]) for e in day.events if e.kind == "add_water" and e.at < last_hour
    )
    capacity = (tun.water.litres + poured) * hlt.WATER_J_PER_LITRE_K

    def rise(water_c: float) -> float:  # °C over the least close, the losses at `water_c`
        return (contactor_w - tun.losses_w(water_c)) / capacity * element2.min_on

    def sag(water_c: float) -> float:  # °C over the hour at the SSR's full power
        return max(0.0, tun.losses_w(water_c) - ssr_w) / capacity * HOUR_S

    most = tun.losses_w(top + rise(top))
    opened = max(element2.min_off, element2.min_on * (contactor_w - most) / (most - ssr_w))
    cycle = _lagged_peak_to_peak(
        rise(top + rise(top)), element2.min_on, opened, tun.water.sensor_lag_s
    )
    return min(sag(foot - sag(foot)), cycle)


RIPPLE_STEP_S = 0.5
"""s: the step `_lagged_peak_to_peak` follows the sensor's lag in."""


def _lagged_peak_to_peak(rise: float, closed: float, opened: float, lag: float) -> float:
    """The peak to peak a first-order sensor of `lag` s shows of water that rises by `rise`
    °C over `closed` s and falls back over `opened` s, again and again: the last of enough
    cycles for the lag's start to fade (to e^−20)."""
    if lag <= 0.0:
        return rise
    cycle = closed + opened
    cycles = math.ceil(20.0 * lag / cycle) + 2
    water = sensor = 0.0
    t, last = 0.0, []
    while t < cycles * cycle:
        phase = t % cycle
        water += RIPPLE_STEP_S * (rise / closed if phase < closed else -rise / opened)
        sensor += (water - sensor) * -math.expm1(-RIPPLE_STEP_S / lag)
        t += RIPPLE_STEP_S
        if t >= (cycles - 1) * cycle:
            last.append(sensor)
    return max(last) - min(last)


def landing_line(tuns: Sequence[PopTun], found: dict[int, dict[str, dict[str, Any]]]) -> str:
    """How many tuns physics lets meet day 2's recovery and after-water goals together
    (`landing_ratio`), and its settle and heat-up overshoot (`settle_landing_ratio`), and
    how many of those day 2 meets both on; and day 1's p-p where the hold must switch a
    contactor (`contactor_line`)."""
    return "\n\n".join(
        [
            *(
                _possible_line(tuns, found, *pair)
                for pair in (
                    (
                        landing_ratio,
                        1.02,
                        "recovery",
                        "overshoot after water",
                        "the water's own instant",
                    ),
                    (settle_landing_ratio, 1.01, "settle", "overshoot", "the day's start"),
                )
            ),
            contactor_line(tuns, found),
        ]
    )


def contactor_line(tuns: Sequence[PopTun], found: dict[int, dict[str, dict[str, Any]]]) -> str:
    """Where the hold must switch the contactor (`contactor_ripple`), how many tuns day 1's
    p-p is possible on, and met on."""
    shown = [tun for tun in tuns if tun.seed in found]
    ripples = {tun.seed: contactor_ripple(tun) for tun in shown}
    switching = sorted(seed for seed, ripple in ripples.items() if ripple is not None)
    limit = next(goal for _, goal, what in DAY_1_GOALS if what == P2P)
    over = [seed for seed in switching if (ripples[seed] or 0.0) > limit]
    met = sum(
        P2P not in missed_goals(found[tun.seed][DAY_1], DAY_1)
        for tun in shown
        if tun.seed not in over
    )
    least = [ripples[seed] or 0.0 for seed in switching]
    return (
        f"- the hold must switch the contactor on {len(switching)}/{len(shown)} tuns (two "
        "elements whose losses anywhere in the band lie between the SSR's element and the "
        f"contactor's: tuns {', '.join(map(str, switching)) or 'none'}); the least p-p the "
        "sensor can show in the last hour there (`contactor_ripple`: a close of the contactor's "
        "least time with the SSR off, then open with the SSR full, the losses the most the "
        "water may reach behind the sensor's lag; or no close, the water sagging at the SSR's "
        "full power) "
        + (f"is {min(least):.3f}–{max(least):.3f} °C, " if least else "")
        + f"over {limit:g} °C on {len(over)} (tuns {', '.join(map(str, over)) or 'none'}), so "
        f"day 1's p-p is possible on {len(shown) - len(over)} tuns and met on {met} of those"
    )


def _possible_line(
    tuns: Sequence[PopTun],
    found: dict[int, dict[str, dict[str, Any]]],
    ratio: Callable[[PopTun], float | None],
    goal: float,
    time_goal: str,
    overshoot_goal: str,
    start: str,
) -> str:
    ratios = {tun.seed: ratio(tun) for tun in tuns if tun.seed in found}
    possible = [seed for seed, r in ratios.items() if r is not None and r <= goal]
    known = [r for r in ratios.values() if r is not None]
    met = sum(
        not {time_goal, overshoot_goal} & set(missed_goals(found[seed][DAY_2], DAY_2))
        for seed in possible
    )
    return (
        f"- {time_goal} ≤ ×{goal:g} with the {overshoot_goal} ≤ {LANDING_OVERSHOOT_C:g} °C, "
        f"the water's own too, is possible on {len(possible)}/{len(ratios)} tuns "
        f"(`{ratio.__name__}`: the least {time_goal} with the water within that overshoot, "
        f"full power from {start} and then the holding duty, × the least {time_goal}; "
        f"{min(known):.3f}–{max(known):.3f}); day 2 meets both on "
        f"{met} of those"
    )


def mean_of(days: list[dict[str, Any]], key: str) -> tuple[float | None, int]:
    """The mean of `key` over `days` that have it, and how many do not."""
    known = [float(d[key]) for d in days if d[key] is not None]
    return (sum(known) / len(known) if known else None), len(days) - len(known)


def means_table(found: dict[int, dict[str, dict[str, Any]]]) -> tuple[str, list[str]]:
    """The population's mean of every measure for each controller, and where day 2's mean
    is not ahead of PIDHerms' (lower is better; in band: higher)."""
    labels = (DAY_1, DAY_2, CBPI)
    lines = [
        "| controller | " + " | ".join(name for _, name, _ in MEASURES) + " | alarms |",
        "|---|" + "---|" * (len(MEASURES) + 1),
    ]
    averages = {}
    for label in labels:
        days = [d[label] for d in found.values()]
        averages[label] = {key: mean_of(days, key) for key, _, _ in MEASURES}
        cells = []
        for key, _, digits in MEASURES:
            mean, lacking = averages[label][key]
            cells.append(_cell(mean, digits) + (f" ({lacking} without)" if lacking else ""))
        alarmed = sum(bool(said_falsely(d)) for d in days)
        lines.append(f"| {label} | " + " | ".join(cells) + f" | {alarmed} |")
    mine = {key: averages[DAY_2][key][0] for key, _, _ in MEASURES}
    theirs = {key: averages[CBPI][key][0] for key, _, _ in MEASURES}
    worse = behind(mine, theirs)
    for key, name, _ in MEASURES:
        if key in dict(AHEAD_KEYS):
            continue
        a, b = mine[key], theirs[key]
        higher_better = key == "held_in_band_pct"
        if a is None or (b is not None and (a < b if higher_better else a > b)):
            worse.append(name)
    return "\n".join(lines), worse


def worst_table(
    tuns: dict[int, PopTun], found: dict[int, dict[str, dict[str, Any]]], count: int = 5
) -> str:
    """The `count` tuns farthest from their goals (day 2's first, then day 1's)."""
    ranked = sorted(
        found,
        key=lambda seed: (excess(found[seed][DAY_2], DAY_2), excess(found[seed][DAY_1], DAY_1)),
        reverse=True,
    )
    lines = [
        "| tun | parameters | controller | "
        + " | ".join(name for _, name, _ in MEASURES)
        + " | alarms | goals missed |",
        "|---|---|---|" + "---|" * (len(MEASURES) + 2),
    ]
    for seed in ranked[:count]:
        for label in (DAY_1, DAY_2, CBPI):
            s = found[seed][label]
            cells = " | ".join(_cell(s[key], digits) for key, _, digits in MEASURES)
            alarms = ", ".join(said_falsely(s)) or "0"
            misses = ", ".join(missed_goals(s, label)) or "none"
            params = tuns[seed].words() if label == DAY_1 else ""
            lines.append(f"| {seed} | {params} | {label} | {cells} | {alarms} | {misses} |")
    return "\n".join(lines)


def _stopped(asked: int, count: int, minutes: float) -> str:
    if count == asked:
        return "."
    return f" (of the {asked} tuns asked: those done within --minutes {minutes:g})."


def kept(path: Path) -> dict[int, Any]:
    """The figures `--keep` appended to `path`, by tun."""
    lines = path.read_text(encoding="utf-8").splitlines()
    return {int(d["seed"]): d["found"] for d in map(json.loads, lines)}


def _run(work: Callable[[int], Any], args: argparse.Namespace) -> tuple[dict[int, Any], str]:
    """The tuns' figures (from `--from`, or run now) and how they came."""
    if args.source is not None:
        found = kept(args.source)
        return found, f"(their figures read from {args.source.name}, kept by --keep)"
    started = time.perf_counter()
    found = _on_pool(work, args.tuns, args.jobs, args.minutes, args.keep)
    wall = time.perf_counter() - started
    return found, f"in {wall:.0f} s on {args.jobs} processes" + _stopped(
        args.tuns, len(found), args.minutes
    )


def brew_days_main(args: argparse.Namespace) -> int:
    found, how = _run(_summaries, args)
    count = len(found)
    drawn = population(count)
    tuns = {t.seed: t for t in drawn.tuns}
    means, worse = means_table(found)
    verdict = (
        "ahead of PIDHerms on the population's mean of every measure"
        if not worse
        else "not ahead of PIDHerms on the population's mean of " + ", ".join(worse)
    )
    kinds = {k: sum(t.kind == k for t in drawn.tuns) for k in SENSOR_KINDS}
    text = "\n\n".join(
        [
            " ".join(
                [
                    f"{count} tuns drawn as bench/population.py's docstring says (seeds",
                    f"1–{count}; {drawn.redrawn} draws redrawn as unable to reach the band",
                    "within 3 h or hold at 80 %;",
                    f"{sum(t.two_elements for t in drawn.tuns)} on two elements,",
                    f"{sum(t.spec.lid_off for t in drawn.tuns)} with the lid off,",
                    ", ".join(f"{n} {k}" for k, n in kinds.items()) + "),",
                    "each on bench/robustness.py's brew day with the day's water ×½–×2 of the",
                    "configured: hermsd's day 1 (shipped config, the tun's configured litres",
                    "and watts), its day 2 (from what day 1 left) and PIDHerms (ITAE-load",
                    "set). Measures as in bench/robustness.py. Goals, day 1: overshoot ≤ 0.3 °C",
                    "(heat-up and after the water), the last hour's p-p ≤ 0.15 °C; day 2:",
                    "overshoot ≤ 0.1 °C (both), settle ≤ ×1.01, recovery ≤ ×1.02, jump ≤ 10 %,",
                    "≤ 720 edges/h; both: 100 % in band, no alarm and no element warning",
                    "(two elements: a warning stops asking the element it names, so a false",
                    "one costs the day as an alarm would). Each goal's pass rate",
                    "(tuns meeting it of all):",
                ]
            ),
            "- day 1: " + "; ".join(pass_rates(found, DAY_1)),
            "- day 2: " + "; ".join(pass_rates(found, DAY_2)),
            landing_line(drawn.tuns, found),
            "The population's mean of every measure (over the tuns that have it), and the "
            f"verdict: day 2 is {verdict}.\n\n" + means,
            "The five tuns farthest from day 2's goals (then day 1's): each measure against "
            "its limit, an alarm, time out of the band or a measure missing the farthest.\n\n"
            + worst_table(tuns, found),
            f"{len(found) * 3} brew days {how}",
        ]
    )
    print(text)
    if args.write:
        sections.write(f"## Population: {count} tuns drawn", text)
    return 0


# Faults ------------------------------------------------------------------------------------


class WaterPeak(hlt.PhysicalPlant):
    """The day's tun that keeps the water's highest temperature after `watch_from` s, as
    the sensor reads it each second (the water itself, not the sensor's lagging view)."""

    __slots__ = ("peak_c", "watch_from")

    def __init__(self, watch_from: float, **params: Any) -> None:
        super().__init__(**params)
        self.watch_from = watch_from
        self.peak_c = -math.inf

    def temperature(self, t: float) -> float:
        if t >= self.watch_from:
            self.peak_c = max(self.peak_c, self.water_temperature(t))
        return super().temperature(t)


def _fault_day(
    tun: PopTun, event: Event, contactor: bool, current: bool = False
) -> scenario.Scenario:
    """The tun's day with `event`; `current`: the element's current input fitted (sim)."""
    day = tun.water.brew_day(noise_c=tun.noise_c, seed=tun.seed)
    config = {**(tf.CONTACTOR if contactor else {}), **(CURRENT if current else {})}
    day = dataclasses.replace(day, events=(*day.events, event), config=config)
    return two_elements(tun.spec, day) if tun.two_elements else day


CURRENT = {"current": {"kind": "sim"}}
"""The element's current input, as the simulator's circuit gives it (docs/current.md)."""


def ssr_short(tun: PopTun) -> dict[str, Any]:
    """A shorted SSR at 5 h in the hold: when told, against the tun's bound, and the water's
    peak against 66.5 °C + the full-power rate × (dead time + 3 min)."""
    sc = _fault_day(tun, Event(tf.FAULT_AT, "ssr", "stuck_on"), contactor=True)
    params = {k: v for k, v in sc.plant.items() if k in hlt.plant_parameters("physical")}
    plant = WaterPeak(tf.FAULT_AT, **params)
    result = scenario.run(sc, tun.config(), outside_plant=plant)
    after = [a for a in result.summary["alarms"] if a["at_s"] >= tf.FAULT_AT]
    told = after[0] if after else None
    return {
        "false": said_falsely(result.summary, tf.FAULT_AT),
        "kind": None if told is None else told["kind"],
        "detected_s": None if told is None else told["detected_after_s"],
        "peak_c": plant.peak_c,
    }


def short_bounds(tun: PopTun) -> tuple[float, float, float]:
    """A shorted SSR's bounds on the tun: the time to tell it (dead time + 3 min), the
    water's peak (66.5 °C + the full-power rise at 66 °C over that time), and that rate
    (°C/s: the SSR's element less the losses; ≤ 0 where that element alone cannot heat the
    water, and a short is then no hazard to tell)."""
    told_s = tun.spec.transport_delay_s + tun.spec.sensor_lag_s + SHORT_MARGIN_S
    ssr_w = tun.day().plant["element_watts"]
    rate = (ssr_w - tun.losses_w()) / (tun.water.litres * hlt.WATER_J_PER_LITRE_K)
    return told_s, SETPOINT + 0.5 + max(rate, 0.0) * told_s, rate


def element_dies(tun: PopTun) -> dict[str, Any]:
    """The element (the SSR's, on two elements) opens at the tun's drawn time: when an
    alarm or (two elements) an element warning first told it."""
    at = tun.dead_at_s
    sc = _fault_day(tun, Event(at, "heater", "open"), contactor=False)
    result = scenario.run(sc, tun.config(), keep_records=True)
    alarm = next((a for a in result.summary["alarms"] if a["at_s"] >= at), None)
    warned = next((r.t for r in result.records if r.t >= at and r.no_heat), None)
    times = [t for t in (None if alarm is None else alarm["at_s"], warned) if t is not None]
    # Two elements: how the other holds once the dead one is told, in periods of the PV out
    # of the hold's band from HELD_FROM_S after the death to the day's end.
    out = [
        r
        for r in result.records
        if r.t >= at + HELD_FROM_S and r.pv is not None and abs(r.pv - r.setpoint) > HELD_BAND
    ]
    return {
        "false": said_falsely(result.summary, at),
        "kind": None if alarm is None else alarm["kind"],
        "warned": warned is not None and (alarm is None or warned < alarm["at_s"]),
        "detected_s": min(times) - at if times else None,
        "out_of_band_s": len(out) * tun.config().control.period if tun.two_elements else None,
    }


HELD_FROM_S = 1800.0
"""s after an element's death from which the water's hold on the other is measured."""
HELD_BAND = 0.5
"""°C: the hold's band."""


def _faults(seed: int) -> dict[str, Any]:
    tun, _ = draw(seed)
    return {"short": ssr_short(tun), "dead": element_dies(tun)}


def _phase(at: float) -> str:
    """Where in the day `at` falls (the water comes at 4 h)."""
    if at >= 4 * 3600.0:
        return "after the water"
    return "heat-up or hold"


def faults_main(args: argparse.Namespace) -> int:
    found, how = _run(_faults, args)
    count = len(found)
    drawn = population(count)
    tuns = {t.seed: t for t in drawn.tuns}
    lines = [
        "| tun | parameters | SSR shorts: told after s | bound s | water's peak °C | bound °C "
        "| element dies at s | told after s | by | said before the fault |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    shorts_in = peaks_in = dead_in = false = harmless = 0
    for seed, tun in tuns.items():
        short, dead = found[seed]["short"], found[seed]["dead"]
        bound_s, peak_bound_c, rate = short_bounds(tun)
        harmless += rate <= 0.0
        told_in = short["kind"] == "ssr_stuck_on" and short["detected_s"] <= bound_s
        short_ok = told_in or rate <= 0.0
        peak_ok = short["peak_c"] <= peak_bound_c
        dead_ok = dead["detected_s"] is not None and dead["detected_s"] <= DEAD_GOAL_S
        shorts_in += short_ok
        peaks_in += peak_ok
        dead_in += dead_ok
        before = short["false"] + dead["false"]
        false += bool(before)
        if short_ok and peak_ok and dead_ok and not before:
            continue
        told = _cell(short["detected_s"], 0)
        if short["kind"] not in (None, "ssr_stuck_on"):
            told += f" ({short['kind']})"
        if rate <= 0.0:
            told += " (the SSR's element cannot heat it)"
        by = "warning" if dead["warned"] else (dead["kind"] or "**missed**")
        lines.append(
            f"| {seed} | {tun.words()} | {told} | {bound_s:.0f} "
            f"| {short['peak_c']:.2f} | {peak_bound_c:.2f} | {tun.dead_at_s:.0f} "
            f"({_phase(tun.dead_at_s)}) | {_cell(dead['detected_s'], 0)} | {by} "
            f"| {', '.join(before) or '0'} |"
        )
    n = len(tuns)
    shorts = sorted(found[s]["short"]["detected_s"] or math.inf for s in tuns)
    deads = sorted(found[s]["dead"]["detected_s"] or math.inf for s in tuns)
    text = "\n\n".join(
        [
            " ".join(
                [
                    f'Tuns 1–{count} of the population (section "Population"), each with',
                    "the day's water and sensor: a shorted SSR (`ssr: stuck_on`, a contactor",
                    "fitted) at 5 h in the hold, and the element (the SSR's, on two elements)",
                    "going open at a drawn time of the day (uniform 0.5–5.5 h: heat-up, hold or",
                    "after the water at 4 h). The shipped config, the supervisor's limits",
                    "unmeasured. Goals: the short told as ssr_stuck_on within the tun's dead",
                    "time (transport delay + sensor lag) + 3 min, the water's peak (the water,",
                    "not the sensor) no higher than 66.5 °C + the full-power rate at 66 °C",
                    "(the SSR's element less the losses, over the water's heat capacity) × that",
                    "time; the dead element told (an alarm, or on two elements the element",
                    "warning) within 20 min; no alarm or element warning before either fault.",
                ]
            ),
            f"- shorted SSR told within its bound: {shorts_in}/{n} (of them {harmless} where "
            "the SSR's element alone cannot heat the water at 66 °C: no hazard, none required); "
            f"water's peak within its "
            f"bound: {peaks_in}/{n}; told after (median, worst): {shorts[n // 2]:.0f} s, "
            f"{shorts[-1]:.0f} s",
            f"- dead element told within 20 min: {dead_in}/{n}; told after (median, worst): "
            f"{deads[n // 2]:.0f} s, {deads[-1]:.0f} s",
            _held_line(found, tuns),
            f"- tuns with an alarm or element warning before a fault (false on a normal "
            f"stretch): {false}/{n}",
            "The tuns that miss a goal:\n\n" + "\n".join(lines),
            f"{n * 2} simulated days {how}",
        ]
    )
    print(text)
    if args.write:
        sections.write(f"## Population: faults on {count} tuns drawn", text)
    return 0


def _held_line(found: dict[int, Any], tuns: dict[int, PopTun]) -> str:
    """How the other element holds the water once the SSR's is told dead (two elements)."""
    held = sorted(
        dead["out_of_band_s"]
        for seed, tun in tuns.items()
        if tun.two_elements
        and (dead := found[seed]["dead"])["detected_s"] is not None
        and dead.get("out_of_band_s") is not None
    )
    if not held:
        return "- two elements: no dead SSR element told"
    return (
        f"- two elements, the SSR's element told dead ({len(held)} tuns): the water outside "
        f"±{HELD_BAND} °C of the setpoint from {HELD_FROM_S / 60:.0f} min after its death to "
        f"the day's end, the other element holding (median, worst): {held[len(held) // 2]:.0f} "
        f"s, {held[-1]:.0f} s"
    )


def _current_faults(seed: int) -> dict[str, Any]:
    """Both faults on the tun with the current input fitted: when each was told, by what, and
    how many samples with the SSR commanded as the fault shows (off for a short, on for an
    open element) the input took from the fault to the verdict: 2 is the least it can."""
    tun, _ = draw(seed)
    found = {}
    for name, event, contactor, shown_on in (
        ("short", Event(tf.FAULT_AT, "ssr", "stuck_on"), True, False),
        ("dead", Event(tun.dead_at_s, "heater", "open"), False, True),
    ):
        sc = _fault_day(tun, event, contactor, current=True)
        result = scenario.run(sc, tun.config(), keep_records=True)
        after = [a for a in result.summary["alarms"] if a["at_s"] >= event.at]
        told = after[0] if after else None
        until = math.inf if told is None else told["at_s"] + 0.001  # at_s is rounded to ms
        samples = [Sample.from_logged(s) for r in result.records for s in r.current or []]
        showing = [s.t for s in samples if event.at <= s.t <= until and s.on == shown_on]
        found[name] = {
            "false": said_falsely(result.summary, event.at),
            "kind": None if told is None else told["kind"],
            "detected_s": None if told is None else told["detected_after_s"],
            "by_current": told is not None and told["message"].startswith("the current input"),
            "samples": len(showing),
            "first_shown_s": showing[0] - event.at if showing else None,
        }
    return found


def current_main(args: argparse.Namespace) -> int:
    """The faults with the current input: told within one control period, no false alarm."""
    found, how = _run(_current_faults, args)
    count = len(found)
    period = CONTROL_PERIOD_S
    tuns = {t.seed: t for t in population(count).tuns}
    expected = {"short": "ssr_stuck_on", "dead": "heater_not_heating"}
    within = {name: 0 for name in expected}
    periods: dict[str, list[float]] = {name: [] for name in expected}
    false = 0
    lines = [
        "| tun | parameters | SSR shorts: told after s | by | element dies at s | told after s "
        "| by | alarms before the fault |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for seed, tun in tuns.items():
        figures = found[seed]
        before = figures["short"]["false"] + figures["dead"]["false"]
        false += bool(before)
        ok = not before
        for name, kind in expected.items():
            fault = figures[name]
            told = fault["detected_s"]
            periods[name].append(math.inf if told is None else told / period)
            in_one = fault["kind"] == kind and told is not None and told <= period
            within[name] += in_one
            ok = ok and in_one
        if ok:
            continue
        cells = []
        for name, kind in expected.items():
            fault = figures[name]
            by = "current" if fault["by_current"] else (fault["kind"] or "**missed**")
            if fault["kind"] not in (None, kind):
                by += f" ({fault['kind']})"
            first = _cell(fault["first_shown_s"], 1)
            cells.append(f"{_cell(fault['detected_s'], 1)} (first sample {first}) | {by}")
        lines.append(
            f"| {seed} | {tun.words()} | {cells[0]} | {tun.dead_at_s:.0f} "
            f"({_phase(tun.dead_at_s)}) | {cells[1]} | {', '.join(before) or '0'} |"
        )
    n = len(tuns)

    def spread(name: str) -> str:
        told = sorted(periods[name])
        least = sum(found[s][name]["samples"] == CONFIRM_SAMPLES for s in tuns)
        waits = sorted(
            math.inf if (w := found[s][name]["first_shown_s"]) is None else w for s in tuns
        )
        after_first = sum(
            (f := found[s][name])["detected_s"] is not None
            and f["first_shown_s"] is not None
            and f["detected_s"] - f["first_shown_s"] <= period
            for s in tuns
        )
        return (
            f"median {told[n // 2]:.2f}, worst {told[-1]:.2f} periods; at the first "
            f"{CONFIRM_SAMPLES} samples that could show it on {least}/{n}; the first of them "
            f"taken after median {waits[n // 2]:.1f} s, worst {waits[-1]:.1f} s; told within "
            f"one period of it on {after_first}/{n}"
        )

    text = "\n\n".join(
        [
            " ".join(
                [
                    f'The days of "Population: faults" on tuns 1–{count}, with the element\'s',
                    "current input fitted (`current.kind: sim`: the simulated circuit as a CT",
                    "on the SSR's element reads it, docs/current.md): a shorted SSR (a contactor",
                    "fitted) at 5 h in the hold, and the SSR's element going open at the tun's",
                    "drawn time (0.5–5.5 h). The shipped config otherwise. Must show: both faults",
                    f"told by the current input within one control period ({period:g} s) on every",
                    "tun, and no alarm on the normal stretch before either fault. The samples",
                    "that could show a fault are those with the SSR commanded off (a short) or",
                    "on (an open element), taken at the thirds of each part of a window long",
                    "enough to keep a read clear of its edges; with the input fitted no pulse or",
                    "gap is shorter than two reads take, and a window that would be fully on",
                    "short of full power is left off for two reads once the last off-sample is",
                    "a minute old, so that a short behind an SSR held fully on shows",
                    "(docs/current.md). An open element shows",
                    "only while the SSR is on, so at a low duty the first sample that could",
                    "show it may come more than a period after the fault (the pulses of two",
                    "windows join, one SSR edge a window): told within one period of that",
                    "sample is what any input can do.",
                ]
            ),
            f"- shorted SSR latched as ssr_stuck_on within one period: {within['short']}/{n}; "
            f"told after {spread('short')}",
            f"- open element latched as heater_not_heating within one period: "
            f"{within['dead']}/{n}; told after {spread('dead')}",
            f"- tuns with an alarm before a fault (false alarms on a normal stretch): {false}/{n}",
            "The tuns that miss:\n\n" + ("\n".join(lines) if len(lines) > 2 else "none"),
            f"{n * 2} simulated days {how}",
        ]
    )
    print(text)
    if args.write:
        sections.write("## Population: faults with an element-current input", text)
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tuns", type=int, default=200, help="tuns 1…N (default 200)")
    parser.add_argument("--jobs", type=int, default=2, help="processes (default 2)")
    parser.add_argument("--faults", action="store_true", help="the faults, not the brew days")
    parser.add_argument(
        "--current", action="store_true", help="with --faults: the element's current input fitted"
    )
    parser.add_argument("--write", action="store_true", help="update bench/RESULTS.md")
    parser.add_argument(
        "--minutes", type=float, default=math.inf, help="stop after this long: the tuns done"
    )
    parser.add_argument(
        "--keep", type=Path, help="also append each tun's figures to this file (JSON lines)"
    )
    parser.add_argument(
        "--from",
        dest="source",
        type=Path,
        help="instead of running: the tables from the figures --keep appended to this file",
    )
    args = parser.parse_args()
    if args.tuns < 1:
        parser.error(f"--tuns {args.tuns}: give at least 1")
    if args.current and not args.faults:
        parser.error("--current goes with --faults")
    if args.faults:
        return current_main(args) if args.current else faults_main(args)
    return brew_days_main(args)


if __name__ == "__main__":
    sys.exit(main())
