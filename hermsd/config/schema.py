"""The daemon's configuration: one YAML file read into frozen, validated dataclasses.

Brewers edit this file on brew day, so reading it is strict and its complaints are meant for
people: every problem at once, each with file, line and column, what is wrong and what would
be right, never a traceback. A Config that comes out of `parse` or `load` is within every
bound and consistent across sections, so the rest of the daemon never checks it again.

Plain (unquoted) scalars are read by a small grammar of this module rather than by YAML 1.1's
resolver, whose surprises would land on brew day: `066` is octal 54 there and `1:30` is 90.
Here a number is decimal (or hexadecimal with 0x), a leading zero or a colon is refused with
a hint, and anything quoted is text.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import os
import re
import typing
from dataclasses import dataclass, field
from typing import Any, NamedTuple, TypeVar

import yaml

from hermsd.control import midrange, pid
from hermsd.control.element2 import MidRangeController, PowerSplit, SplitController, total_share
from hermsd.control.learning import LearnedModel, implausible
from hermsd.control.pid import ALGORITHMS, DEFAULT_ALGORITHM
from hermsd.control.reach import FullPower
from hermsd.files import NotRegularFile, read_regular
from hermsd.safety.element_probe import ElementProbe

MIDRANGE = "midrange"
ALGORITHM_NAMES: tuple[str, ...] = (*ALGORITHMS, MIDRANGE)

_SPEC = "hermsd.config.spec"
_T = TypeVar("_T")


@dataclass(frozen=True, slots=True)
class _Spec:
    """What values a key accepts beyond its type (read by the validator, shown in messages)."""

    unit: str = ""
    low: float | None = None
    high: float | None = None
    low_exclusive: bool = False
    zero_means: str | None = None  # 0 is accepted below `low` and means this
    null_means: str | None = None
    choices: tuple[object, ...] = ()
    max_length: int | None = None
    as_hex: bool = False  # show the bounds in hexadecimal
    left_out: str | None = None  # what leaving the key out means; None: its default, "": refused


def _number(
    default: _T,
    low: float,
    high: float,
    unit: str = "",
    *,
    low_exclusive: bool = False,
    zero_means: str | None = None,
    null_means: str | None = None,
) -> _T:
    spec = _Spec(
        unit=unit,
        low=low,
        high=high,
        low_exclusive=low_exclusive,
        zero_means=zero_means,
        null_means=null_means,
    )
    return field(default=default, metadata={_SPEC: spec})


def _integer(
    default: _T,
    low: int,
    high: int | None = None,
    *,
    as_hex: bool = False,
    null_means: str | None = None,
) -> _T:
    spec = _Spec(low=low, high=high, as_hex=as_hex, null_means=null_means)
    return field(default=default, metadata={_SPEC: spec})


def _choice(default: _T, choices: tuple[object, ...]) -> _T:
    return field(default=default, metadata={_SPEC: _Spec(choices=choices)})


def _text(default: _T, *, max_length: int | None = None, null_means: str | None = None) -> _T:
    spec = _Spec(max_length=max_length, null_means=null_means)
    return field(default=default, metadata={_SPEC: spec})


def _words(default: _T, *, choices: tuple[object, ...] = (), null_means: str | None = None) -> _T:
    """A list of text items (an argv, a set of names): each item checked as a text key is."""
    return field(default=default, metadata={_SPEC: _Spec(choices=choices, null_means=null_means)})


_SERIAL_LINES = ("serial-rts", "serial-dtr")
_BUILT_IN = "the built-in default"


@dataclass(frozen=True, slots=True)
class TunConfig:
    """The vessel and its heater: the plant the loop and the heater watches reason about."""

    name: str = _text("HLT", max_length=32)
    litres: float = _number(90.0, 1, 1000, "L")
    element_watts: float = _number(3000.0, 100, 20000, "W")
    lid: str = _choice("on", ("on", "off"))


@dataclass(frozen=True, slots=True)
class ControlConfig:
    """The setpoint and the PID controller that holds it."""

    setpoint: float = _number(66.0, 0, 100, "°C")
    mode: str = _choice("auto", ("auto", "manual"))
    manual_output: float = _number(0.0, 0, 100, "%")
    algorithm: str = _choice(DEFAULT_ALGORITHM, ALGORITHM_NAMES)
    kc: float = _number(120.0, 0, 10000, "%/°C", low_exclusive=True)
    ti: float = _number(800.0, 1, 100000, "s", zero_means="no integral action")
    td: float = _number(0.0, 0, 10000, "s")
    tf: float | None = _number(None, 0, 10000, "s", null_means="the algorithm's default")
    tt: float | None = _number(None, 1, 100000, "s", null_means="the algorithm's default")
    period: float = _number(5.0, 1, 60, "s")
    max_output: float = _number(100.0, 1, 100, "%")
    model_gain: float = _number(1.689, 0.01, 100, "°C/%")
    model_tau: float = _number(14961.0, 10, 1000000, "s")
    dead_time: float = _number(115.0, 0, pid.MAX_DEAD_TIME, "s")
    model_ambient: float = _number(20.0, -20, 50, "°C")
    model_litres: float | None = _number(
        None, 1, 1000, "L", null_means="not measured: predictive's prior from tun.litres"
    )
    learn: str = _choice("on", ("on", "pinned", "off"))
    # algorithm midrange: C1 drives the SSR's element (u1), C2 the second element (u2).
    k1: float = _number(120.0, 0, 10000, "%/°C", low_exclusive=True)
    ti1: float = _number(800.0, 1, 100000, "s")
    tt1: float | None = _number(100.0, 1, 100000, "s", null_means="ti1")
    k2: float = _number(2.0, 0, 100, "%/%", low_exclusive=True)
    ti2: float = _number(600.0, 1, 100000, "s")
    tt2: float | None = _number(None, 1, 100000, "s", null_means="ti2")
    ks: float = _number(10.0, 0, 1000)
    u1_ref: float = _number(70.0, 1, 99, "%")
    u2_min: float = _number(0.0, 0, 100, "%")
    u2_max: float = _number(100.0, 0, 100, "%", low_exclusive=True)


@dataclass(frozen=True, slots=True)
class SensorConfig:
    """Where the LM92 sits and how often it is read."""

    bus: int = _integer(1, 0, 255)
    address: int = _integer(0x48, 0x48, 0x4B, as_hex=True)
    read_interval: float = _number(1.0, 0.5, 10, "s")


@dataclass(frozen=True, slots=True)
class OutputConfig:
    """The solid-state relay that time-proportions the element."""

    backend: str = _choice("serial-rts", ("sim", *_SERIAL_LINES, "gpio"))
    port: str = _text("/dev/ttyUSB0")
    chip: str = _text("/dev/gpiochip0")
    line: int | None = _integer(None, 0, 511, null_means="none (only the gpio backend uses it)")
    active_low: bool = False
    # A 1 s minimum is far above the five mains half-cycles (50 ms at 50 Hz) a zero-cross
    # SSR needs to resolve a duty, so that rule holds by these bounds alone.
    window: float | None = _number(None, 1, 60, "s", null_means="the control period")
    mains_hz: int = _choice(50, (50, 60))
    min_on: float = _number(0.02, 0, 10, "s")
    min_off: float = _number(0.02, 0, 10, "s")


@dataclass(frozen=True, slots=True)
class ContactorConfig:
    """The series contactor software opens when the SSR may have failed shorted."""

    backend: str = _choice("none", ("none", "gpio", *_SERIAL_LINES, "relay-board"))
    port: str = _text("/dev/ttyUSB1")
    chip: str = _text("/dev/gpiochip0")
    line: int | None = _integer(None, 0, 511, null_means="none (only the gpio backend uses it)")
    active_low: bool = False
    channel: int = _integer(1, 1, 8)
    baud: int = _choice(9600, (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200))


@dataclass(frozen=True, slots=True)
class Element2Config:
    """A second element on its own relay, contactor or SSR: slow, switched whole periods on or
    off no faster than its minimum on and off times allow (hermsd/control/element2.py)."""

    backend: str = _choice("none", ("none", "sim", "gpio", *_SERIAL_LINES, "relay-board"))
    port: str = _text("/dev/ttyUSB2")
    chip: str = _text("/dev/gpiochip0")
    line: int | None = _integer(None, 0, 511, null_means="none (only the gpio backend uses it)")
    active_low: bool = False
    channel: int = _integer(2, 1, 8)
    baud: int = _choice(9600, (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200))
    watts: float = _number(3500.0, 100, 20000, "W")
    # A contactor is rated for about 100k operations: 2 min on and off is at most 30 a hour.
    min_on: float = _number(120.0, 5, 3600, "s")
    min_off: float = _number(120.0, 5, 3600, "s")
    # Off for 60 s in the first heat-up: which element heats (hermsd/safety/element_probe.py).
    check: bool = True


@dataclass(frozen=True, slots=True)
class SafetyConfig:
    """Limits and watches that force the heater off, independent of the controller."""

    max_temp: float = _number(95.0, 30, 105, "°C")
    hysteresis: float = _number(5.0, 0.5, 30, "°C")
    plausible_min: float = _number(-10.0, -55, 150, "°C")
    plausible_max: float = _number(110.0, -55, 150, "°C")
    max_step: float | None = _number(None, 0, 50, "°C", low_exclusive=True, null_means=_BUILT_IN)
    fault_reads: int = _integer(2, 1, 10)
    resume_reads: int = _integer(5, 1, 100)
    stale_after: float | None = _number(None, 1, 60, "s", null_means="3 read intervals")
    dead_time: float | None = _number(
        None, 10, 3600, "s", null_means="300 s, or the tun's measured dead time"
    )
    heater_watch: float | None = _number(None, 30, 7200, "s", null_means=_BUILT_IN)
    heater_min_rise: float | None = _number(
        None, 0, 50, "°C", low_exclusive=True, null_means="a value derived from the tun"
    )
    ssr_watch: float | None = _number(None, 30, 7200, "s", null_means=_BUILT_IN)
    ssr_max_rise: float | None = _number(
        None, 0, 50, "°C", low_exclusive=True, null_means=_BUILT_IN
    )
    dry_fire_factor: float = _number(3.0, 1.5, 100)
    stuck_time: float = _number(600.0, 60, 86400, "s")
    stuck_output_change: float = _number(40.0, 1, 100, "%")
    stall_periods: float = _number(2.0, 0.5, 100)
    reset: int = _integer(0, 0)


@dataclass(frozen=True, slots=True)
class LogConfig:
    """Where the MCAP log goes and how much of it a crash may cost."""

    dir: str | None = _text("/var/log/hermsd", null_means="no log")
    rotate_hours: float = _number(24.0, 0.1, 168, "h")
    flush_interval: float = _number(2.0, 0.1, 2, "s")
    sync_interval: float = _number(10.0, 0.1, 60, "s")
    queue_size: int = _integer(10000, 100, 1000000)


PROGRAM_ALERT_EVENTS: tuple[str, ...] = (
    "step_reached",
    "step_done",
    "waiting",
    "finished",
    "late",
)
"""The mash program's events a brewer hears of (hermsd.program)."""
ALERT_EVENTS: tuple[str, ...] = (
    "alarm_raised",
    "alarm_cleared",
    "started",
    "stopped",
    "element_warning",
    "setpoint_unreachable",
    *PROGRAM_ALERT_EVENTS,
)


@dataclass(frozen=True, slots=True)
class AlertsConfig:
    """A command run for the events the brewer should hear of (see hermsd/runtime/alerts.py)."""

    command: tuple[str, ...] | None = _words(None, null_means="no alerts")
    events: tuple[str, ...] = _words(ALERT_EVENTS, choices=ALERT_EVENTS)
    timeout: float = _number(10.0, 1, 300, "s")
    min_interval: float = _number(60.0, 0, 86400, "s")


@dataclass(frozen=True, slots=True)
class WebConfig:
    """The brewer's web page (`hermsd web`, a process of its own; the daemon ignores this)."""

    listen: str = _text("127.0.0.1:8080", max_length=300)
    password_hash: str | None = _text(None, null_means="no password: the page cannot change")
    session_lifetime: float = _number(12.0, 0.1, 720, "h")
    read_only_view: str = _choice("off", ("on", "off"))
    allowed_hosts: tuple[str, ...] | None = _words(
        None, null_means="localhost, this machine's hostname and any .local name"
    )


@dataclass(frozen=True, slots=True)
class MqttConfig:
    """The bridge to an MQTT broker and Home Assistant (`hermsd mqtt`, docs/mqtt.md); a
    process of its own reads it, the control loop never does."""

    host: str = _text("localhost", max_length=253)
    port: int = _integer(1883, 1, 65535)
    username: str | None = _text(None, max_length=256, null_means="no login")
    password_file: str | None = _text(None, null_means="no password")
    tls: bool = False
    ca_file: str | None = _text(None, null_means="the system's certificate authorities")
    cert_file: str | None = _text(None, null_means="no client certificate")
    key_file: str | None = _text(None, null_means="the key inside cert_file")
    topic_prefix: str = _text("hermsd", max_length=100)
    discovery_prefix: str = _text("homeassistant", max_length=100)
    client_id: str | None = _text(None, max_length=64, null_means="'hermsd-' and topic_prefix")


@dataclass(frozen=True, slots=True)
class Config:
    """Everything the daemon is told, one section per part of the HLT."""

    tun: TunConfig = field(default_factory=TunConfig)
    control: ControlConfig = field(default_factory=ControlConfig)
    sensor: SensorConfig = field(default_factory=SensorConfig)
    output: OutputConfig = field(default_factory=OutputConfig)
    contactor: ContactorConfig = field(default_factory=ContactorConfig)
    element2: Element2Config = field(default_factory=Element2Config)
    safety: SafetyConfig = field(default_factory=SafetyConfig)
    log: LogConfig = field(default_factory=LogConfig)
    alerts: AlertsConfig = field(default_factory=AlertsConfig)
    mqtt: MqttConfig = field(default_factory=MqttConfig)
    web: WebConfig = field(default_factory=WebConfig)


DEFAULT = Config()

# Control keys an operator changes while brewing: they leave the controller's state alone.
OPERATING_KEYS: tuple[str, ...] = ("setpoint", "mode", "manual_output")
# Control keys that make a different controller (the period is fixed until a restart).
TUNING_KEYS: tuple[str, ...] = tuple(
    f.name for f in dataclasses.fields(ControlConfig) if f.name not in (*OPERATING_KEYS, "period")
)

# Keys the running daemon cannot change on reload: they open devices, fix the schedule's
# grid (period, read interval, window) or configure the log writer already running.
RESTART_KEYS: tuple[str, ...] = (
    "control.period",
    "sensor.bus",
    "sensor.address",
    "sensor.read_interval",
    "output.backend",
    "output.port",
    "output.chip",
    "output.line",
    "output.active_low",
    "output.window",
    *(f"contactor.{f.name}" for f in dataclasses.fields(ContactorConfig)),
    *(f"element2.{f.name}" for f in dataclasses.fields(Element2Config)),
    *(f"log.{f.name}" for f in dataclasses.fields(LogConfig)),
)


class Problem(NamedTuple):
    """One thing wrong with a configuration file.

    `line` and `column` are 1-based; 0 means the file as a whole (it could not be read).
    `message` reads "what is wrong (what would be right)".
    """

    file: str
    line: int
    column: int
    key_path: str
    message: str

    def __str__(self) -> str:
        where = f"{self.file}:{self.line}:{self.column}" if self.line else self.file
        return (
            f"{where}: {self.key_path}: {self.message}"
            if self.key_path
            else f"{where}: {self.message}"
        )


class ConfigError(Exception):
    """A configuration file that cannot be used; `str()` lists every problem, one per line."""

    def __init__(self, problems: list[Problem]) -> None:
        self.problems = problems
        super().__init__("\n".join(str(problem) for problem in problems))


# -- the schema, read once from the dataclasses above -------------------------------------------


@dataclass(frozen=True, slots=True)
class _Field:
    path: str
    kind: type  # float, int, str, bool, or tuple (a list of text items)
    nullable: bool
    default: object
    spec: _Spec


def _kind(hint: object) -> tuple[type, bool]:
    """(base type, whether None is allowed) of an annotation such as `float | None`."""
    if typing.get_origin(hint) is tuple:
        return tuple, False
    args = typing.get_args(hint)
    base = next(arg for arg in args if arg is not type(None)) if args else hint
    if typing.get_origin(base) is tuple:
        return tuple, True
    assert isinstance(base, type)
    return base, bool(args)


def _section_fields(section: str, cls: type) -> dict[str, _Field]:
    hints = typing.get_type_hints(cls)
    table = {}
    for f in dataclasses.fields(cls):
        kind, nullable = _kind(hints[f.name])
        table[f.name] = _Field(
            f"{section}.{f.name}", kind, nullable, f.default, f.metadata.get(_SPEC, _Spec())
        )
    return table


_SECTION_CLASSES: dict[str, type] = {
    name: hint for name, hint in typing.get_type_hints(Config).items()
}
_SCHEMA: dict[str, dict[str, _Field]] = {
    name: _section_fields(name, cls) for name, cls in _SECTION_CLASSES.items()
}


# -- reading scalars ------------------------------------------------------------------------------

_NULLS = frozenset({"", "~", "null", "Null", "NULL"})
_BOOLS = {"true": True, "True": True, "TRUE": True, "false": False, "False": False, "FALSE": False}
_DECIMAL = re.compile(r"[-+]?(?:0|[1-9][0-9]*)")
_HEX = re.compile(r"[-+]?0x[0-9a-fA-F]+")
_FLOAT = re.compile(r"[-+]?(?:(?:0|[1-9][0-9]*)(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][-+]?[0-9]+)?")
_LEADING_ZERO = re.compile(r"[-+]?0[0-9]+(?:\.[0-9]*)?(?:[eE][-+]?[0-9]+)?")
_CLOCK_TIME = re.compile(r"[0-9]{1,6}(?::[0-5]?[0-9]){1,2}")  # 1:30 or 1:30:00
_RESOLVER = yaml.resolver.Resolver()


class _TooLong(Exception):
    """A plain number with more digits than Python converts (int() refuses beyond ~4300)."""


def _plain_value(text: str) -> object:
    """What an unquoted scalar means in this file: None, a bool, an int, a float or text."""
    if text in _NULLS:
        return None
    if text in _BOOLS:
        return _BOOLS[text]
    try:
        if _DECIMAL.fullmatch(text):
            return int(text)
        if _HEX.fullmatch(text):
            return int(text, 16)
    except ValueError as exc:
        raise _TooLong from exc
    if _FLOAT.fullmatch(text):
        return float(text)
    return text


def _scalar_value(node: yaml.ScalarNode) -> object:
    """Quoted and block scalars are always text; plain ones go through `_plain_value`."""
    return _plain_value(node.value) if node.style is None else node.value


def _explicit_tag(node: yaml.Node) -> str | None:
    """A tag the author wrote (`!!str 5`, `!x`), or None when the node carries its natural tag."""
    if isinstance(node, yaml.ScalarNode):
        implicit = (node.style is None, node.style is not None)  # as the parser sets it
        natural = _RESOLVER.resolve(yaml.ScalarNode, node.value, implicit)  # type: ignore[no-untyped-call]
    elif isinstance(node, yaml.SequenceNode):
        natural = _RESOLVER.DEFAULT_SEQUENCE_TAG
    else:
        natural = _RESOLVER.DEFAULT_MAPPING_TAG
    return None if node.tag == natural else str(node.tag).replace("tag:yaml.org,2002:", "!!")


def _fmt(number: float) -> str:
    """A bound or value as a brewer would write it: 100 rather than 100.0."""
    if isinstance(number, float) and number.is_integer() and abs(number) < 1e15:
        return str(int(number))
    return str(number)


def _show_default(value: object) -> str:
    """A default as it is written in the file."""
    if value is None or isinstance(value, bool):
        return "null" if value is None else str(value).lower()
    if isinstance(value, int | float):
        return _fmt(value)
    return repr(value)


def _reads_as_number(text: str) -> bool:
    """Whether `text`, written without quotes, would be read as a number."""
    try:
        value = _plain_value(text)
    except _TooLong:
        return True
    return isinstance(value, int | float) and not isinstance(value, bool)


def _quote(text: str, limit: int = 40) -> str:
    shown = text if len(text) <= limit else text[: limit - 1] + "…"
    return repr(shown)


def _describe(node: yaml.Node) -> str:
    """What the author wrote, in words: 'the string '66'', 'a list', 'nothing'."""
    if not isinstance(node, yaml.ScalarNode):
        return "a list" if isinstance(node, yaml.SequenceNode) else "a mapping of keys"
    try:
        value = _scalar_value(node)
    except _TooLong:
        return f"a number with {len(node.value)} characters"
    if value is None:
        return "nothing (null)"
    if isinstance(value, bool):
        return f"the boolean {str(value).lower()}"
    if isinstance(value, int | float):
        return f"the number {node.value}"
    return f"the string {_quote(str(value))}"


def _expected(info: _Field) -> str:
    """What would be right for a key, e.g. 'a number from 0 to 100 °C, or null for ...'."""
    spec = info.spec
    unit = f" {spec.unit}" if spec.unit else ""
    if info.kind is tuple:
        item = _expected(_item_field(info))
        words = f"a list of one or more items, each {item.removeprefix('non-empty ')}"
    elif info.kind is bool:
        words = "true or false"
    elif spec.choices:
        names = [repr(c) if isinstance(c, str) else str(c) for c in spec.choices]
        words = f"{', '.join(names[:-1])} or {names[-1]}"
        words = words if len(names) < 3 else "one of " + words
    elif info.kind is str:
        if spec.max_length is not None:
            words = f"text of 1 to {spec.max_length} printable characters"
        else:
            words = f"non-empty printable text, e.g. {info.default!r}"
    else:
        noun = "a number" if info.kind is float else "a whole number"
        show = (lambda v: f"0x{int(v):02X}") if spec.as_hex else _fmt
        assert spec.low is not None
        if spec.high is None:
            words = f"{noun} of at least {show(spec.low)}"
        elif spec.low_exclusive:
            words = f"{noun} above {show(spec.low)} and at most {show(spec.high)}{unit}"
        else:
            words = f"{noun} from {show(spec.low)} to {show(spec.high)}{unit}"
        if spec.zero_means is not None:
            words = f"0 for {spec.zero_means}, or {words}"
    if spec.null_means is not None:
        words += f", or null for {spec.null_means}"
    return words


class _Invalid(Exception):
    """A value that is wrong; the message says what is wrong (what would be right)."""

    def __init__(self, message: str, mark: yaml.Mark | None = None) -> None:
        super().__init__(message)
        self.mark = mark  # where the wrong part starts, when not at the value itself


def _item_field(info: _Field) -> _Field:
    """How each item of a list key is read: as a text key with the list's choices."""
    example = info.spec.choices[0] if info.spec.choices else "/usr/local/bin/alert"
    return _Field(f"{info.path}[]", str, False, example, _Spec(choices=info.spec.choices))


def _convert_list(info: _Field, node: yaml.Node) -> tuple[str, ...]:
    """A list key's items, each checked as text; an empty list or a repeated choice is refused."""
    expected = _expected(info)
    if not isinstance(node, yaml.SequenceNode) or _explicit_tag(node) is not None:
        raise _Invalid(f"expected a list such as [a, b], got {_describe(node)} ({expected})")
    if not node.value:
        raise _Invalid(f"is an empty list ({expected})")
    items = []
    for number, item in enumerate(node.value, 1):
        try:
            items.append(str(_convert(_item_field(info), item)))
        except _Invalid as problem:
            raise _Invalid(f"item {number}: {problem}", item.start_mark) from None
    if info.spec.choices and len(set(items)) < len(items):
        raise _Invalid(f"names a choice twice ({expected})")
    return tuple(items)


def _number_hint(info: _Field, value: object) -> str:
    """Why a plain scalar that looks numeric is not read as a number, when that is the reason."""
    if not isinstance(value, str):
        return ""
    if _LEADING_ZERO.fullmatch(value):
        return "; drop the leading zeros, which YAML 1.1 reads as octal"
    if info.spec.unit == "s" and _CLOCK_TIME.fullmatch(value):
        seconds = 0
        for part in value.split(":"):
            seconds = seconds * 60 + int(part)
        return f"; durations are plain seconds in this file: write {seconds}"
    return ""


def _convert(info: _Field, node: yaml.Node) -> object:
    """The value of one key as its field holds it, or _Invalid."""
    expected = _expected(info)
    if info.kind is tuple and not _is_null(node):
        return _convert_list(info, node)
    if not isinstance(node, yaml.ScalarNode):
        raise _Invalid(f"expected a single value, got {_describe(node)} ({expected})")
    tag = _explicit_tag(node)
    if tag is not None:
        raise _Invalid(f"the YAML tag {tag!r} is not used in this file (remove it; {expected})")
    try:
        value = _scalar_value(node)
    except _TooLong:
        raise _Invalid(f"{_describe(node)} is not a usable value ({expected})") from None
    if value is None:
        if info.nullable:
            return None
        raise _Invalid(f"has no value ({expected}{_left_out(info)})")

    if info.kind is bool:
        if isinstance(value, bool):
            return value
        raise _Invalid(f"expected true or false, got {_describe(node)} ({expected})")

    if info.kind is str:
        if not isinstance(value, str):
            raise _Invalid(
                f"expected text, got {_describe(node)} ({expected}; quote it to mean text: "
                f"'{node.value}')"
            )
        return _checked_text(info, value, expected)

    whole = not isinstance(value, float) or info.kind is float
    if isinstance(value, bool) or not isinstance(value, int | float) or not whole:
        noun = "a whole number" if info.kind is int else "a number"
        if node.style is not None and isinstance(value, str) and _reads_as_number(value):
            right = f"write it without quotes: {value}; {expected}"
        else:
            right = expected + _number_hint(info, value)
        raise _Invalid(f"expected {noun}, got {_describe(node)} ({right})")
    if isinstance(value, float) and not math.isfinite(value):
        raise _Invalid(f"{node.value} is too large to be a number here ({expected})")
    if not _within(info.spec, value):
        unit = f" {info.spec.unit}" if info.spec.unit else ""
        if info.spec.choices:
            raise _Invalid(f"{node.value} is not one of the choices ({expected})")
        raise _Invalid(f"{node.value}{unit} is out of range ({expected})")
    return float(value) if info.kind is float else value


def _left_out(info: _Field) -> str:
    """What leaving a key out would do instead of the empty value, or nothing if it must be."""
    if info.spec.left_out is None:
        return f"; or leave the key out for the default {_show_default(info.default)}"
    return f"; or leave the key out for {info.spec.left_out}" if info.spec.left_out else ""


def _within(spec: _Spec, number: float) -> bool:
    if spec.choices:
        return number in spec.choices
    if spec.zero_means is not None and number == 0:
        return True
    assert spec.low is not None
    if number < spec.low or (spec.low_exclusive and number == spec.low):
        return False
    return spec.high is None or number <= spec.high


def _checked_text(info: _Field, text: str, expected: str) -> str:
    spec = info.spec
    if spec.choices:
        if text in spec.choices:
            return text
        names = [str(c) for c in spec.choices]
        close = difflib.get_close_matches(text, names, n=1) or difflib.get_close_matches(
            text.lower(), names, n=1
        )
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise _Invalid(f"{_quote(text)} is not one of the choices ({expected}{hint})")
    if not text:
        raise _Invalid(f"is empty ({expected})")
    if not text.isprintable():
        raise _Invalid(f"{_quote(text)} contains a control character such as a tab ({expected})")
    if spec.max_length is not None and len(text) > spec.max_length:
        raise _Invalid(f"{_quote(text)} is {len(text)} characters long ({expected})")
    return text


# -- rules that span keys -------------------------------------------------------------------------


class _Violation(NamedTuple):
    keys: tuple[str, ...]  # every key the rule reads; the first one present in the file is shown
    message: str
    value: str = ""  # keys[0]'s value with its unit, when `message` goes on from it

    def said(self, shown: str) -> str:
        """The message under the key `shown`; another key than its subject's names that."""
        if not self.value:
            return self.message
        subject = self.value if shown == self.keys[0] else f"{self.keys[0]} ({self.value})"
        return f"{subject} {self.message}"


def _violations(config: Config) -> list[_Violation]:
    """Every rule between keys that `config` breaks."""
    found: list[_Violation] = []
    control, output, contactor, safety = (
        config.control,
        config.output,
        config.contactor,
        config.safety,
    )

    if output.window is not None:
        window_key, window, what = (
            "output.window",
            output.window,
            f"the {_fmt(output.window)} s window",
        )
    else:
        window_key, window = "control.period", control.period
        what = f"the {_fmt(window)} s period (the SSR window while output.window is null)"
    pulses = output.min_on + output.min_off
    if window <= pulses:
        found.append(
            _Violation(
                (window_key, "output.min_on", "output.min_off", "output.window"),
                f"{what} is not longer than output.min_on + output.min_off = {_fmt(pulses)} s "
                "(lengthen the window or shorten min_on/min_off)",
            )
        )

    half_cycle = 1 / (2 * output.mains_hz)
    at_least = math.ceil(half_cycle * 1e4) / 1e4
    for name in ("min_on", "min_off"):
        pulse = getattr(output, name)
        if 0 < pulse < half_cycle:
            found.append(
                _Violation(
                    (f"output.{name}", "output.mains_hz"),
                    "is shorter than one mains half-cycle "
                    f"({_fmt(round(half_cycle * 1000, 2))} ms at {output.mains_hz} Hz), the "
                    "shortest pulse a zero-cross SSR delivers "
                    f"(use 0 or at least {_fmt(at_least)})",
                    f"{_fmt(pulse)} s",
                )
            )

    if control.setpoint >= safety.max_temp:
        found.append(
            _Violation(
                ("control.setpoint", "safety.max_temp"),
                "is not below safety.max_temp "
                f"({_fmt(safety.max_temp)} °C), where the over-temperature cut-out switches the "
                f"heater off (set it below {_fmt(safety.max_temp)} °C or raise safety.max_temp)",
                f"{_fmt(control.setpoint)} °C",
            )
        )
    if safety.plausible_min >= safety.plausible_max:
        found.append(
            _Violation(
                ("safety.plausible_min", "safety.plausible_max"),
                f"is not below safety.plausible_max ({_fmt(safety.plausible_max)} °C): the "
                "believable readings run from plausible_min up to plausible_max (lower "
                "plausible_min or raise plausible_max)",
                f"{_fmt(safety.plausible_min)} °C",
            )
        )
    if safety.max_temp >= safety.plausible_max:
        found.append(
            _Violation(
                ("safety.max_temp", "safety.plausible_max"),
                f"is not below safety.plausible_max ({_fmt(safety.plausible_max)} °C), so an "
                "overheat would read as a broken sensor (lower max_temp or raise plausible_max)",
                f"{_fmt(safety.max_temp)} °C",
            )
        )
    if safety.stale_after is not None and safety.stale_after <= config.sensor.read_interval:
        found.append(
            _Violation(
                ("safety.stale_after", "sensor.read_interval"),
                "is not longer than sensor.read_interval "
                f"({_fmt(config.sensor.read_interval)} s), so every reading would go stale "
                f"before the next (make it a few read intervals, e.g. "
                f"{_fmt(3 * config.sensor.read_interval)})",
                f"{_fmt(safety.stale_after)} s",
            )
        )
    if control.manual_output > control.max_output:
        found.append(
            _Violation(
                ("control.manual_output", "control.max_output"),
                f"is above control.max_output ({_fmt(control.max_output)} %) (lower "
                "manual_output or raise max_output)",
                f"{_fmt(control.manual_output)} %",
            )
        )

    for section, device in (
        ("output", output),
        ("contactor", contactor),
        ("element2", config.element2),
    ):
        if device.backend == "gpio" and device.line is None:
            found.append(
                _Violation(
                    (f"{section}.backend", f"{section}.line"),
                    f"the gpio backend needs {section}.line, the line offset on {device.chip} "
                    f"(add 'line: 17' under {section}: for GPIO17, with your line number)",
                )
            )
    if output.backend in _SERIAL_LINES and output.port == contactor.port:
        if contactor.backend == output.backend:
            found.append(
                _Violation(
                    ("contactor.backend", "contactor.port", "output.backend", "output.port"),
                    "the contactor and the SSR output would both switch the "
                    f"{output.backend.removeprefix('serial-').upper()} line of {output.port} "
                    "(give the contactor its own port, or the other line of this one)",
                )
            )
        elif contactor.backend == "relay-board":
            found.append(
                _Violation(
                    ("contactor.backend", "contactor.port", "output.backend", "output.port"),
                    f"the relay board needs {output.port} to itself, but the SSR output switches "
                    f"a line of it (give the relay board its own port)",
                )
            )
    if (
        output.backend == contactor.backend == "gpio"
        and output.line is not None
        and (output.chip, output.line) == (contactor.chip, contactor.line)
    ):
        found.append(
            _Violation(
                (
                    "contactor.line",
                    "contactor.chip",
                    "output.line",
                    "output.chip",
                    "output.backend",
                ),
                f"the contactor and the SSR output would both drive line {output.line} of "
                f"{output.chip} (give the contactor its own line)",
            )
        )
    found.extend(_element2_violations(config))
    found.extend(_controller_violations(control))
    measured = measured_model(config)
    why = implausible(measured) if measured is not None else None
    if why is not None:
        found.append(
            _Violation(
                ("control.model_litres", *(f"control.{key}" for key in _MODEL_KEYS)),
                f"the measured tun (model_litres set) cannot be a water tun: {why} (set "
                "model_litres to null, or write the model again with `hermsd tune --write`)",
            )
        )
    found.extend(_mqtt_violations(config.mqtt))
    found.extend(_web_violations(config.web))
    return found


def split_listen(text: str) -> tuple[str, int] | None:
    """`web.listen`'s host and port (`127.0.0.1:8080`, `[::1]:8080`), or None if malformed."""
    host, colon, port = text.rpartition(":")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    if not colon or not host or not port.isdigit() or not 1 <= int(port) <= 65535:
        return None
    return host, int(port)


def _web_violations(web: WebConfig) -> list[_Violation]:
    from hermsd.web.passwords import EXAMPLE, parse_hash

    found: list[_Violation] = []
    if split_listen(web.listen) is None:
        found.append(
            _Violation(
                ("web.listen",),
                f"{_quote(web.listen)} is not HOST:PORT (e.g. 127.0.0.1:8080, or 0.0.0.0:8080 "
                "for every interface; a port 1 to 65535)",
            )
        )
    if web.password_hash is not None and parse_hash(web.password_hash) is None:
        found.append(
            _Violation(("web.password_hash",), f"not a password hash (expected {EXAMPLE})")
        )
    for name in web.allowed_hosts or ():
        if not _HOST_NAME.fullmatch(name):
            found.append(
                _Violation(
                    ("web.allowed_hosts",),
                    f"{_quote(name)} is not a host name (a name alone, no scheme or port: "
                    "e.g. brew.example.org, or *.example.org for every name under it; IP "
                    "addresses need no entry)",
                )
            )
    return found


_HOST_NAME = re.compile(r"(\*\.)?[A-Za-z0-9_-]+(\.[A-Za-z0-9_-]+)*\.?")


def _device(section: OutputConfig | ContactorConfig | Element2Config) -> tuple[object, ...]:
    """What a section's switch occupies: a serial port (a relay board or a line of it), or a
    gpio line; two sections that occupy the same thing would drive one device."""
    if section.backend == "gpio":
        return ("gpio", section.chip, section.line)
    if section.backend == "relay-board":
        return ("serial", section.port, "relay", getattr(section, "channel", None))
    return ("serial", section.port, section.backend)


def _element2_violations(config: Config) -> list[_Violation]:
    """The second element: the mid-ranging controller only with one (any other controller
    drives the total of both), on a device of its own, its minimum times whole periods at
    least (it switches at periods)."""
    element2, control = config.element2, config.control
    found = []
    fitted = element2.backend != "none"
    if not fitted and control.algorithm == MIDRANGE:
        found.append(
            _Violation(
                ("control.algorithm", "element2.backend"),
                f"control.algorithm {control.algorithm} with element2.backend "
                f"{element2.backend}: the mid-ranging controller drives two elements (give "
                "element2 a backend, or choose another algorithm)",
            )
        )
    if not fitted:
        return found
    for name in ("min_on", "min_off"):
        value = getattr(element2, name)
        if value < control.period:
            found.append(
                _Violation(
                    (f"element2.{name}", "control.period"),
                    f"is shorter than control.period ({_fmt(control.period)} s); the second "
                    f"element switches only at periods (make it at least {_fmt(control.period)})",
                    f"{_fmt(value)} s",
                )
            )
    mine = _device(element2)
    for other_name, other in (("output", config.output), ("contactor", config.contactor)):
        if other.backend in ("none", "sim") or element2.backend == "sim":
            continue
        theirs = _device(other)
        if mine[:2] != theirs[:2]:
            continue
        relays = ("relay" in mine, "relay" in theirs)
        if mine[2:] == theirs[2:] or relays[0] != relays[1]:
            where = f"line {element2.line} of {element2.chip}" if mine[0] == "gpio" else mine[1]
            found.append(
                _Violation(
                    ("element2.backend", "element2.port", "element2.line", "element2.channel"),
                    f"element2 and {other_name} would both drive {where} (give element2 its "
                    "own port, line or relay channel; a relay board needs its port to itself)",
                )
            )
    return found


_MODEL_KEYS = ("model_gain", "model_tau", "dead_time", "model_ambient")


def _mqtt_violations(mqtt: MqttConfig) -> list[_Violation]:
    """A topic prefix MQTT would refuse or misread, and TLS or login keys left without the
    key they go with."""
    found = []
    for name in ("topic_prefix", "discovery_prefix"):
        prefix: str = getattr(mqtt, name)
        wrong = topic_prefix_problem(prefix)
        if wrong:
            found.append(_Violation((f"mqtt.{name}",), f"{_quote(prefix)} {wrong}"))
    if mqtt.password_file is not None and mqtt.username is None:
        found.append(
            _Violation(
                ("mqtt.password_file", "mqtt.username"),
                "a password goes with a user name (add mqtt.username, or remove the password)",
            )
        )
    for name in ("ca_file", "cert_file", "key_file"):
        if getattr(mqtt, name) is not None and not mqtt.tls:
            found.append(
                _Violation(
                    (f"mqtt.{name}", "mqtt.tls"),
                    "is used only over TLS (set mqtt.tls: true, or remove it)",
                )
            )
    if mqtt.key_file is not None and mqtt.cert_file is None:
        found.append(
            _Violation(
                ("mqtt.key_file", "mqtt.cert_file"),
                "a client key goes with its certificate (add mqtt.cert_file)",
            )
        )
    return found


def topic_prefix_problem(prefix: str) -> str | None:
    """What makes `prefix` unfit to start MQTT topic names, or None when it is fit."""
    if "+" in prefix or "#" in prefix:
        return "holds a wildcard, + or # (use letters, digits, - and _, levels split by /)"
    if prefix.startswith("$"):
        return "starts with $, which brokers keep for themselves (e.g. 'hermsd')"
    if "" in prefix.split("/"):
        return "has an empty level: a / at either end or two together (e.g. 'brewery/hlt')"
    return None


WATER_J_PER_LITRE_K = 4186.0
LIDDED_UA_W_PER_K = 3000.0 / (100.0 * 1.689)
"""Heat loss of a lidded 90 L tun (the seed's step test: 3 kW for 1.689 °C/%), W/K; it
scales with the wetted surface, (V/90 L)^⅔."""
LIDDED_LITRES = 90.0


def prior_model(config: Config) -> pid.PlantModel:
    """The tun's model before anything is learned: physics where it can, the keys elsewhere.

    The full-power rate P/(ρ·c·V) follows from `tun.element_watts` and `tun.litres`. The
    losses UA: the smaller of what `control.model_gain` says (UA = P/(100·K)) and a lidded
    tun of this size, since a model that overstates the losses holds too much power and
    overshoots, while one that understates them approaches from below and learns. The
    FOPTD follows (τ = ρ·c·V/UA, K = P/(100·UA)); dead time and room from their keys.
    """
    c, tun = config.control, config.tun
    watts = total_watts(config)
    capacity = WATER_J_PER_LITRE_K * tun.litres
    lidded = LIDDED_UA_W_PER_K * (tun.litres / LIDDED_LITRES) ** (2.0 / 3.0)
    ua = min(watts / (100.0 * c.model_gain), lidded)
    return pid.PlantModel(watts / (100.0 * ua), capacity / ua, c.dead_time, c.model_ambient)


def total_watts(config: Config) -> float:
    """Both elements' power: what 100 % of the controller's output means with two fitted."""
    e2 = config.element2
    return config.tun.element_watts + (e2.watts if e2.backend != "none" else 0.0)


def measured_model(config: Config) -> LearnedModel | None:
    """The tun as `hermsd tune` measured it: the control.model_* keys once model_litres says
    with how much water (None before: the keys are the seed's tun, a guess)."""
    c = config.control
    if c.model_litres is None:
        return None
    foptd = pid.PlantModel(c.model_gain, c.model_tau, c.dead_time, c.model_ambient)
    return LearnedModel.from_plant(foptd, c.model_litres)


def make_controller(control: ControlConfig, model: pid.PlantModel | None = None) -> pid.Controller:
    """The controller a control section describes (ValueError if the algorithm refuses it).

    `model` is the tun's model for predictive; without it, the one the control keys give.
    """
    c = control
    if c.algorithm == MIDRANGE:
        return _midrange_controller(c)
    return pid.create(
        c.algorithm,
        kc=c.kc,
        ti=c.ti,
        td=c.td,
        ts=c.period,
        tf=c.tf,
        tt=c.tt,
        out_min=0.0,
        out_max=c.max_output,
        model=model or pid.PlantModel(c.model_gain, c.model_tau, c.dead_time, c.model_ambient),
    )


def shared_out(config: Config, controller: pid.Controller) -> pid.Controller:
    """The controller the loop runs, given `make_controller`'s: with a second element fitted
    and any algorithm but midrange, that controller on the total power of both elements,
    shared out each period by a `PowerSplit`; else the controller itself."""
    e2 = config.element2
    if e2.backend == "none" or config.control.algorithm == MIDRANGE:
        return controller
    c = config.control
    split = PowerSplit(
        config.tun.element_watts, e2.watts, c.period, e2.min_on, e2.min_off, c.max_output
    )
    probe = ElementProbe(config.tun.element_watts, e2.watts, c.period, c.dead_time)
    return SplitController(controller, split, probe if e2.check else None)


def full_power(config: Config) -> FullPower:
    """The duties that are full power on the tun `config` describes (the reach watch and a
    ready_by heat-up judge by them; replay can from the logged config): the SSR's element at
    control.max_output and a second element on, as mid-ranging gives them at its most (a
    u2_max under 100 % pulses it: never full); shared out, control.max_output limits both
    elements' total instead (`PowerSplit.full_power`)."""
    c, e2 = config.control, config.element2
    if e2.backend == "none":
        return FullPower(c.max_output)
    if c.algorithm == MIDRANGE:
        return FullPower(c.max_output, True)
    watts1 = config.tun.element_watts
    return PowerSplit(watts1, e2.watts, c.period, e2.min_on, e2.min_off, c.max_output).full_power()


def full_power_share(config: Config) -> float:
    """Full power as a % of all the elements' power (the controller's 100 % with two, and
    what the tun's model rate is of): what a ready_by heat-up plans its climb with. Mid-
    ranging under a power limit gives the second element in full (at u2_max on average) and
    the SSR's at control.max_output, more of the total than the limit's %."""
    full, c = full_power(config), config.control
    if full.on2 is None:
        return full.duty1
    duty2 = (c.u2_max if c.algorithm == MIDRANGE else 100.0) if full.on2 else 0.0
    watts1 = config.tun.element_watts
    return total_share(watts1, total_watts(config) - watts1, full.duty1, duty2)


def _midrange_controller(c: ControlConfig) -> MidRangeController:
    """C1 on the SSR's element within 0..max_output; C2 on the second element. A heater's u2
    must rise when u1 sits above u1_ref, so C2's gain is −k2 (k2 is written positive)."""
    inner = midrange.create(
        k1=c.k1,
        ti1=c.ti1,
        tt1=c.tt1,
        k2=-c.k2,
        ti2=c.ti2,
        tt2=c.tt2,
        ks=c.ks,
        h=c.period,
        u1_ref=c.u1_ref,
        u1_min=0.0,
        u1_max=c.max_output,
        u2_min=c.u2_min,
        u2_max=c.u2_max,
    )
    p = inner.params
    params = pid.Params(MIDRANGE, c.k1, c.ti1, 0.0, c.period, 0.0, p.tt1, 0.0, c.max_output)
    return MidRangeController(inner, params)


def _controller_violations(control: ControlConfig) -> list[_Violation]:
    """The algorithm's own rules on its parameters (tt only for back_calculation, …)."""
    try:
        make_controller(control)
    except ValueError as error:
        named = str(error).split("=", 1)[0]
        key = f"control.{named}" if named in _CONTROL_PARAMETERS else "control.algorithm"
        return [_Violation((key, "control.algorithm"), f"{error} (algorithm {control.algorithm})")]
    return []


_CONTROL_PARAMETERS = (
    "kc",
    "ti",
    "td",
    "tf",
    "tt",
    *("k1", "ti1", "tt1", "k2", "ti2", "tt2", "ks", "u1_ref", "u2_min", "u2_max"),
)


# -- reading a document ---------------------------------------------------------------------------


class _Reader:
    """Walks a composed YAML document against the schema, collecting every problem."""

    def __init__(self, filename: str) -> None:
        self.filename = filename
        self.problems: list[Problem] = []
        self.marks: dict[str, yaml.Mark] = {}  # key path -> where its value starts
        self.failed: set[str] = set()  # key paths and sections whose value was refused
        self.written: dict[str, tuple[int, int]] = {}  # each section and key -> (line, column)

    def report(self, mark: yaml.Mark | None, key_path: str, message: str) -> None:
        line, column = (mark.line + 1, mark.column + 1) if mark is not None else (1, 1)
        self.problems.append(Problem(self.filename, line, column, key_path, message))

    def items(
        self, node: yaml.MappingNode, prefix: str, known: list[str]
    ) -> list[tuple[str, yaml.Node]]:
        """The (key, value) pairs of a mapping whose keys are known and not repeated."""
        seen: dict[str, int] = {}
        pairs = []
        for key_node, value_node in node.value:
            if not isinstance(key_node, yaml.ScalarNode):
                self.report(
                    key_node.start_mark,
                    prefix,
                    f"a key must be a plain name, got {_describe(key_node)} "
                    f"(one of: {', '.join(known)})",
                )
                continue
            key = key_node.value
            path = f"{prefix}.{key}" if prefix else key
            if key in seen:
                self.report(
                    key_node.start_mark,
                    path,
                    f"duplicate key (first given on line {seen[key]}; keep one of them)",
                )
                continue
            seen[key] = key_node.start_mark.line + 1
            if key not in known:
                self.report(
                    key_node.start_mark, path, f"unknown key ({self._suggest(key, prefix, known)})"
                )
                continue
            self.written[path] = (key_node.start_mark.line + 1, key_node.start_mark.column + 1)
            pairs.append((key, value_node))
        return pairs

    @staticmethod
    def _suggest(key: str, prefix: str, known: list[str]) -> str:
        homes = [
            section for section, table in _SCHEMA.items() if key in table and section != prefix
        ]
        if homes:
            return f"it belongs in the {homes[0]!r} section"
        close = difflib.get_close_matches(key, known, n=1)
        if close:
            return f"did you mean {close[0]!r}?"
        return f"the keys here are: {', '.join(known)}"

    def document(self, root: yaml.Node | None) -> dict[str, dict[str, object]]:
        """The values the document sets, section by section (refused values left out)."""
        values: dict[str, dict[str, object]] = {section: {} for section in _SCHEMA}
        if root is None:
            return values
        sections = list(_SCHEMA)
        if not isinstance(root, yaml.MappingNode) or _explicit_tag(root) is not None:
            self.report(
                root.start_mark,
                "",
                f"the file must be a mapping of sections, got {_describe(root)} "
                f"(sections such as 'control:' at the start of a line: {', '.join(sections)})",
            )
            return values
        for section, node in self.items(root, "", sections):
            values[section] = self.section(section, node)
        return values

    def section(self, section: str, node: yaml.Node) -> dict[str, object]:
        table = _SCHEMA[section]
        if isinstance(node, yaml.ScalarNode) and node.style is None and node.value in _NULLS:
            return {}  # a section whose keys are all commented out
        if not isinstance(node, yaml.MappingNode) or _explicit_tag(node) is not None:
            self.failed.add(section)
            self.report(
                node.start_mark,
                section,
                f"expected a section of keys, got {_describe(node)} (indented 'key: value' "
                f"lines below '{section}:', keys: {', '.join(table)})",
            )
            return {}
        values = {}
        for name, value_node in self.items(node, section, list(table)):
            info = table[name]
            self.marks[info.path] = value_node.start_mark
            try:
                values[name] = _convert(info, value_node)
            except _Invalid as problem:
                self.failed.add(info.path)
                self.report(problem.mark or value_node.start_mark, info.path, str(problem))
        return values

    def cross_check(self, config: Config) -> None:
        """Report the rules between keys that are broken, unless a key they read was refused."""
        for violation in _violations(config):
            keys = violation.keys
            if any(key in self.failed or key.split(".")[0] in self.failed for key in keys):
                continue
            shown = next((key for key in keys if key in self.marks), keys[0])
            self.report(self.marks.get(shown), shown, violation.said(shown))


def _syntax_problem(filename: str, text: str, error: yaml.YAMLError) -> Problem:
    """A parser error as one Problem at the parser's position."""
    if isinstance(error, yaml.reader.ReaderError):
        before = text[: error.position]
        line = before.count("\n") + 1
        column = error.position - (before.rfind("\n") + 1) + 1
        code = ord(error.character) if isinstance(error.character, str) else error.character
        return Problem(
            filename,
            line,
            column,
            "",
            f"the control character #x{code:x} is not allowed in YAML (delete it)",
        )
    assert isinstance(error, yaml.MarkedYAMLError)
    mark = error.problem_mark or error.context_mark
    line, column = (mark.line + 1, mark.column + 1) if mark is not None else (1, 1)
    what = error.problem or "invalid YAML"
    if error.context and error.context_mark is not None and error.context_mark is not mark:
        what = f"{error.context} on line {error.context_mark.line + 1}, {what}"
    hint = (
        "indent with spaces, not tabs"
        if "'\\t'" in what
        else "check the indentation, the ':' after each key and the quotes, here and on the "
        "line above"
    )
    return Problem(filename, line, column, "", f"invalid YAML: {what} ({hint})")


def _compose(text: str) -> yaml.Node | None:
    loader = yaml.SafeLoader(text)
    try:
        return loader.get_single_node()
    finally:
        loader.dispose()


def _root(text: str, filename: str) -> yaml.Node | None:
    """The YAML document's root node; ConfigError for text that is not YAML."""
    try:
        return _compose(text)
    except yaml.YAMLError as error:
        raise ConfigError([_syntax_problem(filename, text, error)]) from None
    except RecursionError:
        raise ConfigError(
            [
                Problem(
                    filename,
                    1,
                    1,
                    "",
                    "the YAML is nested too deeply (this file needs only sections of "
                    "'key: value' lines)",
                )
            ]
        ) from None


@dataclass(frozen=True, slots=True)
class Document:
    """A valid file: its Config, and what it writes down, which a reload must keep."""

    filename: str
    config: Config
    written: dict[str, tuple[int, int]]  # each section and `section.key` -> (line, column)
    cut_line: int  # the last line when it holds a value but no line break, else 0


def parse(text: str, filename: str = "<string>") -> Config:
    """The Config a YAML text describes; ConfigError lists everything wrong with it."""
    return parse_document(text, filename).config


def parse_document(text: str, filename: str = "<string>") -> Document:
    """`parse`, keeping what the text writes down (for `reload_problems`)."""
    reader = _Reader(filename)
    values = reader.document(_root(text, filename))
    config = Config(**{name: _SECTION_CLASSES[name](**values[name]) for name in _SCHEMA})
    reader.cross_check(config)
    if reader.problems:
        raise ConfigError(sorted(reader.problems, key=lambda p: (p.line, p.column)))
    return Document(filename, config, reader.written, _unfinished_last_line(text))


def load(path: str | os.PathLike[str]) -> Config:
    """The Config in a file; ConfigError (never OSError) when it cannot be read or used."""
    return load_document(path).config


def load_document(path: str | os.PathLike[str]) -> Document:
    """`load`, keeping what the file writes down (for `reload_problems`)."""
    filename = os.fspath(path)
    return parse_document(_read_text(filename), filename)


_LINE_BREAKS = ("\n", "\r", "\x85", "\u2028", "\u2029")  # YAML's, and Unicode's


def _unfinished_last_line(text: str) -> int:
    """The last line's number when it holds a value but ends without a line break, else 0.

    Editors end a file with a line break; a save cut short by a full disk or a crash stops
    anywhere, and a number cut short (`kc: 12` of `kc: 120`) may still be a valid number.
    """
    lines = text.splitlines(keepends=True)
    if not lines or lines[-1].endswith(_LINE_BREAKS):
        return 0
    content = lines[-1].strip()
    return len(lines) if content and not content.startswith("#") else 0


def reload_problems(running: Document, edited: Document) -> list[Problem]:
    """Why `edited`, valid on its own, must not replace the running file's config.

    An emptied file is valid YAML, and so is most of a file cut short: taken as they are,
    every key they lost would fall back to its default (auto mode, full power, the default
    temperature limit) in the middle of a brew. So a reload must name every section and
    key the running file named, and its last line must be finished.
    """
    where = edited.filename
    if running.written and not edited.written:
        return [
            Problem(
                where,
                0,
                0,
                "",
                "names no section: an emptied file, or a save cut short (a reload never "
                "falls back to the built-in defaults; put the file back, or restart hermsd "
                "to run on the defaults)",
            )
        ]
    problems = []
    lost = [key for key in running.written if key not in edited.written]
    gone = [key for key in lost if "." not in key or key.split(".")[0] not in lost]
    if gone:
        names = ", ".join(gone)
        problems.append(
            Problem(
                where,
                0,
                0,
                "",
                f"{names} {'is' if len(gone) == 1 else 'are'} no longer in the file, as in a "
                "save cut short (a reload keeps every key of the running file: to return one "
                "to its default, write the default value; a restart takes the file as it is)",
            )
        )
    if edited.cut_line:
        problems.append(
            Problem(
                where,
                edited.cut_line,
                1,
                "",
                "the last line has no line break at its end, as a save cut short leaves it "
                "(end the file with a newline)",
            )
        )
    return problems


@dataclass(frozen=True, slots=True)
class FoundOutput:
    """One output section as far as a damaged file lets it be read, key by key."""

    section: str  # "output", "contactor" or "element2"
    values: dict[str, object]  # the keys written with a usable value
    refused: dict[str, Problem]  # the keys written with a value that cannot be used
    doubts: list[Problem]  # what may name this device otherwise: unknown keys, unread lines


@dataclass(frozen=True, slots=True)
class FoundOutputs:
    """What `hermsd safe-off` finds in a config file, however damaged."""

    output: FoundOutput
    contactor: FoundOutput
    notes: list[Problem]  # damage outside the output sections, read around
    doubts: list[Problem]  # damage that may hide an output section: nothing is sure then
    element2: FoundOutput = field(default_factory=lambda: FoundOutput("element2", {}, {}, []))


_OUTPUT_SECTIONS = ("output", "contactor", "element2")


def load_outputs(path: str | os.PathLike[str]) -> FoundOutputs:
    """The `output`, `contactor` and `element2` sections of a file, whatever is wrong with it.

    `hermsd safe-off` must find the heater's switches after any bad edit, so this reads
    in steps, each more tolerant than the last: the whole document; if it is not YAML,
    each output section alone, then each of its lines alone; a file that cannot be read
    at all leaves the built-in defaults. Bytes that are not UTF-8 and control characters
    are read as U+FFFD. Every problem on the way is kept, so the caller can tell a file
    read around its damage from one where an output may have been missed.
    """
    filename = os.fspath(path)
    notes: list[Problem] = []
    doubts: list[Problem] = []
    try:
        data = read_bytes(filename)
    except ConfigError as error:
        return _found_outputs(_Reader(filename), {}, notes, error.problems)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as error:
        notes.append(_not_utf8(filename, data, error))
        text = data.decode("utf-8", "replace")
    printable = yaml.reader.Reader.NON_PRINTABLE.sub("\ufffd", text)
    if printable != text:
        try:
            yaml.reader.Reader(text)
        except yaml.reader.ReaderError as error:
            notes.append(_syntax_problem(filename, text, error))
    reader = _Reader(filename)
    try:
        root = _compose(printable)
    except (yaml.YAMLError, RecursionError) as error:
        if isinstance(error, yaml.YAMLError):
            notes.append(_syntax_problem(filename, printable, error))
        return _found_outputs(reader, _scan_lines(reader, printable), notes, doubts)
    if root is not None and not isinstance(root, yaml.MappingNode):
        return _found_outputs(reader, _scan_lines(reader, printable), notes, doubts)
    nodes = dict(reader.items(root, "", list(_SCHEMA))) if root is not None else {}
    if not nodes:
        doubts.append(Problem(filename, 0, 0, "", "names no section (an emptied file?)"))
    ours = {section: nodes[section] for section in _OUTPUT_SECTIONS if section in nodes}
    return _found_outputs(reader, ours, notes, doubts)


def _found_outputs(
    reader: _Reader,
    nodes: dict[str, yaml.Node],
    notes: list[Problem],
    doubts: list[Problem],
) -> FoundOutputs:
    """The sections' usable values and problems, once their nodes are found."""
    values = {section: reader.section(section, node) for section, node in nodes.items()}
    found = []
    for section in _OUTPUT_SECTIONS:
        refused = {}
        section_doubts = []
        for problem in reader.problems:
            if problem.key_path.split(".")[0] != section:
                continue
            if problem.key_path in reader.failed and problem.key_path != section:
                refused[problem.key_path.split(".")[1]] = problem
            else:
                section_doubts.append(problem)
        found.append(FoundOutput(section, values.get(section, {}), refused, section_doubts))
    doubts = doubts + [p for p in reader.problems if p.key_path.split(".")[0] not in _SCHEMA]
    return FoundOutputs(found[0], found[1], notes, doubts, found[2])


_HEADER = re.compile(r"[ \t]*(?P<name>[A-Za-z_][A-Za-z0-9_]*)[ \t]*:(?:[ \t]|$)")


def _scan_lines(reader: _Reader, text: str) -> dict[str, yaml.Node]:
    """The output sections of a text that is not YAML as a whole, found line by line.

    A section runs from its `name:` line (at any indentation) to the next line that is
    indented no deeper. Each is read as YAML on its own; failing that, line by line,
    and a line that cannot be read is a doubt about its section. A top-level line that
    is not a known section may hide an output section: a doubt about the whole file.
    """
    lines = text.splitlines()
    blocks: dict[str, list[int]] = {}
    current: tuple[str, int] | None = None  # the output section being read, its indentation
    for number, line in enumerate(lines):
        content = line.strip()
        if not content or content.startswith("#"):
            continue
        indent = len(line) - len(line.lstrip(" \t"))
        header = _HEADER.match(line)
        name = header["name"] if header else ""
        if name in _OUTPUT_SECTIONS:
            if name in blocks:
                reader.report(_mark(number), name, "the section is given twice (keep one)")
                current = None
            else:
                blocks[name] = [number]
                current = (name, indent)
        elif current is not None and indent > current[1]:
            blocks[current[0]].append(number)
        else:
            current = None
            if indent == 0 and name not in _SCHEMA and content not in ("---", "..."):
                reader.report(
                    _mark(number),
                    "",
                    "cannot tell which section this line is, so it may hold an output "
                    f"(the sections: {', '.join(_SCHEMA)})",
                )
    return {
        name: _section_node(reader, name, lines, numbers[0], numbers[-1])
        for name, numbers in blocks.items()
    }


def _mark(line_index: int) -> yaml.Mark:
    return yaml.Mark("", 0, line_index, 0, "", 0)


def _section_node(
    reader: _Reader, section: str, lines: list[str], first: int, last: int
) -> yaml.Node:
    """Lines `first` to `last` (a section) as a mapping node: as YAML, else line by line."""
    block = _mapping_pairs("\n" * first + "\n".join(lines[first : last + 1]), section)
    if block is not None:
        return block[0][1]
    readable: list[tuple[yaml.Node, yaml.Node]] = []
    header = _mapping_pairs("\n" * first + lines[first], section)
    if header is not None and isinstance(header[0][1], yaml.MappingNode):
        readable.extend(header[0][1].value)
    elif header is None or not _is_null(header[0][1]):
        reader.report(_mark(first), section, "this line cannot be read")
    for number in range(first + 1, last + 1):
        content = lines[number].strip()
        if not content or content.startswith("#"):
            continue
        indent = " " * (len(lines[number]) - len(lines[number].lstrip()))  # tabs too
        pairs = _mapping_pairs("\n" * number + indent + content, None)
        if pairs is None:
            reader.report(_mark(number), section, "this line cannot be read")
        else:
            readable.extend(pairs)
    return yaml.MappingNode(_RESOLVER.DEFAULT_MAPPING_TAG, readable)


def _mapping_pairs(text: str, key: str | None) -> list[tuple[yaml.Node, yaml.Node]] | None:
    """The pairs of a text that is one YAML mapping (of just `key`, if given), else None."""
    try:
        root = _compose(text)
    except (yaml.YAMLError, RecursionError):
        return None
    if not isinstance(root, yaml.MappingNode):
        return None
    pairs: list[tuple[yaml.Node, yaml.Node]] = root.value
    if key is not None:
        if len(pairs) != 1 or not isinstance(pairs[0][0], yaml.ScalarNode):
            return None
        if pairs[0][0].value != key:
            return None
    return pairs


def _is_null(node: yaml.Node) -> bool:
    return isinstance(node, yaml.ScalarNode) and node.style is None and node.value in _NULLS


def every_valid_value(key_path: str) -> list[object]:
    """Every value of a key that has few (choices, or a short range of whole numbers).

    The default comes first.
    """
    section, name = key_path.split(".")
    info = _SCHEMA[section][name]
    spec = info.spec
    if spec.choices:
        values = list(spec.choices)
    else:
        assert spec.low is not None
        assert spec.high is not None
        values = list(range(int(spec.low), int(spec.high) + 1))
    return [info.default, *(value for value in values if value != info.default)]


def key_range(key_path: str) -> tuple[float, float]:
    """The lowest and highest value a bounded numeric key accepts, as the file's check does."""
    section, name = key_path.split(".")
    spec = _SCHEMA[section][name].spec
    assert spec.low is not None
    assert spec.high is not None
    return spec.low, spec.high


def _read_text(filename: str) -> str:
    """The file's text; ConfigError when it cannot be read or is not UTF-8."""
    data = read_bytes(filename)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as error:
        raise ConfigError([_not_utf8(filename, data, error)]) from None


def _not_utf8(filename: str, data: bytes, error: UnicodeDecodeError) -> Problem:
    line_start = data.rfind(b"\n", 0, error.start) + 1
    line = data.count(b"\n", 0, error.start) + 1
    column = len(data[line_start : error.start].decode("utf-8", "replace")) + 1
    return Problem(
        filename,
        line,
        column,
        "",
        f"byte 0x{data[error.start]:02x} is not UTF-8 text (save the file as "
        "UTF-8; an editor set to Latin-1 writes '°' this way)",
    )


MAX_FILE_BYTES = 1 << 16
"""The largest config file read: over five times the shipped one (every key, commented).

Reading and parsing happen beside the control loop, in its process: the cap bounds how
long a reload can take CPU (and Python's one interpreter lock) from the loop.
"""
SHIPPED_FILE_MAX_BYTES = MAX_FILE_BYTES // 4
"""The shipped, fully commented file stays under a quarter of the cap: room for every key's
notes to grow, and a file past the cap is then far from any config (its message says so)."""


def read_bytes(filename: str) -> bytes:
    """A regular file's bytes, at most MAX_FILE_BYTES of them; ConfigError otherwise (see
    `files.read_regular`: a FIFO or a serial device is never opened)."""
    try:
        return read_regular(filename, MAX_FILE_BYTES)
    except OSError as error:
        raise ConfigError([Problem(filename, 0, 0, "", _unreadable(error))]) from None
    except NotRegularFile as error:
        if error.kind is not None:
            message = f"{error} (name the YAML file itself)"
        else:
            message = (
                f"is {error.size} bytes long, more than the {MAX_FILE_BYTES // 1024} KiB a "
                f"config file may be (the shipped one is under {SHIPPED_FILE_MAX_BYTES // 1024} "
                "KiB: is this the right file?)"
            )
        raise ConfigError([Problem(filename, 0, 0, "", message)]) from None


def _unreadable(error: OSError) -> str:
    if isinstance(error, FileNotFoundError):
        return "no such file (check the path, or copy config/hermsd.yaml there)"
    if isinstance(error, PermissionError):
        return "permission denied (make the file readable by the user hermsd runs as)"
    return f"cannot be read: {error.strerror or error} (check the file and its path)"


# -- writing a config back out --------------------------------------------------------------------


def to_dict(config: Config) -> dict[str, Any]:
    """The effective configuration as plain JSON-able data, for the log (lists as lists)."""
    return {
        section: {key: list(v) if isinstance(v, tuple) else v for key, v in values.items()}
        for section, values in dataclasses.asdict(config).items()
    }


class _Dumper(yaml.SafeDumper):
    """Quotes text that this module's plain-scalar grammar would read as something else."""


def _represent_text(dumper: yaml.SafeDumper, text: str) -> yaml.ScalarNode:
    plain_is_text = not _reads_as_number(text) and isinstance(_plain_value(text), str)
    style = None if plain_is_text else "'"
    return dumper.represent_scalar("tag:yaml.org,2002:str", text, style=style)


_Dumper.add_representer(str, _represent_text)


def dump_yaml(config: Config) -> str:
    """The effective configuration as YAML that `parse` reads back to the same Config."""
    return _yaml_text(to_dict(config))


def _yaml_text(data: Any) -> str:
    return yaml.dump(
        data, Dumper=_Dumper, sort_keys=False, default_flow_style=False, allow_unicode=True
    )


def value_at(config: Config, path: str) -> Any:
    """The value of `section.key` in `config`."""
    section, name = path.split(".")
    return getattr(getattr(config, section), name)


def differences(old: Config, new: Config) -> list[str]:
    """Every `section.key` whose value differs between two configs, in file order."""
    return [
        f"{section}.{name}"
        for section, fields in _SCHEMA.items()
        for name in fields
        if value_at(old, f"{section}.{name}") != value_at(new, f"{section}.{name}")
    ]


def from_dict(data: Any, source: str = "<logged config>") -> Config:
    """The Config whose `to_dict` a log holds, checked like a file (ConfigError if it is not).

    A log from another version may hold keys this one does not know, or values it refuses:
    they are reported, not guessed at, since replay must run the controller that ran.
    """
    return parse(_yaml_text(data), source)


def restart_keys_changed(old: Config, new: Config) -> list[str]:
    """The keys in RESTART_KEYS whose values differ: a reload cannot apply them."""
    return [path for path in RESTART_KEYS if value_at(old, path) != value_at(new, path)]


def keep_restart_keys(running: Config, edited: Config) -> Config:
    """`edited` with the running values of every key a reload cannot apply."""
    sections: dict[str, dict[str, Any]] = {}
    for path in restart_keys_changed(running, edited):
        section, name = path.split(".")
        sections.setdefault(section, {})[name] = value_at(running, path)
    return dataclasses.replace(
        edited,
        **{
            section: dataclasses.replace(getattr(edited, section), **values)
            for section, values in sections.items()
        },
    )


def on_simulated_tun(config: Config) -> Config:
    """`config` as a simulated run runs it: the SSR, and the second element when one is
    fitted, are the simulated tun's whatever hardware the file names (a brewer tries the
    service's own file), so that what the run logs and prints names them truly."""
    element2 = config.element2
    if element2.backend != "none":
        element2 = dataclasses.replace(element2, backend="sim")
    output = dataclasses.replace(config.output, backend="sim")
    return dataclasses.replace(config, output=output, element2=element2)


def broken_rules(config: Config) -> list[str]:
    """The rules between keys that `config` breaks, as 'key: what is wrong' lines."""
    return [f"{v.keys[0]}: {v.said(v.keys[0])}" for v in _violations(config)]


def runtime_problems(running: Config, changes: dict[str, object]) -> list[str]:
    """Why an operator's runtime change of keys cannot apply to `running`; [] when it can.

    Each value is checked as the file's would be (the same bounds, choices and messages),
    then the rules across keys with every other value as in `running` (the config with the
    values in force). 'key: what is wrong (what would be right)' lines.
    """
    problems: list[str] = []
    values: dict[str, dict[str, object]] = {}
    for path, value in changes.items():
        section, name = path.split(".")
        try:
            checked = _convert(_SCHEMA[section][name], _runtime_node(value))
        except _Invalid as error:
            problems.append(f"{path}: {error}")
            continue
        values.setdefault(section, {})[name] = checked
    if problems:
        return problems
    candidate = dataclasses.replace(
        running,
        **{
            section: dataclasses.replace(getattr(running, section), **fields)
            for section, fields in values.items()
        },
    )
    return broken_rules(candidate)


def _runtime_node(value: object) -> yaml.ScalarNode:
    """A value given at runtime as the file would hold it: a number plain, text quoted."""
    style = "'" if isinstance(value, str) else None
    text = (
        value if isinstance(value, str) else _fmt(value) if isinstance(value, float) else str(value)
    )
    implicit = (style is None, style is not None)
    tag = _RESOLVER.resolve(yaml.ScalarNode, text, implicit)  # type: ignore[no-untyped-call]
    return yaml.ScalarNode(tag, text, style=style)
