"""What a `program start` request costs the control socket's server thread to check.

The server checks the program while holding the interpreter's lock, which the control loop
needs at each SSR edge (a 10 ms half-cycle grid). Two requests, each as it arrives (JSON
parsed, then checked): the longest program a brewer can write (50 steps, every text at its
longest) and a refused one filling the 64 KiB line (50 steps with over-long names). Each is
checked by `program.model.from_data` (the data's nodes built directly) and, as the peer in
the same run, the way it was checked before (the data dumped to YAML text and parsed back).

    uv run python bench/program_parse.py [--repeat 200]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import time
from collections.abc import Callable
from typing import Any

from hermsd.api.protocol import MAX_LINE
from hermsd.config import read
from hermsd.program import model
from hermsd.runtime.scheduler import percentile


def longest_valid() -> dict[str, Any]:
    steps = [
        {
            "name": f"{index:02d}".ljust(model.NAME_LENGTH, "n"),
            "setpoint": 40.0 + index * 0.5,
            "hold": 3600.0,
            "ramp": 1.5,
            "confirm": "c" * model.MESSAGE_LENGTH,
        }
        for index in range(model.MAX_STEPS)
    ]
    return {"name": "n" * model.NAME_LENGTH, "ready_by": "06:30", "steps": steps}


def longest_refused() -> dict[str, Any]:
    program = longest_valid()
    room = MAX_LINE - len(json.dumps({"v": 1, "cmd": "program", "action": "start"})) - 200
    name_length = (room - len(json.dumps(program))) // model.MAX_STEPS + model.NAME_LENGTH
    for index, step in enumerate(program["steps"]):
        step["name"] = f"{index:02d}".ljust(name_length, "n")
    return program


def before(data: dict[str, Any]) -> None:
    """The check as it was: to YAML text and back through the file's reader."""
    cleaned = {key: value for key, value in data.items() if value is not None}
    cleaned["steps"] = [{k: v for k, v in s.items() if v is not None} for s in cleaned["steps"]]
    for step in cleaned["steps"]:  # a file's hold says its unit; the data's is seconds
        if isinstance(step.get("hold"), int | float):
            step["hold"] = f"{step['hold']:g}s"
    model.parse(read._yaml_text(cleaned), "program")


def after(data: dict[str, Any]) -> None:
    model.from_data(data, "program")


def timed(check: Callable[[dict[str, Any]], None], line: str, repeat: int) -> list[float]:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        with contextlib.suppress(model.ProgramError):
            check(json.loads(line)["program"])
        times.append(time.perf_counter() - start)
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=200)
    args = parser.parse_args()
    print("| request | bytes | check | p50 ms | p99 ms | max ms | before/after (p50) |")
    print("|---|---:|---|---:|---:|---:|---:|")
    for label, data in (("longest valid", longest_valid()), ("64 KiB refused", longest_refused())):
        line = json.dumps({"v": 1, "cmd": "program", "action": "start", "program": data})
        assert len(line) + 1 <= MAX_LINE, len(line)
        rows = {
            name: timed(check, line, args.repeat)
            for name, check in (("before", before), ("after", after))
        }
        ratio = percentile(sorted(rows["before"]), 50) / percentile(sorted(rows["after"]), 50)
        for name, times in rows.items():
            ms = sorted(1000.0 * t for t in times)
            shown = f"{ratio:.0f}×" if name == "after" else ""
            print(
                f"| {label} | {len(line) + 1} | {name} | {percentile(ms, 50):.2f} | "
                f"{percentile(ms, 99):.2f} | {max(ms):.2f} | {shown} |"
            )


if __name__ == "__main__":
    main()
