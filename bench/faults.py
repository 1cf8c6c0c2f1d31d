"""Every fault scenario through the daemon: when it was detected, how fast the heater went off.

uv run python bench/faults.py [--write]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from control import _replace_section  # bench/control.py, beside this file

from hermsd.safety import LATCHED_KINDS
from hermsd.sim import scenario

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="update bench/RESULTS.md")
    args = parser.parse_args()
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
    table = "\n".join(lines)
    text = (
        "## Faults: detection and heater-off latency\n\n"
        "`uv run python bench/faults.py --write` — each scenario in `scenarios/` on the "
        'virtual clock. "Detected after" counts from the injected fault (blank where the '
        "fault is a plant condition from the start or an operator's setpoint); \"heater off "
        'after" is from the alarm to the element losing power in the simulated circuit. '
        "Auto faults clear by themselves (a sensor fault after 5 good reads, over-temperature "
        "below max_temp − hysteresis); latched ones need a reset.\n\n" + table + "\n"
    )
    if args.write:
        _replace_section(Path(__file__).with_name("RESULTS.md"), "## Faults:", text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
