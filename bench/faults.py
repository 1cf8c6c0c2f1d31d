"""Every fault scenario through the daemon: when it was detected, how fast the heater went off.

Then the family of tuns (`hermsd.sim.tuns.FAMILY`): a normal day with half and twice the
configured water (and with 1 kW more loss at 66 °C on top of any evaporation) must raise
no alarm; an element that dies and an SSR that shorts (contactor fitted) in the hold must be
caught, with the supervisor's limits unmeasured and from the tun as measured.

With `--kind ds18b20` or `--kind max31865` the family's days run with that sensor, and each
of its traps is switched on for a minute in each tun's hold.

uv run python bench/faults.py [--write] [--family-only | --scenarios-only]
    [--kind lm92|ds18b20|max31865]
"""

from __future__ import annotations

import argparse
import dataclasses
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import sections  # bench/sections.py, beside this file

from hermsd.config import schema as config_module
from hermsd.safety.limits import LATCHED_KINDS
from hermsd.sim import scenario
from hermsd.sim import tun_faults as tf
from hermsd.sim.scenario import Event
from hermsd.sim.sensors import FAULTS
from hermsd.sim.tuns import FAMILY, TunSpec

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"


def scenario_rows() -> list[str]:
    lines = [
        "| scenario | fault at | alarm | detected after s | heater off after s | recovery |",
        "|---|---|---|---|---|---|",
    ]
    for path in sorted(SCENARIOS.glob("*.yaml")):
        if path.stem in ("default", "brew-day"):  # brew days, not faults
            continue
        sc = scenario.load_scenario(path)
        summary = scenario.run(sc).summary
        fault_at = ", ".join(f"{e.at:.0f} s {e.kind}" for e in sc.events) or "from the start"
        alarms = summary["alarms"] or [None]
        for alarm in alarms:
            if alarm is None:
                lines.append(f"| {path.stem} | {fault_at} | none | – | – | no alarm, no bump |")
                continue
            recovery = "latched" if alarm["kind"] in LATCHED_KINDS else "auto"
            lines.append(
                f"| {path.stem} | {fault_at} | {alarm['kind']} at {alarm['at_s']} s "
                f"| {alarm['detected_after_s']} | {alarm['heater_off_after_s']} | {recovery} |"
            )
        print(lines[-1], flush=True)
    return lines


Limits = bool | Path
"""Where the supervisor's limits come from: False unmeasured, True the tun's true model,
a state directory what the daemon learned there (a copy is used: the day may latch)."""


BASE = [config_module.DEFAULT]
"""The config every family day starts from (its sensor's kind set by --kind)."""


def _day(spec: TunSpec, sc: scenario.Scenario, limits: Limits) -> scenario.Result:
    config = spec.config(BASE[0])
    if isinstance(limits, Path):
        with tempfile.TemporaryDirectory(prefix="hermsd-state-") as state:
            shutil.copytree(limits, state, dirs_exist_ok=True)
            return scenario.run(sc, config, state_dir=Path(state), keep_records=True)
    return scenario.run(
        sc, config, tun_model=tf.measured(spec) if limits else None, keep_records=True
    )


UNREACHABLE: list[str] = []
"""The normal days on which the daemon said full power cannot reach the setpoint."""


def _unreachable(sc: scenario.Scenario, result: scenario.Result) -> str | None:
    """The `setpoint_unreachable` warning of a normal day, if it was said (and counted)."""
    first = next((r for r in result.records if r.ceiling is not None), None)
    if first is None or first.ceiling is None:
        return None
    UNREACHABLE.append(f"{sc.name} at {first.t:.0f} s (near {first.ceiling:.1f} °C)")
    return f"setpoint_unreachable at {first.t:.0f} s (near {first.ceiling:.1f} °C)"


def _learned(spec: TunSpec, state: Path) -> Path:
    """`state` after the tun's brew day at its configured fill: what the daemon learned."""
    day = spec.brew_day()
    result = scenario.run(day, spec.config(BASE[0]), state_dir=state, keep_records=True)
    _unreachable(day, result)
    return state


def _quiet(spec: TunSpec, sc: scenario.Scenario, limits: Limits = False) -> str:
    result = _day(spec, sc, limits)
    said = [f"{a['kind']} at {a['at_s']:.0f} s" for a in result.summary["alarms"]]
    warned = _unreachable(sc, result)
    return ", ".join(said + ([warned] if warned else [])) or "none"


def _caught(spec: TunSpec, sc: scenario.Scenario, kind: str, limits: Limits) -> dict[str, Any]:
    """Detection and heater-off latency of the first alarm, and how far the water went."""
    result = _day(spec, sc, limits)
    alarms = result.summary["alarms"]
    end = alarms[0]["at_s"] if alarms else sc.duration
    # A dead element: how far the water had cooled by the alarm. A shorted SSR: how hot it
    # got, the heat still on its way after the contactor opened included.
    if kind == "ssr_stuck_on":
        extreme = max(s.temp for s in result.samples if s.t >= tf.FAULT_AT)
    else:
        extreme = min(s.temp for s in result.samples if tf.FAULT_AT <= s.t <= end)
    if not alarms:
        return {"text": "**missed**", "extreme": extreme, "ok": False}
    first = alarms[0]
    ok = first["kind"] == kind and first["heater_off_after_s"] is not None
    text = f"{first['detected_after_s']:.0f}" if ok else f"**{first['kind']}**"
    return {"text": text, "off": first["heater_off_after_s"], "extreme": extreme, "ok": ok}


def family_rows() -> tuple[list[str], list[str]]:
    quiet = [
        "| tun | ×½ | ×2 | ×½, +1 kW | ×2, +1 kW | measured: ×½ | measured: ×2 "
        "| learned: ×½ | learned: ×2 |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    faults = [
        "| tun | element dies: detected after s | measured | learned | PV at the alarm °C "
        "| heater off s | SSR shorts: detected after s | measured | learned | highest PV °C "
        "| heater off s |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for spec in FAMILY:
        with tempfile.TemporaryDirectory(prefix="hermsd-learned-") as state:
            learned = _learned(spec, Path(state))
            half, double = tf.normal_day(spec, 0.5), tf.normal_day(spec, 2.0)
            cells = [
                _quiet(spec, half),
                _quiet(spec, double),
                _quiet(spec, tf.normal_day(spec, 0.5, 1000.0)),
                _quiet(spec, tf.normal_day(spec, 2.0, 1000.0)),
                _quiet(spec, half, True),
                _quiet(spec, double, True),
                _quiet(spec, half, learned),
                _quiet(spec, double, learned),
            ]
            quiet.append(f"| {spec.name} | " + " | ".join(cells) + " |")
            print(quiet[-1], flush=True)
            sources: tuple[Limits, ...] = (False, True, learned)
            dead = [_caught(spec, tf.element_dies(spec), "heater_not_heating", m) for m in sources]
            short = [_caught(spec, tf.ssr_shorts(spec), "ssr_stuck_on", m) for m in sources]
        faults.append(
            f"| {spec.name} | {dead[0]['text']} | {dead[1]['text']} | {dead[2]['text']} "
            f"| {dead[0]['extreme']:.2f} | {dead[0].get('off')} | {short[0]['text']} "
            f"| {short[1]['text']} | {short[2]['text']} | {short[0]['extreme']:.2f} "
            f"| {short[0].get('off')} |"
        )
        print(faults[-1], flush=True)
    return quiet, faults


SSR_SHARE = 2.0 / 5.5
"""Two elements: the family tun's watts split as the 2 kW SSR + 3.5 kW contactor pair's."""


def two_elements(spec: TunSpec, sc: scenario.Scenario) -> scenario.Scenario:
    """`sc` with the tun's watts on two elements: the SSR's share and a contactor's rest."""
    ssr_w = round(spec.element_watts * SSR_SHARE)
    plant = {**sc.plant, "element_watts": ssr_w, "element2_watts": spec.element_watts - ssr_w}
    element2 = {"backend": "sim", "watts": spec.element_watts - ssr_w}
    config = {**sc.config, "tun": {"element_watts": ssr_w}, "element2": element2}
    return dataclasses.replace(sc, plant=plant, config=config)


def _two_element_quiet(spec: TunSpec, sc: scenario.Scenario) -> str:
    """Alarms and element warnings on a two-element normal day."""
    result = scenario.run(
        two_elements(spec, sc), spec.config(config_module.DEFAULT), keep_records=True
    )
    said = [a["kind"] + f" at {a['at_s']:.0f} s" for a in result.summary["alarms"]]
    first = next(((r.t, no_heat) for r in result.records if (no_heat := r.no_heat)), None)
    if first is not None:
        t, no_heat = first
        said.append(f"element {no_heat[0]} warning at {t:.0f} s")
    return ", ".join(said) or "none"


def _two_element_fault(spec: TunSpec, kind: str, water: bool) -> str:
    """The first element warning and alarm after `kind` (an element open) at tf.FAULT_AT;
    `water` adds a tenth of the volume of 15 °C water again 30 min later."""
    day = tf.normal_day(spec)
    events = (*day.events, scenario.Event(tf.FAULT_AT, kind, "open"))
    if water:
        litres = {"litres": spec.litres / 10.0, "temp": 15.0}
        events += (scenario.Event(tf.FAULT_AT + 1800.0, "add_water", litres),)
    sc = two_elements(spec, dataclasses.replace(day, events=events))
    result = scenario.run(sc, spec.config(config_module.DEFAULT), keep_records=True)
    first = next((r for r in result.records if r.t >= tf.FAULT_AT and r.no_heat), None)
    said = [] if first is None else [f"{first.t - tf.FAULT_AT:.0f} s"]
    said += [f"{a['kind']} {a['detected_after_s']:.0f} s" for a in result.summary["alarms"][:1]]
    return ", ".join(said) or "**missed**"


TWO_ELEMENT_NOTE = (
    "A contactor's element that nothing asks for cannot be told dead: where the SSR's element "
    "holds the tun alone, the contactor stays open all through the hold (**missed** in that "
    "column); where it cannot, the supervisor latches heater_not_heating (on the garage pot "
    "after the watch told it: no longer asked, it leaves full power the SSR's alone, which "
    "cannot hold the pot: docs/two-elements.md). Asked for by the water at 5 h 30, the dead "
    "contactor's "
    "element is told on every tun but the small 30 L 5.5 kW, whose recovery on the SSR's 2 kW "
    "is over before the watch's windows may start after water (5 min and a dead time, then "
    "120 s past twice the dead time), and the 120 L thermowell, whose 300 s dead time puts a "
    "window's power 600 s back. A dead SSR element is told on every tun, sooner the more of "
    "the hold the SSR carries, slowest on the 120 L thermowell. The normal days include the "
    "heat-up's check (element2.check: the SSR's element off for 60 s, well below the "
    "setpoint): no warning from it either."
)


def two_element_rows() -> list[str]:
    rows = [
        "| tun | SSR + contactor W | ×½ | ×2 | ×½, +1 kW | ×2, +1 kW | SSR element dies "
        "| contactor element dies | … water at 5 h 30 |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for spec in FAMILY:
        ssr_w = round(spec.element_watts * SSR_SHARE)
        days = (
            tf.normal_day(spec, 0.5),
            tf.normal_day(spec, 2.0),
            tf.normal_day(spec, 0.5, 1000.0),
            tf.normal_day(spec, 2.0, 1000.0),
        )
        cells = [_two_element_quiet(spec, day) for day in days]
        cells += [
            _two_element_fault(spec, "heater", False),
            _two_element_fault(spec, "heater2", False),
            _two_element_fault(spec, "heater2", True),
        ]
        rows.append(
            f"| {spec.name} | {ssr_w} + {spec.element_watts - ssr_w:g} | "
            + " | ".join(cells)
            + " |"
        )
        print(rows[-1], flush=True)
    return rows


TRAP_AT = 5 * 3600.0
TRAP_FOR = 60.0


def trap_rows(kind: str) -> list[str]:
    """Each trap of `kind` for a minute in each tun's hold at 5 h: the first alarm, when it
    came and when the heater went off; and whether a PV during the trap was ever taken
    more than 1 °C from the water (a trap read as a temperature)."""
    traps = [f for f in FAULTS[kind] if f not in ("ok", "spike", "stuck", "slow")]
    rows = [
        "| tun | " + " | ".join(traps) + " |",
        "|---|" + "---|" * len(traps),
    ]
    for spec in FAMILY:
        cells = []
        for trap in traps:
            day = spec.brew_day()
            fault = Event(TRAP_AT, "sensor", (trap, None), TRAP_FOR)
            sc = dataclasses.replace(day, name=f"{spec.name} {trap}", events=(*day.events, fault))
            result = _day(spec, sc, False)
            alarms = result.summary["alarms"]
            taken = [
                r.pv
                for r in result.records
                if TRAP_AT <= r.t <= TRAP_AT + TRAP_FOR and r.pv is not None
            ]
            wrong = any(abs(pv - 66.0) > 1.0 for pv in taken)
            if not alarms:
                cells.append("**missed**")
                continue
            first = alarms[0]
            cell = (
                f"{first['kind']} {first['detected_after_s']:.0f} s, off "
                f"{first['heater_off_after_s']:.0f} s"
            )
            cells.append(cell + (" **PV taken**" if wrong else ""))
        rows.append(f"| {spec.name} | " + " | ".join(cells) + " |")
        print(rows[-1], flush=True)
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="update bench/RESULTS.md")
    parser.add_argument("--family-only", action="store_true", help="skip scenarios/*.yaml")
    parser.add_argument(
        "--scenarios-only", action="store_true", help="only scenarios/*.yaml, not the family"
    )
    parser.add_argument(
        "--two-elements", action="store_true", help="only the family on two elements"
    )
    parser.add_argument(
        "--kind", choices=tuple(FAULTS), default="lm92", help="the tun's sensor (default lm92)"
    )
    args = parser.parse_args()
    if args.kind != "lm92":
        return kind_main(args.kind, args.write)
    if args.two_elements:
        started = time.perf_counter()
        rows = two_element_rows()
        text = (
            "Each tun of the family "
            "with its watts on two elements, 2/5.5 of them on the SSR and the rest on a "
            "contactor (min on and off 120 s), the shipped default controller shared out "
            "(docs/two-elements.md); the normal days of the section above (×½, ×2, +1 kW), "
            "noise sd 0.03 °C. Alarms and element warnings (hermsd/safety/element_watch.py), the "
            "first of each: none is right. Then the configured fill with an element going "
            "open at 5 h: the time from it to the first warning and the first alarm "
            "(the contactor's element also with water added at 5 h 30, which asks it for "
            "heat).\n\n"
            + "\n".join(rows)
            + "\n\n"
            + TWO_ELEMENT_NOTE
            + f"\n\n{(len(rows) - 2) * 7} simulated days in "
            + f"{time.perf_counter() - started:.0f} s.\n"
        )
        print(text)
        if args.write:
            sections.write(
                "## Faults on the family: two elements, fills the config does not know", text
            )
        return 0
    if not args.family_only:
        table = "\n".join(scenario_rows())
        text = (
            "Each scenario in `scenarios/` on the "
            'virtual clock. "Detected after" counts from the injected fault (blank where the '
            "fault is a plant condition from the start or an operator's setpoint); \"heater "
            'off after" is from the alarm to the element losing power in the simulated '
            "circuit. Auto faults clear by themselves (a sensor fault after 5 good reads, "
            "over-temperature below max_temp − hysteresis); latched ones need a reset.\n\n"
            + table
            + "\n"
        )
        if args.write:
            sections.write("## Faults: detection and heater-off latency", text)
    if args.scenarios_only:
        return 0
    started = time.perf_counter()
    quiet, faults = family_rows()
    wall = time.perf_counter() - started
    text = (
        "Each tun of `hermsd.sim.tuns.FAMILY` "
        "(noise sd 0.03 °C) with its true litres and watts in the shipped config, through "
        "the daemon on the virtual clock. The brew day: ambient → 66 °C, a tenth of the water "
        "at 15 °C at 4 h, 6 h. Normal days with half and twice the configured water (UA "
        "scaled by the wetted area, volume^⅔; lid-off tuns also evaporate, as the simulator "
        'has it); "+1 kW" raises UA so that 1 kW more is lost at 66 °C, on top. '
        '"Measured": the supervisor is given the tun\'s true model at its configured '
        "fill (K = P/(100·UA), τ = m·c/UA, θ = delay + lag), as `hermsd tune` or the "
        'controller\'s learning would give it. "Learned": the daemon starts from the state '
        "directory its own brew day at the configured fill left (what the controller learned "
        "there, referred to `control.model_ambient`, not the real room), as day 2 of "
        "bench/robustness.py does.\n\n"
        "Alarms on normal days (none is right), and the warning that full power cannot "
        "reach the setpoint (`setpoint_unreachable`, hermsd/control/reach.py): right only where "
        "the water truly cannot, which `uv run python bench/reach.py` lists (four ×2 days, three "
        "of them with +1 kW). For comparison, the supervisor before "
        "these limits (commit 1ea9d7e's `hermsd/safety/supervisor.py` swapped in, measured once on "
        "that commit's simulator, without evaporation) "
        "raised 22 false latched alarms on the 36 ×½, ×2 and ×2 +1 kW days, and "
        "`heater_not_heating` 305 s into the 120 L thermowell's first heat-up at its "
        "configured fill.\n\n"
        + "\n".join(quiet)
        + "\n\nFaults in the hold at 5 h (configured fill; `heater: open`; `ssr: stuck_on` "
        "with a contactor). Detected after: from the fault to the alarm; heater off: from "
        "the alarm to the element losing power (the contactor opens for a shorted SSR). "
        "A dead element is judged once the output has reached 80 % (measured: the output "
        "that beats the tun's losses) and over the 300 s up to 150 s past the time heat "
        "takes to show (300 s unmeasured), so its time includes the controller's climb. "
        "PV at the alarm (lowest since the fault) and highest PV after the fault (the heat "
        "on its way when the contactor opened included): the sensor, unmeasured.\n\n"
        + "\n".join(faults)
        + f"\n\n{len(FAMILY) * 15} simulated days in {wall:.0f} s.\n"
    )
    print(text)
    print(
        f"setpoint_unreachable said on {len(UNREACHABLE)} of {len(FAMILY) * 9} normal days "
        f"(the configured fill and the table's): {'; '.join(UNREACHABLE) or 'none'}"
    )
    if args.write:
        sections.write("## Faults on the family: fills the config does not know", text)
    return 0


def kind_main(kind: str, write: bool) -> int:
    """The family's normal days and hold faults with a sensor of `kind`, then its traps."""
    BASE[0] = dataclasses.replace(
        config_module.DEFAULT,
        sensor=dataclasses.replace(config_module.DEFAULT.sensor, kind=kind),
    )
    started = time.perf_counter()
    quiet, faults = family_rows()
    traps = trap_rows(kind)
    wall = time.perf_counter() - started
    days = len(FAMILY) * (15 + len(traps[0].split("|")) - 3)
    text = (
        'The section "Faults on the family" with the tun read through a '
        + (
            "DS18B20 (w1, 750 ms conversions beside the loop)"
            if kind == "ds18b20"
            else "PT100 on a MAX31865 (430 Ω reference, 3-wire)"
        )
        + ", each day through its real driver on its fake (hermsd/sim/sensors.py). Goals as "
        "there: no alarm on a normal day, every fault in the hold caught.\n\n"
        + "\n".join(quiet)
        + "\n\nFaults in the hold at 5 h, as there:\n\n"
        + "\n".join(faults)
        + f"\n\nThe {kind}'s own traps, each switched on for {TRAP_FOR:.0f} s at 5 h in the "
        "hold (the tun's configured fill): the first alarm, from the trap to it, and from it "
        "to the element losing power; **PV taken** would mark a trap's value taken for the "
        "water (more than 1 °C from it); none is right.\n\n"
        + "\n".join(traps)
        + f"\n\n{days} simulated days in {wall:.0f} s.\n"
    )
    print(text)
    if write:
        sections.write(f"## Faults on the family with a {kind.upper()}: same goals", text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
