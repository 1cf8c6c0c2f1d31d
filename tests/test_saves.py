"""The state files (latched alarms, the learned model) are saved beside the control loop: a
disk that stalls or fails holds up no period, and every save still lands, in order."""

from __future__ import annotations

import itertools
import threading
import time
from pathlib import Path

import pytest
from test_control import Inbox, status_of
from test_reload import BASE, PERIOD, Events, run_for, start

from hermsd.api.link import LoopLink
from hermsd.runtime import daemon as daemon_module
from hermsd.runtime import latch_keeping
from hermsd.runtime.daemon import Daemon
from hermsd.runtime.saver import Outcome, Saver
from hermsd.safety.latches import Latches, LatchStore
from hermsd.sim.world import World

KIND = "sensor_stuck"  # what a dead element in the still, noiseless tun latches first
STALL_S = 3.0  # the longest a stalled save here waits to be let go: then it fails


class StallingDisk(LatchStore):
    """The state directory on a disk whose saves hang until `release` (at most STALL_S,
    then they fail), or fail at once while `refusing`."""

    def __init__(self, directory: Path) -> None:
        super().__init__(directory)
        self.stalls = False
        self.refusing = False
        self.entered = threading.Event()
        self.release = threading.Event()
        self.finished = 0  # saves that returned or raised

    def save(self, latches: Latches) -> None:
        try:
            if self.refusing:
                raise OSError(5, "Input/output error")
            if self.stalls:
                self.entered.set()
                if not self.release.wait(STALL_S):
                    raise OSError(110, "stalled")
            super().save(latches)
        finally:
            self.finished += 1


def boot(state: Path, disk: LatchStore) -> tuple[Daemon, World, Events]:
    """The daemon with its saves on a thread, as the service runs it."""
    daemon, world, _path, events = start(state, BASE, latches=disk, watch=False, saver=Saver())
    return daemon, world, events


def latch(daemon: Daemon, world: World) -> float:
    """A dead element, until the watch latches an alarm; when it did (monotonic s)."""
    world.plant.set_element_ok(False, daemon.clock.monotonic())
    run_for(daemon, 1200.0)
    assert daemon.supervisor.latched == [KIND]
    return next(a.at for a in daemon_alarms(daemon) if a.kind == KIND)


def daemon_alarms(daemon: Daemon) -> list[daemon_module.Alarm]:
    events = next(listener for listener in daemon.listeners if isinstance(listener, Events))
    return [a for a in events.alarms if a.raised]


def test_the_loop_keeps_its_periods_while_a_latch_save_hangs(tmp_path: Path) -> None:
    disk = StallingDisk(tmp_path)
    disk.stalls = True
    daemon, world, events = boot(tmp_path, disk)
    raised_at = latch(daemon, world)
    run_for(daemon, 60.0)
    # The save is still hanging: it has neither landed nor failed …
    assert disk.entered.is_set() and disk.finished == 0
    # … and every period after the alarm came on time, the heater off in each.
    after = [r for r in events.periods if r.t > raised_at]
    assert len(after) >= 12
    assert all(b.t - a.t == 5.0 for a, b in itertools.pairwise(after))
    assert all(not r.heater_allowed and r.output == 0.0 for r in after)
    assert daemon.overruns == 0
    # A hang fails nothing, yet a restart now would lose the latch: said once it lasts.
    assert "latched alarms not saved: the save has not finished in" in daemon.status_text()
    disk.release.set()
    assert daemon.saver.flush(5.0)
    assert [a.kind for a in LatchStore(tmp_path).load().alarms] == [KIND]


def test_a_latch_raised_while_the_disk_fails_is_saved_once_it_works_and_survives_a_crash(
    tmp_path: Path,
) -> None:
    disk = StallingDisk(tmp_path)
    disk.refusing = True
    daemon, world, events = boot(tmp_path, disk)
    LoopLink(daemon).attach(Inbox())
    latch(daemon, world)
    assert daemon.saver.flush(5.0)
    run_for(daemon, PERIOD)  # the next reading takes the outcome, the next period shows it
    failing = "[Errno 5] Input/output error"
    assert f"latched alarms not saved: {failing}" in daemon.status_text()
    assert status_of(daemon)["latches_not_saved"] == failing  # `hermsd status`
    assert status_of(daemon)["warnings"] == [  # the web page's and MQTT's words
        f"latched alarms not saved (tried again until they are): {failing}"
    ]
    assert LatchStore(tmp_path).load().alarms == ()
    disk.refusing = False  # the disk works again: the next retry lands
    run_for(daemon, latch_keeping.LATCH_SAVE_RETRY_S + 2.0)
    assert daemon.saver.flush(5.0)
    run_for(daemon, PERIOD)
    assert "not saved" not in daemon.status_text()
    assert status_of(daemon)["latches_not_saved"] is None
    assert status_of(daemon)["warnings"] == []
    logged = events.logged()
    assert [m for m in logged if m.startswith("saving latched alarms failed")] == [
        "saving latched alarms failed: [Errno 5] Input/output error: sensor_stuck will NOT "
        "survive a restart (the heater stays off while latched; tried again every 30 s)"
    ]
    assert "latched alarms saved after a failed save" in logged
    # A crash: the daemon is gone without a word; the next start raises the alarm again.
    restarted, _world, _path, _events = start(tmp_path, BASE, latches=LatchStore(tmp_path))
    assert restarted.supervisor.latched == [KIND]
    assert not restarted.supervisor.heater_allowed


def test_shutdown_waits_a_bounded_time_for_a_hanging_save_and_says_what_was_not_saved(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(daemon_module, "STOP_WAIT_S", 0.2)
    disk = StallingDisk(tmp_path)
    disk.stalls = True
    daemon, world, events = boot(tmp_path, disk)
    latch(daemon, world)
    began = time.monotonic()
    assert daemon.shutdown("stopped")
    took = time.monotonic() - began
    assert took < STALL_S / 2  # it waited 0.2 s, not for the disk
    assert world.circuit.powered is False
    assert f"not saved at the stop: the latched alarms ({KIND}; on disk: none)" in events.logged()
    disk.release.set()  # the thread saves it after all, while the process lives
    assert daemon.saver.flush(5.0)
    assert [a.kind for a in LatchStore(tmp_path).load().alarms] == [KIND]


def test_saves_of_one_kind_land_in_order_and_only_the_newest_waiting_one_is_done() -> None:
    saver = Saver()
    landed: list[str] = []
    running, release = threading.Event(), threading.Event()

    def first() -> None:
        running.set()
        release.wait(5.0)
        landed.append("latches 1")

    saver.save("latches", first, 1)
    assert running.wait(5.0)
    saver.save("latches", lambda: landed.append("latches 2"), 2)
    saver.save("model", lambda: landed.append("model"), "m")
    saver.save("latches", lambda: landed.append("latches 3"), 3)
    assert saver.waiting() == ["latches", "model", "latches"]
    release.set()
    assert saver.flush(5.0)
    assert landed == ["latches 1", "model", "latches 3"]  # 2 was replaced before it began
    assert saver.take() == [
        Outcome("latches", 1, None),
        Outcome("model", "m", None),
        Outcome("latches", 3, None),
    ]
    assert saver.take() == []


def test_a_save_that_fails_is_said_and_the_next_one_still_runs() -> None:
    saver = Saver()

    def refused() -> None:
        raise OSError(28, "No space left on device")

    def broken() -> None:
        raise ValueError("not serialisable")

    saver.save("latches", refused, "a")
    saver.save("model", broken, "b")
    saver.save("other", lambda: None, "c")
    assert saver.close(5.0) == []
    assert saver.take() == [
        Outcome("latches", "a", "[Errno 28] No space left on device"),
        Outcome("model", "b", "ValueError: not serialisable"),
        Outcome("other", "c", None),
    ]


def test_the_stop_waits_for_the_latched_alarms_before_the_alerts_and_the_program(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A latch save that takes a while at the stop lands before the alerts' and the
    program's waits begin, so they cannot use up the stop's time before it."""
    disk = StallingDisk(tmp_path)
    disk.stalls = True
    daemon, world, events = boot(tmp_path, disk)
    latch(daemon, world)
    on_disk_then: list[list[str]] = []

    def closing(timeout: float) -> bool:
        on_disk_then.append([a.kind for a in LatchStore(tmp_path).load().alarms])
        return True

    monkeypatch.setattr(daemon.alerts, "close", closing)
    monkeypatch.setattr(type(daemon.program), "close", lambda _self, timeout: closing(timeout))
    threading.Timer(0.3, disk.release.set).start()  # the disk comes back during the stop
    assert daemon.shutdown("stopped")
    assert on_disk_then == [[KIND], [KIND]]
    assert not [m for m in events.logged() if m.startswith("not saved at the stop")]
