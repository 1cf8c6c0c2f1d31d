"""The loop while the heater is rightly held off: it stays alive for systemd, keeps its latches
on disk, and holds every element off, the slow second one included."""

from __future__ import annotations

import dataclasses
import datetime as dt
import errno
import itertools
from pathlib import Path

from hermsd.config import rules
from hermsd.config import schema as config_module
from hermsd.config.schema import Config
from hermsd.program.model import Program, Step
from hermsd.runtime.assemble import assemble
from hermsd.runtime.daemon import Daemon
from hermsd.runtime.notify import Notifier
from hermsd.runtime.saver import Saver
from hermsd.safety.latches import LatchedAlarm, Latches, LatchStore
from hermsd.sim.clock import VirtualClock
from hermsd.sim.world import World, build_world

WATCHDOG_USEC = 15_000_000  # WatchdogSec=15s, as the shipped unit: a ping every 7.5 s


class PingCounter(Notifier):
    """The systemd side of sd_notify: when each WATCHDOG=1 came."""

    def __init__(self, clock: VirtualClock) -> None:
        super().__init__(None, WATCHDOG_USEC)
        self.clock = clock
        self.pings: list[float] = []

    def watchdog(self) -> None:
        self.pings.append(self.clock.monotonic())


def longest_silence(pings: list[float], start: float, end: float) -> float:
    """The longest gap systemd sees between `start` and `end`, in seconds."""
    marks = [start, *[p for p in pings if start < p < end], end]
    return max(b - a for a, b in itertools.pairwise(marks))


def watched_daemon(
    config: Config, latches: LatchStore | None = None
) -> tuple[Daemon, World, PingCounter]:
    clock = VirtualClock()
    world = build_world(config, clock)
    notifier = PingCounter(clock)
    daemon = assemble(
        config,
        clock,
        world.sensor,
        world.outputs,
        notifier=notifier,
        latches=latches,
        saver=Saver(threaded=False),  # a virtual clock: each save lands at once
    )
    daemon.start()
    return daemon, world, notifier


def test_a_latched_alarm_keeps_the_watchdog_fed(tmp_path: Path) -> None:
    store = LatchStore(str(tmp_path))
    store.save(Latches((LatchedAlarm("ssr_stuck_on", 1, "PV rose 3 °C", {}),), 0))
    daemon, _, notifier = watched_daemon(config_module.DEFAULT, store)
    daemon.run(until=300.0)
    assert not daemon.supervisor.heater_allowed
    # 15 s without a ping and systemd kills it: every restart re-alerts and starts a new log.
    assert longest_silence(notifier.pings, 0.0, 300.0) < 15.0


def test_a_program_waiting_for_its_time_keeps_the_watchdog_fed() -> None:
    daemon, world, notifier = watched_daemon(config_module.DEFAULT)
    daemon.run(until=60.0)
    due = dt.datetime.fromtimestamp(world.clock.wall_ns() / 1e9 + 10 * 3600, dt.UTC)
    program = Program("Night", (Step("Strike", 72.0, 600.0),))
    daemon.start_program(program, due.astimezone().strftime("%H:%M"), world.clock.monotonic())
    daemon.run(until=360.0)
    assert "scheduled" in daemon.status_text()
    assert longest_silence(notifier.pings, 60.0, 360.0) < 15.0


def test_a_loop_without_readings_stops_earning_pings() -> None:
    daemon, world, notifier = watched_daemon(config_module.DEFAULT)
    daemon.run(until=60.0)
    world.chip.set_fault("gone")
    daemon.run(until=120.0)
    assert longest_silence(notifier.pings, 60.0, 120.0) > 15.0


class FullDisk(LatchStore):
    """A state directory that refuses writes until told it has room again."""

    full = True

    def save(self, latches: Latches) -> None:
        if self.full:
            raise OSError(errno.ENOSPC, "No space left on device")
        super().save(latches)


def test_a_latch_whose_save_failed_is_saved_once_the_disk_has_room(tmp_path: Path) -> None:
    store = FullDisk(str(tmp_path))
    config = dataclasses.replace(
        config_module.DEFAULT,
        control=dataclasses.replace(config_module.DEFAULT.control, setpoint=30.0),
    )
    daemon, world, _ = watched_daemon(config, store)
    daemon.run(until=600.0)
    world.circuit.set_stuck_on(True)  # the SSR fails shorted, no contactor fitted
    while "ssr_stuck_on" not in daemon.supervisor.latched:
        daemon.run(until=world.clock.monotonic() + 60.0)
    assert LatchStore(str(tmp_path)).load().alarms == ()
    store.full = False  # a log rotated: room again
    daemon.run(until=world.clock.monotonic() + 35.0)  # one retry interval and a period
    saved = LatchStore(str(tmp_path)).load()
    assert [alarm.kind for alarm in saved.alarms] == ["ssr_stuck_on"]


def test_manual_zero_switches_the_second_element_off_within_a_period() -> None:
    base = config_module.DEFAULT
    config = dataclasses.replace(
        base,
        tun=dataclasses.replace(base.tun, element_watts=2000.0),
        element2=dataclasses.replace(base.element2, backend="sim", watts=3500.0, min_on=1800.0),
        control=dataclasses.replace(base.control, algorithm="midrange"),
    )
    assert not rules.broken_rules(config)
    clock = VirtualClock()
    plant = {"model": "physical", "litres": 90.0, "element_watts": 2000.0}
    world = build_world(config, clock, {**plant, "element2_watts": 3500.0})
    daemon = assemble(config, clock, world.sensor, world.outputs)
    daemon.start()
    daemon.run(until=60.0)
    assert world.circuit.relay2_on  # heating up from cold: both elements on
    assert "out 100 % + element 2 100 %" in daemon.status_text()  # 5.5 kW, not 2 kW
    daemon.set_manual(0.0)
    daemon.run(until=60.0 + 2 * config.control.period)
    assert not world.circuit.relay2_on  # not after its 1800 s minimum on time
    assert "out 0 % + element 2 0 %" in daemon.status_text()
