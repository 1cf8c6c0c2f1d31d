"""HERMS faults: the supervisor with the pump running, on a family (a benchmark, not a test).

The eight set-ups of bench/herms_cascade.py's family, each as a `hermsd.sim.mash.HermsTun`
through the daemon (`hermsd simulate`'s run, as bench/herms_daemon.py): the HLT (its litres
and element; UA 8 W/K at 90 L scaled by the surface, the element's heat 20 s late, its sensor
20 s behind), a coil passing K W/K (ε·ṁc at 6 L/min), hoses of 20 s each way, the mash (the
set-up's kg as 3/4 water and 1/4 grain, doughed in at its temperature, losing 6 W/K) read by
an LM92 45 s behind it; sensor noise 0.03 °C, seeds 1 and 2. The config states the tun and
the mash as they are (`herms.mash_litres`, `grain_kg`, `hose_s` 40, `mash_sensor_lag` 45; the
mash's losses guessed at 5 W/K), the pump hermsd switches, a contactor; the safety settings
are the shipped ones.

A normal HERMS day: the HLT at 70 °C, the mash's setpoint 63 °C; dough-in at 10 min, the pump
from 15 min, stopped from 50 to 55 min for stirring, the setpoint 72 °C at 75 min and 78 °C at
105 min, 2 h 10 min in all: every alarm raised. The faults at 65 min, in the 63 °C rest: the
element open (time to `heater_not_heating`) and the SSR shorted (time to `ssr_stuck_on`, and
the HLT's highest true temperature after it), with the pump running, and on the same day
with the pump stopped from 60 min on (the same tun without the coil's load); the worse of
the two seeds. Beside the element's times, when that seed's HLT law first asked for heat
after the fault: an open element shows only then (the HLT above its setpoint, as a coast or
a stopped pump leaves it, asks none).

    uv run python bench/herms_faults.py [--write] [--jobs 2]
"""

from __future__ import annotations

import argparse
import math
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import sections  # bench/sections.py, beside this file
from herms_cascade import FAMILY, MASH_LOSS, ROOM, SetUp

from hermsd.config.read import parse
from hermsd.sim import scenario

FLOW = 6.0  # L/min
FLOW_W_PER_K = FLOW / 60.0 * 4186.0
SEEDS = (1, 2)
FAULT_AT = 65 * 60.0
GRAIN_SHARE = 0.25  # of the mash's kg
GRAIN_C = 20.0


def _grain_and_water(s: SetUp) -> tuple[float, float, float]:
    """kg of grain, litres of water and the water's temperature that mix to the set-up's
    dough-in temperature."""
    grain = GRAIN_SHARE * s.mash_kg
    water = s.mash_kg - grain
    water_c = ((4186.0 * water + 1700.0 * grain) * s.dough_in - 1700.0 * grain * GRAIN_C) / (
        4186.0 * water
    )
    return grain, water, water_c


def _plant(s: SetUp, seed: int) -> dict[str, Any]:
    coil_ua = -FLOW_W_PER_K * math.log(1.0 - s.coil / FLOW_W_PER_K)  # ε·ṁc = K
    return {
        "model": "physical",
        "litres": s.litres,
        "element_watts": s.watts,
        "ua_w_per_k": s.hlt_loss,
        "transport_delay_s": 20.0,
        "sensor_lag_s": 20.0,
        "ambient_c": ROOM,
        "start_c": 70.0,
        "noise_c": 0.03,
        "seed": seed,
        "mash": {
            "coil_w_per_k": coil_ua,
            "flow_l_per_min": FLOW,
            "hose_to_coil_s": 20.0,
            "hose_to_mash_s": 20.0,
            "mash_ua_w_per_k": MASH_LOSS,
            "mash_sensor_lag_s": 45.0,
            "tun_heat_capacity_j_per_k": 0.0,
        },
    }


def _config(s: SetUp) -> str:
    grain, water, _ = _grain_and_water(s)
    return (
        "output:\n  backend: sim\nlog:\n  dir: null\ncontrol:\n  setpoint: 63\n"
        f"tun:\n  litres: {s.litres:g}\n  element_watts: {s.watts:g}\n"
        "mash_sensor:\n  kind: lm92\n  address: 0x49\npump:\n  backend: sim\n"
        "contactor:\n  backend: gpio\n  line: 27\n"
        f"herms:\n  mash_litres: {water:g}\n  grain_kg: {grain:g}\n  mash_loss_w_per_k: 5\n"
        "  hose_s: 40\n  mash_sensor_lag: 45\n"
    )


def _day(s: SetUp, seed: int, events: list[dict[str, Any]], duration: float) -> scenario.Result:
    grain, water, water_c = _grain_and_water(s)
    dough = {"grain_kg": grain, "grain_c": GRAIN_C, "water_litres": water, "water_c": water_c}
    doc = {
        "name": s.name(),
        "duration": duration,
        "setpoint": 63.0,
        "plant": _plant(s, seed),
        "events": [
            {"at": 600.0, "dough_in": dough},
            {"at": 900.0, "pump": "on"},
            {"at": 3000.0, "pump": "off"},
            {"at": 3300.0, "pump": "on"},
            *events,
        ],
    }
    return scenario.run(scenario.parse_scenario(doc), parse(_config(s)), keep_records=True)


def normal(s: SetUp, seed: int) -> list[str]:
    """The alarms of a normal day."""
    steps = [{"at": 4500.0, "setpoint": 72.0}, {"at": 6300.0, "setpoint": 78.0}]
    result = _day(s, seed, steps, 7800.0)
    return [f"{a['kind']} at {a['at_s']:.0f} s" for a in result.summary["alarms"]]


def fault(
    s: SetUp, seed: int, kind: str, pumped: bool
) -> tuple[float | None, float, str, float | None]:
    """s from the fault to the first alarm (None: none in the hour after), the HLT's highest
    true temperature after the fault, the alarm's kind, and s from the fault to the first
    period the HLT's law asked for heat (None: never in the hour): an element gone open can
    show only once heat is asked of it."""
    events: list[dict[str, Any]] = []
    if not pumped:
        events.append({"at": FAULT_AT - 300.0, "pump": "off"})
    events.append(
        {"at": FAULT_AT, "heater": "open"}
        if kind == "dead"
        else {"at": FAULT_AT, "ssr": "stuck_on"}
    )
    result = _day(s, seed, events, FAULT_AT + 3600.0)
    peak = max(x.temp for x in result.samples if x.t >= FAULT_AT)
    asked = next((r.t - FAULT_AT for r in result.records if r.t >= FAULT_AT and r.output > 0), None)
    alarms = result.summary["alarms"]
    if not alarms:
        return None, peak, "none", asked
    first = alarms[0]
    return float(first["at_s"]) - FAULT_AT, peak, str(first["kind"]), asked


WANTED = {"dead": "heater_not_heating", "ssr": "ssr_stuck_on"}


def _worst(s: SetUp, kind: str, pumped: bool) -> tuple[str, float]:
    """The slower seed's time to the right verdict (or, in bold, each seed's first alarm:
    none in the hour), the higher peak; for an open element, when that seed's law first
    asked for heat after the fault."""
    found = [fault(s, seed, kind, pumped) for seed in SEEDS]
    peak = max(p for _, p, _, _ in found)
    wrong = any(a != WANTED[kind] for _, _, a, _ in found)
    slower = max(found, key=lambda f: math.inf if f[0] is None else f[0])
    text = "**" + ", ".join(a for _, _, a, _ in found) + "**" if wrong else f"{slower[0]:.0f} s"
    if kind == "dead":
        asked = slower[3]
        text += " (no heat asked)" if asked is None else f" (heat asked from {asked:.0f} s)"
    return text, peak


def row(s: SetUp) -> str:
    """The set-up's line of the table."""
    quiet = [a for seed in SEEDS for a in normal(s, seed)]
    dead_on, _ = _worst(s, "dead", True)
    dead_off, _ = _worst(s, "dead", False)
    ssr_on, peak_on = _worst(s, "ssr", True)
    ssr_off, peak_off = _worst(s, "ssr", False)
    return (
        f"| {s.name()} | {', '.join(quiet) or 'none'} | {dead_on} | {dead_off} "
        f"| {ssr_on} | {ssr_off} | {peak_on:.2f} °C | {peak_off:.2f} °C |"
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--write", action="store_true", help="update bench/RESULTS.md")
    parser.add_argument("--jobs", type=int, default=2, help="set-ups run at once")
    args = parser.parse_args()
    lines = [
        "| set-up | normal day: alarms | element open: pump running | pump stopped "
        "| SSR shorted: pump running | pump stopped | HLT highest: pump running | pump stopped |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        for line in pool.map(row, FAMILY):
            lines.append(line)
            print(line, flush=True)
    text = "\n".join(lines)
    if args.write:
        intro = " ".join((__doc__ or "").split("\n\n")[1].split())
        days = " ".join((__doc__ or "").split("\n\n")[2].split())
        sections.write(
            "## HERMS faults: the supervisor with the pump running", f"{intro}\n\n{days}\n\n{text}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
