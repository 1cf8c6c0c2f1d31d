"""The commands that talk to a running daemon through its control socket: status, set,
program, confirm, reset-alarm."""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hermsd.api.client import NoDaemonError, ReplyError, ask
from hermsd.api.protocol import (
    BUSY,
    ProgramAction,
    ProgramStart,
    Request,
    ResetAlarms,
    SetMode,
    SetPump,
    SetSetpoint,
    Status,
)
from hermsd.cli.common import (
    Unreachable,
    UserError,
    control_socket,
)
from hermsd.cli.run import (
    _default_state_directory,
)
from hermsd.runtime.notify import (
    current_words,
    mash_side_words,
    pump_words,
    role_words,
    status_line,
)
from hermsd.safety.latches import Latches, LatchStore, StateError

if TYPE_CHECKING:
    pass

from hermsd.cli.files import cmd_program_import


def cmd_reset_alarm(args: argparse.Namespace) -> int:
    """Clear the latched alarms: through the socket when a daemon runs, else by a request
    in the state directory that the daemon takes when it starts."""
    socket_path = control_socket(args.socket)  # said once, if it is a simulated daemon's
    try:
        seen = _ask(socket_path, Status())["alarms"]
    except NoDaemonError:
        return _request_reset_in_state(args)
    if not seen:
        print("no alarm to reset")
        return 0
    # Only what was seen here: an alarm raised in between stays, to be read first.
    reply = _ask(socket_path, ResetAlarms(tuple(seen)))
    print(reply["reset"]["text"])  # what was cleared, what stands and why
    return 0


def _request_reset_in_state(args: argparse.Namespace) -> int:
    """Ask the daemon to clear the latched alarms it keeps in its state directory."""
    directory: Path = args.state or _default_state_directory()
    store = LatchStore(directory)
    try:
        try:
            latches = store.load()
        except StateError as error:
            store.save(Latches())
            print(f"{error}: replaced by an empty one; no alarm stays latched")
            return 0
        if not latches.alarms:
            print(f"no latched alarm in {directory}")
            return 0
        store.request_reset([alarm.kind for alarm in latches.alarms])
    except OSError as error:
        raise UserError(
            f"{directory}: {error.strerror or error} (run as root or as the user hermsd runs as)"
        ) from None
    for alarm in latches.alarms:
        when = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime(alarm.wall_ns / 1e9))
        print(f"{alarm.kind}, latched {when}: {alarm.message}")
    print(
        "reset asked: a running hermsd clears these within one control period, "
        "a stopped one when it starts"
    )
    return 0


def _step_number(text: str) -> int:
    """A step as numbered from 1, to the protocol's index from 0."""
    if not text.isdigit() or int(text) < 1:
        raise argparse.ArgumentTypeError(f"expected a step number from 1, got {text!r}")
    return int(text) - 1


def _ask(socket_path: Path | None, request: Request) -> dict[str, Any]:
    """The daemon's reply; a refusal is a UserError (exit 2) with the daemon's one line, a
    daemon too busy to take the connection Unreachable (exit 1: try again)."""
    try:
        reply = ask(control_socket(socket_path), request)
    except ReplyError as error:
        raise Unreachable(str(error)) from None
    if not reply["ok"]:
        why = str(reply.get("error", "refused"))
        raise (Unreachable if why.startswith(BUSY) else UserError)(why)
    return reply


def cmd_status(args: argparse.Namespace) -> int:
    try:
        reply = _ask(args.socket, Status())
    except NoDaemonError as error:
        raise Unreachable(str(error)) from None
    if args.json:
        print(json.dumps(reply, indent=2, ensure_ascii=False))
        return 0
    mash = reply.get("mash")
    hlt_setpoint = None if mash is None else mash.get("hlt_setpoint")
    line = status_line(
        reply["tun"],
        reply["pv"],
        reply["setpoint"] if hlt_setpoint is None else hlt_setpoint,
        reply["output"],
        reply["state"],
        reply.get("output2"),
        mash_side_words(mash, reply.get("pump"), reply["setpoint"]),
    )
    print(f"{line} (applied {reply['applied']:.0f} %), {_mode_text(reply)}")
    if reply.get("coil") is not None:  # the mash and the pump are in the line above
        print(role_words("coil outlet", reply["coil"]))
    if reply.get("current") is not None:
        print(current_words(reply["current"]))
    print(f"alarms: {', '.join(reply['alarms']) or 'none'}")
    for kind, reason in reply.get("alarm_reasons", {}).items():
        print(f"  {kind}: {reason}")
    for warning in reply.get("warnings") or []:
        print(f"warning: {warning}")
    for key, values in reply["runtime"].items():
        print(f"{key} {values['running']} set at runtime (config file: {values['file']})")
    model = reply["model"]
    print(
        f"tun model ({model['from']}): K {model['gain']:.4g} °C/%, "
        f"τ {model['tau']:.0f} s, θ {model['dead_time']:.0f} s, room {model['ambient']:.1f} °C"
    )
    learned = reply["learned"]
    print(f"learned: {learned['text'] if learned is not None else 'nothing yet'}")
    if reply.get("program") is not None:
        print(program_line(reply["program"]))
    print("safety limits in force:")
    for row in reply["limits"]:
        print(f"  {row}")
    return 0


def cmd_set(args: argparse.Namespace) -> int:
    request: Request
    if args.what == "setpoint":
        if args.output is not None:
            raise UserError("--output goes with `set mode manual`")
        request = SetSetpoint(_finite(args.value, "setpoint", "°C"))
    elif args.what == "mode":
        if args.value not in ("auto", "manual"):
            raise UserError(f"mode: expected auto or manual, got {args.value!r}")
        if args.output is not None and args.value != "manual":
            raise UserError("--output goes with `set mode manual`")
        output = None if args.output is None else _finite(args.output, "--output", "%")
        request = SetMode(args.value, output)
    elif args.what == "pump":
        if args.value not in ("on", "off"):
            raise UserError(f"pump: expected on or off, got {args.value!r}")
        if args.output is not None:
            raise UserError("--output goes with `set mode manual`")
        request = SetPump(args.value == "on")
    else:
        raise UserError(f"set: expected setpoint, mode or pump, got {args.what!r}")
    try:
        reply = _ask(args.socket, request)
    except NoDaemonError as error:
        raise Unreachable(str(error)) from None
    pump = "" if reply.get("pump") is None else f", {pump_words(reply['pump'], reply.get('mash'))}"
    print(f"now: setpoint {reply['setpoint']:g} °C, {_mode_text(reply)}{pump}")
    return 0


def cmd_program(args: argparse.Namespace) -> int:
    from hermsd.config import read
    from hermsd.program import model

    needs_file = args.action in ("check", "start", "import")
    if needs_file != (args.file is not None):
        raise UserError(
            f"program {args.action}: "
            + ("name the program file" if needs_file else "takes no file")
        )
    if args.action != "import" and (args.output is not None or args.recipe is not None):
        raise UserError("-o/--output and --recipe go with `program import`")
    if args.action == "import":
        return cmd_program_import(args)
    if args.ready_by is not None and args.action != "start":
        raise UserError("--ready-by goes with `program start`")
    if args.config is not None and args.action != "check":
        raise UserError("--config goes with `program check`")
    if args.step is not None and args.action != "next":
        raise UserError("--step goes with `program next` (and `hermsd confirm`)")
    if args.ready_by is not None and model.READY_BY.fullmatch(args.ready_by) is None:
        raise UserError(f"--ready-by: {args.ready_by!r} is not a local time (HH:MM, e.g. 06:30)")
    request: Request
    if needs_file:
        program = model.load(args.file)  # a ConfigError: every problem, exit 2
        if args.action == "check":
            print(f"{args.file}: program {program.name!r}, {len(program.steps)} steps, valid")
            for number, step in enumerate(program.steps, 1):
                print(f"  {number}. {model.describe_step(step)}")
            config = None if args.config is None else read.load(args.config)
            for warning in [] if config is None else model.config_warnings(program, config):
                print(f"warning: {args.file}: {warning}")
            return 0
        request = ProgramStart(program, args.ready_by)
    else:
        request = ProgramAction(args.action, args.step)
    try:
        reply = _ask(args.socket, request)
    except NoDaemonError as error:
        raise Unreachable(str(error)) from None
    state = reply.get("program")
    if args.action == "stop":
        print(f"program stopped; setpoint {reply['setpoint']:g} °C")
    else:
        print(program_line(state) if state is not None else "no program runs")
    return 0


def cmd_confirm(args: argparse.Namespace) -> int:
    try:
        reply = _ask(args.socket, ProgramAction("confirm", args.step))
    except NoDaemonError as error:
        raise Unreachable(str(error)) from None
    state = reply.get("program")
    print(program_line(state) if state is not None else "no program runs")
    return 0


def program_line(state: dict[str, Any]) -> str:
    """The status reply's `program` in one line."""
    step = state["step"]
    line = (
        f"program {state['name']!r}: {state['state']}, step {step['index'] + 1}/{state['steps']} "
        f"{step['name']!r} at {step['setpoint']:g} °C"
    )
    if state["time_left_s"] is not None:
        line += f", {state['time_left_s'] / 60.0:.1f} min of its hold left"
    if state.get("rest_in_s") is not None:
        line += f", {_rest_in_words(state['rest_in_s'])}"
    if state["message"] is not None:
        line += f", waits for: {state['message']} (`hermsd confirm`)"
    if state["starts_at"] is not None:
        line += f", heating starts at {state['starts_at']}"
    if state.get("late") is not None:
        line += f", LATE: {state['late']}"
    if state["next"] is not None:
        line += f"; next {state['next']!r}"
    return line


def _rest_in_words(seconds: float) -> str:
    """The tun model's estimate of when the step's rest starts, rounded as the web page
    rounds it: an estimate, so whole minutes, and no count of seconds."""
    if seconds < 60.0:
        return "rest in under a minute"
    hours, minutes = divmod(round(seconds / 60.0), 60)
    return f"rest in about {f'{hours} h {minutes} min' if hours else f'{minutes} min'}"


def _mode_text(reply: dict[str, Any]) -> str:
    mode = str(reply["mode"])
    return mode + (f" at {reply['manual_output']:g} %" if mode == "manual" else "")


def _finite(text: str, name: str, unit: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise UserError(f"{name}: expected a number in {unit}, got {text!r}") from None
    if not math.isfinite(value):
        raise UserError(f"{name}: expected a number in {unit}, got {text!r}")
    return value
