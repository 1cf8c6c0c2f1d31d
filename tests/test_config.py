"""The configuration file: defaults, bounds, rules between keys, and messages a brewer can act on.

The schema is written out again below from the specification (not read from hermsd.config),
so a bound that drifts in the module, in the shipped file or in its comments fails here.
"""

from __future__ import annotations

import dataclasses
import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from hermsd.config.read import dump_yaml, from_dict, load, parse, restart_keys_changed, to_dict
from hermsd.config.schema import ALGORITHM_NAMES, DEFAULT, Config, ConfigError, Problem, TunConfig

CONFIG_FILE = Path(__file__).resolve().parents[1] / "config" / "hermsd.yaml"
TWO_ELEMENTS_DOC = Path(__file__).resolve().parents[1] / "docs" / "two-elements.md"
SENSORS_DOC = TWO_ELEMENTS_DOC.with_name("sensors.md")
HERMS_DOC = TWO_ELEMENTS_DOC.with_name("herms.md")
CURRENT_DOC = TWO_ELEMENTS_DOC.with_name("current.md")
FAST_FUZZ = settings(max_examples=200, deadline=None)


# -- the specification, restated ------------------------------------------------------------


@dataclass(frozen=True)
class Bound:
    """One numeric key: its type, range and whether null is allowed."""

    key: str
    kind: type
    low: float
    high: float | None
    low_open: bool = False  # the low end itself is refused ("> 0")
    nullable: bool = False
    zero_ok: bool = False  # 0 is accepted below the range (ti: 0 = no integral)


ROLES = ("mash_sensor", "coil_sensor")
BOUNDS = [
    Bound("tun.litres", float, 1, 1000),
    Bound("tun.element_watts", float, 100, 20000),
    Bound("control.setpoint", float, 0, 100),
    Bound("control.manual_output", float, 0, 100),
    Bound("control.kc", float, 0, 10000, low_open=True),
    Bound("control.ti", float, 1, 100000, zero_ok=True),
    Bound("control.td", float, 0, 10000),
    Bound("control.tf", float, 0, 10000, nullable=True),
    Bound("control.tt", float, 1, 100000, nullable=True),
    Bound("control.period", float, 1, 60),
    Bound("control.max_output", float, 1, 100),
    Bound("control.model_gain", float, 0.01, 100),
    Bound("control.model_tau", float, 10, 1000000),
    Bound("control.dead_time", float, 0, 1800),
    Bound("control.model_ambient", float, -20, 50),
    Bound("control.k1", float, 0, 10000, low_open=True),
    Bound("control.ti1", float, 1, 100000),
    Bound("control.tt1", float, 1, 100000, nullable=True),
    Bound("control.k2", float, 0, 100, low_open=True),
    Bound("control.ti2", float, 1, 100000),
    Bound("control.tt2", float, 1, 100000, nullable=True),
    Bound("control.ks", float, 0, 1000),
    Bound("control.u1_ref", float, 1, 99),
    Bound("control.u2_min", float, 0, 100),
    Bound("control.u2_max", float, 0, 100, low_open=True),
    Bound("control.model_litres", float, 1, 1000, nullable=True),
    Bound("sensor.bus", int, 0, 255),
    Bound("sensor.address", int, 0x48, 0x4B),
    Bound("sensor.read_interval", float, 0.5, 10),
    Bound("sensor.device", int, 0, 255),
    Bound("sensor.r0", float, 10, 10000),
    Bound("sensor.rref", float, 10, 100000),
    Bound("sensor.offset", float, -5, 5),
    *(
        bound
        for role in ROLES
        for bound in (
            Bound(f"{role}.bus", int, 0, 255),
            Bound(f"{role}.address", int, 0x48, 0x4B),
            Bound(f"{role}.device", int, 0, 255),
            Bound(f"{role}.r0", float, 10, 10000),
            Bound(f"{role}.rref", float, 10, 100000),
            Bound(f"{role}.offset", float, -5, 5),
        )
    ),
    Bound("pump.line", int, 0, 511, nullable=True),
    Bound("pump.channel", int, 1, 8),
    Bound("pump.sense_line", int, 0, 511, nullable=True),
    Bound("current.bus", int, 0, 255),
    Bound("current.address", int, 0x48, 0x4B),
    Bound("current.amps_per_volt", float, 0.1, 1000),
    Bound("current.threshold", float, 0, 100, low_open=True),
    Bound("current.line", int, 0, 511, nullable=True),
    Bound("herms.max_hlt_above_mash", float, 1, 20),
    Bound("herms.coil_w_per_k", float, 10, 2000),
    Bound("herms.mash_litres", float, 1, 500),
    Bound("herms.grain_kg", float, 0, 200),
    Bound("herms.mash_loss_w_per_k", float, 0, 100),
    Bound("herms.hose_s", float, 0, 600),
    Bound("herms.mash_sensor_lag", float, 0, 600),
    Bound("herms.max_coil_flow", float, 1, 60),
    Bound("output.line", int, 0, 511, nullable=True),
    Bound("output.window", float, 1, 60, nullable=True),
    Bound("output.min_on", float, 0, 10),
    Bound("output.min_off", float, 0, 10),
    Bound("output.swing", float, 0, 1),
    Bound("contactor.line", int, 0, 511, nullable=True),
    Bound("contactor.channel", int, 1, 8),
    Bound("element2.line", int, 0, 511, nullable=True),
    Bound("element2.channel", int, 1, 8),
    Bound("element2.watts", float, 100, 20000),
    Bound("element2.min_on", float, 5, 3600),
    Bound("element2.min_off", float, 5, 3600),
    Bound("safety.max_temp", float, 30, 105),
    Bound("safety.hysteresis", float, 0.5, 30),
    Bound("safety.plausible_min", float, -55, 150),
    Bound("safety.plausible_max", float, -55, 150),
    Bound("safety.max_step", float, 0, 50, low_open=True, nullable=True),
    Bound("safety.fault_reads", int, 1, 10),
    Bound("safety.resume_reads", int, 1, 100),
    Bound("safety.stale_after", float, 1, 60, nullable=True),
    Bound("safety.dead_time", float, 10, 3600, nullable=True),
    Bound("safety.heater_watch", float, 30, 7200, nullable=True),
    Bound("safety.heater_min_rise", float, 0, 50, low_open=True, nullable=True),
    Bound("safety.ssr_watch", float, 30, 7200, nullable=True),
    Bound("safety.ssr_max_rise", float, 0, 50, low_open=True, nullable=True),
    Bound("safety.dry_fire_factor", float, 1.5, 100),
    Bound("safety.stuck_time", float, 60, 86400),
    Bound("safety.stuck_output_change", float, 1, 100),
    Bound("safety.stall_periods", float, 0.5, 100),
    Bound("safety.reset", int, 0, None),
    Bound("log.rotate_hours", float, 0.1, 168),
    Bound("log.flush_interval", float, 0.1, 2),
    Bound("log.sync_interval", float, 0.1, 60),
    Bound("log.queue_size", int, 100, 1000000),
    Bound("alerts.timeout", float, 1, 300),
    Bound("alerts.min_interval", float, 0, 86400),
    Bound("web.session_lifetime", float, 0.1, 720),
    Bound("mqtt.port", int, 1, 65535),
]
CHOICES: dict[str, tuple[object, ...]] = {
    "control.mode": ("auto", "manual"),
    "tun.lid": ("on", "off"),
    "control.learn": ("on", "pinned", "off"),
    "control.algorithm": (
        "predictive",
        "type_a",
        "type_a_filtered",
        "takahashi",
        "back_calculation",
        "velocity_pi",
        "midrange",
    ),
    "output.backend": ("sim", "serial-rts", "serial-dtr", "gpio"),
    "output.mains_hz": (50, 60),
    "contactor.backend": ("none", "gpio", "serial-rts", "serial-dtr", "relay-board"),
    "contactor.baud": (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200),
    "element2.backend": ("none", "sim", "gpio", "serial-rts", "serial-dtr", "relay-board"),
    "element2.baud": (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200),
    "web.read_only_view": ("on", "off"),
    "sensor.kind": ("lm92", "ds18b20", "max31865"),
    "sensor.wires": (3, 2, 4),
    "sensor.filter_hz": (50, 60),
    **{f"{role}.kind": ("none", "lm92", "ds18b20", "max31865") for role in ROLES},
    **{f"{role}.wires": (3, 2, 4) for role in ROLES},
    **{f"{role}.filter_hz": (50, 60) for role in ROLES},
    "pump.backend": ("none", "sim", "gpio", "relay-board"),
    "pump.baud": (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200),
    "pump.sense": ("none", "gpio", "sim"),
    "current.kind": ("none", "ads1115", "gpio", "sim"),
    "current.input": ("a0-a1", "a0-a3", "a1-a3", "a2-a3", "a0", "a1", "a2", "a3"),
    "current.range": (1.024, 6.144, 4.096, 2.048, 0.512, 0.256),
}
TEXTS = {  # key: (longest, nullable)
    "tun.name": (32, False),
    "output.port": (None, False),
    "output.chip": (None, False),
    "contactor.port": (None, False),
    "contactor.chip": (None, False),
    "element2.port": (None, False),
    "element2.chip": (None, False),
    "log.dir": (None, True),
    "web.listen": (300, False),
    "web.password_hash": (None, True),
    "mqtt.host": (253, False),
    "mqtt.username": (256, True),
    "mqtt.password_file": (None, True),
    "mqtt.ca_file": (None, True),
    "mqtt.cert_file": (None, True),
    "mqtt.key_file": (None, True),
    "mqtt.topic_prefix": (100, False),
    "mqtt.discovery_prefix": (100, False),
    "mqtt.client_id": (64, True),
    "sensor.id": (64, True),
    "sensor.w1_root": (None, False),
    **{f"{role}.id": (64, True) for role in ROLES},
    **{f"{role}.w1_root": (None, False) for role in ROLES},
    "pump.port": (None, False),
    "pump.chip": (None, False),
    "pump.sense_chip": (None, False),
    "current.chip": (None, False),
}
FLAGS = (
    "output.active_low",
    "contactor.active_low",
    "element2.active_low",
    "element2.check",
    "pump.active_low",
    "pump.sense_active_low",
    "current.active_low",
    "mqtt.tls",
)
ALERT_EVENTS = (
    "alarm_raised",
    "alarm_cleared",
    "started",
    "stopped",
    "element_warning",
    "setpoint_unreachable",
    "step_reached",
    "step_done",
    "waiting",
    "finished",
    "late",
)
LISTS = {  # key: (the items it may hold, or () for any printable text; nullable)
    "alerts.command": ((), True),
    "alerts.events": (ALERT_EVENTS, False),
    "web.allowed_hosts": ((), True),
}
RESTART = [
    "control.period",
    "sensor.bus",
    "sensor.address",
    "sensor.read_interval",
    "sensor.kind",
    "sensor.id",
    "sensor.w1_root",
    "sensor.device",
    "sensor.r0",
    "sensor.rref",
    "sensor.wires",
    "sensor.filter_hz",
    "sensor.offset",
    "output.backend",
    "output.port",
    "output.chip",
    "output.line",
    "output.active_low",
    "output.window",
    "contactor.backend",
    "contactor.port",
    "contactor.chip",
    "contactor.line",
    "contactor.active_low",
    "contactor.channel",
    "contactor.baud",
    *(
        f"element2.{key}"
        for key in (
            "backend",
            "port",
            "chip",
            "line",
            "active_low",
            "channel",
            "baud",
            "watts",
            "min_on",
            "min_off",
            "check",
        )
    ),
    *(
        f"{role}.{key}"
        for role in ROLES
        for key in (
            *("bus", "address", "kind", "id", "w1_root", "device", "r0", "rref", "wires"),
            *("filter_hz", "offset"),
        )
    ),
    *(
        f"pump.{key}"
        for key in ("backend", "port", "chip", "line", "active_low", "channel", "baud")
    ),
    *(f"pump.{key}" for key in ("sense", "sense_chip", "sense_line", "sense_active_low")),
    *(f"current.{key}" for key in ("kind", "bus", "address", "input", "range")),
    *(f"current.{key}" for key in ("amps_per_volt", "threshold", "chip", "line", "active_low")),
    "log.dir",
    "log.rotate_hours",
    "log.flush_interval",
    "log.sync_interval",
    "log.queue_size",
]
ALL_KEYS = [b.key for b in BOUNDS] + list(CHOICES) + list(TEXTS) + list(FLAGS) + list(LISTS)
SERIAL = ("serial-rts", "serial-dtr")


def value_at(config: Config, key: str) -> Any:
    section, name = key.split(".")
    return getattr(getattr(config, section), name)


def assert_within_spec(config: Config) -> None:
    """Every bound and every rule between keys of the specification holds for `config`."""
    for bound in BOUNDS:
        value = value_at(config, bound.key)
        if value is None:
            assert bound.nullable, bound.key
            continue
        assert type(value) is bound.kind, bound.key
        if bound.zero_ok and value == 0:
            continue
        assert value > bound.low if bound.low_open else value >= bound.low, bound.key
        assert bound.high is None or value <= bound.high, bound.key
    for key, choices in CHOICES.items():
        assert value_at(config, key) in choices, key
    for key, (longest, nullable) in TEXTS.items():
        text = value_at(config, key)
        if text is None:
            assert nullable, key
            continue
        assert isinstance(text, str), key
        assert text, key
        assert text.isprintable(), key
        assert longest is None or len(text) <= longest, key
    for key in FLAGS:
        assert type(value_at(config, key)) is bool, key
    for key, (items, nullable) in LISTS.items():
        words = value_at(config, key)
        if words is None:
            assert nullable, key
            continue
        assert type(words) is tuple and words, key
        assert all(isinstance(w, str) and w and w.isprintable() for w in words), key
        assert not items or (set(words) <= set(items) and len(set(words)) == len(words)), key

    c, o, k, s = config.control, config.output, config.contactor, config.safety
    half_cycle = 1 / (2 * o.mains_hz)
    window = o.window if o.window is not None else c.period
    assert window > o.min_on + o.min_off
    assert window >= 5 * half_cycle
    assert o.min_on == 0 or o.min_on >= half_cycle
    assert o.min_off == 0 or o.min_off >= half_cycle
    assert c.setpoint < s.max_temp
    assert s.plausible_min < s.plausible_max
    assert s.max_temp < s.plausible_max
    assert c.manual_output <= c.max_output
    assert o.backend != "gpio" or o.line is not None
    assert k.backend != "gpio" or k.line is not None
    if o.backend in SERIAL and o.port == k.port:
        assert k.backend != o.backend
        assert k.backend != "relay-board"
    if o.backend == k.backend == "gpio":
        assert (o.chip, o.line) != (k.chip, k.line)
    assert s.stale_after is None or s.stale_after > config.sensor.read_interval


def document(values: dict[str, str]) -> str:
    """A config text setting `values` ({"control.setpoint": "70"}), one section per prefix."""
    sections: dict[str, list[str]] = {}
    for key, value in values.items():
        section, name = key.split(".")
        sections.setdefault(section, []).append(f"  {name}: {value}\n")
    return "".join(f"{section}:\n" + "".join(lines) for section, lines in sections.items())


def position(text: str, key: str, *, of_key: bool = False) -> tuple[int, int]:
    """1-based line and column of the value (or the key) of the first `key` in `text`."""
    section, name = key.split(".")
    lines = text.splitlines()
    start = lines.index(f"{section}:")
    for number, line in enumerate(lines[start + 1 :], start + 2):
        if line.startswith(f"  {name}:"):
            if of_key:
                return number, 3
            return number, len(f"  {name}: ") + 1
    raise AssertionError(f"{key} not in text")


def problems_of(text: str) -> list[Problem]:
    with pytest.raises(ConfigError) as caught:
        parse(text, "hermsd.yaml")
    return caught.value.problems


def only_problem(text: str) -> Problem:
    problems = problems_of(text)
    assert len(problems) == 1, problems
    return problems[0]


def fmt(number: float) -> str:
    return str(int(number)) if float(number).is_integer() else str(number)


# -- defaults and the shipped file ------------------------------------------------------------


def test_the_restated_schema_covers_every_field() -> None:
    fields = [
        f"{section.name}.{f.name}"
        for section in dataclasses.fields(Config)
        for f in dataclasses.fields(getattr(DEFAULT, section.name))
    ]
    assert sorted(fields) == sorted(ALL_KEYS)


def test_defaults_are_the_specified_ones() -> None:
    expected = {
        "tun": {"name": "HLT", "litres": 90.0, "element_watts": 3000.0, "lid": "on"},
        "control": {
            "setpoint": 66.0,
            "mode": "auto",
            "manual_output": 0.0,
            "algorithm": "predictive",
            "kc": 120.0,
            "ti": 800.0,
            "td": 0.0,
            "tf": None,
            "tt": None,
            "period": 5.0,
            "max_output": 100.0,
            "model_gain": 1.689,
            "model_tau": 14961.0,
            "dead_time": 115.0,
            "model_ambient": 20.0,
            "model_litres": None,
            "learn": "on",
            "k1": 120.0,
            "ti1": 800.0,
            "tt1": 100.0,
            "k2": 2.0,
            "ti2": 600.0,
            "tt2": None,
            "ks": 10.0,
            "u1_ref": 70.0,
            "u2_min": 0.0,
            "u2_max": 100.0,
        },
        "sensor": {
            "bus": 1,
            "address": 0x48,
            "read_interval": 1.0,
            "kind": "lm92",
            "id": None,
            "w1_root": "/sys/bus/w1/devices",
            "device": 0,
            "r0": 100.0,
            "rref": 430.0,
            "wires": 3,
            "filter_hz": 50,
            "offset": 0.0,
        },
        "output": {
            "backend": "serial-rts",
            "port": "/dev/ttyUSB0",
            "chip": "/dev/gpiochip0",
            "line": None,
            "active_low": False,
            "window": None,
            "mains_hz": 50,
            "min_on": 0.02,
            "min_off": 0.02,
            "swing": 0.0,
        },
        "contactor": {
            "backend": "none",
            "port": "/dev/ttyUSB1",
            "chip": "/dev/gpiochip0",
            "line": None,
            "active_low": False,
            "channel": 1,
            "baud": 9600,
        },
        "element2": {
            "backend": "none",
            "port": "/dev/ttyUSB2",
            "chip": "/dev/gpiochip0",
            "line": None,
            "active_low": False,
            "channel": 2,
            "baud": 9600,
            "watts": 3500.0,
            "min_on": 120.0,
            "min_off": 120.0,
            "check": True,
        },
        **{
            role: {
                "bus": 1,
                "address": 0x48,
                "kind": "none",
                "id": None,
                "w1_root": "/sys/bus/w1/devices",
                "device": 0,
                "r0": 100.0,
                "rref": 430.0,
                "wires": 3,
                "filter_hz": 50,
                "offset": 0.0,
            }
            for role in ROLES
        },
        "pump": {
            "backend": "none",
            "port": "/dev/ttyUSB1",
            "chip": "/dev/gpiochip0",
            "line": None,
            "active_low": False,
            "channel": 3,
            "baud": 9600,
            "sense": "none",
            "sense_chip": "/dev/gpiochip0",
            "sense_line": None,
            "sense_active_low": False,
        },
        "current": {
            "kind": "none",
            "bus": 1,
            "address": 0x49,
            "input": "a0-a1",
            "range": 1.024,
            "amps_per_volt": 30.0,
            "threshold": 1.0,
            "chip": "/dev/gpiochip0",
            "line": None,
            "active_low": False,
        },
        "herms": {
            "max_hlt_above_mash": 10.0,
            "max_coil_flow": 12.0,
            "coil_w_per_k": 200.0,
            "mash_litres": 30.0,
            "grain_kg": 7.0,
            "mash_loss_w_per_k": 3.0,
            "hose_s": 20.0,
            "mash_sensor_lag": 10.0,
        },
        "safety": {
            "max_temp": 95.0,
            "hysteresis": 5.0,
            "plausible_min": -10.0,
            "plausible_max": 110.0,
            "max_step": None,
            "fault_reads": 2,
            "resume_reads": 5,
            "stale_after": None,
            "dead_time": None,
            "heater_watch": None,
            "heater_min_rise": None,
            "ssr_watch": None,
            "ssr_max_rise": None,
            "dry_fire_factor": 3.0,
            "stuck_time": 600.0,
            "stuck_output_change": 40.0,
            "stall_periods": 2.0,
            "reset": 0,
        },
        "log": {
            "dir": "/var/log/hermsd",
            "rotate_hours": 24.0,
            "flush_interval": 2.0,
            "sync_interval": 10.0,
            "queue_size": 10000,
        },
        "alerts": {
            "command": None,
            "events": list(ALERT_EVENTS),
            "timeout": 10.0,
            "min_interval": 60.0,
        },
        "web": {
            "listen": "127.0.0.1:8080",
            "password_hash": None,
            "session_lifetime": 12.0,
            "read_only_view": "off",
            "allowed_hosts": None,
        },
        "mqtt": {
            "host": "localhost",
            "port": 1883,
            "username": None,
            "password_file": None,
            "tls": False,
            "ca_file": None,
            "cert_file": None,
            "key_file": None,
            "topic_prefix": "hermsd",
            "discovery_prefix": "homeassistant",
            "client_id": None,
        },
    }
    assert to_dict(DEFAULT) == expected
    assert_within_spec(DEFAULT)
    assert CHOICES["control.algorithm"] == ALGORITHM_NAMES


def test_config_is_frozen() -> None:
    with pytest.raises(dataclasses.FrozenInstanceError):
        DEFAULT.control.setpoint = 70.0  # type: ignore[misc]


@pytest.mark.parametrize(
    "text", ["", "\n", "# only a comment\n", "tun:\n", "tun:\n  # name: HLT\nlog:\n"]
)
def test_empty_file_and_empty_sections_give_the_defaults(text: str) -> None:
    assert parse(text) == DEFAULT


def test_the_shipped_file_is_exactly_the_defaults() -> None:
    assert load(CONFIG_FILE) == DEFAULT


def _comment_blocks() -> dict[str, str]:
    """For each key of the shipped file, the comment lines directly above it (and inline)."""
    blocks: dict[str, str] = {}
    section = ""
    comment: list[str] = []
    for line in CONFIG_FILE.read_text(encoding="utf-8").splitlines():
        if re.fullmatch(r"[a-z0-9_]+:", line):
            section, comment = line[:-1], []
        elif line.lstrip().startswith("#"):
            comment.append(line.strip().lstrip("#").strip())
        elif match := re.match(r"  ([a-z0-9_]+):(.*)", line):
            inline = match[2].split(" #", 1)[1] if " #" in match[2] else ""
            blocks[f"{section}.{match[1]}"] = " ".join([*comment, inline]).strip()
            comment = []
        else:
            comment = []
    return blocks


def _two_element_rows(doc: Path = TWO_ELEMENTS_DOC) -> dict[str, tuple[str, str]]:
    """The keys docs/two-elements.md documents in its tables (the mid-ranging controller's
    and section element2: kept out of the shipped file), each with its default and text;
    or those of another doc written the same way (docs/sensors.md, docs/herms.md). A heading
    naming two sections (`mash_sensor` and `coil_sensor`) heads a table of both."""
    rows: dict[str, tuple[str, str]] = {}
    sections: list[str] = []
    for line in doc.read_text(encoding="utf-8").splitlines():
        if heading := re.match(r"## ((?:`[a-z0-9_]+`(?: and )?)+)", line):
            sections = re.findall(r"`([a-z0-9_]+)`", heading[1])
        elif row := re.fullmatch(r"\| `([a-z0-9_]+)` \| ([^|]*) \| (.*) \|", line):
            rows.update({f"{section}.{row[1]}": (row[2], row[3]) for section in sections})
    return rows


def _documented() -> dict[str, str]:
    """Every key's documentation: its comment in the shipped file, else its table row."""
    tables = _two_element_rows() | _two_element_rows(SENSORS_DOC) | _two_element_rows(HERMS_DOC)
    tables |= _two_element_rows(CURRENT_DOC)
    rows = {key: f"{text} |" for key, (_default, text) in tables.items()}
    return _comment_blocks() | rows


def test_the_sensor_keys_are_documented_with_their_defaults_outside_the_file() -> None:
    rows = _two_element_rows(SENSORS_DOC) | _two_element_rows(HERMS_DOC)
    assert not set(rows) & set(_comment_blocks())
    sections = {key.split(".")[0] for key in rows}
    assert sections == {"sensor", *ROLES, "pump", "herms"}
    for key, (default, _text) in rows.items():
        section, name = key.split(".")
        assert yaml.safe_load(default) == getattr(getattr(DEFAULT, section), name), key


def test_the_current_keys_are_documented_with_their_defaults_outside_the_file() -> None:
    rows = _two_element_rows(CURRENT_DOC)
    assert not set(rows) & set(_comment_blocks())
    assert {key.split(".")[0] for key in rows} == {"current"}
    for key, (default, _text) in rows.items():
        section, name = key.split(".")
        assert yaml.safe_load(default) == getattr(getattr(DEFAULT, section), name), key


def test_the_two_element_keys_are_documented_with_their_defaults_outside_the_file() -> None:
    rows = _two_element_rows()
    assert not set(rows) & set(_comment_blocks())
    assert {key.split(".")[0] for key in rows} == {"control", "element2"}
    for key, (default, _text) in rows.items():
        section, name = key.split(".")
        assert yaml.safe_load(default) == getattr(getattr(DEFAULT, section), name), key


def test_every_key_in_the_shipped_file_has_a_comment_with_its_range() -> None:
    blocks = _documented()
    assert sorted(blocks) == sorted(ALL_KEYS)
    for key, comment in blocks.items():
        assert len(comment) > 20, key
    for bound in BOUNDS:
        comment = blocks[bound.key]
        if bound.key.endswith(".address"):
            assert "0x48 to 0x4B" in comment
            continue
        if bound.high is None:
            written = f"{fmt(bound.low)} or more"
        elif bound.low_open:
            written = f"above {fmt(bound.low)}, at most {fmt(bound.high)}"
        else:
            written = f"{fmt(bound.low)} to {fmt(bound.high)}"
        assert written in comment, (bound.key, written)
        if bound.nullable:
            assert "null" in comment, bound.key
    for key, choices in CHOICES.items():
        for choice in choices:
            assert str(choice) in blocks[key], (key, choice)


def test_the_shipped_file_marks_exactly_the_restart_keys() -> None:
    marked = sorted(key for key, comment in _documented().items() if "RESTART" in comment)
    assert marked == sorted(RESTART)


# -- bounds -----------------------------------------------------------------------------------

# Settings that keep the rules between keys satisfied while one key sits on its bound.
CONTEXT = {
    ("control.setpoint", 100): {"safety.max_temp": "105"},
    ("safety.max_temp", 30): {"control.setpoint": "20"},
    ("output.min_on", 10): {"output.window": "60"},
    ("output.min_off", 10): {"output.window": "60"},
    ("safety.stale_after", 1): {"sensor.read_interval": "0.5"},
    # An LM92 takes no offset (its T_CRIT pin compares its own value).
    ("sensor.offset", -5): {"sensor.kind": "ds18b20"},
    ("sensor.offset", 5): {"sensor.kind": "ds18b20"},
    # Only back_calculation takes tt, and at least one period.
    ("control.tt", 1): {"control.algorithm": "back_calculation", "control.period": "1"},
    ("control.tt", 100000): {"control.algorithm": "back_calculation"},
}
# On its own bound but necessarily against a rule between keys: plausible_min must stay
# below plausible_max (at most 150), plausible_max above max_temp (at least 30).
AGAINST_A_RULE = {("safety.plausible_min", 150), ("safety.plausible_max", -55)}


def bound_cases() -> list[tuple[str, float, bool]]:
    """(key, value, accepted) on both sides of every bound: the bound itself and one step out."""
    cases = []
    for b in BOUNDS:
        step = 1 if b.kind is int else 0.001
        if b.low_open:
            cases += [(b.key, b.low, False), (b.key, b.low + step, True)]
        else:
            cases += [(b.key, b.low, True), (b.key, b.low - step, False)]
        if b.zero_ok:
            cases += [(b.key, 0, True), (b.key, -step, False)]
        if b.high is not None:
            cases += [(b.key, b.high, True), (b.key, b.high + step, False)]
        else:
            cases += [(b.key, 10**30, True)]
    return cases


@pytest.mark.parametrize(("key", "value", "accepted"), bound_cases())
def test_every_bound_just_inside_and_just_outside(key: str, value: float, accepted: bool) -> None:
    written = str(round(value, 6)) if isinstance(value, float) else str(value)
    values = {**CONTEXT.get((key, value), {}), key: written}
    text = document(values)
    if (key, value) in AGAINST_A_RULE:
        problems = problems_of(text)
        assert {p.key_path for p in problems} == {key}
        assert not any("out of range" in p.message for p in problems)
    elif accepted:
        assert value_at(parse(text), key) == value
    else:
        problem = only_problem(text)
        assert (problem.line, problem.column) == position(text, key)
        assert problem.key_path == key
        assert "out of range" in problem.message


def test_the_address_accepts_hex_and_decimal() -> None:
    assert parse("sensor:\n  address: 0x4B\n").sensor.address == 0x4B
    assert parse("sensor:\n  address: 73\n").sensor.address == 0x49
    assert "0x48 to 0x4B" in only_problem("sensor:\n  address: 0x4C\n").message


@pytest.mark.parametrize("bound", [b for b in BOUNDS if b.nullable], ids=lambda b: b.key)
def test_null_only_where_the_type_allows_it(bound: Bound) -> None:
    assert value_at(parse(document({bound.key: "null"})), bound.key) is None


@pytest.mark.parametrize(
    "key",
    [b.key for b in BOUNDS if not b.nullable]
    + [key for key, (_, nullable) in TEXTS.items() if not nullable]
    + list(CHOICES)
    + list(FLAGS),
)
def test_null_is_refused_elsewhere(key: str) -> None:
    problem = only_problem(document({key: "null"}))
    assert problem.key_path == key
    assert "has no value" in problem.message


@pytest.mark.parametrize(("key", "choices"), CHOICES.items())
def test_every_choice_is_accepted(key: str, choices: tuple[object, ...]) -> None:
    for choice in choices:
        values = {key: str(choice)}
        if choice == "gpio":
            line = "sense_line" if key == "pump.sense" else "line"
            values[key.split(".", maxsplit=1)[0] + f".{line}"] = "17"
        if key.startswith("element2.") and choice != "none":
            values["control.algorithm"] = "midrange"  # the second element needs midrange
            values.setdefault("element2.backend", "sim")
        if choice == "midrange":
            values["element2.backend"] = "sim"
        section = key.split(".", maxsplit=1)[0]
        if section in ROLES:  # not the HLT's LM92, at 0x48
            values[f"{section}.address"] = "0x49"
        assert value_at(parse(document(values)), key) == choice


@pytest.mark.parametrize(
    ("key", "wrong", "suggestion"),
    [
        ("control.mode", "Manual", "did you mean 'manual'?"),
        ("control.algorithm", "takahasi", "did you mean 'takahashi'?"),
        ("output.backend", "serial_rts", "did you mean 'serial-rts'?"),
        ("contactor.backend", "relay_board", "did you mean 'relay-board'?"),
    ],
)
def test_a_wrong_choice_names_the_closest(key: str, wrong: str, suggestion: str) -> None:
    problem = only_problem(document({key: wrong}))
    assert problem.key_path == key
    assert suggestion in problem.message


@pytest.mark.parametrize(("key", "wrong"), [("output.mains_hz", "55"), ("contactor.baud", "9601")])
def test_numeric_choices_refuse_other_numbers(key: str, wrong: str) -> None:
    problem = only_problem(document({key: wrong}))
    assert problem.key_path == key
    assert "not one of" in problem.message


def test_text_bounds() -> None:
    assert parse(document({"tun.name": "A" * 32})).tun.name == "A" * 32
    assert only_problem(document({"tun.name": "A" * 33})).key_path == "tun.name"
    assert only_problem(document({"tun.name": "''"})).key_path == "tun.name"
    assert "control character" in only_problem(document({"tun.name": '"HL\\tT"'})).message
    assert only_problem(document({"output.port": "''"})).key_path == "output.port"
    assert parse(document({"log.dir": "null"})).log.dir is None
    assert parse(document({"log.dir": "run/logs"})).log.dir == "run/logs"
    assert only_problem(document({"log.dir": "''"})).key_path == "log.dir"


@pytest.mark.parametrize(("written", "value"), [("true", True), ("false", False), ("True", True)])
def test_flags(written: str, value: bool) -> None:
    assert parse(document({"output.active_low": written})).output.active_low is value


# -- rules between keys ----------------------------------------------------------------------

# (settings, the key the problem points at, words the message must contain); each rule also
# has a neighbouring accepted case in CROSS_ACCEPTED.
CROSS_REFUSED = [
    # 1.0 s window, not longer than 0.5 + 0.5 s of minimum pulses.
    (
        {"output.window": "1", "output.min_on": "0.5", "output.min_off": "0.5"},
        "output.window",
        "output.min_on + output.min_off",
    ),
    # With window null the control period is the window.
    (
        {"control.period": "1", "output.min_on": "0.5", "output.min_off": "0.5"},
        "control.period",
        "output.min_on + output.min_off",
    ),
    # One half-cycle at 50 Hz is 1/(2·50) = 0.01 s.
    ({"output.min_on": "0.005"}, "output.min_on", "half-cycle"),
    ({"output.min_off": "0.0099"}, "output.min_off", "half-cycle"),
    # At 60 Hz it is 1/120 = 0.00833 s.
    ({"output.mains_hz": "60", "output.min_on": "0.008"}, "output.min_on", "half-cycle"),
    ({"control.setpoint": "95"}, "control.setpoint", "safety.max_temp"),
    ({"safety.max_temp": "60"}, "safety.max_temp", "safety.max_temp"),
    ({"safety.plausible_min": "110"}, "safety.plausible_min", "plausible_max"),
    ({"safety.plausible_max": "95"}, "safety.plausible_max", "plausible_max"),
    ({"output.backend": "gpio"}, "output.backend", "output.line"),
    ({"contactor.backend": "gpio"}, "contactor.backend", "contactor.line"),
    (
        {"contactor.backend": "serial-rts", "contactor.port": "/dev/ttyUSB0"},
        "contactor.backend",
        "/dev/ttyUSB0",
    ),
    (
        {
            "output.backend": "serial-dtr",
            "contactor.backend": "serial-dtr",
            "contactor.port": "/dev/ttyUSB0",
        },
        "contactor.backend",
        "/dev/ttyUSB0",
    ),
    (
        {"contactor.backend": "relay-board", "contactor.port": "/dev/ttyUSB0"},
        "contactor.backend",
        "relay board",
    ),
    (
        {
            "output.backend": "gpio",
            "output.line": "17",
            "contactor.backend": "gpio",
            "contactor.line": "17",
        },
        "contactor.line",
        "line 17",
    ),
    (
        {"control.manual_output": "50", "control.max_output": "40"},
        "control.manual_output",
        "max_output",
    ),
    ({"safety.stale_after": "1"}, "safety.stale_after", "read_interval"),
    ({"mqtt.topic_prefix": "brewery/+"}, "mqtt.topic_prefix", "wildcard"),
    ({"mqtt.discovery_prefix": "ha/#"}, "mqtt.discovery_prefix", "wildcard"),
    ({"mqtt.topic_prefix": "$SYS"}, "mqtt.topic_prefix", "starts with $"),
    ({"mqtt.topic_prefix": "brewery/"}, "mqtt.topic_prefix", "empty level"),
    ({"mqtt.topic_prefix": "brewery//hlt"}, "mqtt.topic_prefix", "empty level"),
    ({"mqtt.password_file": "/etc/hermsd/mqtt-password"}, "mqtt.password_file", "user name"),
    ({"mqtt.ca_file": "/etc/ssl/ca.pem"}, "mqtt.ca_file", "mqtt.tls: true"),
    (
        {"mqtt.tls": "true", "mqtt.key_file": "/etc/hermsd/key.pem"},
        "mqtt.key_file",
        "mqtt.cert_file",
    ),
]
CROSS_ACCEPTED = [
    {"output.window": "1", "output.min_on": "0.5", "output.min_off": "0.49"},
    {"control.period": "1", "output.min_on": "0.49", "output.min_off": "0.5"},
    {"output.min_on": "0", "output.min_off": "0.01"},
    {"output.mains_hz": "60", "output.min_on": "0.0084", "output.min_off": "0"},
    {"control.setpoint": "94.9"},
    {"safety.plausible_min": "109.9"},
    {"safety.plausible_max": "95.1"},
    {"output.backend": "gpio", "output.line": "0"},
    {"contactor.backend": "gpio", "contactor.line": "5"},
    # RTS to the SSR and DTR to the contactor on one adapter: two different lines.
    {"contactor.backend": "serial-dtr", "contactor.port": "/dev/ttyUSB0"},
    {"contactor.backend": "relay-board", "contactor.port": "/dev/ttyUSB1"},
    {
        "output.backend": "gpio",
        "output.line": "17",
        "contactor.backend": "gpio",
        "contactor.line": "27",
    },
    {
        "output.backend": "gpio",
        "output.line": "17",
        "contactor.backend": "gpio",
        "contactor.line": "17",
        "contactor.chip": "/dev/gpiochip4",
    },
    {"control.manual_output": "40", "control.max_output": "40"},
    {"safety.stale_after": "1.5"},
    {"mqtt.topic_prefix": "brewery/hlt-1", "mqtt.discovery_prefix": "home_assistant"},
    {"mqtt.username": "hermsd", "mqtt.password_file": "/etc/hermsd/mqtt-password"},
    {"mqtt.tls": "true", "mqtt.cert_file": "/etc/hermsd/c.pem", "mqtt.key_file": "/etc/k.pem"},
]


@pytest.mark.parametrize(("values", "key", "words"), CROSS_REFUSED)
def test_rules_between_keys_refuse(values: dict[str, str], key: str, words: str) -> None:
    text = document(values)
    problem = only_problem(text)
    assert problem.key_path == key
    assert (problem.line, problem.column) == position(text, key)
    assert words in problem.message


@pytest.mark.parametrize("values", CROSS_ACCEPTED)
def test_rules_between_keys_accept_their_neighbours(values: dict[str, str]) -> None:
    assert_within_spec(parse(document(values)))


def test_two_gpio_backends_without_lines_are_told_to_add_lines_not_to_share_one() -> None:
    problems = problems_of(document({"output.backend": "gpio", "contactor.backend": "gpio"}))
    assert [p.key_path for p in problems] == ["output.backend", "contactor.backend"]
    assert all(".line, the line offset" in p.message for p in problems)


def test_a_rule_shown_at_another_key_than_its_subject_names_the_subject() -> None:
    """Only plausible_max is in the file: the defaults it clashes with are named, with theirs."""
    problems = problems_of("safety:\n  plausible_max: -55\n")
    assert [(p.line, p.column, p.key_path, p.message) for p in problems] == [
        (
            2,
            18,
            "safety.plausible_max",
            "safety.plausible_min (-10 °C) is not below safety.plausible_max (-55 °C): the "
            "believable readings run from plausible_min up to plausible_max (lower "
            "plausible_min or raise plausible_max)",
        ),
        (
            2,
            18,
            "safety.plausible_max",
            "safety.max_temp (95 °C) is not below safety.plausible_max (-55 °C), so an overheat "
            "would read as a broken sensor (lower max_temp or raise plausible_max)",
        ),
    ]
    subject = only_problem("safety:\n  plausible_min: 130\n")  # its own key: its value alone
    assert subject.message.startswith("130 °C is not below safety.plausible_max (110 °C)")


def test_a_rule_is_not_reported_when_one_of_its_keys_was_refused() -> None:
    problem = only_problem(document({"control.setpoint": "hot", "safety.max_temp": "40"}))
    assert problem.key_path == "control.setpoint"


# -- keys, duplicates, syntax -----------------------------------------------------------------


def test_unknown_key_with_suggestion() -> None:
    text = "control:\n  setpont: 60\n"
    problem = only_problem(text)
    assert (problem.line, problem.column) == (2, 3)
    assert problem.key_path == "control.setpont"
    assert "did you mean 'setpoint'?" in problem.message
    assert "did you mean 'control'?" in only_problem("contol:\n  setpoint: 60\n").message


def test_a_key_in_the_wrong_section_is_sent_home() -> None:
    assert "'safety' section" in only_problem("control:\n  max_temp: 90\n").message
    assert "'control' section" in only_problem("setpoint: 60\n").message


def test_unknown_key_without_a_close_match_lists_the_keys() -> None:
    message = only_problem("sensor:\n  colour: blue\n").message
    assert "bus, address, kind, id, w1_root" in message and "read_interval" in message


def test_duplicate_keys_are_refused() -> None:
    text = "control:\n  setpoint: 60\n  kc: 50\n  setpoint: 70\n"
    problem = only_problem(text)
    assert (problem.line, problem.column) == (4, 3)
    assert "duplicate" in problem.message
    assert "line 2" in problem.message
    section = only_problem("tun:\n  litres: 50\ncontrol:\n  kc: 5\ntun:\n  litres: 60\n")
    assert (section.line, section.key_path) == (5, "tun")


@pytest.mark.parametrize(
    "text",
    [
        "control:\n  setpoint: [66\n",
        "control:\n  setpoint: 66\n kc: 5\n",
        "control: {setpoint: 66\n",
        "control:\n  name: 'HLT\n",
        "tun:\n  name: a\n---\ntun:\n  name: b\n",
        "control:\n  setpoint: *nowhere\n",
    ],
)
def test_yaml_syntax_errors_point_where_the_parser_does(text: str) -> None:
    problem = only_problem(text)
    with pytest.raises(yaml.MarkedYAMLError) as caught:
        yaml.safe_load(text)
    mark = caught.value.problem_mark
    assert mark is not None
    assert (problem.line, problem.column) == (mark.line + 1, mark.column + 1)
    assert problem.message.startswith("invalid YAML")


def test_a_tab_is_named() -> None:
    problem = only_problem("control:\n\tsetpoint: 66\n")
    assert (problem.line, problem.column) == (2, 1)
    assert "not tabs" in problem.message


def test_a_control_character_is_located() -> None:
    problem = only_problem("tun:\n  name: H\x07LT\n")
    assert (problem.line, problem.column) == (2, 10)  # "  name: H" is 9 characters
    assert "#x7" in problem.message


@pytest.mark.parametrize("text", ["- tun\n", "just words\n", "~\n", "[tun]\n"])
def test_the_top_level_must_be_a_mapping(text: str) -> None:
    problem = only_problem(text)
    assert problem.line == 1
    assert "mapping of sections" in problem.message


def test_a_section_must_be_a_mapping() -> None:
    problem = only_problem("control: 66\n")
    assert (problem.line, problem.column, problem.key_path) == (1, 10, "control")
    assert "setpoint" in problem.message


# -- types ------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("key", "written", "words"),
    [
        ("control.setpoint", "'66'", "expected a number, got the string '66'"),
        ("control.setpoint", '"66"', "write it without quotes: 66"),
        ("control.setpoint", "true", "expected a number, got the boolean true"),
        ("control.setpoint", "hot", "expected a number, got the string 'hot'"),
        ("control.setpoint", "[66]", "got a list"),
        ("control.setpoint", "{a: 1}", "got a mapping"),
        ("control.setpoint", "066", "leading zeros"),
        ("control.setpoint", ".inf", "expected a number"),
        ("control.setpoint", "1e999", "too large"),
        ("control.setpoint", "!!str 66", "tag '!!str'"),
        ("control.period", "1:30", "write 90"),  # 1 min 30 s
        ("sensor.bus", "1.0", "expected a whole number, got the number 1.0"),
        ("sensor.bus", "false", "expected a whole number"),
        ("tun.name", "123", "expected text, got the number 123"),
        ("tun.name", "{a: 1}", "mapping"),
        ("output.port", "false", "expected text"),
        ("output.active_low", "yes", "expected true or false, got the string 'yes'"),
        ("output.active_low", "1", "expected true or false, got the number 1"),
        ("output.active_low", "'true'", "expected true or false"),
    ],
)
def test_wrong_types_are_named(key: str, written: str, words: str) -> None:
    text = document({key: written})
    problem = only_problem(text)
    assert problem.key_path == key
    assert (problem.line, problem.column) == position(text, key)
    assert words in problem.message
    assert problem.message.endswith(")")


def test_an_int_is_accepted_for_a_float() -> None:
    config = parse("control:\n  setpoint: 70\n  kc: 1e2\n  td: .5\n")
    assert (config.control.setpoint, config.control.kc, config.control.td) == (70.0, 100.0, 0.5)
    assert type(config.control.setpoint) is float


def test_a_quoted_number_is_text_where_text_is_expected() -> None:
    assert parse("tun:\n  name: '2024'\n").tun.name == "2024"


# -- several problems at once -----------------------------------------------------------------


def test_every_problem_is_reported_at_once_in_file_order() -> None:
    text = (
        "# brew day\n"
        "tun:\n"
        "  litres: 2000\n"
        "control:\n"
        "  setpoint: '66'\n"
        "  algoritm: type_a\n"
        "sensor:\n"
        "  address: 0x49\n"
        "  address: 0x4A\n"
        "output:\n"
        "  mains_hz: 55\n"
    )
    lines = text.splitlines()

    def at(fragment: str, token: str) -> str:
        number = next(i for i, line in enumerate(lines, 1) if fragment in line)
        return f"cfg.yaml:{number}:{lines[number - 1].index(token) + 1}"

    with pytest.raises(ConfigError) as caught:
        parse(text, "cfg.yaml")
    reported = str(caught.value).splitlines()
    quoted = "'66'"
    expected = [
        f"{at('2000', '2000')}: tun.litres: 2000 L is out of range",
        f"{at(quoted, quoted)}: control.setpoint: expected a number, got the string {quoted}",
        f"{at('algoritm', 'algoritm')}: control.algoritm: unknown key (did you mean 'algorithm'?)",
        f"{at('0x4A', 'address')}: sensor.address: duplicate key (first given on line 8",
        f"{at('55', '55')}: output.mains_hz: 55 is not one of the choices",
    ]
    assert len(reported) == len(expected)
    for line, start in zip(reported, expected, strict=True):
        assert line.startswith(start), (line, start)
    assert [p.line for p in caught.value.problems] == [3, 5, 6, 9, 11]


# -- files ------------------------------------------------------------------------------------


def test_load_a_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "nope.yaml"
    with pytest.raises(ConfigError) as caught:
        load(path)
    (problem,) = caught.value.problems
    assert problem.line == 0
    assert (
        str(caught.value)
        == f"{path}: no such file (check the path, or copy config/hermsd.yaml there)"
    )


def test_load_a_directory(tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as caught:
        load(tmp_path)
    assert "is a directory" in str(caught.value)


def test_load_a_file_that_is_not_utf8(tmp_path: Path) -> None:
    path = tmp_path / "latin1.yaml"
    text = "control:\n  setpoint: 66  # °C\n"
    path.write_bytes(text.encode("latin-1"))
    with pytest.raises(ConfigError) as caught:
        load(path)
    (problem,) = caught.value.problems
    assert (problem.line, problem.column) == (2, text.splitlines()[1].index("°") + 1)
    assert "0xb0" in problem.message
    assert "UTF-8" in problem.message


def test_load_reads_utf8_with_a_byte_order_mark(tmp_path: Path) -> None:
    path = tmp_path / "bom.yaml"
    path.write_bytes(b"\xef\xbb\xbfcontrol:\n  setpoint: 67  # \xc2\xb0C\n")
    assert load(path).control.setpoint == 67.0


# -- writing back -----------------------------------------------------------------------------


def test_to_dict_is_json() -> None:
    config = parse("control:\n  tf: 3\nlog:\n  dir: null\n")
    assert json.loads(json.dumps(to_dict(config))) == to_dict(config)
    assert to_dict(config)["control"]["tf"] == 3.0


def test_dump_yaml_reads_back_to_the_same_config() -> None:
    assert parse(dump_yaml(DEFAULT)) == DEFAULT
    tricky = dataclasses.replace(DEFAULT, tun=TunConfig(name="1e3"))
    assert parse(dump_yaml(tricky)) == tricky
    for name in ("066", "yes", "null", "0x48", "1:30", "~", "true"):
        named = dataclasses.replace(DEFAULT, tun=TunConfig(name=name))
        assert parse(dump_yaml(named)).tun.name == name


def test_from_dict_reads_a_logged_config_back() -> None:
    tuned = parse(
        "tun:\n  name: '066'\ncontrol:\n  algorithm: back_calculation\n  kc: 80.8\n"
        "  ti: 489\n  td: 44.9\n  tt: 1.5e1\n  max_output: 1e2\nlog:\n  dir: null\n"
        "safety:\n  max_step: 0.00001\n"
    )
    for config in (DEFAULT, tuned):
        assert from_dict(json.loads(json.dumps(to_dict(config)))) == config
    assert tuned.safety.max_step == 1e-05  # written 1.0e-05 on the way: the exponent survives


def test_from_dict_refuses_what_a_file_would_refuse() -> None:
    logged = to_dict(DEFAULT)
    bad = {**logged, "control": {**logged["control"], "kc": -1.0, "gain": 2.0}}
    with pytest.raises(ConfigError) as caught:
        from_dict(bad)
    assert {p.key_path for p in caught.value.problems} == {"control.kc", "control.gain"}
    with pytest.raises(ConfigError, match="mapping of sections"):
        from_dict(["not", "a", "config"])


def test_restart_keys_changed() -> None:
    assert restart_keys_changed(DEFAULT, DEFAULT) == []
    live = parse(
        "control:\n  setpoint: 70\n  kc: 60\nsafety:\n  reset: 1\noutput:\n  min_on: 0.5\n"
    )
    assert restart_keys_changed(DEFAULT, live) == []
    new = parse(
        "control:\n  period: 10\nsensor:\n  address: 0x49\n"
        "contactor:\n  baud: 19200\nlog:\n  dir: null\n"
    )
    assert restart_keys_changed(DEFAULT, new) == [
        "control.period",
        "sensor.address",
        "contactor.baud",
        "log.dir",
    ]
    for key in RESTART:
        section, name = key.split(".")
        old = value_at(DEFAULT, key)
        changed = {bool: not old, int: 3 if old == 2 else 2, str: "/dev/other"}.get(type(old), 7)
        part = dataclasses.replace(getattr(DEFAULT, section), **{name: changed})
        assert restart_keys_changed(DEFAULT, dataclasses.replace(DEFAULT, **{section: part})) == [
            key
        ]


# -- fuzz -------------------------------------------------------------------------------------


def assert_sound_outcome(outcome: Config | ConfigError) -> None:
    """An accepted config is within spec; a refusal places and explains each problem."""
    if isinstance(outcome, Config):
        assert_within_spec(outcome)
        return
    assert outcome.problems
    for problem in outcome.problems:
        assert problem.line >= 1, problem
        assert problem.column >= 1, problem
        assert problem.message.endswith(")"), problem
    assert len(str(outcome).splitlines()) >= len(outcome.problems)


def parse_outcome(text: str) -> Config | ConfigError:
    try:
        return parse(text)
    except ConfigError as error:
        return error


FIELDS_OF: dict[str, list[str]] = {}
for _key in ALL_KEYS:
    FIELDS_OF.setdefault(_key.split(".")[0], []).append(_key.split(".")[1])
scalars = (
    st.none()
    | st.booleans()
    | st.integers()
    | st.integers(-100, 2000)
    | st.floats()
    | st.floats(-100, 2000)
    | st.text(max_size=12)
    | st.sampled_from([str(c) for choices in CHOICES.values() for c in choices])
)
keys = st.sampled_from(sorted({n for names in FIELDS_OF.values() for n in names}))
trees = st.recursive(
    scalars,
    lambda children: (
        st.lists(children, max_size=3)
        | st.dictionaries(keys | st.text(max_size=8) | st.integers(0, 3), children, max_size=4)
    ),
    max_leaves=10,
)


def in_range(key: str) -> st.SearchStrategy[Any]:
    """Values the specification accepts for `key` on its own."""
    if key in CHOICES:
        return st.sampled_from(CHOICES[key])
    if key in TEXTS:
        longest, nullable = TEXTS[key]
        text = st.text(st.characters(codec="utf-8"), min_size=1, max_size=longest or 40)
        return text.filter(str.isprintable) | (st.none() if nullable else st.nothing())
    if key in FLAGS:
        return st.booleans()
    if key in LISTS:
        items, nullable = LISTS[key]
        if items:
            return st.lists(st.sampled_from(items), min_size=1, unique=True)
        word = st.text(st.characters(codec="utf-8"), min_size=1, max_size=20)
        return st.lists(word.filter(str.isprintable), min_size=1, max_size=4) | st.none()
    bound = next(b for b in BOUNDS if b.key == key)
    if bound.kind is int:
        values: st.SearchStrategy[Any] = st.integers(int(bound.low), int(bound.high or 10**9))
    else:
        values = st.floats(bound.low, bound.high, exclude_min=bound.low_open)
    return values | st.none() if bound.nullable else values


def nest(pairs: list[tuple[str, Any]]) -> dict[str, dict[str, Any]]:
    sections: dict[str, dict[str, Any]] = {}
    for key, value in pairs:
        section, name = key.split(".")
        sections.setdefault(section, {})[name] = value
    return sections


# Mostly known keys with values in their ranges, so that many documents are accepted and
# checked against the whole specification; the rest anything at all.
setting = st.sampled_from(ALL_KEYS).flatmap(lambda key: st.tuples(st.just(key), in_range(key)))
plausible = st.lists(setting | st.tuples(st.sampled_from(ALL_KEYS), scalars), max_size=5).map(nest)
wild = st.dictionaries(
    st.sampled_from(sorted(FIELDS_OF)) | st.text(max_size=6),
    st.dictionaries(keys, trees, max_size=4) | trees,
    max_size=4,
)
documents = plausible | wild


@FAST_FUZZ
@given(documents)
def test_fuzz_random_documents(doc: dict[Any, Any]) -> None:
    assert_sound_outcome(parse_outcome(yaml.safe_dump(doc, sort_keys=False)))


@FAST_FUZZ
@given(st.text(max_size=80))
def test_fuzz_random_text(text: str) -> None:
    assert_sound_outcome(parse_outcome(text))


SHIPPED = CONFIG_FILE.read_bytes()


@st.composite
def mutated_config(draw: st.DrawFn) -> bytes:
    """The shipped file with one to three edits a hurried brewer (or a bad SD card) might make."""
    lines = SHIPPED.split(b"\n")
    for _ in range(draw(st.integers(1, 3))):
        edit = draw(st.sampled_from(["delete", "duplicate", "value", "bytes"]))
        keyed = [i for i, line in enumerate(lines) if re.match(rb"  [a-z_]+:", line)]
        pool = keyed if edit == "value" and keyed else range(len(lines))
        index = draw(st.sampled_from(pool))
        if edit == "delete":
            del lines[index]
        elif edit == "duplicate":
            lines.insert(index, lines[index])
        elif edit == "value":
            head = lines[index].split(b":", 1)[0]
            section = next(
                (line[:-1] for line in reversed(lines[:index]) if re.fullmatch(rb"[a-z_]+:", line)),
                b"",
            )
            key = f"{section.decode(errors='replace')}.{head.strip().decode(errors='replace')}"
            scalar = draw(in_range(key) | scalars if key in ALL_KEYS else scalars)
            written = yaml.safe_dump(scalar).removesuffix("\n...\n").strip()
            raw = draw(st.just(written) | st.text(max_size=10))
            lines[index] = head + b": " + raw.encode("utf-8", "surrogatepass")
        else:
            junk = draw(st.binary(min_size=1, max_size=6))
            at = draw(st.integers(0, len(lines[index])))
            lines[index] = lines[index][:at] + junk + lines[index][at:]
        if not lines:
            break
    return b"\n".join(lines)


@pytest.fixture(scope="module")
def scratch(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fuzz") / "hermsd.yaml"


@FAST_FUZZ
@given(data=mutated_config())
def test_fuzz_mutations_of_the_shipped_file(scratch: Path, data: bytes) -> None:
    scratch.write_bytes(data)
    try:
        outcome: Config | ConfigError = load(scratch)
    except ConfigError as error:
        outcome = error
    assert_sound_outcome(outcome)


valid_values = st.fixed_dictionaries(
    {
        "control.setpoint": st.floats(0, 94.9),
        "control.kc": st.floats(0.01, 10000),
        "output.window": st.none() | st.floats(1, 60),
        "safety.hysteresis": st.floats(0.5, 30),
        "tun.name": st.text(st.characters(codec="utf-8"), min_size=1, max_size=32).filter(
            str.isprintable
        ),
        "log.queue_size": st.integers(100, 1000000),
    }
)


@settings(max_examples=100, deadline=None)
@given(valid_values)
def test_fuzz_dump_yaml_round_trips(values: dict[str, Any]) -> None:
    config = dataclasses.replace(
        DEFAULT,
        **{
            s: dataclasses.replace(getattr(DEFAULT, s), **v)
            for s, v in nest(list(values.items())).items()
        },
    )
    assert parse(dump_yaml(config)) == config


@pytest.mark.parametrize(
    ("text", "where"),
    [
        ("control:\n  tt: 1.0\n", "2:7: control.tt: tt=1.0 is invalid here"),
        ("control:\n  algorithm: velocity_pi\n  td: 5\n", "3:7: control.td: td=5.0 is invalid"),
    ],
)
def test_the_algorithms_own_rules_are_checked_with_the_file(text: str, where: str) -> None:
    """What the controller would refuse at start or reload is refused with its line."""
    with pytest.raises(ConfigError) as caught:
        parse(text, "f.yaml")
    assert str(caught.value).startswith(f"f.yaml:{where}")
    assert str(caught.value).endswith(")")
