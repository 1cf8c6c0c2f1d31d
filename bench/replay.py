"""How long `hermsd replay` takes on a 24-hour log, whole command and stage by stage.

Logs a 24-hour day of the daemon on the simulated tun (20 → 66 °C, then holding) the way the
running daemon writes it, a chunk per flush (`simulate` of bench/log_bench.py; small chunks
are what makes a real log slow to read), then times `hermsd replay` as a user runs it (a new
Python process, best of three) for the summary, --verify and --what-if, and the stages
inside one process. Goal: the summary of a day in under 1 s.

    uv run python bench/replay.py [--write] [--against CHECKOUT [--label NAME]]

`--against` also times the summary command with the hermsd of another checkout (its
source directory; e.g. `git archive main | tar -x -C /tmp/main`) on the same log, turn
about with this one, for a ratio.
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import sections  # bench/sections.py, beside this file
from log_bench import simulate  # bench/log_bench.py: a day logged as the daemon logs it

from hermsd.commissioning import identify
from hermsd.log import reader, replay
from hermsd.log.mcap_file import LogFile


def best_of(runs: int, action: Callable[[], Any]) -> float:
    times = []
    for _ in range(runs):
        started = time.perf_counter()
        action()
        times.append(time.perf_counter() - started)
    return min(times)


def command(*args: str, source: Path | None = None) -> Callable[[], None]:
    """`hermsd replay ARGS` in a new process; with `source`, that checkout's hermsd."""
    env = None if source is None else {**os.environ, "PYTHONPATH": str(source)}

    def run() -> None:
        subprocess.run(
            [sys.executable, "-m", "hermsd.cli", "replay", *args],
            check=True,
            stdout=subprocess.DEVNULL,
            env=env,
        )

    return run


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="update bench/RESULTS.md")
    parser.add_argument(
        "--against", type=Path, help="another checkout whose summary command to time too"
    )
    parser.add_argument("--label", help="what to call that checkout (default: its path)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as directory:
        simulate(24.0, Path(directory))
        files = sorted(Path(directory).glob("*.mcap"))
        names = [str(p) for p in files]
        messages = sum(_recovered(p) for p in files)
        megabytes = sum(p.stat().st_size for p in files) / 1e6
        log = reader.load(names)
        rows = [
            ("`hermsd replay FILES`", best_of(3, command(*names))),
            ("`hermsd replay FILES --verify`", best_of(3, command(*names, "--verify"))),
            (
                "`hermsd replay FILES --what-if kc=80`",
                best_of(3, command(*names, "--what-if", "kc=80")),
            ),
            ("in process: read the files (`replay.load`)", best_of(3, lambda: reader.load(names))),
            ("in process: `replay.summarise`", best_of(3, lambda: replay.summarise(log))),
            ("in process: `replay.verify`", best_of(3, lambda: replay.verify(log.entries))),
            ("in process: fit the tun (`replay.identify`)", best_of(3, lambda: _identify(log))),
        ]
        periods = len(log.periods)
        if args.against is not None:
            ours, theirs = command(*names), command(*names, source=args.against.resolve())
            mine = other = math.inf
            for _ in range(3):  # turn about, so a busy moment costs both alike
                mine, other = min(mine, best_of(2, ours)), min(other, best_of(2, theirs))
            rows.append((f"`hermsd replay FILES`, {args.label or args.against}", other))
            rows.append(("`hermsd replay FILES`, this checkout, in the same turns", mine))
            rows.append((f"ratio: this checkout / {args.label or args.against}", mine / other))
    lines = ["| what | seconds |", "|---|---|"]
    lines += [f"| {what} | {seconds:.3f} |" for what, seconds in rows]
    table = "\n".join(lines)
    print(table)
    text = (
        "A 24-hour day of the daemon on the "
        "simulated tun (20 → 66 °C, then holding), logged as the daemon logs it (a chunk "
        f"per 2 s flush): {len(files)} files, {megabytes:.1f} MB, {messages} messages of "
        f"which {periods} control periods. Commands are a new Python process each, best of "
        "three. Goal: the summary in under 1 s (100,000× real time)."
        + (
            " The last rows take turns with another checkout on the same log (best of six "
            "each), so the load of a shared machine costs both alike."
            if args.against is not None
            else ""
        )
        + "\n\n"
        + table
        + "\n"
    )
    if args.write:
        sections.write("## Replay: a 24-hour log", text)
    return 0


def _recovered(path: Path) -> int:
    file = LogFile(path)
    for _ in file.messages(()):
        pass
    return file.recovered


def _identify(log: reader.Log) -> identify.TunModel:
    period_s = log.period_s()
    drops = reader.sudden_drops(log.elapsed, [p.pv for p in log.periods])
    n = identify.fit_span(log, drops, period_s)
    return identify.identify(
        [p.pv for p in log.periods[:n]], [p.applied for p in log.periods[:n]], period_s
    )


if __name__ == "__main__":
    sys.exit(main())
