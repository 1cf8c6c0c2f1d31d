"""Where hermsd's day 2 loses to CraftBeerPi's PIDHerms on a tun of the family, and why (a
diagnosis, not a test): the figures behind a "not ahead" of bench/robustness.py.

For each tun named (by the start of its name in `hermsd.sim.tuns.FAMILY`): hermsd's day 1
and day 2 (day 2 from the state day 1 left) and PIDHerms, on the brew day of
bench/robustness.py. Prints, on the sensor's temperature without its noise:
- the heat-up: the highest point above the setpoint before the water and when it came, and
  the hold's level from an hour after settling to the water (mean, highest): a peak in the
  hold is the hold's level, not the approach;
- the water: recovery, its minimum (full power from the water) and its floor (s);
- each period from the water until one delivers full power: the output asked at its start,
  its readings, `full_from` (after how many of them the daemon asked for full power inside
  the period) and the duty it delivered (the SSR's on-time alternates between a window's
  end and the next one's start, so a full_from may come while the element is on already).

    uv run --group bench python bench/not_ahead.py "thermowell 40" garage "big 150 L 5.5"
    uv run --group bench python bench/not_ahead.py "thermowell 40" --seeds 6
    uv run --group bench python bench/not_ahead.py --seeds 6 --jobs 2   # every tun
    uv run --group bench python bench/not_ahead.py --population-tun 17  # bench/population.py's
"""

from __future__ import annotations

import argparse
import itertools
import sys

from population import days_of, draw, missed_goals  # bench/population.py, beside this file
from robustness import (  # bench/robustness.py, beside this file
    AHEAD_KEYS,
    CBPI,
    DAY_1,
    DAY_2,
    SHIPPED,
    Summaries,
    behind,
    brew_days,
    missed,
    run_seeds,
)

from hermsd.config import read
from hermsd.sim import scenario
from hermsd.sim.tuns import FAMILY

WATER_S = 4 * 3600.0  # when the brew day adds its water (TunSpec.brew_day)
HOUR_S = 3600.0


def heat_up(label: str, result: scenario.Result, setpoint: float) -> None:
    before = [s for s in result.samples if s.t < WATER_S]
    peak = max(before, key=lambda s: s.temp)
    settled = result.summary["settle_s"]
    hold = [s.temp - setpoint for s in before if settled is not None and s.t >= settled + HOUR_S]
    level = f"mean {sum(hold) / len(hold):.4f}, highest {max(hold):.4f}" if hold else "–"
    print(
        f"{label}: heat-up peak {peak.temp - setpoint:.4f} °C at {peak.t:.0f} s "
        f"(settled at {settled} s); the hold from an hour after settling: {level} °C"
    )


def water(label: str, result: scenario.Result) -> None:
    s = result.summary
    print(
        f"{label}: recovery {s['recovery_s']} s, minimum {s['recovery_min_s']} s, "
        f"floor {s['recovery_floor_s']} s (×{s['recovery_ratio']})"
    )
    records = [r for r in result.records if r.t >= WATER_S]
    for record, after in itertools.pairwise(records):
        readings = ", ".join(f"{x:g}" for x in after.readings)
        print(
            f"  {record.t:.0f}–{after.t:.0f} s: asked {record.output:.1f} %, readings "
            f"[{readings}], full_from {after.full_from}, delivered {after.applied:.1f} %"
        )
        if after.applied >= 100.0:
            break


def seed_day(days: Summaries) -> tuple[list[str], list[str], str]:
    """One tun's `days` on one noise seed: where day 2 is behind PIDHerms, the goals day 1
    and day 2 miss, and the day's figures beside PIDHerms'."""
    mine, theirs = days[DAY_2], days[CBPI]
    misses = [f"day 1 {what}" for what in missed(days[DAY_1], DAY_1)]
    misses += [f"day 2 {what}" for what in missed(mine, DAY_2)]
    cells = ", ".join(f"{what} {mine[key]} ({theirs[key]})" for key, what in AHEAD_KEYS)
    return behind(mine, theirs), misses, cells


def seeds(indices: list[int], count: int, jobs: int) -> None:
    """Day 2 beside PIDHerms on each measure of `AHEAD_KEYS` under each noise seed, and the
    goals of both days: the seed by seed figures behind bench/robustness.py's means."""
    found = run_seeds(indices, count, jobs, peers=(CBPI,))
    ahead_days = met_days = 0
    for index in indices:
        print(f"## {FAMILY[index].name}")
        ahead = met = 0
        for seed in range(1, count + 1):
            worse, misses, cells = seed_day(found[(index, seed)])
            ahead += not worse
            met += not misses
            verdict = "ahead" if not worse else "not ahead on " + ", ".join(worse)
            goals = "goals met" if not misses else "misses " + ", ".join(misses)
            print(f"  seed {seed}: day 2 (PIDHerms) {cells}: {verdict}; {goals}")
        print(
            f"{FAMILY[index].name}: day 2 ahead of PIDHerms on every measure with {ahead} of "
            f"{count} seeds; both days meet their goals with {met}"
        )
        ahead_days, met_days = ahead_days + ahead, met_days + met
    days = len(indices) * count
    print(
        f"Seeds 1–{count} on {len(indices)} tuns: day 2 ahead of PIDHerms on every measure on "
        f"{ahead_days} of {days} days; both days meet their goals on {met_days} of {days}"
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("tuns", nargs="*", help="the start of a tun's name (--seeds: all)")
    parser.add_argument(
        "--seeds", type=int, default=0, help="instead: day 2 beside PIDHerms on noise seeds 1…N"
    )
    parser.add_argument("--jobs", type=int, default=2, help="processes for --seeds (default 2)")
    parser.add_argument(
        "--population-tun", type=int, default=0, help="instead: bench/population.py's tun SEED"
    )
    args = parser.parse_args()
    if args.population_tun:
        population_tun(args.population_tun)
        return 0
    indices = []
    for name in args.tuns:
        found = [i for i, spec in enumerate(FAMILY) if spec.name.startswith(name)]
        if len(found) != 1:
            names = "; ".join(spec.name for spec in FAMILY)
            print(f"{name!r} names {len(found)} tuns, not one: the family is {names}")
            return 2
        indices.append(found[0])
    if args.seeds:
        seeds(indices or list(range(len(FAMILY))), args.seeds, args.jobs)
        return 0
    if not indices:
        parser.error("name a tun (or ask for --seeds)")
    for index in indices:
        spec = FAMILY[index]
        print(f"## {spec.name}")
        results = brew_days(spec, peers=(CBPI,), keep_records=True)
        config = spec.config(read.load(SHIPPED))
        setpoint = scenario.effective_config(config, spec.brew_day()).control.setpoint
        show(results, setpoint)
    return 0


def show(results: dict[str, scenario.Result], setpoint: float) -> None:
    """Each day's heat-up, then day 2's and PIDHerms' recovery from the water."""
    for label, result in results.items():
        heat_up(label, result, setpoint)
    for label in (DAY_2, CBPI):
        water(label, results[label])


def population_tun(seed: int) -> None:
    """bench/population.py's tun `seed`: its parameters, the goals each day misses, and the
    figures of `show`."""
    tun, _ = draw(seed)
    print(f"## tun {seed}: {tun.words()}")
    results = days_of(tun, keep_records=True)
    for label, result in results.items():
        print(f"{label}: misses {', '.join(missed_goals(result.summary, label)) or 'nothing'}")
    show(results, scenario.effective_config(tun.config(), tun.day()).control.setpoint)


if __name__ == "__main__":
    sys.exit(main())
