"""`hermsd recover`: what a crash left becomes a log; the live log and the unreadable stay."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from test_recorder import chunked_log, decoded

from hermsd import cli
from hermsd.instance import DirectoryLock

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
        assert cli.main(["recover", str(part)]) == cli.EXIT_USAGE
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
