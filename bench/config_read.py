"""What reading the config file costs the control loop, on the loop and off it.

For the shipped file, a file of the largest size read (the shipped file padded with
comments) and a 50 MB one (refused by its size): how long `ConfigFile.poll` holds its
caller when the check runs on the caller's thread (`at_once`, as every reload did before)
and when it runs on the reader thread (`in_thread`, as the daemon now does), the median
of several polls each; and, while the reader thread parses the largest file, the lateness of
a 10 ms ticker on the calling thread (the GIL is shared), against the same ticker idle.

    uv run python bench/config_read.py
"""

from __future__ import annotations

import os
import platform
import statistics
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

from hermsd.config.file import ConfigFile, Start, at_once, in_thread
from hermsd.config.read import MAX_FILE_BYTES

SHIPPED = Path(__file__).parent.parent / "config" / "hermsd.yaml"
POLLS = 5
TICK = 0.01


def held_ms(path: Path, start: Start) -> tuple[float, float]:
    """Median time `poll(force=True)` holds its caller, and median time to the result, in ms."""
    held, total = [], []
    source = ConfigFile(path, start)
    for _ in range(POLLS):
        began = time.perf_counter()
        result = source.poll(force=True)
        returned = time.perf_counter()
        while result is None:  # the reader thread is at work: the test waits, not the loop
            pending = source._pending
            assert pending is not None
            pending.result()
            result = source.poll(force=True)
        held.append((returned - began) * 1e3)
        total.append((time.perf_counter() - began) * 1e3)
    return statistics.median(held), statistics.median(total)


def ticker_lateness_ms(background: Callable[[], object] | None) -> tuple[float, float, int]:
    """p50 and max lateness of a 10 ms sleep on this thread while `background` runs beside.

    Each tick is timed from its own sleep, so one late tick does not make the next late.
    """
    done = threading.Event()

    def work() -> None:
        if background is not None:
            background()
        done.set()

    worker = threading.Thread(target=work)
    late: list[float] = []
    worker.start()
    while not done.is_set() or len(late) < 50:
        due = time.perf_counter() + TICK
        time.sleep(TICK)
        late.append((time.perf_counter() - due) * 1e3)
    worker.join()
    return statistics.median(late), max(late), len(late)


def main() -> None:
    with tempfile.TemporaryDirectory() as scratch:
        big = Path(scratch) / "big.yaml"
        text = SHIPPED.read_text(encoding="utf-8")
        padding = MAX_FILE_BYTES - len(text.encode())
        line = "# " + "x" * 77 + "\n"
        big.write_text(text + line * (padding // len(line)) + "#" * (padding % len(line)))
        huge = Path(scratch) / "huge.yaml"
        huge.touch()
        os.truncate(huge, 50_000_000)
        print(f"Python {sys.version.split()[0]}, {platform.machine()}, {os.cpu_count()} cores")
        print()
        print("| file | poll holds the loop, check on the loop | ... off the loop | result after |")
        print("|---|---|---|---|")
        for name, path in (
            (f"shipped ({SHIPPED.stat().st_size} B)", SHIPPED),
            (f"largest read ({big.stat().st_size} B)", big),
            ("50 MB (refused by its size)", huge),
        ):
            on_loop, _ = held_ms(path, at_once)
            off_loop, after = held_ms(path, in_thread)
            print(
                f"| {name} | {on_loop:.2f} ms | {off_loop:.3f} ms (×{off_loop / on_loop:.2g}) "
                f"| {after:.2f} ms |"
            )
        print()
        for name, background in (
            ("idle", None),
            ("the shipped file parsed beside", lambda: ConfigFile(SHIPPED, at_once).load()),
            ("the largest file read parsed beside", lambda: ConfigFile(big, at_once).load()),
        ):
            p50, worst, ticks = ticker_lateness_ms(background)
            print(
                f"10 ms sleep, {name}: late by p50 {p50:.3f} ms, max {worst:.3f} ms ({ticks} ticks)"
            )


if __name__ == "__main__":
    main()
