"""A real `hermsd run` killed with SIGKILL: its restart recovers the log it was writing.

This test runs on the real clock (a real process cannot be killed on a virtual one): the
daemon runs at 20 times real time for a few seconds. What it must have handed to the recorder
is known without the log: period k is due 5 s (simulated) after period k − 1, and the kill
time on the daemon's clock follows from when the daemon said it had started.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import time
from pathlib import Path

from mcap.reader import make_reader

from hermsd.config import schema as config_module
from hermsd.log.topics import (
    LOG_TOPIC,
    PART_SUFFIX,
    PERIOD_TOPIC,
    READING_TOPIC,
    RECOVERY_METADATA_NAME,
)
from hermsd.sim.clock import DEFAULT_EPOCH_NS

SPEED = 20.0  # simulated seconds per real second
PERIOD_S = config_module.DEFAULT.control.period  # 5 s of simulated time
PROMISE_S = 2.0  # real seconds: what was handed over before kill − 2 s must survive
# A crash costs at most the records since the last flush. At the default flush_interval (2 s)
# the promise would have no room for a loaded machine's scheduling; at 1 s it has a second.
FLUSH_S = 1.0
# The kill comes this long after the first flush was seen: a recorder that then went more
# than PROMISE_S without flushing would lose records it promised to keep.
KILL_AFTER_FLUSH_S = 2.5
TIMEOUT_S = 30.0  # give up (a broken build, not a slow machine)


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "hermsd.cli", *args]


def _daemon_seconds(log_time_ns: int) -> float:
    """The daemon's monotonic time of a log stamp (the simulated clock stamps epoch + t)."""
    return (log_time_ns - DEFAULT_EPOCH_NS) / 1e9


def _first_data(proc: subprocess.Popen[str], directory: Path) -> tuple[Path, float]:
    """The `.part` being written, and when its first flushed chunk was seen (monotonic)."""
    deadline = time.monotonic() + TIMEOUT_S
    while time.monotonic() < deadline:
        assert proc.poll() is None, "the daemon died"
        parts = list(directory.glob(f"*.mcap{PART_SUFFIX}"))
        if parts and parts[0].stat().st_size > 0:  # nothing reaches the OS before a flush
            return parts[0], time.monotonic()
        time.sleep(0.02)
    raise AssertionError(f"no log data after {TIMEOUT_S} s")


def _run_until(proc: subprocess.Popen[str], until: float) -> None:
    while (now := time.monotonic()) < until:
        assert proc.poll() is None, "the daemon died before the kill"
        time.sleep(min(0.05, until - now))


def test_sigkill_loses_at_most_the_last_flush_and_a_restart_recovers_the_log(
    tmp_path: Path,
) -> None:
    config = tmp_path / "hermsd.yaml"
    config.write_text(f"log:\n  flush_interval: {FLUSH_S}\n")
    logs = tmp_path / "logs"
    run = ("run", "--simulate", "--speed", str(SPEED), "--config", str(config), "--log", str(logs))
    proc = subprocess.Popen(
        _cli(*run), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=tmp_path
    )
    try:
        assert proc.stderr is not None
        line = proc.stderr.readline()  # printed just before the "started" event is recorded
        started_seen = time.monotonic()
        assert "started" in line, line
        part, first_flush_seen = _first_data(proc, logs)
        _run_until(proc, first_flush_seen + KILL_AFTER_FLUSH_S)
    finally:
        killed_at = time.monotonic()
        proc.kill()
        proc.communicate(timeout=TIMEOUT_S)
    assert not list(logs.glob("*.mcap")), "SIGKILL left no chance to finish a file"

    restart = subprocess.run(
        _cli(*run, "--duration", "5s"),
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
        cwd=tmp_path,
    )
    assert restart.returncode == 0, restart.stderr
    recovered = part.with_name(part.name.removesuffix(PART_SUFFIX))
    assert f"recovered {recovered}" in restart.stderr
    assert not part.exists()

    # The recovered file through mcap's own indexed reader, every chunk's CRC checked.
    with recovered.open("rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        messages = [
            (channel.topic, message.log_time, message.data)
            for _, channel, message in reader.iter_messages(log_time_order=True)
        ]
        recovery = {m.name: m.metadata for m in reader.iter_metadata()}[RECOVERY_METADATA_NAME]
    assert summary.statistics.message_count == len(messages) == int(recovery["messages"])

    periods = [(t, json.loads(data)) for topic, t, data in messages if topic == PERIOD_TOPIC]
    ks = [period["k"] for _, period in periods]
    assert ks == list(range(1, len(ks) + 1)), "periods missing in the middle"

    # The daemon's clock at the kill: it stamped "started" when it printed it, so its clock
    # read t_started at `started_seen` or a little before; the kill is later by the real time
    # between, times SPEED (a late readline only makes the kill look earlier: more lenient).
    [started_ns] = [
        t
        for topic, t, data in messages
        if topic == LOG_TOPIC and json.loads(data)["message"] == "started"
    ]
    kill_t = _daemon_seconds(started_ns) + (killed_at - started_seen) * SPEED
    # Period N + 1 is due N periods after period 1. It had to be in the log if it was due
    # PROMISE_S before the kill; so the periods kept must reach to that point.
    assert periods, "no period survived"
    first_t = _daemon_seconds(periods[0][0])
    must_have = math.floor((kill_t - PROMISE_S * SPEED - first_t) / PERIOD_S) + 1
    assert len(ks) >= must_have, f"{len(ks)} periods kept, {must_have} were due by kill − 2 s"
    # The busiest topic, one reading a simulated second, reaches as far.
    last_reading_t = _daemon_seconds(max(t for topic, t, _ in messages if topic == READING_TOPIC))
    assert last_reading_t >= kill_t - PROMISE_S * SPEED - 1.0
