"""`hermsd replay` and `hermsd recover`: a brew day's logs read back, re-run, plotted; the
logs a crash left turned into finished ones."""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import sys
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hermsd.cli.common import (
    EXIT_USAGE,
    UserError,
)
from hermsd.cli.run import (
    _print_summary,
)
from hermsd.files import write_new
from hermsd.log.mcap_file import recover
from hermsd.runtime.instance import DirectoryLock, InstanceError

if TYPE_CHECKING:
    pass


def _write_new(path: Path, write: Callable[[Path], object]) -> None:
    """`write_new`, its failures said: an existing file is refused, never replaced."""
    try:
        write_new(path, write)
    except FileExistsError:
        raise UserError(f"{path}: exists; name another file or remove it first") from None
    except OSError as error:
        raise UserError(f"{path}: cannot write: {error.strerror or error}") from None


def cmd_replay(args: argparse.Namespace) -> int:
    from hermsd.log import reader, replay

    status = 0
    try:
        overrides = None if args.what_if is None else replay.parse_what_if(args.what_if)
        if args.plot is not None:
            from hermsd.log import dayplot

            dayplot.check_format(args.plot)
        if not args.files:
            raise UserError("replay: name the .mcap (or .mcap.part) files of one day")
        log = reader.load(args.files)
        result: dict[str, Any] = {}
        if args.verify:
            verification = replay.verify(log.entries)
            nothing = verification.verified == 0 and verification.mismatch is None
            if nothing and verification.other_law is None:
                raise reader.ReplayError(
                    "nothing to verify: the controller never stepped from a known state "
                    "(no auto period with a PV, or the records of its start are missing)"
                )
            status = 0 if verification.mismatch is None else 1
            result["verify"] = dataclasses.asdict(verification)
        if overrides is not None:
            logging.getLogger("hermsd").setLevel(logging.WARNING)  # not the simulated daemon's
            result["what_if"] = dataclasses.asdict(replay.what_if(log, overrides))
        if not result:
            result = replay.summarise(log)
        if args.csv is not None:
            _write_new(args.csv, partial(replay.write_csv, log))
        if args.plot is not None:
            _write_new(args.plot, partial(replay.plot, log))
    except reader.ReplayError as error:
        raise UserError(str(error)) from None
    if args.json:
        print(json.dumps(result, indent=2))
    elif "verify" in result or "what_if" in result:
        if "verify" in result:
            _print_verification(result["verify"])
        if "what_if" in result:
            _print_what_if(result["what_if"])
    else:
        _print_summary(result)
    return status


def _print_verification(verification: dict[str, Any]) -> None:
    other = verification["other_law"]
    if other is not None:
        # Not wrong, only not re-run: another law would decide otherwise (exit 0).
        law = other["logged"]
        written = (
            "a control law before law 1 (its log names none)"
            if law is None
            else f"control law {law}"
        )
        part = " in part" if other["in_part"] else ""
        print(
            f"written{part} by {written}, not re-run (this hermsd runs control law {other['runs']})"
        )
        return
    verified, unknown = verification["verified"], verification["unknown_state"]
    skipped = f" ({unknown} steps after missing records not re-run)" if unknown else ""
    mismatch = verification["mismatch"]
    if mismatch is None:
        print(f"{verified} periods verified{skipped}")
        return
    print(
        f"period k={mismatch['k']} (t {mismatch['t']!r} s) differs: {mismatch['name']} logged "
        f"{mismatch['logged']!r}, recomputed {mismatch['recomputed']!r}"
    )
    print(f"{verified} periods verified before it{skipped}")


def _print_what_if(what_if: dict[str, Any]) -> None:
    m = what_if["model"]
    print(
        f"tun model: K {m['gain']:.4g} °C/%, τ {m['tau']:.0f} s, θ {m['dead_time']:g} s, "
        f"ambient {m['ambient']:.2f} °C, start {m['start']:.2f} °C; fit RMS {m['rms']:.4f} °C "
        f"over the first {m['fit_s']:g} s"
    )
    rows = [("", "logged", "what-if")]
    settings = what_if["settings"]
    rows += [(k, settings["logged"][k], settings["what_if"][k]) for k in settings["logged"]]
    rows += [(k, what_if["logged"][k], what_if["what_if"][k]) for k in what_if["logged"]]
    width = max(len(str(row[0])) for row in rows)
    column = max(len(str(row[1])) for row in rows)
    for key, logged, new in rows:
        print(f"{key:{width}} {logged!s:{column}} {new}")


def cmd_recover(args: argparse.Namespace) -> int:
    failed = 0
    for path in args.files:
        try:
            lock = _hold_for_recovery(path.parent)
        except InstanceError as error:
            daemon = "a running hermsd" + (f" (pid {error.holder})" if error.holder else "")
            print(
                f"hermsd recover: {path}: refused, nothing touched: {path.parent} is the log "
                f"directory of {daemon}: its .part is the log being written (recover is for "
                "what a crash left); stop that daemon first",
                file=sys.stderr,
            )
            failed += 1
            continue
        try:
            print(recover(path).describe())
        except (OSError, ValueError) as error:
            print(f"hermsd recover: {path}: {error}", file=sys.stderr)
            failed += 1
        finally:
            if lock is not None:
                lock.release()
    return EXIT_USAGE if failed else 0


def _hold_for_recovery(directory: Path) -> DirectoryLock | None:
    """The log directory's lock, held while its `.part` files are recovered.

    A `.part` in the directory of a living daemon is the log it is writing: recovering it
    would leave that daemon writing on into a deleted file. Holding the lock also keeps a
    daemon from starting there mid-recovery. None when no lock file can be made there (the
    recovery, which writes beside it, says why if it cannot either).
    """
    lock = DirectoryLock(directory)
    try:
        lock.acquire("log directory")  # InstanceError when a daemon holds it
    except OSError:
        return None
    return lock
