"""A state directory that cannot keep latched alarms stops the daemon before it heats.

A latched alarm that a restart cannot find comes back as a heater that is on over the fault
(the unit restarts the daemon on any exit). So `run` and `simulate --state` refuse to start,
the heater never switched on, when the state directory cannot be made, locked or written
durably; and a failed write leaves no temporary file behind.
"""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest

from hermsd import files
from hermsd.cli import commands as cli
from hermsd.cli import common
from hermsd.control.learning import LEARNED_FILE, LearnedModel, ModelStore
from hermsd.runtime import instance
from hermsd.runtime.instance import LOCK_FILE, DirectoryLock
from hermsd.runtime.latch_keeping import latch_save_failed_text
from hermsd.runtime.saver import Outcome
from hermsd.safety.latches import LATCHED_FILE, Latches, LatchStore

RUN = ["run", "--simulate", "--speed", "max", "--duration", "10s", "--state"]
SIMULATE = ["simulate", "--scenario", "scenarios/ssr-stuck-on.yaml", "--state"]
ROOT = Path(__file__).resolve().parent.parent


def _no_space(*_args: object, **_kwargs: object) -> None:
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def _refused(capsys: pytest.CaptureFixture[str], args: list[str]) -> str:
    """The one line the daemon said on refusing to start (it must not have started)."""
    code = cli.main(args)
    out, err = capsys.readouterr()
    assert code == common.EXIT_USAGE
    assert out == ""  # not even the control socket's line
    [line] = err.splitlines()
    assert line.startswith("hermsd: ") and "not started, heater off" in line
    return line


@pytest.mark.parametrize("command", [RUN, SIMULATE], ids=["run", "simulate"])
def test_a_state_directory_that_cannot_be_made_refuses_the_start(
    tmp_path: Path, command: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "file").write_text("")
    state = tmp_path / "file" / "state"  # its parent is a file: read-only, even for root

    line = _refused(capsys, [*command, str(state)])

    assert str(state) in line and "Not a directory" in line


FULL_DISK = {
    # The lock file cannot be made or written: nothing is locked.
    "lock": (DirectoryLock, "acquire", "cannot lock the state directory"),
    # The lock file is already there; a new file's blocks are not.
    "latch": (files.os, "fsync", "cannot keep latched alarms in"),
}


@pytest.mark.parametrize("failing", FULL_DISK.values(), ids=FULL_DISK)
@pytest.mark.parametrize("command", [RUN, SIMULATE], ids=["run", "simulate"])
def test_a_full_state_directory_refuses_the_start_and_leaves_nothing_half_written(
    tmp_path: Path,
    command: list[str],
    failing: tuple[object, str, str],
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    owner, name, said = failing
    monkeypatch.chdir(ROOT)
    monkeypatch.setattr(owner, name, _no_space)

    line = _refused(capsys, [*command, str(tmp_path)])

    assert f"{said} {tmp_path}: No space left on device" in line
    assert not [p for p in tmp_path.iterdir() if p.name != LOCK_FILE]  # no probe, no .tmp


def test_a_writable_state_directory_leaves_nothing_of_the_probe(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert cli.main([*RUN, str(tmp_path)]) == 0
    capsys.readouterr()
    assert not [p for p in tmp_path.iterdir() if "probe" in p.name or p.suffix == ".tmp"]


@pytest.mark.parametrize(
    "save",
    [
        lambda d: LatchStore(d).save(Latches()),
        lambda d: ModelStore(d).save(LearnedModel(0.01, 1e-4, 60.0, 20.0, 30.0)),
    ],
    ids=[LATCHED_FILE, LEARNED_FILE],
)
@pytest.mark.parametrize("failing", ["fsync", "replace"])
def test_a_failed_save_leaves_no_temporary_file_and_the_old_file_as_it_was(
    tmp_path: Path, save: object, failing: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    assert callable(save)
    (tmp_path / "keep").write_text("old")
    monkeypatch.setattr(files.os, failing, _no_space)

    with pytest.raises(OSError, match="No space left"):
        save(tmp_path)

    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep"]


def test_a_lock_file_that_cannot_be_written_is_not_held(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A full disk makes the lock file but not its pid: nothing stays locked or open."""
    with monkeypatch.context() as patch:
        patch.setattr(instance.os, "write", _no_space)
        with pytest.raises(OSError, match="No space left"):
            DirectoryLock(tmp_path).acquire("state directory")
    again = DirectoryLock(tmp_path)
    again.acquire("state directory")  # not refused as held by this very process
    again.release()


def test_a_failed_save_says_which_latched_alarms_a_restart_would_lose() -> None:
    lost = Outcome("latches", ["dry_fire", "ssr_stuck_on"], "[Errno 28] No space left on device")
    assert latch_save_failed_text(lost, ["dry_fire"]) == (
        "saving latched alarms failed: [Errno 28] No space left on device: ssr_stuck_on will "
        "NOT survive a restart (the heater stays off while latched; tried again every 30 s)"
    )
    cleared = Outcome("latches", [], "[Errno 28] No space left on device")
    assert latch_save_failed_text(cleared, ["dry_fire"]) == (
        "saving latched alarms failed: [Errno 28] No space left on device "
        "(a restart finds dry_fire, as on disk)"
    )
