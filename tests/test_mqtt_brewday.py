"""The brew day from Home Assistant, against a real mosquitto and a real daemon (the rig of
test_mqtt.py): the program's state, its buttons, a program started from the folder, the
alarm reset's exact words, alarms as events, and the thermostat's range from the daemon.
Every discovery payload is checked against the keys Home Assistant's MQTT platforms take."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import pytest
from test_mqtt import PREFIX, TIMEOUT, Message, Rig, discovered, step_until
from test_reload import BASE, PERIOD, edited, run_for

from hermsd.config import read
from hermsd.mqtt import brewday
from hermsd.mqtt.bridge import Bridge
from hermsd.sim.hlt import FoptdPlant, Plant

# From Home Assistant's MQTT integration docs (integrations/<platform>.mqtt), discovery keys
# written out in full. Every entity may carry the common ones.
COMMON = {
    "availability", "availability_mode", "availability_template", "availability_topic",
    "payload_available", "payload_not_available", "device", "origin", "enabled_by_default",
    "encoding", "entity_category", "entity_picture", "icon", "json_attributes_template",
    "json_attributes_topic", "name", "object_id", "default_entity_id", "unique_id", "qos",
}  # fmt: skip
PLATFORMS: dict[str, tuple[set[str], set[str]]] = {  # platform: (required, allowed beyond COMMON)
    "button": ({"command_topic"}, {"command_template", "device_class", "payload_press", "retain"}),
    "event": ({"state_topic", "event_types"}, {"device_class", "value_template"}),
    "select": (
        {"command_topic", "options"},
        {"command_template", "optimistic", "retain", "state_topic", "value_template"},
    ),
    "sensor": (
        {"state_topic"},
        {
            "device_class",
            "expire_after",
            "force_update",
            "last_reset_value_template",
            "options",
            "suggested_display_precision",
            "state_class",
            "unit_of_measurement",
            "value_template",
        },
    ),
    "binary_sensor": (
        {"state_topic"},
        {
            "device_class",
            "expire_after",
            "force_update",
            "off_delay",
            "payload_off",
            "payload_on",
            "value_template",
        },
    ),
    "switch": (
        {"command_topic"},
        {
            "device_class",
            "optimistic",
            "payload_off",
            "payload_on",
            "retain",
            "state_off",
            "state_on",
            "state_topic",
            "value_template",
        },
    ),
    "climate": (
        set(),
        {
            "action_template",
            "action_topic",
            "current_humidity_template",
            "current_humidity_topic",
            "current_temperature_template",
            "current_temperature_topic",
            "fan_mode_command_template",
            "fan_mode_command_topic",
            "fan_mode_state_template",
            "fan_mode_state_topic",
            "fan_modes",
            "initial",
            "max_humidity",
            "max_temp",
            "min_humidity",
            "min_temp",
            "mode_command_template",
            "mode_command_topic",
            "mode_state_template",
            "mode_state_topic",
            "modes",
            "optimistic",
            "payload_off",
            "payload_on",
            "power_command_template",
            "power_command_topic",
            "precision",
            "preset_mode_command_template",
            "preset_mode_command_topic",
            "preset_mode_state_topic",
            "preset_mode_value_template",
            "preset_modes",
            "retain",
            "swing_mode_command_template",
            "swing_mode_command_topic",
            "swing_mode_state_template",
            "swing_mode_state_topic",
            "swing_modes",
            "target_humidity_command_template",
            "target_humidity_command_topic",
            "target_humidity_state_template",
            "target_humidity_state_topic",
            "temperature_command_template",
            "temperature_command_topic",
            "temperature_high_command_template",
            "temperature_high_command_topic",
            "temperature_high_state_template",
            "temperature_high_state_topic",
            "temperature_low_command_template",
            "temperature_low_command_topic",
            "temperature_low_state_template",
            "temperature_low_state_topic",
            "temperature_state_template",
            "temperature_state_topic",
            "temperature_unit",
            "temp_step",
            "value_template",
        },
    ),
}
EVENT_DEVICE_CLASSES = {"button", "doorbell", "motion"}
PROGRAM = """name: HA mash
steps:
  - name: Strike
    setpoint: {setpoint}
    hold: 0s
    confirm: Mash in
  - name: Rest
    setpoint: {setpoint}
    hold: 10m
"""


class BrewRig(Rig):
    """The rig with a program folder the bridge offers."""

    def __init__(self, tmp_path: Path, *, text: str = BASE, tun: Plant | None = None) -> None:
        self.programs = tmp_path / "programs"
        self.programs.mkdir()
        (self.programs / "broken.yaml").write_text("name: Broken\nsteps: []\n", encoding="utf-8")
        (self.programs / "notes.txt").write_text("not a program\n", encoding="utf-8")
        super().__init__(tmp_path, text=text, tun=tun)
        self.brew = self.bridge.brewday

    def start_bridge(self) -> None:
        mark = len(self.watcher.messages)
        self.bridge = bridge_with(self, self.programs)
        self.thread = threading.Thread(target=self.bridge.run)
        self.thread.start()
        discovered(self.watcher, mark)

    def press(self, button: str, payload: bytes = b"PRESS") -> None:
        self.command(self.brew.press[button], payload)

    def result(self, mark: int) -> dict[str, Any]:
        found: dict[str, Any] = self.watcher.wait_for(
            lambda m: m.topic == self.brew.result, mark
        ).json()
        return found

    def result_after_steps(self, mark: int) -> dict[str, Any]:
        """The result of a command the daemon answers after a period boundary."""
        for _ in range(20):
            if self.watcher.on(self.brew.result, mark):
                return self.result(mark)
            self.step()
        raise AssertionError("no result within 20 periods")

    def alerts(self, mark: int = 0) -> list[dict[str, Any]]:
        return [m.json() for m in self.watcher.on(self.brew.event, mark)]


def bridge_with(rig: Rig, programs: Path) -> Bridge:
    return Bridge(rig.config, rig.socket, poll=0.02, broker_retry=(1, 2), programs=programs)


@pytest.fixture
def brew(tmp_path: Path) -> Any:
    with BrewRig(tmp_path) as made:
        yield made


def check_schema(topic: str, payload: dict[str, Any]) -> None:
    platform = topic.split("/")[1]
    required, allowed = PLATFORMS[platform]
    assert required <= set(payload), (topic, required - set(payload))
    assert set(payload) <= COMMON | required | allowed, (topic, set(payload) - COMMON - allowed)
    for key, value in payload.items():
        if key.endswith("_topic"):
            assert isinstance(value, str) and value and "+" not in value and "#" not in value
    if platform == "event":
        assert payload["event_types"] and all(isinstance(t, str) for t in payload["event_types"])
        assert payload.get("device_class") in (None, *EVENT_DEVICE_CLASSES)
    if platform == "select":
        assert payload["options"] and all(isinstance(o, str) for o in payload["options"])
    if platform == "sensor" and payload.get("device_class") == "enum":
        assert payload["options"] and "unit_of_measurement" not in payload
    if platform == "button":
        assert payload.get("payload_press", "PRESS") == "PRESS"


def test_every_entity_announced_keeps_to_home_assistants_schema_for_its_platform(
    brew: BrewRig,
) -> None:
    entities = discovered(brew.watcher)
    assert {topic.split("/")[1] for topic in entities} == set(PLATFORMS) - {"switch"}
    for topic, payload in entities.items():
        check_schema(topic, payload)
    node = brew.topics.node_id
    buttons = {t.split("/")[3] for t in entities if t.split("/")[1] == "button"}
    assert buttons == {"confirm", "next", "pause", "resume", "stop", "start", "reset_alarm"}
    select = entities[f"homeassistant/select/{node}/program/config"]
    assert select["options"] == ["broken.yaml"]  # the folder's programs, not its other files
    assert select["command_topic"] == f"{PREFIX}/set/program/choose"  # under set/: the ACL's
    event = entities[f"homeassistant/event/{node}/alert/config"]
    assert event["event_types"] == ["alarm", "alarm_cleared", "warning", "warning_cleared",
                                    "waiting"]  # fmt: skip
    state = entities[f"homeassistant/sensor/{node}/program_state/config"]
    assert state["options"] == ["running", "paused", "waiting", "done", "none"]


def test_a_herms_config_keeps_to_the_schema_too(tmp_path: Path) -> None:
    from test_reload import HERMS, doughed_in

    with BrewRig(tmp_path, text=HERMS, tun=doughed_in()) as herms:
        for topic, payload in discovered(herms.watcher).items():
            check_schema(topic, payload)


def test_a_program_is_chosen_started_confirmed_paused_resumed_and_stopped_from_buttons(
    brew: BrewRig,
) -> None:
    pv = brew.status()["pv"]
    setpoint = round(pv + 0.45, 1)  # in band at once: the strike step waits for the brewer
    (brew.programs / "ha-mash.yaml").write_text(PROGRAM.format(setpoint=setpoint), "utf-8")
    mark = len(brew.watcher.messages)
    brew.step()  # the bridge sees the new file and offers it
    select = brew.watcher.wait_for(lambda m: m.topic.endswith("/select/brewery_hlt/program/config")
                                   and b"ha-mash" in m.payload, mark).json()  # fmt: skip
    assert select["options"] == ["broken.yaml", "ha-mash.yaml"]

    mark = len(brew.watcher.messages)
    brew.press("start")  # nothing chosen yet: refused here, nothing sent
    refused = brew.result(mark)
    assert refused["ok"] is False and "choose a program first" in refused["text"]

    mark = len(brew.watcher.messages)
    brew.command(brew.brew.choose, b"../hermsd.yaml")  # only what the folder offers
    assert "is not a program file" in brew.result(mark)["text"]

    brew.command(brew.brew.choose, b"broken.yaml")
    brew.watcher.wait_for(lambda m: m.topic == brew.brew.chosen and m.payload == b"broken.yaml")
    mark = len(brew.watcher.messages)
    brew.press("start")  # checked as `hermsd program start` checks the file
    refused = brew.result(mark)
    assert refused["ok"] is False and "broken.yaml" in refused["text"]
    assert brew.status()["program"] is None

    brew.command(brew.brew.choose, b"ha-mash.yaml")
    brew.watcher.wait_for(lambda m: m.topic == brew.brew.chosen and m.payload == b"ha-mash.yaml")
    mark = len(brew.watcher.messages)
    brew.press("start")
    state = step_until(brew, lambda s: s["run_state"] == "waiting")
    assert brew.result(mark) == {
        "topic": f"{PREFIX}/set/program/start",
        "ok": True,
        "text": "program start 'HA mash' (2 steps): applied",
    }
    assert (state["step_text"], state["message_text"], state["next_text"]) == (
        "Strike",
        "Mash in",
        "Rest",
    )
    # The event follows the state it is drawn from: waited for, as any message on the broker.
    brew.watcher.wait_for(lambda m: m.topic == brew.brew.event and b'"waiting"' in m.payload, mark)
    waiting = [e for e in brew.alerts(mark) if e["event_type"] == "waiting"]
    assert waiting == [{"event_type": "waiting", "tun": "HLT", "kind": "", "message": "Mash in"}]

    mark = len(brew.watcher.messages)
    brew.press("confirm")
    state = step_until(brew, lambda s: s["step_text"] == "Rest")
    assert (state["run_state"], state["message_text"], state["next_text"]) == (
        "running",
        "none",
        "none",
    )
    assert brew.result(mark)["ok"] is True

    mark = len(brew.watcher.messages)
    brew.press("confirm")  # nothing waits now: the daemon's refusal, in its words
    refused = brew.result_after_steps(mark)
    assert refused["ok"] is False and refused["text"].startswith("refused, nothing changed: ")
    assert [m.json()["error"] for m in brew.watcher.on(brew.topics.error, mark)] == [
        refused["text"]
    ]

    brew.press("pause")
    assert step_until(brew, lambda s: s["run_state"] == "paused")["step_text"] == "Rest"
    brew.press("resume")
    step_until(brew, lambda s: s["run_state"] == "running")
    brew.press("stop")
    state = step_until(brew, lambda s: s["run_state"] == "none")
    assert (state["step_text"], state["next_text"], state["message_text"]) == (
        "none",
        "none",
        "none",
    )


def test_a_press_other_than_the_buttons_payload_is_refused(brew: BrewRig) -> None:
    mark = len(brew.watcher.messages)
    brew.press("stop", b"now")
    assert brew.result(mark) == {
        "topic": f"{PREFIX}/set/program/stop",
        "ok": False,
        "text": "refused, nothing changed: a button sends PRESS, got 'now'",
    }


def test_the_reset_button_says_the_hot_over_temperature_stands_and_the_alarm_is_an_event(
    tmp_path: Path,
) -> None:
    """Water at 97 °C over the 95 °C cut-out: the alarm reaches Home Assistant as an event,
    and a reset says it stands, does not latch and clears below 90 °C, not "done"."""
    with BrewRig(tmp_path, tun=FoptdPlant(start_c=97.0)) as hot:
        alarm = hot.watcher.wait_for(lambda m: m.topic == hot.brew.event).json()
        assert (alarm["event_type"], alarm["kind"]) == ("alarm", "over_temperature")
        assert "at or above the limit 95.0 °C" in alarm["message"]
        mark = len(hot.watcher.messages)
        hot.press("reset_alarm")
        said = hot.result_after_steps(mark)
        assert said["ok"] is True
        assert said["text"].startswith(
            "reset: cleared none; still standing, the heater stays off: over_temperature: "
            "does not latch, so no reset clears it: it clears by itself once the water is "
            "below 90 °C"
        )
        assert hot.status()["alarms"] == ["over_temperature"]


def test_an_alarm_cleared_and_a_warning_are_events_once_each() -> None:
    news = brewday.News()
    status: dict[str, Any] = {"tun": "HLT", "alarms": [], "warnings": [], "program": None}
    assert news.of(status) == []
    raised = {**status, "alarms": ["sensor_fault"], "alarm_reasons": {"sensor_fault": "bus"}}
    assert news.of(raised) == [
        {"event_type": "alarm", "tun": "HLT", "kind": "sensor_fault", "message": "bus"}
    ]
    assert news.of(raised) == []  # the same alarm standing is no news
    warned = {**status, "warnings": ["log failing"]}
    assert [e["event_type"] for e in news.of(warned)] == ["alarm_cleared", "warning"]
    assert [e["event_type"] for e in news.of(status)] == ["warning_cleared"]


def test_the_thermostat_takes_the_daemons_cut_out_and_refuses_as_the_daemon_does(
    brew: BrewRig,
) -> None:
    """The daemon runs with its cut-out at 80 °C while the bridge's file says 95 °C: the
    card's range follows the daemon, and 85 °C is refused in the daemon's own words."""
    brew.bridge.stop()
    brew.thread.join(TIMEOUT)
    brew.config = read.parse(edited(brew.text, safety__max_temp="95"))
    brew.path.write_text(edited(brew.text, safety__max_temp="80"), encoding="utf-8")
    run_for(brew.daemon, 2 * PERIOD)  # the daemon reloads its edited file
    assert brew.status()["setpoint_limits"] == {"min": 0.0, "max": 100.0, "below": 80.0}
    mark = len(brew.watcher.messages)
    brew.start_bridge()
    climate_topic = f"homeassistant/climate/{brew.topics.node_id}/tun/config"

    def card(m: Message) -> bool:
        return m.topic == climate_topic and m.json()["max_temp"] == 79.5

    climate = brew.watcher.wait_for(card, mark).json()
    assert (climate["min_temp"], climate["max_temp"]) == (0.0, 79.5)
    for payload, says in [
        (b"85", "control.setpoint: 85 °C is not below safety.max_temp (80 °C)"),
        (b"79.8", "79.8 °C is outside the thermostat's range, 0 to 79.5 °C"),
    ]:
        mark = len(brew.watcher.messages)
        brew.command(brew.topics.set_setpoint, payload)
        error = brew.watcher.wait_for(lambda m: m.topic == brew.topics.error, mark).json()
        assert says in error["error"], error
    assert brew.status()["setpoint"] == 66.0
