"""Log lines written beside the control loop: a `logging` call never waits for stderr.

stderr is a pipe (the journal's, a terminal's) that can stall: journald busy, a terminal
paused with Ctrl-S, a reader that stopped reading. A thread that writes to it then waits,
and if that thread is the control loop, the heater's switching and the safety checks wait
with it. So a record is put on a bounded queue (one non-blocking put) and a thread of its
own writes it. A full queue drops the record and counts it; the count is written as one
line where the records went missing, once the writer can write again. The events the loop
reports (`Daemon._event`) are also on the flight recorder's `/hermsd/log` topic when the
daemon keeps an MCAP log: a line dropped here is still there (what the recorder could not
keep, it says itself).
"""

from __future__ import annotations

import logging
import queue
import threading
from logging.handlers import QueueHandler, QueueListener
from typing import Final

# A queued record of a long line holds about 0.8 kB (bench/log_queue.py), so a full queue is
# about 3 MB: nothing to a Pi's 512 MB or more. The daemon logs events, not samples (a
# simulated 24 h day: 2 lines); a warning said again every minute while it lasts (a failing
# log disk) fills 4096 places after 68 h of a stalled stderr.
LOG_QUEUE_SIZE: Final = 4096


class DroppingQueueHandler(QueueHandler):
    """Hands records to a writer thread that passes them to `target`, without ever waiting.

    `start` starts the writer thread (before the loop takes real-time priority, so that the
    thread stays ordinary); `stop` writes what is queued and ends it.
    """

    def __init__(self, target: logging.Handler, size: int = LOG_QUEUE_SIZE) -> None:
        self.records: queue.Queue[logging.LogRecord | None] = queue.Queue(size)
        super().__init__(self.records)
        self.target = target
        self._drops_lock = threading.Lock()  # held for queue puts and the count, never for I/O
        self._dropped = 0
        self._writer = _Writer(self)

    def start(self) -> None:
        self._writer.start()

    def stop(self) -> None:
        """Wait until every queued record is written (the unit's TimeoutStopSec bounds a
        stderr that never drains), and say what was dropped since the last one."""
        self._writer.stop()
        self.write_drops_if_idle()

    def enqueue(self, record: logging.LogRecord) -> None:
        """One put that never waits: after a run of drops, the line counting them goes first."""
        with self._drops_lock:
            try:
                if self._dropped:
                    self.records.put_nowait(_dropped_line(self._dropped))
                    self._dropped = 0
                self.records.put_nowait(record)
            except queue.Full:
                self._dropped += 1

    def write_drops_if_idle(self) -> None:
        """With the queue empty, write the count of records dropped after the last one written
        (when no record came after them to carry it)."""
        with self._drops_lock:
            if not self._dropped or not self.records.empty():
                return
            dropped, self._dropped = self._dropped, 0
        self.target.handle(_dropped_line(dropped))


class _Writer(QueueListener):
    """The thread that writes the queued records to the handler's target."""

    def __init__(self, source: DroppingQueueHandler) -> None:
        super().__init__(source.records, source.target)
        self._source = source

    def handle(self, record: logging.LogRecord) -> None:
        super().handle(record)
        self._source.write_drops_if_idle()

    def enqueue_sentinel(self) -> None:
        """Waits for room (the base class's put_nowait fails on a full queue): the records
        ahead of the stop are written first."""
        self._source.records.put(None)


def _dropped_line(count: int) -> logging.LogRecord:
    lines = "line" if count == 1 else "lines"
    return logging.LogRecord(
        "hermsd",
        logging.WARNING,
        __file__,
        0,
        f"{count} log {lines} dropped while stderr was blocked",
        None,
        None,
    )
