"""A log that cannot be written: control goes on, and the failure is said everywhere it shows.

A full disk, a read-only directory, a directory that cannot be made, a file size limit: the
recorder counts and describes the failure, retries ever less often without leaving empty
files, and the daemon says it at start, in its status line (and so in sd_notify STATUS), in
the journal at warning priority, again every minute while it lasts, and once when it is over.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import resource
import socket
import subprocess
import sys
import threading
from pathlib import Path
from typing import BinaryIO

import pytest
from test_recorder import FakeDisk
from test_reload import Events, FakeNotifier

from hermsd.cli import commands as cli
from hermsd.config import schema as config_module
from hermsd.log.mcap_file import LogFile
from hermsd.log.recorder import RETRY_INTERVAL_S, RETRY_MAX_S, Recorder
from hermsd.log.topics import PERIOD_TOPIC
from hermsd.runtime.assemble import assemble
from hermsd.runtime.daemon import Daemon
from hermsd.runtime.reporting import LOG_FAILING_REPEAT_S
from hermsd.sim.clock import DEFAULT_EPOCH_NS, VirtualClock
from hermsd.sim.world import build_world

S = 1_000_000_000
ENOSPC = os.strerror(errno.ENOSPC)
EROFS = os.strerror(errno.EROFS)


class Disk(FakeDisk):
    """A FakeDisk failing with `error` from the start, that notes when each file is opened
    and, as a read-only directory does, can refuse the file itself."""

    def __init__(self, clock: VirtualClock, error: int, *, fail_open: bool = False) -> None:
        super().__init__(error)
        self.full = True
        self.clock = clock
        self.fail_open = fail_open
        self.opened_at: list[float] = []

    def open(self, path: Path) -> BinaryIO:
        self.opened_at.append(self.clock.monotonic())
        if self.fail_open and self.full:
            raise OSError(self.error, os.strerror(self.error))
        return super().open(path)


def period(k: int) -> dict[str, object]:
    return {"t": 5.0 * k, "k": k}


def test_a_full_disk_is_retried_ever_less_often_and_leaves_no_empty_file(tmp_path: Path) -> None:
    clock = VirtualClock()
    disk = Disk(clock, errno.ENOSPC)
    recorder = Recorder(tmp_path, now=clock.monotonic, flush_interval=0.0, open_file=disk.open)
    assert recorder.failing is None  # the directory itself is fine
    for second in range(700):
        clock.sleep_until(float(second))
        recorder.write(PERIOD_TOPIC, DEFAULT_EPOCH_NS + second * S, period(second))
        assert not recorder.sync(timeout=5)
    # After a failure at t the next file is tried at t + 5, 10, 20, … s, at most every 300 s.
    delays = [min(RETRY_INTERVAL_S * 2**n, RETRY_MAX_S) for n in range(7)]
    expected = [0.0]
    for delay in delays:
        expected.append(expected[-1] + delay)
    assert expected == [0, 5, 15, 35, 75, 155, 315, 615]
    assert disk.opened_at == expected
    assert recorder.failing is not None and ENOSPC in recorder.failing
    assert list(tmp_path.iterdir()) == [], "a file that never held a record is removed"

    disk.full = False  # room again: the next retry (at 915 s) writes, and the failure is over
    clock.sleep_until(915.0)
    recorder.write(PERIOD_TOPIC, DEFAULT_EPOCH_NS + 915 * S, period(915))
    assert recorder.sync(timeout=5)
    assert recorder.failing is None
    recorder.close()
    [kept] = list(tmp_path.iterdir())
    assert [m.message for m in LogFile(kept).messages()] == [period(915)]


def test_a_file_with_records_on_disk_stays_for_recovery(tmp_path: Path) -> None:
    clock = VirtualClock()
    disk = Disk(clock, errno.ENOSPC)
    disk.full = False
    recorder = Recorder(tmp_path, now=clock.monotonic, flush_interval=0.0, open_file=disk.open)
    recorder.write(PERIOD_TOPIC, DEFAULT_EPOCH_NS, period(0))
    assert recorder.sync(timeout=5)
    disk.full = True
    recorder.write(PERIOD_TOPIC, DEFAULT_EPOCH_NS + S, period(1))
    assert not recorder.sync(timeout=5)
    recorder.close()
    [part] = list(tmp_path.iterdir())
    assert [m.message for m in LogFile(part).messages()] == [period(0)]


def test_a_directory_that_is_not_there_is_failing_from_the_start(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("")
    recorder = Recorder(tmp_path / "file" / "logs")
    assert recorder.failing is not None
    assert str(tmp_path / "file" / "logs") in recorder.failing
    recorder.close()


def started_daemon(recorder: Recorder, clock: VirtualClock) -> tuple[Daemon, Events, list[str]]:
    config = config_module.DEFAULT
    world = build_world(config, clock)
    events = Events()
    notified: list[str] = []
    daemon = assemble(
        config,
        clock,
        world.sensor,
        world.outputs,
        recorder=recorder,
        notifier=FakeNotifier(notified),  # type: ignore[arg-type]
    )
    daemon.listeners.append(events)
    daemon.start()
    return daemon, events, notified


def failing_lines(caplog: pytest.LogCaptureFixture) -> list[logging.LogRecord]:
    return [r for r in caplog.records if r.getMessage().startswith("log failing")]


def test_a_read_only_log_is_said_at_start_every_minute_and_when_it_is_over(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="hermsd")
    clock = VirtualClock()
    disk = Disk(clock, errno.EROFS, fail_open=True)
    recorder = Recorder(tmp_path, now=clock.monotonic, flush_interval=0.0, open_file=disk.open)
    recorder.write(PERIOD_TOPIC, DEFAULT_EPOCH_NS, period(0))  # the failure is known at start
    assert not recorder.sync(timeout=5)
    daemon, events, notified = started_daemon(recorder, clock)
    with daemon:
        lines = failing_lines(caplog)
        assert len(lines) == 1, "said at start"
        daemon.run(until=299.0)
        # Said again once a minute, not every period: at 0, 60, 120, 180 and 240 s.
        assert len(failing_lines(caplog)) == 1 + int(299.0 // LOG_FAILING_REPEAT_S)
        assert all(r.levelno == logging.WARNING for r in failing_lines(caplog))
        assert all(EROFS in r.getMessage() for r in failing_lines(caplog))
        assert f"log failing: creating {tmp_path}" in daemon.status_text()
        statuses = [n for n in notified if n.startswith("STATUS=")]
        assert statuses and all("log failing" in s and EROFS in s for s in statuses)
        assert len(events.periods) == 60, "control went on: a period every 5 s"
        assert events.periods[-1].pv is not None

        disk.full = False  # the next retry (5, 10, 20, … s after each failure) can write
        until = 300.0
        while not recorder.sync(timeout=5):
            assert until < 1000.0, "the recorder never tried again"
            until += 10.0
            daemon.run(until=until)
        daemon.run(until=until + 10.0)
    recorder.close()
    over = [r for r in caplog.records if r.getMessage().startswith("log writing again")]
    assert len(over) == 1
    assert "log failing" not in daemon.status_text()
    assert "log failing" not in notified[-2]  # the last STATUS before STOPPING=1
    [file] = [p for p in tmp_path.iterdir() if p.suffix == ".mcap"]
    written = [m.message["message"] for m in LogFile(file).messages({"/hermsd/log"})]
    assert any(text.startswith("log writing again") for text in written)


def test_warnings_reach_the_journal_with_their_priority() -> None:
    formatter = cli.JournalFormatter("%(levelname)s %(message)s")

    def line(level: int) -> str:
        return formatter.format(logging.LogRecord("hermsd", level, "", 0, "x", None, None))

    assert line(logging.WARNING) == "<4>WARNING x"
    assert line(logging.ERROR) == "<3>ERROR x"
    assert line(logging.CRITICAL) == "<2>CRITICAL x"
    assert line(logging.INFO) == "<6>INFO x"
    assert line(logging.DEBUG) == "<7>DEBUG x"


def test_run_with_a_log_dir_that_cannot_be_made_says_so_everywhere(
    tmp_path: Path, capfd: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    blocker = tmp_path / "not-a-directory"
    blocker.write_text("")
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify.bind(str(tmp_path / "notify"))
    notify.settimeout(2.0)
    messages: list[str] = []

    def receive() -> None:  # at once: a datagram socket queues only ten
        with contextlib.suppress(TimeoutError):
            while not messages or messages[-1] != "STOPPING=1":
                messages.append(notify.recv(4096).decode())

    receiver = threading.Thread(target=receive)
    receiver.start()
    status = os.fstat(sys.stderr.fileno())
    monkeypatch.setenv("JOURNAL_STREAM", f"{status.st_dev}:{status.st_ino}")
    monkeypatch.setenv("NOTIFY_SOCKET", str(tmp_path / "notify"))
    monkeypatch.delenv("WATCHDOG_USEC", raising=False)
    monkeypatch.delenv("STATE_DIRECTORY", raising=False)
    # In real time (a second): the receiver keeps up, so no datagram is dropped.
    argv = ["run", "--simulate", "--speed", "30", "--duration", "30s"]
    assert cli.main([*argv, "--log", str(blocker / "logs")]) == 0
    err = capfd.readouterr().err
    not_a_directory = os.strerror(errno.ENOTDIR)
    assert f"<4>WARNING log failing: cannot create {blocker / 'logs'}: {not_a_directory}" in err
    # The daemon's own line, at start: the directory, or the first file in it, cannot be made.
    [started, daemon_line] = err.splitlines()[1:3]
    assert started == "<6>INFO started"
    assert daemon_line.startswith("<4>WARNING log failing: ")
    assert str(blocker / "logs") in daemon_line
    receiver.join()
    notify.close()
    statuses = [m for m in messages if m.startswith("STATUS=")]
    assert 6 <= len(statuses) <= 7  # a period every 5 s for 30 s (and at 30 s): control went on
    assert all("log failing" in s for s in statuses)


def test_a_file_size_limit_is_reported_not_fatal(tmp_path: Path) -> None:
    config = tmp_path / "hermsd.yaml"
    config.write_text("log:\n  flush_interval: 0.1\n")
    limit = 4096  # bytes: less than the first chunk (schemas and channels)

    def limit_files() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    argv = ["run", "--simulate", "--speed", "300", "--duration", "5m", "--config", str(config)]
    run = subprocess.run(
        [sys.executable, "-m", "hermsd.cli", *argv, "--log", str(tmp_path / "logs")],
        capture_output=True,
        text=True,
        timeout=60,
        preexec_fn=limit_files,
        env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"},
        cwd=tmp_path,
    )
    assert run.returncode == 0, run.stderr  # SIGXFSZ would have killed it (−25)
    assert "WARNING log failing" in run.stderr
    assert os.strerror(errno.EFBIG) in run.stderr
