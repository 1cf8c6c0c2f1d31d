"""A running program's progress in the state directory, so a restart or a crash resumes it.

`program.json` holds the program and its `Progress`. It is replaced every control period
while a program runs (a temporary file renamed over it: a crash, SIGKILL included, leaves the
last period's or the one before), and made durable (fsync) whenever the step or the phase
changes and at least once a minute otherwise, so a power cut costs at most a minute of a
hold's counted time (the rest is then that much longer, never shorter).
"""

from __future__ import annotations

import contextlib
import json
import math
from pathlib import Path
from typing import Any

from hermsd.files import write_atomically
from hermsd.latches import StateError, read_state_json
from hermsd.program.model import Program, ProgramError, from_data, to_data
from hermsd.program.runner import PHASES, Progress

PROGRAM_FILE = "program.json"
DURABLE_EVERY_S = 60.0


class ProgressStore:
    """`program.json` in the state directory, next to the latches and the learned model."""

    def __init__(self, directory: Path | str) -> None:
        self.path = Path(directory) / PROGRAM_FILE
        self._durable: tuple[int, str] | None = None  # step and phase last made durable
        self._durable_at = -math.inf

    def load(self) -> tuple[Program, Progress] | None:
        """The stored program and its progress; None when none. StateError for a bad file."""
        document = read_state_json(self.path)
        if document is None:
            return None
        try:
            program = from_data(
                document.get("program") if isinstance(document, dict) else None, str(self.path)
            )
            progress = _progress(document["progress"], program)
        except ProgramError as error:
            raise StateError(f"{self.path}: its program is not valid: {error}") from None
        except (KeyError, TypeError, ValueError) as error:
            raise StateError(f"{self.path}: not a program's progress ({error})") from None
        return program, progress

    def save(self, program: Program, progress: Progress, t: float) -> None:
        """Replace the stored progress (OSError when the disk refuses)."""
        document = {
            "program": to_data(program),
            "progress": {
                "index": progress.index,
                "phase": progress.phase,
                "paused": progress.paused,
                "reached": progress.reached,
                "held_s": progress.held_s,
                "setpoint": progress.setpoint,
                "ready_at_ns": progress.ready_at_ns,
            },
        }
        mark = (progress.index, progress.phase)
        durable = mark != self._durable or t - self._durable_at >= DURABLE_EVERY_S
        write_atomically(self.path, json.dumps(document, indent=1), durable=durable)
        if durable:
            self._durable, self._durable_at = mark, t

    def clear(self) -> None:
        """No program runs: nothing to resume."""
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()
        self._durable = None


def _progress(data: Any, program: Program) -> Progress:
    """A progress record checked field by field (nothing coerced)."""
    if not isinstance(data, dict):
        raise TypeError("'progress' must be an object")
    index, phase, held = data["index"], data["phase"], data["held_s"]
    setpoint, ready = data["setpoint"], data["ready_at_ns"]
    if not (isinstance(index, int) and 0 <= index < len(program.steps)):
        raise ValueError(f"step index {index!r} is not one of the program's")
    if phase not in PHASES:
        raise ValueError(f"phase {phase!r} is not one of {', '.join(PHASES)}")
    if not (isinstance(held, int | float) and held >= 0.0):
        raise ValueError(f"held_s {held!r} is not a time")
    if setpoint is not None and not (isinstance(setpoint, int | float) and 0 <= setpoint <= 100):
        raise ValueError(f"setpoint {setpoint!r} is not a temperature")
    if ready is not None and not isinstance(ready, int):
        raise ValueError(f"ready_at_ns {ready!r} is not a time")
    paused, reached = data["paused"], data["reached"]
    if not (isinstance(paused, bool) and isinstance(reached, bool)):
        raise ValueError("paused and reached must be true or false")
    if phase == "scheduled" and ready is None:
        raise ValueError("a scheduled program needs ready_at_ns")
    return Progress(
        index,
        phase,
        paused,
        reached,
        float(held),
        None if setpoint is None else float(setpoint),
        ready,
    )
