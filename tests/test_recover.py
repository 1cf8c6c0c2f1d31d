"""`hermsd recover`: what a crash left becomes a log; the live log and the unreadable stay."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import pytest
from test_recorder import chunked_log, chunks_of, decoded

from hermsd.cli import commands as cli
from hermsd.cli import common, run
from hermsd.config import schema as config
from hermsd.runtime.instance import DirectoryLock

PERIODS = 20
PER_CHUNK = 5


@pytest.fixture(scope="module")
def day(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished file of the config and 20 periods, in 4 chunks of 5 (the first 6)."""
    return chunked_log(tmp_path_factory.mktemp("day"), PERIODS, PER_CHUNK)


def test_the_part_a_running_daemon_writes_is_refused_and_left_as_it_is(
    day: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    logs = tmp_path / "logs"
    logs.mkdir()
    part = logs / "hermsd-20260101T000000Z.mcap.part"
    data = day.read_bytes()[:-100]
    part.write_bytes(data)
    daemon = DirectoryLock(logs)  # as a running daemon holds its log directory
    daemon.acquire("log directory")
    try:
        assert cli.main(["recover", str(part)]) == common.EXIT_USAGE
        err = capsys.readouterr().err
        assert f"{logs} is the log directory of a running hermsd (pid {os.getpid()})" in err
        assert "nothing touched" in err
        assert sorted(p.name for p in logs.iterdir()) == [".hermsd.lock", part.name]
        assert part.read_bytes() == data
    finally:
        daemon.release()
    # Once that daemon is gone, the .part is what it left: recovered.
    assert cli.main(["recover", str(part)]) == 0
    assert not part.exists()
    assert decoded(logs / "hermsd-20260101T000000Z.mcap") == decoded(day)


@pytest.mark.parametrize(
    "damage",
    [b"\0" * 8, b"", b"not a log at all"],
    ids=["magic-zeroed", "empty", "junk"],
)
def test_a_part_with_nothing_readable_is_left_as_it_is_and_said(
    day: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], damage: bytes
) -> None:
    part = tmp_path / "hermsd-20260101T000000Z.mcap.part"
    data = damage + day.read_bytes()[len(damage) :] if damage == b"\0" * 8 else damage
    part.write_bytes(data)
    assert cli.main(["recover", str(part)]) == common.EXIT_USAGE
    err = capsys.readouterr().err
    assert f"no message readable in its {len(data)} bytes" in err
    assert "left as it is" in err
    assert part.read_bytes() == data
    assert sorted(p.name for p in tmp_path.iterdir()) == [".hermsd.lock", part.name]


def test_a_daemon_starting_beside_an_unreadable_part_says_so_keeps_it_and_runs(
    day: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    junk = tmp_path / "hermsd-20251231T000000Z.mcap.part"
    junk.write_bytes(b"\0" * 8 + day.read_bytes()[8:])
    cut = tmp_path / "hermsd-20260101T000000Z.mcap.part"
    cut.write_bytes(day.read_bytes()[:-100])
    with caplog.at_level(logging.WARNING, logger="hermsd"):
        recorder = run._open_recorder(tmp_path, config.DEFAULT)
    recorder.close()
    said = caplog.text
    assert f"{junk} not recovered: no message readable" in said
    assert junk.read_bytes()[8:] == day.read_bytes()[8:]
    assert f"recovered {tmp_path / 'hermsd-20260101T000000Z.mcap'} from {cut.name}: " in said
    assert decoded(tmp_path / "hermsd-20260101T000000Z.mcap") == decoded(day)


def test_what_a_recovery_kept_of_a_cut_part_is_said(
    day: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = day.read_bytes()
    whole = tmp_path / "hermsd-20260101T000000Z.mcap.part"
    whole.write_bytes(data[:-100])  # into the summary: every chunk read
    cut = tmp_path / "hermsd-20260102T000000Z.mcap.part"
    third = chunks_of(day)[2]
    cut.write_bytes(data[: third[1] - 1])  # inside the third chunk: the first two kept
    assert cli.main(["recover", str(whole), str(cut)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith(
        f"{tmp_path / 'hermsd-20260101T000000Z.mcap'} from {whole.name}: {1 + PERIODS} "
        f"messages, read to the end of its {len(data) - 100} bytes"
    )
    assert out[1] == (
        f"{tmp_path / 'hermsd-20260102T000000Z.mcap'} from {cut.name}: {1 + 2 * PER_CHUNK} "
        f"messages, read to byte {third[0]} of its {third[1] - 1} (the rest lost)"
    )
