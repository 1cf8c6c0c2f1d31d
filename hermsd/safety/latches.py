"""Latched alarms on disk, so that neither a restart nor a crash clears them.

A latched alarm (element not heating, SSR stuck on, dry fire, stuck sensor, controller
fault) says the hardware is not what the loop believes; only the brewer may clear it.
`Restart=always` would otherwise clear it within seconds of a crash. The daemon writes the
latched alarms to `latched.json` in its state directory whenever they change (atomically: a
temporary file, fsync, rename; beside the control loop, `hermsd.runtime.saver`, the heater being off
already; a failed save is tried again every 30 s until it lands), and raises them again at
start.

A directory that cannot keep them would let a restart heat over a latched fault, so the daemon
does not start on one: before any output is opened it locks the state directory and writes a
latch file there as a save does (`LatchStore.probe`). A save that fails later leaves the alarm
latched in memory, the heater off, and says in the log that the alarm will not survive a
restart; the heater is not held off for the failure itself (`latch_keeping.latch_save_failed_text`
says why).

Two ways to clear them, both deliberate acts:
- bump `safety.reset` in the config: a reload, or a start with a value other than the one
  the alarms were latched under, clears them;
- `hermsd reset-alarm` writes `reset-alarm.json` naming the alarms it saw; the daemon clears
  exactly those at its next control period (or at its next start), so an alarm raised after
  the brewer looked is not cleared by mistake.
"""

from __future__ import annotations

import contextlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeGuard

from hermsd.files import NotRegularFile, read_regular, write_atomically
from hermsd.safety.limits import LATCHED_KINDS

LATCHED_FILE = "latched.json"
RESET_FILE = "reset-alarm.json"
MAX_STATE_BYTES = 1 << 20  # a latch file holds a few alarms: far less than this
PROBE_FILE = "latched.json.probe"
PROBE_MESSAGE_CHARS = 400  # an alarm's message is one line: a few hundred characters at most


class StateError(Exception):
    """The state directory holds something that is not hermsd's state."""


@dataclass(frozen=True, slots=True)
class LatchedAlarm:
    """A latched alarm as stored: what, when (UTC ns), why, and the values that showed it."""

    kind: str
    wall_ns: int
    message: str
    values: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class Latches:
    """The latched alarms and the `safety.reset` counter they were latched under."""

    alarms: tuple[LatchedAlarm, ...] = ()
    reset: int = 0


class LatchStore:
    """The files in the state directory (systemd's StateDirectory=)."""

    def __init__(self, directory: Path | str) -> None:
        self.directory = Path(directory)

    @property
    def latched_path(self) -> Path:
        return self.directory / LATCHED_FILE

    @property
    def reset_path(self) -> Path:
        return self.directory / RESET_FILE

    def load(self) -> Latches:
        """The stored latches; none when there is no file. StateError for a damaged one."""
        path = self.latched_path
        document = read_state_json(path)
        if document is None:
            return Latches()
        try:
            return _latches(document)
        except _Malformed as error:
            raise StateError(f"{path}: not a hermsd latch file: {error}") from None

    def save(self, latches: Latches) -> None:
        """Replace the stored latches atomically (OSError when the disk refuses)."""
        write_atomically(self.latched_path, _document(latches))

    def probe(self) -> None:
        """Write a latch file of every latched kind beside the real one, as a save writes it
        (durably), and remove it: OSError when this directory cannot keep a latched alarm
        (full, read-only, gone), found at the start, before the heater is ever on."""
        message = "x" * PROBE_MESSAGE_CHARS
        every = tuple(LatchedAlarm(kind, 0, message, {}) for kind in LATCHED_KINDS)
        path = self.directory / PROBE_FILE
        try:
            write_atomically(path, _document(Latches(every)))
        finally:
            with contextlib.suppress(FileNotFoundError):
                path.unlink()

    def request_reset(self, kinds: list[str]) -> None:
        """Ask the daemon to clear these latched alarms (`hermsd reset-alarm`)."""
        write_atomically(self.reset_path, json.dumps({"kinds": sorted(kinds)}))

    def take_reset_request(self) -> list[str] | None:
        """The latched kinds a pending `reset-alarm` names, removing the request; None when none.

        A request that cannot be read is removed too, and raises StateError: it cannot make
        the daemon clear alarms nobody saw, nor stop it.
        """
        path = self.reset_path
        try:
            document = read_state_json(path)
            if document is None:
                return None
            kinds = document.get("kinds") if isinstance(document, dict) else None
            if not (isinstance(kinds, list) and all(isinstance(k, str) for k in kinds)):
                raise StateError(f'{path}: not a reset request (expected {{"kinds": [names]}})')
        except StateError as error:
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
            raise StateError(f"{error}; discarded") from None
        with contextlib.suppress(FileNotFoundError):
            path.unlink()
        return [kind for kind in kinds if kind in LATCHED_KINDS]


def _document(latches: Latches) -> str:
    document = {
        "alarms": [
            {"kind": a.kind, "wall_ns": a.wall_ns, "message": a.message, "values": a.values}
            for a in latches.alarms
        ],
        "reset": latches.reset,
    }
    return json.dumps(document, default=str, indent=1)


class _Malformed(Exception):
    """What is wrong with a latch document, for StateError's message."""


def _latches(document: Any) -> Latches:
    """A latch document checked key by key and type by type: nothing is coerced or guessed."""
    if not isinstance(document, dict):
        raise _Malformed("expected an object with 'alarms' and 'reset'")
    alarms, reset = document.get("alarms"), document.get("reset")
    if not isinstance(alarms, list):
        raise _Malformed("'alarms' must be a list")
    if not is_int(reset):
        raise _Malformed("'reset' must be a whole number")
    return Latches(tuple(_alarm(item) for item in alarms), reset)


def _alarm(item: Any) -> LatchedAlarm:
    if not isinstance(item, dict):
        raise _Malformed("each alarm must be an object")
    kind, wall_ns, message = item.get("kind"), item.get("wall_ns"), item.get("message")
    values = item.get("values", {})
    if kind not in LATCHED_KINDS:
        raise _Malformed(f"unknown alarm kind {kind!r} (latched kinds: {', '.join(LATCHED_KINDS)})")
    if not (is_int(wall_ns) and 0 <= wall_ns < 2**63):  # what the wall clock gives
        raise _Malformed(f"{kind}: 'wall_ns' must be a whole number of ns since 1970")
    if not isinstance(message, str):
        raise _Malformed(f"{kind}: 'message' must be text")
    scalars = (str, int, float, bool, type(None))
    if not (isinstance(values, dict) and all(isinstance(v, scalars) for v in values.values())):
        raise _Malformed(f"{kind}: 'values' must be an object of numbers, text or null")
    return LatchedAlarm(kind, wall_ns, message, values)


def is_int(value: Any) -> TypeGuard[int]:
    """A JSON whole number (a boolean is not one, though Python's bool is an int)."""
    return isinstance(value, int) and not isinstance(value, bool)


def _finite(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"number {text} is out of range")
    return value


def _no_constant(name: str) -> float:
    raise ValueError(f"{name} is not a number JSON allows")


def read_state_json(path: Path) -> Any:
    """The JSON document at `path`, None when there is none; StateError for anything else.

    Read as `files.read_regular` reads (a FIFO or a tty put there is never opened), up to
    MAX_STATE_BYTES, parsed strictly: no NaN or Infinity, no number beyond a float's range,
    no nesting deep enough to exhaust the parser.
    """
    try:
        data = read_regular(path, MAX_STATE_BYTES)
    except FileNotFoundError:
        return None
    except OSError as error:
        raise StateError(f"{path}: cannot be read: {error.strerror or error}") from None
    except NotRegularFile as error:
        if error.kind is not None:
            raise StateError(f"{path}: {error}") from None
        raise StateError(
            f"{path}: larger than {MAX_STATE_BYTES} bytes, not hermsd's state"
        ) from None
    try:
        return json.loads(data.decode("utf-8"), parse_float=_finite, parse_constant=_no_constant)
    except UnicodeDecodeError as error:
        raise StateError(f"{path}: not UTF-8 text: {error}") from None
    except ValueError as error:  # json.JSONDecodeError is one; so are the hooks' refusals
        raise StateError(f"{path}: not valid JSON: {error}") from None
    except RecursionError:
        raise StateError(f"{path}: not valid JSON: nested too deeply") from None
