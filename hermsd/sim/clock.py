"""A virtual clock: hours of brewing in seconds, and callbacks at exact simulated times."""

from __future__ import annotations

import datetime as dt
import heapq
import itertools
import math
import time
from collections.abc import Callable

# 2026-01-01T00:00:00Z: a fixed epoch keeps simulated logs reproducible.
DEFAULT_EPOCH_NS = 1_767_225_600_000_000_000


class VirtualClock:
    """Monotonic time that advances only when someone sleeps.

    `call_at` schedules a callback (a scenario event, a fault switched on) that runs with the
    clock set to exactly its time, before any sleeper passes that time.
    """

    def __init__(
        self,
        start: float = 0.0,
        epoch_ns: int = DEFAULT_EPOCH_NS,
        zone: dt.tzinfo = dt.UTC,
    ) -> None:
        self.zone = zone  # the simulated local time (a mash program's ready_by), not the host's
        self._now = start
        self._start = start
        self._epoch_ns = epoch_ns
        self._pending: list[tuple[float, int, Callable[[], None]]] = []
        self._order = itertools.count()

    def monotonic(self) -> float:
        return self._now

    def wall_ns(self) -> int:
        return self._epoch_ns + round((self._now - self._start) * 1e9)

    def call_at(self, when: float, callback: Callable[[], None]) -> None:
        """Run `callback` when the clock reaches `when` (at once on the next sleep if past)."""
        heapq.heappush(self._pending, (when, next(self._order), callback))

    def sleep_until(self, deadline: float) -> None:
        while self._pending and self._pending[0][0] <= deadline:
            when, _, callback = heapq.heappop(self._pending)
            self._now = max(self._now, when)
            callback()
        self._now = max(self._now, deadline)

    def sleep(self, seconds: float) -> None:
        self.sleep_until(self._now + seconds)

    def advance(self, seconds: float) -> None:
        """Time passes without anyone sleeping (a slow I2C read, a stalled loop)."""
        self.sleep_until(self._now + seconds)


class PacedClock(VirtualClock):
    """Virtual time paced to real time `speed` times faster: the simulated tun, watchable.

    Time still advances only when the loop sleeps, so the loop's own work and the machine's
    hiccups take no simulated time: at --speed 500 a 20 ms pause of the process would
    otherwise be 10 simulated seconds, and the supervisor would rightly call the reading
    stale and the loop stalled. A machine too slow for `speed` makes the run slower than
    asked, never wrong. (The loop's lateness is therefore not measured here: bench/timing.py
    does that on the real clock.)
    """

    def __init__(self, speed: float, epoch_ns: int = DEFAULT_EPOCH_NS) -> None:
        if not (speed > 0 and math.isfinite(speed)):
            raise ValueError(f"speed must be positive and finite, got {speed}")
        super().__init__(epoch_ns=epoch_ns)
        self.speed = speed
        self._real_start = time.monotonic()

    def sleep_until(self, deadline: float) -> None:
        remaining = self._real_start + deadline / self.speed - time.monotonic()
        if remaining > 0:
            time.sleep(remaining)
        super().sleep_until(deadline)
