"""Weak tuns: when the daemon says full power cannot reach the setpoint, and how right it is.

Each tun runs a 12 h day at full power toward 66 °C through the daemon on the virtual clock
(noise sd 0.03 °C before the LM92's steps, no water added). The true ceiling is where the
simulated plant's element power equals its losses (hermsd/sim/hlt.py: UA·(T − T_room), plus
evaporation from the open surface with the lid off); the named one is what the warning said
(`setpoint_unreachable`, hermsd/control/reach.py). Then the family's near misses: tuns whose ceiling
lies 0.5 to 2 °C above the setpoint, where nothing may be said. Tuns named "2 el." have their
watts on two elements, 2/5.5 on the SSR and the rest on a contactor (min on and off 120 s),
shared out (the default) or mid-ranging: full power is both at theirs
(hermsd.control.reach.FullPower).

uv run python bench/reach.py
"""

from __future__ import annotations

import dataclasses
import logging
import sys
import time
from concurrent.futures import ProcessPoolExecutor

from hermsd.config import schema as config_module
from hermsd.sim import scenario
from hermsd.sim import tun_faults as tf
from hermsd.sim.hlt import BOILING_C, evaporation_w, pot_surface_m2
from hermsd.sim.tuns import FAMILY, TunSpec

DAY_S = 12 * 3600.0
SETPOINT = 66.0


def losses_w(spec: TunSpec, water_c: float, ua_w_per_k: float | None = None) -> float:
    """What the simulated tun loses at `water_c` (W): walls (UA, the spec's unless given), and
    the open surface."""
    ua = spec.ua_w_per_k if ua_w_per_k is None else ua_w_per_k
    walls = ua * (water_c - spec.ambient_c)
    if not spec.lid_off:
        return walls
    return walls + evaporation_w(water_c, spec.ambient_c, pot_surface_m2(spec.litres))


def true_ceiling(spec: TunSpec, ua_w_per_k: float | None = None) -> float:
    """Where the element's power equals the losses (bisection; the boil at most)."""
    low, high = spec.ambient_c, BOILING_C
    if losses_w(spec, high, ua_w_per_k) < spec.element_watts:
        return high
    for _ in range(60):
        middle = (low + high) / 2.0
        below = losses_w(spec, middle, ua_w_per_k) < spec.element_watts
        low, high = (middle, high) if below else (low, middle)
    return low


def unreachable_normal_days() -> list[str]:
    """The normal days of bench/faults.py whose water cannot reach the setpoint at all."""
    rows = []
    for spec in FAMILY:
        for fill, extra in ((1.0, 0.0), (0.5, 0.0), (2.0, 0.0), (0.5, 1000.0), (2.0, 1000.0)):
            day = tf.normal_day(spec, fill, extra)
            filled = dataclasses.replace(spec, litres=day.plant["litres"])
            ceiling = true_ceiling(filled, day.plant["ua_w_per_k"])
            if ceiling < SETPOINT:
                rows.append(f"| {day.name} | {ceiling:.2f} |")
    return rows


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
    TunSpec("150 L 2 el. lid off, 12 °C", 150, 2000, 1.5, 90, 20, 12, lid_off=True),
    TunSpec("150 L 2 el. lid off, 12 °C, midrange", 150, 2000, 1.5, 90, 20, 12, lid_off=True),
    with_ceiling(
        "70 L 2 el. lid off, 2 °C short", TunSpec("", 70, 0, 1.5, 60, 20, 12, lid_off=True), 64.0
    ),
)
NEAR = (
    with_ceiling("90 L lid on, 0.5 °C over", TunSpec("", 90, 0, 1.0, 60, 10, 20), 66.5),
    with_ceiling("90 L lid on, 1 °C over", TunSpec("", 90, 0, 1.0, 60, 10, 20), 67.0),
    with_ceiling(
        "70 L lid off, 0.5 °C over", TunSpec("", 70, 0, 1.5, 60, 20, 12, lid_off=True), 66.5
    ),
    with_ceiling("40 L thermowell, 1 °C over", TunSpec("", 40, 0, 1.2, 90, 60, 18), 67.0),
    with_ceiling("90 L 2 el. lid on, 0.5 °C over", TunSpec("", 90, 0, 1.0, 60, 10, 20), 66.5),
    with_ceiling(
        "70 L 2 el. lid off, 0.5 °C over, midrange",
        TunSpec("", 70, 0, 1.5, 60, 20, 12, lid_off=True),
        66.5,
    ),
)


SHARE2 = 3.5 / 5.5
"""A two-element tun's watts on its contactor's element (bench/two_element.py's 2 + 3.5 kW)."""
TWO = {
    "150 L 2 el. lid off, 12 °C": None,
    "150 L 2 el. lid off, 12 °C, midrange": "midrange",
    "70 L 2 el. lid off, 2 °C short": None,
    "90 L 2 el. lid on, 0.5 °C over": None,
    "70 L 2 el. lid off, 0.5 °C over, midrange": "midrange",
}
"""The tuns on two elements, by name, with the controller (None: the default, shared out)."""


def day_of(spec: TunSpec, seed: int) -> tuple[scenario.Scenario, config_module.Config]:
    """The 12 h day of `spec` and its config: on two elements if TWO names it."""
    day = dataclasses.replace(spec.brew_day(seed=seed), duration=DAY_S, events=())
    config = spec.config(config_module.DEFAULT)
    if spec.name not in TWO:
        return day, config
    watts2 = spec.element_watts * SHARE2
    watts1 = spec.element_watts - watts2
    element2 = dataclasses.replace(config.element2, backend="sim", watts=watts2)
    control = dataclasses.replace(config.control, algorithm=TWO[spec.name] or "predictive")
    tun = dataclasses.replace(config.tun, element_watts=watts1)
    config = dataclasses.replace(config, tun=tun, element2=element2, control=control)
    plant = {**day.plant, "element_watts": watts1, "element2_watts": watts2}
    return dataclasses.replace(day, plant=plant), config


def said(job: tuple[TunSpec, int]) -> tuple[str, int, float | None, float | None, float | None]:
    """(name, seed, when the warning was first said (s), the ceiling it named then, and the
    one it names at the day's end: each later sure estimate takes its place)."""
    spec, seed = job
    logging.getLogger("hermsd").setLevel(logging.ERROR)  # the table says what was said
    day, config = day_of(spec, seed)
    result = scenario.run(day, config, keep_records=True)
    first = next((r for r in result.records if r.ceiling is not None), None)
    at = None if first is None else first.t
    ceiling = None if first is None else first.ceiling
    return spec.name, seed, at, ceiling, result.records[-1].ceiling


def main() -> int:
    started = time.perf_counter()
    seeds = (1, 2, 3)
    jobs = [(spec, seed) for spec in (*WEAK, *NEAR) for seed in seeds]
    with ProcessPoolExecutor(2) as pool:
        results = list(pool.map(said, jobs))
    specs = {spec.name: spec for spec in (*WEAK, *NEAR)}
    truth = {name: true_ceiling(spec) for name, spec in specs.items()}
    print(
        "| tun | W | noise seed | true ceiling °C | said at | named ceiling °C | error °C "
        "| named at 12 h °C | error °C |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for name, seed, at, named, last in results:
        tun = f"| {name} | {specs[name].element_watts:.0f} | {seed} | {truth[name]:.2f} |"
        if at is None or named is None:
            print(f"{tun} never | – | – | – | – |")
            continue
        end = "– | –" if last is None else f"{last:.2f} | {last - truth[name]:+.2f}"
        print(f"{tun} {at / 3600.0:.2f} h | {named:.2f} | {named - truth[name]:+.2f} | {end} |")
    wall = time.perf_counter() - started
    print(f"\n{len(jobs)} simulated 12 h days in {wall:.0f} s on 2 processes.\n")
    print("Normal days of bench/faults.py on which full power cannot reach 66 °C at all:\n")
    print("| day | true ceiling °C |\n|---|---|")
    print("\n".join(unreachable_normal_days()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
