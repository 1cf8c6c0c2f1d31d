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
release of the last approach) and what the element spent there, and when a `late` warning
was first said (one said of a day that was then ready in time is a false warning). Prints a
Markdown table; `--write` puts it into bench/RESULTS.md.

`--population N`: the same two days on tuns 1…N of bench/population.py (the shipped config
with the tun's configured litres and watts, the day's water ×½–×2 of them, its sensor and
noise; day 2 after its own brew day). The table is the pass rate and the days that missed,
each with whether a `late` warning said so before the time asked for (a tun that cannot be
ready must say it, not be silently late), and how many days a `late` was said of that were
then ready in time (false warnings).

    uv run python bench/program.py [--write] [--jobs 2] [--population N]
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

import population  # bench/population.py, beside this file
import sections  # bench/sections.py, beside this file

from hermsd.config import read
from hermsd.config.schema import Config
from hermsd.log.reader import load
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
POPULATION_HEADING = "## Population: strike water ready by the time asked for"
STRIKE = Program("Strike", (Step("Strike", 72.0, 600.0),), "05:00")
WAIT_AT = 72.0 - WAIT_BELOW
CLOCK = scenario._clock("2026-11-28T00:00:00+01:00", lambda key, what: scenario.ScenarioError(what))


def ready_days(index: int) -> list[dict[str, Any]]:
    """Day 1 (nothing learned) and day 2 (after an ordinary brew day) of tun `index`."""
    spec = FAMILY[index]
    return _two_days(spec.brew_day(), spec.config(read.load(SHIPPED)), spec.element_watts)


def population_days(seed: int) -> list[dict[str, Any]]:
    """The same two days on population tun `seed`, its own water, sensor and elements (each
    row with the tun's parameters in words)."""
    tun, _ = population.draw(seed)
    rows = _two_days(tun.day(), tun.config(), tun.spec.element_watts)
    return [row | {"tun": tun.words()} for row in rows]


def _two_days(brew_day: scenario.Scenario, config: Config, watts: float) -> list[dict[str, Any]]:
    """The strike program on `brew_day`'s tun from an empty state, then again after the
    brew day itself has been run on that state (what the daemon learned of the tun)."""
    day = dataclasses.replace(
        brew_day, events=(), duration=READY_S + 1800.0, program=STRIKE, clock=CLOCK
    )
    rows = []
    with tempfile.TemporaryDirectory(prefix="hermsd-state-") as state:
        rows.append(_ready_day(day, config, Path(state), watts))
        (Path(state) / PROGRAM_FILE).unlink()  # the brewer stops the program: the day is over
        scenario.run(brew_day, config, state_dir=Path(state))  # learns the tun
        rows.append(_ready_day(day, config, Path(state), watts))
    return rows


def _ready_day(day: scenario.Scenario, config: Config, state: Path, watts: float) -> dict[str, Any]:
    """One strike day on `state`: its row, with when a `late` warning was first said."""
    with tempfile.TemporaryDirectory(prefix="hermsd-log-") as logs:
        result = scenario.run(day, config, state_dir=state, keep_records=True, log_dir=Path(logs))
        said = [e.at for e in load(sorted(Path(logs).iterdir())).program if e.event == "late"]
    row = _row(result.summary) | _wait(result.records, watts)
    return row | {"late_s": said[0] if said else None}


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


def _signed(seconds: float | None) -> str:
    return "--" if seconds is None else f"{seconds:+.0f}"


def _minutes(seconds: float | None) -> str:
    return "--" if seconds is None else f"{seconds / 60.0:.0f} min"


def _kwh(kwh: float | None) -> str:
    return "--" if kwh is None else f"{kwh:.2f}"


def _judged(row: dict[str, Any]) -> bool:
    """Within GOAL_S of the time asked for, and no alarm."""
    error = row["error_s"]
    return error is not None and abs(error) <= GOAL_S and not row["alarms"]


def family_main(args: argparse.Namespace) -> int:
    started = time.perf_counter()
    lines = [
        "| tun | day | heating from | reached | error s | within 2 min | waited at 70 °C "
        "| kWh there | late said at |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    met = worst = 0.0
    days = never = false = 0
    with multiprocessing.get_context("fork").Pool(args.jobs) as pool:
        for spec, rows in zip(FAMILY, pool.imap(ready_days, range(len(FAMILY))), strict=True):
            for label, row in zip(("1", "2"), rows, strict=True):
                error = row["error_s"]
                ok = _judged(row)
                met += ok
                days += 1
                never += error is None
                worst = max(worst, abs(error) if error is not None else 0.0)
                false += ok and row["late_s"] is not None
                lines.append(
                    f"| {spec.name} | {label} | {_clock(row['start_s'])} | "
                    f"{_clock(row['reached_s'])} | "
                    f"{_signed(error)} | {'yes' if ok else 'no'} | "
                    f"{_minutes(row['waited_s'])} | {_kwh(row['wait_kwh'])} | "
                    f"{_clock(row['late_s'])} |"
                )
                print(lines[-1], flush=True)
    wall = time.perf_counter() - started
    tally = (
        f"Within 2 minutes of ready_by on {met:.0f} of {days} days; {never} not reached by "
        f"05:30, the largest error of the others {worst:.0f} s; a `late` said of {false} "
        f"days ready in time. {3 * len(FAMILY)} simulated days in {wall:.0f} s on "
        f"{args.jobs} processes."
    )
    print(tally)
    about = __doc__.split("\n\n")[1].split(" Prints")[0].replace("\n", " ")
    table = "\n".join(lines)
    text = f"{about} {tally}\n\n{table}\n"
    if args.write:
        sections.write(HEADING, text)
    return 0


def population_main(args: argparse.Namespace) -> int:
    started = time.perf_counter()
    seeds = range(1, args.population + 1)
    lines = [
        "| tun | parameters | day | heating from | reached | error s | late said at | alarms |",
        "|---|---|---|---|---|---|---|---|",
    ]
    met = [0, 0]
    said = [0, 0]
    false = [0, 0]
    with multiprocessing.get_context("fork").Pool(args.jobs) as pool:
        for seed, rows in zip(seeds, pool.imap(population_days, seeds), strict=True):
            for day, row in enumerate(rows):
                late = row["late_s"]
                if _judged(row):
                    met[day] += 1
                    false[day] += late is not None
                    continue
                said[day] += late is not None and late <= READY_S
                lines.append(
                    f"| {seed} | {row['tun']} | {day + 1} | "
                    f"{_clock(row['start_s'])} | {_clock(row['reached_s'])} | "
                    f"{_signed(row['error_s'])} | {_clock(late)} | {row['alarms']} |"
                )
                print(lines[-1], flush=True)
    wall = time.perf_counter() - started
    count = len(seeds)
    tally = (
        f"Within 2 minutes of ready_by, no alarm: day 1 {met[0]} of {count} tuns, day 2 "
        f"{met[1]} of {count}; of the days that missed, a `late` warning said so by 05:00 on "
        f"{said[0]} of {count - met[0]} (day 1) and {said[1]} of {count - met[1]} (day 2); "
        f"a `late` said of days then ready in time: {false[0]} (day 1), {false[1]} (day 2). "
        f"{3 * count} simulated days in {wall:.0f} s on {args.jobs} processes."
    )
    print(tally)
    about = __doc__.split("\n\n")[2].replace("\n", " ")
    text = f"{about} {tally}\n\nThe days that missed:\n\n" + "\n".join(lines) + "\n"
    if args.write:
        sections.write(POPULATION_HEADING, text)
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="update bench/RESULTS.md")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument(
        "--population", type=int, default=0, help="tuns 1…N of bench/population.py instead"
    )
    args = parser.parse_args()
    return population_main(args) if args.population else family_main(args)


if __name__ == "__main__":
    sys.exit(main())
