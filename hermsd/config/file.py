"""The config file on disk, watched by polling its metadata once a control period.

Polling `stat` is one system call a period and catches both ways editors save: writing the
file in place (size, mtime or ctime change) and writing a new file renamed over it (the
inode changes). A file read while an editor is still writing it is not trusted: its
metadata is compared before and after the read, and a file that changed meanwhile is read
again at the next poll. systemd's `ExecReload=` (SIGHUP) forces a read of an unchanged file.

The disk is never waited for on the control loop: each check (stat, read, parse) runs on a
reader thread, and `poll` only takes a check that has finished, starting the next one. The
file is read only if it is a regular file within `config.MAX_FILE_BYTES`.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from concurrent.futures import Future
from functools import partial
from pathlib import Path
from typing import TypeVar

from hermsd.config.read import Document, load_document, on_simulated_tun, reload_problems
from hermsd.config.schema import Config, ConfigError, Problem

_T = TypeVar("_T")
_Signature = tuple[int, int, int, int, int] | None
_Result = Config | ConfigError | None
Check = Callable[[], _Result]
Start = Callable[[Check], Future[_Result]]
"""How a check runs: `in_thread` for the daemon, `at_once` for tests on a virtual clock."""


def _signature(path: Path) -> _Signature:
    """What changes whenever the file's content may have: inode, device, size, mtime, ctime."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return (st.st_ino, st.st_dev, st.st_size, st.st_mtime_ns, st.st_ctime_ns)


def in_thread(check: Callable[[], _T], name: str = "hermsd-config") -> Future[_T]:
    """Run the check on a thread of its own; a read that hangs never holds up the exit."""
    future: Future[_T] = Future()
    threading.Thread(target=_run_into, args=(future, check), name=name, daemon=True).start()
    return future


def at_once(check: Callable[[], _T]) -> Future[_T]:
    """Run the check now, on the caller's thread: for tests on a virtual clock."""
    future: Future[_T] = Future()
    _run_into(future, check)
    return future


def _run_into(future: Future[_T], check: Callable[[], _T]) -> None:
    try:
        future.set_result(check())
    except BaseException as error:  # handed to the loop, which raises it as if it had run it
        future.set_exception(error)


class ConfigFile:
    """One config file; `poll` returns its config (or why not) when it has changed."""

    def __init__(
        self, path: Path | str, start: Start = in_thread, *, simulated: bool = False
    ) -> None:
        """`simulated`: the configs it gives are a simulated run's (`on_simulated_tun`), so
        that a reload compares like with like."""
        self.path = Path(path)
        self._start = start
        self._simulated = simulated
        self._seen = _signature(self.path)
        self._running: Document | None = None
        self._pending: Future[_Result] | None = None

    def load(self) -> Config:
        """Read the file now (at start-up); later polls report changes from this version."""
        self._seen = _signature(self.path)
        self._running = load_document(self.path)
        return self._as_run(self._running.config)

    def poll(self, force: bool = False) -> Config | ConfigError | None:
        """The file's new config or its problems; None when unchanged, being written or read.

        `force` reads the file even when it looks unchanged (a SIGHUP).
        """
        if self._pending is not None and not self._pending.done():
            return None
        result = self._take()
        if result is None:
            self._pending = self._start(partial(self._check, force))
            if self._pending.done():
                result = self._take()
        return result

    def _as_run(self, config: Config) -> Config:
        return on_simulated_tun(config) if self._simulated else config

    def _take(self) -> Config | ConfigError | None:
        """The finished check's result (None when there is none)."""
        finished, self._pending = self._pending, None
        return finished.result() if finished is not None else None

    def _check(self, force: bool) -> Config | ConfigError | None:
        """On the reader: the changed file's config, or why it cannot replace the running one."""
        before = _signature(self.path)
        if before == self._seen and not force:
            return None
        try:
            document = load_document(self.path)
            problems = reload_problems(self._running, document) if self._running else []
        except ConfigError as error:
            result: Config | ConfigError = error
        except Exception as error:  # a fault in the checking itself: refuse, don't stop the loop
            why = f"could not be checked ({type(error).__name__}: {error})"
            result = ConfigError([Problem(str(self.path), 0, 0, "", why)])
        else:
            result = ConfigError(problems) if problems else self._as_run(document.config)
        if _signature(self.path) != before:
            return None  # changed while being read: an editor is still at work
        self._seen = before
        if isinstance(result, Config):
            self._running = document
        return result
