"""The heat-up's fit behind slow sensors: how close to the true rate a taken fit lies.

The ramp is the formula of docs/heat-up-fit.md (a delay, then a first-order sensor lag on
the water's ramp), each reading with Gaussian noise and rounded to the LM92's LSB, five a
period, their mean the period's PV, fed to the controller's watch (`control/watches.py`)
until it fits or the PV has risen 40 °C (a 20 → 60 °C heat-up; the step ends there).
Over a grid of rates 0.003–0.15 °C/s, delays 10–300 s, lags 0–150 s, noise sd
0–0.06 °C, `--seeds` noise seeds each: the fits taken (their rate ÷ the true one, the
dead time against delay + lag) and the refusals.

    uv run python bench/heat_up_fit.py [--seeds 2] [--write]
"""

from __future__ import annotations

import argparse
import itertools
import math
import random

import sections  # bench/sections.py, beside this file

from hermsd.control.pid import SENSOR_LSB
from hermsd.control.watches import HeatUpFit, _HeatUpWatch

TS = 5.0
READS = 5
TOP = 40.0
RATES = (0.003, 0.01, 0.03, 0.08, 0.15)
DELAYS = (10.0, 60.0, 150.0, 300.0)
LAGS = (0.0, 20.0, 60.0, 100.0, 150.0)
NOISES = (0.0, 0.03, 0.06)


def rise(t: float, rate: float, delay: float, lag: float) -> float:
    u = t - delay
    if u <= 0.0:
        return 0.0
    return rate * (u - lag * (1.0 - math.exp(-u / lag))) if lag > 0.0 else rate * u


def heat_up(rate: float, delay: float, lag: float, noise: float, seed: int) -> HeatUpFit | None:
    """The watch's verdict on one ramp: a fit, a refusal, or None (ended without a test)."""
    rng = random.Random(seed)
    pv0 = 20.0 + rng.random()  # where the LSB's steps fall differs from one day to the next
    watch = _HeatUpWatch()
    watch.arm(pv0, 100.0)
    k = 0
    while True:
        k += 1
        reads = (
            pv0 + rise((k - 1 + (j + 0.5) / READS) * TS, rate, delay, lag) + rng.gauss(0, noise)
            for j in range(READS)
        )
        pv = sum(round(r / SENSOR_LSB) * SENSOR_LSB for r in reads) / READS
        if pv - pv0 > TOP:
            return watch.ended(TS, rate)
        fit = watch.add(pv, TS, 0.0, rate)
        if fit is not None:
            return fit


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=2, help="noise seeds a ramp")
    parser.add_argument("--write", action="store_true", help="update bench/RESULTS.md")
    args = parser.parse_args()
    taken: list[tuple[float, float, str]] = []
    refused = silent = 0
    grid = itertools.product(RATES, DELAYS, LAGS, NOISES, range(args.seeds))
    for rate, delay, lag, noise, seed in grid:
        fit = heat_up(rate, delay, lag, noise, seed)
        if fit is None:
            silent += 1
        elif fit.refused is not None:
            refused += 1
        else:
            ramp = f"{rate} °C/s, delay {delay:.0f} s, lag {lag:.0f} s, noise {noise} °C"
            taken.append((fit.rate / rate, fit.dead_time - (delay + lag), ramp))
    taken.sort()
    ratios = [r for r, _, _ in taken]
    count = len(taken) + refused + silent
    rows = [
        "| fits taken | rate ÷ true: lowest | 5th percentile | median | highest "
        "| dead time − (delay + lag) s: least | most | refused (still bent) | no verdict |",
        "|---|---|---|---|---|---|---|---|---|",
        f"| {len(taken)} of {count} | {ratios[0]:.3f} | {ratios[len(ratios) // 20]:.3f} "
        f"| {ratios[len(ratios) // 2]:.3f} | {ratios[-1]:.3f} "
        f"| {min(d for _, d, _ in taken):.0f} | {max(d for _, d, _ in taken):.0f} "
        f"| {refused} | {silent} |",
    ]
    lowest = "; ".join(f"{r:.3f} ({ramp})" for r, _, ramp in taken[:3])
    text = "\n\n".join(
        [
            " ".join(
                [
                    f"{count} ramps (bench/heat_up_fit.py's grid, {args.seeds} noise seeds",
                    "each) through the heat-up's watch: a fit is taken only where the ramp's",
                    "last two quarters climb alike, and is then of the whole rise to the lag's",
                    "own curve (docs/heat-up-fit.md). The refused ones are fast tuns behind",
                    "long lags whose ramp was still bending after 40 °C.",
                ]
            ),
            "\n".join(rows),
            f"The three lowest: {lowest}.",
        ]
    )
    print(text)
    if args.write:
        sections.write("## Heat-up fit: the rate behind slow sensors", text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
