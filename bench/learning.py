"""The default controller on the family of tuns, day 1 and day 2 (a benchmark, not a test).

Each tun of `hermsd.sim.tuns.FAMILY` runs its brew day through the real daemon with the
shipped config (litres and watts true), day 1 from an empty state directory and day 2 on
what day 1 learned (the same directory). The sensor noise (0.03 °C before the LM92's
truncation) would alone put 0.14 °C of "overshoot" into the maximum of six hours of
readings, so the temperatures are measured on the tun's noise-free sensor; output jumps,
edges and alarms come from the daemon as it ran on the noisy readings. The heater watch is
given 1800 s: the supervisor's limits for these tuns are another change's work.
Recovery's minimum is full power from the moment of the water until the sensor is back in
the band (the simulator's own minimum returns 0 while the sensor lags the water).

    uv run python bench/learning.py [--write]
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from control import _replace_section

from hermsd import config as config_module
from hermsd.daemon import PeriodRecord
from hermsd.metrics import BAND, Sample, in_band_for_good
from hermsd.sim import hlt, scenario
from hermsd.sim.tuns import FAMILY, TunSpec

WATER_AT = 4 * 3600.0
GOALS = "day 2: overshoot ≤ 0.1 °C, settle ≤ ×1.01, recovery ≤ ×1.02, jump ≤ 10 %, 100 % in band"


class _Clean(scenario._Collector):
    """The simulator's collector, also keeping the sensor's noise-free temperature."""

    clean: list[tuple[float, float]]

    def period(self, record: PeriodRecord) -> None:
        super().period(record)
        self.clean.append((record.t, self.plant._sensor_c))  # type: ignore[attr-defined]


def _recovery_minimum(plant: hlt.Plant, start: float, setpoint: float) -> float:
    """Full power from `start` until the noise-free sensor, once below the band, is back."""
    plant = copy.deepcopy(plant)
    plant.set_heater(True, start)
    t, dipped = start, False
    while t - start < 4 * 3600.0:
        t += 1.0
        plant.temperature(t)
        sensor: float = plant._sensor_c  # type: ignore[attr-defined]
        dipped = dipped or sensor < setpoint - BAND
        if dipped and sensor >= setpoint - BAND:
            return t - start
    return float("nan")


def brew_day(spec: TunSpec, state: Path) -> dict[str, Any]:
    clean: list[tuple[float, float]] = []
    minimum: dict[str, float] = {}
    original_collector, original_band = scenario._Collector, scenario.time_to_band

    def collector(plant: hlt.Plant, **kwargs: Any) -> _Clean:
        made = _Clean(plant, **kwargs)
        made.clean = clean
        return made

    def time_to_band(plant: hlt.Plant, start: float, sp: float, limit: float) -> float | None:
        if start > 0.0:
            minimum["recovery"] = _recovery_minimum(plant, start, sp)
        return original_band(plant, start, sp, limit)

    base = config_module.DEFAULT
    base = dataclasses.replace(base, safety=dataclasses.replace(base.safety, heater_watch=1800.0))
    scenario._Collector, scenario.time_to_band = collector, time_to_band  # type: ignore[assignment,misc]
    try:
        summary = scenario.run(spec.brew_day(), spec.config(base), state_dir=state).summary
    finally:
        scenario._Collector, scenario.time_to_band = original_collector, original_band  # type: ignore[misc]
    sp = 66.0
    samples = [Sample(t, sp, temp, 0.0) for t, temp in clean]
    settled = in_band_for_good(samples, 0.0, WATER_AT)
    recovered = in_band_for_good(samples, WATER_AT, spec.brew_day().duration)
    first = next(t for t, temp in clean if abs(temp - sp) <= BAND)
    hold = [temp for t, temp in clean if t >= first and not WATER_AT <= t < (recovered or 0.0)]
    recovery_s = None if recovered is None else recovered - WATER_AT
    return {
        "overshoot_heat": max(temp for t, temp in clean if t < WATER_AT) - sp,
        "overshoot_water": max(temp for t, temp in clean if t >= WATER_AT) - sp,
        "settle_ratio": None if settled is None else settled / summary["physical_min_s"],
        "recovery_ratio": None if recovery_s is None else recovery_s / minimum["recovery"],
        "jump": summary["max_output_jump"],
        "in_band_pct": 100.0 * sum(abs(temp - sp) <= BAND for temp in hold) / len(hold),
        "last_hour_pp": max(t for _, t in clean[-720:]) - min(t for _, t in clean[-720:]),
        "edges_h": summary["ssr_edges_per_hour"],
        "alarms": [a["kind"] for a in summary["alarms"]],
    }


def two_days(spec: TunSpec) -> tuple[str, dict[str, Any], dict[str, Any]]:
    with tempfile.TemporaryDirectory() as state:
        return spec.name, brew_day(spec, Path(state)), brew_day(spec, Path(state))


def row(name: str, day: str, f: dict[str, Any]) -> str:
    def num(value: float | None, digits: int) -> str:
        return "—" if value is None else f"{value:.{digits}f}"

    return (
        f"| {name} | {day} | {num(f['overshoot_heat'], 3)} | {num(f['overshoot_water'], 3)} "
        f"| {num(f['settle_ratio'], 4)} | {num(f['recovery_ratio'], 4)} | {num(f['jump'], 1)} "
        f"| {num(f['in_band_pct'], 1)} | {num(f['last_hour_pp'], 3)} | {f['edges_h']} "
        f"| {', '.join(f['alarms']) or 0} |"
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="update bench/RESULTS.md")
    args = parser.parse_args()
    lines = [
        "| tun | day | overshoot heat-up °C | after water °C | settle ×min | recovery ×min "
        "| jump % | in band % | last hour p-p °C | edges/h | alarms |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    with ProcessPoolExecutor(2) as pool:
        for name, day1, day2 in pool.map(two_days, FAMILY):
            lines += [row(name, "1", day1), row(name, "2", day2)]
            print(lines[-2], lines[-1], sep="\n", flush=True)
    text = (
        "## Learning: predictive on the family of tuns, day 1 and day 2\n\n"
        "`uv run python bench/learning.py --write` — each tun's brew day (ambient → 66 °C, a "
        "tenth of its volume of 15 °C water at 4 h, 6 h, sensor noise 0.03 °C), shipped config "
        "with its litres and watts; day 2 on what day 1 learned. Temperatures on the "
        "noise-free sensor; in band counts the hold from first entering the band, the "
        f"recovery excluded. Goals: {GOALS}.\n\n" + "\n".join(lines) + "\n"
    )
    if args.write:
        _replace_section(Path(__file__).with_name("RESULTS.md"), "## Learning:", text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
