"""Latched alarms on disk, so that neither a restart nor a crash clears them.

A latched alarm (element not heating, SSR stuck on, dry fire, stuck sensor) says the
hardware is not what the loop believes; only the brewer may clear it. `Restart=always`
would otherwise clear it within seconds of a crash. The daemon writes the latched alarms
to `latched.json` in its state directory whenever they change (atomically: a temporary
file, fsync, rename), and raises them again at start.

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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hermsd.files import write_atomically
from hermsd.safety import LATCHED_KINDS

LATCHED_FILE = "latched.json"
RESET_FILE = "reset-alarm.json"


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
        document = self._read_json(self.latched_path)
        if document is None:
            return Latches()
        try:
            alarms = tuple(
                LatchedAlarm(
                    str(item["kind"]),
                    int(item["wall_ns"]),
                    str(item["message"]),
                    dict(item.get("values", {})),
                )
                for item in document["alarms"]
            )
            reset = int(document["reset"])
        except (KeyError, TypeError, ValueError) as error:
            raise StateError(f"{self.latched_path}: not a hermsd latch file ({error})") from None
        unknown = [a.kind for a in alarms if a.kind not in LATCHED_KINDS]
        if unknown:
            raise StateError(f"{self.latched_path}: unknown alarm kinds {unknown}")
        return Latches(alarms, reset)

    def save(self, latches: Latches) -> None:
        """Replace the stored latches atomically (OSError when the disk refuses)."""
        document = {
            "alarms": [
                {"kind": a.kind, "wall_ns": a.wall_ns, "message": a.message, "values": a.values}
                for a in latches.alarms
            ],
            "reset": latches.reset,
        }
        write_atomically(self.latched_path, json.dumps(document, default=str, indent=1))

    def request_reset(self, kinds: list[str]) -> None:
        """Ask the daemon to clear these latched alarms (`hermsd reset-alarm`)."""
        write_atomically(self.reset_path, json.dumps({"kinds": sorted(kinds)}))

    def take_reset_request(self) -> list[str] | None:
        """The kinds a pending `reset-alarm` names, removing the request; None when none.

        A request that cannot be read is removed too and names nothing, so it cannot make
        the daemon clear alarms nobody saw.
        """
        try:
            document = self._read_json(self.reset_path)
        except StateError:
            document = {"kinds": []}
        if document is None:
            return None
        with contextlib.suppress(FileNotFoundError):
            self.reset_path.unlink()
        kinds = document.get("kinds") if isinstance(document, dict) else None
        if not isinstance(kinds, list):
            return []
        return [kind for kind in kinds if kind in LATCHED_KINDS]

    @staticmethod
    def _read_json(path: Path) -> Any:
        try:
            text = path.read_text(encoding="utf-8")
        except FileNotFoundError:
            return None
        except (OSError, UnicodeDecodeError) as error:
            raise StateError(f"{path}: cannot be read: {error}") from None
        try:
            return json.loads(text)
        except json.JSONDecodeError as error:
            raise StateError(f"{path}: not valid JSON: {error}") from None
