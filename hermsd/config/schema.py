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
import re
import typing
from dataclasses import dataclass, field
from typing import NamedTuple, TypeVar

import yaml

from hermsd.control import pid
from hermsd.control.pid import ALGORITHMS, DEFAULT_ALGORITHM

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


SENSOR_KINDS: tuple[str, ...] = ("lm92", "ds18b20", "max31865")
NOT_FITTED = "none"


@dataclass(frozen=True, slots=True)
class SensorKeys:
    """Which chip a sensor is, where it sits and its calibration: every sensor's keys."""

    bus: int = _integer(1, 0, 255)
    address: int = _integer(0x48, 0x48, 0x4B, as_hex=True)
    kind: str = _choice("lm92", SENSOR_KINDS)
    id: str | None = _text(None, max_length=64, null_means="the one DS18B20 found")
    w1_root: str = _text("/sys/bus/w1/devices")
    device: int = _integer(0, 0, 255)
    r0: float = _number(100.0, 10, 10000, "Ω")
    rref: float = _number(430.0, 10, 100000, "Ω")
    wires: int = _choice(3, (2, 3, 4))
    filter_hz: int = _choice(50, (50, 60))
    offset: float = _number(0.0, -5, 5, "°C")


@dataclass(frozen=True, slots=True)
class SensorConfig(SensorKeys):
    """The HLT's sensor, the one the heater is controlled and guarded by; its read interval
    is every sensor's."""

    read_interval: float = _number(1.0, 0.5, 10, "s")


@dataclass(frozen=True, slots=True)
class RoleSensorConfig(SensorKeys):
    """A sensor beside the HLT's (the mash's, the coil outlet's): the same keys, read at
    `sensor.read_interval`, not fitted unless its kind is named."""

    kind: str = _choice(NOT_FITTED, (NOT_FITTED, *SENSOR_KINDS))

    @property
    def fitted(self) -> bool:
        return self.kind != NOT_FITTED


ROLE_SENSORS: dict[str, str] = {"mash_sensor": "mash", "coil_sensor": "coil outlet"}
"""The config's sections of the sensors beside the HLT's, and the role each is read in."""


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
    swing: float = _number(0.0, 0, 1, "°C")


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
class PumpConfig:
    """The HERMS pump that carries the wort from the mash tun through the HLT's coil and
    back: switched on and off as commanded, off whenever hermsd is not running. One hermsd
    does not switch (`backend: none`) may be seen running through a contact (`sense`)."""

    backend: str = _choice(NOT_FITTED, (NOT_FITTED, "sim", "gpio", "relay-board"))
    port: str = _text("/dev/ttyUSB1")
    chip: str = _text("/dev/gpiochip0")
    line: int | None = _integer(None, 0, 511, null_means="none (only the gpio backend uses it)")
    active_low: bool = False
    channel: int = _integer(3, 1, 8)
    baud: int = _choice(9600, (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200))
    sense: str = _choice(NOT_FITTED, (NOT_FITTED, "gpio", "sim"))
    sense_chip: str = _text("/dev/gpiochip0")
    sense_line: int | None = _integer(None, 0, 511, null_means="none (only the gpio sense uses it)")
    sense_active_low: bool = False


ADS1115_INPUTS = ("a0-a1", "a0-a3", "a1-a3", "a2-a3", "a0", "a1", "a2", "a3")
"""The ADS1115's input multiplexer settings (config register MUX, 000..111 in this order)."""
ADS1115_RANGES = (6.144, 4.096, 2.048, 1.024, 0.512, 0.256)
"""The ADS1115's full-scale ranges, ±V (config register PGA, 000..101 in this order)."""


@dataclass(frozen=True, slots=True)
class CurrentConfig:
    """Whether the SSR's element draws current (docs/safety.md, "The element's current"): a
    current transformer into an ADS1115 (`ads1115`), a mains-present optocoupler across the
    element on a GPIO input (`gpio`: tells a shorted SSR or a dead SSR, contactor or fuse, not
    an open element), or the simulator's circuit (`sim`)."""

    kind: str = _choice(NOT_FITTED, (NOT_FITTED, "ads1115", "gpio", "sim"))
    bus: int = _integer(1, 0, 255)
    address: int = _integer(0x49, 0x48, 0x4B, as_hex=True)  # ADDR to VDD: the LM92 has 0x48
    input: str = _choice("a0-a1", ADS1115_INPUTS)
    range: float = _choice(1.024, ADS1115_RANGES)
    amps_per_volt: float = _number(30.0, 0.1, 1000, "A/V")
    threshold: float = _number(1.0, 0.0, 100, "A", low_exclusive=True)
    chip: str = _text("/dev/gpiochip0")
    line: int | None = _integer(None, 0, 511, null_means="none (only the gpio kind uses it)")
    active_low: bool = False

    @property
    def fitted(self) -> bool:
        return self.kind != NOT_FITTED


@dataclass(frozen=True, slots=True)
class HermsConfig:
    """What holding the mash through the HLT's coil needs to know beyond the HLT."""

    # At most this far above the mash at the coil's outlet: the enzymes' protection.
    max_hlt_above_mash: float = _number(10.0, 1, 20, "°C")
    # The outer loop's model (docs/mash-control.md): the coil's conductance before the day's
    # pump runs teach it, the mash's water and grain, a LOW guess of the tun's losses, the
    # wort's round trip through the hoses and the mash sensor's lag.
    coil_w_per_k: float = _number(200.0, 10, 2000, "W/K")
    mash_litres: float = _number(30.0, 1, 500, "L")
    grain_kg: float = _number(7.0, 0, 200, "kg")
    mash_loss_w_per_k: float = _number(3.0, 0, 100, "W/K")
    hose_s: float = _number(20.0, 0, 600, "s")
    mash_sensor_lag: float = _number(10.0, 0, 600, "s")
    # The most the pump moves through the coil: the safety's bound on the coil's load.
    max_coil_flow: float = _number(12.0, 1, 60, "L/min")


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
    mash_sensor: RoleSensorConfig = field(default_factory=RoleSensorConfig)
    coil_sensor: RoleSensorConfig = field(default_factory=RoleSensorConfig)
    output: OutputConfig = field(default_factory=OutputConfig)
    contactor: ContactorConfig = field(default_factory=ContactorConfig)
    element2: Element2Config = field(default_factory=Element2Config)
    pump: PumpConfig = field(default_factory=PumpConfig)
    current: CurrentConfig = field(default_factory=CurrentConfig)
    herms: HermsConfig = field(default_factory=HermsConfig)
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
    *(f"sensor.{f.name}" for f in dataclasses.fields(SensorConfig)),
    *(f"{role}.{f.name}" for role in ROLE_SENSORS for f in dataclasses.fields(RoleSensorConfig)),
    "output.backend",
    "output.port",
    "output.chip",
    "output.line",
    "output.active_low",
    "output.window",
    *(f"contactor.{f.name}" for f in dataclasses.fields(ContactorConfig)),
    *(f"element2.{f.name}" for f in dataclasses.fields(Element2Config)),
    *(f"pump.{f.name}" for f in dataclasses.fields(PumpConfig)),
    *(f"current.{f.name}" for f in dataclasses.fields(CurrentConfig)),
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


# -- reading a document ---------------------------------------------------------------------------


# -- writing a config back out --------------------------------------------------------------------


def _is_null(node: yaml.Node) -> bool:
    return isinstance(node, yaml.ScalarNode) and node.style is None and node.value in _NULLS
