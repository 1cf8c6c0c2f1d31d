"""Absolute deadlines on an injected clock: periodic tasks that never drift, and exact timers.

A periodic task's k-th deadline is `origin + k·period`, computed from k, never by adding up
periods, so rounding cannot drift. A task that finds its next deadline already past counts an
overrun and skips ahead to the first deadline still in the future: after a stall the loop
resumes on its grid, never with a burst of catch-up periods. Only the monotonic clock is
read, so a wall-clock jump (NTP on a Pi without an RTC) moves nothing.
"""

from __future__ import annotations

import heapq
import itertools
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from hermsd.runtime.clock import Clock


class LatenessStats:
    """The recent lateness of one kind of event, for p50/p99/max in status and logs."""

    def __init__(self, keep: int = 4096) -> None:
        self._samples: deque[float] = deque(maxlen=keep)
        self.count = 0
        self.worst = 0.0

    def add(self, lateness: float) -> None:
        self._samples.append(lateness)
        self.count += 1
        self.worst = max(self.worst, lateness)

    def summary(self) -> tuple[float, float, float]:
        """(p50, p99, max) over the kept samples; zeros before the first sample."""
        if not self._samples:
            return 0.0, 0.0, 0.0
        ordered = sorted(self._samples)
        return percentile(ordered, 50), percentile(ordered, 99), ordered[-1]


def percentile(ordered: list[float], p: float) -> float:
    """The nearest-rank percentile of an ascending list."""
    rank = max(1, math.ceil(p / 100.0 * len(ordered)))
    return ordered[rank - 1]


@dataclass(slots=True)
class Timer:
    """A one-shot action at an exact time; `cancel()` before it fires and it never will."""

    when: float
    action: Callable[[float, float], None]
    cancelled: bool = False

    def cancel(self) -> None:
        self.cancelled = True


class Periodic:
    """A task run at `origin + k·period`; `action(deadline, now)`."""

    __slots__ = ("action", "index", "lateness", "name", "origin", "overruns", "period", "priority")

    def __init__(
        self,
        name: str,
        period: float,
        origin: float,
        action: Callable[[float, float], None],
        priority: int,
    ) -> None:
        if not period > 0:
            raise ValueError(f"period of {name} must be positive, got {period}")
        self.name = name
        self.period = period
        self.origin = origin
        self.action = action
        self.priority = priority
        self.index = 0
        self.overruns = 0
        self.lateness = LatenessStats()

    @property
    def deadline(self) -> float:
        return self.origin + self.index * self.period

    def advance(self, now: float) -> None:
        """Step to the next deadline, skipping every one already past."""
        self.index += 1
        if self.deadline < now:
            behind = math.floor((now - self.origin) / self.period) + 1
            self.overruns += behind - self.index
            self.index = behind


class Scheduler:
    """Runs periodic tasks and timers in deadline order on `clock` until stopped.

    At equal times, lower `priority` runs first; timers run after periodic tasks.
    """

    TIMER_PRIORITY = 1_000

    def __init__(self, clock: Clock) -> None:
        self.clock = clock
        self._heap: list[tuple[float, int, int, Periodic | Timer]] = []
        self._order = itertools.count()
        self._stopped = False

    def every(
        self,
        name: str,
        period: float,
        action: Callable[[float, float], None],
        *,
        origin: float,
        priority: int = 0,
    ) -> Periodic:
        task = Periodic(name, period, origin, action, priority)
        self._push(task.deadline, priority, task)
        return task

    def at(self, when: float, action: Callable[[float, float], None]) -> Timer:
        timer = Timer(when, action)
        self._push(when, self.TIMER_PRIORITY, timer)
        return timer

    def stop(self) -> None:
        self._stopped = True

    def run(self, until: float = math.inf) -> None:
        """Run events due before `until` (monotonic seconds), or until `stop()`."""
        self._stopped = False
        heap, clock = self._heap, self.clock
        while heap and not self._stopped:
            when, priority, _, item = heap[0]
            if when >= until:
                clock.sleep_until(until)
                return
            clock.sleep_until(when)
            heapq.heappop(heap)
            if isinstance(item, Timer):
                if not item.cancelled:
                    item.action(when, clock.monotonic())
                continue
            now = clock.monotonic()
            item.lateness.add(now - when)
            item.action(when, now)
            item.advance(clock.monotonic())
            self._push(item.deadline, priority, item)

    def _push(self, when: float, priority: int, item: Periodic | Timer) -> None:
        heapq.heappush(self._heap, (when, priority, next(self._order), item))
