"""Log lines and the status line never hold up the thread that logs: a stalled stderr is
waited for by the writer thread alone, a full queue drops and counts, and a stop writes what
is queued; a stalled stdout is waited for by the status line's thread alone."""

from __future__ import annotations

import json
import logging
import math
import threading
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

from hermsd.cli import commands as cli
from hermsd.cli import common
from hermsd.cli import run as cli_run
from hermsd.commissioning import relay, step_response
from hermsd.runtime.daemon import Daemon
from hermsd.runtime.log_queue import LOG_QUEUE_SIZE, DroppingQueueHandler

GUARD_S = 10.0  # only a guard against a hung test: nothing here waits for it to pass


class StalledStream:
    """A stderr whose every write waits until the test lets it through (a paused terminal,
    a busy journal)."""

    def __init__(self, tty: bool = False) -> None:
        self.tty = tty
        self.written: list[str] = []
        self._change = threading.Condition()
        self._allowed: float = 0  # writes let through and not yet made
        self._waiting = False

    def write(self, text: str) -> int:
        with self._change:
            self._waiting = True
            self._change.notify_all()
            if not self._change.wait_for(lambda: self._allowed > 0, GUARD_S):
                raise TimeoutError("the test never let this write through")
            self._waiting = False
            self._allowed -= 1
            self.written.append(text)
            self._change.notify_all()
        return len(text)

    def flush(self) -> None:
        pass

    def isatty(self) -> bool:
        return self.tty

    def let_through(self, count: float = math.inf) -> None:
        with self._change:
            self._allowed += count
            self._change.notify_all()

    def wait_for_written(self, count: int) -> None:
        with self._change:
            written = self._change.wait_for(lambda: len(self.written) >= count, GUARD_S)
        assert written, f"{len(self.written)} lines written, not {count}"

    def wait_until_stalled(self) -> None:
        """Until a write waits with none let through: the writer thread is stuck in it."""
        with self._change:
            stuck = self._change.wait_for(lambda: self._waiting and self._allowed == 0, GUARD_S)
        assert stuck, "the writer thread never reached the stream"


def stalled_logger(size: int) -> tuple[logging.Logger, DroppingQueueHandler, StalledStream]:
    """A logger of its own (no parent, no other handler), whose first record is already
    taken by the writer thread and stuck in the stream's write."""
    stream = StalledStream()
    target = logging.StreamHandler(stream)
    target.setFormatter(logging.Formatter("%(levelname)s %(message)s"))
    queued = DroppingQueueHandler(target, size)
    logger = logging.Logger("stalled")
    logger.addHandler(queued)
    queued.start()
    logger.warning("first")
    stream.wait_until_stalled()
    return logger, queued, stream


def log_from_another_thread(logger: logging.Logger, messages: list[str]) -> None:
    """Log `messages` on a thread of their own; asserts the calls all returned."""
    returned = threading.Event()

    def log_all() -> None:
        for message in messages:
            logger.info(message)
        returned.set()

    thread = threading.Thread(target=log_all)
    thread.start()
    assert returned.wait(GUARD_S), "a log call waited for the stream"
    thread.join(GUARD_S)


def test_a_log_call_returns_while_stderr_is_blocked_and_every_line_follows_in_order() -> None:
    logger, queued, stream = stalled_logger(size=8)
    log_from_another_thread(logger, ["one", "two", "three"])
    assert stream.written == []  # returned while the writer is still stuck in the first line
    stream.let_through()
    queued.stop()
    assert stream.written == ["WARNING first\n", "INFO one\n", "INFO two\n", "INFO three\n"]


def test_a_full_queue_drops_without_waiting_and_says_how_many_once_stderr_writes() -> None:
    logger, queued, stream = stalled_logger(LOG_QUEUE_SIZE)  # the daemon's queue
    logged = LOG_QUEUE_SIZE + 25
    log_from_another_thread(logger, [f"line {n}" for n in range(1, logged + 1)])
    assert stream.written == []
    stream.let_through()
    # "first" is in the writer's hands, not the queue: the queue keeps the first
    # LOG_QUEUE_SIZE lines logged after it and drops the other 25, said as soon as stderr
    # writes again.
    said = [
        "WARNING first\n",
        *(f"INFO line {n}\n" for n in range(1, LOG_QUEUE_SIZE + 1)),
        f"WARNING {logged - LOG_QUEUE_SIZE} log lines dropped while stderr was blocked\n",
    ]
    stream.wait_for_written(len(said))
    assert stream.written == said
    queued.stop()
    assert stream.written == said


@pytest.mark.parametrize(
    ("written_before", "later", "after_the_count"),
    [
        # "first" and "line 1" written, stuck in "line 2"'s write: 2 places free, for the
        # count and then the line.
        (2, ["later"], ["INFO later\n"]),
        # "first" written, stuck in "line 1"'s: 1 place free, which the count takes; both
        # lines are dropped, and counted after it.
        (1, ["later", "even later"], ["WARNING 2 log lines dropped while stderr was blocked\n"]),
    ],
)
def test_the_drop_count_stands_where_the_lines_went_missing(
    written_before: int, later: list[str], after_the_count: list[str]
) -> None:
    logger, queued, stream = stalled_logger(size=4)
    log_from_another_thread(logger, [f"line {n}" for n in range(1, 11)])  # 10 - 4 = 6 dropped
    stream.let_through(written_before)
    stream.wait_until_stalled()
    log_from_another_thread(logger, later)
    stream.let_through()
    queued.stop()
    assert stream.written == [
        "WARNING first\n",
        *(f"INFO line {n}\n" for n in range(1, 5)),
        "WARNING 6 log lines dropped while stderr was blocked\n",
        *after_the_count,
    ]


def test_a_stop_writes_a_full_queue_out_before_it_returns() -> None:
    size = 4
    logger, queued, stream = stalled_logger(size)
    log_from_another_thread(logger, [f"line {n}" for n in range(1, size + 1)])  # full
    stopped = threading.Event()

    def stop() -> None:
        queued.stop()  # waits for a place for its end mark, then for the writer
        stopped.set()

    stopper = threading.Thread(target=stop)
    stopper.start()
    assert not stopped.is_set()
    stream.let_through()
    stopper.join(GUARD_S)
    assert stopped.is_set()
    assert stream.written == ["WARNING first\n", *(f"INFO line {n}\n" for n in range(1, 5))]


def test_the_daemon_runs_to_a_sigterm_with_stderr_blocked_and_main_writes_every_line_out(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    stream = StalledStream()
    monkeypatch.setattr("sys.stderr", stream)
    monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
    monkeypatch.delenv("JOURNAL_STREAM", raising=False)
    loop_ended, stopping = threading.Event(), threading.Event()
    run, stop = Daemon.run, DroppingQueueHandler.stop

    def run_to_a_sigterm(daemon: Daemon, until: float) -> None:
        run(daemon, until=until)
        loop_ended.set()
        raise common.Shutdown("SIGTERM")  # as the signal handler raises it in the loop

    def say_stopping(handler: DroppingQueueHandler) -> None:
        stopping.set()
        stop(handler)

    monkeypatch.setattr(Daemon, "run", run_to_a_sigterm)
    monkeypatch.setattr(DroppingQueueHandler, "stop", say_stopping)
    before_release: dict[str, object] = {}

    def let_through_when_main_stops() -> None:
        before_release["loop ended"] = loop_ended.wait(GUARD_S)
        before_release["stopping"] = stopping.wait(GUARD_S)
        before_release["written"] = list(stream.written)
        stream.let_through()

    releaser = threading.Thread(target=let_through_when_main_stops)
    releaser.start()
    argv = ["run", "--simulate", "--speed", "max", "--duration", "1h"]
    assert cli.main([*argv, "--state", str(tmp_path)]) == 0
    releaser.join(GUARD_S)
    # An hour on the simulated tun and the stop went by with stderr stuck in the first
    # line's write; `main` returned only when every line was out, the last ones included.
    assert before_release == {"loop ended": True, "stopping": True, "written": []}
    assert stream.written[0] == "INFO started\n"
    assert stream.written[-2:] == [
        "INFO heater off: stopped (SIGTERM)\n",
        "INFO SIGTERM received\n",
    ]


def test_a_status_update_returns_while_stdout_is_blocked_and_the_newest_is_shown() -> None:
    stdout = StalledStream(tty=True)
    status = cli_run.StatusLine(stdout)  # type: ignore[arg-type]  # a TextIO in what it is used for
    status.update("HLT 20.00 °C")
    stdout.wait_until_stalled()  # its thread is stuck drawing the first one
    returned = threading.Event()

    def update_every_period() -> None:
        for celsius in (20.5, 21.0, 21.5):
            status.update(f"HLT {celsius:.2f} °C")
        returned.set()

    loop = threading.Thread(target=update_every_period)
    loop.start()
    assert returned.wait(GUARD_S), "an update waited for stdout"
    loop.join(GUARD_S)
    assert stdout.written == []
    stdout.let_through()
    status.close()
    # The ones overtaken while stdout was stuck are never drawn; the line is cleared at the end.
    assert stdout.written == ["\r\033[KHLT 20.00 °C", "\r\033[KHLT 21.50 °C", "\r\033[K"]


@pytest.mark.parametrize(
    ("command", "module", "start"), [("step", step_response, "run"), ("relay", relay, "start")]
)
def test_a_tune_experiment_runs_to_its_end_with_stderr_blocked_and_its_progress_follows(
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    command: str,
    module: ModuleType,
    start: str,
) -> None:
    stream = StalledStream()
    monkeypatch.setattr("sys.stderr", stream)
    monkeypatch.delenv("JOURNAL_STREAM", raising=False)
    ended = threading.Event()
    experiment = getattr(module, start)

    def run_to_its_end(*args: Any) -> None:
        experiment(*args)
        ended.set()

    monkeypatch.setattr(module, start, run_to_its_end)
    before_release: dict[str, object] = {}

    def let_through_when_it_ended() -> None:
        before_release["ended"] = ended.wait(GUARD_S)
        before_release["written"] = list(stream.written)
        stream.let_through()

    releaser = threading.Thread(target=let_through_when_it_ended)
    releaser.start()
    assert cli.main(["tune", command, "--simulate", "--json"]) == 0
    releaser.join(GUARD_S)
    # The whole experiment ran with stderr stuck in the first line's write: the progress
    # lines waited in the log's queue, then came out in order with the daemon's own lines.
    assert before_release == {"ended": True, "written": []}
    progress = [line for line in stream.written if line.startswith(f"INFO {command} +")]
    assert len(progress) >= 2
    assert json.loads(capsys.readouterr().out)["stopped"]
