"""HERMS: the no-flow sign (a stuck bed) and the mash after it, as `hermsd simulate` runs it.

The daemon itself (`control/flow_watch.py` in `runtime/mash_control.py`) on a family of
HERMS plants (the HLT's size, element and sensor, the coil, the pump's flow, the mash's size,
its tun's losses and its sensor's lag), each with the HLT's sensor noise 0.03 °C under two
seeds (the mash sensor reads in the LM92's 0.0625 °C steps). Each day: the HLT at 66 °C, the
mash doughed in at 38 °C at 1 h, the pump started by hermsd at 1 h 5 min, the mash's setpoint
66 °C; the pump stopped 10 min at 2 h 30 min (stirring), the setpoint 72 °C at 3 h (the next
rest), 4 h in all. The herms keys are the mash's as doughed in, its losses guessed 5 W/K.
The normal day has nothing more; the stuck days have the bed stuck 10 min (the pump runs,
nothing flows) in the first climb (1 h 20 min) or near the rest (2 h).

Measured: on normal days the periods with the sign up (false signs: none wanted); on stuck
days the time from the bed sticking to the sign, from the bed freeing to its end, any sign
outside those, and the mash's highest reading above 66 °C from the bed's freeing to the
stirring stop (the overshoot the stuck bed leaves: at most 0.2 °C wanted); on every day the
mash's highest reading above each rest's setpoint (before 3 h 66 °C, after 72 °C).

    uv run python bench/herms_stuck.py [--write]
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from typing import Any

import sections  # bench/sections.py, beside this file

from hermsd.config.read import parse
from hermsd.runtime.period import PeriodRecord
from hermsd.sim import scenario

SP, NEXT_SP, STEP_AT, STIR_AT, STIR_S = 66.0, 72.0, 10800.0, 9000.0, 600.0
STUCK_S = 600.0
WATER, GRAIN = 4186.0, 1700.0


@dataclass(frozen=True)
class SetUp:
    """One brewery: the HLT (L, W, sensor lag s), the coil (W/K, L/min), the mash (L, kg,
    its tun's losses W/K, its sensor's lag s) and the hoses (s each way)."""

    litres: float
    watts: float
    hlt_lag: float
    coil: float
    flow: float
    mash_litres: float
    grain_kg: float
    mash_ua: float
    mash_lag: float
    hose: float

    def name(self) -> str:
        return (
            f"{self.litres:g} L {self.watts / 1000:g} kW, coil {self.coil:g} W/K "
            f"{self.flow:g} L/min, mash {self.mash_litres:g} L {self.grain_kg:g} kg "
            f"({self.mash_ua:g} W/K, lag {self.mash_lag:g} s)"
        )


FAMILY = (
    SetUp(90, 3000, 10, 250, 6, 50, 12, 10, 10, 10),  # herms-day's
    SetUp(50, 3500, 10, 150, 5, 25, 6, 6, 10, 10),
    SetUp(150, 5500, 20, 400, 8, 80, 20, 15, 30, 20),
    SetUp(40, 2000, 10, 100, 4, 20, 5, 4, 10, 10),
    SetUp(120, 3000, 40, 300, 6, 60, 15, 10, 60, 15),
    SetUp(70, 9000, 10, 200, 7, 40, 10, 8, 5, 10),
)
SEEDS = (1, 2)
STUCK_AT = {"normal": None, "stuck in the climb": 4800.0, "stuck near the rest": 7200.0}


def day(s: SetUp, seed: int, stuck_at: float | None) -> list[PeriodRecord]:
    grain, water = GRAIN * s.grain_kg, WATER * s.mash_litres
    strike = (38.0 * (grain + water) - 20.0 * grain) / water
    events: list[dict[str, Any]] = [
        {
            "at": 3600,
            "dough_in": {
                "grain_kg": s.grain_kg,
                "grain_c": 20,
                "water_litres": s.mash_litres,
                "water_c": round(strike, 2),
            },
        },
        {"at": 3900, "pump": "on"},
        {"at": STIR_AT, "pump": "off"},
        {"at": STIR_AT + STIR_S, "pump": "on"},
        {"at": STEP_AT, "setpoint": NEXT_SP},
    ]
    if stuck_at is not None:
        events += [
            {"at": stuck_at, "recirculation": "stuck"},
            {"at": stuck_at + STUCK_S, "recirculation": "ok"},
        ]
    plant = {
        "model": "physical",
        "litres": s.litres,
        "element_watts": s.watts,
        "sensor_lag_s": s.hlt_lag,
        "start_c": 66,
        "ambient_c": 20,
        "noise_c": 0.03,
        "seed": seed,
        "mash": {
            "coil_w_per_k": s.coil,
            "flow_l_per_min": s.flow,
            "hose_to_coil_s": s.hose,
            "hose_to_mash_s": s.hose,
            "mash_ua_w_per_k": s.mash_ua,
            "mash_sensor_lag_s": s.mash_lag,
            "tun_heat_capacity_j_per_k": 0,
        },
    }
    doc = {"name": "stuck", "duration": "4h", "setpoint": SP, "plant": plant, "events": events}
    config = parse(
        "output:\n  backend: sim\nlog:\n  dir: null\n"
        f"tun:\n  litres: {s.litres:g}\n  element_watts: {s.watts:g}\n"
        "mash_sensor:\n  kind: lm92\n  address: 0x49\npump:\n  backend: sim\n"
        f"herms:\n  mash_litres: {s.mash_litres:g}\n  grain_kg: {s.grain_kg:g}\n"
        f"  mash_loss_w_per_k: 5\n  hose_s: {2 * s.hose:g}\n  mash_sensor_lag: {s.mash_lag:g}\n"
    )
    return scenario.run(scenario.parse_scenario(doc), config, keep_records=True).records


def over(records: list[PeriodRecord], start: float, end: float, sp: float) -> float:
    return max(
        (r.mash - sp for r in records if start <= r.t < end and r.mash is not None),
        default=float("nan"),
    )


def measure(records: list[PeriodRecord], stuck_at: float | None) -> dict[str, Any]:
    signs = [r.t for r in records if r.cascade == "no flow"]
    m: dict[str, Any] = {
        "rest1": over(records, 3900.0, STEP_AT, SP),
        "rest2": over(records, STEP_AT, 4 * 3600.0, NEXT_SP),
    }
    if stuck_at is None:
        m["false"] = len(signs)
        return m
    free = stuck_at + STUCK_S
    during = [t for t in signs if t >= stuck_at]
    m["sign"] = during[0] - stuck_at if during else None
    after = [r.t for r in records if r.t > free and r.cascade != "no flow"]
    m["clear"] = after[0] - free if after and during else None
    m["false"] = len([t for t in signs if t < stuck_at or (after and t > after[0])])
    m["after"] = over(records, free, STIR_AT, SP)
    return m


def main() -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--write", action="store_true", help="update bench/RESULTS.md")
    args = parser.parse_args()
    lines = [
        "| plant | day | seed | sign after sticking | ended after freeing | false signs "
        "| mash over 66 °C after freeing | over 66 °C in rest 1 | over 72 °C in rest 2 |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    worst = {"sign": 0.0, "clear": 0.0, "false": 0, "after": -9.0, "rest": -9.0}
    for s in FAMILY:
        for label, stuck_at in STUCK_AT.items():
            for seed in SEEDS:
                m = measure(day(s, seed, stuck_at), stuck_at)
                worst["false"] += m["false"]
                worst["rest"] = max(worst["rest"], m["rest1"], m["rest2"])
                cells = ["", "", ""]
                if stuck_at is not None:
                    sign, clear = m["sign"], m["clear"]
                    cells = [
                        "none" if sign is None else f"{sign:.0f} s",
                        "never" if clear is None else f"{clear:.0f} s",
                        f"{m['after']:+.3f} °C",
                    ]
                    worst["sign"] = max(worst["sign"], float("inf") if sign is None else sign)
                    worst["clear"] = max(worst["clear"], float("inf") if clear is None else clear)
                    worst["after"] = max(worst["after"], m["after"])
                lines.append(
                    f"| {s.name()} | {label} | {seed} | {cells[0]} | {cells[1]} | {m['false']} "
                    f"| {cells[2]} | {m['rest1']:+.3f} °C | {m['rest2']:+.3f} °C |"
                )
                print(lines[-1], flush=True)
    summary = (
        f"Worst over the family: the sign {worst['sign']:.0f} s after the bed sticks, ended "
        f"{worst['clear']:.0f} s after it frees; {worst['false']} false signs; the mash "
        f"{worst['after']:+.3f} °C over its setpoint after the bed frees, "
        f"{worst['rest']:+.3f} °C over a rest's setpoint on any day."
    )
    print(summary)
    if args.write:
        about = [" ".join(part.split()) for part in (__doc__ or "").split("\n\n")[1:3]]
        body = "\n\n".join([*about, "\n".join(lines), summary])
        sections.write("## HERMS: the no-flow sign (a stuck bed) and the mash after it", body)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
