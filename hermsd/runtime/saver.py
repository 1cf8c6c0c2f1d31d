"""The daemon's state files (latched alarms, the learned model) saved beside the control loop.

Each save is durable (a temporary file, fsync, rename, fsync of the directory), and on a Pi's
SD card an fsync can stall for seconds: longer than a control period, and far longer than an
SSR edge may be late. So the loop hands its saves to a `Saver`, which does them on a thread of
its own, as `program.store.ProgressWriter` does the mash program's: in the order handed over;
of several saves of one kind waiting, only the newest is done, so an older state never
overwrites a newer one. The loop takes what became of each save (`Outcome`) at a period of
its own and says it there; whether and when to try a failed save again is the loop's call,
on its own clock.

`threaded=False` does each save at once on the caller's thread: for a day on a virtual clock,
where the disk takes no simulated time and the day must come out the same on every run.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True, slots=True)
class Outcome:
    """What became of one save: its kind, the tag it was handed over with, and why it failed
    (None: it landed)."""

    kind: str
    tag: Any
    error: str | None


class Saver:
    """Does the loop's saves on a thread of its own (started at the first save)."""

    def __init__(self, *, threaded: bool = True) -> None:
        self._threaded = threaded
        self._jobs: list[tuple[str, Callable[[], None], Any]] = []
        self._busy: str | None = None  # the kind being saved now
        self._outcomes: list[Outcome] = []
        self._closed = False
        self._wake = threading.Condition()
        self._thread: threading.Thread | None = None

    def save(self, kind: str, job: Callable[[], None], tag: Any = None) -> None:
        """Hand over `job`, the save of `kind`; a save of that kind still waiting is dropped."""
        if not self._threaded:
            self._record(kind, tag, _attempt(job))
            return
        with self._wake:
            self._jobs = [waiting for waiting in self._jobs if waiting[0] != kind]
            self._jobs.append((kind, job, tag))
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="hermsd-state", daemon=True)
                self._thread.start()
            self._wake.notify_all()

    def take(self) -> list[Outcome]:
        """The outcomes of the saves done since the last call, in the order they were done."""
        with self._wake:
            done, self._outcomes = self._outcomes, []
        return done

    def waiting(self) -> list[str]:
        """The kinds handed over and not done yet (being saved, or waiting)."""
        with self._wake:
            busy = [] if self._busy is None else [self._busy]
            return busy + [kind for kind, _job, _tag in self._jobs]

    def flush(self, timeout: float | None = None) -> bool:
        """Wait until every save handed over is done; False when `timeout` passed first."""
        with self._wake:
            return self._wake.wait_for(lambda: not self._jobs and self._busy is None, timeout)

    def close(self, timeout: float) -> list[str]:
        """Wait at most `timeout` s for the saves handed over; the kinds still not done.

        The thread goes on with them while the process lives, then stops."""
        self.flush(timeout)
        with self._wake:
            self._closed = True
            self._wake.notify_all()
        return self.waiting()

    def _record(self, kind: str, tag: Any, error: str | None) -> None:
        with self._wake:
            self._outcomes.append(Outcome(kind, tag, error))

    def _run(self) -> None:
        while True:
            with self._wake:
                self._wake.wait_for(lambda: bool(self._jobs) or self._closed)
                if not self._jobs:
                    self._thread = None  # closed: a later save starts another
                    return
                kind, job, tag = self._jobs.pop(0)
                self._busy = kind
            error = _attempt(job)
            with self._wake:
                self._outcomes.append(Outcome(kind, tag, error))
                self._busy = None
                self._wake.notify_all()


def _attempt(job: Callable[[], None]) -> str | None:
    """Run a save; why it failed, or None. Any fault is caught: the next save must still run."""
    try:
        job()
    except OSError as error:
        return str(error)
    except Exception as error:
        return f"{type(error).__name__}: {error}"
    return None
