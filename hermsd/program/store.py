"""A running program and its progress in the state directory, so a restart or a crash
resumes it.

`program.json` holds the program, written once when it starts; `program-progress.json` a
small record of where it is (`Progress`, and the wall time of the save). The driver hands a
record over only when it matters: at each change of step, phase, pause or reached, and at
most once a minute otherwise (the hold's counted time, the ramp's position). `ProgressWriter`
writes them on a thread of its own, each durably (temporary file, fsync, rename, fsync of the
directory), so the control loop never waits on the disk. A crash or a power cut therefore
costs at most a minute of a hold's counted time and of a ramp (the rest is then that much
longer, never shorter).
"""

from __future__ import annotations

import json
import os
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple, TypeGuard

from hermsd.files import fsync_directory, write_atomically
from hermsd.program.model import Program, ProgramError, from_data, to_data
from hermsd.program.runner import PHASES, Progress
from hermsd.safety.latches import StateError, is_int, read_state_json

PROGRAM_FILE = "program.json"
PROGRESS_FILE = "program-progress.json"
STALE_SUFFIX = ".stale"  # a stored program not resumed, kept beside for the brewer to read
SAVE_EVERY_S = 60.0  # the most a crash may take off a hold's counted time (or a ramp)
CLEAR_RETRY_S = 30.0  # a failed clear is tried again this often until it lands
# How old (wall time) a save may be and still resume: a crash, systemd's restart or a
# brewer's `systemctl restart` is back within a minute or two; longer (a power cut, a boot
# days later) the water has cooled or was drained, and heating it unattended is not safe.
RESUME_WITHIN_S = 15 * 60.0
MAX_HELD_S = 7 * 86_400.0  # s: a step's counted time past its hold (waiting), or until told


class Stored(NamedTuple):
    program: Program
    progress: Progress
    saved_at_ns: int  # the wall time of the progress's save
    started_at_ns: int  # the wall time the program started: it names the program stored
    boot_id: str | None = None  # the machine's boot it was saved in (None: unknown)


BOOT_ID_FILE = Path("/proc/sys/kernel/random/boot_id")


def this_boot() -> str | None:
    """The kernel's id of the running boot, or None where there is none. A Pi without a clock
    chip starts from the time it last saved, so only the boot tells a crash from a power cut."""
    try:
        return BOOT_ID_FILE.read_text(encoding="ascii").strip() or None
    except OSError:
        return None


class ProgressStore:
    """`program.json` and `program-progress.json` in the state directory, next to the
    latches and the learned model. Every method writes at once (OSError when refused)."""

    def __init__(self, directory: Path | str, boot: str | None = None) -> None:
        self.path = Path(directory) / PROGRAM_FILE
        self.progress_path = Path(directory) / PROGRESS_FILE
        self.boot = boot if boot is not None else this_boot()

    def load(self) -> Stored | None:
        """The stored program, its progress and when; None when none. StateError if bad."""
        document = read_state_json(self.path)
        record = read_state_json(self.progress_path)
        if document is None and record is None:
            return None
        where = self.path  # the file being checked, named in the error
        try:
            if document is None or record is None:
                missing = self.path if document is None else self.progress_path
                where = self.progress_path if document is None else self.path
                raise ValueError(f"{missing.name} is missing")
            program = from_data(
                document.get("program") if isinstance(document, dict) else None, str(self.path)
            )
            started_at = _wall_ns("started_at_ns", document["started_at_ns"])
            where = self.progress_path
            if not isinstance(record, dict):
                raise TypeError("expected an object")
            if record["program_at_ns"] != started_at:
                raise ValueError("the progress is another program's")
            progress = _progress(record["progress"], program)
            saved_at = _wall_ns("saved_at_ns", record["saved_at_ns"])
            boot = record.get("boot_id")
            if boot is not None and not isinstance(boot, str):
                raise ValueError(f"boot_id {boot!r} is not a boot's id")
        except ProgramError as error:
            raise StateError(f"{self.path}: its program is not valid: {error}") from None
        except (KeyError, TypeError, ValueError) as error:
            raise StateError(f"{where}: not a program's progress ({error})") from None
        return Stored(program, progress, saved_at, started_at, boot)

    def save_program(self, program: Program, started_at_ns: int) -> None:
        """Store a program that starts (its progress follows)."""
        document = {"started_at_ns": started_at_ns, "program": to_data(program)}
        write_atomically(self.path, json.dumps(document, indent=1))

    def save_progress(self, progress: Progress, started_at_ns: int, wall_ns: int) -> None:
        """Replace the stored progress of the program started at `started_at_ns`."""
        record = {
            "program_at_ns": started_at_ns,
            "saved_at_ns": wall_ns,
            "boot_id": self.boot,
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
        write_atomically(self.progress_path, json.dumps(record))

    def clear(self) -> None:
        """No program runs: nothing to resume, after a power cut too."""
        removed = False
        for path in (self.progress_path, self.path):
            try:
                path.unlink()
            except FileNotFoundError:
                continue
            removed = True
        if removed:
            fsync_directory(self.path.parent)

    def set_aside(self) -> Path:
        """Rename the stored program's files to `….stale`, durably; where the program went."""
        for path in (self.progress_path, self.path):
            try:
                os.replace(path, path.with_name(path.name + STALE_SUFFIX))
            except FileNotFoundError:
                continue
        fsync_directory(self.path.parent)
        return self.path.with_name(self.path.name + STALE_SUFFIX)


class ProgressWriter:
    """Does the store's writes on a thread of its own, in order; of several progress
    records waiting, only the newest is written. `failure` says why the last write failed
    (None once one succeeds)."""

    def __init__(self, store: ProgressStore, clear_retry_s: float = CLEAR_RETRY_S) -> None:
        self.store = store
        self._clear_retry_s = clear_retry_s
        self.failure: str | None = None
        self._jobs: list[tuple[str, Callable[[], None]]] = []
        self._unsaved_program: Callable[[], None] | None = None  # a program write that failed
        self._busy = False
        self._retry_clear: Callable[[], None] | None = None  # a clear that failed
        self._closed = False
        self._wake = threading.Condition()
        self._thread: threading.Thread | None = None

    def program(self, program: Program, started_at_ns: int) -> None:
        self._put("program", lambda: self.store.save_program(program, started_at_ns))

    def progress(self, progress: Progress, started_at_ns: int, wall_ns: int) -> None:
        self._put("progress", lambda: self.store.save_progress(progress, started_at_ns, wall_ns))

    def clear(self) -> None:
        self._put("clear", self.store.clear)

    def flush(self, timeout: float | None = None) -> bool:
        """Wait until every write handed over is done; False when `timeout` passed first."""
        with self._wake:
            return self._wake.wait_for(lambda: not self._jobs and not self._busy, timeout)

    def close(self, timeout: float) -> bool:
        """Finish what is waiting (at most `timeout` s), then stop the thread."""
        done = self.flush(timeout)
        with self._wake:
            self._closed = True
            self._wake.notify_all()
        return done

    def _put(self, kind: str, job: Callable[[], None]) -> None:
        with self._wake:
            if kind == "clear":  # nothing before it matters any more
                self._jobs.clear()
            elif kind == "progress" and self._jobs and self._jobs[-1][0] == "progress":
                self._jobs.pop()  # the newest wins
            self._jobs.append((kind, job))
            if self._thread is None:
                self._thread = threading.Thread(
                    target=self._run, name="hermsd-program", daemon=True
                )
                self._thread.start()
            self._wake.notify_all()

    def _run(self) -> None:
        while True:
            with self._wake:
                retry = self._retry_clear
                self._wake.wait_for(
                    lambda: self._jobs or self._closed,
                    None if retry is None else self._clear_retry_s,
                )
                if retry is not None:  # first, and in order: a failed clear again
                    kind, job = "clear", retry
                elif self._jobs:
                    kind, job = self._jobs.pop(0)
                else:
                    return
                if self._closed and not self._jobs and retry is not None:
                    return  # closing: a clear that still fails stays said in `failure`
                self._retry_clear = None
                self._busy = True
            if kind == "clear":
                self._unsaved_program = None
            elif kind == "program":
                self._unsaved_program = job
            try:
                if self._unsaved_program is not None:  # its progress is nothing without it
                    self._unsaved_program()
                    self._unsaved_program = None
                if kind != "program":
                    job()
            except OSError as error:
                self.failure = str(error)
            except Exception as error:  # any fault: the thread must live to write the next
                self.failure = f"{type(error).__name__}: {error}"
            else:
                self.failure = None
            with self._wake:
                self._busy = False
                if kind == "clear" and self.failure is not None and not self._jobs:
                    # A stopped program left on disk would resume after a crash and heat:
                    # tried again every clear_retry_s until it lands, or until new writes
                    # (a new program) come to replace it.
                    self._retry_clear = job
                self._wake.notify_all()


def stale_reason(
    stored: Stored, wall_ns: int, zone_text: str, boot: str | None = None
) -> str | None:
    """Why `stored` must not resume at `wall_ns` in the boot `boot` (None: it may).
    `zone_text` is its ready-by time in local words, for a scheduled program."""
    progress, age_s = stored.progress, (wall_ns - stored.saved_at_ns) / 1e9
    if progress.phase == "done":
        return "it had finished"
    if stored.boot_id is not None and boot is not None and stored.boot_id != boot:
        return (
            "it was saved before the machine last started (a power cut or a reboot: the "
            "water may have cooled or been drained)"
        )
    if abs(age_s) > RESUME_WITHIN_S:
        when = "ago" if age_s > 0 else "ahead of this clock"
        return (
            f"it was saved {abs(age_s) / 60.0:.0f} min {when}, "
            f"more than the {RESUME_WITHIN_S / 60.0:.0f} min a restart may take"
        )
    ready = progress.ready_at_ns
    if progress.phase == "scheduled" and ready is not None and ready <= wall_ns:
        return f"its ready-by time {zone_text} has passed"
    return None


def _progress(data: Any, program: Program) -> Progress:
    """A progress record checked field by field (nothing coerced)."""
    if not isinstance(data, dict):
        raise TypeError("'progress' must be an object")
    index, phase, held = data["index"], data["phase"], data["held_s"]
    setpoint, ready = data["setpoint"], data["ready_at_ns"]
    if not (is_int(index) and 0 <= index < len(program.steps)):
        raise ValueError(f"step index {index!r} is not one of the program's")
    if phase not in PHASES:
        raise ValueError(f"phase {phase!r} is not one of {', '.join(PHASES)}")
    hold = program.steps[index].hold
    # A hold reaching its time ends at once (`Runner.period`): one still holding has held less.
    most = hold if phase == "holding" and hold is not None else MAX_HELD_S
    if not (_is_number(held) and 0.0 <= held <= most):
        raise ValueError(f"held_s {held!r} is not a time within 0–{most:g} s")
    if setpoint is not None and not (_is_number(setpoint) and 0 <= setpoint <= 100):
        raise ValueError(f"setpoint {setpoint!r} is not a temperature")
    if ready is not None:
        _wall_ns("ready_at_ns", ready)
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


def _wall_ns(key: str, value: Any) -> int:
    """A wall-clock time in ns since 1970, as the clock gives it (within 64 bits: years
    1970–2262, all of which a datetime can show); ValueError naming `key` otherwise."""
    if not (is_int(value) and 0 <= value < 2**63):
        raise ValueError(f"{key} {value!r} is not a time (ns since 1970)")
    return value


def _is_number(value: Any) -> TypeGuard[int | float]:
    return is_int(value) or isinstance(value, float)
