"""What the queue between the loop and stderr costs: memory when full, time per log call.

- Memory: `LOG_QUEUE_SIZE` records queued for a stderr that takes none (the writer thread
  not started), measured with `tracemalloc`, per record and in all.
- The caller's time per `log.info` call, which the control loop pays: straight into a
  `StreamHandler` on /dev/null (the peer: how it was), through the queue with the writer
  thread writing to /dev/null, and into a full queue that drops.

    uv run python bench/log_queue.py [--calls 20000]
"""

from __future__ import annotations

import argparse
import logging
import os
import time
import tracemalloc

from hermsd.log_queue import LOG_QUEUE_SIZE, DroppingQueueHandler

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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=20000)
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


if __name__ == "__main__":
    main()
