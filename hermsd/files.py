"""Writing files so that a power cut leaves either the old version or the new one."""

from __future__ import annotations

import os
import stat
from pathlib import Path


def fsync_directory(directory: Path) -> None:
    """Make a rename or unlink in `directory` survive a power cut."""
    fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_atomically(path: Path, text: str, like: os.stat_result | None = None) -> None:
    """Replace `path` with `text`: a temporary file, fsync, rename, fsync of the directory.

    `like`: the file being replaced, whose permission bits, owner and group the new one has
    from its first moment (a config file root edits for the daemon's group must not turn
    unreadable to the daemon, even briefly). OSError when they cannot be kept.
    """
    temporary = path.with_name(path.name + ".tmp")
    with temporary.open("w", encoding="utf-8") as file:
        if like is not None:
            os.fchown(file.fileno(), like.st_uid, like.st_gid)
            os.fchmod(file.fileno(), stat.S_IMODE(like.st_mode))
        file.write(text)
        file.flush()
        os.fsync(file.fileno())
    os.replace(temporary, path)
    fsync_directory(path.parent)
