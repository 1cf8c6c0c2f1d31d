"""What the queue between the loop and stderr costs: memory when full, time per log call.

- Memory: `LOG_QUEUE_SIZE` records queued for a stderr that takes none (the writer thread
  not started), measured with `tracemalloc`, per record and in all.
- The caller's time per `log.warning` call, which the control loop pays: straight into a
  `StreamHandler` on /dev/null (the peer: how it was), through the queue with the writer
  thread writing to /dev/null, and into a full queue that drops.
- A simulated day (`hermsd run --simulate --speed max --log DIR`) with its stderr a pipe
  whose buffer is already full and that nobody reads, against the same day with stderr
  read: when the loop has finished (the recorder's last file finished, which comes before
  the log lines are written out), and what comes out once the pipe is read.

    uv run python bench/log_queue.py [--calls 20000] [--hours 24]
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import subprocess
import sys
import tempfile
import threading
import time
import tracemalloc
from pathlib import Path

from hermsd.runtime.log_queue import LOG_QUEUE_SIZE, DroppingQueueHandler

# A long line of the daemon's own (`Daemon._check_log`): the queue's worst case is many such.
MESSAGE = (
    "log failing for 120 s: cannot create /var/log/hermsd/2026-11-28T01-25-34.mcap.part: "
    "No space left on device; control goes on"
)


def _logger(handler: logging.Handler) -> logging.Logger:
    logger = logging.Logger("bench")
    handler.setFormatter(logging.Formatter("%(levelname)s %(message)s"))
    logger.addHandler(handler)
    return logger


def _per_call_us(logger: logging.Logger, calls: int) -> float:
    start = time.perf_counter()
    for _ in range(calls):
        logger.warning(MESSAGE)
    return (time.perf_counter() - start) / calls * 1e6


def _day_with_stderr(hours: float, *, stuck: bool) -> None:
    """Run a simulated day with stderr a pipe, read from the start or only after the loop."""
    read_end, write_end = os.pipe()
    if stuck:  # fill the pipe's buffer: the daemon's first line waits for a reader
        os.set_blocking(write_end, False)
        with contextlib.suppress(BlockingIOError):
            while True:
                os.write(write_end, b"\n" * 4096)
        os.set_blocking(write_end, True)
    read: list[bytes] = []

    def drain() -> None:  # until the daemon's end closes the pipe
        read.extend(iter(lambda: os.read(read_end, 1 << 16), b""))

    reader = threading.Thread(target=drain)
    with tempfile.TemporaryDirectory() as logs:
        argv = ["run", "--simulate", "--speed", "max", "--duration", f"{hours}h", "--log", logs]
        start = time.perf_counter()
        daemon = subprocess.Popen(
            [sys.executable, "-m", "hermsd.cli", *argv],
            stdout=subprocess.DEVNULL,
            stderr=write_end,
        )
        os.close(write_end)
        if not stuck:
            reader.start()
        over = False
        while not over and daemon.poll() is None and time.perf_counter() - start < 120:
            time.sleep(0.05)
            # The recorder has finished its last file: the loop is over.
            over = any(Path(logs).glob("*.mcap")) and not any(Path(logs).glob("*.part"))
        ended = time.perf_counter() - start
        alive = daemon.poll() is None
        if stuck:
            reader.start()
        code = daemon.wait(60)
        reader.join(60)
    os.close(read_end)
    lines = [line for line in b"".join(read).decode().splitlines() if line]
    what = "stuck until the loop ended" if stuck else "read throughout"
    print(
        f"a {hours:g} h day, stderr {what}: loop {'over' if over else 'NOT over'} after "
        f"{ended:.1f} s (daemon still "
        f"running: {'yes' if alive else 'no'}), exit {code}, lines: {lines}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=20000)
    parser.add_argument("--hours", type=float, default=24.0)
    args = parser.parse_args()
    with open(os.devnull, "w") as devnull:
        stalled = DroppingQueueHandler(logging.StreamHandler(devnull))
        logger = _logger(stalled)
        tracemalloc.start()
        for _ in range(LOG_QUEUE_SIZE):
            logger.warning(MESSAGE)
        held, _peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        print(
            f"full queue: {LOG_QUEUE_SIZE} records, {held / 1e6:.2f} MB, "
            f"{held / LOG_QUEUE_SIZE:.0f} B a record ({len(MESSAGE)}-character message)"
        )
        dropping = _per_call_us(logger, args.calls)
        direct = _per_call_us(_logger(logging.StreamHandler(devnull)), args.calls)
        writing = DroppingQueueHandler(logging.StreamHandler(devnull), args.calls + 1)
        writing.start()
        queued = _per_call_us(_logger(writing), args.calls)
        writing.stop()
    print(f"per log call, straight to /dev/null (peer): {direct:.1f} µs")
    print(f"per log call, queued, writer on /dev/null: {queued:.1f} µs ({queued / direct:.2f}×)")
    print(f"per log call, full queue (dropped): {dropping:.1f} µs ({dropping / direct:.2f}×)")
    _day_with_stderr(args.hours, stuck=False)
    _day_with_stderr(args.hours, stuck=True)


if __name__ == "__main__":
    main()
