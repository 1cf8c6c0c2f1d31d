"""The log reader: a brew day's MCAP logs (finished or cut) read back as periods, events and config.

Below everything that reads a log (replay, the plot, tune): it only reads, never re-runs."""

from __future__ import annotations

import bisect
import dataclasses
import itertools
import math
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple, TypeGuard

from hermsd.files import not_regular
from hermsd.log.mcap_file import LogFile
from hermsd.log.mcap_writer import MCAP_MAGIC
from hermsd.log.topics import (
    CONFIG_TOPIC,
    LOG_TOPIC,
    METADATA_NAME,
    PERIOD_TOPIC,
    PROGRAM_TOPIC,
    TIMING_TOPIC,
    LogLevel,
)
from hermsd.runtime.period import PeriodRecord
from hermsd.safety.limits import RAISED_ALARM

if TYPE_CHECKING:
    pass


TOPICS_READ = (PERIOD_TOPIC, CONFIG_TOPIC, LOG_TOPIC, TIMING_TOPIC, PROGRAM_TOPIC)


# A sudden drop: PV falls this much within this time. Heat loss alone cools a hot tun by
# (T − T_amb)/τ ≈ 0.2 °C a minute at most; cold water poured in drops it by degrees at once.
DROP_C = 1.0


DROP_WINDOW_S = 60.0


_PERIOD_FIELDS = tuple(f.name for f in dataclasses.fields(PeriodRecord))


class ReplayError(ValueError):
    """Logs that cannot be replayed as asked; the message is one line that says why."""


@dataclass(frozen=True, slots=True)
class FileReport:
    """What was recovered from one file."""

    path: str
    size: int
    messages: int  # in its complete records, on any topic
    periods: int
    finished: bool
    cut_at: int | None  # bytes of complete records, for a file that was not finished
    cut_reason: str | None
    damaged: list[str] = field(default_factory=list)  # parts skipped, and what they cost


@dataclass(frozen=True, slots=True)
class LoggedConfig:
    """A /hermsd/config record: the configuration (as `config.to_dict` wrote it) from `t` on."""

    t: float
    reason: str
    config: dict[str, Any]
    model: dict[str, Any] | None = None  # the tun's model the controller used (predictive)
    safety_model: dict[str, Any] | None = None  # the measured tun the safety limits came from
    control_law: int | None = None  # `pid.CONTROL_LAW_VERSION` of its daemon (None: before 1)
    repeat: bool = False  # the copy of the record in force that opens a rotated file of a run


@dataclass(frozen=True, slots=True)
class LogEvent:
    """A /hermsd/log event, placed on the replay's clock."""

    at: float
    level: int
    message: str


@dataclass(frozen=True, slots=True)
class ProgramEvent:
    """A /hermsd/program record (a step started, reached, done; waiting; …) on the replay's
    clock; the fields a record lacks, or holds with the wrong type, are None."""

    at: float
    event: str
    program: str | None
    step: int | None
    name: str | None
    setpoint: float | None
    message: str | None


@dataclass(slots=True)
class Log:
    """The records of a day's files that replay uses, in replay order."""

    files: list[FileReport] = field(default_factory=list)
    entries: list[LoggedConfig | PeriodRecord] = field(default_factory=list)
    configs: list[LoggedConfig] = field(default_factory=list)
    periods: list[PeriodRecord] = field(default_factory=list)
    elapsed: list[float] = field(default_factory=list)  # of each period, s since the first
    log_time_ns: list[int] = field(default_factory=list)  # of each period (wall clock)
    events: list[LogEvent] = field(default_factory=list)
    program: list[ProgramEvent] = field(default_factory=list)
    timings: list[dict[str, Any]] = field(default_factory=list)
    runs: list[dict[str, Any]] = field(default_factory=list)  # of the daemon, one after another

    def period_s(self) -> float:
        """The control period: the logged config's, else the typical spacing of the records."""
        for entry in self.configs:
            value = _lookup(entry.config, "control", "period")
            if value is not None and value > 0:
                return value
        gaps = sorted(b - a for a, b in itertools.pairwise(self.elapsed) if b > a)
        return gaps[len(gaps) // 2] if gaps else 1.0


@dataclass(slots=True)
class _FileRecords:
    """What one file holds for replay, before the files are put in order and joined."""

    path: Path
    report: FileReport
    run: str | None  # the recorder's run id (older files have none)
    configs: list[LoggedConfig] = field(default_factory=list)
    config_times: list[int] = field(default_factory=list)  # the log time of each config
    periods: list[tuple[PeriodRecord, int]] = field(default_factory=list)  # with log time
    anchors: list[tuple[int, float]] = field(default_factory=list)  # (log time, t), no config
    raw_events: list[tuple[int, int, str]] = field(default_factory=list)
    program: list[dict[str, Any]] = field(default_factory=list)  # each with a number `t`
    timings: list[dict[str, Any]] = field(default_factory=list)
    first_ns: int | None = None  # log time of its first and last record read
    last_ns: int | None = None


def load(paths: Sequence[Path | str]) -> Log:
    """The records of `paths` in the order of their first record; ReplayError when nothing
    usable is in them, or when they are not the files of one day (see `_in_order`)."""
    files = _in_order([_read(path) for path in _distinct(paths)])
    log = Log()
    origin: float | None = None  # t of the first period
    offset = 0.0  # added to a file's t to continue the clock of the files before it
    in_force: LoggedConfig | None = None  # the last config record of the files before
    before: _FileRecords | None = None
    carried: list[tuple[int, float]] = []  # the last (log time, t) of the file before
    for file in files:
        log.files.append(file.report)
        latest = file.configs[-1] if file.configs else in_force
        rotated = bool(file.configs) and before is not None and _rotated(file, before, in_force)
        if rotated:
            file.configs[0] = dataclasses.replace(file.configs[0], repeat=True)
        in_force = latest
        before = file
        periods = sorted(file.periods, key=lambda p: p[0].t)
        if periods:
            first_t, first_ns = periods[0][0].t, periods[0][1]
            if origin is None:
                origin = first_t
            elif first_t + offset <= log.elapsed[-1] + origin:
                # t started again: join the clocks by the wall-clock gap (at least one period)
                gap = max((first_ns - log.log_time_ns[-1]) / 1e9, log.period_s())
                offset = log.elapsed[-1] + origin + gap - first_t
            for record, log_time_ns in periods:
                log.periods.append(record)
                log.elapsed.append(record.t + offset - origin)
                log.log_time_ns.append(log_time_ns)
        entries: list[LoggedConfig | PeriodRecord] = [*file.configs, *(p for p, _ in periods)]
        entries.sort(key=lambda e: (e.t, isinstance(e, PeriodRecord)))
        log.entries.extend(entries)
        log.configs.extend(e for e in entries if isinstance(e, LoggedConfig))
        # A repeat carries the t it was first written at, not the t of the time it opens the
        # file at: there the run's clock goes on from the file before.
        configs = zip(file.configs, file.config_times, strict=True)
        anchors = (carried if rotated else []) + sorted(
            file.anchors + [(ns, c.t) for c, ns in configs if not c.repeat]
        )
        carried = anchors[-1:]
        if origin is not None:
            shift = offset - origin
            log.events.extend(
                LogEvent(_t_at(anchors, ns) + shift, level, text)
                for ns, level, text in file.raw_events
                if anchors
            )
            log.timings.extend(file.timings)
            log.program.extend(_program_event(m, m["t"] + shift) for m in file.program)
    log.runs = _runs(files)
    if not log.periods:
        names = ", ".join(str(p) for p in paths)
        raise ReplayError(f"{names}: no control periods recovered, nothing to replay")
    log.events.sort(key=lambda e: e.at)
    log.program.sort(key=lambda e: e.at)
    return log


def _rotated(file: _FileRecords, before: _FileRecords, in_force: LoggedConfig | None) -> bool:
    """Whether `file` is the next file of the run `before` was the last file of, rotated: it
    then opens with a copy of the config record in force (the recorder repeats it).

    The recorder's run id tells a run's files from another run's. Another run's first
    record may be identical to it (a simulated run starts at t = 0 with the same config), and
    is a new start all the same. Files without the id (an older recorder): another run's
    periods count from k = 1 again, a rotated file's go on from the last file's.
    """
    if file.configs[0] != in_force:
        return False
    if file.run is not None and before.run is not None:
        return file.run == before.run
    if not file.periods or not before.periods:
        return True
    return min(p.k for p, _ in file.periods) > max(p.k for p, _ in before.periods)


def _distinct(paths: Sequence[Path | str]) -> list[Path]:
    """`paths`, or ReplayError when one file is named twice (its records would count twice)."""
    seen: dict[tuple[int, int], Path] = {}
    for path in map(Path, paths):
        try:
            status = path.stat()
        except OSError:
            continue  # _open says why
        first = seen.setdefault((status.st_dev, status.st_ino), path)
        if first is not path:
            same = "is given twice" if first == path else f"and {first} are the same file"
            raise ReplayError(f"{path} {same}: name each file once")
    return list(map(Path, paths))


def _read(path: Path) -> _FileRecords:
    """The records replay uses of one file."""
    log_file = _open(path)
    file = _FileRecords(path, FileReport(str(path), 0, 0, 0, False, None, None), None)
    try:
        for topic, log_time_ns, message in log_file.messages(TOPICS_READ):
            if file.first_ns is None:
                file.first_ns = log_time_ns
            file.last_ns = log_time_ns
            if topic == PERIOD_TOPIC:
                record = _period(message, path)
                file.periods.append((record, log_time_ns))
                file.anchors.append((log_time_ns, record.t))
            elif topic == CONFIG_TOPIC:
                file.configs.append(_config(message, path))
                file.config_times.append(log_time_ns)
            elif topic == TIMING_TOPIC and _is_number(message.get("t")):
                file.timings.append(message)
                file.anchors.append((log_time_ns, float(message["t"])))
            elif topic == PROGRAM_TOPIC and _is_number(message.get("t")):
                file.program.append(message)
                file.anchors.append((log_time_ns, float(message["t"])))
            elif topic == LOG_TOPIC:
                level = message.get("level")
                level = level if isinstance(level, int) else 0
                file.raw_events.append((log_time_ns, level, str(message.get("message"))))
    except ValueError as error:
        raise ReplayError(str(error)) from None
    file.run = log_file.metadata_read.get(METADATA_NAME, {}).get("run")
    file.report = FileReport(
        str(path),
        log_file.size,
        log_file.recovered,
        len(file.periods),
        log_file.finished,
        log_file.cut_at,
        log_file.cut_reason,
        [damage.describe() for damage in log_file.damaged],
    )
    return file


def _in_order(files: list[_FileRecords]) -> list[_FileRecords]:
    """The files by the log time of their first record, checked to be one day's.

    Files of one run (the recorder's run id) follow each other; runs that follow each other
    (a restart) are one day with a gap. Refused: files of different runs (or without a run
    id) that overlap in time, such as two simulated days logged into one folder, and files
    of one run that hold the same control periods (a copy).
    """
    order = sorted(files, key=lambda f: (f.first_ns is None, f.first_ns or 0))
    latest: _FileRecords | None = None  # the file read so far that ends last
    periods_seen: dict[tuple[str, int], Path] = {}
    for file in order:
        if file.first_ns is None or file.last_ns is None:
            continue
        for record, _ in file.periods:
            if file.run is None:
                continue
            other = periods_seen.setdefault((file.run, record.k), file.path)
            if other != file.path:
                raise ReplayError(
                    f"{file.path} and {other} hold the same control periods (k={record.k} "
                    "and more): one is a copy of the other; name each once"
                )
        overlaps = latest is not None and file.first_ns < (latest.last_ns or 0)
        if overlaps and latest is not None and (file.run is None or file.run != latest.run):
            raise ReplayError(
                f"{file.path} ({_span(file)}) overlaps {latest.path} ({_span(latest)}): "
                f"not one day's logs; replay each run on its own: {_listing(order)}"
            )
        if latest is None or (latest.last_ns or 0) < file.last_ns:
            latest = file
    return order


def _runs(files: list[_FileRecords]) -> list[dict[str, Any]]:
    """The runs of the daemon in `files`, in order: each with its id, files and start."""
    runs: list[dict[str, Any]] = []
    for file in files:
        if runs and file.run is not None and runs[-1]["run"] == file.run:
            runs[-1]["files"].append(str(file.path))
            continue
        start = None if file.first_ns is None else _utc(file.first_ns)
        runs.append({"run": file.run, "start_utc": start, "files": [str(file.path)]})
    return runs


def _listing(files: list[_FileRecords]) -> str:
    return "; ".join(
        f"run {run['run'] or '(no id)'} from {run['start_utc']}: {', '.join(run['files'])}"
        for run in _runs([f for f in files if f.first_ns is not None])
    )


def _span(file: _FileRecords) -> str:
    return f"{_utc(file.first_ns or 0)} to {_utc(file.last_ns or 0)}"


def _utc(log_time_ns: int) -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(log_time_ns // 1_000_000_000))


def _open(path: Path) -> LogFile:
    """The file as a LogFile, or ReplayError saying in one line why it cannot be one."""
    try:
        kind = not_regular(path)
        if kind == "a directory":
            raise ReplayError(f"{path}: is a directory (name the .mcap files in it)")
        if kind is not None:
            raise ReplayError(f"{path}: is {kind}, not a regular file (name the .mcap files)")
        with path.open("rb") as f:
            head = f.read(len(MCAP_MAGIC))
        file = LogFile(path)
    except FileNotFoundError:
        raise ReplayError(f"{path}: no such file") from None
    except OSError as error:
        raise ReplayError(f"{path}: cannot be read: {error.strerror or error}") from None
    if not head:
        raise ReplayError(f"{path}: the file is empty")
    if not MCAP_MAGIC.startswith(head):
        raise ReplayError(f"{path}: not an MCAP file (it does not start with the MCAP magic)")
    return file


def _period(message: dict[str, Any], path: Path) -> PeriodRecord:
    try:
        record = PeriodRecord(**message)
    except TypeError:
        try:  # another version's record: keep the fields this one knows
            record = PeriodRecord(**{k: message[k] for k in _PERIOD_FIELDS if k in message})
        except TypeError as error:
            raise ReplayError(f"{path}: a period record is incomplete: {error}") from None
    if not (
        _is_number(record.t)
        and _is_number(record.setpoint)
        and _is_number(record.output)
        and _is_number(record.applied)
        and (record.pv is None or _is_number(record.pv))
        and (record.reset_from is None or _is_number(record.reset_from))
        and (record.full_from is None or isinstance(record.full_from, int))
        and isinstance(record.k, int)
        and isinstance(record.alarms, list)
        and all(isinstance(kind, str) for kind in record.alarms)
    ):
        raise ReplayError(f"{path}: period record k={record.k!r} holds a value of the wrong type")
    return record


def _config(message: dict[str, Any], path: Path) -> LoggedConfig:
    t, config = message.get("t"), message.get("config")
    if not _is_number(t) or not isinstance(config, dict):
        raise ReplayError(f"{path}: a config record lacks its time or its configuration")
    model, safety_model = message.get("model"), message.get("safety_model")
    law = message.get("control_law")
    return LoggedConfig(
        float(t),
        str(message.get("reason", "")),
        config,
        model if isinstance(model, dict) else None,
        safety_model if isinstance(safety_model, dict) else None,
        law if isinstance(law, int) and not isinstance(law, bool) else None,
    )


def _program_event(message: dict[str, Any], at: float) -> ProgramEvent:
    def text(key: str) -> str | None:
        value = message.get(key)
        return value if isinstance(value, str) else None

    step, setpoint = message.get("step"), message.get("setpoint")
    return ProgramEvent(
        at,
        text("event") or "",
        text("program"),
        step if isinstance(step, int) and not isinstance(step, bool) else None,
        text("name"),
        float(setpoint) if _is_number(setpoint) else None,
        text("message"),
    )


def _is_number(value: object) -> TypeGuard[int | float]:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _lookup(config: dict[str, Any], section: str, key: str) -> float | None:
    value = config.get(section, {}).get(key) if isinstance(config.get(section), dict) else None
    return float(value) if _is_number(value) else None


def _t_at(anchors: list[tuple[int, float]], log_time_ns: int) -> float:
    """The daemon's t at a log time, from the nearest earlier record that carries t."""
    i = max(0, bisect.bisect_right(anchors, (log_time_ns, math.inf)) - 1)
    anchor_ns, anchor_t = anchors[i]
    return anchor_t + (log_time_ns - anchor_ns) / 1e9


class Drop(NamedTuple):
    """PV fell fast (cold water poured in): at `at` it was still `before`, then `after`."""

    at: float
    before: float
    after: float


def sudden_drops(times: Sequence[float], pvs: Sequence[float | None]) -> list[Drop]:
    """Falls of at least DROP_C within DROP_WINDOW_S, each at its last sample near the top."""
    drops: list[Drop] = []
    window: deque[tuple[float, float]] = deque()  # (t, pv), pv decreasing: window[0] is the max
    recent: deque[tuple[float, float]] = deque()  # every (t, pv) of the window
    falling_until = -math.inf
    for t, pv in zip(times, pvs, strict=True):
        if pv is None:
            continue
        if t <= falling_until and drops:
            drops[-1] = drops[-1]._replace(after=min(drops[-1].after, pv))
            continue
        while window and window[0][0] < t - DROP_WINDOW_S:
            window.popleft()
        while recent and recent[0][0] < t - DROP_WINDOW_S:
            recent.popleft()
        if window and window[0][1] - pv >= DROP_C:
            top = window[0][1]
            at = max(s for s, v in recent if v >= top - DROP_C / 4)
            drops.append(Drop(at, top, pv))
            falling_until = t + DROP_WINDOW_S
            window.clear()
            recent.clear()
            continue
        while window and window[-1][1] <= pv:
            window.pop()
        window.append((t, pv))
        recent.append((t, pv))
    return drops


def alarms(log: Log) -> list[dict[str, Any]]:
    """Alarms raised: from the log's events, and from the period records for any event lost."""
    found = []
    for event in log.events:
        match = RAISED_ALARM.fullmatch(event.message)
        if match and event.level >= LogLevel.WARNING:
            found.append((event.at, match["kind"], match["message"]))
    period_s = log.period_s()
    active: set[str] = set()
    previous_at = -math.inf
    for record, at in zip(log.periods, log.elapsed, strict=True):
        now = set(record.alarms)
        for kind in sorted(now - active):
            told = any(
                k == kind and previous_at - period_s <= a <= at + period_s for a, k, _ in found
            )
            if not told:
                found.append((at, kind, None))
        active, previous_at = now, at
    found.sort(key=lambda a: a[0])
    return [{"kind": kind, "at_s": round(at, 3), "message": text} for at, kind, text in found]
