"""The supervisor with the HERMS pump running (docs/herms.md, "The coil and the safety"): a
faulty mash sensor does not blind it, and its faults are caught through the daemon on the
plant of scenarios/herms-day.yaml (a 90 L 3 kW HLT, 50 L and 12 kg doughed in at 38 °C at
1 h, the pump hermsd switches started at 1 h 5 min), with the shipped safety settings."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

from hermsd.config.read import parse
from hermsd.runtime.assemble import assemble
from hermsd.runtime.daemon import Daemon
from hermsd.runtime.period import PeriodRecord
from hermsd.safety.coil_load import MashSpan, MashWatch, coil_load, fastest_mash_cooling
from hermsd.safety.limits import Alarm
from hermsd.sim.clock import VirtualClock
from hermsd.sim.mash import make_herms_plant
from hermsd.sim.world import World, build_world

ROOT = Path(__file__).resolve().parents[1]
PLANT = yaml.safe_load((ROOT / "scenarios" / "herms-day.yaml").read_text())["plant"]
CONFIG = (
    "output:\n  backend: sim\nlog:\n  dir: null\ncontrol:\n  setpoint: 66\n"
    "mash_sensor:\n  kind: lm92\n  address: 0x49\npump:\n  backend: sim\n"
    "contactor:\n  backend: gpio\n  line: 27\n"
    "herms:\n  mash_litres: 50\n  grain_kg: 12\n  mash_loss_w_per_k: 5\n"
)
DOUGH_IN, PUMP_AT, FAULT_AT = 3600.0, 3900.0, 8400.0


class Alarms:
    """The alarms the daemon raised (its listener)."""

    def __init__(self) -> None:
        self.raised: list[Alarm] = []

    def period(self, record: PeriodRecord) -> None:
        """Not looked at here."""

    def alarm(self, alarm: Alarm) -> None:
        if alarm.raised:
            self.raised.append(alarm)

    def write(self, topic: str, log_time_ns: int, message: dict[str, Any]) -> None:
        """Not looked at here."""


def herms_day() -> tuple[Daemon, World, Alarms]:
    """The daemon on herms-day's plant: doughed in at 1 h, the pump started at 1 h 5 min."""
    config = parse(CONFIG)
    clock = VirtualClock()
    hlt = {k: v for k, v in PLANT.items() if k not in ("model", "mash")}
    tun: Any = make_herms_plant(PLANT["model"], PLANT["mash"], **hlt)
    world = build_world(config, clock, tun=tun)
    assert world.mash is not None
    daemon = assemble(
        config, clock, world.sensor, world.outputs, mash_sensor=world.mash.mash_sensor
    )
    alarms = Alarms()
    daemon.listeners.append(alarms)
    daemon.start()
    clock.call_at(DOUGH_IN, lambda: tun.dough_in(12.0, 20.0, 50.0, 39.75, DOUGH_IN))
    clock.call_at(PUMP_AT, lambda: daemon.set_pump(True, "by the test"))
    return daemon, world, alarms


def test_a_faulty_mash_sensor_leaves_a_shorted_ssr_caught_with_the_pump_running() -> None:
    """The mash sensor fails in the rest (2 h 10 min), the SSR shorts at 2 h 20 min, the pump
    running: the mash is no warmer than its last reading (+1 °C) or the hottest the HLT has
    been since, so the coil can give nothing back to an HLT climbing above both, and the rise
    is judged as with the sensor good (which catches it in 795 s). The old bound took the
    mash anywhere up to 100 °C and explained any rise by heat back: never caught."""
    daemon, world, alarms = herms_day()
    assert world.mash is not None and world.mash.mash_chip is not None
    chip = world.mash.mash_chip
    world.clock.call_at(FAULT_AT - 600.0, lambda: chip.set_fault("nack"))
    world.clock.call_at(FAULT_AT, lambda: world.circuit.set_stuck_on(True))
    daemon.run(until=FAULT_AT + 1200.0)
    assert daemon.mash_side_fields()["mash"] is None  # the sensor still faulty
    assert [a.kind for a in alarms.raised] == ["ssr_stuck_on"]
    assert FAULT_AT < alarms.raised[0].at <= FAULT_AT + 1000.0


def test_a_faulty_mash_sensor_is_bounded_from_its_last_good_reading() -> None:
    """The HLT at 70 °C, the mash last read at 66 °C 100 s ago, the HLT at 72 °C since:
    no warmer than 72 °C, no colder than 66 − 1 − 100 s at the fastest a 25 L mash (half
    of 50 L) cools from 66 °C in an open pot: (1.769·25^⅔ W/K·61 K + 1000·(25/90)^⅔ W)
    / (25·4186 J/K) = (922.7 + 425.7) / 104650 = 0.01288 °C/s, so 63.71 °C."""
    watch = MashWatch()
    watch.span(0.0, 68.0, 66.0, 50.0)
    watch.span(50.0, 72.0, None, 50.0)
    span = watch.span(100.0, 70.0, None, 50.0)
    assert span.warmest == 72.0
    assert span.coldest == pytest.approx(66.0 - 1.0 - 100.0 * 0.01288, abs=0.005)
    assert fastest_mash_cooling(66.0, 50.0) == pytest.approx(0.01288, rel=0.002)
    # 12 L/min (837.2 W/K): gives back 837.2 × (72 − 70) = 1674.4 W at most, takes
    # 837.2 × (70 − 63.71) at most.
    load = coil_load(70.0, span, True, 12.0)
    assert load.most_given == pytest.approx(1674.4, rel=1e-3)
    assert load.most_taken == pytest.approx(837.2 * (70.0 - span.coldest), rel=1e-3)
    assert MashWatch().span(0.0, 70.0, None, 50.0) == MashSpan(0.0, 100.0)  # never read
