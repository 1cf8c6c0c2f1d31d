"""The MQTT bridge against a real broker and a real daemon.

The broker is Debian's mosquitto, started here on a free loopback port with its own config
(never the system's service); without it these tests are skipped, saying why (failed in CI,
which installs it). The daemon runs
on the virtual clock behind the real control socket, and the test steps it one period at a
time; every wait on the real clock is for a network event, bounded by TIMEOUT.
"""

from __future__ import annotations

import ast
import contextlib
import json
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt
import pytest
from paho.mqtt.enums import CallbackAPIVersion
from programs import require_program
from test_reload import BASE, PERIOD, Events, edited, run_for, start

from hermsd.api import protocol
from hermsd.api.client import ask
from hermsd.api.link import LoopLink
from hermsd.api.protocol import ProgramAction, ProgramStart, Request
from hermsd.api.server import ControlServer
from hermsd.cli import main
from hermsd.config import read
from hermsd.mqtt import bridge as bridge_module
from hermsd.mqtt.bridge import Bridge
from hermsd.mqtt.messages import Topics, discovery_messages, setpoint_range, state_message
from hermsd.program.model import Program, Step
from hermsd.program.store import PROGRESS_FILE
from hermsd.runtime.instance import InstanceError
from hermsd.safety.latches import LatchStore
from hermsd.sim.hlt import Plant

ROOT = Path(__file__).resolve().parents[1]
MOSQUITTO = Path("/usr/sbin/mosquitto")
MOSQUITTO_PASSWD = Path("/usr/bin/mosquitto_passwd")
TIMEOUT = 20.0
"""s: a bound on each wait, not a wait (each returns at its event): a `hermsd mqtt` process
started by a test takes seconds to import its libraries on a loaded machine."""
PREFIX = "brewery/hlt"
# What Home Assistant accepts (its MQTT climate, sensor and binary_sensor schemas).
HA_HVAC_MODES = {"auto", "off", "cool", "heat", "dry", "fan_only", "heat_cool"}
HA_ACTIONS = {"off", "heating", "cooling", "drying", "idle", "fan", "preheating", "defrosting"}
HA_COMPONENTS = {"climate", "sensor", "binary_sensor", "button", "event"}
ENTITIES = 24  # without a program folder: no program select, no start button


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port: int = probe.getsockname()[1]
        return port


class Broker:
    """A mosquitto of the test's own on a loopback port, without persistence (a restart
    forgets every retained message)."""

    def __init__(self, directory: Path, users: dict[str, str] | None = None) -> None:
        require_program(MOSQUITTO, "mosquitto", what="the MQTT bridge's tests")
        self.port = free_port()
        self.conf = directory / "mosquitto.conf"
        # `user root`: started by root it would read its files as the mosquitto user, who
        # may not enter the test's directory
        lines = [f"listener {self.port} 127.0.0.1", "persistence false", "user root"]
        if users:
            passwords = directory / "mosquitto.passwd"
            passwords.touch(0o600)
            for name, password in users.items():
                subprocess.run(
                    [MOSQUITTO_PASSWD, "-b", passwords, name, password], check=True, timeout=TIMEOUT
                )
            lines += ["allow_anonymous false", f"password_file {passwords}"]
        else:
            lines += ["allow_anonymous true"]
        self.conf.write_text("\n".join(lines) + "\n", encoding="utf-8")
        self.log = directory / "mosquitto.log"
        self.process: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        with self.log.open("ab") as log:
            self.process = subprocess.Popen(
                [MOSQUITTO, "-c", self.conf], stdout=log, stderr=subprocess.STDOUT
            )
        deadline = time.monotonic() + TIMEOUT
        while True:  # until it listens: a connection is the network event waited for
            with contextlib.suppress(ConnectionRefusedError), socket.socket() as probe:
                probe.connect(("127.0.0.1", self.port))
                return
            assert self.process.poll() is None, self.log.read_text()
            assert time.monotonic() < deadline, "mosquitto did not listen"
            threading.Event().wait(0.01)

    def stop(self) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.terminate()
            self.process.wait(TIMEOUT)


@dataclass(frozen=True)
class Message:
    topic: str
    payload: bytes
    retain: bool

    def json(self) -> Any:
        return json.loads(self.payload)


class Watcher:
    """A client of the test's own that records every message on the broker."""

    def __init__(self, port: int, login: tuple[str, str] | None = None) -> None:
        self.messages: list[Message] = []
        self._changed = threading.Condition()
        self.client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"watcher-{id(self)}")
        self.client.on_message = self._on_message
        subscribed = threading.Event()
        self.client.on_subscribe = lambda *_: subscribed.set()
        self.client.on_connect = lambda client, *_: client.subscribe("#", 1)
        if login is not None:
            self.client.username_pw_set(*login)
        self.client.connect("127.0.0.1", port)
        self.client.loop_start()
        assert subscribed.wait(TIMEOUT)

    def _on_message(self, _client: mqtt.Client, _userdata: Any, message: Any) -> None:
        with self._changed:
            self.messages.append(Message(message.topic, bytes(message.payload), message.retain))
            self._changed.notify_all()

    def wait_for(self, match: Callable[[Message], bool], since: int = 0) -> Message:
        """The first message from index `since` on that `match`es, waiting up to TIMEOUT."""
        with self._changed:
            found: list[Message] = []

            def seen() -> bool:
                found.extend(m for m in self.messages[since:] if match(m))
                return bool(found)

            assert self._changed.wait_for(seen, TIMEOUT), f"no such message in {self.messages}"
            return found[0]

    def on(self, topic: str, since: int = 0) -> list[Message]:
        with self._changed:
            return [m for m in self.messages[since:] if m.topic == topic]

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


class Rig:
    """Broker, daemon behind its socket, the bridge on a thread, and a watcher."""

    def __init__(
        self,
        tmp_path: Path,
        latches: LatchStore | None = None,
        *,
        text: str = BASE,
        tun: Plant | None = None,
    ) -> None:
        """`text` and `tun`: the daemon's config and plant (a HERMS: `test_reload.HERMS`)."""
        self.broker = Broker(tmp_path)
        self.broker.start()
        self.text = edited(text, mqtt__port=str(self.broker.port), mqtt__topic_prefix=PREFIX)
        self.daemon, _world, self.path, self.events = start(
            tmp_path, self.text, latches=latches, tun=tun
        )
        self.config = read.load(self.path)
        self.socket = tmp_path / "control.sock"
        self.server = self._serve()
        run_for(self.daemon, 60.0)
        self.topics = Topics.of(PREFIX, "homeassistant")
        self.watcher = Watcher(self.broker.port)
        self.start_bridge()

    def start_bridge(self) -> None:
        """A bridge, once it hears commands: it announces itself after it subscribed."""
        mark = len(self.watcher.messages)
        self.bridge = Bridge(self.config, self.socket, poll=0.02, broker_retry=(1, 2))
        self.thread = threading.Thread(target=self.bridge.run)
        self.thread.start()
        discovered(self.watcher, mark)

    def _serve(self) -> ControlServer:
        link = LoopLink(self.daemon)
        server = ControlServer(self.socket, link.status_line)
        server.start()
        link.attach(server)
        return server

    def status(self) -> dict[str, Any]:
        assert isinstance(self.daemon.control, LoopLink)
        reply: dict[str, Any] = json.loads(self.daemon.control.status_line())
        return reply

    def step(self) -> Message:
        """One control period; the state the bridge publishes for it."""
        mark = len(self.watcher.messages)
        run_for(self.daemon, PERIOD)
        t = self.status()["t"]
        return self.watcher.wait_for(
            lambda m: m.topic == self.topics.state and m.json()["t"] == t, mark
        )

    def at_boundary(self, request: Request) -> dict[str, Any]:
        """The state after the daemon's reply to `request`, sent while the test runs the next
        period."""
        replies: list[dict[str, Any]] = []
        asking = threading.Thread(target=lambda: replies.append(ask(self.socket, request)))
        asking.start()
        deadline = time.monotonic() + TIMEOUT
        while not self.server._commands:  # the command waits for the boundary
            assert time.monotonic() < deadline, "no command reached the daemon"
            threading.Event().wait(0.005)
        state = self.step().json()
        asking.join(TIMEOUT)
        assert replies and replies[0]["ok"], replies
        return state

    def command(self, topic: str, payload: bytes, *, retain: bool = False) -> None:
        self.watcher.client.publish(topic, payload, 1, retain=retain).wait_for_publish(TIMEOUT)

    def __enter__(self) -> Rig:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self.bridge.stop()
        self.thread.join(TIMEOUT)
        assert not self.thread.is_alive()
        self.watcher.close()
        self.server.close()
        self.broker.stop()


@pytest.fixture
def rig(tmp_path: Path) -> Iterator[Rig]:
    with Rig(tmp_path) as made:
        yield made


def operator_lines(events: Events) -> list[str]:
    return [line for line in events.logged() if line.startswith("operator:")]


def discovered(watcher: Watcher, since: int = 0) -> dict[str, dict[str, Any]]:
    """Every discovery message the bridge published: {topic: payload}; waits for the last."""
    watcher.wait_for(lambda m: m.topic.endswith("/alarm/config"), since)
    messages = [m for m in watcher.messages[since:] if m.topic.startswith("homeassistant/")]
    return {m.topic: m.json() for m in messages if m.topic.endswith("/config") and m.payload}


# -- what Home Assistant is told ------------------------------------------------------------


def test_discovery_gives_home_assistant_a_climate_entity_sensors_and_an_alarm(rig: Rig) -> None:
    rig.watcher.wait_for(lambda m: m.topic == rig.topics.availability and m.payload == b"online")
    entities = discovered(rig.watcher)
    state = rig.step().json()
    node = "brewery_hlt"
    components = {topic.split("/")[1] for topic in entities}
    assert components == HA_COMPONENTS
    assert len(entities) == ENTITIES
    # no second element here: its entity, if an earlier config made one, is removed
    removed = f"homeassistant/sensor/{node}/output2/config"
    assert removed not in entities
    assert any(m.topic == removed and m.payload == b"" for m in rig.watcher.messages)
    ids = set()
    for topic, entity in entities.items():
        # <discovery prefix>/<component>/<node id>/<object id>/config, ids unique and stable
        _prefix, _component, node_id, object_id, _config = topic.split("/")
        assert node_id == node and re.fullmatch(r"[a-zA-Z0-9_-]+", object_id)
        assert entity["unique_id"] == f"hermsd_{node}_{object_id}"
        ids.add(entity["unique_id"])
        assert entity["device"]["identifiers"] == [f"hermsd_{node}"]
        assert entity["device"]["name"] == "hermsd HLT"
        assert entity["availability_topic"] == rig.topics.availability
        assert (entity["payload_available"], entity["payload_not_available"]) == (
            "online",
            "offline",
        )
        # every template picks a field that the state holds
        for key, value in entity.items():
            if key.endswith("_topic") and not key.endswith("command_topic"):
                brewday = rig.bridge.brewday
                assert value in (
                    rig.topics.state,
                    rig.topics.availability,
                    brewday.result,
                    brewday.event,
                ), key
            if key.endswith("template") and entity.get("state_topic") == rig.topics.state:
                for field in re.findall(r"value_json\.(\w+)", value):
                    assert field in state, (topic, field)
    assert len(ids) == len(entities)

    climate = entities[f"homeassistant/climate/{node}/tun/config"]
    assert climate["temperature_command_topic"] == f"{PREFIX}/set/setpoint"
    assert climate["mode_command_topic"] == f"{PREFIX}/set/mode"
    assert set(climate["modes"]) == {"heat", "off"} <= HA_HVAC_MODES
    assert state["climate_mode"] in climate["modes"] and state["action"] in HA_ACTIONS
    assert climate["temperature_unit"] == "C"
    # the shipped cut-out is 95 °C: the highest setpoint offered is the step below it, and
    # the bridge takes what the card offers, no more (94.9 is refused: BAD_COMMANDS)
    assert (climate["min_temp"], climate["max_temp"], climate["temp_step"]) == (0, 94.5, 0.5)
    assert (climate["min_temp"], climate["max_temp"]) == setpoint_range(rig.config)
    warning = entities[f"homeassistant/binary_sensor/{node}/warning/config"]
    assert warning["device_class"] == "problem"

    temperature = entities[f"homeassistant/sensor/{node}/temperature/config"]
    assert (temperature["device_class"], temperature["unit_of_measurement"]) == (
        "temperature",
        "°C",
    )
    time_left = entities[f"homeassistant/sensor/{node}/time_left/config"]
    assert (time_left["device_class"], time_left["unit_of_measurement"]) == ("duration", "s")
    rest_in = entities[f"homeassistant/sensor/{node}/rest_in/config"]
    assert (rest_in["name"], rest_in["value_template"]) == (
        "Rest starts in",
        "{{ value_json.rest_in_s }}",
    )
    assert (rest_in["device_class"], rest_in["unit_of_measurement"]) == ("duration", "s")
    alarm = entities[f"homeassistant/binary_sensor/{node}/alarm/config"]
    assert alarm["device_class"] == "problem"
    assert alarm["value_template"] == "{{ 'ON' if value_json.alarm else 'OFF' }}"

    # all retained: a client that comes later (Home Assistant restarted) is told it all
    late = Watcher(rig.broker.port)
    try:
        assert discovered(late) == entities
        late.wait_for(lambda m: m.topic == rig.topics.state and m.json() == state)
        retained = {
            m.topic: m.retain for m in late.messages if m.topic.startswith(("home", PREFIX))
        }
        assert set(retained) == {*entities, rig.topics.availability, rig.topics.state}
        assert all(retained.values())
    finally:
        late.close()


def test_home_assistant_back_online_is_told_everything_again(rig: Rig) -> None:
    discovered(rig.watcher)
    mark = len(rig.watcher.messages)
    rig.command(rig.topics.home_assistant_status, b"online")  # Home Assistant's birth message
    assert len(discovered(rig.watcher, mark)) == ENTITIES
    rig.watcher.wait_for(lambda m: m.topic == rig.topics.availability, mark)


def test_the_state_is_published_retained_once_per_control_period(rig: Rig) -> None:
    now = rig.status()["t"]  # the bridge has published the period in force before the mark
    rig.watcher.wait_for(lambda m: m.topic == rig.topics.state and m.json()["t"] == now)
    mark = len(rig.watcher.messages)
    periods = []
    for _ in range(4):
        rig.step()
        periods.append(rig.status())
    published = [m.json() for m in rig.watcher.on(rig.topics.state, mark)]
    assert [s["t"] for s in published] == [p["t"] for p in periods]  # one each, none twice
    assert [s["t"] - periods[0]["t"] for s in published] == [0, PERIOD, 2 * PERIOD, 3 * PERIOD]
    last, status = published[-1], periods[-1]
    assert (last["pv"], last["setpoint"], last["output"], last["applied"]) == (
        status["pv"],
        status["setpoint"],
        status["output"],
        status["applied"],
    )
    # heating up from 20 °C at full power, in auto: Home Assistant sees heat, heating
    assert (last["mode"], last["climate_mode"], last["action"]) == ("auto", "heat", "heating")
    assert (last["alarm"], last["alarm_text"], last["program"], last["step_text"]) == (
        False,
        "none",
        None,
        "none",
    )


# -- commands -------------------------------------------------------------------------------


def step_until(rig: Rig, done: Callable[[dict[str, Any]], bool]) -> dict[str, Any]:
    """Step periods until a published state is `done` (a command is applied at a boundary)."""
    for _ in range(20):
        state: dict[str, Any] = rig.step().json()
        if done(state):
            return state
    raise AssertionError("the command was not applied within 20 periods")


def test_setpoint_and_mode_commands_are_applied_through_the_socket(rig: Rig) -> None:
    rig.watcher.wait_for(lambda m: m.topic == rig.topics.state)
    rig.command(rig.topics.set_setpoint, b"72.5")
    state = step_until(rig, lambda s: s["setpoint"] == 72.5)
    assert rig.status()["setpoint"] == 72.5
    assert operator_lines(rig.events) == [
        "operator: set setpoint 72.5 °C (from the control socket)"
    ]

    rig.command(rig.topics.set_mode, b"off")
    state = step_until(rig, lambda s: s["mode"] == "manual")
    status = rig.status()
    assert (status["mode"], status["manual_output"], status["output"]) == ("manual", 0.0, 0.0)
    assert (state["climate_mode"], state["action"], state["mode_text"]) == (
        "off",
        "off",
        "manual at 0 %",
    )

    rig.command(rig.topics.set_mode, b"heat")
    state = step_until(rig, lambda s: s["mode"] == "auto")
    assert (rig.status()["mode"], state["climate_mode"], state["setpoint"]) == (
        "auto",
        "heat",
        72.5,
    )
    assert rig.watcher.on(rig.topics.error) == []


def test_quick_setpoints_end_at_the_latest_none_refused(rig: Rig) -> None:
    """A slider dragged: 15 setpoints, one a period, faster than the daemon takes a client's
    commands (10 at once, then 2 a second). Those that wait are replaced by newer ones, the
    bridge sends what it may when it may, and the last one is what holds."""
    rig.watcher.wait_for(lambda m: m.topic == rig.topics.state)
    for tenths in range(600, 675, 5):
        rig.command(rig.topics.set_setpoint, f"{tenths / 10:g}".encode())
        rig.step()
    deadline = time.monotonic() + TIMEOUT  # the bridge waits on the real clock for its turn
    while rig.step().json()["setpoint"] != 67.0:
        assert time.monotonic() < deadline, "the latest setpoint was not applied"
    assert rig.watcher.on(rig.topics.error) == []
    applied = [float(line.split()[3]) for line in operator_lines(rig.events)]
    assert applied[-1] == 67.0 and applied == sorted(applied)  # never back to an older one


BAD_COMMANDS = [  # (topic, payload, what the error says)
    ("set/setpoint", b"hot", "setpoint: expected a number in °C such as 66.5, got 'hot'"),
    ("set/setpoint", b"nan", "expected a number"),
    ("set/setpoint", b"1e999", "control.setpoint: expected a number"),
    ("set/setpoint", b"150", "control.setpoint: 150 °C is out of range"),
    ("set/setpoint", b"95", "is not below safety.max_temp"),
    ("set/setpoint", b"94.9", "94.9 °C is outside the thermostat's range, 0 to 94.5 °C"),
    ("set/setpoint", b"-0.5", "control.setpoint: -0.5 °C is out of range"),
    ("set/setpoint", b'{"setpoint": 70}', "expected a number"),
    ("set/setpoint", b"\xff70", "not UTF-8"),
    ("set/setpoint", b"7" * 100, "100 bytes is not a command"),
    ("set/mode", b"cool", "mode: expected heat (auto) or off (manual at 0 %), got 'cool'"),
    ("set/mode", b"manual", "got 'manual'"),
]


def test_a_bad_command_is_refused_nothing_reaches_the_daemon_and_the_bridge_serves_on(
    rig: Rig, caplog: pytest.LogCaptureFixture
) -> None:
    rig.watcher.wait_for(lambda m: m.topic == rig.topics.state)
    before = rig.status()
    for topic, payload, says in BAD_COMMANDS:
        mark = len(rig.watcher.messages)
        rig.command(f"{PREFIX}/{topic}", payload)
        error = rig.watcher.wait_for(lambda m: m.topic == rig.topics.error, mark).json()
        assert error["topic"] == f"{PREFIX}/{topic}"
        assert error["error"].startswith("refused, nothing changed: ")
        assert says in error["error"], payload
        logged = f"mqtt command on {PREFIX}/{topic}: {error['error']}"
        assert logged in caplog.messages, payload
    state = rig.step().json()  # the bridge still publishes each period
    status = rig.status()
    assert (status["setpoint"], status["mode"]) == (before["setpoint"], before["mode"])
    assert (state["setpoint"], state["mode"]) == (before["setpoint"], before["mode"])
    assert operator_lines(rig.events) == []


def test_a_command_the_daemon_refuses_is_published_in_its_words(rig: Rig) -> None:
    """The bridge read its config before the file was edited: it lets 97 °C through, the
    daemon, with its cut-out at 95 °C, refuses it."""
    rig.watcher.wait_for(lambda m: m.topic == rig.topics.state)
    rig.bridge.stop()
    rig.thread.join(TIMEOUT)
    rig.config = read.parse(edited(rig.text, safety__max_temp="100"))
    rig.start_bridge()
    rig.command(rig.topics.set_setpoint, b"97")
    for _ in range(20):  # the daemon answers after the next period boundary
        rig.step()
        if rig.watcher.on(rig.topics.error):
            break
    error = rig.watcher.on(rig.topics.error)[0].json()
    assert error["error"].startswith("refused, nothing changed: control.setpoint: 97 °C")
    assert rig.status()["setpoint"] == 66.0


def test_a_retained_command_is_not_applied_when_the_bridge_connects(rig: Rig) -> None:
    """A retained command would be applied again at every connection: MQTT 3.1.1 marks it
    retained when the bridge subscribes, and the bridge refuses it then."""
    rig.watcher.wait_for(lambda m: m.topic == rig.topics.state)
    rig.bridge.stop()
    rig.thread.join(TIMEOUT)
    rig.command(rig.topics.set_setpoint, b"70", retain=True)
    mark = len(rig.watcher.messages)
    rig.start_bridge()
    error = rig.watcher.wait_for(lambda m: m.topic == rig.topics.error, mark).json()
    assert "a retained command is not applied" in error["error"]
    rig.command(rig.topics.set_setpoint, b"", retain=True)  # cleared, as the error says
    rig.step()
    assert rig.status()["setpoint"] == 66.0
    assert operator_lines(rig.events) == []
    assert len(rig.watcher.on(rig.topics.error, mark)) == 1  # clearing it is not a command


# -- losing the broker and the daemon -------------------------------------------------------


def test_a_broker_restart_is_survived_and_everything_published_again(rig: Rig) -> None:
    discovered(rig.watcher)
    rig.watcher.wait_for(lambda m: m.topic == rig.topics.state)
    rig.watcher.close()
    rig.broker.stop()
    rig.broker.start()  # on the same port, with no retained message left
    rig.watcher = Watcher(rig.broker.port)
    entities = discovered(rig.watcher)  # retained, or live once the bridge is back
    assert len(entities) == ENTITIES
    rig.watcher.wait_for(lambda m: m.topic == rig.topics.availability and m.payload == b"online")
    rig.watcher.wait_for(lambda m: m.topic == rig.topics.state)
    rig.step()  # and the next period's state too
    rig.command(rig.topics.set_setpoint, b"70")  # commands are heard again
    step_until(rig, lambda s: s["setpoint"] == 70)


def test_the_daemon_gone_is_offline_and_back_online_when_it_returns(rig: Rig) -> None:
    rig.watcher.wait_for(lambda m: m.topic == rig.topics.availability and m.payload == b"online")
    mark = len(rig.watcher.messages)
    rig.server.close()
    # "online" goes out twice at the start (the connection's announcement, retained, and the
    # daemon's first answer), in either order: the one after `mark` may be the second.
    rig.watcher.wait_for(
        lambda m: m.topic == rig.topics.availability and m.payload == b"offline", mark
    )
    rig.command(rig.topics.set_setpoint, b"70")
    error = rig.watcher.wait_for(lambda m: m.topic == rig.topics.error).json()
    assert error["error"].startswith("not applied, nothing changed: no hermsd is running")
    rig.server = rig._serve()  # as a daemon started again: it answers after its first period
    run_for(rig.daemon, PERIOD)
    rig.watcher.wait_for(
        lambda m: m.topic == rig.topics.availability and m.payload == b"online", mark
    )
    assert rig.status()["setpoint"] == 66.0


def test_a_killed_bridge_leaves_offline_behind_as_its_last_will(rig: Rig, tmp_path: Path) -> None:
    """`hermsd mqtt` as the service runs it, killed without a word to the broker."""
    config = tmp_path / "bridge.yaml"
    text = (tmp_path / "hermsd.yaml").read_text(encoding="utf-8")
    config.write_text(edited(text, mqtt__topic_prefix="brewery/two"), encoding="utf-8")
    availability = "brewery/two/availability"
    command = [Path(sys.executable).parent / "hermsd", "mqtt", "--config", config]
    process = subprocess.Popen([*command, "--socket", rig.socket], stderr=subprocess.PIPE)
    try:
        rig.watcher.wait_for(lambda m: m.topic == availability and m.payload == b"online")
        mark = len(rig.watcher.messages)
        process.send_signal(signal.SIGKILL)
        # An "online" sent before the kill may still be on its way (the bridge says it when
        # it announces itself to the broker and when the daemon answers): the will is the
        # first other word after the kill.
        will = rig.watcher.wait_for(
            lambda m: m.topic == availability and m.payload != b"online", mark
        )
        assert will.payload == b"offline"
        late = Watcher(rig.broker.port)  # and it stays, retained, for whoever comes later
        kept = late.wait_for(lambda m: m.topic == availability)
        late.close()
        assert (kept.payload, kept.retain) == (b"offline", True)
    finally:
        process.kill()
        process.wait(TIMEOUT)
    assert process.stderr is not None
    assert "bridging" in process.stderr.read().decode()


def test_the_state_names_the_program_step_when_the_daemon_reports_one() -> None:
    """The `program` field of the status (its own branch of the daemon) is optional: absent
    or null, the state says "none"; present, its step, time left and next step show."""
    status = {
        "t": 10.0,
        "tun": "HLT",
        "pv": 66.1,
        "setpoint": 66.0,
        "output": 12.0,
        "applied": 11.0,
        "mode": "auto",
        "manual_output": 0.0,
        "state": "holding",
        "alarms": ["stale"],
        "heater_allowed": False,
    }
    assert state_message(status)["step_text"] == "none"
    assert state_message({**status, "program": None})["program_state"] == "none"
    program = {
        "name": "Step mash",
        "state": "holding",
        "step": {"index": 1, "name": "Saccharification", "setpoint": 66.0},
        "steps": 3,
        "time_left_s": 1234.0,
        "next": "Mash out",
        "message": None,
        "starts_at": None,
        "rest_in_s": None,
    }
    state = state_message({**status, "program": program})
    assert (state["program"], state["step_text"], state["time_left_s"], state["next_step"]) == (
        "Step mash",
        "Saccharification",
        1234.0,
        "Mash out",
    )
    # an alarm holds the heater off: never "heating", whatever the output asked
    assert (state["alarm"], state["alarm_text"], state["action"]) == (True, "stale", "off")
    # the second element heats too: its SSR partner at 0 % is no "idle"
    two = {**status, "alarms": [], "heater_allowed": True, "output": 0.0, "output2": 100.0}
    assert (state_message(two)["action"], state_message(two)["output2"]) == ("heating", 100.0)
    assert state_message({**two, "output2": 0.0})["action"] == "idle"
    # what needs a look but holds no heater off: in its words, or "none"
    assert state_message(status)["warning_text"] == "none"
    warned = {**status, "warnings": ["element 2 gives no heat? (docs/two-elements.md)", "x"]}
    assert state_message(warned)["warning_text"] == (
        "element 2 gives no heat? (docs/two-elements.md); x"
    )


def test_a_running_programs_step_time_left_and_next_step_are_published(rig: Rig) -> None:
    """A program started on the daemon through its socket: the step sensor's field names
    its step, the time left counts down one period a period, the next step follows."""
    pv = rig.status()["pv"]
    setpoint = round(pv + 0.45, 1)  # in band (0.5 °C) at once, and the slow tun stays there
    program = Program(
        "MQTT mash", (Step("Dough-in", setpoint, 600.0), Step("Mash out", setpoint, None))
    )

    at_boundary = rig.at_boundary
    state = at_boundary(ProgramStart(program))
    assert (state["program"], state["step_text"], state["next_step"]) == (
        "MQTT mash",
        "Dough-in",
        "Mash out",
    )
    assert state["time_left_s"] == 600.0  # reached in its first period: the whole hold
    assert state["rest_in_s"] is None  # in the band: no rest to wait for
    later = [rig.step().json()["time_left_s"] for _ in range(2)]
    assert later == [595.0, 590.0]

    state = at_boundary(ProgramAction("next"))
    assert (state["step_text"], state["time_left_s"], state["next_step"]) == (
        "Mash out",
        None,  # held until told
        None,
    )
    state = at_boundary(ProgramAction("stop"))
    assert (state["program"], state["step_text"]) == (None, "none")


def test_while_the_tun_heats_towards_a_step_the_rest_is_published_to_start_in_s(
    rig: Rig,
) -> None:
    """The daemon's estimate of when the rest starts, as its status gives it, each period."""
    pv = rig.status()["pv"]
    program = Program("Warm up", (Step("Rest", round(pv + 20.0), 600.0),))
    state = rig.at_boundary(ProgramStart(program))
    assert state["program_state"] == "heating"
    for _ in range(2):
        state = rig.step().json()
        estimate = rig.status()["program"]["rest_in_s"]  # the loop stands between periods
        assert isinstance(estimate, float) and estimate > 0.0
        assert state["rest_in_s"] == estimate and state["time_left_s"] is None
    state = rig.at_boundary(ProgramAction("stop"))
    assert state["rest_in_s"] is None


def test_a_failing_log_and_an_unsaved_program_progress_are_published(tmp_path: Path) -> None:
    """Both hold no heater off, and both lose what the brewer counts on: Home Assistant
    shows them in the warnings sensor and turns the Warning problem sensor on."""
    state_dir = tmp_path / "state"
    state_dir.mkdir()
    rig = Rig(tmp_path, latches=LatchStore(state_dir))
    try:
        entity = f"homeassistant/binary_sensor/{rig.topics.node_id}/warning/config"
        warning = discovered(rig.watcher)[entity]
        assert warning["value_template"] == "{{ 'ON' if value_json.warning else 'OFF' }}"
        state = rig.step().json()
        assert (state["warning"], state["warning_text"]) == (False, "none")

        rig.events.failing = "writing brew.mcap: [Errno 28] No space left on device"  # type: ignore[attr-defined]
        rig.step()  # the recorder is looked at after the period's state is out
        state = rig.step().json()
        assert state["warning"] is True
        assert state["warnings"] == [
            "log failing (control goes on, this brew is not recorded): "
            "writing brew.mcap: [Errno 28] No space left on device"
        ]

        (state_dir / PROGRESS_FILE).mkdir()  # nothing can be renamed over a directory
        pv = rig.status()["pv"]
        rig.at_boundary(ProgramStart(Program("Saved?", (Step("Rest", round(pv, 1), None),))))
        assert rig.daemon.program.flush(TIMEOUT)
        state = rig.step().json()
        progress, log_failing = state["warnings"]
        assert progress.startswith("program progress not saved (a restart may not resume it): ")
        assert "Is a directory" in progress and log_failing.startswith("log failing")
        assert state["warning"] is True and "program progress not saved" in state["warning_text"]
    finally:
        rig.close()


def test_a_second_bridge_for_the_same_broker_and_client_id_is_refused(
    rig: Rig, capsys: pytest.CaptureFixture[str]
) -> None:
    """Two bridges with one client id would put each other off the broker once a second."""
    rig.watcher.wait_for(lambda m: m.topic == rig.topics.state)
    mark = len(rig.watcher.messages)
    second = Bridge(rig.config, rig.socket, poll=0.02)
    refused: list[BaseException] = []

    def run_second() -> None:
        try:
            second.run()
        except InstanceError as error:
            refused.append(error)

    running = threading.Thread(target=run_second)
    running.start()
    running.join(TIMEOUT)
    second.stop()  # if it did start, it serves no longer
    running.join(TIMEOUT)
    assert refused, "the second bridge ran"
    assert isinstance(refused[0], InstanceError)
    assert refused[0].holder == os.getpid()  # the first bridge runs in this process
    code = main(["mqtt", "--config", str(rig.path), "--socket", str(rig.socket)])
    err = capsys.readouterr().err
    assert code == 2
    assert err == (
        f"hermsd: another hermsd mqtt (pid {os.getpid()}) serves mqtt://localhost:"
        f"{rig.broker.port} as client id hermsd-brewery_hlt: one bridge per broker and client "
        "id (two put each other off the broker); stop that one first, or give this one its "
        "own mqtt.client_id\n"
    )
    # the first is undisturbed: still connected, still publishing each period
    rig.step()
    assert not [m for m in rig.watcher.on(rig.topics.availability, mark) if m.payload != b"online"]
    # and once it stops, a bridge on the same client id starts
    rig.bridge.stop()
    rig.thread.join(TIMEOUT)
    rig.start_bridge()


def test_a_fault_handling_one_message_is_one_line_and_later_ones_are_handled(
    rig: Rig, caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    rig.watcher.wait_for(lambda m: m.topic == rig.topics.state)
    parse, send = bridge_module.parse_command, bridge_module.ask

    def parse_failing(topics: Topics, topic: str, payload: bytes, config: Any) -> Any:
        if payload == b"68":
            raise RuntimeError("a fault\nover two lines")
        return parse(topics, topic, payload, config)

    def ask_failing(path: Path, request: Request, timeout: float) -> dict[str, Any]:
        if request == protocol.SetSetpoint(69.0):
            raise KeyError("v")
        return send(path, request, timeout)

    monkeypatch.setattr(bridge_module, "parse_command", parse_failing)
    monkeypatch.setattr(bridge_module, "ask", ask_failing)
    mark = len(rig.watcher.messages)
    rig.command(rig.topics.set_setpoint, b"68")  # fails as it is taken (paho's thread)
    rig.command(rig.topics.set_setpoint, b"69")  # fails as it is sent (the command thread)
    error = rig.watcher.wait_for(lambda m: m.topic == rig.topics.error, mark).json()
    assert error["error"] == "not handled: KeyError: 'v'"
    rig.command(rig.topics.set_setpoint, b"70")
    step_until(rig, lambda state: state["setpoint"] == 70.0)
    said = [r for r in caplog.records if "not handled" in r.getMessage()]
    assert [r.getMessage() for r in said] == [
        f"mqtt message on {rig.topics.set_setpoint} not handled: RuntimeError: a fault over two "
        "lines",
        f"mqtt command on {rig.topics.set_setpoint}: not handled: KeyError: 'v'",
    ]
    assert all(r.exc_info is None for r in said)  # one line each, no traceback


# -- logging in -----------------------------------------------------------------------------


def test_the_bridge_logs_in_with_the_password_from_its_file(tmp_path: Path) -> None:
    broker = Broker(tmp_path, users={"hermsd": "s3cret 0f the tun", "watcher": "w"})
    broker.start()
    try:
        password = tmp_path / "mqtt-password"
        password.write_text("s3cret 0f the tun\n", encoding="utf-8")
        text = edited(
            BASE,
            mqtt__port=str(broker.port),
            mqtt__username="hermsd",
            mqtt__password_file=str(password),
        )
        config = read.parse(text)
        watcher = Watcher(broker.port, login=("watcher", "w"))
        bridge = Bridge(config, tmp_path / "no.sock", poll=0.02)
        thread = threading.Thread(target=bridge.run)
        thread.start()
        try:
            # let in: it announces itself (offline: no daemon answers on no.sock)
            watcher.wait_for(lambda m: m.topic == "hermsd/availability")
        finally:
            bridge.stop()
            thread.join(TIMEOUT)
            watcher.close()
    finally:
        broker.stop()


@pytest.mark.parametrize(
    ("keys", "says"),
    [
        (
            {"mqtt__username": "hermsd", "mqtt__password_file": "{missing}"},
            "mqtt.password_file {missing}: No such file or directory",
        ),
        (
            {"mqtt__tls": "true", "mqtt__ca_file": "{missing}"},
            "mqtt TLS files {missing}: No such file or directory",
        ),
    ],
)
def test_a_password_or_tls_file_it_cannot_read_is_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], keys: dict[str, str], says: str
) -> None:
    missing = str(tmp_path / "missing")
    config = tmp_path / "hermsd.yaml"
    values = {key: value.format(missing=missing) for key, value in keys.items()}
    config.write_text(edited(BASE, **values), encoding="utf-8")
    assert main(["mqtt", "--config", str(config), "--socket", str(tmp_path / "s")]) == 2
    assert capsys.readouterr().err == f"hermsd: {says.format(missing=missing)}\n"


def test_without_paho_the_command_says_how_to_install_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delitem(sys.modules, "hermsd.mqtt.bridge")
    monkeypatch.setitem(sys.modules, "paho.mqtt.client", None)  # as if not installed
    config = tmp_path / "hermsd.yaml"
    config.write_text(BASE, encoding="utf-8")
    assert main(["mqtt", "--config", str(config)]) == 2
    assert "the MQTT bridge needs paho-mqtt: install hermsd with its mqtt extra" in (
        capsys.readouterr().err
    )


def test_a_second_element_gets_its_own_output_sensor_and_none_without_it() -> None:
    topics = Topics.of(PREFIX, "homeassistant")
    one = dict(discovery_messages(topics, read.parse(BASE)))
    two_text = BASE + "\nelement2:\n  backend: sim\n"
    two = dict(discovery_messages(topics, read.parse(two_text)))
    topic = topics.discovery("sensor", "output2")
    assert one[topic] is None and set(two) == set(one)  # None: sent empty, removes it
    assert {t for t, p in one.items() if p is not None} | {topic} == {
        t for t, p in two.items() if p is not None
    }
    sensor = two[topic]
    assert sensor["unit_of_measurement"] == "%"
    assert sensor["unique_id"] == f"hermsd_{topics.node_id}_output2"
    # its template picks the field the state carries (null without a second element)
    assert sensor["value_template"] == "{{ value_json.output2 }}"
    status = {
        "t": 1.0, "tun": "HLT", "pv": 66.0, "setpoint": 66.0, "output": 0.0, "applied": 0.0,
        "mode": "auto", "manual_output": 0.0, "state": "holding", "alarms": [],
        "heater_allowed": True, "output2": 100.0,
    }  # fmt: skip
    assert state_message(status)["output2"] == 100.0


@pytest.mark.parametrize(("kind", "measured"), [("sim", True), ("ads1115", True), ("gpio", False)])
def test_an_element_current_measured_in_amps_is_a_current_sensor(kind: str, measured: bool) -> None:
    """A current transformer's amps are a sensor of their own; a mains-present optocoupler
    measures none (its entity, and one no input leaves, removed as output2's is)."""
    topics = Topics.of(PREFIX, "homeassistant")
    line = "\n  line: 23" if kind == "gpio" else ""
    fitted = dict(
        discovery_messages(topics, read.parse(f"{BASE}\ncurrent:\n  kind: {kind}{line}\n"))
    )
    none = dict(discovery_messages(topics, read.parse(BASE)))
    topic = topics.discovery("sensor", "element_amps")
    assert none[topic] is None and set(fitted) == set(none)
    sensor = fitted[topic]
    if not measured:
        assert sensor is None
        return
    assert (sensor["device_class"], sensor["unit_of_measurement"]) == ("current", "A")
    assert sensor["value_template"] == "{{ value_json.element_amps }}"
    status = {
        "t": 1.0, "tun": "HLT", "pv": 66.0, "setpoint": 66.0, "output": 50.0, "applied": 50.0,
        "mode": "auto", "manual_output": 0.0, "state": "ok", "alarms": [],
        "heater_allowed": True, "current": {"on": True, "drawing": True, "amps": 13.04},
    }  # fmt: skip
    assert state_message(status)["element_amps"] == 13.04
    assert state_message({**status, "current": None})["element_amps"] is None


@pytest.mark.parametrize(("max_temp", "highest"), [("95", 94.5), ("80.2", 80.0), ("80", 79.5)])
def test_the_thermostat_offers_setpoints_only_below_the_cut_out(
    max_temp: str, highest: float
) -> None:
    config = read.parse(edited(BASE, control__setpoint="60", safety__max_temp=max_temp))
    assert setpoint_range(config) == (0.0, highest)


def test_a_second_stop_signal_inside_the_first_handler_does_not_hang(tmp_path: Path) -> None:
    bridge = Bridge(read.parse(BASE), tmp_path / "no.sock", poll=0.02)
    wake = bridge._wake
    notify = wake.notify_all

    def signal_while_locked() -> None:  # the second SIGTERM lands while the lock is held
        bridge.stop()  # the nested handler
        notify()

    wake.notify_all = signal_while_locked  # type: ignore[method-assign]
    stopping = threading.Thread(target=bridge.stop, daemon=True)
    stopping.start()
    stopping.join(TIMEOUT)
    assert not stopping.is_alive()


def _states_the_loop_sets() -> set[str]:
    """Every value the control period gives `state` (read from its source, so a new one
    cannot go unnoticed)."""
    tree = ast.parse((ROOT / "hermsd" / "runtime" / "daemon.py").read_text(encoding="utf-8"))
    period = next(
        node
        for node in ast.walk(tree)
        if isinstance(node, ast.FunctionDef) and node.name == "_on_control"
    )
    states: set[str] = set()
    for node in ast.walk(period):
        if not isinstance(node, ast.Assign):
            continue
        for target in node.targets:
            value: ast.expr = node.value
            if isinstance(target, ast.Tuple) and isinstance(value, ast.Tuple):
                names = [getattr(element, "id", None) for element in target.elts]
                if "state" not in names:
                    continue
                value = value.elts[names.index("state")]
            elif getattr(target, "id", None) != "state":
                continue
            states |= {
                c.value
                for c in ast.walk(value)
                if isinstance(c, ast.Constant) and isinstance(c.value, str)
            }
    return states


def test_every_state_the_daemon_reports_is_documented_where_the_others_are() -> None:
    states = _states_the_loop_sets()
    assert {"ok", "manual", "alarm", "waiting", "scheduled"} <= states
    row = next(
        line
        for line in (ROOT / "docs" / "mqtt.md").read_text(encoding="utf-8").splitlines()
        if line.startswith("| sensor State |")
    )
    protocol_doc = protocol.__doc__ or ""
    for state in states:
        assert f"`{state}`" in row, state
        assert f'"{state}"' in protocol_doc, state
