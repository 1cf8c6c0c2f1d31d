"""The mash program file: named steps, each a setpoint held for a time, read strictly.

The file is YAML, read by the config's own reader (`hermsd.config`): the same plain-scalar
grammar (no octal, no sexagesimal surprises), the same checks of each value and the same
`FILE:LINE:COL: key: what is wrong (what would be right)` messages, every problem at once.
A program sent over the control socket is its `to_data` form, checked again the same way.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from hermsd.config import read
from hermsd.config import schema as config_module
from hermsd.config.schema import ConfigError, Problem
from hermsd.durations import NoUnit, parse_duration

MAX_STEPS = 50
NAME_LENGTH = 40
MESSAGE_LENGTH = 120
MAX_HOLD_S = 24 * 3600.0
MAX_RAMP = 10.0  # °C per minute: faster than any element heats a tun
SETPOINT_RANGE = (0.0, 100.0)  # °C: the water's, liquid
# The slowest ramp still crosses the widest span of setpoints within the 24 h a hold may
# last: 100 °C / 1440 min = 0.0694 °C/min, rounded up to the two decimals a ramp is written
# with. Slower, a step would "ramp" for days (1e-300 °C/min: for ever) without a word.
MIN_RAMP = math.ceil((SETPOINT_RANGE[1] - SETPOINT_RANGE[0]) / (MAX_HOLD_S / 60.0) * 100) / 100
UNTIL_TOLD = "until told"
HOLD_EXPECTED = (
    f"a duration such as 90s, 60m or 1h30m (at most {MAX_HOLD_S / 3600:g} h), or {UNTIL_TOLD!r}"
)
READY_BY = re.compile(r"(?P<hour>[01][0-9]|2[0-3]):(?P<minute>[0-5][0-9])")

_TOP_KEYS = ["name", "ready_by", "steps"]
_STEP_KEYS = [
    "name",
    "setpoint",
    "hold",
    "ramp",
    "confirm",
    "pump",
    *("pump_off_every", "pump_off_for"),
]
PUMP_WORDS = {"on": True, "off": False}
PUMP_TIMER_KEYS = ("pump_off_every", "pump_off_for")
LEAST_PUMP_STOP_S = 10.0  # s: a shorter stop is a relay's chatter, not a stir
LEAST_PUMP_RUN_S = 60.0  # s the pump runs each cycle at the least: the hoses filled again


@dataclass(frozen=True, slots=True)
class Step:
    """One rest: reach `setpoint`, hold it `hold` s (None: until told), then maybe wait."""

    name: str
    setpoint: float
    hold: float | None
    ramp: float | None = None  # °C per minute; None: the setpoint moves at once
    confirm: str | None = None  # asked of the brewer at the end of the hold
    pump: bool | None = None  # None: on once the mash is in (`pump_wanted`), off before
    pump_timer: tuple[float, float] | None = None  # (every, for) s: stopped `for` each `every`


@dataclass(frozen=True, slots=True)
class Program:
    name: str
    steps: tuple[Step, ...]
    ready_by: str | None = None  # local "HH:MM"


def mash_in_index(program: Program) -> int:
    """The first step on the mash: the one after a first step that waits for the brewer (the
    strike water's, "Mash in"), else the first: a program without that wait starts mashed in."""
    return 1 if program.steps[0].confirm is not None else 0


def strike_warnings(program: Program, max_hlt_above_mash: float) -> list[str]:
    """What a HERMS cannot honour: a step before the mash is in (the strike water, held on the
    HLT) above the first rest + `max_hlt_above_mash` leaves the HLT above its limit when the
    pump starts, and an HLT cannot be cooled ('steps[0]: …' lines; [] when none)."""
    first = mash_in_index(program)
    if first >= len(program.steps):
        return []
    rest = program.steps[first]
    limit = rest.setpoint + max_hlt_above_mash
    return [
        f"steps[{index}].setpoint: {step.name} {step.setpoint:g} °C is above the first rest "
        f"{rest.name} {rest.setpoint:g} °C + herms.max_hlt_above_mash {max_hlt_above_mash:g} °C "
        f"= {limit:g} °C: the HLT will stand above the limit when the pump starts; lower the "
        "strike or raise herms.max_hlt_above_mash"
        for index, step in enumerate(program.steps[:first])
        if step.setpoint > limit
    ]


def config_warnings(program: Program, config: config_module.Config) -> list[str]:
    """What `config` cannot do of `program` ('steps[0]: …' lines; [] when none): a strike
    above the HLT's limit (`strike_warnings`, with a mash sensor fitted), and a pump timer
    where hermsd switches no pump (`pump.backend: none`): it stops nothing."""
    warnings = []
    if config.mash_sensor.fitted:
        warnings += strike_warnings(program, config.herms.max_hlt_above_mash)
    if config.pump.backend == config_module.NOT_FITTED:
        warnings += [
            f"steps[{index}].pump_off_every: pump.backend is none: hermsd switches no pump, "
            "so this timer stops nothing (fit the pump's switch, or leave the timer out)"
            for index, step in enumerate(program.steps)
            if step.pump_timer is not None
        ]
    return warnings


def pump_wanted(program: Program, index: int) -> bool:
    """Whether step `index` runs the pump: as it says, else on once the mash is in."""
    step = program.steps[index]
    return step.pump if step.pump is not None else index >= mash_in_index(program)


class ProgramError(ConfigError):
    """A program that cannot be used; `str()` lists every problem, one per line."""


def _field(path: str, kind: type, example: object, **spec: Any) -> config_module._Field:
    """A key of the program; one left out has no default (`left_out` says what it means)."""
    nullable = spec.pop("nullable", False)
    spec.setdefault("left_out", "")
    return config_module._Field(path, kind, nullable, example, config_module._Spec(**spec))


def _name_field(path: str, left_out: str = "") -> config_module._Field:
    return _field(path, str, "Saccharification", max_length=NAME_LENGTH, left_out=left_out)


class _Reader(read._Reader):
    @staticmethod
    def _suggest(key: str, prefix: str, known: list[str]) -> str:
        import difflib

        close = difflib.get_close_matches(key, known, n=1)
        if close:
            return f"did you mean {close[0]!r}?"
        return f"the keys here are: {', '.join(known)}"

    def value(self, info: config_module._Field, node: yaml.Node) -> Any:
        """The checked value of one key, or None (reported) when it is wrong."""
        try:
            return config_module._convert(info, node)
        except config_module._Invalid as problem:
            self.report(problem.mark or node.start_mark, info.path, str(problem))
            return None

    def program(self, root: yaml.Node | None, default_name: str) -> Program | None:
        if root is None or not isinstance(root, yaml.MappingNode):
            mark = root.start_mark if root is not None else None
            got = "nothing" if root is None else config_module._describe(root)
            self.report(mark, "", f"a program is a mapping with steps, got {got} (see README)")
            return None
        values = dict(self.items(root, "", _TOP_KEYS))
        name = default_name
        if "name" in values:
            name = self.value(_name_field("name", "the file's name"), values["name"]) or name
        ready_by = None
        if "ready_by" in values:
            ready_by = self.ready_by(values["ready_by"])
        steps = self.steps(values.get("steps"), root)
        if self.problems or steps is None:
            return None
        return Program(name[:NAME_LENGTH], steps, ready_by)

    def ready_by(self, node: yaml.Node) -> str | None:
        info = _field("ready_by", str, "06:30", max_length=5, nullable=True)
        text = self.value(info, node)
        if text is not None and READY_BY.fullmatch(text) is None:
            self.report(
                node.start_mark,
                "ready_by",
                f"{text!r} is not a local time (HH:MM on a 24 h clock, e.g. '06:30')",
            )
            return None
        return str(text) if text is not None else None

    def steps(self, node: yaml.Node | None, root: yaml.Node) -> tuple[Step, ...] | None:
        if node is None:
            self.report(root.start_mark, "steps", f"missing (a list of 1 to {MAX_STEPS} steps)")
            return None
        if not isinstance(node, yaml.SequenceNode) or not 1 <= len(node.value) <= MAX_STEPS:
            got = (
                f"{len(node.value)} steps"
                if isinstance(node, yaml.SequenceNode)
                else config_module._describe(node)
            )
            self.report(
                node.start_mark,
                "steps",
                f"expected a list of 1 to {MAX_STEPS} steps ('- name: ...' lines), got {got}",
            )
            return None
        steps: list[Step] = []
        first_place: dict[str, str] = {}
        for index, item in enumerate(node.value):
            step = self.step(f"steps[{index}]", item)
            if step is None:
                continue
            if step.name in first_place:
                self.report(
                    item.start_mark,
                    f"steps[{index}].name",
                    f"{step.name!r} names an earlier step too ({first_place[step.name]}; "
                    "give each step its own name)",
                )
            first_place.setdefault(step.name, self.place(index, item))
            steps.append(step)
        return tuple(steps)

    def place(self, index: int, node: yaml.Node) -> str:
        """Where the brewer finds step `index` of the file: its line."""
        return f"line {node.start_mark.line + 1}"

    def step(self, path: str, node: yaml.Node) -> Step | None:
        if not isinstance(node, yaml.MappingNode):
            self.report(
                node.start_mark,
                path,
                f"expected a step (name, setpoint, hold), got {config_module._describe(node)}",
            )
            return None
        before = len(self.problems)
        values = dict(self.items(node, path, _STEP_KEYS))
        for key in ("name", "setpoint", "hold"):
            if key not in values:
                self.report(node.start_mark, f"{path}.{key}", f"missing ({_REQUIRED[key]})")
        name = setpoint = None
        hold: float | None = None
        if "name" in values:
            name = self.value(_name_field(f"{path}.name"), values["name"])
        if "setpoint" in values:
            low, high = SETPOINT_RANGE
            info = _field(f"{path}.setpoint", float, 66.0, unit="°C", low=low, high=high)
            setpoint = self.value(info, values["setpoint"])
        if "hold" in values:
            hold = self.hold(f"{path}.hold", values["hold"])
        ramp = confirm = None
        if "ramp" in values:
            info = _field(
                f"{path}.ramp",
                float,
                1.0,
                unit="°C/min",
                low=MIN_RAMP,
                high=MAX_RAMP,
                nullable=True,
                null_means="at once",
            )
            ramp = self.value(info, values["ramp"])
        if "confirm" in values:
            info = _field(
                f"{path}.confirm",
                str,
                "Mash in",
                max_length=MESSAGE_LENGTH,
                left_out="a step that does not wait",
            )
            confirm = self.value(info, values["confirm"])
            if confirm is not None and hold is None and "hold" in values:
                self.report(
                    values["confirm"].start_mark,
                    f"{path}.confirm",
                    f"a step held {UNTIL_TOLD!r} ends with `hermsd program next`, never "
                    "waits (give the hold a time, or leave confirm out)",
                )
        mash_in = confirm if path == "steps[0]" else None
        pump = self.pump(f"{path}.pump", values.get("pump"), mash_in)
        timer = self.pump_timer(path, node, values, off=pump is False or bool(mash_in))
        if len(self.problems) > before or name is None or setpoint is None:
            return None
        return Step(str(name), float(setpoint), hold, ramp, confirm, pump, timer)

    def pump_timer(
        self, path: str, node: yaml.Node, values: dict[str, yaml.Node], *, off: bool
    ) -> tuple[float, float] | None:
        """`pump_off_every` and `pump_off_for` together (a recirculation timer: the pump
        stopped `for` at the end of each `every` from the step's start), on a step whose
        pump runs (`off`: it does not); None when both are left out."""
        given = [key for key in PUMP_TIMER_KEYS if key in values]
        if not given:
            return None
        if len(given) == 1:
            missing = next(key for key in PUMP_TIMER_KEYS if key not in values)
            self.report(
                node.start_mark,
                f"{path}.{missing}",
                f"missing (a pump timer needs both {' and '.join(PUMP_TIMER_KEYS)}, e.g. "
                "pump_off_every: 20m and pump_off_for: 2m)",
            )
            return None
        every, stop = (self.timer_span(f"{path}.{key}", values[key]) for key in PUMP_TIMER_KEYS)
        if off:
            self.report(
                values["pump_off_every"].start_mark,
                f"{path}.pump_off_every",
                "a pump timer on a step whose pump is off (write pump: on, or leave the timer out)",
            )
            return None
        if every is None or stop is None:
            return None
        if stop < LEAST_PUMP_STOP_S or every - stop < LEAST_PUMP_RUN_S:
            self.report(
                values["pump_off_for"].start_mark,
                f"{path}.pump_off_for",
                f"{stop:g} s off every {every:g} s: stop the pump {LEAST_PUMP_STOP_S:g} s at "
                f"the least, and leave it running {LEAST_PUMP_RUN_S:g} s of each cycle",
            )
            return None
        return every, stop

    def timer_span(self, path: str, node: yaml.Node) -> float | None:
        """A pump timer's duration in s, as a hold is written ('until told' refused)."""
        if isinstance(node, yaml.ScalarNode) and node.value == UNTIL_TOLD:
            self.report(node.start_mark, path, "a pump timer's times are durations, e.g. 20m")
            return None
        before = len(self.problems)
        seconds = self.hold(path, node)
        return seconds if len(self.problems) == before else None

    def pump(self, path: str, node: yaml.Node | None, mash_in: str | None) -> bool | None:
        """`on` or `off` (None: left out); `on` is refused on a first step that waits for the
        brewer: the tun holds no mash yet, and a pump run dry is harmed."""
        if node is None:
            return None
        info = _field(path, str, "on", choices=tuple(PUMP_WORDS), left_out="on once mashed in")
        on = _plain_bool(node)
        if on is None:
            word = self.value(info, node)
            if word is None:
                return None
            on = PUMP_WORDS[word]
        if on and mash_in:
            self.report(
                node.start_mark,
                path,
                f"the pump stays off until the mash is in (this step waits for {mash_in!r}; "
                "write pump: off, or leave it out)",
            )
        return on

    def hold(self, path: str, node: yaml.Node) -> float | None:
        """Seconds, or None for 'until told' (a wrong value is reported, and None)."""
        if isinstance(node, yaml.ScalarNode) and node.style is None:
            try:
                plain = config_module._plain_value(node.value)
            except config_module._TooLong:
                plain = None
            if isinstance(plain, int | float) and not isinstance(plain, bool):
                return self.bare_hold(path, node, plain)
        if config_module._is_null(node):
            self.report(node.start_mark, path, f"has no value ({HOLD_EXPECTED})")
            return None
        text = self.value(_field(path, str, "60m", nullable=False), node)
        if text is None or text == UNTIL_TOLD:
            return None
        return self.duration_hold(path, node, text)

    def bare_hold(self, path: str, node: yaml.Node, number: float) -> float | None:
        """A hold written as a bare number: refused, since 60 may mean minutes or seconds."""
        return self.duration_hold(path, node, node.value)

    def duration_hold(self, path: str, node: yaml.Node, text: str) -> float | None:
        """The seconds of a hold written as a duration with its unit."""
        try:
            seconds = parse_duration(text, unit_required=True)
        except NoUnit as problem:
            self.report(node.start_mark, path, str(problem))
            return None
        except ValueError:
            seconds = -1.0
        return self.hold_within(path, node, text, seconds)

    def hold_within(self, path: str, node: yaml.Node, shown: object, seconds: float) -> float:
        """`seconds`, reported (as `shown`) when it is no hold."""
        if not 0.0 <= seconds <= MAX_HOLD_S:
            self.report(node.start_mark, path, f"{shown!r} is not a hold ({HOLD_EXPECTED})")
        return seconds


def _plain_bool(node: yaml.Node) -> bool | None:
    """A plain true or false (a scenario's YAML 1.1 reads `on` so), else None."""
    if not isinstance(node, yaml.ScalarNode) or node.style is not None:
        return None
    return config_module._BOOLS.get(node.value)


_REQUIRED = {
    "name": f"text of 1 to {NAME_LENGTH} characters, unique in the program",
    "setpoint": "°C, e.g. 66",
    "hold": f"a duration such as 60m, or {UNTIL_TOLD!r}",
}


class _DataReader(_Reader):
    """Reads a program sent as data (`to_data`'s form), which has no lines to point at."""

    def place(self, index: int, node: yaml.Node) -> str:
        return f"steps[{index}]"

    def bare_hold(self, path: str, node: yaml.Node, number: float) -> float | None:
        """The data form's holds are seconds, as `to_data` writes them (a program's own)."""
        return self.hold_within(path, node, number, float(number))


class _TypedDataReader(_DataReader):
    """Reads a program typed by hand as data (a scenario's inline program): units required."""

    bare_hold = _Reader.bare_hold


_NOWHERE = yaml.Mark("<data>", 0, 0, 0, "", 0)
_DATA_DEPTH = 3  # program, steps, step: deeper lists and objects are only ever described


def _data_node(value: object, depth: int = 0) -> yaml.Node:
    """`value` (JSON data) as the node the file's text for it would compose to.

    Strings are quoted scalars (always text, as the file's quoted strings are); numbers,
    booleans and null are plain ones that `config._plain_value` reads back as they were.
    Building the nodes directly spares the dump to YAML and the parse back, which for a
    64 KiB request cost a tenth of a second of the interpreter's lock.
    """
    if isinstance(value, dict | list):
        deeper = depth + 1
        if isinstance(value, list):
            items = [_data_node(item, deeper) for item in value] if depth < _DATA_DEPTH else []
            tag = config_module._RESOLVER.DEFAULT_SEQUENCE_TAG
            return yaml.SequenceNode(tag, items, _NOWHERE, _NOWHERE)
        pairs = (
            [(_data_node(str(key)), _data_node(item, deeper)) for key, item in value.items()]
            if depth < _DATA_DEPTH
            else []
        )
        tag = config_module._RESOLVER.DEFAULT_MAPPING_TAG
        return yaml.MappingNode(tag, pairs, _NOWHERE, _NOWHERE)
    style: str | None = None
    if value is None:
        text = "null"
    elif isinstance(value, bool):
        text = "true" if value else "false"
    elif isinstance(value, int | float):
        text = repr(value)
    else:
        text, style = str(value), '"'
    implicit = (style is None, style is not None)
    tag = config_module._RESOLVER.resolve(yaml.ScalarNode, text, implicit)  # type: ignore[no-untyped-call]
    return yaml.ScalarNode(tag, text, _NOWHERE, _NOWHERE, style)


def _checked(reader: _Reader, root: yaml.Node | None, filename: str) -> Program:
    """The program `root` holds, read by `reader`; ProgramError lists everything wrong."""
    program = reader.program(root, Path(filename).stem[:NAME_LENGTH] or "program")
    if reader.problems or program is None:
        problems = reader.problems or [Problem(filename, 1, 1, "", "not a program")]
        raise ProgramError(sorted(problems, key=lambda p: (p.line, p.column)))
    return program


def parse(text: str, filename: str = "<program>") -> Program:
    """The program a YAML text describes; ProgramError lists everything wrong with it.

    Every rule of a program file, its length too: text made in memory (an import) passes
    here exactly when its file would pass `load` (and `program check`)."""
    try:
        read.check_size(text, filename)
        root = read._root(text, filename)
    except ConfigError as error:
        raise ProgramError(error.problems) from None
    return _checked(_Reader(filename), root, filename)


def load(path: str | os.PathLike[str]) -> Program:
    """The program in a file; ProgramError (never OSError) when it cannot be read or used."""
    filename = os.fspath(path)
    try:
        text = read._read_text(filename)
    except ConfigError as error:
        hint = ", or copy config/hermsd.yaml there"  # the config's advice, not a program's
        problems = [p._replace(message=p.message.replace(hint, "")) for p in error.problems]
        raise ProgramError(problems) from None
    return parse(text, filename)


def to_data(program: Program) -> dict[str, Any]:
    """The program as plain JSON-able data (what the socket carries and the state keeps)."""
    return {
        "name": program.name,
        "ready_by": program.ready_by,
        "steps": [
            {
                "name": step.name,
                "setpoint": step.setpoint,
                "hold": UNTIL_TOLD if step.hold is None else step.hold,
                "ramp": step.ramp,
                "confirm": step.confirm,
                "pump": None if step.pump is None else ("on" if step.pump else "off"),
                **dict(zip(PUMP_TIMER_KEYS, step.pump_timer or (None, None), strict=True)),
            }
            for step in program.steps
        ],
    }


def from_data(data: Any, source: str = "<program>", *, typed: bool = False) -> Program:
    """The program `to_data` made, checked exactly as a file is (ProgramError if it is not).

    Its holds may be bare numbers of seconds, unless `typed` (by hand: a scenario's inline
    program), where a hold must say its unit as in a file.
    """
    if not isinstance(data, dict):
        raise ProgramError([Problem(source, 0, 0, "", "a program is an object with steps")])
    cleaned = {key: value for key, value in data.items() if value is not None}
    if isinstance(cleaned.get("steps"), list):
        cleaned["steps"] = [
            {k: v for k, v in step.items() if v is not None} if isinstance(step, dict) else step
            for step in cleaned["steps"]
        ]
    reader = _TypedDataReader(source) if typed else _DataReader(source)
    return _checked(reader, _data_node(cleaned), source)


def describe_step(step: Step) -> str:
    """'Saccharification: 66 °C, hold 60 min, ramp 1 °C/min, then waits for: Mash in'."""
    hold = UNTIL_TOLD if step.hold is None else f"hold {step.hold / 60.0:g} min"
    words = f"{step.name}: {step.setpoint:g} °C, {hold}"
    if step.ramp is not None:
        words += f", ramp {step.ramp:g} °C/min"
    if step.pump is not None:
        words += f", pump {'on' if step.pump else 'off'}"
    if step.pump_timer is not None:
        every, stop = step.pump_timer
        words += f", pump off {stop / 60.0:g} min every {every / 60.0:g} min"
    if step.confirm is not None:
        words += f", then waits for: {step.confirm}"
    return words


def one_line(error: ConfigError) -> str:
    """Every problem of `error` on one line (for the socket's reply)."""
    return "; ".join(
        f"{problem.key_path}: {problem.message}" if problem.key_path else problem.message
        for problem in error.problems
    )
