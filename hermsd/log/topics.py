"""The flight recorder's format: its topics and their fields, file names and metadata.

Apart from the recorder that writes them, for every reader of a log (the MCAP reader,
replay, the plot, Foxglove's layout)."""

from __future__ import annotations

import dataclasses
import json
import types
import typing
from dataclasses import dataclass
from enum import IntEnum
from typing import Any, Final

from hermsd import __version__
from hermsd.config.schema import Config
from hermsd.control.learning import LearnedModel
from hermsd.control.pid import PlantModel

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
    later, so the logs written before them still read), and no other is allowed: a field
    the schema does not declare is one a schema-driven reader (Foxglove) cannot see."""
    return {
        "title": title,
        "description": description,
        "type": "object",
        "properties": properties,
        "required": [name for name in properties if name not in optional],
        "additionalProperties": False,
    }


_JSON_TYPES: Final[dict[object, str]] = {
    float: "number",
    int: "integer",
    str: "string",
    bool: "boolean",
    type(None): "null",
}


def _dataclass_schema(
    record: type, description: str, *, nullable: bool = False, optional: tuple[str, ...] = ()
) -> dict[str, Any]:
    """The schema of a dataclass as `dataclasses.asdict` writes it (tuples as lists); every
    field required but the `optional` ones (added later, or not written everywhere).

    Derived from its fields' types, so a field added to the class is declared in the log.
    """
    hints = typing.get_type_hints(record)
    properties = {f.name: _type_schema(hints[f.name]) for f in dataclasses.fields(record)}
    schema: dict[str, Any] = {
        "type": ["object", "null"] if nullable else "object",
        "description": description,
        "properties": properties,
        "required": [name for name in properties if name not in optional],
        "additionalProperties": False,
    }
    return schema


def _type_schema(hint: Any) -> dict[str, Any]:
    if dataclasses.is_dataclass(hint) and isinstance(hint, type):
        return _dataclass_schema(hint, hint.__doc__ or hint.__name__)
    if isinstance(hint, types.UnionType):
        kinds = [_type_schema(member) for member in typing.get_args(hint)]
        if len(kinds) == 2 and {"type": "null"} in kinds:  # X | None
            [kind] = [k for k in kinds if k != {"type": "null"}]
            return {**kind, "type": [kind["type"], "null"]}
        raise TypeError(f"no JSON schema for {hint}")
    if typing.get_origin(hint) is tuple:
        item, *_ = typing.get_args(hint)
        return {"type": "array", "items": _type_schema(item)}
    return {"type": _JSON_TYPES[hint]}


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
                "setpoint": _field("number", "setpoint, °C (the mash's with a mash sensor fitted)"),
                "pv": _field(["number", "null"], "process value for the period, °C"),
                "readings": _field(
                    "array", "sensor readings of the period, °C", items={"type": "number"}
                ),
                "output": _field("number", "controller output, %"),
                "applied": _field(
                    "number",
                    "duty the SSR was driven at in the period before, as switched (with "
                    "output.swing: the heat its runs carry counted when asked), %",
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
                "no_heat": _field(
                    ["array", "null"],
                    "the reports standing (two elements): 1 or 2 that element gives no heat, "
                    "0 one of them does, 3 more heat came than asked",
                    items={"type": "integer", "enum": [0, 1, 2, 3]},
                ),
                "ceiling": _field(
                    ["number", "null"],
                    "where full power levels the water out, while short of the setpoint, °C",
                ),
                "mash": _field(
                    ["number", "null"],
                    "the mash sensor's latest good reading, °C (null: none fitted, or faulty)",
                ),
                "coil": _field(
                    ["number", "null"],
                    "the coil outlet sensor's latest good reading, °C (null: none fitted, or "
                    "faulty)",
                ),
                "pump": _field(["boolean", "null"], "the HERMS pump running (null: none fitted)"),
                "hlt_setpoint": _field(
                    ["number", "null"],
                    "the HLT's setpoint the mash's outer loop chose, °C, what the HLT law "
                    "stepped to (null: no mash sensor; setpoint is then the mash's)",
                ),
                "coil_load": _field(
                    ["number", "null"],
                    "the coil's load fed forward to the HLT law, W (null: no mash sensor)",
                ),
                "coil_load_met": _field(
                    ["boolean", "null"],
                    "false: the coil_load is a draw the HLT law lets act, sending no heat for "
                    "it (the coast above its setpoint); null: fed forward",
                ),
                "cascade": _field(
                    ["string", "null"],
                    "the outer loop's phase (null: no mash sensor)",
                    enum=["climb", "coast", "hold", "ready", "no flow", "held", "strike", None],
                ),
                "pump_in": _field(
                    ["number", "null"],
                    "s until a prepared pump start: the coil_load fed forward begins then "
                    "(null: none pending)",
                ),
                "pump_stop_in": _field(
                    ["number", "null"],
                    "s until a pump stop the program's timer announces: the coil_load fed "
                    "forward ends then (null: none announced)",
                ),
                "coil_k": _field(
                    ["number", "null"],
                    "the coil's conductance the coil_load was reckoned on, W/K: the HLT law "
                    "learns the share of that load the water shows until it changes (null: no "
                    "load reckoned)",
                ),
                "current": _field(
                    ["array", "null"],
                    "the element's current input's samples in the period, each [t, the SSR "
                    "commanded on, drawing (null: the read failed), amps (null: none measured), "
                    "why the read failed] (null: no input fitted)",
                    items={"type": "array"},
                ),
                "current_said": _field(
                    ["array", "null"],
                    "what the current watch said of them: warnings, and the alarms it latched "
                    "(null: no input fitted)",
                    items={"type": "string"},
                ),
            },
            optional=(
                *("u2", "applied2", "switched2", "on2", "free2", "no_heat", "ceiling"),
                *("mash", "coil", "pump", "hlt_setpoint", "coil_load", "cascade", "pump_in"),
                "coil_load_met",
                *("pump_stop_in", "coil_k", "current", "current_said"),
            ),
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
                    "additionalProperties": False,
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
                "config": _dataclass_schema(Config, "the configuration as loaded"),
                "reason": _field("string", "why it was recorded: start, reload, …"),
                # `measured` (whether its losses were measured) came with control law 6;
                # the safety limits' tun is its four figures alone.
                "model": _dataclass_schema(
                    PlantModel,
                    "the tun's model the controller uses: °C/%, s, s, °C",
                    optional=("measured",),
                ),
                "safety_model": _dataclass_schema(
                    PlantModel,
                    "the tun as measured, the safety limits' (null: they hold for any tun)",
                    nullable=True,
                    optional=("measured",),
                ),
                "control_law": _field(
                    "integer",
                    "which control law made the decisions logged (replay --verify re-runs its own)",
                    minimum=1,
                ),
            },
            optional=("safety_model",),
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
                        "no_mash",
                        "mash_again",
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
                "learned": _dataclass_schema(
                    LearnedModel,
                    "rate °C/s at full power, loss 1/s, dead_time s, ambient °C, litres, "
                    "wall_ns when learned (ns since the Unix epoch), a HERMS coil's "
                    "conductance coil W/K and its sd coil_sd (0: none learned), and the "
                    "elements whose full power rate is (1, or 2 with a second fitted)",
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
