"""The loop thread's real-time priority: its thread only, given back, and a fallback said."""

from __future__ import annotations

import errno
import logging
import os
import threading

import pytest

from hermsd.hardware.realtime import loop_priority

RESET_ON_FORK = os.SCHED_RESET_ON_FORK  # sched_getscheduler reports it with the policy


def _skip_unless_permitted() -> None:
    """Try in a thread of its own, so that the test's thread is left as it was."""
    permitted: list[bool] = []

    def probe() -> None:
        with loop_priority(1) as took:
            permitted.append(took)

    thread = threading.Thread(target=probe)
    thread.start()
    thread.join(5)
    if permitted != [True]:
        pytest.skip("real-time scheduling is not permitted here")


def test_only_the_calling_thread_becomes_real_time_and_gets_its_policy_back() -> None:
    _skip_unless_permitted()
    seen: dict[str, object] = {}
    raised, looked = threading.Event(), threading.Event()

    def recorder_like() -> None:  # started before the raise, as the recorder is
        raised.wait(5)
        seen["other"] = os.sched_getscheduler(0)
        looked.set()

    def started_by_the_loop() -> None:  # a reader or helper the loop starts later
        seen["later"] = os.sched_getscheduler(0)

    def loop() -> None:
        with loop_priority(1) as took:
            seen["took"], seen["inside"] = took, os.sched_getscheduler(0) & ~RESET_ON_FORK
            raised.set()
            looked.wait(5)
            later = threading.Thread(target=started_by_the_loop)
            later.start()
            later.join(5)
        seen["after"] = os.sched_getscheduler(0) & ~RESET_ON_FORK

    threads = [threading.Thread(target=recorder_like), threading.Thread(target=loop)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(10)

    assert seen == {
        "took": True,
        "inside": os.SCHED_FIFO,
        "other": os.SCHED_OTHER,
        "later": os.SCHED_OTHER,
        "after": os.SCHED_OTHER,
    }
    assert os.sched_getscheduler(0) == os.SCHED_OTHER


def test_not_permitted_says_so_in_one_line_and_changes_nothing(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    def refuse(pid: int, policy: int, param: os.sched_param) -> None:
        raise PermissionError(errno.EPERM, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    before = os.sched_getscheduler(0)

    with caplog.at_level(logging.INFO, logger="hermsd"), loop_priority() as raised:
        inside = os.sched_getscheduler(0)

    assert not raised
    assert inside == before
    assert [r.levelno for r in caplog.records] == [logging.WARNING]
    assert "not permitted" in caplog.text and "LimitRTPRIO=10" in caplog.text


def test_the_config_reader_the_loop_starts_runs_at_ordinary_priority() -> None:
    from hermsd.config.file import in_thread

    _skip_unless_permitted()
    policies: dict[str, int] = {}

    def loop() -> None:
        with loop_priority(1):
            policies["loop"] = os.sched_getscheduler(0) & ~RESET_ON_FORK
            policies["reader"] = in_thread(lambda: os.sched_getscheduler(0)).result(5)

    thread = threading.Thread(target=loop)
    thread.start()
    thread.join(10)

    assert policies == {"loop": os.SCHED_FIFO, "reader": os.SCHED_OTHER}
