"""A damaged chunk costs its own records, not the rest of the file.

One flipped bit in a chunk's data, in a chunk's length, or in the summary: every other
chunk's records are read (by `LogFile`, `recover` and `replay`) and the loss is said.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from test_recorder import Messages, chunked_log, chunks_of, decoded

from hermsd.cli import commands as cli
from hermsd.log.mcap_file import LogFile, recover

CHUNKS = 8
PER_CHUNK = 10
LENGTH_AT = 1  # a record: opcode (1 byte), then its length (8 bytes, little-endian)
# A zstd chunk's compressed records start after opcode, length, start and end time, size
# (8 bytes each), CRC, the name's length (4 each), "zstd" and the records' length (8): their
# first byte is the first of the zstd frame's magic number. (A bit flipped further in may be
# one zstd never reads: the chunk would be whole.)
DATA_AT = 1 + 8 + 8 + 8 + 8 + 4 + 4 + len("zstd") + 8


@pytest.fixture(scope="module")
def day(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished file of the config and 80 periods, in 8 chunks of 10 (the first 11)."""
    return chunked_log(tmp_path_factory.mktemp("day"), CHUNKS * PER_CHUNK, PER_CHUNK)


def all_but(chunks: list[tuple[int, int, Messages]], lost: int) -> Messages:
    return [m for i, (_, _, ms) in enumerate(chunks) if i != lost for m in ms]


def damaged_copy(day: Path, directory: Path, at: int, *, name: str, end: int | None = None) -> Path:
    data = bytearray(day.read_bytes())
    data[at] ^= 0x10
    path = directory / name
    path.write_bytes(data[:end])
    return path


@pytest.mark.parametrize("finished", [True, False], ids=["finished", "cut-before-summary"])
def test_a_bit_flipped_in_the_first_chunk_costs_only_that_chunk(
    day: Path, tmp_path: Path, finished: bool
) -> None:
    """The first chunk also defines the channels: the summary, or hermsd's own metadata for
    a file without one, defines them again."""
    chunks = chunks_of(day)
    assert len(chunks) == CHUNKS
    start, _, first = chunks[0]
    path = damaged_copy(
        day,
        tmp_path,
        start + DATA_AT,
        name="hermsd-20260101T000000Z.mcap" + ("" if finished else ".part"),
        end=None if finished else chunks[-1][1],
    )
    log = LogFile(path)
    assert [tuple(m) for m in log.messages()] == all_but(chunks, 0)
    [damage] = log.damaged
    assert damage.describe().startswith(f"chunk at byte {start} damaged (")
    assert damage.messages == len(first) == PER_CHUNK + 1
    if not finished:
        recovered = recover(path).path
        assert decoded(recovered) == all_but(chunks, 0)
        recovery = LogFile(recovered).metadata()["hermsd.recovery"]
        assert recovery["damaged"] == damage.describe()


@pytest.mark.parametrize("bit", [0, 7 * 8 + 6], ids=["length-off-by-one", "length-past-the-end"])
def test_a_bit_flipped_in_a_chunk_length_costs_only_that_chunk(
    day: Path, tmp_path: Path, bit: int
) -> None:
    chunks = chunks_of(day)
    start = chunks[3][0]
    data = bytearray(day.read_bytes())
    data[start + LENGTH_AT + bit // 8] ^= 1 << (bit % 8)
    path = tmp_path / "length.mcap"
    path.write_bytes(data)
    log = LogFile(path)
    assert [tuple(m) for m in log.messages()] == all_but(chunks, 3)
    [damage] = log.damaged
    assert damage.what == f"bytes {start} to {chunks[4][0]}"  # read on from the next chunk
    assert "skipped" in damage.describe()


def test_a_bit_flipped_in_the_summary_costs_nothing_and_is_said(day: Path, tmp_path: Path) -> None:
    chunks = chunks_of(day)
    size = day.stat().st_size
    path = damaged_copy(day, tmp_path, (chunks[-1][1] + size) // 2, name="summary.mcap")
    log = LogFile(path)
    assert [tuple(m) for m in log.messages()] == decoded(day)
    assert not log.finished
    [damage] = log.damaged
    assert damage.describe().startswith("the summary")
    assert damage.describe().endswith("skipped (no messages lost)")


def test_replay_reads_on_after_a_damaged_chunk_and_says_what_was_lost(
    day: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    chunks = chunks_of(day)
    start, _, second = chunks[1]
    path = damaged_copy(day, tmp_path, start + DATA_AT, name="day.mcap")
    assert cli.main(["replay", str(path)]) == 0
    out = capsys.readouterr().out
    assert f"chunk at byte {start} damaged (" in out
    assert f"skipped ({len(second)} messages lost)" in out
    assert f"{CHUNKS * PER_CHUNK - PER_CHUNK} control periods" in out
