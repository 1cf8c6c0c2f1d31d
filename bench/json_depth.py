"""What reading a request's JSON costs the control socket's server thread, its nesting bound
included (hermsd.api.jsontext.loads, as parse_request reads every line).

The server thread holds the interpreter's lock while it reads a line, and the control loop
waits for that lock at each SSR edge: every burst must stay short, whatever a client sends.
Lines: a `status` request, the costliest `program start` a line holds (bench/program_parse.py's
64 KiB refused program), and 64 KiB lines built to be costly to bound: brackets only, brackets
nested just past the bound over and over, and just within it in one value. Each row: the
bound alone (`deeper_than`), the whole read (`loads`, refused or not), and `json.loads` of the
same line for scale (it refuses all but the program start: not JSON, or too deep for its
stack).

    uv run python bench/json_depth.py [--repeat 50]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import time
from collections.abc import Callable
from functools import partial

from program_parse import longest_refused  # bench/program_parse.py, beside this file

from hermsd.api.jsontext import MAX_DEPTH, deeper_than, loads
from hermsd.api.protocol import MAX_LINE
from hermsd.runtime.scheduler import percentile

PROGRAM = {"v": 1, "cmd": "program", "action": "start", "program": longest_refused()}
PAST = "[" * (MAX_DEPTH + 1) + "]" * (MAX_DEPTH + 1)
WITHIN = "[" * (MAX_DEPTH - 1) + "]" * (MAX_DEPTH - 1)


def lines() -> list[tuple[str, str]]:
    fill = MAX_LINE - 1
    return [
        ("status", '{"v": 1, "cmd": "status"}'),
        ("64 KiB program start", json.dumps(PROGRAM, ensure_ascii=False)),
        ("64 KiB of '[]'", "[]" * (fill // 2)),
        ("64 KiB of '['", "[" * fill),
        (f"64 KiB of {MAX_DEPTH + 1} deep", PAST * (fill // len(PAST))),
        (f"64 KiB {MAX_DEPTH} deep in one", "[" + WITHIN * ((fill - 2) // len(WITHIN)) + "]"),
    ]


def timed(work: Callable[[], object], repeat: int) -> list[float]:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        with contextlib.suppress(ValueError, RecursionError):  # refused: timed all the same
            work()
        times.append(1000.0 * (time.perf_counter() - start))
    return sorted(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=50)
    args = parser.parse_args()
    print(f"| line | bytes | deeper than {MAX_DEPTH} | read | p50 ms | p99 ms | max ms |")
    print("|---|---:|---:|---|---:|---:|---:|")
    for label, text in lines():
        data = text.encode()
        assert len(data) < MAX_LINE, label
        reads: list[tuple[str, Callable[[], object]]] = [
            ("deeper_than", partial(deeper_than, text, MAX_DEPTH)),
            ("loads", partial(loads, data, MAX_LINE)),
            ("json.loads", partial(json.loads, data)),
        ]
        for name, work in reads:
            ms = timed(work, args.repeat)
            print(
                f"| {label} | {len(data)} | {deeper_than(text, MAX_DEPTH)} | {name} | "
                f"{percentile(ms, 50):.3f} | {percentile(ms, 99):.3f} | {max(ms):.3f} |"
            )


if __name__ == "__main__":
    main()
