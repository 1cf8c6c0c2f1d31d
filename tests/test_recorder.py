"""The flight recorder: every record comes back, whatever happened to the process or the disk."""

from __future__ import annotations

import errno
import io
import json
import os
import random
import shutil
import struct
import threading
import time
import tracemalloc
from pathlib import Path
from typing import Any, BinaryIO, cast

import pytest
from jsonschema import Draft202012Validator
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.writer import CompressionType, Writer

import hermsd
from hermsd.config import read as config_read
from hermsd.config import schema as config_module
from hermsd.log import topics as log_topics
from hermsd.log.mcap_file import (
    LogFile,
    NotRecovered,
    Recovery,
    read_messages,
    recover,
    recover_directory,
)
from hermsd.log.recorder import RETRY_INTERVAL_S, Recorder
from hermsd.log.topics import (
    CONFIG_TOPIC,
    LOG_TOPIC,
    MODEL_TOPIC,
    PERIOD_TOPIC,
    PROGRAM_TOPIC,
    READING_TOPIC,
    TIMING_TOPIC,
    TOPICS,
    WINDOW_TOPIC,
    LogLevel,
)
from hermsd.sim.clock import VirtualClock

# 2026-01-01T00:00:00Z = 20454 days (56 years, 14 of them leap) after the Unix epoch.
EPOCH_NS = 20454 * 86400 * 1_000_000_000
S = 1_000_000_000  # ns per second

# LM92 word for 65.875 °C with the T_HIGH flag: 65.875 / 0.0625 = 1054 counts, << 3 = 8432, + 2.
PERIOD = {
    "t": 1234.5,
    "k": 247,
    "setpoint": 66.0,
    "pv": 65.875,
    "readings": [65.8125, 65.875, 65.9375],
    "output": 42.25,
    "applied": 40.0,
    "p": 10.5,
    "i": 30.25,
    "d": 1.5,
    "mode": "auto",
    "algorithm": "type_c",
    "state": "ok",
    "alarms": [],
    "heater_allowed": True,
    "reset_from": None,
    "u2": 12.5,
    "applied2": 10.0,
    "switched2": 0.0,
    "full_from": None,
    "step": "Saccharification",
    "step_index": 1,
    "step_left_s": 1795.0,
    "next_step": "Mash out",
}
PROGRAM = {
    "t": 1240.0,
    "event": "waiting",
    "program": "Step mash",
    "step": 0,
    "name": "Strike",
    "setpoint": 72.0,
    "message": "Mash in",
}
READING = {
    "t": 1234.0,
    "celsius": 65.875,
    "raw": 8434,
    "crit": False,
    "high": True,
    "low": False,
    "error": None,
    "errno": None,
    "accepted": True,
}
FAILED_READING = {
    "t": 1235.0,
    "celsius": None,
    "raw": None,
    "crit": None,
    "high": None,
    "low": None,
    "error": "I2C read of 0x48 failed: [Errno 121] Remote I/O error",
    "errno": 121,
    "accepted": False,
}
WINDOW = {"t": 1235.0, "window": 5.0, "requested": 42.25, "on_time": 2.1, "applied": 42.0}
TIMING = {
    "t": 1240.0,
    "period_lateness_p50": 0.0004,
    "period_lateness_p99": 0.0021,
    "period_lateness_max": 0.0105,
    "edge_error_p50": 0.0001,
    "edge_error_p99": 0.0009,
    "edge_error_max": 0.003,
    "overruns": 1,
    "dropped": 0,
}
CONFIG = {
    "t": 0.0,
    "config": config_read.to_dict(config_module.DEFAULT),
    "reason": "start",
    "model": {"gain": 1.689, "tau": 14961.0, "dead_time": 115.0, "ambient": 20.0},
    "safety_model": None,
    "control_law": 1,
}
MODEL = {
    "t": 6600.0,
    "learned": {
        "rate": 0.0113,
        "loss": 6.7e-5,
        "dead_time": 117.5,
        "ambient": 20.0,
        "litres": 90,
        "wall_ns": EPOCH_NS,
        "coil": 0.0,
        "coil_sd": 0.0,
        "elements": 1,
    },
}


def period(k: int) -> dict[str, Any]:
    return {**PERIOD, "k": k, "t": 5.0 * k}


class FakeDisk:
    """Creates real files behind a wrapper that fails like a full disk and signals flushes."""

    def __init__(self, error: int = errno.ENOSPC) -> None:
        self.full = False
        self.error = error  # what a write fails with while `full`
        self.flushes = 0
        self.flushed = threading.Semaphore(0)
        self.opened: list[Path] = []

    def open(self, path: Path) -> BinaryIO:
        self.opened.append(path)
        return cast(BinaryIO, _DiskFile(open(path, "xb"), self))


class _DiskFile:
    def __init__(self, file: io.BufferedWriter, disk: FakeDisk) -> None:
        self._file = file
        self._disk = disk

    def _check_space(self) -> None:
        if self._disk.full:
            raise OSError(self._disk.error, os.strerror(self._disk.error))

    def write(self, data: bytes) -> int:
        self._check_space()
        return self._file.write(data)

    def flush(self) -> None:
        self._check_space()
        self._file.flush()
        self._disk.flushes += 1
        self._disk.flushed.release()

    def tell(self) -> int:
        return self._file.tell()

    def fileno(self) -> int:
        return self._file.fileno()

    def close(self) -> None:
        self._file.close()


def conforms(value: Any, schema: dict[str, Any]) -> bool:
    """Whether `value` is valid against the JSON schema (which lets no undeclared field by)."""
    return Draft202012Validator(schema).is_valid(value)


def finished_files(directory: Path) -> list[Path]:
    return sorted(directory.glob("*.mcap"))


def decoded(path: Path) -> list[tuple[str, int, dict[str, Any]]]:
    """Messages of a finished file through the indexed reader, CRCs checked."""
    with path.open("rb") as f:
        reader = make_reader(f, validate_crcs=True)
        assert reader.get_summary() is not None
        return [
            (channel.topic, message.log_time, json.loads(message.data))
            for _, channel, message in reader.iter_messages(log_time_order=True)
        ]


def chunk_message_counts(path: Path) -> list[int]:
    records = StreamReader(str(path), emit_chunks=True, validate_crcs=True).records
    return [
        sum(isinstance(r, Message) for r in breakup_chunk(chunk))
        for chunk in records
        if isinstance(chunk, Chunk)
    ]


def test_round_trip_of_every_topic_through_the_indexed_reader(tmp_path: Path) -> None:
    clock = VirtualClock()
    recorder = Recorder(tmp_path, now=clock.monotonic, metadata={"site": "garage"})
    sent = [
        (CONFIG_TOPIC, EPOCH_NS, CONFIG),
        (READING_TOPIC, EPOCH_NS + 1 * S, READING),
        (READING_TOPIC, EPOCH_NS + 2 * S, FAILED_READING),
        (PERIOD_TOPIC, EPOCH_NS + 3 * S, PERIOD),
        (WINDOW_TOPIC, EPOCH_NS + 4 * S, WINDOW),
        (TIMING_TOPIC, EPOCH_NS + 5 * S, TIMING),
        (MODEL_TOPIC, EPOCH_NS + 6 * S, MODEL),
        (PROGRAM_TOPIC, EPOCH_NS + 6 * S + 1, PROGRAM),
    ]
    for topic, log_time, message in sent:
        recorder.write(topic, log_time, message)
    log_time = EPOCH_NS + 6 * S + 500_000_123
    recorder.log(LogLevel.WARNING, "sensor read failed twice", log_time)
    recorder.close()

    # The event, written out by hand in foxglove.Log's form.
    event = {
        "timestamp": {"sec": EPOCH_NS // S + 6, "nsec": 500_000_123},
        "level": 3,
        "message": "sensor read failed twice",
        "name": "hermsd",
        "file": "",
        "line": 0,
    }
    expected = [*sent, (LOG_TOPIC, log_time, event)]
    assert [p.name for p in tmp_path.iterdir()] == ["hermsd-20260101T000000Z.mcap"]
    path = tmp_path / "hermsd-20260101T000000Z.mcap"
    assert decoded(path) == expected
    assert list(read_messages([path])) == expected
    assert recorder.errors == recorder.dropped == recorder.lost == 0

    with path.open("rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        assert summary is not None
        schemas = {s.name: json.loads(s.data) for s in summary.schemas.values()}
        assert {s.encoding for s in summary.schemas.values()} == {"jsonschema"}
        assert {c.message_encoding for c in summary.channels.values()} == {"json"}
        topic_schema = {
            c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()
        }
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    assert topic_schema == {
        PERIOD_TOPIC: "hermsd.Period",
        READING_TOPIC: "hermsd.Reading",
        WINDOW_TOPIC: "hermsd.Window",
        TIMING_TOPIC: "hermsd.Timing",
        LOG_TOPIC: "foxglove.Log",
        CONFIG_TOPIC: "hermsd.Config",
        MODEL_TOPIC: "hermsd.LearnedModel",
        PROGRAM_TOPIC: "hermsd.ProgramEvent",
    }
    for topic, _, message in expected:
        assert conforms(message, schemas[topic_schema[topic]]), topic
    config_record = json.loads(metadata["hermsd.config"].pop("record"))
    assert metadata["hermsd"].pop("run") == recorder.run_id  # one id for all files of a run
    assert len(recorder.run_id) == 16
    assert config_record == CONFIG  # the effective config, for readers of metadata only
    assert metadata == {
        "hermsd": {
            "version": hermsd.__version__,
            "started_utc": "2026-01-01T00:00:00Z",
            "site": "garage",
        },
        "hermsd.config": {"version": hermsd.__version__},
        # Outside chunks: the channels again, for a reader whose first chunk is damaged.
        "hermsd.channels": {str(n): topic for n, topic in enumerate(TOPICS, start=1)},
    }


def test_schemas_reject_what_their_topics_must_not_carry() -> None:
    period_schema = TOPICS[PERIOD_TOPIC].schema
    assert conforms(PERIOD, period_schema)
    assert not conforms({**PERIOD, "pv": "65.9"}, period_schema)  # Foxglove plots numbers only
    assert not conforms({**PERIOD, "mode": "cruise"}, period_schema)
    assert not conforms({k: v for k, v in PERIOD.items() if k != "applied"}, period_schema)
    program_schema = TOPICS[PROGRAM_TOPIC].schema
    assert conforms(PROGRAM, program_schema)
    assert not conforms({**PROGRAM, "event": "exploded"}, program_schema)
    assert not conforms({**PROGRAM, "step": "0"}, program_schema)
    log_schema = TOPICS[LOG_TOPIC].schema
    assert not conforms({**log_topics.log_message(LogLevel.INFO, "x", 0), "level": 6}, log_schema)


def test_not_a_number_is_recorded_as_null_and_bad_records_are_counted(tmp_path: Path) -> None:
    clock = VirtualClock()
    recorder = Recorder(tmp_path, now=clock.monotonic)
    recorder.write(PERIOD_TOPIC, EPOCH_NS, {**PERIOD, "pv": float("nan"), "d": float("inf")})
    recorder.write("/hermsd/unknown", EPOCH_NS + 1, {"t": 0.0})
    recorder.write(WINDOW_TOPIC, EPOCH_NS + 2, {**WINDOW, "window": object()})
    recorder.close()
    [path] = finished_files(tmp_path)
    assert decoded(path) == [(PERIOD_TOPIC, EPOCH_NS, {**PERIOD, "pv": None, "d": None})]
    assert recorder.errors == 2
    assert recorder.last_error is not None
    assert "not JSON" in recorder.last_error


def test_a_malformed_event_costs_an_error_not_the_writer_thread(tmp_path: Path) -> None:
    clock = VirtualClock()
    recorder = Recorder(tmp_path, now=clock.monotonic)
    recorder.write(LOG_TOPIC, EPOCH_NS, cast(dict[str, Any], ["not", "an", "event"]))
    recorder.write(PERIOD_TOPIC, EPOCH_NS + S, period(1))
    recorder.close()
    [path] = finished_files(tmp_path)
    assert (PERIOD_TOPIC, EPOCH_NS + S, period(1)) in decoded(path)
    assert recorder.errors == 1


def test_full_queue_drops_new_records_and_says_so_once_there_is_room(tmp_path: Path) -> None:
    entered, release = threading.Event(), threading.Event()

    def slow_open(path: Path) -> BinaryIO:
        entered.set()
        assert release.wait(5)
        return open(path, "xb")

    clock = VirtualClock()
    recorder = Recorder(tmp_path, now=clock.monotonic, queue_size=5, open_file=slow_open)
    recorder.write(PERIOD_TOPIC, EPOCH_NS, period(0))
    assert entered.wait(5)  # the writer thread holds record 0 and waits on the disk
    for k in range(1, 9):  # 5 fill the queue, 3 are dropped
        recorder.write(PERIOD_TOPIC, EPOCH_NS + k * S, period(k))
    assert recorder.dropped == 3
    release.set()
    assert recorder.sync(timeout=5)
    recorder.write(PERIOD_TOPIC, EPOCH_NS + 9 * S, period(9))
    recorder.close()

    [path] = finished_files(tmp_path)
    messages = decoded(path)
    assert [m["k"] for topic, _, m in messages if topic == PERIOD_TOPIC] == [0, 1, 2, 3, 4, 5, 9]
    [(_, log_time, warning)] = [m for m in messages if m[0] == LOG_TOPIC]
    assert log_time == EPOCH_NS + 9 * S
    assert warning["level"] == LogLevel.WARNING
    assert "3 records dropped" in warning["message"]
    assert recorder.dropped == 3


def test_a_lossless_recorder_waits_for_room_instead_of_dropping(tmp_path: Path) -> None:
    entered, release, full = threading.Event(), threading.Event(), threading.Event()

    def slow_open(path: Path) -> BinaryIO:
        entered.set()
        assert release.wait(5)
        return open(path, "xb")

    clock = VirtualClock()
    recorder = Recorder(
        tmp_path,
        now=clock.monotonic,
        queue_size=5,
        open_file=slow_open,
        lossless=True,
    )
    recorder.write(PERIOD_TOPIC, EPOCH_NS, period(0))
    assert entered.wait(5)  # the writer thread holds record 0 and waits on the disk

    def produce() -> None:
        for k in range(1, 9):  # 5 fill the queue; the 6th must wait for room
            if k == 6:
                full.set()
            recorder.write(PERIOD_TOPIC, EPOCH_NS + k * S, period(k))

    producer = threading.Thread(target=produce)
    producer.start()
    assert full.wait(5)
    release.set()
    producer.join(5)
    recorder.close()
    [path] = finished_files(tmp_path)
    assert [m["k"] for topic, _, m in decoded(path) if topic == PERIOD_TOPIC] == list(range(9))
    assert recorder.dropped == 0


def test_disk_full_never_reaches_the_caller_and_writing_resumes_in_a_new_file(
    tmp_path: Path,
) -> None:
    disk = FakeDisk()
    clock = VirtualClock()
    recorder = Recorder(tmp_path, now=clock.monotonic, open_file=disk.open)
    recorder.write(CONFIG_TOPIC, EPOCH_NS, CONFIG)
    recorder.write(PERIOD_TOPIC, EPOCH_NS, period(0))
    assert recorder.sync(timeout=5)
    first_part = tmp_path / "hermsd-20260101T000000Z.mcap.part"
    assert recorder.current_file == first_part

    disk.full = True
    recorder.write(PERIOD_TOPIC, EPOCH_NS + 5 * S, period(1))
    assert not recorder.sync(timeout=5)
    assert recorder.errors == 1
    assert recorder.lost == 1
    assert recorder.last_error is not None
    assert str(first_part) in recorder.last_error
    assert os.strerror(errno.ENOSPC) in recorder.last_error

    disk.full = False
    clock.advance(RETRY_INTERVAL_S / 2)  # too soon to retry: the record is lost, no new file
    recorder.write(PERIOD_TOPIC, EPOCH_NS + 10 * S, period(2))
    assert not recorder.sync(timeout=5)
    assert (len(disk.opened), recorder.lost) == (1, 2)

    clock.advance(RETRY_INTERVAL_S)
    recorder.write(PERIOD_TOPIC, EPOCH_NS + 15 * S, period(3))
    assert recorder.sync(timeout=5)
    recorder.close()

    assert recorder.errors == 1
    assert len(disk.opened) == 2
    # The new file starts with the configuration again, named and stamped after its first record.
    [resumed] = finished_files(tmp_path)
    assert resumed.name == "hermsd-20260101T000015Z.mcap"
    assert decoded(resumed) == [
        (CONFIG_TOPIC, EPOCH_NS + 15 * S, CONFIG),
        (PERIOD_TOPIC, EPOCH_NS + 15 * S, period(3)),
    ]
    # The abandoned file keeps what reached the disk before it filled up.
    assert decoded(recover(first_part).path) == [
        (CONFIG_TOPIC, EPOCH_NS, CONFIG),
        (PERIOD_TOPIC, EPOCH_NS, period(0)),
    ]


def test_a_vanished_directory_is_reported_and_writing_resumes_when_it_is_back(
    tmp_path: Path,
) -> None:
    directory = tmp_path / "logs"
    clock = VirtualClock()
    recorder = Recorder(directory, now=clock.monotonic)
    recorder.write(PERIOD_TOPIC, EPOCH_NS, period(0))
    assert not recorder.sync(timeout=5)
    assert recorder.errors == 1
    assert recorder.last_error is not None
    assert str(directory) in recorder.last_error
    assert os.strerror(errno.ENOENT) in recorder.last_error

    directory.mkdir()
    clock.advance(RETRY_INTERVAL_S)
    recorder.write(PERIOD_TOPIC, EPOCH_NS + 5 * S, period(1))
    recorder.close()
    [path] = finished_files(directory)
    assert decoded(path) == [(PERIOD_TOPIC, EPOCH_NS + 5 * S, period(1))]
    assert (recorder.errors, recorder.lost) == (1, 1)


def test_files_rotate_on_log_time_and_each_starts_complete(tmp_path: Path) -> None:
    clock = VirtualClock()
    recorder = Recorder(
        tmp_path,
        now=clock.monotonic,
        rotate_s=10,
        metadata={"site": "garage"},
    )
    recorder.write(CONFIG_TOPIC, EPOCH_NS, CONFIG)
    for k, seconds in enumerate(range(0, 25, 4)):
        recorder.write(PERIOD_TOPIC, EPOCH_NS + seconds * S, period(k))
    recorder.close()

    # A file holds records less than 10 s after its first: 0 4 8 | 12 16 20 | 24.
    files = finished_files(tmp_path)
    assert [p.name for p in files] == [
        "hermsd-20260101T000000Z.mcap",
        "hermsd-20260101T000012Z.mcap",
        "hermsd-20260101T000024Z.mcap",
    ]
    for path, first_s, ks in zip(files, (0, 12, 24), ([0, 1, 2], [3, 4, 5], [6]), strict=True):
        messages = decoded(path)
        assert messages[0] == (CONFIG_TOPIC, EPOCH_NS + first_s * S, CONFIG)
        assert [m["k"] for _, _, m in messages[1:]] == ks
        assert LogFile(path).metadata()["hermsd"]["site"] == "garage"
    assert not list(tmp_path.glob("*.part"))


def test_files_started_in_the_same_second_get_distinct_names(tmp_path: Path) -> None:
    recorder = Recorder(tmp_path, rotate_s=0.25)
    for k in range(3):
        recorder.write(PERIOD_TOPIC, EPOCH_NS + k * S // 4, period(k))  # 0, 0.25, 0.5 s
    recorder.close()
    assert [p.name for p in finished_files(tmp_path)] == [
        "hermsd-20260101T000000Z-1.mcap",
        "hermsd-20260101T000000Z-2.mcap",
        "hermsd-20260101T000000Z.mcap",
    ]


def test_records_reach_the_os_within_the_flush_interval(tmp_path: Path) -> None:
    disk = FakeDisk()
    flush_interval = 0.05
    recorder = Recorder(tmp_path, flush_interval=flush_interval, open_file=disk.open)
    handed_over = time.monotonic()
    recorder.write(PERIOD_TOPIC, EPOCH_NS, period(0))
    assert disk.flushed.acquire(timeout=5)
    waited = time.monotonic() - handed_over
    # Not before the interval (chunks stay whole for compression); well within it plus a
    # scheduling margin after.
    assert flush_interval <= waited < flush_interval + 2.0
    part = LogFile(tmp_path / "hermsd-20260101T000000Z.mcap.part")
    assert [m.message for m in part.messages()] == [period(0)]
    assert not part.finished
    recorder.close()


def test_fdatasync_at_most_every_sync_interval(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    disk = FakeDisk()
    synced_after_flush: list[int] = []
    monkeypatch.setattr(os, "fdatasync", lambda fd: synced_after_flush.append(disk.flushes))
    clock = VirtualClock()
    recorder = Recorder(
        tmp_path,
        now=clock.monotonic,
        flush_interval=0.0,
        sync_interval=10.0,
        open_file=disk.open,
    )
    for seconds in range(35):
        clock.sleep_until(seconds)
        recorder.write(PERIOD_TOPIC, EPOCH_NS + seconds * S, period(seconds))
        assert disk.flushed.acquire(timeout=5)  # flush_interval 0: one flush per record
    recorder.close()
    # The file opens at 0 s; record n is flush n + 1. Syncs at 10, 20, 30 s, then at close
    # after the 36th flush (the finished file).
    assert synced_after_flush == [11, 21, 31, 36]


def test_memory_does_not_grow_with_the_chunks_of_a_file(tmp_path: Path) -> None:
    """A chunk per flush (43,200 a day at 2 s) costs the writer no memory per chunk: the
    daemon runs for months. mcap's Writer kept some 600 bytes a chunk until the file closed."""
    clock = VirtualClock()  # flush_interval 0: every record is a chunk of its own
    recorder = Recorder(tmp_path, now=clock.monotonic, flush_interval=0.0, sync_interval=1e9)
    chunks = 1500

    def write_chunks(first: int) -> int:
        for k in range(first, first + chunks):
            recorder.write(WINDOW_TOPIC, EPOCH_NS + k * S, WINDOW)
        assert recorder.sync(timeout=60)
        return tracemalloc.get_traced_memory()[0]

    tracemalloc.start()
    try:
        write_chunks(0)  # the file, its channels and the writer's buffers made
        before = write_chunks(chunks)
        grown = write_chunks(2 * chunks) - before
    finally:
        tracemalloc.stop()
    recorder.close()
    assert grown < 20 * chunks  # bytes per chunk: noise, not an index entry
    [path] = finished_files(tmp_path)
    with path.open("rb") as f:  # … and the summary still indexes every chunk
        summary = make_reader(f, validate_crcs=True).get_summary()
    assert summary is not None and len(summary.chunk_indexes) == 3 * chunks
    data = path.read_bytes()
    for entry in summary.chunk_indexes:  # where a seeking reader (Foxglove) will look
        assert struct.unpack_from("<BQ", data, entry.chunk_start_offset) == (
            0x06,  # a chunk record, of the length indexed
            entry.chunk_length - 9,
        )
        for channel, offset in entry.message_index_offsets.items():
            assert struct.unpack_from("<BQH", data, offset)[::2] == (0x07, channel)
    assert [topic for topic, _, _ in decoded(path)] == [WINDOW_TOPIC] * (3 * chunks)


def test_an_error_event_reaches_the_os_at_once(tmp_path: Path) -> None:
    disk = FakeDisk()
    clock = VirtualClock()  # never advances: no flush is due by time
    recorder = Recorder(tmp_path, now=clock.monotonic, open_file=disk.open)
    recorder.write(PERIOD_TOPIC, EPOCH_NS, period(0))
    recorder.log(LogLevel.INFO, "heating", EPOCH_NS + 1)
    recorder.log(LogLevel.ERROR, "sensor lost", EPOCH_NS + 2)
    assert disk.flushed.acquire(timeout=5)
    recorder.write(PERIOD_TOPIC, EPOCH_NS + 3, period(1))
    recorder.close()
    [path] = finished_files(tmp_path)
    assert chunk_message_counts(path) == [3, 1]


def test_writing_after_close_is_dropped_quietly(tmp_path: Path) -> None:
    recorder = Recorder(tmp_path)
    recorder.close()
    recorder.write(PERIOD_TOPIC, EPOCH_NS, period(0))
    recorder.close()
    assert recorder.dropped == 1
    assert not recorder.sync(timeout=1)


def test_recover_a_file_copied_while_the_recorder_was_writing(tmp_path: Path) -> None:
    live, crashed = tmp_path / "live", tmp_path / "crashed"
    live.mkdir()
    crashed.mkdir()
    clock = VirtualClock()
    recorder = Recorder(live, now=clock.monotonic, metadata={"site": "garage"})
    recorder.write(CONFIG_TOPIC, EPOCH_NS, CONFIG)
    for k in range(10):
        recorder.write(PERIOD_TOPIC, EPOCH_NS + k * S, period(k))
    assert recorder.sync(timeout=5)
    part = crashed / "hermsd-20260101T000000Z.mcap.part"
    shutil.copyfile(live / part.name, part)  # what a power cut would leave
    for k in range(10, 15):
        recorder.write(PERIOD_TOPIC, EPOCH_NS + k * S, period(k))
    recorder.close()

    before = [(CONFIG_TOPIC, EPOCH_NS, CONFIG)] + [
        (PERIOD_TOPIC, EPOCH_NS + k * S, period(k)) for k in range(10)
    ]
    cut = LogFile(part)
    assert list(cut.messages()) == before
    assert (cut.finished, cut.count, cut.cut_at) == (False, 11, part.stat().st_size)

    recovered = recover(part).path
    assert recovered == crashed / "hermsd-20260101T000000Z.mcap"
    assert not part.exists()
    assert decoded(recovered) == before
    metadata = LogFile(recovered).metadata()
    assert metadata["hermsd"]["site"] == "garage"
    assert metadata["hermsd.recovery"]["messages"] == "11"
    assert list(crashed.iterdir()) == [recovered]


def chunked_log(directory: Path, periods: int, per_chunk: int) -> Path:
    """A finished file of the config and `periods` periods, a chunk per `per_chunk` of them
    (the first chunk holds the config too)."""
    clock = VirtualClock()
    recorder = Recorder(directory, now=clock.monotonic)
    recorder.write(CONFIG_TOPIC, EPOCH_NS, CONFIG)
    for k in range(periods):
        recorder.write(PERIOD_TOPIC, EPOCH_NS + k * S, period(k))
        if k % per_chunk == per_chunk - 1:
            assert recorder.sync(timeout=5)
    recorder.close()
    [path] = finished_files(directory)
    return path


@pytest.fixture(scope="module")
def finished_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished file of 31 messages in 6 chunks: config and 30 periods, a sync every 5."""
    return chunked_log(tmp_path_factory.mktemp("finished"), 30, 5)


Messages = list[tuple[str, int, dict[str, Any]]]


def chunks_of(path: Path) -> list[tuple[int, int, Messages]]:
    """(start, end, messages) of every chunk, found through the file's own chunk index."""
    chunks = []
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
        assert summary is not None
        topics = {c.id: c.topic for c in summary.channels.values()}
        for index in sorted(summary.chunk_indexes, key=lambda i: i.chunk_start_offset):
            f.seek(index.chunk_start_offset)
            chunk = next(StreamReader(f, skip_magic=True, emit_chunks=True).records)
            assert isinstance(chunk, Chunk)
            messages = [
                (topics[r.channel_id], r.log_time, json.loads(r.data))
                for r in breakup_chunk(chunk, validate_crc=True)
                if isinstance(r, Message)
            ]
            start = index.chunk_start_offset
            chunks.append((start, start + index.chunk_length, messages))
    return chunks


def cut_offsets(path: Path, chunk_ends: list[int], samples: int) -> list[int]:
    """Offsets around every chunk end, inside the magic, and at random."""
    size = path.stat().st_size
    around_ends = {end + d for end in chunk_ends for d in (-1, 0, 1)}
    rng = random.Random(20260101)
    return sorted(
        (around_ends | {0, 1, 8, 9, size - 1} | set(rng.sample(range(size), samples))) - {size}
    )


def test_a_cut_file_yields_every_message_of_its_complete_chunks(
    finished_log: Path, tmp_path: Path
) -> None:
    data = finished_log.read_bytes()
    chunks = chunks_of(finished_log)
    assert [len(messages) for _, _, messages in chunks] == [6, 5, 5, 5, 5, 5]
    path = tmp_path / "cut.mcap.part"
    for cut in cut_offsets(finished_log, [end for _, end, _ in chunks], samples=150):
        path.write_bytes(data[:cut])
        expected = [m for _, end, messages in chunks if end <= cut for m in messages]
        log = LogFile(path)
        assert [tuple(m) for m in log.messages()] == expected, cut
        assert not log.finished
        assert log.count == len(expected)
        assert log.cut_at is not None
        assert log.cut_at <= cut


def test_recover_keeps_every_complete_chunk_of_a_cut_file(
    finished_log: Path, tmp_path: Path
) -> None:
    data = finished_log.read_bytes()
    chunks = chunks_of(finished_log)
    for cut in cut_offsets(finished_log, [end for _, end, _ in chunks][:2], samples=20):
        part = tmp_path / f"hermsd-cut{cut}.mcap.part"
        part.write_bytes(data[:cut])
        expected = [m for _, end, ms in chunks if end <= cut for m in ms]
        if not expected:  # nothing to make a log of: the bytes stay as they are
            with pytest.raises(NotRecovered, match="no message readable"):
                recover(part)
            assert part.read_bytes() == data[:cut]
            continue
        recovered = recover(part).path
        assert decoded(recovered) == expected, cut
        assert not part.exists()
        assert LogFile(recovered).metadata()["hermsd.recovery"]["source_bytes"] == str(cut)


def test_recover_keeps_the_part_when_the_new_file_cannot_be_made(
    finished_log: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    part = tmp_path / "hermsd-20260101T000000Z.mcap.part"
    data = finished_log.read_bytes()[:-100]
    part.write_bytes(data)

    def full_disk(source: Path, target: Path) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    with monkeypatch.context() as patch:
        patch.setattr(os, "replace", full_disk)
        with pytest.raises(OSError, match=os.strerror(errno.ENOSPC)):
            recover(part)
    assert part.read_bytes() == data
    assert decoded(recover(part).path) == decoded(finished_log)


def test_recover_directory_finishes_every_leftover_part(finished_log: Path, tmp_path: Path) -> None:
    data = finished_log.read_bytes()
    chunks = chunks_of(finished_log)
    # Finished but never renamed (a crash between the two), and cut inside the fourth chunk.
    (tmp_path / "hermsd-20260101T000000Z.mcap.part").write_bytes(data)
    (tmp_path / "hermsd-20260102T000000Z.mcap.part").write_bytes(data[: chunks[3][1] - 1])
    untouched = tmp_path / "hermsd-20251231T000000Z.mcap"
    untouched.write_bytes(data)

    recovered = [cast(Recovery, outcome).path for outcome in recover_directory(tmp_path)]
    assert recovered == [
        tmp_path / "hermsd-20260101T000000Z.mcap",
        tmp_path / "hermsd-20260102T000000Z.mcap",
    ]
    assert decoded(recovered[0]) == decoded(finished_log)
    assert decoded(recovered[1]) == [m for _, _, ms in chunks[:3] for m in ms]
    assert untouched.read_bytes() == data
    assert not list(tmp_path.glob("*.part"))


def test_only_the_topics_asked_for_are_read(finished_log: Path, tmp_path: Path) -> None:
    data = finished_log.read_bytes()
    chunks = chunks_of(finished_log)
    cut = tmp_path / "cut.mcap.part"
    cut.write_bytes(data[: chunks[3][1] + 10])
    for path in (finished_log, cut):
        everything = list(LogFile(path).messages())
        log = LogFile(path)
        periods = list(log.messages({PERIOD_TOPIC}))
        assert periods == [m for m in everything if m.topic == PERIOD_TOPIC]
        assert log.count == len(periods) < len(everything) == log.recovered
    whole = LogFile(finished_log)
    assert len(list(whole.messages())) == 31
    assert (whole.finished, whole.cut_at, whole.cut_reason) == (True, None, None)


def test_a_damaged_chunk_is_skipped_and_said(finished_log: Path, tmp_path: Path) -> None:
    data = bytearray(finished_log.read_bytes())
    chunks = chunks_of(finished_log)
    third_start, third_end, third = chunks[2]
    data[(third_start + third_end) // 2] ^= 0x55  # a bit flip inside the third chunk
    path = tmp_path / "damaged.mcap.part"
    path.write_bytes(data[: chunks[4][1]])
    log = LogFile(path)
    assert [tuple(m) for m in log.messages()] == [
        m for i, (_, _, ms) in enumerate(chunks[:5]) if i != 2 for m in ms
    ]
    [damage] = log.damaged
    assert (damage.what, damage.messages) == (f"chunk at byte {third_start}", len(third))
    assert damage.describe().startswith(f"chunk at byte {third_start} damaged (")
    assert damage.describe().endswith(f"skipped ({len(third)} messages lost)")
    assert (log.cut_at, log.cut_reason) == (chunks[4][1], None)


# A chunk record, by the MCAP spec: opcode (1 byte) and length (8), then message start and end
# times (8 each), uncompressed size (8) and uncompressed CRC (4).
CHUNK_SIZE_AT = 1 + 8 + 8 + 8
CHUNK_CRC_AT = CHUNK_SIZE_AT + 8


@pytest.mark.parametrize(
    ("field", "reason"), [(CHUNK_CRC_AT, "CRC"), (CHUNK_SIZE_AT, "bytes, not the")]
)
def test_a_chunk_that_does_not_match_its_size_or_crc_is_skipped(
    finished_log: Path, tmp_path: Path, field: int, reason: str
) -> None:
    data = bytearray(finished_log.read_bytes())
    chunks = chunks_of(finished_log)
    third_start = chunks[2][0]
    data[third_start + field] ^= 0x01  # the records themselves are intact
    path = tmp_path / "damaged.mcap.part"
    path.write_bytes(data[: chunks[4][1]])
    log = LogFile(path)
    assert [tuple(m) for m in log.messages()] == [
        m for i, (_, _, ms) in enumerate(chunks[:5]) if i != 2 for m in ms
    ]
    [damage] = log.damaged
    assert damage.what == f"chunk at byte {third_start}"
    assert reason in damage.reason
    assert (log.cut_at, log.cut_reason) == (chunks[4][1], None)


def test_a_chunk_crc_of_zero_is_not_checked(finished_log: Path, tmp_path: Path) -> None:
    data = bytearray(finished_log.read_bytes())
    chunks = chunks_of(finished_log)
    third_start = chunks[2][0]
    data[third_start + CHUNK_CRC_AT : third_start + CHUNK_CRC_AT + 4] = bytes(4)  # "none"
    path = tmp_path / "no-crc.mcap.part"
    path.write_bytes(data[: chunks[4][1]])  # five whole chunks
    log = LogFile(path)
    assert [tuple(m) for m in log.messages()] == [m for _, _, ms in chunks[:5] for m in ms]
    assert (log.cut_at, log.cut_reason) == (chunks[4][1], None)


def test_a_file_cut_between_records_ended_there_one_cut_inside_a_record_says_so(
    finished_log: Path, tmp_path: Path
) -> None:
    data = finished_log.read_bytes()
    chunks = chunks_of(finished_log)
    path = tmp_path / "cut.mcap.part"
    path.write_bytes(data[: chunks[1][1]])
    log = LogFile(path)
    assert len(list(log.messages())) == 6 + 5
    assert (log.cut_at, log.cut_reason) == (chunks[1][1], None)
    # One byte less: the second chunk is torn; the first one's message indexes are whole.
    path.write_bytes(data[: chunks[1][1] - 1])
    log = LogFile(path)
    assert len(list(log.messages())) == 6
    assert (log.cut_at, log.cut_reason) == (chunks[1][0], "the file ends inside a record")


# The footer, by the MCAP spec: opcode, length (8 bytes), summary start (8), summary offset
# start (8), summary CRC (4), then the 8 bytes of magic that end the file.
FOOTER_FROM_END = 1 + 8 + 8 + 8 + 4 + 8


def test_a_footer_that_does_not_match_its_summary_is_not_finished(
    finished_log: Path, tmp_path: Path
) -> None:
    data = bytearray(finished_log.read_bytes())
    offset_start = len(data) - FOOTER_FROM_END + 1 + 8 + 8  # covered by the summary CRC
    data[offset_start] ^= 0x01
    path = tmp_path / "torn.mcap"
    path.write_bytes(data)
    log = LogFile(path)
    assert [tuple(m) for m in log.messages()] == decoded(finished_log)
    assert (log.finished, log.cut_at, log.cut_reason) == (False, len(data), None)


def test_a_footer_without_a_summary_crc_is_taken_as_it_is(
    finished_log: Path, tmp_path: Path
) -> None:
    data = bytearray(finished_log.read_bytes())
    crc_at = len(data) - FOOTER_FROM_END + 1 + 8 + 8 + 8
    data[crc_at : crc_at + 4] = bytes(4)  # a CRC of 0 means none was computed
    data[crc_at - 1] ^= 0x01  # so this change cannot be seen
    path = tmp_path / "no-crc.mcap"
    path.write_bytes(data)
    log = LogFile(path)
    assert len(list(log.messages())) == 31
    assert (log.finished, log.cut_at) == (True, None)


def test_a_footer_without_its_closing_magic_is_not_finished(
    finished_log: Path, tmp_path: Path
) -> None:
    data = finished_log.read_bytes()
    path = tmp_path / "torn.mcap.part"
    path.write_bytes(data[:-1])
    log = LogFile(path)
    assert [tuple(m) for m in log.messages()] == decoded(finished_log)
    assert not log.finished
    assert log.cut_at == len(data) - 8  # the footer was whole
    assert log.cut_reason is not None
    assert "magic" in log.cut_reason


def written_by_mcap(path: Path, log_times: list[int], **options: Any) -> None:
    """Periods logged at `log_times` (in that order) by the mcap library with its `options`."""
    with path.open("wb") as f:
        writer = Writer(f, **options)
        writer.start(profile="", library="another recorder")
        schema = writer.register_schema("hermsd.Period", "jsonschema", b"{}")
        channel = writer.register_channel(PERIOD_TOPIC, "json", schema)
        for k, log_time in enumerate(log_times):
            writer.add_message(channel, log_time, json.dumps(period(k)).encode(), log_time)
        writer.add_metadata("hermsd", {"site": "garage"})
        writer.finish()  # type: ignore[no-untyped-call]


@pytest.mark.parametrize(
    "options",
    [
        {"compression": CompressionType.NONE, "enable_crcs": False},
        {"use_chunking": False},
    ],
    ids=["uncompressed-no-crcs", "unchunked"],
)
def test_files_of_other_writers_are_read_in_log_time_order(
    tmp_path: Path, options: dict[str, Any]
) -> None:
    path = tmp_path / "other.mcap"
    written_by_mcap(path, [EPOCH_NS + 2 * S, EPOCH_NS, EPOCH_NS + S], **options)
    log = LogFile(path)
    assert list(log.messages()) == [
        (PERIOD_TOPIC, EPOCH_NS, period(1)),
        (PERIOD_TOPIC, EPOCH_NS + S, period(2)),
        (PERIOD_TOPIC, EPOCH_NS + 2 * S, period(0)),
    ]
    assert (log.finished, log.recovered, log.cut_at) == (True, 3, None)


def test_a_data_section_crc_is_checked(tmp_path: Path) -> None:
    path = tmp_path / "data-crc.mcap"
    written_by_mcap(path, [EPOCH_NS, EPOCH_NS + S], enable_data_crcs=True)
    log = LogFile(path)
    assert len(list(log.messages())) == 2
    assert (log.finished, log.cut_at) == (True, None)

    data = bytearray(path.read_bytes())
    at = data.index(b"garage")  # in the metadata record: no CRC of its own
    data[at : at + 6] = b"garbge"
    path.write_bytes(data)
    summary_start = int.from_bytes(data[-FOOTER_FROM_END + 9 : -FOOTER_FROM_END + 17], "little")
    log = LogFile(path)
    assert len(list(log.messages())) == 2  # the chunk is whole
    assert log.finished  # the summary is too
    assert log.cut_at == summary_start - (1 + 8 + 4)  # the data end record: opcode, length, CRC
    assert log.cut_reason is not None
    assert "CRC" in log.cut_reason


def test_chunks_compressed_other_than_with_zstd_are_skipped(tmp_path: Path) -> None:
    path = tmp_path / "lz4.mcap"
    written_by_mcap(path, [EPOCH_NS], compression=CompressionType.LZ4)
    log = LogFile(path)
    assert list(log.messages()) == []
    [damage] = log.damaged
    assert "lz4" in damage.reason


def test_a_zero_filled_tail_after_a_power_cut_keeps_what_came_before(
    finished_log: Path, tmp_path: Path
) -> None:
    chunks = chunks_of(finished_log)
    path = tmp_path / "hermsd-20260101T000000Z.mcap.part"
    path.write_bytes(finished_log.read_bytes()[: chunks[1][1]] + bytes(4096))
    assert decoded(recover(path).path) == [m for _, _, ms in chunks[:2] for m in ms]


def test_an_unfinished_file_is_read_in_log_time_order(tmp_path: Path) -> None:
    clock = VirtualClock()
    recorder = Recorder(tmp_path, now=clock.monotonic)
    recorder.write(PERIOD_TOPIC, EPOCH_NS + 2 * S, period(0))
    recorder.log(LogLevel.INFO, "stamped before the period, handed over after", EPOCH_NS + S)
    assert recorder.sync(timeout=5)
    part = tmp_path / "hermsd-20260101T000002Z.mcap.part"  # named after the first handed over
    unfinished = [m.topic for m in LogFile(part).messages()]
    recorder.close()
    assert unfinished == [LOG_TOPIC, PERIOD_TOPIC]
    assert [m.topic for m in read_messages(finished_files(tmp_path))] == unfinished


def test_a_file_is_named_after_the_log_time_of_its_first_record(tmp_path: Path) -> None:
    recorder = Recorder(tmp_path, rotate_s=3600)
    first = EPOCH_NS + (3600 + 2 * 60 + 3) * S + 999_999_999  # 01:02:03.999…, named 01:02:03
    recorder.write(PERIOD_TOPIC, first, period(1))
    recorder.write(PERIOD_TOPIC, first + 3600 * S, period(2))  # one hour on: a new file
    recorder.close()
    files = finished_files(tmp_path)
    assert [p.name for p in files] == [
        "hermsd-20260101T010203Z.mcap",
        "hermsd-20260101T020203Z.mcap",
    ]
    assert [LogFile(p).metadata()["hermsd"]["started_utc"] for p in files] == [
        "2026-01-01T01:02:03Z",
        "2026-01-01T02:02:03Z",
    ]
