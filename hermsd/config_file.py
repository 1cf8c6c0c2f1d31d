"""The config file on disk, watched by polling its metadata once a control period.

Polling `stat` is one system call a period and catches both ways editors save: writing the
file in place (size, mtime or ctime change) and writing a new file renamed over it (the
inode changes). A file read while an editor is still writing it is not trusted: its
metadata is compared before and after the read, and a file that changed meanwhile is read
again at the next poll. systemd's `ExecReload=` (SIGHUP) forces a read of an unchanged file.
"""

from __future__ import annotations

import os
from pathlib import Path

from hermsd.config import Config, ConfigError, load

_Signature = tuple[int, int, int, int, int] | None


def _signature(path: Path) -> _Signature:
    """What changes whenever the file's content may have: inode, device, size, mtime, ctime."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return (st.st_ino, st.st_dev, st.st_size, st.st_mtime_ns, st.st_ctime_ns)


class ConfigFile:
    """One config file; `poll` returns its config (or why not) when it has changed."""

    def __init__(self, path: Path | str) -> None:
        self.path = Path(path)
        self._seen = _signature(self.path)

    def load(self) -> Config:
        """Read the file now (at start-up); later polls report changes from this version."""
        self._seen = _signature(self.path)
        return load(self.path)

    def poll(self, force: bool = False) -> Config | ConfigError | None:
        """The file's new config or its problems; None when unchanged or being written.

        `force` reads the file even when it looks unchanged (a SIGHUP).
        """
        before = _signature(self.path)
        if before == self._seen and not force:
            return None
        try:
            result: Config | ConfigError = load(self.path)
        except ConfigError as error:
            result = error
        if _signature(self.path) != before:
            return None  # changed while being read: an editor is still at work
        self._seen = before
        return result
