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
from hermsd.safety.limits import Alarm, SafetyLimits
from hermsd.safety.supervisor import Supervisor
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


def _supervised(mash_rate: float) -> list[str]:
    """A supervisor (90 L, 3 kW) fed an HLT falling 0.003 °C/s from 70 °C at full power for
    20 min, the pump running from the start and the mash (50 L + 12 kg) at 50 °C warming at
    `mash_rate` °C/s: the alarms raised."""
    limits = SafetyLimits.derive(litres=90.0, element_watts=3000.0, period=5.0, read_interval=1)
    supervisor, watch = Supervisor(limits), MashWatch()
    t = 0.0
    while t <= 1200.0:
        pv = 70.0 - 0.003 * t
        supervisor.reading(t, pv, raw=round(pv / 0.0625))
        load = watch.load(
            t,
            pv,
            50.0 + mash_rate * t,
            True,
            max_flow=6.0,
            litres=50.0,
            grain_kg=12.0,
            lags=(20.0, 10.0),
        )
        supervisor.period(t, pv, 100.0, 100.0, load)
        t += 5.0
    return [alarm.kind for alarm in supervisor.drain_events() if alarm.raised]


def test_the_mash_warming_explains_a_fall_and_a_mash_not_warming_does_not() -> None:
    """With a working element at 80 % or more making up both vessels' losses, the HLT falls
    by no more than the heat the mash gains: C_m·dT_m/dt, at most 2 × (50 × 4186 + 12 × 1700)
    = 459.4 kJ/K times the mash's slope, into the least water, 45 L (188.37 kJ/K). A mash
    warming 0.005 °C/s: 2297 W, 0.0122 °C/s, more than the HLT's 0.003 °C/s fall: no verdict.
    A mash cooling explains none of it: 0.45 °C in each half-watch, a dead element (the
    flow's bound, 418.6 W/K × (70 − 50 + 1 °C) = 8.8 kW, explained it all)."""
    assert _supervised(0.005) == []
    assert _supervised(-0.001) == ["heater_not_heating"]


def test_a_frozen_mash_reading_is_no_mash_standing_still() -> None:
    """A mash reading that does not change at all over the slope's window (a frozen register)
    could hide any warming: the flow's bound stands, which explains the fall."""
    assert _supervised(0.0) == []
