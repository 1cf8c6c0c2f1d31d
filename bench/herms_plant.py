"""The HERMS plant (hermsd/sim/mash.py): what a pump start does to the HLT, and what a
HERMS day costs to simulate.

The plant of scenarios/herms-day.yaml: a 90 L, 3 kW HLT at 66 °C, 50 L of strike water and
12 kg of grain mixed to 38.0 °C, a 250 W/K coil at 6 L/min, 10 s of hose each way. The HLT's
fall at pump start is measured with the element off and with it at full power from the pump
start (no controller can do more), then under the daemon (scenarios/herms-day.yaml). The
cost: the plant alone over a 6-hour day read once a second with the heater switched every
5 s, and the 6-hour day through the daemon with and without the mash side.

    uv run python bench/herms_plant.py [--write]
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import sections  # bench/sections.py, beside this file

from hermsd.sim import scenario
from hermsd.sim.hlt import PhysicalPlant
from hermsd.sim.mash import HermsTun

DAY = Path(__file__).resolve().parents[1] / "scenarios" / "herms-day.yaml"
HEADING = "## HERMS plant: the HLT's fall at pump start, and a day's cost"
SIX_HOURS = 6 * 3600.0


def tun() -> HermsTun:
    """The plant of herms-day.yaml, doughed in at 0 s (the HLT's sensor lag: 10 s)."""
    spec = scenario.load_scenario(DAY).plant
    hlt = PhysicalPlant(
        **{k: v for k, v in spec.items() if k not in ("model", "mash", "noise_c", "seed")}
    )
    plant = HermsTun(hlt, **spec["mash"])
    plant.dough_in(12.0, 20.0, 50.0, 39.75, 0.0)
    return plant


def fall(heater: bool) -> str:
    """The pump on at 0: a table row of the coil's load, the HLT's sensor 5 and 10 min on,
    its lowest in 2 h and when, and the mash's sensor after 1 h."""
    plant = tun()
    plant.set_heater(heater, 0.0)
    plant.set_pump(True, 0.0)
    coil_w = plant.coil_watts(0.0)
    hlt, mash = {}, {}
    for second in range(7201):
        hlt[second] = plant.temperature(float(second))
        mash[second] = plant.mash_temperature(float(second))
    lowest = min(hlt, key=hlt.__getitem__)
    when = "still falling at 2 h" if lowest == 7200 else f"{lowest} s"
    element = "3 kW from the pump start" if heater else "off"
    return (
        f"| {element} | {coil_w:.0f} | {hlt[300]:.2f} | {hlt[600]:.2f} | {hlt[lowest]:.2f} "
        f"({when}) | {mash[3600]:.2f} |"
    )


def plant_day_s() -> float:
    """The plant alone, 6 h read each second, heater switched every 5 s, pump on at 1 h."""
    plant = tun()
    started = time.perf_counter()
    for second in range(1, int(SIX_HOURS) + 1):
        t = float(second)
        if second == 3600:
            plant.set_pump(True, t)
        if second % 5 == 0:
            plant.set_heater(plant.temperature(t) < 66.0, t)
        plant.temperature(t)
        plant.mash_temperature(t)
    return time.perf_counter() - started


def daemon_days() -> tuple[float, float]:
    """Wall s of the herms-day scenario lengthened to 6 h, and of that day without the mash
    side or its events (so without the recovery minimums run after each event)."""
    day = dataclasses.replace(scenario.load_scenario(DAY), duration=SIX_HOURS)
    herms = scenario.run(day).summary["wall_s"]
    plain_plant = {k: v for k, v in day.plant.items() if k != "mash"}
    plain_config = {k: v for k, v in day.config.items() if k != "mash_sensor"}
    plain = dataclasses.replace(day, plant=plain_plant, config=plain_config, events=())
    return float(herms), float(scenario.run(plain).summary["wall_s"])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.partition("\n\n")[0])
    parser.add_argument("--write", action="store_true", help="rewrite the section of RESULTS.md")
    write = parser.parse_args().write
    alone = plant_day_s()
    herms_s, plain_s = daemon_days()
    daemon = scenario.run(scenario.load_scenario(DAY))
    by_t = {s.t: s.temp for s in daemon.samples}
    alarms = ", ".join(f"{a['kind']} at {a['at_s']:g} s" for a in daemon.summary["alarms"])
    lines = [
        "The plant of `scenarios/herms-day.yaml`: a 90 L, 3 kW HLT at 66 °C; 50 L at 39.75 °C "
        "and 12 kg at 20 °C mixed to 38.0 °C; a 250 W/K coil (ε = 0.45 at 6 L/min), 10 s of "
        "hose each way, the tun's UA 10 W/K. The HLT's sensor (10 s lag), the pump started "
        "at 0 s:",
        "",
        "| element | coil at pump start W | HLT 5 min on °C | 10 min on °C "
        "| lowest in 2 h °C | mash after 1 h °C |",
        "|---|---|---|---|---|---|",
        fall(heater=False),
        fall(heater=True),
        "",
        f"Under the daemon (herms-day.yaml, setpoint 66 °C, pump on at 3900 s): the HLT "
        f"{by_t[3900.0]:.2f} °C at the pump start, {by_t[4200.0]:.2f} °C 5 min on, "
        f"{by_t[4500.0]:.2f} °C 10 min on; alarms: {alarms or 'none'}.",
        "",
        f"Cost: the plant alone over 6 h, read each second and its heater switched every 5 s "
        f"(pump on for 5 h): {alone:.3f} s. The herms-day lengthened to 6 h through the "
        f"daemon: {herms_s:.2f} s wall, against {plain_s:.2f} s for the same day without the "
        "mash side or its events (each event runs two recovery minimums, full power on copies "
        "of the plant to the day's end when the HLT cannot win back). Wall times on a shared "
        "2-core machine.",
    ]
    body = "\n".join(lines)
    print(body)
    if write:
        sections.write(HEADING, body)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
