"""Scenarios: a brew day (or a fault) run at full speed through the very same daemon code.

A scenario is YAML: `duration`, `plant` (model and parameters: `hermsd.sim.hlt.PLANT_KINDS`
and their keyword parameters, plus the sensor's `noise_c` and `seed`; README.md, Simulate),
initial `setpoint` (else the config's), optional `config` (overrides of the daemon's config,
validated like the file), and `events`, each with `at` and one action; errors name the file,
line and column. A scenario may run a mash program (`program:` a file, relative to the
scenario's, or the program inline; started half a period in) on a simulated local time
(`clock:` its start, ISO 8601 with the offset, e.g. "2026-11-28T04:00:00+01:00"; default
2026-01-01T00:00Z), and answer the program's confirmations (`confirm:` events: from `at` on,
the next wait for that message is confirmed). A `plant:` with a `mash:` mapping
(`hermsd.sim.mash.MASH_RANGES`) is a HERMS: the HLT with a mash tun, a coil and a pump, which
`dough_in`, `pump` and `recirculation` events drive (`pump` through the daemon when the
config fits one, `pump.backend: sim`; else the plant's, as a switch hermsd does not own). The
runner wires the fake bus, the tun model and the simulated heater circuit into `Daemon` on a
virtual clock, and measures the run against physics: the earliest any controller could
settle is full power from the start.
"""

from __future__ import annotations

import copy
import datetime as dt
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from hermsd.config import read
from hermsd.config import schema as config_module
from hermsd.config.schema import Config
from hermsd.control.learning import ModelStore
from hermsd.durations import parse_duration
from hermsd.files import NotRegularFile, read_regular
from hermsd.log.recorder import Recorder
from hermsd.metrics import BAND, SIMULATED_TEMPERATURE, Sample, compute, report
from hermsd.program import model as program_model
from hermsd.program.driver import next_local_time
from hermsd.program.model import Program, ProgramError, mash_in_index
from hermsd.program.quality import step_quality
from hermsd.runtime.assemble import assemble
from hermsd.runtime.daemon import Daemon
from hermsd.runtime.period import PeriodRecord
from hermsd.runtime.saver import Saver
from hermsd.safety.latches import LatchStore
from hermsd.safety.limits import Alarm, MeasuredTun
from hermsd.sim.bus import Fault, fault_value
from hermsd.sim.circuit import HeaterCircuit
from hermsd.sim.clock import VirtualClock
from hermsd.sim.hlt import PLANT_KINDS, Plant, TwoElementPlant, make_plant, plant_parameters
from hermsd.sim.mash import (
    DOUGH_IN_RANGES,
    MASH_RANGES,
    HermsTun,
    as_herms_plant,
    make_herms_plant,
)
from hermsd.sim.sensors import FAULTS, FakeChip, sensor_reading
from hermsd.sim.world import SENSOR_KEYS, World, build_world

SENSOR_FAULTS = tuple(dict.fromkeys(name for names in FAULTS.values() for name in names))
"""Every kind's faults (sim/sensors.py); a run refuses those its sensor's kind has not."""
FAULT_KINDS = ("sensor", "heater", "ssr", "heater2", "relay2", "recirculation")
MASH_EVENTS = ("dough_in", "pump", "recirculation")
"""Events for a HERMS plant's mash side (`hermsd.sim.mash.HermsPlant`)."""
EVENT_KINDS = (
    "confirm",
    "add_water",
    "setpoint",
    "mode",
    "output",
    "sensor",
    "mash_sensor",
    "heater",
    "ssr",
    "heater2",
    "relay2",
    "current",
    "ambient",
    "config",
    *MASH_EVENTS,
)


# What the daemon and the tun model accept (the daemon's setpoint and manual output, the
# config's tun size and ambient); a scenario is refused before its run, not half-way in.
SETPOINT_RANGE = (0.0, 100.0, "°C")
EVENT_RANGES = {
    "setpoint": SETPOINT_RANGE,
    "output": (0.0, 100.0, "%"),
    "ambient": (-20.0, 50.0, "°C"),
}
WATER = {"litres": (0.1, 1000.0, "L"), "temp": (0.0, 100.0, "°C (liquid water)")}


class ScenarioError(ValueError):
    """A scenario file that cannot be run; the message names the file and the key."""


@dataclass(frozen=True, slots=True)
class Event:
    at: float
    kind: str
    value: Any
    lasts: float | None = None  # sensor faults: how long, else until the next sensor event


@dataclass(frozen=True, slots=True)
class Scenario:
    name: str = "default"
    duration: float = 6 * 3600.0
    plant: dict[str, Any] = field(default_factory=lambda: {"model": "foptd"})
    setpoint: float | None = None  # None: the config's (control.setpoint)
    config: dict[str, Any] = field(default_factory=dict)
    events: tuple[Event, ...] = (Event(4 * 3600.0, "add_water", {"litres": 10.0, "temp": 15.0}),)
    program: Program | None = None
    clock: tuple[int, dt.tzinfo] | None = None  # wall-clock start (ns) and local zone
    source: str = ""  # the file, for errors found later (a config override's)
    positions: dict[str, tuple[int, int]] = field(default_factory=dict)  # each key's place


DEFAULT = Scenario()

MAX_SCENARIO_BYTES = 1 << 20
"""The longest scenario file read: thousands of events (the shipped ones are under 2 KiB)."""
MAX_DURATION = 7 * 86400.0
"""s: the longest scenario run. A brew day with an overnight mash and a next day fits many
times over, and a week runs in minutes on the virtual clock; a longer one is a typo
(100000h), which would otherwise run until killed."""


def load_scenario(path: Path) -> Scenario:
    try:
        text = read_regular(path, MAX_SCENARIO_BYTES).decode("utf-8")
    except (OSError, UnicodeDecodeError, NotRegularFile) as error:
        raise ScenarioError(f"{path}: cannot read the scenario: {error}") from None
    loader = yaml.SafeLoader(text)
    try:
        node = loader.get_single_node()
        doc = loader.construct_document(node) if node is not None else None
        positions = _positions(node, "") if node is not None else {}
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        where = f"{path}:{mark.line + 1}:{mark.column + 1}" if mark else str(path)
        raise ScenarioError(f"{where}: not valid YAML: {error}") from None
    except RecursionError:
        raise ScenarioError(f"{path}: nested too deeply to be a scenario") from None
    finally:
        loader.dispose()
    return parse_scenario(doc if doc is not None else {}, str(path), positions)


def _positions(node: yaml.Node, key: str) -> dict[str, tuple[int, int]]:
    """Line and column (1-based) of every value in the document, by its key path."""
    found = {key: (node.start_mark.line + 1, node.start_mark.column + 1)}
    if isinstance(node, yaml.MappingNode):
        for key_node, value_node in node.value:
            name = f"{key}.{key_node.value}" if key else str(key_node.value)
            found.update(_positions(value_node, name))
    elif isinstance(node, yaml.SequenceNode):
        for index, item in enumerate(node.value):
            found.update(_positions(item, f"{key}[{index}]"))
    return found


def parse_scenario(
    doc: Any, source: str = "<scenario>", positions: dict[str, tuple[int, int]] | None = None
) -> Scenario:
    """A validated scenario from a parsed YAML document (`positions`: where each key is)."""

    def fail(key: str, what: str) -> ScenarioError:
        return ScenarioError(f"{_where(source, positions or {}, key)}: {key}: {what}")

    if not isinstance(doc, dict):
        raise fail("(top level)", "expected a mapping with duration, plant, setpoint, events")
    known = {"name", "duration", "plant", "setpoint", "config", "events", "program", "clock"}
    unknown = set(doc) - known
    if unknown:
        raise fail(", ".join(sorted(map(str, unknown))), "unknown key")
    try:
        duration = parse_duration(doc.get("duration", DEFAULT.duration))
    except ValueError as error:
        raise fail("duration", str(error)) from None
    if duration > MAX_DURATION:
        raise fail(
            "duration", f"{duration:g} s is longer than a scenario runs ({MAX_DURATION:g} s)"
        )
    plant = _plant(doc.get("plant", DEFAULT.plant), fail)
    overrides = doc.get("config", {}) or {}
    if not isinstance(overrides, dict):
        raise fail("config", "expected a mapping of config sections")
    setpoint = None
    if "setpoint" in doc:
        setpoint = _number(doc["setpoint"], fail, "setpoint", SETPOINT_RANGE)
        control = overrides.get("control")
        if isinstance(control, dict) and "setpoint" in control:
            raise fail(
                "config.control.setpoint",
                "the setpoint is given twice (keep the top-level setpoint, or this one)",
            )
    raw_events = doc.get("events", []) or []
    if not isinstance(raw_events, list):
        raise fail("events", "expected a list of events")
    events = [_event(e, i, fail) for i, e in enumerate(raw_events)]
    for index, event in enumerate(events):
        if event.at > duration:
            raise fail(
                f"events[{index}].at",
                f"{event.at:g} s lies after the scenario's end ({duration:g} s): it would "
                "never happen (lengthen duration, or move the event)",
            )
    if "mash" in plant:
        _check_first_dough_in(plant, events, fail)
    events.sort(key=lambda e: e.at)
    return Scenario(
        name=str(doc.get("name", Path(source).stem)),
        duration=duration,
        plant=plant,
        setpoint=setpoint,
        config=overrides,
        events=tuple(events),
        program=_program(doc["program"], source, fail) if "program" in doc else None,
        clock=_clock(doc["clock"], fail) if "clock" in doc else None,
        source=source,
        positions=positions or {},
    )


def _where(source: str, positions: dict[str, tuple[int, int]], key: str) -> str:
    """FILE:LINE:COL of `key`, else of its nearest enclosing key, else FILE."""
    path = key
    while positions:
        if path in positions:
            line, column = positions[path]
            return f"{source}:{line}:{column}"
        cut = max(path.rfind("."), path.rfind("["))
        if cut <= 0:
            break
        path = path[:cut]
    return source


def _program(raw: Any, source: str, fail: Callable[[str, str], ScenarioError]) -> Program:
    """The scenario's mash program: a file (beside the scenario) or the program inline."""
    try:
        if isinstance(raw, str):
            return program_model.load(Path(source).parent / raw)
        return program_model.from_data(raw, "program", typed=True)
    except ProgramError as error:
        if isinstance(raw, str):
            raise ScenarioError(str(error)) from None  # the file's own FILE:LINE:COL
        raise fail("program", program_model.one_line(error)) from None


CLOCK_EXAMPLE = "2026-11-28T04:00:00+01:00"


def _clock(raw: Any, fail: Callable[[str, str], ScenarioError]) -> tuple[int, dt.tzinfo]:
    """The simulated wall clock's start and local zone, from an ISO 8601 time with offset."""
    moment = None
    if isinstance(raw, str):
        try:
            moment = dt.datetime.fromisoformat(raw)
        except ValueError:
            moment = None
    if isinstance(raw, dt.datetime):
        moment = raw
    if moment is None or moment.tzinfo is None:
        raise fail(
            "clock", f"expected a local time with its offset, e.g. {CLOCK_EXAMPLE!r}, got {raw!r}"
        )
    offset = moment.utcoffset()
    assert offset is not None
    return round(moment.timestamp() * 1e9), dt.timezone(offset)


def _plant(raw: Any, fail: Callable[[str, str], ScenarioError]) -> dict[str, Any]:
    """The `plant:` mapping, checked key by key: the tun's parameters, and the sensor's."""
    kinds = ", ".join(sorted(PLANT_KINDS))
    if not isinstance(raw, dict):
        raise fail("plant", f"expected a mapping with model ({kinds}) and its parameters")
    spec = {"model": "foptd", **raw}
    model = spec.pop("model")
    if model not in PLANT_KINDS:
        raise fail("plant.model", f"expected one of {kinds}, got {model!r}")
    known = (*plant_parameters(model), *SENSOR_KEYS, "mash")
    for key, value in spec.items():
        where = f"plant.{key}"
        if key not in known:
            raise fail(where, f"unknown key for model {model}: expected one of {', '.join(known)}")
        if key == "mash":
            spec["mash"] = _mash(value, fail)
        elif key == "lid":
            if not isinstance(value, bool):
                raise fail(where, f"expected on or off, got {value!r}")
        elif key == "seed":
            if isinstance(value, bool) or not isinstance(value, int):
                raise fail(where, f"expected a whole number, got {value!r}")
        else:
            _number(value, fail, where)
    try:
        tun = make_plant(model, **_hlt_parameters(spec))
        sensor_reading(tun, VirtualClock(), spec.get("noise_c", 0.0), 0)
    except ValueError as error:
        name = str(error).partition(" = ")[0]
        raise fail(f"plant.{name}", str(error)) from None
    return {"model": model, **spec}


def _hlt_parameters(spec: dict[str, Any]) -> dict[str, Any]:
    """The HLT's own keyword parameters of a `plant:` mapping (its model taken out)."""
    return {k: v for k, v in spec.items() if k not in (*SENSOR_KEYS, "model", "mash")}


MASH_EXAMPLE = "{coil_w_per_k: 250, flow_l_per_min: 6}"


def _mash(raw: Any, fail: Callable[[str, str], ScenarioError]) -> dict[str, float]:
    """The `plant.mash:` mapping, each key in its range (`MASH_RANGES`)."""
    if not isinstance(raw, dict):
        raise fail("plant.mash", f"expected a mapping of the mash side's keys, e.g. {MASH_EXAMPLE}")
    for key in raw:
        if key not in MASH_RANGES:
            known = ", ".join(MASH_RANGES)
            raise fail(f"plant.mash.{key}", f"unknown key: expected one of {known}")
    return {k: _number(v, fail, f"plant.mash.{k}", MASH_RANGES[k]) for k, v in raw.items()}


def _check_first_dough_in(
    plant: dict[str, Any], events: list[Event], fail: Callable[[str, str], ScenarioError]
) -> None:
    """The first dough-in must more than fill the hoses and coil (flow × the hoses' delays)."""
    doughs = [(event.at, index) for index, event in enumerate(events) if event.kind == "dough_in"]
    if not doughs:
        return
    index = min(doughs)[1]
    dough = events[index].value
    tun = make_herms_plant(plant["model"], plant["mash"], **_hlt_parameters(plant))
    try:
        tun.dough_in(
            dough["grain_kg"], dough["grain_c"], dough["water_litres"], dough["water_c"], 0.0
        )
    except ValueError as error:
        raise fail(f"events[{index}].dough_in", str(error)) from None


def _herms_tun(config: Config, spec: dict[str, Any]) -> HermsTun:
    """The HERMS a `plant:` mapping with `mash:` describes, its HLT's second element the
    config's as `build_world` gives a plant built from the mapping."""
    params = _hlt_parameters(spec)
    if config.element2.backend != "none":
        params.setdefault("element2_watts", config.element2.watts)
    return make_herms_plant(spec["model"], spec["mash"], **params)


def _number(
    value: Any,
    fail: Callable[[str, str], ScenarioError],
    key: str,
    within: tuple[float, float, str] | None = None,
) -> float:
    """A finite number, within (low, high, unit) when given: else the error that says so."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise fail(key, f"expected a number, got {value!r}")
    if within is not None and not within[0] <= value <= within[1]:
        low, high, unit = within
        raise fail(key, f"{value:g} is out of range (expected {low:g} to {high:g} {unit})")
    return float(value)


def _event(raw: Any, index: int, fail: Callable[[str, str], ScenarioError]) -> Event:
    key = f"events[{index}]"
    if not isinstance(raw, dict) or "at" not in raw:
        raise fail(key, "expected a mapping with 'at' and one action")
    actions = [k for k in raw if k in EVENT_KINDS]
    extra = set(raw) - {"at", "for", "value", *EVENT_KINDS}
    if len(actions) != 1 or extra:
        raise fail(key, f"expected 'at' and exactly one of {', '.join(EVENT_KINDS)}")
    try:
        at = parse_duration(raw["at"])
        lasts = parse_duration(raw["for"]) if "for" in raw else None
    except ValueError as error:
        raise fail(key, str(error)) from None
    kind = actions[0]
    value = raw[kind]
    if kind == "add_water":
        if not isinstance(value, dict) or set(value) != {"litres", "temp"}:
            raise fail(f"{key}.add_water", "expected {litres: L, temp: °C}")
        value = {k: _number(v, fail, f"{key}.add_water.{k}", WATER[k]) for k, v in value.items()}
    elif kind in ("setpoint", "output", "ambient"):
        value = _number(value, fail, f"{key}.{kind}", EVENT_RANGES[kind])
    elif kind == "mode" and value not in ("manual", "auto"):
        raise fail(f"{key}.mode", "expected manual or auto")
    elif kind in ("sensor", "mash_sensor"):
        if value not in SENSOR_FAULTS:
            raise fail(f"{key}.{kind}", f"expected one of {', '.join(SENSOR_FAULTS)}")
        value = (value, _number(raw["value"], fail, f"{key}.value") if "value" in raw else None)
        try:
            if value[0] in FAULTS["lm92"]:
                fault_value(Fault(value[0]), value[1])
            elif value[1] is not None:
                raise ValueError(f"the {value[0]!r} fault takes no value, got {value[1]}")
        except ValueError as error:
            raise fail(f"{key}.value", str(error)) from None
    elif kind == "heater" and value not in ("open", "ok"):
        raise fail(f"{key}.heater", "expected open or ok")
    elif kind in ("ssr", "relay2") and value not in ("stuck_on", "ok"):
        raise fail(f"{key}.{kind}", "expected stuck_on or ok")
    elif kind == "current" and value not in ("unplugged", "failing", "ok"):
        raise fail(f"{key}.current", "expected unplugged, failing or ok")
    elif kind == "dough_in":
        if not isinstance(value, dict) or set(value) != set(DOUGH_IN_RANGES):
            raise fail(
                f"{key}.dough_in",
                "expected {grain_kg: kg, grain_c: °C, water_litres: L, water_c: °C}",
            )
        value = {
            k: _number(v, fail, f"{key}.dough_in.{k}", DOUGH_IN_RANGES[k]) for k, v in value.items()
        }
    elif kind == "pump":
        if value not in ("on", "off") and not isinstance(value, bool):  # YAML reads on as True
            raise fail(f"{key}.pump", f"expected on or off, got {value!r}")
        value = value in (True, "on")
    elif kind == "recirculation" and value not in ("stuck", "ok"):
        raise fail(f"{key}.recirculation", "expected stuck or ok")
    elif kind == "heater2" and value not in ("open", "ok"):
        raise fail(f"{key}.heater2", "expected open or ok")
    elif kind == "config" and not isinstance(value, dict):
        raise fail(f"{key}.config", "expected config sections to change, as in the file")
    elif kind == "confirm" and not isinstance(value, str):
        raise fail(f"{key}.confirm", "expected the message of the step that waits, as text")
    return Event(at, kind, value, lasts)


def effective_config(base: Config, scenario: Scenario) -> Config:
    """The daemon's config with the scenario's overrides, validated like the file."""
    merged = _merge(read.to_dict(base), scenario.config)
    if scenario.setpoint is not None:
        merged.setdefault("control", {})["setpoint"] = scenario.setpoint
    return _validated(merged, scenario, "config")


def _validated(document: dict[str, Any], scenario: Scenario, at: str) -> Config:
    """A config document on the simulated heater, checked as a file would be; a problem is
    said at its key in the scenario (`at`: where its overrides are), else at `at`."""
    document.setdefault("output", {})["backend"] = "sim"
    element2 = document.get("element2")
    if isinstance(element2, dict) and element2.get("backend", "none") != "none":
        element2["backend"] = "sim"  # the simulated tun's second element, whatever the file's
    source = scenario.source or f"<scenario {scenario.name}>"
    try:
        return read.parse(yaml.safe_dump(document), source)
    except config_module.ConfigError as error:
        keys = [f"{at}.{p.key_path}" if p.key_path else at for p in error.problems]
        raise ScenarioError(
            "\n".join(
                f"{_where(source, scenario.positions, key)}: {key}: {p.message}"
                for key, p in zip(keys, error.problems, strict=True)
            )
        ) from None


def _reloads(config: Config, scenario: Scenario) -> dict[int, Config]:
    """The config each `config` event saves, by event index: edits accumulate like a file's."""
    reloads = {}
    for index, event in enumerate(scenario.events):
        if event.kind == "config":
            document = _merge(read.to_dict(config), event.value)
            config = _validated(document, scenario, f"events[{index}].config")
            reloads[index] = config
    return reloads


def _merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _merge(out[key], value)
        else:
            out[key] = value
    return out


@dataclass(slots=True)
class _Collector:
    """Samples the tun's true sensor temperature at every control period."""

    plant: Plant
    samples: list[Sample] = field(default_factory=list)
    pv_samples: list[Sample] = field(default_factory=list)  # of the daemon's PV, as logged
    records: list[PeriodRecord] = field(default_factory=list)
    alarms: list[Alarm] = field(default_factory=list)
    warned: dict[int, float] = field(default_factory=dict)  # element → first reported at
    keep_records: bool = False

    def period(self, record: PeriodRecord) -> None:
        for element in record.no_heat or ():
            self.warned.setdefault(element, record.t)
        temp = self.plant.temperature(record.t)
        self.samples.append(Sample(record.t, record.setpoint, temp, record.output))
        if record.pv is not None:
            self.pv_samples.append(Sample(record.t, record.setpoint, record.pv, record.output))
        if self.keep_records:
            self.records.append(record)

    def alarm(self, alarm: Alarm) -> None:
        if alarm.raised:
            self.alarms.append(alarm)


@dataclass(slots=True)
class Result:
    """What `hermsd simulate` reports."""

    summary: dict[str, Any]
    samples: list[Sample]
    records: list[PeriodRecord]


def time_to_band(
    plant: Plant, start: float, setpoint: float, limit: float, *, element2: bool
) -> float | None:
    """Seconds of full power from `start` until the sensor is in the band for good: when it
    last rises through setpoint − BAND (0 if it never falls below it); None if that takes
    more than `limit` s. On the plant's `temperature()`, the sensor without its noise. At
    full power, once the water rises and both it and the sensor are at or above the band's
    lower edge, neither falls below it again. Full power is every element the config fits:
    `element2`, the second one too (`factory.total_watts`), as the daemon's 100 % drives it."""
    target = setpoint - BAND
    plant.set_heater(True, start)
    if element2:
        if not isinstance(plant, TwoElementPlant):
            raise ValueError("element2: the plant has no second element")
        plant.set_heater2(True, start)
    crossed = 0.0
    t = start
    sensor = plant.temperature(t)
    water = plant.water_temperature(t)
    while t - start < limit:
        t += 1.0
        now, water_now = plant.temperature(t), plant.water_temperature(t)
        if sensor < target <= now:
            crossed = t - 1.0 - start + (target - sensor) / (now - sensor)
        if now >= target and target <= water < water_now:
            return crossed
        sensor, water = now, water_now
    return None


def reactive_floor(
    plant: Plant,
    start: float,
    setpoint: float,
    limit: float,
    period: float,
    duty: float,
    seen: float,
    *,
    element2: bool,
) -> float | None:
    """The least recovery a controller that acts on every reading can show: nothing can
    know of the water before the first reading after it, `seen` s after it, so until then
    the element runs at `duty` % as decided before the water (the period's on-time first,
    the soonest it can come; a second element stays as the daemon left it), then at full
    power (`element2` as for `time_to_band`). (A controller that acts once a period has
    `seen` = `period`.) On a copy of `plant`."""
    late = copy.deepcopy(plant)
    late.set_heater(True, start)
    on_time = period * duty / 100.0
    if on_time < seen:
        late.set_heater(False, start + on_time)
    rest = time_to_band(late, start + seen, setpoint, limit - seen, element2=element2)
    return None if rest is None else seen + rest


def first_read_after(t: float, read_interval: float) -> float:
    """When the daemon's first reading at or after `t` comes: it reads half an interval after
    it starts (at 0 in a scenario), then once an interval; an event at a reading's own time
    runs before it."""
    half = read_interval / 2.0
    return half + max(0, math.ceil((t - half) / read_interval)) * read_interval


ONE_SETPOINT_KEYS = (
    "overshoot_c",
    "overshoots",
    "settle_s",
    "recovery_s",
    "in_band_fraction",
    "in_band_s",
    "in_band_pct",
    "iae",
    "heatup_overshoot_c",
    "upset_overshoot_c",
    "last_hour_p2p_c",
    "held_in_band_pct",
    "pv_overshoot_c",
    "physical_min_s",
    "settle_ratio",
    "recovery_min_s",
    "recovery_ratio",
    "recovery_floor_s",
    "recovery_floor_ratio",
)
"""The summary's measures of one setpoint's heat-up, hold and recovery: a program's day has
several setpoints, so they are left out; each step's own (`steps`) take their place."""


def _ready_by(ready_at_s: list[float], steps: list[dict[str, Any]]) -> dict[str, Any]:
    """When a `ready_by` program's first step was due and reached, and the difference (s)."""
    if not ready_at_s:
        return {}
    due = round(ready_at_s[0], 1)
    reached = steps[0]["reached_s"] if steps else None
    error = None if reached is None else round(reached - due, 1)
    return {"ready_at_s": due, "first_reached_s": reached, "ready_error_s": error}


def run(
    scenario: Scenario,
    base: Config | None = None,
    *,
    log_dir: Path | None = None,
    keep_records: bool = False,
    outside_plant: Plant | None = None,
    state_dir: Path | None = None,
    tun_model: MeasuredTun | None = None,
    attach: Callable[[Daemon], object] | None = None,
) -> Result:
    """Run `scenario` through the daemon on a virtual clock; measure it (and log it).

    `outside_plant` replaces the scenario's tun (its `plant:` mapping then only gives the sensor's
    noise); it is used up by the run. `state_dir` is the daemon's state directory, kept from
    one run to the next as the service keeps it from one brew day to the next. `tun_model` is
    the tun as measured, for the supervisor's limits (None: not measured). `attach` is called
    with the daemon before it runs: a bench's listeners, or an outer loop of its own that sets
    the daemon's setpoint each period as the control socket would."""
    config = effective_config(base or config_module.DEFAULT, scenario)
    reloads = _reloads(config, scenario)
    started = time.perf_counter()
    clock = VirtualClock() if scenario.clock is None else VirtualClock(0.0, *scenario.clock)
    recorder = None
    if log_dir is not None:
        log_dir.mkdir(parents=True, exist_ok=True)
        recorder = Recorder(
            log_dir,
            now=clock.monotonic,
            metadata={"scenario": scenario.name},
            lossless=True,
        )
    try:
        tun = outside_plant
        if tun is None and "mash" in scenario.plant:
            tun = _herms_tun(config, scenario.plant)
        world = build_world(config, clock, scenario.plant, tun=tun, history=True)
    except (TypeError, ValueError) as error:
        raise ScenarioError(f"plant: {error}") from None
    plant, circuit = world.plant, world.circuit
    check_events(scenario, config, world)
    reference = copy.deepcopy(plant)
    latches = models = None
    if state_dir is not None:
        state_dir.mkdir(parents=True, exist_ok=True)
        latches, models = LatchStore(state_dir), ModelStore(state_dir)
    daemon = assemble(
        config,
        clock,
        world.sensor,
        world.outputs,
        recorder=recorder,
        latches=latches,
        models=models,
        tun_model=tun_model,
        saver=Saver(threaded=False),  # the disk takes no virtual time: the same day every run
        mash_sensor=None if world.mash is None else world.mash.mash_sensor,
        coil_sensor=None if world.mash is None else world.mash.coil_sensor,
        pump_sense=None if world.mash is None else world.mash.pump_sense,
        current_sense=world.current,
    )
    program = scenario.program
    herms_day = config.mash_sensor.fitted  # judged on the mash: its records are needed
    collector = _Collector(plant, keep_records=keep_records or program is not None or herms_day)
    daemon.listeners.append(collector)
    if attach is not None:
        attach(daemon)
    brewer = _Brewer(daemon)
    ready_at_s: list[float] = []  # a program's ready_by, in the run's seconds
    if program is not None:

        def start_program() -> None:  # as a brewer would, with the daemon running
            problems = daemon.program_problems(program)  # a program resumed from the state too
            if problems:
                raise ScenarioError(f"program: {'; '.join(problems)}")
            daemon.start_program(program, None, clock.monotonic())
            if program.ready_by is not None:
                wall = clock.wall_ns()
                due = next_local_time(wall, program.ready_by, clock.zone)
                ready_at_s.append(clock.monotonic() + (due - wall) / 1e9)

        clock.call_at(config.control.period / 2, start_program)
        daemon.listeners.append(brewer)

    recovery_min: dict[str, float | None] = {}
    period = config.control.period
    element2 = config.element2.backend != "none"  # full power: both elements, as world's
    fault_times: list[float] = []

    def measure(index: int, event: Event, t: float) -> None:
        """What an event of the tun (not an answer) sets the run's measures to."""
        if event.kind in FAULT_KINDS and event.value not in (
            ("ok", None),
            "ok",
        ):
            fault_times.append(t)
        snapshot = copy.deepcopy(plant)
        sp = event.value if event.kind == "setpoint" else daemon.setpoint
        if index in reloads:
            sp = reloads[index].control.setpoint
        seen = first_read_after(t, config.sensor.read_interval) - t
        recovery_min["floor"] = reactive_floor(
            snapshot, t, sp, scenario.duration, period, daemon.output, seen, element2=element2
        )
        recovery_min["s"] = time_to_band(snapshot, t, sp, scenario.duration, element2=element2)

    schedule_events(scenario, reloads, clock, world, daemon, brewer, measure)
    try:
        with daemon:
            daemon.run(until=scenario.duration)
    finally:
        if recorder is not None:
            recorder.close()
    wall = time.perf_counter() - started

    ended = min(scenario.duration, clock.monotonic())  # an attached loop may end it early
    disturbances = [e.at for e in scenario.events if e.kind != "confirm" and e.at <= ended]
    metrics = compute(collector.samples, disturbances, ended, circuit.ssr_edges)
    physical_min = time_to_band(
        reference, 0.0, config.control.setpoint, scenario.duration, element2=element2
    )
    alarms = []
    for alarm in collector.alarms:
        off = circuit.off_at_or_after(alarm.at)
        fault = max((f for f in fault_times if f <= alarm.at), default=None)
        alarms.append(
            {
                "at_s": round(alarm.at, 3),
                "kind": alarm.kind,
                "heater_off_after_s": None if off is None else round(off - alarm.at, 3),
                "detected_after_s": None if fault is None else round(alarm.at - fault, 3),
                "message": alarm.message,
            }
        )
    recovery_min_s = recovery_min.get("s")
    recovery_floor_s = recovery_min.get("floor")
    summary: dict[str, Any] = {
        "scenario": scenario.name,
        "algorithm": config.control.algorithm,
        "duration_s": scenario.duration,
        "temperature": SIMULATED_TEMPERATURE,
        **report(metrics),
        "pv_overshoot_c": round(compute(collector.pv_samples, disturbances, ended).overshoot_c, 4),
        "physical_min_s": None if physical_min is None else round(physical_min, 1),
        "settle_ratio": _ratio(metrics.settle_s, physical_min),
        "recovery_min_s": None if recovery_min_s is None else round(recovery_min_s, 1),
        "recovery_ratio": _ratio(metrics.recovery_s, recovery_min_s),
        "recovery_floor_s": None if recovery_floor_s is None else round(recovery_floor_s, 1),
        "recovery_floor_ratio": _ratio(recovery_floor_s, recovery_min_s),
        "alarms": alarms,
        "element_warnings": [
            {"at_s": round(at, 3), "element": element}
            for element, at in sorted(collector.warned.items(), key=lambda kv: kv[1])
        ],
        "overruns": daemon.overruns,
        "wall_s": round(wall, 3),
    }
    herms = [r for r in collector.records if r.hlt_setpoint is not None]
    if herms and program is None:
        for key in ONE_SETPOINT_KEYS:  # the outer loop moves the HLT's setpoint: the mash says
            del summary[key]
        summary["temperature"] = SIMULATED_TEMPERATURE.partition(";")[0] + ")"
        summary["mash"] = _mash_summary(herms, config.herms.max_hlt_above_mash)
    if program is not None:
        steps = step_quality(((r.t, r) for r in collector.records), mash_in_index(program))
        for key in ONE_SETPOINT_KEYS:  # the program moves the setpoint: its steps say it
            del summary[key]
        summary["temperature"] = SIMULATED_TEMPERATURE.partition(";")[0] + ")"  # no pv_…
        summary["program"] = {
            "name": program.name,
            "state": daemon.program.runner.state if daemon.program.runner else "stopped",
            "steps_run": len({step["index"] for step in steps}),
            "steps": len(program.steps),
            **_ready_by(ready_at_s, steps),
        }
        summary["steps"] = steps
    records = collector.records if keep_records else []
    return Result(summary, collector.samples, records)


def check_events(scenario: Scenario, config: Config, world: World) -> None:
    """ScenarioError for an event the simulated hardware cannot take: a mash event without
    a HERMS plant, a sensor fault the config's kind has not, a second element's without one."""
    if as_herms_plant(world.plant) is None and any(e.kind in MASH_EVENTS for e in scenario.events):
        raise ScenarioError(
            f"{scenario.source or scenario.name}: events: dough_in, pump and recirculation "
            "need a HERMS plant (a plant: mash: mapping, or --plant with "
            "hermsd.sim.mash.HermsPlant's methods)"
        )
    chip = None if world.mash is None else world.mash.mash_chip
    if chip is None and any(e.kind == "mash_sensor" for e in scenario.events):
        raise ScenarioError("events: mash_sensor needs a mash sensor (mash_sensor.kind)")
    for event in scenario.events:
        if event.kind not in ("sensor", "mash_sensor"):
            continue
        sensor = config.sensor if event.kind == "sensor" else config.mash_sensor
        if event.value[0] not in FAULTS[sensor.kind]:
            raise ScenarioError(
                f"events: the {event.kind} fault {event.value[0]!r} at {event.at:g} s is not "
                f"one a {sensor.kind} has (expected one of {', '.join(FAULTS[sensor.kind])})"
            )
    if world.circuit.relay2 is None and any(
        e.kind in ("heater2", "relay2") for e in scenario.events
    ):
        raise ScenarioError("events: heater2 and relay2 need a second element (element2.backend)")
    if world.current is None and any(e.kind == "current" for e in scenario.events):
        raise ScenarioError("events: current needs the element's current input (current.kind)")


def schedule_events(
    scenario: Scenario,
    reloads: dict[int, Config],
    clock: VirtualClock,
    world: World,
    daemon: Daemon,
    brewer: _Brewer,
    measure: Callable[[int, Event, float], None] | None = None,
) -> None:
    """Each of the scenario's events on `clock` at its time: a config saved (`reloads`,
    by event index), an answer handed to the `brewer`, else the tun, the hardware or the
    daemon changed (then `measure`d), and a sensor fault that lasts ended."""

    def schedule(index: int, event: Event) -> None:
        def fire() -> None:
            t = clock.monotonic()
            if index in reloads:
                daemon.reload(reloads[index])
            if event.kind == "confirm":
                brewer.answers.append(event.value)
                return  # an answer, not a disturbance of the tun
            if event.kind == "current":  # the current input's own fault (sim/circuit.py)
                assert world.current is not None  # check_events refuses it without one
                world.current.set_fault(event.value)
                return
            if event.kind == "mash_sensor":  # the mash's own sensor, not the tun
                _faulted_chip(event, world).set_fault(*event.value)
                return
            _apply(event, t, world.plant, world.chip, world.circuit, daemon)
            if measure is not None:
                measure(index, event, t)

        clock.call_at(event.at, fire)
        if event.kind in ("sensor", "mash_sensor") and event.lasts is not None:
            chip = _faulted_chip(event, world)
            clock.call_at(event.at + event.lasts, lambda: chip.set_fault("ok"))

    for index, event in enumerate(scenario.events):
        schedule(index, event)


def _faulted_chip(event: Event, world: World) -> FakeChip:
    """The fake sensor an event faults: the mash's for `mash_sensor` (check_events refuses
    one without it), else the HLT's."""
    if event.kind == "mash_sensor":
        chip = None if world.mash is None else world.mash.mash_chip
        assert chip is not None
        return chip
    return world.chip


def _mash_summary(records: list[PeriodRecord], limit: float) -> dict[str, Any]:
    """A HERMS day under the outer loop, judged on the mash's sensor: how far it rose above
    its setpoint, and the HLT's highest reading against the limit (mash setpoint + limit)."""
    read = [r for r in records if r.mash is not None]
    over = max((r.mash - r.setpoint for r in read if r.mash is not None), default=None)
    hlt = max((c for r in records for c in r.readings), default=None)
    return {
        "setpoint_c": records[-1].setpoint,
        "last_c": None if not read else read[-1].mash,
        "highest_above_setpoint_c": None if over is None else round(over, 4),
        "hlt_highest_c": hlt,
        "hlt_limit_c": max(r.setpoint for r in records) + limit,
    }


@dataclass(slots=True)
class _Brewer:
    """Answers the program's confirmations the scenario's `confirm` events allow."""

    daemon: Daemon
    answers: list[str] = field(default_factory=list)

    def period(self, record: PeriodRecord) -> None:
        status = self.daemon.program.status(0)
        if status is None or status["state"] != "waiting" or status["message"] not in self.answers:
            return
        self.answers.remove(status["message"])
        self.daemon.program_command("confirm", record.t)

    def alarm(self, alarm: Alarm) -> None:
        """Alarms are the supervisor's; the brewer answers only the program."""


def _ratio(value: float | None, minimum: float | None) -> float | None:
    if value is None or minimum is None or minimum <= 0:
        return None
    return round(value / minimum, 4)


def _apply(
    event: Event,
    t: float,
    plant: Plant,
    chip: FakeChip,
    circuit: HeaterCircuit,
    daemon: Daemon,
) -> None:
    kind, value = event.kind, event.value
    if kind == "add_water":
        plant.add_water(value["litres"], value["temp"], t)
    elif kind == "ambient":
        plant.set_ambient(value, t)
    elif kind == "setpoint":
        daemon.set_setpoint(value)
    elif kind == "mode":
        daemon.set_auto() if value == "auto" else daemon.set_manual()
    elif kind == "output":
        daemon.set_manual(value)
    elif kind == "sensor":
        fault, amount = value
        chip.set_fault(fault, amount)
    elif kind == "heater":
        circuit.set_element_ok(value == "ok", t)
    elif kind == "ssr":
        circuit.set_stuck_on(value == "stuck_on")
    elif kind == "relay2":
        circuit.set_relay2_stuck_on(value == "stuck_on")
    elif kind == "heater2":
        if not isinstance(plant, TwoElementPlant):
            raise ScenarioError("heater2: the plant has no second element")
        plant.set_element2_ok(value == "ok", t)
    elif kind in MASH_EVENTS:
        herms = as_herms_plant(plant)
        assert herms is not None  # run() refuses mash events without a HERMS plant
        if kind == "dough_in":
            grain_kg, grain_c = value["grain_kg"], value["grain_c"]
            herms.dough_in(grain_kg, grain_c, value["water_litres"], value["water_c"], t)
        elif kind == "pump" and daemon.pump_fitted:
            daemon.set_pump(value, "by the operator")  # hermsd switches it: through hermsd
        elif kind == "pump":
            herms.set_pump(value, t)
        else:
            herms.set_recirculation_ok(value == "ok", t)
