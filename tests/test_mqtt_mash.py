"""The MQTT bridge of a HERMS against a real broker (mosquitto) and a real daemon: the mash's
temperature a sensor, the pump a switch that commands `set pump` through the control socket,
both announced only when the config fits them, and the pump refused in one line without one.

The plant is `test_reload.doughed_in()`: its mash mixed at 70.1 °C, the HLT at 20 °C."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import pytest
from test_mqtt import ENTITIES, PREFIX, Rig, discovered, operator_lines, step_until
from test_reload import BASE, HERMS, doughed_in

from hermsd.config import read
from hermsd.mqtt.messages import Topics, discovery_messages, state_message

NODE = "brewery_hlt"
SWITCH = f"homeassistant/switch/{NODE}/pump/config"
MASH = f"homeassistant/sensor/{NODE}/mash/config"
HLT_SETPOINT = f"homeassistant/sensor/{NODE}/hlt_setpoint/config"
PHASE = f"homeassistant/sensor/{NODE}/mash_phase/config"
TIMER = f"homeassistant/sensor/{NODE}/pump_turn_in/config"
CLIMATE = f"homeassistant/climate/{NODE}/tun/config"
OUTER_LOOP_PHASES = ("climb", "coast", "hold", "ready", "held")  # control/cascade.py
NO_PUMP = (
    "refused, nothing changed: pump: no pump is fitted (set pump.backend in the config file "
    "and restart hermsd)"
)


@pytest.fixture
def herms(tmp_path: Path) -> Iterator[Rig]:
    with Rig(tmp_path, text=HERMS, tun=doughed_in()) as made:
        yield made


def test_a_herms_announces_a_mash_temperature_sensor_and_a_pump_switch(herms: Rig) -> None:
    entities = discovered(herms.watcher)
    state = herms.step().json()
    # the HLT's, the mash's three sensors, the pump's switch and its timer's next turn
    assert len(entities) == ENTITIES + 5
    for topic in (MASH, HLT_SETPOINT, PHASE, SWITCH, TIMER):
        entity = entities[topic]
        object_id = topic.split("/")[3]
        assert entity["unique_id"] == f"hermsd_{NODE}_{object_id}"
        assert entity["device"]["identifiers"] == [f"hermsd_{NODE}"]
        assert entity["availability_topic"] == herms.topics.availability
        assert entity["state_topic"] == herms.topics.state
        for field in re.findall(r"value_json\.(\w+)", entity["value_template"]):
            assert field in state, (topic, field)
    mash = entities[MASH]
    assert (mash["name"], mash["device_class"], mash["unit_of_measurement"]) == (
        "Mash temperature",
        "temperature",
        "°C",
    )
    assert mash["value_template"] == "{{ value_json.mash }}"
    switch = entities[SWITCH]
    assert switch["command_topic"] == f"{PREFIX}/set/pump"
    assert (switch["payload_on"], switch["payload_off"]) == ("ON", "OFF")
    assert switch["value_template"] == (
        "{{ 'ON' if value_json.pump or value_json.pump_start_in is not none else 'OFF' }}"
    )
    # the published state: the daemon's reading of the mash (near the mix) and the pump off
    status = herms.status()
    assert state["mash"] == status["mash"]["celsius"] and 60.0 < state["mash"] <= 70.2
    assert state["pump"] is False


def test_the_pump_switch_runs_and_stops_the_pump_through_the_socket(herms: Rig) -> None:
    herms.watcher.wait_for(lambda m: m.topic == herms.topics.state)
    herms.command(herms.topics.set_pump, b"ON")
    state = step_until(herms, lambda s: s["pump"] is True)
    assert herms.status()["pump"] is True and herms.daemon.mash_side_fields()["pump"] is True
    herms.command(herms.topics.set_pump, b"OFF")
    step_until(herms, lambda s: s["pump"] is False)
    assert herms.status()["pump"] is False
    assert operator_lines(herms.events) == [
        "operator: set pump on (from the control socket)",
        "operator: set pump off (from the control socket)",
    ]
    assert "pump on: by the operator (from the control socket)" in herms.events.logged()
    assert state["mash"] is not None and herms.watcher.on(herms.topics.error) == []


def test_a_bad_pump_payload_is_refused_in_one_line(herms: Rig) -> None:
    herms.watcher.wait_for(lambda m: m.topic == herms.topics.state)
    mark = len(herms.watcher.messages)
    herms.command(herms.topics.set_pump, b"on")
    error = herms.watcher.wait_for(lambda m: m.topic == herms.topics.error, mark).json()
    assert error["error"] == (
        "refused, nothing changed: pump: expected ON (run it) or OFF (stop it), got 'on'"
    )
    herms.step()
    assert operator_lines(herms.events) == [] and herms.status()["pump"] is False


def test_without_a_pump_the_switch_command_is_refused_and_nothing_reaches_the_daemon(
    tmp_path: Path,
) -> None:
    with Rig(tmp_path) as hlt_only:
        entities = discovered(hlt_only.watcher)
        assert not {SWITCH, MASH, HLT_SETPOINT, PHASE, TIMER} & set(entities)
        assert entities[CLIMATE]["current_temperature_template"] == "{{ value_json.pv }}"
        # sent empty: an entity a HERMS config announced earlier is removed
        emptied = {m.topic for m in hlt_only.watcher.messages if m.payload == b""}
        assert {SWITCH, MASH, HLT_SETPOINT, PHASE, TIMER} <= emptied
        mark = len(hlt_only.watcher.messages)
        hlt_only.command(hlt_only.topics.set_pump, b"ON")
        error = hlt_only.watcher.wait_for(lambda m: m.topic == hlt_only.topics.error, mark).json()
        assert error["error"] == NO_PUMP
        state = hlt_only.step().json()
        assert (state["mash"], state["pump"]) == (None, None)
        assert operator_lines(hlt_only.events) == []


def test_each_part_of_the_mash_side_is_announced_on_its_own() -> None:
    topics = Topics.of(PREFIX, "homeassistant")
    sensor_only = BASE + "mash_sensor:\n  kind: lm92\n  address: 0x49\n"
    pump_only = BASE + "pump:\n  backend: sim\n"
    announced = {
        name: {t for t, p in discovery_messages(topics, read.parse(text)) if p is not None}
        for name, text in (("none", BASE), ("sensor", sensor_only), ("pump", pump_only))
    }
    assert announced["sensor"] - announced["none"] == {MASH, HLT_SETPOINT, PHASE}
    assert announced["pump"] - announced["none"] == {SWITCH, TIMER}


def test_the_outer_loops_choice_is_published_and_the_thermostat_holds_the_mash(
    herms: Rig,
) -> None:
    entities = discovered(herms.watcher)
    hlt = entities[HLT_SETPOINT]
    assert (hlt["name"], hlt["device_class"], hlt["unit_of_measurement"]) == (
        "HLT setpoint (outer loop)",
        "temperature",
        "°C",
    )
    assert hlt["value_template"] == "{{ value_json.hlt_setpoint }}"
    assert entities[PHASE]["name"] == "Mash phase"
    assert entities[PHASE]["value_template"] == "{{ value_json.mash_phase }}"
    # the thermostat card: the mash's temperature against the mash's setpoint, which it sets
    climate = entities[CLIMATE]
    assert climate["current_temperature_template"] == "{{ value_json.mash }}"
    assert climate["temperature_state_template"] == "{{ value_json.setpoint }}"
    state = herms.step().json()
    status = herms.status()
    assert state["hlt_setpoint"] == status["mash"]["hlt_setpoint"]
    assert state["mash_phase"] == status["mash"]["phase"] and state["mash_phase"] in (
        OUTER_LOOP_PHASES
    )
    assert state["setpoint"] == 66.0 and state["hlt_setpoint"] <= 66.0 + 10.0
    herms.command(herms.topics.set_setpoint, b"68.5")
    state = step_until(herms, lambda s: s["setpoint"] == 68.5)
    # the card's setpoint is the mash's: the outer loop now chooses the HLT's for 68.5 °C
    fields = herms.daemon.mash_side_fields()
    assert herms.daemon.setpoint == 68.5 and fields["hlt_setpoint"] == state["hlt_setpoint"]
    assert state["hlt_setpoint"] <= 68.5 + 10.0
    assert herms.watcher.on(herms.topics.error) == []


def test_a_prepared_pump_start_is_published_with_the_pump_asked_on(herms: Rig) -> None:
    """While hermsd sends the coil's load ahead of a start it commanded, the state carries
    `pump_start_in` (s), which the switch's template reads as on: the switch a brewer turned
    on does not flip back to off until the pump runs."""
    status = herms.status()
    mash = status["mash"]
    assert isinstance(mash, dict)
    assert state_message(status)["pump_start_in"] is None  # no start being prepared
    starting = {**status, "pump": False, "mash": {**mash, "pump_start_in": 42.4}}
    assert state_message(starting)["pump_start_in"] == 42.4


def test_the_pump_timers_next_turn_is_published_as_a_duration(herms: Rig) -> None:
    """A program's `pump_off_every` turns the pump by itself: the state carries when it next
    does (`pump_turn_in`, s; null while no timer runs), a duration sensor shows it."""
    timer = discovered(herms.watcher)[TIMER]
    assert (timer["name"], timer["value_template"]) == (
        "Pump timer: next turn in",
        "{{ value_json.pump_turn_in }}",
    )
    assert (timer["device_class"], timer["unit_of_measurement"]) == ("duration", "s")
    status = herms.status()
    mash = status["mash"]
    assert isinstance(mash, dict)
    assert state_message(status)["pump_turn_in"] is None  # no program: no timer
    turning = {**status, "pump": True, "mash": {**mash, "pump_turn_in": 240.0}}
    assert state_message(turning)["pump_turn_in"] == 240.0
