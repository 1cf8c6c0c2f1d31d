"""A large cold dump is no sensor fault; a spike, an erratic sensor and a stuck one still are.

Mixing is worked by T = (V·T₀ + v·Tᵥ)/(V + v); the sensor sees the step through its
first-order lag, so its reads fall by less each time, all the same way.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import pytest

from hermsd.config import schema as config_module
from hermsd.safety.limits import SafetyLimits
from hermsd.safety.supervisor import Supervisor
from hermsd.sim import scenario
from hermsd.sim.scenario import Event, Scenario


def limits() -> SafetyLimits:
    return SafetyLimits.derive(litres=90.0, element_watts=3000.0, period=5.0, read_interval=1.0)


def mixed(litres: float, celsius: float, added: float, added_celsius: float) -> float:
    return (litres * celsius + added * added_celsius) / (litres + added)


@pytest.mark.parametrize(
    ("litres", "added", "lag"), [(60.0, 60.0, 1.0), (60.0, 60.0, 5.0), (30.0, 11.0, 2.0)]
)
def test_a_large_cold_dump_through_a_fast_sensor_is_no_sensor_fault(
    litres: float, added: float, lag: float
) -> None:
    """60 L of 10 °C into 60 L at 66 °C: a 28 °C step, 17.7 °C of it within the first
    second through a 1 s lag; 11 L into 30 L: 15 °C. Each read falls more than 2 °C from the
    one before, for several reads, each fall smaller than the last."""
    assert 66.0 - mixed(60.0, 66.0, 60.0, 10.0) == pytest.approx(28.0)
    assert 66.0 - mixed(30.0, 66.0, 11.0, 10.0) == pytest.approx(15.02, abs=0.01)
    plant = {
        "model": "physical",
        "litres": litres,
        "element_watts": 3000,
        "sensor_lag_s": lag,
        "transport_delay_s": 10,
        "noise_c": 0.03,
        "start_c": 66.0,
    }
    dump = Event(600.0, "add_water", {"litres": added, "temp": 10.0})
    day = Scenario(name="dump", duration=900.0, plant=plant, setpoint=66.0, events=(dump,))
    base = config_module.DEFAULT
    config = dataclasses.replace(base, tun=dataclasses.replace(base.tun, litres=litres))
    found: list[dict[str, Any]] = scenario.run(day, config).summary["alarms"]
    assert [a["kind"] for a in found] == []


def reads(sup: Supervisor, values: list[float]) -> list[bool]:
    return [sup.reading(float(t), value) for t, value in enumerate(values)]


def test_a_spike_down_of_5_c_for_one_read_is_refused() -> None:
    sup = Supervisor(limits())
    # After a fall of one LSB (the direction a run would need), and after a real fall too:
    # the spike falls further than the step before it, as no lagged step does.
    assert reads(sup, [66.0, 66.0, 65.9375, 60.9375, 65.9375]) == [True] * 3 + [False, True]
    assert sup.heater_allowed
    falling = Supervisor(limits())
    assert reads(falling, [66.0, 63.0, 60.5, 55.5]) == [True, False, True, False]


def test_an_alternating_sensor_is_refused_and_raised() -> None:
    sup = Supervisor(limits())
    values = [66.0] + [66.0 + (3.0 if k % 2 == 0 else -3.0) for k in range(8)]
    assert reads(sup, values) == [True] + [False] * 8
    assert sup.active == ["sensor_fault"]


def test_a_sensor_stuck_at_a_wrong_value_after_a_jump_is_as_before() -> None:
    """The jump is refused; the next read agrees with it and is believed, as a real step
    is; the reading then never changes while the output swings: `sensor_stuck` latches."""
    lim = limits()
    sup = Supervisor(lim)
    assert sup.reading(0.0, 66.0, raw=1056)
    assert not sup.reading(1.0, 50.0, raw=800)
    assert sup.reading(2.0, 50.0, raw=800)
    t = 2.0
    for k in range(1, 400):
        t = 2.0 + 5.0 * k
        sup.reading(t, 50.0, raw=800)
        output = 100.0 if (k // 12) % 2 == 0 else 0.0  # a minute on, a minute off
        sup.period(t, 50.0, output, output)
        if sup.latched:
            break
    assert sup.latched == ["sensor_stuck"]
    assert t - 2.0 >= lim.stuck_time
