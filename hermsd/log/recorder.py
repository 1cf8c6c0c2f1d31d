"""Flight recorder: MCAP logs written beside the control loop that survive a crash or a bad disk.

The control loop hands records over with `Recorder.write`, which is one queue put: it never
blocks and never raises, because a log is worth less than a control period. A thread of its
own encodes the records as JSON and writes them with the `mcap` library, which is not
thread-safe and is touched by that thread only.

What survives what:

- A crash or power cut loses at most the records of the last `flush_interval` seconds: the
  open chunk is closed and handed to the OS at that pace (`mcap.writer.Writer.flush`), and
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
import io
import itertools
import json
import math
import os
import queue
import struct
import threading
import time
import uuid
import zlib
from collections.abc import Callable, Collection, Iterable, Iterator
from dataclasses import dataclass
from enum import IntEnum
from pathlib import Path
from typing import Any, BinaryIO, Final, NamedTuple

import zstandard
from mcap.data_stream import ReadDataStream
from mcap.records import Channel, Header, McapRecord, Message, Metadata, Schema
from mcap.writer import CompressionType, Writer

from hermsd import __version__
from hermsd.files import fsync_directory

PERIOD_TOPIC: Final = "/hermsd/period"
READING_TOPIC: Final = "/hermsd/reading"
WINDOW_TOPIC: Final = "/hermsd/window"
TIMING_TOPIC: Final = "/hermsd/timing"
LOG_TOPIC: Final = "/hermsd/log"
CONFIG_TOPIC: Final = "/hermsd/config"
MODEL_TOPIC: Final = "/hermsd/model"
PROGRAM_TOPIC: Final = "/hermsd/program"

FILE_PREFIX: Final = "hermsd-"
PART_SUFFIX: Final = ".part"
METADATA_NAME: Final = "hermsd"
RECOVERY_METADATA_NAME: Final = "hermsd.recovery"
CONFIG_METADATA_NAME: Final = "hermsd.config"  # the config record again, for metadata readers
# Channel id → topic, outside chunks: read when the chunk defining a channel is damaged.
CHANNELS_METADATA_NAME: Final = "hermsd.channels"
LIBRARY: Final = f"hermsd/{__version__}"

# Chunks are closed by time (flush_interval), so this size is only an upper bound on memory.
CHUNK_SIZE: Final = 256 * 1024
RETRY_INTERVAL_S: Final = 5.0
RETRY_MAX_S: Final = 300.0
MCAP_MAGIC: Final = b"\x89MCAP0\r\n"


class LogLevel(IntEnum):
    """Levels of `foxglove.Log`, as Foxglove's log panel shows them."""

    DEBUG = 1
    INFO = 2
    WARNING = 3
    ERROR = 4
    FATAL = 5


@dataclass(frozen=True)
class TopicSpec:
    """A fixed topic: the name of its schema and the JSON schema its messages follow."""

    schema_name: str
    schema: dict[str, Any]

    def schema_bytes(self) -> bytes:
        return json.dumps(self.schema, separators=(",", ":")).encode()


def _field(kind: str | list[str], description: str, **extra: Any) -> dict[str, Any]:
    return {"type": kind, "description": description, **extra}


def _object(
    title: str, description: str, properties: dict[str, Any], optional: tuple[str, ...] = ()
) -> dict[str, Any]:
    """A record's schema; every property is required but the `optional` ones (fields added
    later, so the logs written before them still read)."""
    return {
        "title": title,
        "description": description,
        "type": "object",
        "properties": properties,
        "required": [name for name in properties if name not in optional],
    }


_T = _field("number", "monotonic time of the daemon, s")

TOPICS: Final[dict[str, TopicSpec]] = {
    PERIOD_TOPIC: TopicSpec(
        "hermsd.Period",
        _object(
            "hermsd.Period",
            "One control period: what was measured, decided and applied.",
            {
                "t": _T,
                "k": _field("integer", "period number since start"),
                "setpoint": _field("number", "setpoint, °C"),
                "pv": _field(["number", "null"], "process value for the period, °C"),
                "readings": _field(
                    "array", "sensor readings of the period, °C", items={"type": "number"}
                ),
                "output": _field("number", "controller output, %"),
                "applied": _field(
                    "number", "duty the SSR was driven at in the period before, as switched, %"
                ),
                "p": _field("number", "proportional part of the output (midrange: C1's), %"),
                "i": _field("number", "integral part of the output (midrange: C1's), %"),
                "d": _field("number", "derivative part of the output (midrange: C2's integral), %"),
                "mode": _field("string", "who sets the output", enum=["auto", "manual"]),
                "algorithm": _field("string", "controller in use"),
                "state": _field("string", "safety state: ok, held, alarm, …"),
                "alarms": _field("array", "active alarms", items={"type": "string"}),
                "heater_allowed": _field("boolean", "whether safety lets the element heat"),
                "reset_from": _field(
                    ["number", "null"],
                    "output the controller was reset to before this step (bumpless start), %",
                ),
                "u2": _field(["number", "null"], "second element's duty (midrange only), %"),
                "applied2": _field(
                    ["number", "null"],
                    "second element's duty in the period before, on account (C2 tracks it), %",
                ),
                "switched2": _field(
                    ["number", "null"],
                    "second element's duty in the period before, as switched, %",
                ),
                "full_from": _field(
                    ["integer", "null"],
                    "after this many of the readings the controller asked for full power at once "
                    "(a sudden drop: cold water)",
                ),
                "step": _field(["string", "null"], "the mash program's step, if one runs"),
                "step_index": _field(["integer", "null"], "that step's index, from 0"),
                "step_left_s": _field(
                    ["number", "null"], "time left of its hold, s (null: not reached, or held)"
                ),
                "next_step": _field(["string", "null"], "the next step's name"),
                "on2": _field(
                    ["boolean", "null"], "second element on as the period began (two elements)"
                ),
                "free2": _field(
                    ["boolean", "null"],
                    "its minimum on or off time let it switch this period (two elements)",
                ),
                "ceiling": _field(
                    ["number", "null"],
                    "where full power levels the water out, while short of the setpoint, °C",
                ),
            },
            optional=("u2", "applied2", "switched2", "on2", "free2", "ceiling"),
        ),
    ),
    READING_TOPIC: TopicSpec(
        "hermsd.Reading",
        _object(
            "hermsd.Reading",
            "One attempt to read the temperature sensor.",
            {
                "t": _T,
                "celsius": _field(["number", "null"], "temperature, °C"),
                "raw": _field(["integer", "null"], "temperature register word"),
                "crit": _field(["boolean", "null"], "T_CRIT flag of the register"),
                "high": _field(["boolean", "null"], "T_HIGH flag of the register"),
                "low": _field(["boolean", "null"], "T_LOW flag of the register"),
                "error": _field(["string", "null"], "why the read failed"),
                "errno": _field(["integer", "null"], "OS error number of a failed read"),
                "accepted": _field("boolean", "whether the reading fed the process value"),
            },
        ),
    ),
    WINDOW_TOPIC: TopicSpec(
        "hermsd.Window",
        _object(
            "hermsd.Window",
            "One time-proportioning window of the solid-state relay (a later record with "
            "the same t: the window was re-planned at full power inside it, cold water).",
            {
                "t": _T,
                "window": _field("number", "window length, s"),
                "requested": _field("number", "duty asked for, %"),
                "on_time": _field(
                    "number", "time the SSR is to be driven on, s (re-planned: from then on)"
                ),
                "applied": _field("number", "duty planned for the SSR in the whole window, %"),
            },
        ),
    ),
    TIMING_TOPIC: TopicSpec(
        "hermsd.Timing",
        _object(
            "hermsd.Timing",
            "How well the loop kept time since the last timing record.",
            {
                "t": _T,
                "period_lateness_p50": _field("number", "median lateness of a period start, s"),
                "period_lateness_p99": _field("number", "99th percentile of that lateness, s"),
                "period_lateness_max": _field("number", "worst lateness of a period start, s"),
                "edge_error_p50": _field("number", "median error of a relay edge, s"),
                "edge_error_p99": _field("number", "99th percentile of that error, s"),
                "edge_error_max": _field("number", "worst error of a relay edge, s"),
                "overruns": _field("integer", "periods that ran past their deadline"),
                "dropped": _field("integer", "records the recorder dropped"),
            },
        ),
    ),
    LOG_TOPIC: TopicSpec(
        "foxglove.Log",
        _object(
            "foxglove.Log",
            "An event, shown in Foxglove's log panel.",
            {
                "timestamp": {
                    "type": "object",
                    "description": "wall-clock time of the event",
                    "properties": {
                        "sec": {"type": "integer", "minimum": 0},
                        "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999},
                    },
                    "required": ["sec", "nsec"],
                },
                "level": _field(
                    "integer",
                    "1 DEBUG, 2 INFO, 3 WARNING, 4 ERROR, 5 FATAL",
                    enum=[level.value for level in LogLevel],
                ),
                "message": _field("string", "what happened"),
                "name": _field("string", "part of the daemon that speaks"),
                "file": _field("string", "source file, if any"),
                "line": _field("integer", "source line, if any", minimum=0),
            },
        ),
    ),
    CONFIG_TOPIC: TopicSpec(
        "hermsd.Config",
        _object(
            "hermsd.Config",
            "The configuration in force, repeated at the start of every file.",
            {
                "t": _T,
                "config": _field("object", "the configuration as loaded"),
                "reason": _field("string", "why it was recorded: start, reload, …"),
                "model": _field(
                    "object", "the tun's model the controller uses: gain, tau, dead_time, ambient"
                ),
                "drop_readings": _field(
                    "integer", "readings in a row that show cold water inside a period (full_from)"
                ),
                "drop_onset_c": _field(
                    "number", "°C below the last PV the first of those readings must lie"
                ),
                "drop_fall_c": _field(
                    "number", "°C below the last PV the latest of them must lie at least"
                ),
                "drop_carry": _field(
                    "boolean", "full power acted on inside a period carries on while PV falls"
                ),
                "reach_watch": _field(
                    "boolean", "each period's ceiling is the reach watch's (replay checks it)"
                ),
                "steady_duty_share": _field(
                    "number", "share of a measuring step to full power the duty may move before"
                ),
                "recovery_fit_periods": _field(
                    "integer", "fewest full-power periods a recovery's rate is fitted over"
                ),
            },
            optional=("drop_carry", "reach_watch", "steady_duty_share", "recovery_fit_periods"),
        ),
    ),
    PROGRAM_TOPIC: TopicSpec(
        "hermsd.ProgramEvent",
        _object(
            "hermsd.ProgramEvent",
            "One event of the mash program.",
            {
                "t": _T,
                "event": _field(
                    "string",
                    "what happened",
                    enum=[
                        "started",
                        "step_started",
                        "step_reached",
                        "step_done",
                        "waiting",
                        "confirmed",
                        "paused",
                        "resumed",
                        "skipped",
                        "finished",
                        "stopped",
                        "release",
                        "late",
                        "climb",
                    ],
                ),
                "program": _field("string", "the program's name"),
                "step": _field(["integer", "null"], "the step's index, from 0"),
                "name": _field(["string", "null"], "the step's name"),
                "setpoint": _field(["number", "null"], "the step's setpoint, °C"),
                "message": _field(["string", "null"], "the confirmation asked for or given"),
            },
        ),
    ),
    MODEL_TOPIC: TopicSpec(
        "hermsd.LearnedModel",
        _object(
            "hermsd.LearnedModel",
            "What was learned of the tun, as stored for the next start.",
            {
                "t": _T,
                "learned": _field(
                    "object", "rate °C/s at full power, loss 1/s, dead_time s, ambient °C, litres"
                ),
            },
        ),
    ),
}


def log_message(
    level: LogLevel, message: str, log_time_ns: int, *, name: str = "hermsd"
) -> dict[str, Any]:
    """A `foxglove.Log` message stamped with `log_time_ns` (ns since the Unix epoch)."""
    sec, nsec = divmod(log_time_ns, 1_000_000_000)
    return {
        "timestamp": {"sec": sec, "nsec": nsec},
        "level": int(level),
        "message": message,
        "name": name,
        "file": "",
        "line": 0,
    }


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
        self.writer = Writer(stream, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD)
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
        self.writer.flush()  # type: ignore[no-untyped-call]
        self.flushed += self.unflushed
        self.unflushed = 0
        self.flush_due = None

    def datasync(self, now: float) -> None:
        os.fdatasync(self.stream.fileno())
        self.last_sync = now
        self.sync_due = None

    def finish(self) -> None:
        self.writer.finish()  # type: ignore[no-untyped-call]
        self.stream.flush()
        self.unflushed = 0
        os.fdatasync(self.stream.fileno())
        self.stream.close()

    def discard(self) -> None:
        """Let the file go; remove it if no message of it reached the OS (nothing to recover)."""
        # The disk already failed; closing releases the descriptor even when it raises.
        with contextlib.suppress(Exception):
            self.stream.close()
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


def _describe(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror  # the file is named by the caller, once
    return str(exc) or type(exc).__name__


# --- reading and recovery --------------------------------------------------------------------


class RecordedMessage(NamedTuple):
    topic: str
    log_time_ns: int
    message: dict[str, Any]


class Damage(NamedTuple):
    """Part of a file that could not be read and was skipped; the records after it were read.

    `messages` is how many messages were lost with it, when that is known (a damaged chunk's
    message indexes say how many it held).
    """

    what: str  # "chunk at byte 1234", "bytes 1234 to 5678", "the summary"
    reason: str
    messages: int | None = None

    def describe(self) -> str:
        if self.messages is None:
            lost = ""
        else:
            lost = f" ({self.messages or 'no'} message{'' if self.messages == 1 else 's'} lost)"
        return f"{self.what} damaged ({self.reason}), skipped{lost}"


_RECORD_HEAD = struct.Struct("<BQ")  # opcode, length of the body
_CHANNEL_HEAD = struct.Struct("<HHI")  # id, schema id, length of the topic
_MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_MESSAGE_INDEX_HEAD = struct.Struct("<HI")  # channel id, length of its (time, offset) pairs
_MESSAGE_INDEX_ENTRY_SIZE: Final = 16
_UINT32 = struct.Struct("<I")
_OP_HEADER: Final = 0x01
_OP_FOOTER: Final = 0x02
_OP_SCHEMA: Final = 0x03
_OP_CHANNEL: Final = 0x04
_OP_MESSAGE: Final = 0x05
_OP_CHUNK: Final = 0x06
_OP_MESSAGE_INDEX: Final = 0x07
_OP_METADATA: Final = 0x0C
_OP_DATA_END: Final = 0x0F
_OP_LAST_DEFINED: Final = 0x0F  # opcodes 0x10 to 0x7f are reserved; 0x80 and up are private
_OP_PRIVATE: Final = 0x80
_COPIED_OUTSIDE_CHUNKS: Final = (_OP_HEADER, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_METADATA)


def _sift_chunk(
    data: bytes,
    channels: dict[int, str | None],
    topics: Collection[str] | None,
    into: list[tuple[int, int, str, bytes]],
    orphans: list[tuple[int, int, bytes]],
) -> int:
    """Add (log time, order, topic, data) of a run's messages on wanted topics to `into`.

    Channels defined in the run are added to `channels` (None for a topic not wanted), so
    the other messages are skipped unread (parsing by hand costs a fraction of building
    every record). A message on a channel not defined yet (its definition was in a damaged
    chunk) goes to `orphans` as (channel id, log time, data). Returns how many messages the
    run holds on any topic.
    """
    position, end, messages = 0, len(data), 0
    while position < end:
        opcode, length = _RECORD_HEAD.unpack_from(data, position)
        body = position + _RECORD_HEAD.size
        position = body + length
        if position > end:
            raise ValueError("a record runs past the end of its chunk")
        if opcode == _OP_MESSAGE:
            messages += 1
            channel_id, _, log_time, _ = _MESSAGE_HEAD.unpack_from(data, body)
            topic = channels.get(channel_id)
            if topic is not None:
                into.append(
                    (log_time, len(into), topic, data[body + _MESSAGE_HEAD.size : position])
                )
            elif channel_id not in channels:
                orphans.append((channel_id, log_time, data[body + _MESSAGE_HEAD.size : position]))
        elif opcode == _OP_CHANNEL:
            channel_id, _, topic_length = _CHANNEL_HEAD.unpack_from(data, body)
            start = body + _CHANNEL_HEAD.size
            topic = data[start : start + topic_length].decode()
            (encoding_length,) = _UINT32.unpack_from(data, start + topic_length)
            encoding = data[start + topic_length + 4 : start + topic_length + 4 + encoding_length]
            wanted = encoding == b"json" and (topics is None or topic in topics)
            channels.setdefault(channel_id, topic if wanted else None)
    return messages


_FOOTER = struct.Struct("<BQQQI")  # opcode, length, summary start, summary offset start, CRC
_FOOTER_LENGTH: Final = _FOOTER.size - _RECORD_HEAD.size
_FOOTER_CRC_SIZE: Final = 4  # the CRC covers the footer up to, not including, itself


def _is_finished(path: Path) -> bool:
    """Whether `path` ends with a footer and a whole summary (it was closed properly).

    The summary is checked against the CRC in the footer, not parsed: it indexes every chunk,
    tens of thousands of records for a day logged a chunk per flush.
    """
    tail_size = _FOOTER.size + len(MCAP_MAGIC)
    try:
        with path.open("rb") as f:
            size = f.seek(0, os.SEEK_END)
            if size < len(MCAP_MAGIC) + tail_size:
                return False
            f.seek(0)
            head = f.read(len(MCAP_MAGIC))
            footer_at = f.seek(size - tail_size)
            tail = f.read(tail_size)
            opcode, length, summary_start, _, summary_crc = _FOOTER.unpack_from(tail)
            if (
                head != MCAP_MAGIC
                or tail[_FOOTER.size :] != MCAP_MAGIC
                or (opcode, length) != (_OP_FOOTER, _FOOTER_LENGTH)
                or not len(MCAP_MAGIC) <= summary_start < footer_at  # 0: no summary
            ):
                return False
            if summary_crc == 0:  # written without CRCs
                return True
            f.seek(summary_start)
            covered = f.read(footer_at - summary_start + _FOOTER.size - _FOOTER_CRC_SIZE)
            return zlib.crc32(covered) == int(summary_crc)
    except OSError:
        return False


_CHUNK_HEAD = struct.Struct("<16xQII")  # (times,) uncompressed size and CRC, name length
_LENGTH = struct.Struct("<Q")
_DATA_END = struct.Struct("<I")  # CRC of the data section
# A zstd chunk, as hermsd writes them, has its compression's name this far into the record:
# opcode and length (9 bytes), start and end time (16), size (8) and CRC (4) of its records.
_ZSTD_NAME: Final = _UINT32.pack(4) + b"zstd"
_ZSTD_NAME_AT: Final = _RECORD_HEAD.size + _CHUNK_HEAD.size - _UINT32.size


class _Damaged(Exception):
    """A record that cannot be read whole."""


class _Walk:
    """The readable records of an MCAP file, as runs of records for `_sift_chunk`.

    A chunk's run is its records, decompressed, yielded only if they match the chunk's size
    and CRC; a header, schema, channel, message or metadata record outside chunks is a run of
    its own; other records are skipped by their length, unread. A damaged chunk is skipped
    (`damaged` says where and why) and reading goes on after it: at its end, when a record
    plausibly starts there, else at the next zstd chunk further on. Where no readable record
    follows, the file is cut: `cut_at` says where, `cut_reason` why (None: the file simply
    ended there). After the data section only channel and schema records are yielded (the
    summary repeats them: the definitions a damaged first chunk took with it).
    Reading by hand costs a fraction of what mcap's StreamReader does (an object for each of
    the chunks, message indexes and chunk indexes of a day, a decompressor per chunk).
    """

    def __init__(self, data: bytes) -> None:
        self.data = data
        self.cut_at: int | None = None
        self.cut_reason: str | None = None
        self.damaged: list[Damage] = []
        self.footer_read = False
        self.metadata: dict[str, dict[str, str]] = {}  # by name, a later record winning
        self.messages_found = False  # a whole chunk, or a message outside chunks, was read
        self._resume_at = 0  # where `_resume_after` found readable records again

    def runs(self) -> Iterator[bytes]:
        data = self.data
        if not data.startswith(MCAP_MAGIC):
            self.cut_at, self.cut_reason = 0, "the file does not start with the MCAP magic"
            return
        view = memoryview(data)
        decompressor = zstandard.ZstdDecompressor()
        position, size = len(MCAP_MAGIC), len(data)
        in_summary = False
        skipped_chunk: int | None = None  # index in `damaged` of a chunk just skipped
        head = _RECORD_HEAD
        while position < size:
            body = position + head.size
            opcode, end = head.unpack_from(data, position) if body <= size else (0, 0)
            end += body
            if end > size or opcode == 0 or _OP_LAST_DEFINED < opcode < _OP_PRIVATE:
                try:
                    self._record_at(position)  # for the reason
                except _Damaged as exc:
                    if not self._resume_after(position, str(exc), in_summary):
                        return
                position = self._resume_at
                continue
            if opcode == _OP_MESSAGE_INDEX:  # the commonest record: several after each chunk
                if skipped_chunk is not None:
                    damage = self.damaged[skipped_chunk]
                    lost = (end - body - _MESSAGE_INDEX_HEAD.size) // _MESSAGE_INDEX_ENTRY_SIZE
                    counted = (damage.messages or 0) + lost
                    self.damaged[skipped_chunk] = damage._replace(messages=counted)
                position = end
                continue
            skipped_chunk = None
            if opcode == _OP_CHUNK:
                try:
                    records = _chunk_records(view[body:end], decompressor)
                except (_Damaged, zstandard.ZstdError, struct.error) as exc:
                    reason = _describe(exc)
                    if not self._follows_a_record(end):
                        if not self._resume_after(position, reason, in_summary):
                            return
                        position = self._resume_at
                        continue
                    skipped_chunk = len(self.damaged)
                    self.damaged.append(Damage(f"chunk at byte {position}", reason, 0))
                else:
                    self.messages_found = True
                    yield records
            elif opcode in _COPIED_OUTSIDE_CHUNKS:
                if not in_summary or opcode in (_OP_SCHEMA, _OP_CHANNEL):
                    if opcode == _OP_METADATA:
                        self._note_metadata(view[body:end])
                    self.messages_found |= opcode == _OP_MESSAGE
                    yield data[position:end]
            elif opcode == _OP_DATA_END:
                (crc,) = _DATA_END.unpack_from(view[body:end])
                if crc != 0 and zlib.crc32(view[:position]) != crc:
                    self.cut_at, self.cut_reason = (
                        position,
                        "the data section does not match its CRC",
                    )
                    return
                in_summary = True
            elif opcode == _OP_FOOTER:
                if data[end : end + len(MCAP_MAGIC)] != MCAP_MAGIC:
                    self.cut_at = end  # the footer was whole
                    self.cut_reason = "the footer is not followed by the MCAP magic"
                    return
                self.footer_read = True
                return
            position = end

    def _record_at(self, position: int) -> tuple[int, int, int]:
        """(opcode, start of body, end) of the record at `position`; _Damaged if none is."""
        size = len(self.data)
        if position + _RECORD_HEAD.size > size:
            raise _Damaged("the file ends inside a record")
        opcode, length = _RECORD_HEAD.unpack_from(self.data, position)
        if opcode == 0 or _OP_LAST_DEFINED < opcode < _OP_PRIVATE:
            raise _Damaged(f"no record starts there (opcode {opcode:#04x})")
        body = position + _RECORD_HEAD.size
        if body + length > size:
            raise _Damaged("the file ends inside a record")
        return opcode, body, body + length

    def _follows_a_record(self, position: int) -> bool:
        """Whether the end of a damaged chunk is plausibly the start of the next record."""
        if position == len(self.data):
            return True
        try:
            opcode, body, end = self._record_at(position)
        except _Damaged:
            return False
        if opcode == _OP_MESSAGE_INDEX:
            if end - body < _MESSAGE_INDEX_HEAD.size:
                return False
            _, pairs = _MESSAGE_INDEX_HEAD.unpack_from(self.data, body)
            return bool(end - body == _MESSAGE_INDEX_HEAD.size + pairs)
        if opcode == _OP_DATA_END:
            return end - body == _DATA_END.size
        return bool(opcode in (_OP_CHUNK, _OP_METADATA))

    def _resume_after(self, position: int, reason: str, in_summary: bool) -> bool:
        """Find where to read on after unreadable bytes at `position`; False: nowhere (a cut).

        In the summary nothing more is needed: its damage is noted and reading stops.
        """
        if in_summary:
            self.damaged.append(Damage(f"the summary at byte {position}", reason, 0))
            return False
        found = self.data.find(_ZSTD_NAME, position + 1 + _ZSTD_NAME_AT)
        while found != -1:
            start = found - _ZSTD_NAME_AT
            try:
                opcode, _, _ = self._record_at(start)
            except _Damaged:
                opcode = 0
            if opcode == _OP_CHUNK:
                self.damaged.append(Damage(f"bytes {position} to {start}", reason))
                self._resume_at = start
                return True
            found = self.data.find(_ZSTD_NAME, found + 1)
        self.cut_at, self.cut_reason = position, reason
        return False

    def _note_metadata(self, body: memoryview) -> None:
        try:
            name, values = _metadata(bytes(body))
        except (struct.error, UnicodeDecodeError, ValueError, EOFError):
            return
        self.metadata[name] = values

    @property
    def channel_topics(self) -> dict[int, str]:
        """Channel id → topic, from the hermsd.channels metadata (none in older files)."""
        named = self.metadata.get(CHANNELS_METADATA_NAME, {})
        return {int(key): topic for key, topic in named.items() if key.isdigit()}


def _metadata(body: bytes) -> tuple[str, dict[str, str]]:
    """The name and the key-value pairs of a metadata record's body."""
    stream = ReadDataStream(io.BytesIO(body))
    record = Metadata.read(stream)
    return record.name, dict(record.metadata)


def _chunk_records(chunk: memoryview, decompressor: zstandard.ZstdDecompressor) -> bytes:
    """The records in a chunk's body, decompressed; _Damaged unless they match its size and CRC."""
    size, crc, name_length = _CHUNK_HEAD.unpack_from(chunk)
    name_end = _CHUNK_HEAD.size + name_length
    compression = bytes(chunk[_CHUNK_HEAD.size : name_end])
    (length,) = _LENGTH.unpack_from(chunk, name_end)
    start = name_end + _LENGTH.size
    if start + length != len(chunk):
        raise _Damaged("a chunk's records do not fill it")
    compressed = chunk[start : start + length]
    if compression == b"zstd":
        records = decompressor.decompress(compressed, max_output_size=size)
    elif compression == b"":
        records = bytes(compressed)
    else:
        raise _Damaged(f"chunks compressed with {compression!r} are not supported")
    if len(records) != size:
        raise _Damaged(f"a chunk holds {len(records)} bytes, not the {size} it declares")
    if crc != 0 and zlib.crc32(records) != crc:
        raise _Damaged("a chunk does not match its CRC")
    return records


class LogFile:
    """One hermsd MCAP file, finished or cut short, read in log-time order.

    Every file is read record by record up to its end or its cut, a finished one too (its
    index would only say where the same chunks are). After `messages()` has run, `count`
    says how many messages it yielded, `recovered` how many its readable records hold on
    any topic, `damaged` which parts were skipped and why (reading went on after them) and,
    unless the file was finished and read whole, `cut_at` up to which byte it held readable
    records and `cut_reason` why the next one could not be read (None: the file simply
    ended there).
    """

    def __init__(self, path: Path | str) -> None:
        self.path = Path(path)
        self.finished = _is_finished(self.path)
        self.count = 0
        self.recovered = 0
        self.cut_at: int | None = None
        self.cut_reason: str | None = None
        self.damaged: list[Damage] = []
        self.metadata_read: dict[str, dict[str, str]] = {}  # by `messages()`, as `metadata()`
        self.size = self.path.stat().st_size

    def messages(self, topics: Collection[str] | None = None) -> Iterator[RecordedMessage]:
        """The messages in log-time order; only those on `topics`, when given, are decoded.

        ValueError: the file holds records that pass their CRC but cannot be decoded.
        """
        self.count = self.recovered = 0
        channels: dict[int, str | None] = {}
        pending: list[tuple[int, int, str, bytes]] = []
        orphans: list[tuple[int, int, bytes]] = []
        content = self.path.read_bytes()  # tens of MB for a day: read at once, walked by hand
        self.size = len(content)  # a file being written may have grown since it was opened
        walk = _Walk(content)
        try:
            for run in walk.runs():
                self.recovered += _sift_chunk(run, channels, topics, pending, orphans)
        except (struct.error, UnicodeDecodeError, ValueError) as exc:
            raise ValueError(f"{self.path}: damaged MCAP data: {_describe(exc)}") from exc
        self.damaged = walk.damaged
        self.metadata_read = walk.metadata
        unknown = 0
        channel_topics = walk.channel_topics
        for channel_id, log_time, data in orphans:  # their channel was in a damaged chunk
            topic = channels.get(channel_id) or channel_topics.get(channel_id)
            if topic is None and channel_id not in channels:
                unknown += 1
            elif topic is not None and (topics is None or topic in topics):
                pending.append((log_time, len(pending), topic, data))
        if unknown:
            reason = "their channel was defined in a damaged chunk"
            self.damaged.append(Damage(f"{unknown} messages", reason))
        if walk.footer_read and not self.finished:
            self.damaged.append(Damage("the summary", "it does not match its CRC", 0))
        if not (self.finished and walk.cut_at is None):
            self.cut_at = self.size if walk.cut_at is None else walk.cut_at
            self.cut_reason = walk.cut_reason
        pending.sort()
        for log_time, _, topic, data in pending:
            try:
                message = json.loads(data)
            except ValueError as exc:
                raise ValueError(f"{self.path}: a message is not JSON: {exc}") from exc
            self.count += 1
            yield RecordedMessage(topic, log_time, message)

    def metadata(self) -> dict[str, dict[str, str]]:
        """Metadata records by name (a later record of the same name wins)."""
        walk = _Walk(self.path.read_bytes())
        for _ in walk.runs():
            pass
        return walk.metadata


def read_messages(paths: Iterable[Path | str]) -> Iterator[RecordedMessage]:
    """Every message of `paths`, file after file, each file in log-time order."""
    for path in paths:
        yield from LogFile(path).messages()


def _records(runs: Iterable[bytes]) -> Iterator[McapRecord]:
    """The header, schema, channel, message and metadata records of runs, as mcap's objects."""
    readers: dict[int, Callable[[ReadDataStream, int], McapRecord]] = {
        _OP_HEADER: lambda stream, _: Header.read(stream),
        _OP_SCHEMA: lambda stream, _: Schema.read(stream),
        _OP_CHANNEL: lambda stream, _: Channel.read(stream),
        _OP_MESSAGE: Message.read,
        _OP_METADATA: lambda stream, _: Metadata.read(stream),
    }
    for run in runs:
        position = 0
        while position < len(run):
            opcode, length = _RECORD_HEAD.unpack_from(run, position)
            body = position + _RECORD_HEAD.size
            position = body + length
            reader = readers.get(opcode)
            if reader is not None:
                yield reader(ReadDataStream(io.BytesIO(run[body:position])), length)


class NotRecovered(ValueError):
    """No log was made from a `.part` (no message in it could be read): it is left as it is."""

    def __init__(self, part: Path, why: str) -> None:
        super().__init__(f"{why}; left as it is, no log made from it")
        self.part = part


class Recovery(NamedTuple):
    """What `recover` made of a `.part`: the brewer is told how much of it was kept."""

    path: Path
    source: str  # the .part's name
    messages: int
    source_bytes: int
    complete_bytes: int  # up to where its records could be read (the rest is lost)
    damaged: tuple[Damage, ...]

    def describe(self) -> str:
        if self.complete_bytes == self.source_bytes:
            read = f"read to the end of its {self.source_bytes} bytes"
        else:
            read = f"read to byte {self.complete_bytes} of its {self.source_bytes} (the rest lost)"
        damaged = "".join(f"; {damage.describe()}" for damage in self.damaged)
        return f"{self.path} from {self.source}: {self.messages} messages, {read}{damaged}"


def recover(path: Path | str) -> Recovery:
    """Turn a leftover `.mcap.part` into a finished `.mcap` holding every readable record.

    Damaged chunks are skipped (said in the recovery metadata and the returned Recovery),
    not the rest of the file. The new file is written beside it, synced and renamed into
    place before the `.part` is removed, so an interruption at any point leaves the data on
    disk (a rerun redoes it). NotRecovered, the `.part` untouched, when no message in it can
    be read: its bytes may still be worth a look, and an empty log in their place says
    nothing. Call it before a Recorder starts writing in the same directory.
    """
    part = Path(path)
    if not part.name.endswith(".mcap" + PART_SUFFIX):
        raise ValueError(f"recover: {part} is not a .mcap.part file")
    final = part.with_name(part.name.removesuffix(PART_SUFFIX))
    temporary = part.with_name(final.name + ".recovering")
    data = part.read_bytes()
    walk = _Walk(data)
    try:
        with temporary.open("wb") as target:
            writer = Writer(target, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD)
            try:
                kept = _copy_records(_records(walk.runs()), writer, lambda: walk.channel_topics)
            except (struct.error, UnicodeDecodeError, ValueError, EOFError) as exc:
                raise NotRecovered(part, f"damaged MCAP data: {_describe(exc)}") from exc
            if not kept:
                why = "" if walk.cut_reason is None else f" ({walk.cut_reason})"
                raise NotRecovered(part, f"no message readable in its {len(data)} bytes{why}")
            complete = len(data) if walk.cut_at is None else walk.cut_at
            writer.add_metadata(
                RECOVERY_METADATA_NAME,
                {
                    "source": part.name,
                    "messages": str(kept),
                    "source_bytes": str(len(data)),
                    "complete_bytes": str(complete),
                    "cut": "no" if walk.cut_reason is None else walk.cut_reason,
                    "damaged": "; ".join(d.describe() for d in walk.damaged) or "no",
                },
            )
            writer.finish()  # type: ignore[no-untyped-call]
            target.flush()
            os.fsync(target.fileno())
        os.replace(temporary, final)
    except BaseException:
        with contextlib.suppress(OSError):
            temporary.unlink(missing_ok=True)
        raise
    fsync_directory(final.parent)
    part.unlink()
    fsync_directory(final.parent)
    return Recovery(final, part.name, kept, len(data), complete, tuple(walk.damaged))


def recover_directory(directory: Path | str) -> list[Recovery | NotRecovered]:
    """Recover every leftover `.mcap.part` of the recorder in `directory`, oldest first.

    A `.part` with nothing readable stays as it is (its NotRecovered says why) and the
    others are still recovered. Disk errors propagate (the `.part` files stay for the next
    attempt).
    """
    outcomes: list[Recovery | NotRecovered] = []
    for part in sorted(Path(directory).glob(f"{FILE_PREFIX}*.mcap{PART_SUFFIX}")):
        try:
            outcomes.append(recover(part))
        except NotRecovered as error:
            outcomes.append(error)
    return outcomes


def _copy_records(
    records: Iterator[McapRecord], writer: Writer, channel_topics: Callable[[], dict[int, str]]
) -> int:
    """Write the schemas, channels, messages and metadata of `records` again; count messages.

    Schemas and channels repeated in a summary section are written once. A message whose
    channel was defined in a damaged chunk is kept when the summary defines it again, or
    when `channel_topics()` (hermsd's own metadata, once all is read) names one of
    hermsd's topics for it.
    """
    first = next(records, None)
    if isinstance(first, Header):
        writer.start(first.profile, first.library)
    else:
        writer.start("", LIBRARY)
        if first is not None:
            records = itertools.chain([first], records)
    schema_ids: dict[int, int] = {0: 0}
    channel_ids: dict[int, int] = {}
    orphans: list[Message] = []
    kept = 0
    for record in records:
        if isinstance(record, Schema) and record.id not in schema_ids:
            schema_ids[record.id] = writer.register_schema(
                record.name, record.encoding, record.data
            )
        elif (
            isinstance(record, Channel)
            and record.id not in channel_ids
            and record.schema_id in schema_ids
        ):
            channel_ids[record.id] = writer.register_channel(
                record.topic, record.message_encoding, schema_ids[record.schema_id], record.metadata
            )
        elif isinstance(record, Message):
            if record.channel_id in channel_ids:
                _copy_message(writer, channel_ids[record.channel_id], record)
                kept += 1
            else:
                orphans.append(record)
        elif isinstance(record, Metadata):
            writer.add_metadata(record.name, record.metadata)
    topics = channel_topics()
    for record in orphans:
        if record.channel_id not in channel_ids:
            spec = TOPICS.get(topics.get(record.channel_id, ""))
            if spec is None:
                continue
            schema = writer.register_schema(spec.schema_name, "jsonschema", spec.schema_bytes())
            topic = topics[record.channel_id]
            channel_ids[record.channel_id] = writer.register_channel(topic, "json", schema)
        _copy_message(writer, channel_ids[record.channel_id], record)
        kept += 1
    return kept


def _copy_message(writer: Writer, channel_id: int, record: Message) -> None:
    writer.add_message(
        channel_id, record.log_time, record.data, record.publish_time, record.sequence
    )
