"""The control socket's protocol, version 1: one JSON object a line, a request then its reply.

The socket is a Unix stream socket (mode 0660, the service's group). A client writes one
request, a JSON object on one line of UTF-8 ended by a newline, at most MAX_LINE bytes with
the newline, and reads one reply line before it sends the next request. Every request names
the protocol version it speaks and a command:

    {"v": 1, "cmd": "status"}
    {"v": 1, "cmd": "set", "setpoint": 72}
    {"v": 1, "cmd": "set", "mode": "manual", "output": 40}    (output optional: hold the
                                                               output in force)
    {"v": 1, "cmd": "set", "mode": "auto"}
    {"v": 1, "cmd": "set", "pump": true}      (true runs the HERMS pump, false stops it;
                                               refused when no pump is fitted)
    {"v": 1, "cmd": "reset-alarm", "kinds": ["dry_fire"]}    (kinds optional: the latched
                                    alarms the brewer saw; absent, all of them. One raised
                                    since stays latched, for the brewer to see first)
    {"v": 1, "cmd": "program", "action": "start", "program": {...}, "ready_by": "06:30"}
                                    (program: a mash program file's content as JSON, as
                                     hermsd.program.model.to_data gives it; ready_by optional,
                                     local HH:MM, null or absent: the program's own)
    {"v": 1, "cmd": "program", "action": "next" | "pause" | "resume" | "stop"}
    {"v": 1, "cmd": "confirm"}                (answers the step that waits for the brewer)
    {"v": 1, "cmd": "confirm", "step": 0}     (`step` optional with `confirm` and `program
                                    next`: the index of the step they act on, as `status`'s
                                    program step shows it; refused when that step is no longer
                                    the current one. Absent, the step that was current a second
                                    before the request arrived (hermsd.api.link.SEEN_S):
                                    so of two alike sent together, the second is refused rather
                                    than ending the step the first brought, unseen)
    {"v": 1, "cmd": "history", "since": 1234.5, "limit": 500}   (both optional)

Every reply carries `"v": 1` and `"ok"`. A refused request gets `{"v": 1, "ok": false,
"error": "one line: what is wrong (what would be right)"}` and changes nothing. `status` is
answered at once from the last control period: `tun`, `pv` (°C, null when unknown),
`setpoint` (°C), `output` (% of the SSR's element), `output2` (% of the second element, null
when none is fitted), `applied` (% the SSR was driven at in the period before),
`mode`, `manual_output`, `state` ("ok"; "manual"; "alarm": an alarm holds the heater off;
"waiting": off until the sensor is trusted; "scheduled": off until a mash program's
`ready_by` heat-up is due to start), `alarms`, `alarm_reasons` (each alarm's message, by its
kind), `heater_allowed`, `setpoint_limits` (`min`, `max`: the setpoints taken, °C, and `below`:
a setpoint must be below it, the running `safety.max_temp`), `limits` (the safety limits in
force, one line each), `model` (the controller's model of the tun: gain °C/%, tau s,
dead_time s, ambient °C, and `from`: "learned" (from the brew days), "measured" (by
`hermsd tune`, kept in the config) or "prior" (the config's tun, before either)),
`learned` (what was learned of the tun and stored, with `text` in words, or null) and
`runtime` (each operating key set at runtime whose value differs from the config file's:
`{"control.setpoint": {"running": 72.0, "file": 66.0}}`) and `program` (the mash program that
runs, null when none: `name`, `state`, `step` {index, name, setpoint}, `steps`,
`time_left_s`, `next`, `message`, `starts_at`, `rest_in_s`: s until the step's band is
reached by the tun's model, heating or cooling towards it, else null; see
hermsd/program/driver.py), `mash` and
`coil` (the mash's and the coil outlet's sensors: null when not fitted, else `celsius`, the
latest good reading or null while faulty, and `fault`, why it is faulty or null; the
mash's also `hlt_setpoint` and `phase`, the HLT's setpoint the outer loop chose and its
phase, when it steers, `warning`, the no-flow sign's words while it stands, else the words
of the HLT at its most leaving the mash short of its rest, else null, and `levels_at`, where
that mash levels out (°C), else null: docs/mash-control.md), `pump`
(true running, false stopped, null when no pump is fitted or seen; `pump_switched` false
when hermsd only sees the pump through its sense, `pump.sense`, and cannot switch it),
`current` (the element-current input's, null when none is fitted: the latest sample's `on`,
the SSR's command then, `drawing`, `amps`, null from an input that measures none, `age_s`,
and `judging`, whether its verdicts are on, and `warning`, why not, else null:
docs/current.md). `no_heat`
(two elements; null with one): what the element watch says, 1 or 2 an element that gives no
heat, 0 either, 3 more heat than asked (docs/two-elements.md); `latches_not_saved` (why the
latched alarms' save fails, while it does; else null); `log_failing` (why the log cannot be
written, while it cannot; else null); `warnings` (those three in words, that the program's
progress is not saved (`program`'s `save_failed`), and that full power levels the water out
short of the setpoint (hermsd/control/reach.py), and a fault of the mash's or the coil
outlet's sensor and the no-flow sign (the pump runs, nothing flows through the coil), and
the element-current input's fault or no-signal (its verdicts off), one line each, empty
when there is nothing to say: what holds no heater off but needs a look). A program
sent with `start` is checked on the server's thread exactly as a program file is (and its
setpoints against the running config at the boundary); `program` and `confirm` commands
are answered like `set`. A `set` or `reset-alarm` is checked
against the running config as strictly as the config file is, applied at the next control
period boundary, logged as an operator action, and answered after that boundary with the
same fields as `status` (so the reply shows the change in force); the reply to
`reset-alarm` also has `reset`: `cleared` (the latched alarms it cleared), `standing` (each
alarm still standing: why, in words; an alarm that does not latch clears by itself, not by a
reset) and `text`, the two in one line (hermsd/safety/reset_outcome.py).

`history` pages through the periods of the last 24 hours, kept in memory by the daemon for
the web page's chart (`hermsd/api/history.py`), and is answered at once like `status`:
the rows with `t` after `since` (from the oldest kept when `since` is null or absent), at
most `limit` of them (1 to 2000, default 2000), oldest first:
`{"v": 1, "ok": true, "period": 5.0, "fields": ["t", "pv", "setpoint", "output",
"applied", "mash", "hlt_setpoint"], "more": false, "rows": [[1230.0, 66.062, 66.0, 12.5, 12.5,
null, null], ...]}`. Each row holds the fields in that order (`t` in the daemon's seconds as
`status`'s `t`, `pv` null when unknown, `mash` the mash sensor's reading, null when none is
fitted or while it is faulty, `hlt_setpoint` the HLT's setpoint the outer loop chose, null
without a mash sensor, numbers rounded to 0.001); `more` is true when later rows remain: ask again
with `since` set to the last row's `t`. The daemon keeps no history across a restart.

A line longer than MAX_LINE, or one that is not a JSON object (or nests arrays and objects
deeper than hermsd.api.jsontext.MAX_DEPTH), is refused; an over-long line also ends the
connection (its rest cannot be told from the next request). A number -0 is read as 0.

A connection the daemon has no room for (too many from the client's process, its user or in
all: hermsd/api/server.py) is answered at once with one error line that begins "busy: "
and closed, before the client's request is read: its send may fail (EPIPE), its reply is
there to read all the same. A request the daemon fails to answer is answered with an error
line and ends that connection alone.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

from hermsd.api import jsontext
from hermsd.api.jsontext import JsonTextError
from hermsd.program.model import READY_BY, Program, ProgramError, from_data, one_line, to_data
from hermsd.safety.limits import AUTO_KINDS, LATCHED_KINDS

VERSION = 1
MAX_LINE = 1 << 16
"""Bytes in a request line, newline included: a request is well under 200, a program's
`start` at most about 40 kB (50 steps, each name and message at their longest in 4-byte
UTF-8 characters)."""
MAX_PAGE = 2000
"""Rows in one `history` reply: about 90 kB, well under a client's 1 MiB reply limit."""


BUSY = "busy: "
"""How the error of a connection refused for want of room begins: try again later."""


class ProtocolError(ValueError):
    """A request that cannot be understood; the message is the reply's one-line error."""


@dataclass(frozen=True, slots=True)
class Status:
    pass


@dataclass(frozen=True, slots=True)
class SetSetpoint:
    celsius: float


@dataclass(frozen=True, slots=True)
class SetMode:
    mode: str
    output: float | None = None  # manual: this output in %; None holds the output in force


@dataclass(frozen=True, slots=True)
class SetPump:
    on: bool


@dataclass(frozen=True, slots=True)
class ResetAlarms:
    kinds: tuple[str, ...] | None = None  # the latched alarms to clear; None: all


@dataclass(frozen=True, slots=True)
class ProgramStart:
    program: Program
    ready_by: str | None = None  # local HH:MM; None: the program's own


@dataclass(frozen=True, slots=True)
class ProgramAction:
    action: str  # next, pause, resume, stop; or confirm (the `confirm` command)
    step: int | None = None  # confirm, next: the index of the step they act on; None: current


STEP_ACTIONS = ("confirm", "next")
"""The program actions that end a step, and so name the step they mean to end."""


@dataclass(frozen=True, slots=True)
class History:
    since: float | None = None  # rows after this t; None: from the oldest kept
    limit: int = MAX_PAGE


Command = SetSetpoint | SetMode | SetPump | ResetAlarms | ProgramStart | ProgramAction
Request = Status | History | Command
"""The requests that change something: applied by the loop at a period boundary."""


_WHAT_TEXT_IS = ("not ", "longer ", "nested ")
"""How JsonTextError's messages that say what the text is begin."""


def parse_request(line: bytes) -> Request:
    """The request a line holds, or ProtocolError saying what is wrong with it."""
    try:
        data = jsontext.loads(line, MAX_LINE)
    except JsonTextError as error:
        why = str(error)  # what the text is, or a sentence of its own (a constant: "NaN is …")
        said = why if not why.startswith(_WHAT_TEXT_IS) else f"the request is {why}"
        raise ProtocolError(said) from None
    if not isinstance(data, dict):
        raise ProtocolError('a request is a JSON object, e.g. {"v": 1, "cmd": "status"}')
    version = data.get("v")
    if version != VERSION:
        raise ProtocolError(
            f'protocol version {version!r} is not spoken here (send "v": {VERSION})'
        )
    command = data.get("cmd")
    fields = set(data) - {"v", "cmd"}
    if command == "status":
        _no_other_fields(command, fields, set())
        return Status()
    if command == "reset-alarm":
        _no_other_fields(command, fields, {"kinds"})
        return ResetAlarms(_alarm_kinds(data["kinds"]) if "kinds" in fields else None)
    if command == "history":
        _no_other_fields(command, fields, {"since", "limit"})
        return _history(data)
    if command == "set":
        if fields == {"setpoint"}:
            return SetSetpoint(_number(data, "setpoint"))
        if "mode" in fields:
            _no_other_fields("set mode", fields, {"mode", "output"})
            mode = data["mode"]
            if not isinstance(mode, str):
                raise ProtocolError(f"mode: expected 'auto' or 'manual', got {mode!r}")
            output = data.get("output")
            if output is not None and mode != "manual":
                raise ProtocolError("output goes with mode 'manual' only")
            return SetMode(mode, None if output is None else _number(data, "output"))
        if "pump" in fields:
            _no_other_fields("set pump", fields, {"pump"})
            if not isinstance(data["pump"], bool):
                raise ProtocolError(f"pump: expected true or false, got {json.dumps(data['pump'])}")
            return SetPump(data["pump"])
        raise ProtocolError(
            "set takes either setpoint, or mode (with output for manual), or pump (true or false)"
        )
    if command == "confirm":
        _no_other_fields(command, fields, {"step"})
        return ProgramAction("confirm", _step(data))
    if command == "program":
        return _program_request(data, fields)
    raise ProtocolError(
        f"unknown command {command!r} (one of 'status', 'set', 'reset-alarm', 'program', "
        "'confirm', 'history')"
    )


PROGRAM_ACTIONS = ("start", "next", "pause", "resume", "stop")


def _program_request(data: dict[str, Any], fields: set[str]) -> Request:
    action = data.get("action")
    if action not in PROGRAM_ACTIONS:
        raise ProtocolError(
            f"program: action {action!r} is not one of {', '.join(map(repr, PROGRAM_ACTIONS))}"
        )
    if action != "start":
        named = {"step"} if action in STEP_ACTIONS else set()
        _no_other_fields(f"program {action}", fields, {"action", *named})
        return ProgramAction(action, _step(data))
    _no_other_fields("program start", fields, {"action", "program", "ready_by"})
    if "program" not in data:
        raise ProtocolError("program start: the program is missing (send the file's content)")
    ready_by = data.get("ready_by")
    if ready_by is not None and not (isinstance(ready_by, str) and READY_BY.fullmatch(ready_by)):
        raise ProtocolError(
            f"ready_by: {json.dumps(ready_by)} is not a local time (HH:MM on a 24 h clock, "
            "e.g. '06:30')"
        )
    try:
        program = from_data(data["program"], "program")
    except ProgramError as error:
        raise ProtocolError(f"program: {one_line(error)}") from None
    return ProgramStart(program, ready_by)


def _history(data: dict[str, Any]) -> History:
    since = None if data.get("since") is None else _number(data, "since")
    limit = data.get("limit", MAX_PAGE)
    if isinstance(limit, bool) or not isinstance(limit, int) or not 1 <= limit <= MAX_PAGE:
        raise ProtocolError(f"limit: expected a whole number 1 to {MAX_PAGE}, got {limit!r}")
    return History(since, limit)


def _step(data: dict[str, Any]) -> int | None:
    step = data.get("step")
    if step is not None and (isinstance(step, bool) or not isinstance(step, int) or step < 0):
        raise ProtocolError(
            f"step: expected the index of a step (a whole number from 0, as status shows it), "
            f"got {json.dumps(step)}"
        )
    return step


def _alarm_kinds(value: Any) -> tuple[str, ...]:
    """The alarms as `status` lists them; only the latched ones among them are cleared."""
    known = (*AUTO_KINDS, *LATCHED_KINDS)
    if not isinstance(value, list) or not all(kind in known for kind in value):
        raise ProtocolError(
            f"kinds: expected a list of alarms as status names them ({', '.join(known)}), "
            f"got {json.dumps(value)}"
        )
    return tuple(value)


def _no_other_fields(command: str, fields: set[str], allowed: set[str]) -> None:
    extra = sorted(fields - allowed)
    if extra:
        raise ProtocolError(f"{command} does not take {', '.join(extra)}")


def _number(data: dict[str, Any], key: str) -> float:
    value = data[key]
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ProtocolError(f"{key}: expected a number, got {json.dumps(value)}")
    number = float(value)
    if not math.isfinite(number):
        raise ProtocolError(f"{key}: {value} is not a usable number")
    return number + 0.0  # -0.0 is 0.0: no surface shows a "-0"


def request_message(request: Request) -> dict[str, Any]:
    """The JSON object of a request (the client's side of `parse_request`)."""
    message: dict[str, Any] = {"v": VERSION}
    if isinstance(request, Status):
        message["cmd"] = "status"
    elif isinstance(request, ResetAlarms):
        message["cmd"] = "reset-alarm"
        if request.kinds is not None:
            message["kinds"] = list(request.kinds)
    elif isinstance(request, SetSetpoint):
        message.update(cmd="set", setpoint=request.celsius)
    elif isinstance(request, ProgramStart):
        message.update(
            cmd="program",
            action="start",
            program=to_data(request.program),
            ready_by=request.ready_by,
        )
    elif isinstance(request, ProgramAction):
        if request.action == "confirm":
            message["cmd"] = "confirm"
        else:
            message.update(cmd="program", action=request.action)
        if request.step is not None:
            message["step"] = request.step
    elif isinstance(request, History):
        message.update(cmd="history", since=request.since, limit=request.limit)
    elif isinstance(request, SetPump):
        message.update(cmd="set", pump=request.on)
    else:
        message.update(cmd="set", mode=request.mode)
        if request.output is not None:
            message["output"] = request.output
    return message


def encode(message: dict[str, Any]) -> bytes:
    """One line of the protocol; NaN and infinities are refused, never sent."""
    return json.dumps(message, allow_nan=False, ensure_ascii=False).encode("utf-8") + b"\n"


def error_reply(message: str) -> dict[str, Any]:
    return {"v": VERSION, "ok": False, "error": message}


STARTING = "hermsd is starting: no control period has run yet"
"""The error `status` is answered with before the loop has published a period."""


def describe(command: Command) -> str:
    """The operator action in words, for the log."""
    if isinstance(command, SetSetpoint):
        return f"set setpoint {command.celsius:g} °C"
    if isinstance(command, ResetAlarms):
        return "reset-alarm" + ("" if command.kinds is None else f" {', '.join(command.kinds)}")
    if isinstance(command, ProgramStart):
        ready = f", ready by {command.ready_by}" if command.ready_by else ""
        return f"program start {command.program.name!r} ({len(command.program.steps)} steps{ready})"
    if isinstance(command, SetPump):
        return f"set pump {'on' if command.on else 'off'}"
    if isinstance(command, ProgramAction):
        what = command.action if command.action == "confirm" else f"program {command.action}"
        return what if command.step is None else f"{what} of step {command.step + 1}"
    if command.output is not None:
        return f"set mode {command.mode} at {command.output:g} %"
    return f"set mode {command.mode}"
