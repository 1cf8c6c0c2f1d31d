"""Flight recorder: MCAP logs written beside the control loop that survive a crash or a bad disk.

The control loop hands records over with `Recorder.write`, which is one queue put: it never
blocks and never raises, because a log is worth less than a control period. A thread of its
own encodes the records as JSON and writes them with `hermsd.log.mcap_writer` (mcap's
records, and the chunk index kept on disk until the file is finished, so the memory stays
flat over months), which is not thread-safe and is touched by that thread only.

What survives what:

- A crash or power cut loses at most the records of the last `flush_interval` seconds: the
  open chunk is closed and handed to the OS at that pace (`LogWriter.flush`), and
  `os.fdatasync` pushes it to the card at most every `sync_interval` seconds (SD cards wear).
  The file being written is named `*.mcap.part`; `recover` turns a leftover one into a
  finished `.mcap` that keeps every complete chunk.
- A full, failing, read-only or vanished disk is counted (`errors`) and described
  (`last_error`, and `failing` until a later write reaches the OS again); the file in hand
  is abandoned as it stands (recoverable; removed if no chunk of it ever reached the OS),
  and writing resumes in a new file at the next record after `RETRY_INTERVAL_S`, then after
  twice as long at each failure in a row, up to `RETRY_MAX_S`: a full disk gets no new
  empty file every few seconds.
- A full queue drops the new record (`dropped`), and a WARNING event on `/hermsd/log` says how
  many were dropped as soon as there is room again.

Files are named after the log time of their first record, and rotate when a record's log
time is `rotate_s` past that: log time, not the recorder's clock, so a simulated day (whose
clock runs far ahead of the writer thread) gives the same files as a real one, and a wall
clock that jumps forward (a Pi without RTC meeting NTP) starts a file with a true name.
"""

from __future__ import annotations

import contextlib
import errno
import itertools
import json
import math
import os
import queue
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, BinaryIO, Final, NamedTuple

from hermsd import __version__
from hermsd.files import fsync_directory
from hermsd.log.mcap_file import _describe, _Walk
from hermsd.log.mcap_writer import LogWriter
from hermsd.log.topics import (
    CHANNELS_METADATA_NAME,
    CHUNK_SIZE,
    CONFIG_METADATA_NAME,
    CONFIG_TOPIC,
    FILE_PREFIX,
    LIBRARY,
    LOG_TOPIC,
    METADATA_NAME,
    PART_SUFFIX,
    TOPICS,
    LogLevel,
    log_message,
)

RETRY_INTERVAL_S: Final = 5.0
RETRY_MAX_S: Final = 300.0


def _create_exclusive(path: Path) -> BinaryIO:
    return open(path, "xb")


class _Record(NamedTuple):
    topic: str
    log_time_ns: int
    message: dict[str, Any]


class _SyncRequest:
    def __init__(self) -> None:
        self.done = threading.Event()
        self.ok = False


_STOP: Final = None
_QueueItem = _Record | _SyncRequest | None


class Recorder:
    """Writes records to rotating MCAP files from a thread of its own.

    Files are named after the log time of their first record; `now` (monotonic seconds)
    paces flushes, syncs and retries.
    `open_file` creates a new file for writing and must fail if it exists (tests inject
    failing disks through it). A message handed to `write` belongs to the recorder from then
    on: it is encoded later, on the writer thread. `lossless` makes `write` wait for room
    instead of dropping: for a simulation on a virtual clock, which has no deadline to keep
    and would otherwise outrun the writer thread and lose records.
    """

    def __init__(
        self,
        directory: Path | str,
        *,
        rotate_s: float = 86400.0,
        flush_interval: float = 2.0,
        sync_interval: float = 10.0,
        queue_size: int = 10000,
        metadata: dict[str, str] | None = None,
        now: Callable[[], float] = time.monotonic,
        open_file: Callable[[Path], BinaryIO] = _create_exclusive,
        lossless: bool = False,
    ) -> None:
        if rotate_s <= 0 or flush_interval < 0 or sync_interval < 0 or queue_size < 1:
            raise ValueError(
                "recorder: rotate_s and queue_size must be positive, "
                "flush_interval and sync_interval not negative"
            )
        self._directory = Path(directory)
        self._rotate_ns = round(rotate_s * 1e9)
        self._flush_interval = flush_interval
        self._sync_interval = sync_interval
        self._metadata = {"run": uuid.uuid4().hex[:16], **(metadata or {})}
        self._now = now
        self._open_file = open_file
        self._lossless = lossless
        self._queue: queue.Queue[_QueueItem] = queue.Queue(maxsize=queue_size)
        self._closed = False
        self._drop_lock = threading.Lock()
        self._dropped = 0
        self._drops_reported = 0
        # Writer-thread state (read elsewhere only as plain values).
        self._file: _OpenFile | None = None
        self._retry_at: float | None = None
        self._last_config: bytes | None = None
        self._sequences: dict[str, Iterator[int]] = {topic: itertools.count(1) for topic in TOPICS}
        self._errors = 0
        self._lost = 0
        self._last_error: str | None = None
        self._failing: str | None = _unwritable(self._directory)
        self._retry_delay = RETRY_INTERVAL_S
        self._thread = threading.Thread(target=self._run, name="hermsd-recorder", daemon=True)
        self._thread.start()

    # --- caller side -----------------------------------------------------------------------

    def write(self, topic: str, log_time_ns: int, message: dict[str, Any]) -> None:
        """Hand a record over (log time: ns since the Unix epoch); dropped if the queue is full."""
        if self._dropped != self._drops_reported:
            self._report_drops(log_time_ns)
        if self._closed:
            self._count_drop()
            return
        if self._lossless:
            self._queue.put(_Record(topic, log_time_ns, message))
            return
        try:
            self._queue.put_nowait(_Record(topic, log_time_ns, message))
        except queue.Full:
            self._count_drop()

    def log(self, level: LogLevel, message: str, log_time_ns: int, *, name: str = "hermsd") -> None:
        """Record an event for Foxglove's log panel; ERROR and FATAL reach the OS at once."""
        self.write(LOG_TOPIC, log_time_ns, log_message(level, message, log_time_ns, name=name))

    def sync(self, timeout: float | None = None) -> bool:
        """Block until everything handed over so far is on stable storage.

        Returns False while a disk error keeps records out of the files, or when `timeout`
        expired. Not for the control loop: it waits for the disk.
        """
        if self._closed:
            return False
        request = _SyncRequest()
        try:
            self._queue.put(request, timeout=timeout)
        except queue.Full:
            return False
        return request.done.wait(timeout) and request.ok

    def close(self, timeout: float | None = None) -> None:
        """Write what is queued, finish the file (fsync, rename to `.mcap`) and stop the thread."""
        if not self._closed:
            self._closed = True
            try:
                self._queue.put(_STOP, timeout=timeout)
            except queue.Full:
                return
        self._thread.join(timeout)

    @property
    def dropped(self) -> int:
        """Records refused because the queue was full (or the recorder closed)."""
        return self._dropped

    @property
    def lost(self) -> int:
        """Records taken from the queue that a disk error kept out of the files."""
        return self._lost

    @property
    def errors(self) -> int:
        """Failures: disk errors, and records that could not be encoded."""
        return self._errors

    @property
    def last_error(self) -> str | None:
        """One line about the latest failure, for the status line."""
        return self._last_error

    @property
    def run_id(self) -> str:
        """Names this recorder's files as one run (metadata "run"): replay joins runs only
        one after the other, never two that overlap in time."""
        return self._metadata["run"]

    @property
    def failing(self) -> str | None:
        """Why records are not reaching the disk now, from the failure until a write succeeds.

        Set at construction already when the directory is plainly unusable (missing, not
        writable), so the very first status line can say so.
        """
        return self._failing

    @property
    def current_file(self) -> Path | None:
        """The `.mcap.part` being written, if any."""
        file = self._file
        return None if file is None else file.part

    def _count_drop(self) -> None:
        with self._drop_lock:
            self._dropped += 1

    def _report_drops(self, log_time_ns: int) -> None:
        with self._drop_lock:
            unreported = self._dropped - self._drops_reported
            if unreported == 0 or self._closed:
                return
            notice = log_message(
                LogLevel.WARNING,
                f"recorder queue full: {unreported} records dropped ({self._dropped} since start)",
                log_time_ns,
                name="hermsd.recorder",
            )
            try:
                self._queue.put_nowait(_Record(LOG_TOPIC, log_time_ns, notice))
            except queue.Full:
                return
            self._drops_reported += unreported

    # --- writer thread ---------------------------------------------------------------------

    def _run(self) -> None:
        while True:
            try:
                item = self._queue.get(timeout=self._seconds_to_next_deadline())
            except queue.Empty:
                self._keep_time()
                continue
            if item is _STOP:
                if self._file is not None:
                    self._finish(self._file)
                return
            try:
                if isinstance(item, _SyncRequest):
                    item.ok = self._sync_now()
                    item.done.set()
                else:
                    self._write_record(item)
                self._keep_time()
            except Exception as exc:  # a flaw may cost a record, never the recorder thread
                self._report(f"internal error: {_describe(exc)}")

    def _seconds_to_next_deadline(self) -> float | None:
        file = self._file
        if file is None:
            return None
        deadlines = [d for d in (file.flush_due, file.sync_due) if d is not None]
        if not deadlines:
            return None
        return max(0.0, min(deadlines) - self._now())

    def _keep_time(self) -> None:
        file = self._file
        if file is None:
            return
        now = self._now()
        if file.flush_due is not None and now >= file.flush_due:
            self._flush(file, now)
        elif file.sync_due is not None and now >= file.sync_due:
            self._guarded(file, "syncing", lambda: file.datasync(now))

    def _write_record(self, record: _Record) -> None:
        spec = TOPICS.get(record.topic)
        if spec is None:
            self._report(f"record on unknown topic {record.topic!r} not written")
            return
        try:
            data = _encode(record.message)
        except (TypeError, ValueError, RecursionError) as exc:
            self._report(f"record on {record.topic} not written, not JSON: {exc}")
            return
        if record.topic == CONFIG_TOPIC:
            self._last_config = data
        file = self._file_for(record)
        if file is None:
            self._lost += 1
            return
        sequence = next(self._sequences[record.topic])
        now = self._now()
        if not self._guarded(
            file,
            "writing",
            lambda: file.add(record.topic, record.log_time_ns, data, sequence),
        ):
            return
        if file.flush_due is None:
            file.flush_due = now + self._flush_interval
        if record.topic == LOG_TOPIC and _is_alarming(record.message):
            self._flush(file, now)

    def _file_for(self, record: _Record) -> _OpenFile | None:
        """The file to write `record` in: rotated, or reopened after a failure, as due."""
        file = self._file
        if file is not None and record.log_time_ns - file.first_log_time_ns >= self._rotate_ns:
            self._finish(file)
            file = self._file
        if file is not None:
            return file
        if self._retry_at is not None and self._now() < self._retry_at:
            return None
        return self._start(record)

    def _start(self, record: _Record) -> _OpenFile | None:
        """A new file for `record`, named after its log time (the writer may run far behind)."""
        part = self._unused_part_path(_utc_stamp(record.log_time_ns))
        metadata = {"version": __version__, "started_utc": _utc_iso(record.log_time_ns)}
        metadata.update(self._metadata)
        try:
            stream = self._open_file(part)
        except Exception as exc:
            self._fail(f"creating {part}: {_describe(exc)}")
            return None
        file = _OpenFile(part, stream, record.log_time_ns, self._now())
        self._file = file
        if not self._guarded(file, "starting", lambda: file.start(metadata)):
            return None
        config = self._last_config
        if config is not None and record.topic != CONFIG_TOPIC:
            sequence = next(self._sequences[CONFIG_TOPIC])
            if not self._guarded(
                file,
                "writing",
                lambda: file.add(CONFIG_TOPIC, record.log_time_ns, config, sequence),
            ):
                return None
        self._retry_at = None
        return file

    def _unused_part_path(self, stamp: str) -> Path:
        for n in itertools.count():
            stem = f"{FILE_PREFIX}{stamp}" + (f"-{n}" if n else "")
            final = self._directory / f"{stem}.mcap"
            part = final.with_name(final.name + PART_SUFFIX)
            if not final.exists() and not part.exists():
                return part
        raise AssertionError("unreachable")

    def _flush(self, file: _OpenFile, now: float) -> None:
        if not self._guarded(file, "writing", file.flush):
            return
        self._healthy()
        if now - file.last_sync >= self._sync_interval:
            self._guarded(file, "syncing", lambda: file.datasync(now))
        else:
            file.sync_due = file.last_sync + self._sync_interval

    def _sync_now(self) -> bool:
        file = self._file
        if file is None:
            return self._retry_at is None
        now = self._now()
        if not self._guarded(file, "writing", file.flush):
            return False
        self._healthy()
        return self._guarded(file, "syncing", lambda: file.datasync(now))

    def _finish(self, file: _OpenFile) -> None:
        final = file.part.with_name(file.part.name.removesuffix(PART_SUFFIX))
        if not self._guarded(file, "finishing", file.finish):
            return
        self._file = None
        try:
            os.replace(file.part, final)
            fsync_directory(final.parent)
        except OSError as exc:
            self._report(f"renaming {file.part}: {_describe(exc)}")

    def _guarded(self, file: _OpenFile, action: str, operation: Callable[[], None]) -> bool:
        """Run a file operation; on any failure abandon the file, so the loop never sees it."""
        try:
            operation()
        except Exception as exc:
            self._fail(f"{action} {file.part}: {_describe(exc)}")
            self._lost += file.unflushed
            file.discard()
            self._file = None
            return False
        return True

    def _report(self, message: str) -> None:
        self._errors += 1
        self._last_error = f"recorder: {message}"

    def _fail(self, message: str) -> None:
        """A disk failure: said, and the next file tried later each time it happens again."""
        self._report(message)
        self._failing = message
        self._retry_at = self._now() + self._retry_delay
        self._retry_delay = min(2.0 * self._retry_delay, RETRY_MAX_S)

    def _healthy(self) -> None:
        """Records reached the OS: whatever failed before is over."""
        self._failing = None
        self._retry_delay = RETRY_INTERVAL_S


class _OpenFile:
    """A `.mcap.part` being written by the writer thread, with its channels registered."""

    def __init__(self, part: Path, stream: BinaryIO, first_log_time_ns: int, now: float) -> None:
        self.part = part
        self.stream = stream
        self.first_log_time_ns = first_log_time_ns
        self.writer = LogWriter(stream, part.parent, chunk_size=CHUNK_SIZE)
        self.channels: dict[str, int] = {}
        self.unflushed = 0
        self.flush_due: float | None = None
        self.sync_due: float | None = None
        self.last_sync = now
        self.flushed = 0  # messages handed to the OS

    def start(self, metadata: dict[str, str]) -> None:
        self.writer.start(profile="", library=LIBRARY)
        for topic, spec in TOPICS.items():
            schema_id = self.writer.register_schema(
                spec.schema_name, "jsonschema", spec.schema_bytes()
            )
            self.channels[topic] = self.writer.register_channel(topic, "json", schema_id)
        self.writer.add_metadata(METADATA_NAME, metadata)
        channel_topics = {str(channel): topic for topic, channel in self.channels.items()}
        self.writer.add_metadata(CHANNELS_METADATA_NAME, channel_topics)

    def add(self, topic: str, log_time_ns: int, data: bytes, sequence: int) -> None:
        self.unflushed += 1
        self.writer.add_message(
            self.channels[topic], log_time_ns, data, publish_time=log_time_ns, sequence=sequence
        )
        if topic == CONFIG_TOPIC:
            metadata = {"version": __version__, "record": data.decode("utf-8")}
            self.writer.add_metadata(CONFIG_METADATA_NAME, metadata)

    def flush(self) -> None:
        """Close the open chunk and hand everything to the OS."""
        self.writer.flush()
        self.flushed += self.unflushed
        self.unflushed = 0
        self.flush_due = None

    def datasync(self, now: float) -> None:
        os.fdatasync(self.stream.fileno())
        self.last_sync = now
        self.sync_due = None

    def finish(self) -> None:
        self.writer.finish()
        self.stream.flush()
        self.unflushed = 0
        os.fdatasync(self.stream.fileno())
        self.stream.close()

    def discard(self) -> None:
        """Let the file go; remove it if no message of it reached the OS (nothing to recover)."""
        # The disk already failed; closing releases the descriptor even when it raises.
        with contextlib.suppress(Exception):
            self.stream.close()
        with contextlib.suppress(Exception):
            self.writer.close_index()
        if self.flushed == 0 and not _holds_messages(self.part):
            with contextlib.suppress(OSError):
                self.part.unlink()


def _holds_messages(path: Path) -> bool:
    """Whether a whole chunk or message of `path` is on disk (True when that cannot be told)."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return False
    except OSError:
        return True
    walk = _Walk(data)
    for _ in walk.runs():
        pass
    return walk.messages_found


def _unwritable(directory: Path) -> str | None:
    """Why no file can be made in `directory`, when that shows without making one."""
    if not directory.is_dir():
        reason = os.strerror(errno.ENOTDIR if directory.exists() else errno.ENOENT)
        return f"{directory}: {reason}"
    if not os.access(directory, os.W_OK | os.X_OK):
        return f"{directory}: {os.strerror(errno.EACCES)}"
    return None


def _is_alarming(event: dict[str, Any]) -> bool:
    level = event.get("level")
    return isinstance(level, int) and level >= LogLevel.ERROR


def _encode(message: dict[str, Any]) -> bytes:
    """Compact JSON; NaN and infinities (not JSON) become null, i.e. no value."""
    try:
        text = json.dumps(message, separators=(",", ":"), allow_nan=False)
    except ValueError:
        text = json.dumps(_finite_or_null(message), separators=(",", ":"), allow_nan=False)
    return text.encode()


def _finite_or_null(value: Any) -> Any:
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {key: _finite_or_null(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_finite_or_null(item) for item in value]
    return value


def _utc_stamp(log_time_ns: int) -> str:
    return time.strftime("%Y%m%dT%H%M%SZ", time.gmtime(log_time_ns // 1_000_000_000))


def _utc_iso(log_time_ns: int) -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(log_time_ns // 1_000_000_000))
