"""Closed-loop comparison of every controller on the simulated HLT (a benchmark, not a test).

The plant is seed 001's identified FOPTD tun (K 1.689 °C/%, τ 14961 s, θ 115 s), read once a
second through the fake LM92 (0.0625 °C steps), 5 s control period and SSR window: heat
20 → 66 °C, add 10 L of 15 °C water at 4 h, stop at 6 h. Each algorithm runs with Table 2's
"ITAE-load" and "Ziegler-Nichols closed loop" PID sets, the default algorithm also with its
own default gains, and the peers of bench/peers.py (simple-pid 2.0.1, CraftBeerPi's
PIDHerms) with the same gains through the same daemon. Prints a Markdown table; `--write`
puts it into bench/RESULTS.md.

    uv run --group bench python bench/control.py [--write]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from typing import Any

import sections  # bench/sections.py, beside this file
from peers import ITAE_LOAD, PEERS, controlled_by  # bench/peers.py, beside this file

from hermsd.config import schema as config_module
from hermsd.control import pid
from hermsd.sim import scenario

GAIN_SETS = {
    "ITAE-load": ITAE_LOAD,
    "ZN closed loop": {"kc": 92.4, "ti": 230.0, "td": 57.5},
}
GOALS = {"overshoot_c": 0.1, "settle_ratio": 1.01, "recovery_ratio": 1.02, "max_output_jump": 10}


def run(algorithm: str, gains: dict[str, float]) -> dict[str, Any]:
    base = config_module.DEFAULT
    control = dataclasses.replace(
        base.control,
        algorithm="predictive" if algorithm in PEERS else algorithm,
        tf=None,
        kc=gains["kc"],
        ti=gains["ti"],
        td=gains["td"],
    )
    config = dataclasses.replace(base, control=control)
    if algorithm in PEERS:
        with controlled_by(algorithm, gains):
            return scenario.run(scenario.DEFAULT, config).summary
    return scenario.run(scenario.DEFAULT, config).summary


def meets(row: dict[str, Any]) -> bool:
    return all(row[k] is not None and row[k] <= limit for k, limit in GOALS.items()) and (
        row["in_band_fraction"] == 1.0
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="update bench/RESULTS.md")
    args = parser.parse_args()
    default = config_module.DEFAULT.control
    cases: list[tuple[str, str, dict[str, float]]] = [
        (
            default.algorithm,
            "default",
            {"kc": default.kc, "ti": default.ti, "td": default.td},
        )
    ]
    for set_name, gains in GAIN_SETS.items():
        for name in (*pid.ALGORITHMS, *PEERS):
            g = dict(gains)
            if name == "velocity_pi":
                g["td"] = 0.0  # a PI: the sets' Td has nowhere to go
            cases.append((name, set_name, g))
    lines = [
        "| algorithm | gains | overshoot °C | settle s | ×min | IAE °C·s | recovery s | ×min "
        "| jump/LSB % | edges/h | in band | goals |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    rows = []
    for name, set_name, gains in cases:
        row = run(name, gains)
        rows.append(row)
        lines.append(
            f"| {name} | {set_name} (Kc {gains['kc']}, Ti {gains['ti']}, Td {gains['td']}) "
            f"| {row['overshoot_c']:.3f} | {row['settle_s']} | {row['settle_ratio']} "
            f"| {row['iae']:.0f} | {row['recovery_s']} | {row['recovery_ratio']} "
            f"| {row['max_output_jump']:.1f} | {row['ssr_edges_per_hour']} "
            f"| {row['in_band_fraction']} | {'yes' if meets(row) else 'no'} |"
        )
        print(lines[-1], flush=True)
    first = rows[0]
    table = "\n".join(lines)
    text = (
        "20 → 66 °C, 10 L of 15 °C water at 4 h, 6 h; physical minimum to settle "
        f"{first['physical_min_s']} s, to recover {first['recovery_min_s']} s (full power "
        "from the start, and from the water). Settle and recovery: when the sensor entered "
        "the band for good, interpolated between the two 5 s period samples around it, as "
        "the minimums are crossing times (hermsd/metrics.py). "
        "Jump/LSB is the largest output change between "
        "two periods while holding. Goals: overshoot ≤ 0.1 °C, settle ≤ ×1.01, recovery "
        "≤ ×1.02, jump ≤ 10 %, 100 % in band.\n\n" + table + "\n"
    )
    if args.write:
        sections.write("## Control: every algorithm on the seed-001 plant", text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
