"""The HERMS pump start through the daemon: the HLT's drop when hermsd starts the pump (the
coil's load sent ahead by the element's dead time), and when a pump it does not switch is
seen starting (its coil outlet sensor), against full power from the pump's first instant.

Each set-up is `hermsd.sim.mash.HermsTun` around a physical HLT (litres, element, UA 17.8 W/K
at 90 L scaled by the surface, the element's heat 60 s on its way, the sensor's lag 10 s),
a coil of UA at 6 L/min, 10 s of hose each way, the mash's sensor 10 s behind it. The
daemon is configured with the tun's litres and element, the HLT's model as a tune measures
it (gain, τ, dead time 70 s), a mash and a coil outlet sensor (LM92), the coil's prior K the
coil's effective one (ṁc·(1 − e^(−UA/ṁc))) and the mash's water and grain. The HLT starts at
the outer loop's setpoint for a mash doughed in at 10 min, far below its rest (so the HLT
is readied at the limit, the mash's setpoint + 10 − 0.15 °C, and from the command on
steered to the climb's setpoint below it, `cascade.stop_room`); at 40 min the pump is
started:

- **commanded**: `set pump on` through the daemon (`pump.backend: sim`): the drop is the
  HLT's water's largest fall below the lesser of the water at the command and the HLT's
  setpoint in force, until 10 min after the pump ran (bench/herms.py's measure: once the
  pump runs, the climb's setpoint keeps room under the limit for an unannounced stop,
  `cascade.stop_room`, a setpoint the HLT is let down to, not a fall);
- **seen**: the pump switched outside hermsd (`pump.backend: none`), seen by the coil outlet
  sensor: the drop the same, from the water at the pump's start, in the 10 min after;
- **full power**: the same plant, copied at the seen start's first instant, with its element
  at full power from then: the least drop any control can give there.

The load at the start is the coil's effective K times the HLT over the mash.

    uv run python bench/herms_pump.py [--write]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path
from typing import Any

import sections  # bench/sections.py, beside this file

from hermsd.config.read import parse
from hermsd.runtime.period import PeriodRecord
from hermsd.sim import scenario
from hermsd.sim.hlt import PhysicalPlant
from hermsd.sim.mash import GRAIN_J_PER_KG_K

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from test_pump_start import TracedTun, fall_below

WATER = 4186.0
ROOM, DELAY_S, LAG_S, FLOW = 20.0, 60.0, 10.0, 6.0
DOUGH_AT, PUMP_AT, AFTER = 600.0, 2400.0, 600.0
HEADING = "## HERMS pump start: the HLT's drop, prepared and seen"


@dataclasses.dataclass(frozen=True)
class SetUp:
    litres: float
    watts: float
    coil: float  # the coil's UA, W/K
    mash_litres: float
    grain_kg: float
    mash_c: float  # the mash as doughed in
    rest: float  # its setpoint

    @property
    def ua(self) -> float:
        return 3000.0 / 168.9 * math.pow(self.litres / 90.0, 2.0 / 3.0)

    @property
    def effective(self) -> float:
        flow = FLOW / 60.0 * WATER
        return flow * (1.0 - math.exp(-self.coil / flow))

    @property
    def hlt(self) -> float:
        return self.rest + 10.0 - 0.15

    def name(self) -> str:
        return f"{self.litres:g} L {self.watts / 1000:g} kW, coil {self.coil:g} W/K"


FAMILY = (
    SetUp(90, 3000, 250, 50, 12, 45, 66),
    SetUp(90, 9000, 250, 50, 12, 45, 66),
    SetUp(40, 3500, 100, 25, 6, 45, 67),
    SetUp(70, 5500, 150, 40, 10, 45, 66),
    SetUp(150, 5500, 400, 70, 18, 45, 66),
    SetUp(150, 9000, 150, 70, 18, 45, 66),
    SetUp(120, 2000, 300, 60, 15, 45, 66),
)


def plant(s: SetUp) -> TracedTun:
    hlt = PhysicalPlant(
        litres=s.litres,
        element_watts=s.watts,
        ua_w_per_k=s.ua,
        transport_delay_s=DELAY_S,
        sensor_lag_s=LAG_S,
        ambient_c=ROOM,
        start_c=s.hlt,
    )
    return TracedTun(
        hlt,
        coil_w_per_k=s.coil,
        flow_l_per_min=FLOW,
        hose_to_coil_s=10.0,
        hose_to_mash_s=10.0,
        mash_ua_w_per_k=5.0,
        mash_sensor_lag_s=10.0,
    )


def config(s: SetUp, pump: str, dead_time: float = DELAY_S + LAG_S) -> str:
    capacity = WATER * s.litres
    return (
        "output:\n  backend: sim\nlog:\n  dir: null\n"
        f"tun:\n  litres: {s.litres:g}\n  element_watts: {s.watts:g}\n"
        f"control:\n  setpoint: {s.rest:g}\n  model_gain: {s.watts / (100 * s.ua):.4f}\n"
        f"  model_tau: {capacity / s.ua:.0f}\n  dead_time: {dead_time:g}\n"
        "mash_sensor:\n  kind: lm92\n  address: 0x49\n"
        "coil_sensor:\n  kind: lm92\n  address: 0x4a\n"
        f"pump:\n  backend: {pump}\n"
        f"herms:\n  mash_litres: {s.mash_litres:g}\n  grain_kg: {s.grain_kg:g}\n"
        f"  coil_w_per_k: {s.effective:.0f}\n  mash_loss_w_per_k: 4\n"
    )


def run(
    s: SetUp, pump: str, dead_time: float = DELAY_S + LAG_S
) -> tuple[TracedTun, list[PeriodRecord]]:
    """The set-up's day through the daemon, the pump started at PUMP_AT (through hermsd with
    `pump` sim, outside it with none), the HLT law's model's dead time `dead_time`."""
    tun = plant(s)
    water_c = (s.mash_c * (WATER * s.mash_litres + GRAIN_J_PER_KG_K * s.grain_kg)) / (
        WATER * s.mash_litres
    ) - GRAIN_J_PER_KG_K * s.grain_kg * ROOM / (WATER * s.mash_litres)
    dough = {"grain_kg": s.grain_kg, "grain_c": ROOM, "water_litres": s.mash_litres}
    events: list[dict[str, Any]] = [
        {"at": f"{DOUGH_AT:g}s", "dough_in": {**dough, "water_c": round(water_c, 2)}},
        {"at": f"{PUMP_AT:g}s", "pump": "on"},
    ]
    doc = {
        "name": "pump-start",
        "duration": f"{PUMP_AT + AFTER + 200:g}s",
        "setpoint": s.rest,
        "plant": {"model": "physical", "litres": s.litres, "element_watts": s.watts},
        "events": events,
    }
    day = scenario.parse_scenario(doc)
    result = scenario.run(
        day, parse(config(s, pump, dead_time)), outside_plant=tun, keep_records=True
    )
    return tun, result.records


def full_power(tun: TracedTun) -> tuple[float, float]:
    """The drop from the pump's first instant with the element at full power from then, and
    the coil's load at that instant (W)."""
    copied = tun.at_start
    assert copied is not None
    t0 = tun.started
    copied.set_heater(True, t0)
    load = copied.coil_watts(t0)
    start = copied.water_temperature(t0)
    low = min(copied.water_temperature(t0 + second) for second in range(int(AFTER) + 1))
    return start - low, load


def row(s: SetUp) -> tuple[str, dict[str, float]]:
    commanded, records = run(s, "sim")
    before = commanded.trace[max(t for t in commanded.trace if t <= PUMP_AT)]
    started = commanded.started
    prepared = fall_below(commanded, records, before, PUMP_AT, started + AFTER)
    seen_tun, seen_records = run(s, "none")
    at = seen_tun.trace[max(t for t in seen_tun.trace if t <= seen_tun.started)]
    seen = fall_below(seen_tun, seen_records, at, seen_tun.started, seen_tun.started + AFTER)
    ideal, load = full_power(seen_tun)
    exceeds = s.watts > load + s.ua * (s.hlt - ROOM)
    m = {"prepared": prepared, "seen": seen, "ideal": ideal, "exceeds": float(exceeds)}
    text = (
        f"| {s.name()} | {load:.0f} | {'yes' if exceeds else 'no'} | "
        f"{started - PUMP_AT:.0f} s | {prepared:.2f} | {seen:.2f} | {ideal:.2f} | "
        f"{seen / ideal:.2f} |"
    )
    return text, m


def wrong_dead_time() -> list[str]:
    """The commanded start where the element exceeds the load, the model's dead time other
    than the tun's 70 s: the drop, and the HLT's most above where it stood."""
    lines = [
        "| set-up | model's dead time s | pump ran after | drop °C | highest above °C |",
        "|---|---|---|---|---|",
    ]
    for s in FAMILY[1:4]:
        for dead_time in (40.0, 115.0):
            tun, records = run(s, "sim", dead_time)
            before = tun.trace[max(t for t in tun.trace if t <= PUMP_AT)]
            window = [c for t, c in tun.trace.items() if PUMP_AT <= t <= tun.started + AFTER]
            drop = fall_below(tun, records, before, PUMP_AT, tun.started + AFTER)
            lines.append(
                f"| {s.name()} | {dead_time:g} | {tun.started - PUMP_AT:.0f} s | "
                f"{drop:.2f} | {max(window) - before:.2f} |"
            )
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--write", action="store_true", help="update bench/RESULTS.md")
    args = parser.parse_args()
    lines = [
        "| set-up | load at start W | element exceeds load and losses | commanded: pump ran "
        "after | commanded drop °C | seen drop °C | full power drop °C | seen ÷ full power |",
        "|---|---|---|---|---|---|---|---|",
    ]
    worst_prepared, worst_ratio = 0.0, 0.0
    for s in FAMILY:
        text, m = row(s)
        lines.append(text)
        print(text, flush=True)
        if m["exceeds"]:
            worst_prepared = max(worst_prepared, m["prepared"])
        worst_ratio = max(worst_ratio, m["seen"] / m["ideal"])
    lines.append(
        f"\nWorst commanded drop where the element exceeds the load: {worst_prepared:.2f} °C; "
        f"worst seen start against full power from its first instant: ×{worst_ratio:.2f}."
    )
    lines += [
        "",
        "The commanded start on a model whose dead time is not the tun's (the config's "
        "default is 115 s; `hermsd tune` measures it):",
        "",
        *wrong_dead_time(),
    ]
    text = "\n".join(lines)
    print(text)
    if args.write:
        intro = "\n\n".join(" ".join(p.split()) for p in (__doc__ or "").split("\n\n")[1:4])
        sections.write(HEADING, f"{intro}\n\n{text}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
