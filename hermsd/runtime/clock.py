"""Time as the daemon sees it: an injected clock, so one loop runs on the Pi and in simulation.

Deadlines use a monotonic clock, never the wall clock (a Pi without an RTC jumps when NTP
syncs). The wall clock is read only to stamp log records.
"""

from __future__ import annotations

import time
from typing import Protocol


class Clock(Protocol):
    """What the daemon needs of time."""

    def monotonic(self) -> float:
        """Seconds on a clock that never jumps; the origin is arbitrary."""
        ...

    def sleep_until(self, deadline: float) -> None:
        """Return at (or as soon as possible after) `deadline` on the monotonic scale."""
        ...

    def wall_ns(self) -> int:
        """Wall-clock time in ns since the Unix epoch, for log stamps only."""
        ...


class MonotonicClock:
    """The real clock: `time.monotonic` for deadlines, `time.time_ns` for stamps."""

    def monotonic(self) -> float:
        return time.monotonic()

    def sleep_until(self, deadline: float) -> None:
        remaining = deadline - time.monotonic()
        if remaining > 0:
            time.sleep(remaining)

    def wall_ns(self) -> int:
        return time.time_ns()
