"""One daemon per log directory and per state directory; one MQTT bridge per broker login.

A second daemon on the same log directory would recover the first one's live `.part` at its
start (the first then writes on into a deleted file), and two on one state directory would
overwrite each other's latched alarms. Each directory therefore holds a lock file that a
daemon locks (`flock`, exclusive) for its whole life and writes its pid into; the kernel
drops the lock when the process ends however it ends, so a crash never leaves a stale one.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import os
import socket
import struct
from pathlib import Path
from typing import Final

LOCK_FILE: Final = ".hermsd.lock"  # hidden: `replay logs/*` must not take it for a log


class InstanceError(Exception):
    """Another process holds a directory this one needs; the message names its pid."""

    def __init__(self, message: str, holder: int | None) -> None:
        super().__init__(message)
        self.holder = holder  # the pid the lock file names, None when it names none


class DirectoryLock:
    """An exclusive lock on `directory`, held from `acquire` until `release` or exit."""

    def __init__(self, directory: Path) -> None:
        self.directory = directory
        self.path = directory / LOCK_FILE
        self._fd: int | None = None

    def acquire(self, role: str) -> None:
        """Lock the directory (its `role`, e.g. "log directory", is for the message).

        InstanceError when another process holds it; OSError when the lock file cannot be
        made (the caller decides whether to go on without it).
        """
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as error:
            holder = _read_pid(fd)
            os.close(fd)
            if error.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):
                raise
            who = f"pid {holder}" if holder is not None else "a process that gave no pid"
            raise InstanceError(
                f"{self.directory} is the {role} of another hermsd ({who}): one daemon per "
                f"{role}; stop that one first, or give this one another",
                holder,
            ) from None
        try:
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())
        except OSError:
            os.close(fd)  # a full disk: not locked, and nothing held open
            raise
        self._fd = fd

    def release(self) -> None:
        """Give the directory up (the file stays: unlinking a lock file races a new locker)."""
        if self._fd is not None:
            with contextlib.suppress(OSError):
                os.close(self._fd)
            self._fd = None


BACKLOG = 8
"""Connections a held name keeps unaccepted: each refused start's probe stays queued (the
holder never accepts), so the queue bounds what repeated refusals cost it."""


class NameLock:
    """An exclusive hold on a name, for a process with no directory of its own to lock.

    The MQTT bridge's service sees a read-only file system and a private /tmp, so two
    bridges share no file. They share the network namespace: the lock is a Linux abstract
    Unix socket bound to the name (a hash of it), which the kernel frees when the process
    ends however it ends. The holder listens, so a second one learns its pid by connecting.
    """

    def __init__(self, name: str) -> None:
        digest = hashlib.sha256(name.encode()).hexdigest()[:32]
        self.address = f"\0hermsd/{digest}"  # the leading NUL: abstract, no file
        self._socket: socket.socket | None = None

    def acquire(self, taken: str) -> None:
        """Hold the name; InstanceError saying `taken` (and the holder's pid) when held."""
        held = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC)
        try:
            held.bind(self.address)
            held.listen(BACKLOG)
        except OSError as error:
            held.close()
            if error.errno != errno.EADDRINUSE:
                raise
            holder = self._holder()
            who = f"pid {holder}" if holder is not None else "a process that gave no pid"
            raise InstanceError(taken.format(who=who), holder) from None
        self._socket = held

    def release(self) -> None:
        if self._socket is not None:
            self._socket.close()
            self._socket = None

    def _holder(self) -> int | None:
        """The pid of the process that holds the name, from the kernel's credentials."""
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC) as probe:
            probe.setblocking(False)  # a backlog full of earlier probes: no pid, no wait
            try:
                probe.connect(self.address)
                credentials = probe.getsockopt(
                    socket.SOL_SOCKET, socket.SO_PEERCRED, struct.calcsize("3i")
                )
            except OSError:
                return None
        pid: int = struct.unpack("3i", credentials)[0]
        return pid


def _read_pid(fd: int) -> int | None:
    try:
        text = os.pread(fd, 32, 0).decode("ascii").strip()
    except (OSError, UnicodeDecodeError):
        return None
    return int(text) if text.isdigit() else None
