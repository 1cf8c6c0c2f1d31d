"""Writing files so that a power cut leaves either the old version or the new one."""

from __future__ import annotations

import contextlib
import os
import secrets
import stat
from collections.abc import Callable
from pathlib import Path


def fsync_directory(directory: Path) -> None:
    """Make a rename or unlink in `directory` survive a power cut."""
    fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_atomically(
    path: Path, text: str, like: os.stat_result | None = None, *, durable: bool = True
) -> None:
    """Replace `path` with `text`: a temporary file, fsync, rename, fsync of the directory.

    `durable` False leaves out both fsyncs: the rename still leaves the old text or the new
    one to any reader and after a crash of the process, only not after a power cut.

    `like`: the file being replaced, whose permission bits, owner and group the new one has
    from its first moment (a config file root edits for the daemon's group must not turn
    unreadable to the daemon, even briefly). OSError when they cannot be kept.

    The temporary file is a new one of a random name, made with O_EXCL and O_NOFOLLOW: a
    file or symlink planted beside `path` is never followed, written through or truncated
    (root's write would otherwise land in whatever the link names). A write that fails (a
    full disk, a read-only one) removes its temporary file: `path` is as it was, and nothing
    half-written is left beside it.
    """
    temporary = path.with_name(f".{path.name}.{secrets.token_hex(8)}.tmp")
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC
    fd = os.open(temporary, flags, 0o666 if like is None else 0o600)
    try:
        with open(fd, "w", encoding="utf-8") as file:
            if like is not None:
                os.fchown(file.fileno(), like.st_uid, like.st_gid)
                os.fchmod(file.fileno(), stat.S_IMODE(like.st_mode))
            file.write(text)
            file.flush()
            if durable:
                os.fsync(file.fileno())
        os.replace(temporary, path)
    except BaseException:
        with contextlib.suppress(OSError):
            temporary.unlink()
        raise
    if durable:
        fsync_directory(path.parent)


def read_only(status: os.stat_result) -> str | None:
    """Why a file's mode bits forbid this process to write it ("mode 0444"), or None.

    By the bits alone, for the class the process is in (owner, group, others): root may
    write anything, but a file made read-only was made so on purpose and is not replaced.
    """
    mode = stat.S_IMODE(status.st_mode)
    if os.geteuid() == 0:
        allowed = mode & (stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH)
    elif os.geteuid() == status.st_uid:
        allowed = mode & stat.S_IWUSR
    elif status.st_gid in (os.getegid(), *os.getgroups()):
        allowed = mode & stat.S_IWGRP
    else:
        allowed = mode & stat.S_IWOTH
    return None if allowed else f"mode {mode:04o}"


def write_new(path: Path, write: Callable[[Path], object]) -> None:
    """Make `path`, which must not exist yet (FileExistsError), from what `write` writes.

    The name is taken first, by an exclusive create: an existing file (a brew day's log
    named by mistake among them) is never replaced, nor one made meanwhile. `write` fills a
    temporary file beside it, renamed over the empty one once whole; a failure removes both,
    so no half-written file is left to be taken for a whole one (a shorter day, a program
    with steps missing).
    """
    with path.open("x"):
        pass
    temporary = path.with_name(f".{path.stem}.writing{path.suffix}")  # the suffix: its format
    try:
        write(temporary)
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        path.unlink(missing_ok=True)
        raise


class NotRegularFile(ValueError):
    """A path that names something other than a regular file (`kind` says what), or a
    regular file over the size limit (`kind` None, `size` its length)."""

    def __init__(self, kind: str | None, size: int, limit: int) -> None:
        self.kind, self.size = kind, size
        what = f"is {kind}, not a regular file" if kind else f"is {size} bytes long"
        super().__init__(what if kind else f"{what}, more than the {limit} bytes allowed")


def read_regular(path: str | os.PathLike[str], limit: int) -> bytes:
    """A regular file's bytes, at most `limit` of them; NotRegularFile or OSError otherwise.

    The kind of file is checked before it is opened: opening a FIFO waits for a writer, and
    opening a serial device raises its modem lines, which may drive an SSR. The size is
    checked before reading, and again by what was read, so neither a huge file nor one that
    grows while it is read costs more than the limit in memory and time.
    """
    status = os.stat(path)
    kind, size = _file_kind(status.st_mode), status.st_size
    data = b""
    if kind is None and size <= limit:
        flags = os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC
        with open(os.open(path, flags), "rb") as file:
            kind = _file_kind(os.fstat(file.fileno()).st_mode)  # replaced meanwhile?
            data = b"" if kind else file.read(limit + 1)
            size = max(size, len(data))
    if kind is not None or size > limit:
        raise NotRegularFile(kind, size, limit)
    return data


def not_regular(path: str | os.PathLike[str]) -> str | None:
    """What `path` is, in words, when it is not a regular file; None for a regular file.

    By its status alone: a FIFO or a device is never opened (opening a FIFO waits for a
    writer; reading /dev/zero never ends). OSError when it cannot be looked at."""
    return _file_kind(os.stat(path).st_mode)


def _file_kind(mode: int) -> str | None:
    """What a file that is not a regular file is, in words; None for a regular file."""
    if stat.S_ISREG(mode):
        return None
    for test, kind in (
        (stat.S_ISDIR, "a directory"),
        (stat.S_ISFIFO, "a FIFO (named pipe)"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISSOCK, "a socket"),
    ):
        if test(mode):
            return kind
    return "some other kind of file"
