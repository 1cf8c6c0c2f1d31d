"""Weak tuns: when the daemon says full power cannot reach the setpoint, and how right it is.

Each tun runs a 12 h day at full power toward 66 °C through the daemon on the virtual clock
(noise sd 0.03 °C before the LM92's steps, no water added). The true ceiling is where the
simulated plant's element power equals its losses (hermsd/sim/hlt.py: UA·(T − T_room), plus
evaporation from the open surface with the lid off); the named one is what the warning said
(`setpoint_unreachable`, hermsd/reach.py). Then the family's near misses: tuns whose ceiling
lies 0.5 to 2 °C above the setpoint, where nothing may be said.

uv run python bench/reach.py
"""

from __future__ import annotations

import dataclasses
import logging
import sys
import time
from concurrent.futures import ProcessPoolExecutor

from hermsd import config as config_module
from hermsd.sim import scenario
from hermsd.sim.hlt import BOILING_C, evaporation_w, pot_surface_m2
from hermsd.sim.tuns import TunSpec

DAY_S = 12 * 3600.0
SETPOINT = 66.0


def losses_w(spec: TunSpec, water_c: float) -> float:
    """What the simulated tun loses at `water_c` (W): walls, and the open surface."""
    walls = spec.ua_w_per_k * (water_c - spec.ambient_c)
    if not spec.lid_off:
        return walls
    return walls + evaporation_w(water_c, spec.ambient_c, pot_surface_m2(spec.litres))


def true_ceiling(spec: TunSpec) -> float:
    """Where the element's power equals the losses (bisection; the boil at most)."""
    low, high = spec.ambient_c, BOILING_C
    if losses_w(spec, high) < spec.element_watts:
        return high
    for _ in range(60):
        middle = (low + high) / 2.0
        low, high = (middle, high) if losses_w(spec, middle) < spec.element_watts else (low, middle)
    return low


def with_ceiling(name: str, spec: TunSpec, ceiling: float) -> TunSpec:
    """`spec` with the element that levels its water out at `ceiling` °C."""
    return dataclasses.replace(spec, name=name, element_watts=losses_w(spec, ceiling))


WEAK = (
    TunSpec("150 L 2 kW lid off, 12 °C", 150, 2000, 1.5, 90, 20, 12, lid_off=True),
    TunSpec("120 L 1.5 kW lid off, 5 °C", 120, 1500, 1.5, 60, 20, 5, lid_off=True),
    with_ceiling("90 L lid on, 2 °C short", TunSpec("", 90, 0, 1.0, 60, 10, 20), 64.0),
    with_ceiling(
        "70 L lid off, 2 °C short", TunSpec("", 70, 0, 1.5, 60, 20, 12, lid_off=True), 64.0
    ),
    with_ceiling("120 L thermowell, 4 °C short", TunSpec("", 120, 0, 1.0, 180, 120, 15), 62.0),
)
NEAR = (
    with_ceiling("90 L lid on, 0.5 °C over", TunSpec("", 90, 0, 1.0, 60, 10, 20), 66.5),
    with_ceiling("90 L lid on, 1 °C over", TunSpec("", 90, 0, 1.0, 60, 10, 20), 67.0),
    with_ceiling(
        "70 L lid off, 0.5 °C over", TunSpec("", 70, 0, 1.5, 60, 20, 12, lid_off=True), 66.5
    ),
    with_ceiling("40 L thermowell, 1 °C over", TunSpec("", 40, 0, 1.2, 90, 60, 18), 67.0),
)


def said(job: tuple[TunSpec, int]) -> tuple[str, int, float | None, float | None]:
    """(name, seed, when the warning was first said (s), the ceiling it named then)."""
    spec, seed = job
    logging.getLogger("hermsd").setLevel(logging.ERROR)  # the table says what was said
    day = dataclasses.replace(spec.brew_day(seed=seed), duration=DAY_S, events=())
    result = scenario.run(day, spec.config(config_module.DEFAULT), keep_records=True)
    first = next((r for r in result.records if r.ceiling is not None), None)
    return spec.name, seed, None if first is None else first.t, first and first.ceiling


def main() -> int:
    started = time.perf_counter()
    seeds = (1, 2, 3)
    jobs = [(spec, seed) for spec in (*WEAK, *NEAR) for seed in seeds]
    with ProcessPoolExecutor(2) as pool:
        results = list(pool.map(said, jobs))
    truth = {spec.name: true_ceiling(spec) for spec in (*WEAK, *NEAR)}
    print("| tun | noise seed | true ceiling °C | said at | named ceiling °C | error °C |")
    print("|---|---|---|---|---|---|")
    for name, seed, at, named in results:
        if at is None or named is None:
            print(f"| {name} | {seed} | {truth[name]:.2f} | never | – | – |")
            continue
        error = named - truth[name]
        print(
            f"| {name} | {seed} | {truth[name]:.2f} | {at / 3600.0:.2f} h | {named:.2f} "
            f"| {error:+.2f} |"
        )
    wall = time.perf_counter() - started
    print(f"\n{len(jobs)} simulated 12 h days in {wall:.0f} s on 2 processes.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
