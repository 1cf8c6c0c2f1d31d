"""The brew day over MQTT: the mash program's state, its buttons, a program start, the alarm
reset and the alerts, for a brewer whose dashboard is Home Assistant. Pure: no network.

Every button is a command the command line has (`hermsd confirm`, `hermsd program next|
pause|resume|stop|start`, `hermsd reset-alarm`), sent through the control socket as the
command line sends it, so the daemon checks it the same way; what became of each, applied or
refused and why, is published on `<prefix>/result` (the Last command sensor) beside the
error topic.

A program is started from a file in the program folder: a `select` of the folder's files and
a Start program button, rather than a `text` entity. A select offers only files that are
there (no path to mistype, nothing outside the folder to name), and choosing is not
starting: the start is a press of its own, as deliberate as `hermsd program start FILE`.

Alarms and warnings are an `event` entity: one event when each is raised and when it clears,
and when a step waits for the brewer, so an automation can push them to a phone
(docs/mqtt.md). Events are not retained: Home Assistant would fire them again at each
restart.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hermsd.api.protocol import Command, ProgramAction, ProgramStart, ResetAlarms
from hermsd.config.schema import ConfigError
from hermsd.program import model

PRESS = "PRESS"  # Home Assistant's button payload
ACTIONS = ("confirm", "next", "pause", "resume", "stop")
BUTTONS = {
    "confirm": "Confirm step",
    "next": "Next step",
    "pause": "Pause program",
    "resume": "Resume program",
    "stop": "Stop program",
    "start": "Start program",
    "reset_alarm": "Reset alarm",
}
RUN_STATES = ("running", "paused", "waiting", "done", "none")
EVENT_TYPES = ("alarm", "alarm_cleared", "warning", "warning_cleared", "waiting")
PROGRAM_SUFFIXES = (".yaml", ".yml")
MAX_PROGRAMS = 100  # files the select offers: a folder of programs, not an archive
TEXT_LIMIT = 255  # characters Home Assistant keeps in a sensor's state

Entity = Callable[..., dict[str, Any]]
"""Makes an entity's discovery payload: (object id, name, **fields) with the device's keys."""


class Refused(ValueError):
    """A press or choice that is not sent; the message says what is wrong."""


@dataclass(frozen=True, slots=True)
class BrewdayTopics:
    """The brew day's topics under the tun's prefix; commands under `<prefix>/set/`, which
    the broker's ACL for Home Assistant covers already."""

    press: dict[str, str]  # button: its command topic
    choose: str  # the program select's command topic
    chosen: str  # … and its state, retained
    result: str  # what became of each command
    event: str  # alarms, warnings and waits, as they happen

    @classmethod
    def of(cls, prefix: str) -> BrewdayTopics:
        return cls(
            press={name: f"{prefix}/set/program/{name}" for name in BUTTONS if name in ACTIONS}
            | {"start": f"{prefix}/set/program/start", "reset_alarm": f"{prefix}/set/reset-alarm"},
            choose=f"{prefix}/set/program/choose",
            chosen=f"{prefix}/program/chosen",
            result=f"{prefix}/result",
            event=f"{prefix}/event",
        )

    def commands(self) -> list[str]:
        return [*self.press.values(), self.choose]


def run_state(program: dict[str, Any] | None) -> str:
    """The program's state as Home Assistant shows it: running (heating, holding, ramping or
    scheduled), paused, waiting (for the brewer), done, or none."""
    if program is None:
        return "none"
    state = str(program.get("state"))
    return state if state in ("paused", "waiting", "done") else "running"


def state_fields(program: dict[str, Any] | None) -> dict[str, Any]:
    """The state message's brew-day fields, in the words the sensors show."""
    program = program or {}
    return {
        "run_state": run_state(program or None),
        "next_text": str(program.get("next") or "none")[:TEXT_LIMIT],
        "message_text": str(program.get("message") or "none")[:TEXT_LIMIT],
    }


def discovery(
    topics: BrewdayTopics,
    discovery_topic: Callable[[str, str], str],
    entity: Entity,
    state_topic: str,
    programs: list[str] | None,
) -> list[tuple[str, dict[str, Any] | None]]:
    """The brew day's entities; the select and the start button only when the program folder
    holds programs (else sent empty: removed)."""

    def sensor(object_id: str, name: str, field: str, **fields: Any) -> tuple[str, Any]:
        return discovery_topic("sensor", object_id), entity(
            object_id,
            name,
            state_topic=state_topic,
            value_template=f"{{{{ value_json.{field} }}}}",
            **fields,
        )

    def button(name: str) -> tuple[str, Any]:
        return discovery_topic("button", name), entity(
            name,
            BUTTONS[name],
            command_topic=topics.press[name],
            payload_press=PRESS,
            qos=1,
        )

    starting = bool(programs)
    return [
        sensor(
            "program_state",
            "Program state",
            "run_state",
            device_class="enum",
            options=list(RUN_STATES),
        ),
        sensor("next_step", "Next step", "next_text"),
        sensor("waiting_for", "Waiting for", "message_text", icon="mdi:account-alert"),
        (
            discovery_topic("sensor", "last_command"),
            entity(
                "last_command",
                "Last command",
                state_topic=topics.result,
                value_template="{{ value_json.text }}",
                icon="mdi:message-reply-text",
            ),
        ),
        *(button(name) for name in (*ACTIONS, "reset_alarm")),
        button("start") if starting else (discovery_topic("button", "start"), None),
        (
            discovery_topic("select", "program"),
            entity(
                "program",
                "Program",
                command_topic=topics.choose,
                state_topic=topics.chosen,
                options=programs,
                qos=1,
            )
            if starting
            else None,
        ),
        (
            discovery_topic("event", "alert"),
            entity("alert", "Alert", state_topic=topics.event, event_types=list(EVENT_TYPES)),
        ),
    ]


def list_programs(folder: Path | None) -> list[str] | None:
    """The program files in `folder`, sorted (None: no folder, or it cannot be read)."""
    if folder is None:
        return None
    try:
        with os.scandir(folder) as entries:
            names = sorted(
                entry.name
                for entry in entries
                if entry.name.endswith(PROGRAM_SUFFIXES) and entry.is_file()
            )
    except OSError:
        return None
    return names[:MAX_PROGRAMS]


def pressed(
    topics: BrewdayTopics,
    topic: str,
    payload: str,
    *,
    alarms: list[str],
    chosen: str | None,
    folder: Path | None,
) -> Command:
    """The command a button press asks for, as the command line would send it: `confirm`
    and `next` name no step (the daemon takes the step shown a second before), a reset the
    alarms Home Assistant was shown, a start the chosen file, read and checked as
    `hermsd program start` reads it."""
    if payload != PRESS:
        raise Refused(f"a button sends {PRESS}, got {payload[:64]!r}")
    name = next(name for name, press in topics.press.items() if press == topic)
    if name in ACTIONS:
        return ProgramAction(name)
    if name == "reset_alarm":
        return ResetAlarms(tuple(alarms))
    if folder is None or chosen is None:
        raise Refused("start program: choose a program first (the Program select)")
    if chosen not in (list_programs(folder) or []):
        raise Refused(f"start program: {chosen} is no longer in {folder}")
    try:
        program = model.load(folder / chosen)
    except ConfigError as error:
        raise Refused(f"start program: {' '.join(str(error).split())}") from None
    return ProgramStart(program)


def choice(payload: str, programs: list[str] | None) -> str:
    """The program chosen in the select: one the folder holds."""
    if payload not in (programs or []):
        raise Refused(f"program: {payload[:64]!r} is not a program file in the program folder")
    return payload


class News:
    """What changed between two states, as events: an alarm raised or cleared, a warning
    raised or cleared, a step that starts to wait. The first state's alarms and warnings are
    news too: one raised while the bridge was away must still reach the phone."""

    def __init__(self) -> None:
        self._alarms: dict[str, str] = {}
        self._warnings: list[str] = []
        self._message: str | None = None

    def of(self, status: dict[str, Any]) -> list[dict[str, Any]]:
        tun = status["tun"]
        alarms = {str(kind): "" for kind in status["alarms"]}
        alarms.update({k: str(v) for k, v in (status.get("alarm_reasons") or {}).items()})
        warnings = [str(warning) for warning in status.get("warnings") or []]
        program = status.get("program")
        message = program.get("message") if isinstance(program, dict) else None
        events = [
            _event("alarm", tun, kind, alarms[kind]) for kind in alarms if kind not in self._alarms
        ]
        events += [
            _event("alarm_cleared", tun, kind, f"{kind} cleared")
            for kind in self._alarms
            if kind not in alarms
        ]
        events += [_event("warning", tun, "", w) for w in warnings if w not in self._warnings]
        events += [
            _event("warning_cleared", tun, "", w) for w in self._warnings if w not in warnings
        ]
        if message is not None and message != self._message:
            events.append(_event("waiting", tun, "", str(message)))
        self._alarms, self._warnings, self._message = alarms, warnings, message
        return events


def _event(event_type: str, tun: str, kind: str, message: str) -> dict[str, Any]:
    return {"event_type": event_type, "tun": tun, "kind": kind, "message": message}
