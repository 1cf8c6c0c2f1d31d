"""`ready_by` on the family of brewers' tuns: is the strike water there when it was asked for?

Each tun of `hermsd.sim.tuns.FAMILY` starts at its room's temperature at 00:00 (simulated
local time) with a one-step program, strike water at 72 °C, held 10 min, `ready_by: "05:00"`,
run through the real daemon with the shipped config (only the tun's litres and watts set to
the truth). Day 1 starts from an empty state directory, so the heat-up is timed by the
config's model; day 2 from the state an ordinary brew day left (the family's reference day,
ambient → 66 °C: bench/robustness.py), so by what the daemon learned of the tun. The error is
when the step was reached (the PV first within ±0.5 °C of 72 °C) less 05:00; the goal: within
2 minutes either way (not reached by 05:30: a miss). "Heating from" is when the climb first
started (it may stop for a while once the element's rate is measured). The energy side: how
long the water waited at the waiting temperature (from first within 0.5 °C of it to the
release of the last approach) and what the element spent there. Prints a Markdown table;
`--write` puts it into bench/RESULTS.md.

    uv run python bench/program.py [--write] [--jobs 2]
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import multiprocessing
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import sections  # bench/sections.py, beside this file

from hermsd.config import read
from hermsd.metrics import BAND
from hermsd.program.model import Program, Step
from hermsd.program.readiness import WAIT_BELOW
from hermsd.program.store import PROGRAM_FILE
from hermsd.runtime.period import PeriodRecord
from hermsd.sim import scenario
from hermsd.sim.tuns import FAMILY

SHIPPED = Path(__file__).resolve().parents[1] / "config" / "hermsd.yaml"
READY_S = 5 * 3600.0  # 05:00, from a start at 00:00
GOAL_S = 120.0
HEADING = "## Mash program: strike water ready by the time asked for"
STRIKE = Program("Strike", (Step("Strike", 72.0, 600.0),), "05:00")
WAIT_AT = 72.0 - WAIT_BELOW
CLOCK = scenario._clock("2026-11-28T00:00:00+01:00", lambda key, what: scenario.ScenarioError(what))


def ready_days(index: int) -> list[dict[str, Any]]:
    """Day 1 (nothing learned) and day 2 (after an ordinary brew day) of tun `index`."""
    spec = FAMILY[index]
    config = spec.config(read.load(SHIPPED))
    day = dataclasses.replace(
        spec.brew_day(), events=(), duration=READY_S + 1800.0, program=STRIKE, clock=CLOCK
    )
    rows = []
    with tempfile.TemporaryDirectory(prefix="hermsd-state-") as state:
        result = scenario.run(day, config, state_dir=Path(state), keep_records=True)
        rows.append(_row(result.summary) | _wait(result.records, spec.element_watts))
        (Path(state) / PROGRAM_FILE).unlink()  # the brewer stops the program: the day is over
        scenario.run(spec.brew_day(), config, state_dir=Path(state))  # learns the tun
        result = scenario.run(day, config, state_dir=Path(state), keep_records=True)
        rows.append(_row(result.summary) | _wait(result.records, spec.element_watts))
    return rows


def _wait(records: list[PeriodRecord], watts: float) -> dict[str, Any]:
    """Minutes at the waiting temperature before the release, and the element's kWh there."""
    arrived = released = None
    joules = 0.0
    for before, record in itertools.pairwise(records):
        if released is None and record.setpoint == 72.0 and arrived is not None:
            released = record.t
        if arrived is None and record.pv is not None and record.pv >= WAIT_AT - BAND:
            arrived = record.t
        if arrived is not None and released is None:
            joules += record.applied / 100.0 * watts * (record.t - before.t)
    if arrived is None or released is None:
        return {"waited_s": None, "wait_kwh": None}
    return {"waited_s": released - arrived, "wait_kwh": joules / 3.6e6}


def _row(summary: dict[str, Any]) -> dict[str, Any]:
    [strike] = summary["steps"] or [{"start_s": None, "reached_s": None}]
    reached = strike["reached_s"]
    return {
        "start_s": strike["start_s"],
        "reached_s": reached,
        "error_s": None if reached is None else reached - READY_S,
        "alarms": len(summary["alarms"]),
    }


def _clock(seconds: float | None) -> str:
    if seconds is None:
        return "--"
    minutes = round(seconds / 60.0)
    return f"{minutes // 60:02d}:{minutes % 60:02d}"


def _minutes(seconds: float | None) -> str:
    return "--" if seconds is None else f"{seconds / 60.0:.0f} min"


def _kwh(kwh: float | None) -> str:
    return "--" if kwh is None else f"{kwh:.2f}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="update bench/RESULTS.md")
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args()
    started = time.perf_counter()
    lines = [
        "| tun | day | heating from | reached | error s | within 2 min | waited at 70 °C "
        "| kWh there |",
        "|---|---|---|---|---|---|---|---|",
    ]
    met = worst = 0.0
    days = never = 0
    with multiprocessing.get_context("fork").Pool(args.jobs) as pool:
        for spec, rows in zip(FAMILY, pool.imap(ready_days, range(len(FAMILY))), strict=True):
            for label, row in zip(("1", "2"), rows, strict=True):
                error = row["error_s"]
                ok = error is not None and abs(error) <= GOAL_S and not row["alarms"]
                met += ok
                days += 1
                never += error is None
                worst = max(worst, abs(error) if error is not None else 0.0)
                lines.append(
                    f"| {spec.name} | {label} | {_clock(row['start_s'])} | "
                    f"{_clock(row['reached_s'])} | "
                    f"{'--' if error is None else f'{error:+.0f}'} | {'yes' if ok else 'no'} | "
                    f"{_minutes(row['waited_s'])} | {_kwh(row['wait_kwh'])} |"
                )
                print(lines[-1], flush=True)
    wall = time.perf_counter() - started
    tally = (
        f"Within 2 minutes of ready_by on {met:.0f} of {days} days; {never} not reached by "
        f"05:30, the largest error of the others {worst:.0f} s. {3 * len(FAMILY)} simulated "
        f"days in {wall:.0f} s on {args.jobs} processes."
    )
    print(tally)
    about = __doc__.split("\n\n")[1].split(" Prints")[0].replace("\n", " ")
    table = "\n".join(lines)
    text = f"{about} {tally}\n\n{table}\n"
    if args.write:
        sections.write(HEADING, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
