"""The HERMS coil's load in the safety supervisor's heat balances (hermsd/safety/coil_load.py):
its bounds computed by hand, a fall the coil explains is no dead element and a rise it
explains no shorted SSR, and the HERMS scenarios through the simulator (no alarm on a normal
day, each fault still caught)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from hermsd.safety.coil_load import MASH_RANGE, NO_LOAD, MashSpan, coil_load
from hermsd.safety.limits import SafetyLimits
from hermsd.safety.supervisor import Supervisor
from hermsd.sim import scenario

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"
PERIOD = 5.0


def test_the_most_a_coil_takes_is_the_whole_flow_brought_to_the_hlt() -> None:
    # 12 L/min = 0.2 kg/s of wort, × 4186 J/(kg·K) = 837.2 W/K; the HLT at 66 °C, the mash at
    # 38 °C and a sensor's 1 °C: 837.2 × 29 = 24278.8 W taken, nothing given back.
    load = coil_load(66.0, 38.0, True, 12.0)
    assert load.high == pytest.approx(24278.8)
    assert load.most_given == 0.0
    assert load.watts is None  # no conductance known: no best estimate


def test_the_most_a_coil_gives_back_from_a_warmer_mash() -> None:
    # 6 L/min: 418.6 W/K; a 38 °C mash into a 20 °C HLT, +1 °C: 418.6 × 19 = 7953.4 W back.
    load = coil_load(20.0, 38.0, True, 6.0)
    assert load.low == pytest.approx(-7953.4)
    assert load.most_taken == 0.0


def test_a_learned_conductance_narrows_the_bound() -> None:
    # K = 200 W/K, at most 250: 250 × 29 = 7250 W at most, 200 × 28 = 5600 W the estimate.
    load = coil_load(66.0, 38.0, True, 12.0, conductance=(200.0, 250.0))
    assert load.high == pytest.approx(7250.0)
    assert load.watts == pytest.approx(5600.0)


def test_a_mash_never_read_is_anywhere_from_0_to_100_c() -> None:
    # The HLT at 50 °C, 6 L/min: 418.6 × (50 − 0) = 20930 W either way.
    load = coil_load(50.0, MashSpan(*MASH_RANGE), None, 6.0)
    assert load.high == pytest.approx(20930.0)
    assert load.low == pytest.approx(-20930.0)


def test_a_stopped_pump_exchanges_nothing() -> None:
    assert coil_load(66.0, 38.0, False, 12.0) == NO_LOAD


def _run(start: float, rate: float, applied: float, pumped: bool, mash: float) -> list[str]:
    """A supervisor fed a PV moving at `rate` °C/s for 40 min at `applied` %, with the coil's
    load of a mash at `mash` °C pumped at 6 L/min (`pumped`) or none; the alarms it raised."""
    limits = SafetyLimits.derive(litres=90.0, element_watts=3000.0, period=PERIOD, read_interval=1)
    sup = Supervisor(limits)
    t = 0.0
    while t <= 2400.0:
        pv = start + rate * t
        sup.reading(t, pv, raw=round(pv / 0.0625))
        load = coil_load(pv, mash, True, 6.0) if pumped else NO_LOAD
        sup.period(t, pv, applied, applied, load)
        t += PERIOD
    return [alarm.kind for alarm in sup.drain_events() if alarm.raised]


def test_a_fall_the_coil_explains_is_no_dead_element() -> None:
    # The coil taking 1.5 kW beyond the element's 3 kW from 90 L: 1500 / (90 × 4186) =
    # 0.004 °C/s at full power, a mash at 38 °C (up to 418.6 × 19 = 8 kW at 56 °C).
    assert _run(66.0, -0.004, 100.0, False, 38.0) == ["heater_not_heating"]
    assert _run(66.0, -0.004, 100.0, True, 38.0) == []


def test_a_rise_the_coil_explains_is_no_shorted_ssr() -> None:
    # A 38 °C mash warming a 20 °C HLT by 1.5 kW: 0.004 °C/s with the element off, up to 30 °C.
    assert _run(20.0, 0.004, 0.0, False, 38.0) == ["ssr_stuck_on"]
    assert _run(20.0, 0.004, 0.0, True, 38.0) == []


def test_water_the_coil_holds_still_is_no_stuck_sensor() -> None:
    """A HERMS hold: 85 % of 3 kW into the coil, the HLT's reading steady for 40 min. A
    working element gives at least 0.85 × 0.81 (−10 % mains) × 3000 = 2065.5 W; a coil that
    may take that much explains the standstill. Without a coil, nothing does."""
    assert _run(66.0, 0.0, 85.0, False, 38.0) == ["sensor_stuck"]
    # 6 L/min: 418.6 W/K; the mash at 61.5 °C, +1 °C: 418.6 × 5.5 = 2302.3 W at most.
    assert _run(66.0, 0.0, 85.0, True, 61.5) == []


def test_the_losses_count_with_the_coil_against_a_still_reading() -> None:
    """Full power at 40 °C, the pump running: the element gives at least 0.81 × 3000 =
    2430 W; the HLT may lose (the unmeasured envelope, limits.py: an open pot of the least
    water, 45 L, in a 5 °C room) 2 × 17.76 × (45/90)^⅔ = 22.38 W/K × 35 K = 783.2 W, plus
    1000 W of evaporation at 66 °C × 0.2799 (Magnus, 40 against 66 °C) = 279.9 W: 1063.1 W.
    A coil that may take 1366.8 W or more explains a still reading; 6 L/min is 418.6 W/K."""
    # The mash at 37 °C, −1 °C: 418.6 × 4 = 1674.4 W, enough.
    assert _run(40.0, 0.0, 100.0, True, 37.0) == []
    # The mash at 38 °C: 418.6 × 3 = 1255.8 W, short by 111 W: the sensor is stuck.
    assert _run(40.0, 0.0, 100.0, True, 38.0) == ["sensor_stuck"]


def _alarms(name: str, duration: float) -> list[dict[str, object]]:
    day = scenario.load_scenario(SCENARIOS / f"{name}.yaml")
    alarms: list[dict[str, object]] = scenario.run(
        dataclasses.replace(day, duration=duration)
    ).summary["alarms"]
    return alarms


def test_the_herms_day_raises_no_alarm() -> None:
    """The coil's 5.3 kW at pump start (1h05m) outpaces the 3 kW element: the HLT falls at
    full power, which the coil explains (the old supervisor latched heater_not_heating); and
    the bed stuck from 2h to 2h10m: when the flow returns, the mash's 240 s slope shows the
    coil's pull only gradually."""
    assert _alarms("herms-day", 3 * 3600.0) == []


def test_heat_back_from_a_warmer_mash_raises_no_alarm() -> None:
    assert _alarms("herms-heat-back", 3 * 3600.0) == []


def test_a_dead_element_is_caught_with_the_pump_running() -> None:
    """Open at 2h20m (8400 s) in the rest, the pump running until 2h40m (9600 s): the mash
    stops warming, so the coil explains none of the HLT's fall, which is judged as without a
    coil once the output has been at full power for the dead time and the watch (300 + 300 s)
    after it climbed there. (On the flow's bound it was caught only after the pump stopped.)"""
    alarms = _alarms("herms-heater-open", 10800.0)
    assert [a["kind"] for a in alarms] == ["heater_not_heating"]
    assert 8400.0 < float(str(alarms[0]["at_s"])) < 9600.0


def test_a_shorted_ssr_is_caught_with_the_pump_running() -> None:
    alarms = _alarms("herms-ssr-stuck-on", 10000.0)
    assert [a["kind"] for a in alarms] == ["ssr_stuck_on"]
    assert 8400.0 < float(str(alarms[0]["at_s"])) <= 8400.0 + 1000.0


def test_a_dead_element_after_the_pump_stopped_for_good_is_judged_by_the_heat_balance() -> None:
    """herms-heater-open's plant with 9 kW in the HLT: the pump stops at 2 h and the element
    goes open at 2h20m in the HLT's hold (some 20 % of 9 kW). The coil drew nothing for longer
    than the heat's memory, so the balance judges the HLT as one without a coil: the law's
    climb with the water falling tells it (695 s), where with the balance off for the hour the
    watches look back the output watch told it only after full output for its watch (980 s)."""
    day = scenario.load_scenario(SCENARIOS / "herms-heater-open.yaml")
    events = [e for e in day.events if e.kind not in ("pump", "heater") or e.value is True]
    events += [scenario.Event(7200.0, "pump", False), scenario.Event(8400.0, "heater", "open")]
    nine_kw = {"litres": 90, "element_watts": 9000}
    day = dataclasses.replace(
        day,
        plant={**day.plant, "element_watts": 9000},
        config={**day.config, "tun": nine_kw},
        events=tuple(sorted(events, key=lambda e: e.at)),
        duration=8400.0 + 1800.0,
    )
    [alarm] = scenario.run(day).summary["alarms"]
    assert alarm["kind"] == "heater_not_heating"
    assert str(alarm["message"]).startswith("output climbed")
    assert float(str(alarm["at_s"])) - 8400.0 <= 12 * 60.0
