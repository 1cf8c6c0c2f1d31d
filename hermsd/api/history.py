"""The last 24 hours of control periods, kept in memory for the web page's chart.

The loop appends one row per period (`LoopLink.period`): the row is encoded to its JSON text
there, once, a few µs, so that the server thread answers a page of `history` by joining
ready bytes (tens of µs for a full page) instead of encoding thousands of numbers while it
holds the interpreter lock the loop may be waiting for. The ring is a fixed list written in
place; one lock guards the write index, held by the loop for one assignment and by the
server thread for a binary search and a slice of at most protocol.MAX_PAGE references (µs).

Rows are rounded to 0.001 (°C, %, s): finer than the LM92's 0.0625 °C steps, and it keeps a
row about 50 bytes. `mash` is the HERMS mash sensor's reading (null when none is fitted, or
while it is faulty): the chart's second line; `hlt_setpoint` the HLT's setpoint the outer loop
chose for the mash (null without a mash sensor): the chart's dashed HLT setpoint.
"""

from __future__ import annotations

import json
import math
import threading
from collections.abc import Sequence

from hermsd.runtime.period import PeriodRecord

FIELDS = ("t", "pv", "setpoint", "output", "applied", "mash", "hlt_setpoint")
KEPT_SECONDS = 24 * 3600.0


def capacity_for(period: float) -> int:
    """Rows that hold KEPT_SECONDS of periods of `period` seconds (17,280 at 5 s)."""
    return math.ceil(KEPT_SECONDS / period)


def encode_row(record: PeriodRecord) -> tuple[float, bytes]:
    """The period's time and its row as JSON text, in FIELDS' order. Formatted by hand, so
    that nothing here can raise on the loop: a number that is not finite becomes null."""
    t = round(record.t, 3)
    values = (
        record.pv,
        record.setpoint,
        record.output,
        record.applied,
        record.mash,
        record.hlt_setpoint,
    )
    text = ",".join(
        repr(round(value, 3)) if value is not None and math.isfinite(value) else "null"
        for value in (t, *values)
    )
    return t, f"[{text}]".encode()


class HistoryRing:
    """Rows in time order, the oldest overwritten once `capacity` are kept."""

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity
        self._times: list[float] = [0.0] * capacity
        self._rows: list[bytes] = [b""] * capacity
        self._start = 0  # slot of the oldest row
        self._count = 0
        self._lock = threading.Lock()

    def append(self, t: float, row: bytes) -> None:
        """On the loop: add the newest row (its t later than every kept row's)."""
        with self._lock:
            if self._count < self.capacity:
                slot = (self._start + self._count) % self.capacity
                self._count += 1
            else:
                slot = self._start
                self._start = (self._start + 1) % self.capacity
            self._times[slot] = t
            self._rows[slot] = row

    def page(self, since: float | None, limit: int) -> tuple[list[bytes], bool]:
        """Up to `limit` rows with t after `since` (all kept rows when None), oldest first,
        and whether more such rows follow the last one given."""
        with self._lock:
            start, count, capacity = self._start, self._count, self.capacity
            first = 0 if since is None else _first_after(self._times, start, count, since)
            last = min(count, first + limit)
            begin, end = (start + first) % capacity, (start + first) % capacity + last - first
            rows = self._rows[begin:end] + self._rows[: max(0, end - capacity)]
        return rows, last < count


def _first_after(times: Sequence[float], start: int, count: int, since: float) -> int:
    """The logical index of the first row with t > since (binary search over the ring)."""
    low, high = 0, count
    capacity = len(times)
    while low < high:
        middle = (low + high) // 2
        if times[(start + middle) % capacity] <= since:
            low = middle + 1
        else:
            high = middle
    return low


def page_line(rows: list[bytes], more: bool, period: float) -> bytes:
    """The encoded `history` reply for one page (see protocol.py)."""
    fields = json.dumps(FIELDS, separators=(",", ":")).encode()
    return b"".join(
        (
            b'{"v":1,"ok":true,"period":',
            json.dumps(period).encode(),
            b',"fields":',
            fields,
            b',"more":',
            b"true" if more else b"false",
            b',"rows":[',
            b",".join(rows),
            b"]}\n",
        )
    )
