"""Replay: read a brew day's MCAP logs back, measure them, re-run the controller, ask what if.

The files of one day (finished `.mcap` or cut `.mcap.part`) are read in the order of their
first record, whatever order they are named in; a file named twice, and files of different
runs of the daemon that overlap in time (two simulated days logged into one folder), are
refused, while runs that follow each other are one day with a restart. Within a file,
config and period records are put in the order of the daemon's monotonic time `t` (a config
before a period of the same `t`: the daemon records a reload before the period it takes
effect in). Times in the summary are seconds since the first period, on one clock across
files: when `t` starts again (a reboot between files) the wall-clock gap of the log times
joins the two.

- `summarise`: what `hermsd replay FILE...` prints. The metrics are those of `hermsd
  simulate` (hermsd.metrics), measured on the logged PV rather than the simulated water.
- `verify`: the logged controller re-run on the logged inputs, every step bit for bit, and
  what the daemon's watches logged of each period derived again from them.
- `what_if`: a first-order-plus-dead-time model of the tun fitted to the logged duty and PV,
  and the day run again through the daemon on that model with other settings.
"""

from __future__ import annotations

import bisect
import csv
import dataclasses
import itertools
import math
import time
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple, TypeGuard

from hermsd.commissioning.identify import IdentifyError, TunModel, fit_span, identify
from hermsd.config import schema as config_module
from hermsd.config.schema import make_controller, shared_out
from hermsd.control.element2 import MidRangeController, SplitController, TwoElementController
from hermsd.control.pid import (
    DROP_READINGS,
    DROP_RULE,
    FIRST_DROP_RULE,
    LAW_DROP_RULE,
    Controller,
    DropRule,
    PlantModel,
    cold_water_seen,
    full_power_now,
    logged_duty_share,
    logged_recovery_periods,
    predating_drop_fall,
)
from hermsd.control.reach import PREFIX as REACH_PREFIX
from hermsd.control.reach import ReachWatch
from hermsd.files import not_regular
from hermsd.log.recorder import (
    CONFIG_TOPIC,
    LOG_TOPIC,
    MCAP_MAGIC,
    METADATA_NAME,
    PART_SUFFIX,
    PERIOD_TOPIC,
    PROGRAM_TOPIC,
    TIMING_TOPIC,
    LogFile,
    LogLevel,
)
from hermsd.metrics import LOGGED_TEMPERATURE, Metrics, Sample, compute, report
from hermsd.program.quality import step_quality
from hermsd.program.readiness import SCHEDULE_EVENTS
from hermsd.runtime.daemon import (
    RAISED_ALARM,
    PeriodRecord,
    element2_watts,
    element_watch,
    keep_probe,
    reach_period,
    reach_restarts,
    retunes,
    watch_changes,
)
from hermsd.safety.element_watch import ElementWatch

if TYPE_CHECKING:
    from hermsd.sim.scenario import Event

TOPICS_READ = (PERIOD_TOPIC, CONFIG_TOPIC, LOG_TOPIC, TIMING_TOPIC, PROGRAM_TOPIC)

# A sudden drop: PV falls this much within this time. Heat loss alone cools a hot tun by
# (T − T_amb)/τ ≈ 0.2 °C a minute at most; cold water poured in drops it by degrees at once.
DROP_C = 1.0
DROP_WINDOW_S = 60.0

WHAT_IF_KEYS = config_module.TUNING_KEYS  # what a new tune may change

_PERIOD_FIELDS = tuple(f.name for f in dataclasses.fields(PeriodRecord))


class ReplayError(ValueError):
    """Logs that cannot be replayed as asked; the message is one line that says why."""


# -- reading ------------------------------------------------------------------------------------


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
    drop_readings: int | None = None  # the rule of `full_from` (None: not acted on in periods)
    drop_onset_c: float | None = None  # and its onset (None: the first rule, if drop_readings)
    drop_fall_c: float | None = None  # and its fall (None: the rule of the law's answer alone)
    drop_carry: bool = False  # full power on cold water carried across the period's end
    reach_watch: bool = False  # each period's `ceiling` is the reach watch's (None: not said)
    repeat: bool = False  # the copy of the record in force that opens a rotated file of a run
    steady_duty_share: float | None = None  # a measured step needs a steady duty (None: not)
    recovery_fit_periods: int | None = None  # the fewest periods of a recovery's fit (None: 0)


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
    drop_readings, drop_onset = message.get("drop_readings"), message.get("drop_onset_c")
    drop_fall, steady_duty = message.get("drop_fall_c"), message.get("steady_duty_share")
    recovery = message.get("recovery_fit_periods")
    return LoggedConfig(
        float(t),
        str(message.get("reason", "")),
        config,
        model if isinstance(model, dict) else None,
        safety_model if isinstance(safety_model, dict) else None,
        drop_readings if isinstance(drop_readings, int) else None,
        float(drop_onset) if _is_number(drop_onset) else None,
        float(drop_fall) if _is_number(drop_fall) else None,
        message.get("drop_carry") is True,
        message.get("reach_watch") is True,
        steady_duty_share=float(steady_duty) if _is_number(steady_duty) else None,
        recovery_fit_periods=recovery if isinstance(recovery, int) else None,
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


# -- the summary --------------------------------------------------------------------------------


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


def _report(metrics: Metrics) -> dict[str, Any]:
    """hermsd.metrics' report without the SSR's edges, which period records do not hold."""
    reported = report(metrics)
    del reported["ssr_edges_per_hour"]
    return reported


def disturbances(log: Log, drops: list[Drop]) -> list[float]:
    """When the tun was upset from outside: setpoint or mode changed, cold water poured in."""
    times = [drop.at for drop in drops]
    for (a, _), (b, t) in itertools.pairwise(zip(log.periods, log.elapsed, strict=True)):
        if b.setpoint != a.setpoint or b.mode != a.mode:
            times.append(t)
    return sorted(times)


def measure(
    periods: Sequence[PeriodRecord],
    elapsed: Sequence[float],
    upsets: list[float],
    period_s: float,
) -> Metrics:
    """hermsd.metrics on the PV of period records (periods without a PV are left out)."""
    samples = [
        Sample(t, r.setpoint, r.pv, r.output)
        for r, t in zip(periods, elapsed, strict=True)
        if r.pv is not None
    ]
    end = elapsed[-1] + period_s if elapsed else 0.0
    return compute(samples, upsets, end)


def delivered(log: Log) -> tuple[float | None, float | None]:
    """(mean applied duty %, energy kWh) over the periods recovered.

    A period's `applied` is the duty of the span since the period before it, so it is
    weighed by that span; after missing records, by one control period. The element's
    watts come from the config in force; without one the energy is unknown (None). A second
    element's energy (its duty as switched, `switched2`) is added; the mean duty is the
    SSR's.
    """
    watts: float | None = None
    watts2 = 0.0
    watts_known = True
    duty_s = span_s = joules = 0.0
    period_s = log.period_s()
    previous: PeriodRecord | None = None
    for entry in log.entries:
        if isinstance(entry, LoggedConfig):
            watts = _lookup(entry.config, "tun", "element_watts")
            watts2 = _lookup(entry.config, "element2", "watts") or 0.0
            continue
        if previous is not None and entry.k == previous.k + 1 and entry.t >= previous.t:
            span = entry.t - previous.t
        else:
            span = period_s if entry.k > 1 else 0.0  # the first period of a run follows nothing
        previous = entry
        duty_s += entry.applied * span
        span_s += span
        if watts is None:
            watts_known = False
        else:
            joules += watts * entry.applied / 100.0 * span
            if _is_number(entry.switched2):
                joules += watts2 * entry.switched2 / 100.0 * span
    if span_s == 0:
        return None, None
    return duty_s / span_s, joules / 3.6e6 if watts_known else None


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


def timing(log: Log) -> dict[str, Any]:
    """How well the loop kept time: the worst of the timing records, and what was lost."""
    records = log.timings

    def worst(key: str) -> float | None:
        values = [r[key] for r in records if _is_number(r.get(key))]
        return round(max(values) * 1000.0, 3) if values else None

    return {
        "records": len(records),
        "period_lateness_p99_ms": worst("period_lateness_p99"),
        "period_lateness_max_ms": worst("period_lateness_max"),
        "edge_error_p99_ms": worst("edge_error_p99"),
        "edge_error_max_ms": worst("edge_error_max"),
        "overruns": _total(r.get("overruns") for r in records),
        "dropped": _total(r.get("dropped") for r in records),
    }


def _total(counts: Iterable[object]) -> int:
    """The sum of counters that each run of the daemon starts again from zero."""
    total = previous = 0
    for count in counts:
        if not isinstance(count, int):
            continue
        total += count - previous if count >= previous else count
        previous = count
    return total


def summarise(log: Log) -> dict[str, Any]:
    """What `hermsd replay` prints: what was recovered, how the day went, what it cost."""
    period_s = log.period_s()
    drops = sudden_drops(log.elapsed, [p.pv for p in log.periods])
    metrics = measure(log.periods, log.elapsed, disturbances(log, drops), period_s)
    mean_applied, energy = delivered(log)
    algorithms = list(dict.fromkeys(p.algorithm for p in log.periods))
    return {
        "files": [dataclasses.asdict(f) for f in log.files],
        "runs": log.runs,  # more than one: the daemon restarted during the day
        "start_utc": time.strftime(
            "%Y-%m-%dT%H:%M:%SZ", time.gmtime(log.log_time_ns[0] // 1_000_000_000)
        ),
        "periods": len(log.periods),
        "duration_s": round(log.elapsed[-1], 3),
        "algorithm": ", ".join(algorithms),
        "cold_water_at_s": [round(d.at, 1) for d in drops],
        "temperature": LOGGED_TEMPERATURE,
        **_report(metrics),
        "mean_applied_pct": None if mean_applied is None else round(mean_applied, 2),
        "energy_kwh": None if energy is None else round(energy, 3),
        "alarms": alarms(log),
        "timing": timing(log),
        "tun_model": next((c.model for c in reversed(log.configs) if c.model), None),
        # None: the safety limits held for any tun the config may describe (nothing measured)
        "safety_tun_model": log.configs[-1].safety_model if log.configs else None,
        "learning": learning(log),
        # When full power could not reach the setpoint, and when that cleared
        # (hermsd.control.reach).
        "reach": [
            {"at_s": round(e.at, 3), "message": e.message}
            for e in log.events
            if e.message.startswith(REACH_PREFIX)
        ],
        "steps": step_quality(zip(log.elapsed, log.periods, strict=True)),
        # What a ready_by schedule decided (the climb, the release, a late warning), and why.
        "schedule": [
            {"at_s": round(e.at, 3), "event": e.event, "message": e.message}
            for e in log.program
            if e.event in SCHEDULE_EVENTS
        ],
    }


LEARNING_EVENTS = ("heat-up measure", "learned ")
"""How the daemon's events about measuring and learning the tun begin."""


def learning(log: Log) -> list[dict[str, Any]]:
    """What the controller measured and the daemon learned (or refused), in order."""
    return [
        {"at_s": round(e.at, 3), "message": e.message}
        for e in log.events
        if e.message.startswith(LEARNING_EVENTS)
    ]


# -- verify -------------------------------------------------------------------------------------


def logged_model(entry: LoggedConfig) -> PlantModel | None:
    """The tun's model a config record says was in force (None in older logs: the keys')."""
    if entry.model is None:
        return None
    try:
        return PlantModel(
            **{k: float(entry.model[k]) for k in ("gain", "tau", "dead_time", "ambient")}
        )
    except (KeyError, TypeError, ValueError) as error:
        raise ValueError(f"the model logged with it is not one: {error}") from None


@dataclass(frozen=True, slots=True)
class Mismatch:
    """The first value the re-run controller did not reproduce."""

    k: int
    t: float
    name: str
    logged: float | None
    recomputed: float | None


@dataclass(frozen=True, slots=True)
class Verification:
    """What `verify` found: how many steps it reproduced, and the first it did not."""

    verified: int  # controller steps reproduced bit for bit
    unknown_state: int  # steps after missing records and before the next reset: not re-run
    mismatch: Mismatch | None


def verify(entries: Iterable[LoggedConfig | PeriodRecord]) -> Verification:
    """Re-run the logged controller on the logged inputs, by the daemon's rules.

    A config record makes a new controller (the repeat of the one in force that opens every
    rotated file, as `load` marks it, does not, nor does a reload that leaves the tuning, the
    tun and the model as they were: the daemon keeps its controller then). The controller
    steps in auto mode when heating is allowed and there is a PV, after `reset(pv,
    reset_from)` if `reset_from` is set; its output and its p, i, d terms must equal the
    logged ones exactly (midrange: u2 too, the second element's logged applied2 handed in
    first, as the daemon does; two elements under any other controller: u2 too, its logged
    applied2, on2 and free2 handed in first). The daemon resets the controller on its first
    step and after every hold, reload or return to auto, so where records are missing the
    check resumes at the next reset.

    A period's `full_from` (the reading after which the controller asked for full power at
    once) must be what `pid.full_power_now` gives on its readings, with the controller as the
    step of the record before it left it; None where no step came before it. It is checked
    by the rule the config record in force names (`drop_readings`, `drop_onset_c` since
    the onset was lowered, `drop_fall_c` since a fall the element cannot undo in a period
    is acted on whatever the law says; without the onset, `pid.FIRST_DROP_RULE`, without
    the fall `pid.LAW_DROP_RULE`): an older daemon never acted inside a period and logged
    no such thing.

    A period's `ceiling` must be what a reach watch names that was fed every period as the
    daemon fed its own (`daemon.reach_period`: the record, the model and the config in
    force, and the dead time of the controller's heat-up measurement, re-run here), made
    afresh at each start and measuring afresh where a reload changed full power
    (`daemon.reach_restarts`). Only under a config record that says the daemon logs it
    (`reach_watch`; an older log is checked as before); after missing records, not until
    the next start (the blocks it measured over them are not known).

    The predictive controller takes a step to full power for a measurement of the tun only
    from a duty that was steady before it, by the share a config record names
    (`steady_duty_share`); under one without it, from any duty, as the daemons before it did.
    It fits a recovery's rate over at least the periods a config record names
    (`recovery_fit_periods`); under one without it, over the first span alone, as the daemons
    before it did.
    """
    controller = None
    in_force: LoggedConfig | None = None
    in_force_model: dict[str, Any] | None = None
    control: config_module.ControlConfig | None = None
    known = False  # whether the controller's state is that of the daemon's
    previous_k: int | None = None
    stepped: tuple[Controller, PeriodRecord] | None = None  # the last step, if fresh and known
    drop_rule: DropRule | None = None  # how the daemon that logged these periods acted on drops
    watch: ElementWatch | None = None  # the element watch as the daemon's, once known
    watched: config_module.Config | None = None  # the config it was made for
    reach: ReachWatch | None = None  # the reach watch as the daemon's, once known
    model: PlantModel | None = None  # the tun's model in force, as logged
    fed: PeriodRecord | None = None  # the last period, not yet fed to `reach`
    verified = unknown = 0

    def ceiling_mismatch() -> Mismatch | None:
        """The last period fed to the reach watch after its step, as the daemon fed it: by
        the next entry the controller's heat-up fit is the one the daemon's had then."""
        if fed is None or reach is None or controller is None or watched is None or model is None:
            return None
        return _ceiling_mismatch(reach, fed, model, watched, controller)

    for entry in entries:
        mismatch = ceiling_mismatch()
        if mismatch is not None:
            return Verification(verified, unknown, mismatch)
        fed = None
        if isinstance(entry, LoggedConfig):
            if entry.repeat:
                continue
            in_force = entry
            drop_rule = _drop_rule(entry)
            try:
                whole = _as_logged(config_module.from_dict(entry.config), entry.config)
                if entry.reason == "start" or (watched and watch_changes(watched, whole)):
                    kept, watch = watch, element_watch(whole) if element2_watts(whole) else None
                    same = watched is not None and watched.tun == whole.tun
                    if entry.reason != "start" and same and kept and watch:
                        watch.keep_probed(kept)
                if entry.reason == "start":
                    reach = ReachWatch() if entry.reach_watch else None
                elif reach is not None and watched is not None and reach_restarts(watched, whole):
                    reach.restart()
                same_tun = watched is not None and watched.tun == whole.tun
                before, watched = watched, whole
                reloaded = whole.control
                same_model = in_force_model == entry.model
                if (
                    entry.reason == "reload"
                    and control
                    and not retunes(control, reloaded)
                    and same_model
                    and same_tun  # the daemon makes a new controller for a new tun
                ):
                    control = reloaded  # a new setpoint or mode: the same controller goes on
                    continue
                control = reloaded
                in_force_model = entry.model
                model = logged_model(entry)
                made = make_controller(control, model)
                if entry.drop_fall_c is None:  # a daemon from before it judged steady so
                    predating_drop_fall(made)
                logged_duty_share(made, entry.steady_duty_share)
                logged_recovery_periods(made, entry.recovery_fit_periods)
                unknown_probe = controller is None and same_tun  # what it would keep is not known
                previous, controller = controller, shared_out(whole, made)
                if entry.reason == "reload" and before is not None:
                    keep_probe(before, whole, previous, controller)
                    if unknown_probe and isinstance(controller, SplitController):
                        controller = None if controller.probe is not None else controller
            except (config_module.ConfigError, ValueError) as error:
                detail = str(error).replace("\n", "; ")
                raise ReplayError(f"the config logged at t {entry.t!r} s: {detail}") from None
            known = False
            if entry.reason == "start":
                previous_k, stepped = None, None
            continue
        record = entry
        if record.k != (previous_k or 0) + 1:
            reach = None  # what the missing periods told it is not known
        fed = record
        if previous_k is not None and record.k != previous_k + 1:
            known = False
            stepped = None
            watch = None  # what the missing periods told it is not known
            probe = controller.probe if isinstance(controller, SplitController) else None
            if probe is not None and not probe.done:
                # The daemon's heat-up check may have run in them: its state is not known
                # until a new controller, so nothing after is held against this one.
                controller = None
        # The probe's finding of the step before, taken as the daemon takes it.
        probed = controller.probe_result() if isinstance(controller, SplitController) else None
        if watch is not None and record.switched2 is not None:
            if probed is not None and probed.element is not None:
                watch.blame(record.t, probed.element, probed.message)
            watch.period(
                record.t,
                record.pv,
                record.setpoint,
                record.applied,
                record.switched2,
                record.state == "ok",
            )
            if record.no_heat is not None and sorted(watch.suspect) != record.no_heat:
                name = f"no_heat {record.no_heat} (derived {sorted(watch.suspect)})"
                return Verification(
                    verified, unknown, Mismatch(record.k, record.t, name, None, None)
                )
        if drop_rule is not None and (stepped is not None or known):
            full_from = _full_from(stepped, record.readings, drop_rule)
            if record.full_from != full_from:
                mismatch = Mismatch(record.k, record.t, "full_from", record.full_from, full_from)
                return Verification(verified, unknown, mismatch)
        stepped = None
        previous_k = record.k
        if not (record.mode == "auto" and record.heater_allowed and record.pv is not None):
            continue
        if record.state == "scheduled":  # a program waits for its time: the heater held off
            continue
        if controller is None:
            unknown += 1
            continue
        if isinstance(controller, MidRangeController):
            if not (_is_number(record.applied2) and _is_number(record.u2)):
                raise ReplayError(f"period k={record.k}: a midrange period without u2, applied2")
            controller.applied2 = record.applied2  # what the daemon handed in, as logged
        if isinstance(controller, SplitController):
            if not (
                _is_number(record.applied2)
                and isinstance(record.on2, bool)
                and isinstance(record.free2, bool)
            ):
                raise ReplayError(f"period k={record.k}: a two-element period without its state")
            controller.applied2 = record.applied2
            controller.on2, controller.free2 = record.on2, record.free2
        try:
            if record.reset_from is not None:
                controller.reset(record.pv, record.reset_from)
                known = True
            if not known:
                unknown += 1
                continue
            if record.full_from is not None and in_force is not None and in_force.drop_carry:
                cold_water_seen(controller)
            output = controller.step(record.setpoint, record.pv, record.applied)
        except ValueError as error:
            raise ReplayError(f"period k={record.k}: the controller refused it: {error}") from None
        p, i, d = controller.terms
        compared = [
            ("output", record.output, output),
            ("p", record.p, p),
            ("i", record.i, i),
            ("d", record.d, d),
        ]
        if isinstance(controller, TwoElementController) and record.u2 is not None:
            compared.append(("u2", record.u2, controller.u2))
        for name, logged, recomputed in compared:
            if logged != recomputed:
                return Verification(
                    verified, unknown, Mismatch(record.k, record.t, name, logged, recomputed)
                )
        stepped = (controller, record)
        verified += 1
    return Verification(verified, unknown, ceiling_mismatch())


def _ceiling_mismatch(
    reach: ReachWatch,
    record: PeriodRecord,
    model: PlantModel,
    config: config_module.Config,
    controller: Controller,
) -> Mismatch | None:
    """Feed `reach` the period of `record` as the daemon did; a Mismatch when the ceiling it
    names then is not the logged one."""
    reach_period(reach, record, model, config, controller)
    if record.ceiling == reach.ceiling:
        return None
    return Mismatch(record.k, record.t, "ceiling", record.ceiling, reach.ceiling)


def _as_logged(config: config_module.Config, logged: dict[str, Any]) -> config_module.Config:
    """The config as the daemon that logged it ran it: a daemon from before the heat-up's
    check of two elements (a record without `element2.check`) never made it."""
    if "check" in logged.get("element2", {}):
        return config
    return dataclasses.replace(config, element2=dataclasses.replace(config.element2, check=False))


def _drop_rule(entry: LoggedConfig) -> DropRule | None:
    """The rule by which the daemon that wrote `entry` acted on drops inside a period (None:
    it did not, or by a rule this version does not know, so `full_from` is not checked)."""
    if entry.drop_readings != DROP_READINGS:
        return None
    if entry.drop_onset_c is None:
        return FIRST_DROP_RULE
    if entry.drop_fall_c is None:
        return LAW_DROP_RULE if entry.drop_onset_c == LAW_DROP_RULE.onset else None
    same = (entry.drop_onset_c, entry.drop_fall_c) == (DROP_RULE.onset, DROP_RULE.fall)
    return DROP_RULE if same else None


def _full_from(
    stepped: tuple[Controller, PeriodRecord] | None, readings: list[float], rule: DropRule
) -> int | None:
    """After how many of a period's `readings` the daemon asks for full power (see
    `Daemon._act_on_drop`), given the controller and the record of the step before them,
    by `rule`."""
    if stepped is None:
        return None
    controller, before = stepped
    if before.pv is None:
        return None
    for n in range(1, len(readings) + 1):
        if full_power_now(controller, before.setpoint, before.pv, readings[:n], rule):
            return n
    return None


# -- what if ------------------------------------------------------------------------------------


WHAT_IF_LOGGED = "logged"  # --what-if logged: the day again with the settings it had


def parse_what_if(text: str) -> dict[str, Any]:
    """`kc=100,ti=900,algorithm=type_a` as control settings (checked later, like the file).

    A log file's name in their place (`--what-if day.mcap`) is said as such.
    """
    if text.strip() == WHAT_IF_LOGGED:
        return {}
    if "=" not in text and (text.endswith((".mcap", PART_SUFFIX)) or Path(text).exists()):
        raise ReplayError(
            f"--what-if takes settings, not the log file {text!r}: write --what-if "
            f"kc=80,ti=600 (or --what-if {WHAT_IF_LOGGED} for the logged ones) after the files"
        )
    settings: dict[str, Any] = {}
    for item in filter(None, (part.strip() for part in text.split(","))):
        key, sep, value = (s.strip() for s in item.partition("="))
        if not sep or key not in WHAT_IF_KEYS:
            raise ReplayError(
                f"--what-if: {item!r} is not key=value with a key of {', '.join(WHAT_IF_KEYS)} "
                "(name the files before --what-if)"
            )
        settings[key] = _scalar(value)
    return settings


def _scalar(text: str) -> Any:
    if text.lower() in ("null", "none", ""):
        return None
    try:
        return float(text)
    except ValueError:
        return text


@dataclass(frozen=True, slots=True)
class WhatIf:
    """The fitted tun, and the day as logged beside the day with the new settings."""

    model: TunModel
    settings: dict[str, dict[str, Any]]  # "logged" and "what_if": the control settings
    logged: dict[str, Any]  # metrics of the log
    what_if: dict[str, Any]  # metrics of the run with the new settings


def what_if(log: Log, overrides: dict[str, Any]) -> WhatIf:
    """The day again on the fitted tun, with `overrides` of the logged control settings.

    The fit uses the log up to the first sudden drop (cold water: a disturbance the model
    has no input for) or the first gap. The run starts from the fitted initial temperature
    with the config logged first, and repeats the log's setpoint and mode changes; each
    drop is poured in again as water at the fitted ambient temperature, in the amount that
    gives the drop logged. Faults are not repeated.
    """
    from hermsd.sim.scenario import Scenario, ScenarioError, effective_config
    from hermsd.sim.scenario import run as run_scenario  # the simulator only when asked for

    configs = log.configs
    if not configs:
        raise ReplayError("--what-if: no config record recovered, so no settings to start from")
    try:
        base = config_module.from_dict(configs[0].config)
    except config_module.ConfigError as error:
        detail = str(error).replace("\n", "; ")
        raise ReplayError(f"the config logged at t {configs[0].t!r} s: {detail}") from None
    scenario = Scenario(
        name="what-if", setpoint=log.periods[0].setpoint, config={"control": overrides}
    )
    try:  # the settings are checked before the fit and the run
        settings = effective_config(base, scenario).control
    except ScenarioError as error:
        raise ReplayError(f"--what-if: {error}".replace("\n", "; ")) from None
    period_s = base.control.period
    pvs = [p.pv for p in log.periods]
    drops = sudden_drops(log.elapsed, pvs)
    upsets = disturbances(log, drops)
    n = fit_span(log, drops, period_s)
    try:
        model = identify(pvs[:n], [p.applied for p in log.periods[:n]], period_s)
    except IdentifyError as error:
        raise ReplayError(str(error)) from None
    plant = {
        "model": "foptd",
        "gain_c_per_pct": model.gain,
        "tau_s": model.tau,
        "dead_time_s": model.dead_time,
        "ambient_c": model.ambient,
        "start_c": model.start,
        "litres": base.tun.litres,
        "element_watts": base.tun.element_watts,
    }
    scenario = dataclasses.replace(
        scenario,
        duration=log.elapsed[-1] + period_s,
        plant=plant,
        events=tuple(_replayed_events(log, base, model, drops)),
    )
    try:
        runs = run_scenario(scenario, base, keep_records=True).records
    except ScenarioError as error:
        raise ReplayError(f"--what-if: {error}".replace("\n", "; ")) from None
    return WhatIf(
        model=model,
        settings={
            "logged": {key: getattr(base.control, key) for key in WHAT_IF_KEYS},
            "what_if": {key: getattr(settings, key) for key in WHAT_IF_KEYS},
        },
        logged=_report(measure(log.periods, log.elapsed, upsets, period_s)),
        what_if=_report(measure(runs, [r.t for r in runs], upsets, period_s)),
    )


def _replayed_events(
    log: Log, base: config_module.Config, model: TunModel, drops: list[Drop]
) -> list[Event]:
    """The scenario events that repeat the log's operator actions and its cold water."""
    from hermsd.sim.scenario import Event

    period_s = base.control.period
    events: list[Event] = []
    setpoint = log.periods[0].setpoint
    mode, manual = base.control.mode, base.control.manual_output
    for record, t in zip(log.periods, log.elapsed, strict=True):
        at = max(0.0, t - period_s / 2)  # between periods: applied at this one
        if record.setpoint != setpoint:
            setpoint = record.setpoint
            events.append(Event(at, "setpoint", setpoint))
        manual_now = record.state == "manual"  # in manual mode and heating: output is the user's
        if manual_now and (mode != "manual" or record.output != manual):
            mode, manual = "manual", record.output
            events.append(Event(at, "output", manual))
        elif record.mode == "auto" and mode != "auto":
            mode = "auto"
            events.append(Event(at, "mode", "auto"))
    litres = base.tun.litres
    for drop in drops:
        if drop.after - model.ambient <= 0.1 or not 0.0 <= model.ambient <= 100.0:
            continue  # the drop cannot be water at the ambient temperature
        added = litres * (drop.before - drop.after) / (drop.after - model.ambient)
        events.append(Event(drop.at, "add_water", {"litres": added, "temp": model.ambient}))
        litres += added
    events.sort(key=lambda e: e.at)
    return events


# -- CSV and plot -------------------------------------------------------------------------------


def write_csv(log: Log, path: Path) -> None:
    """One row per period with every field of its record; lists joined by spaces."""
    with path.open("w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f)
        writer.writerow(_PERIOD_FIELDS)
        for record in log.periods:
            writer.writerow(_cell(getattr(record, name)) for name in _PERIOD_FIELDS)


def _cell(value: object) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, list):
        return " ".join(map(str, value))
    return repr(value) if isinstance(value, float) else str(value)


def plot(log: Log, path: Path) -> None:
    """The day drawn for a brewer to read at a glance (hermsd.log.dayplot; needs matplotlib)."""
    from hermsd.log import dayplot

    dayplot.save(log, path)
