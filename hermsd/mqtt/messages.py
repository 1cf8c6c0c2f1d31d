"""What the MQTT bridge says and hears: its topics, Home Assistant's discovery messages, the
state it publishes, and the commands it takes. Pure: no network, no clock.

Modes, and why they are mapped so. hermsd has two modes: auto (the loop holds the setpoint)
and manual (a fixed output). Home Assistant's climate entity has HVAC modes. The honest fit:

- auto is "heat": the tun is heated to the target, and has nothing to cool it;
- manual at 0 % is "off": the element stays off;
- manual above 0 % is "heat" too: the element is heating, and Home Assistant must never show
  "off" while it is. The state's `mode_text` ("manual at 40 %") and the mode sensor say which.

Commands can only make the tun safer or put it back under the loop: "heat" asks for auto
(the loop takes over bumplessly and holds the running setpoint, within the supervisor's
limits), "off" asks for manual at 0 %. A manual output above 0 % is not offered over MQTT:
a fixed duty nobody watches heats until the supervisor's cut-out, which is the last line,
not the plan. A setpoint is checked by the config's own rules here, before it is sent, and
again by the daemon.

A HERMS's mash side: the mash sensor's reading is a temperature sensor of its own, and the
pump a switch ("ON" runs it, "OFF" stops it, as `hermsd set pump on|off`), each announced
only when the config fits it. With a mash sensor the setpoint is the mash's: the thermostat
shows the mash's temperature against it and sets it, and two sensors show what the outer
loop chose for the HLT (its setpoint, and its phase).
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from typing import Any

from hermsd import __version__
from hermsd.api import protocol
from hermsd.api.protocol import SetMode, SetPump, SetSetpoint
from hermsd.config import read, rules
from hermsd.config.schema import Config
from hermsd.mqtt import brewday
from hermsd.runtime.mash_side import pump_refusal

ONLINE = "online"
OFFLINE = "offline"
TEMP_STEP = 0.5  # °C: the climate card's step; brewers set 66, 67.5, 72
MAX_PAYLOAD = 64  # bytes: a setpoint or a mode is a few; more is not a command
TEXT_STATE_LIMIT = 255  # characters Home Assistant keeps in a sensor's state
_NUMBER = re.compile(r"[-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][-+]?[0-9]+)?")
HA_MODES = {"heat": SetMode("auto"), "off": SetMode("manual", 0.0)}
PUMP_PAYLOADS = {"ON": SetPump(True), "OFF": SetPump(False)}  # the switch's, HA's defaults

Command = protocol.Command


class Refused(ValueError):
    """A command that is not applied; the message says what is wrong (what would be right)."""


@dataclass(frozen=True, slots=True)
class Topics:
    """Every topic of one tun, from the config's two prefixes (`Topics.of`)."""

    prefix: str
    discovery_prefix: str
    node_id: str  # the prefix as Home Assistant spells node ids: [a-zA-Z0-9_-]
    state: str
    availability: str
    set_setpoint: str
    set_mode: str
    set_pump: str
    error: str
    home_assistant_status: str  # its birth and last will: "online" when it (re)starts

    @classmethod
    def of(cls, prefix: str, discovery_prefix: str) -> Topics:
        return cls(
            prefix=prefix,
            discovery_prefix=discovery_prefix,
            node_id=re.sub(r"[^a-zA-Z0-9_-]", "_", prefix),
            state=f"{prefix}/state",
            availability=f"{prefix}/availability",
            set_setpoint=f"{prefix}/set/setpoint",
            set_mode=f"{prefix}/set/mode",
            set_pump=f"{prefix}/set/pump",
            error=f"{prefix}/error",
            home_assistant_status=f"{discovery_prefix}/status",
        )

    def discovery(self, component: str, object_id: str) -> str:
        return f"{self.discovery_prefix}/{component}/{self.node_id}/{object_id}/config"


PUMP_TEMPLATE = "{{ 'ON' if value_json.pump or value_json.pump_start_in is not none else 'OFF' }}"
"""The pump switch's state: on while it runs and while hermsd prepares its start."""


def state_message(status: dict[str, Any]) -> dict[str, Any]:
    """The retained state, from a `status` reply: the daemon's fields, the program's (null
    when none runs, or when the daemon has no programs), and the words Home Assistant shows,
    made here so that its templates only pick a field."""
    mode, manual = status["mode"], status["manual_output"]
    climate_mode = "off" if mode == "manual" and manual == 0 else "heat"
    if climate_mode == "off" or not status["heater_allowed"]:
        action = "off"
    else:
        # The second element (status output2, null without one) heats as well as the SSR's.
        heating = status["output"] > 0 or (status.get("output2") or 0.0) > 0
        action = "heating" if heating else "idle"
    alarms = [str(alarm) for alarm in status["alarms"]]
    program = status.get("program")
    program = program if isinstance(program, dict) else {}
    step = program.get("step")
    step = step if isinstance(step, dict) else {}
    mash = status.get("mash")
    mash = mash if isinstance(mash, dict) else {}
    current = status.get("current")
    current = current if isinstance(current, dict) else {}
    return {
        "t": status["t"],
        "tun": status["tun"],
        "pv": status["pv"],
        "setpoint": status["setpoint"],
        "output": status["output"],
        "output2": status.get("output2"),
        "applied": status["applied"],
        "mode": mode,
        "manual_output": manual,
        "mode_text": "auto" if mode == "auto" else f"manual at {manual:g} %",
        "state": status["state"],
        "heater_allowed": status["heater_allowed"],
        "alarms": alarms,
        "alarm": bool(alarms),
        "alarm_text": (", ".join(alarms) or "none")[:TEXT_STATE_LIMIT],
        "warning": bool(status.get("warnings")),
        "warnings": list(status.get("warnings") or []),
        "warning_text": ("; ".join(status.get("warnings") or []) or "none")[:TEXT_STATE_LIMIT],
        "climate_mode": climate_mode,
        "action": action,
        "program": program.get("name"),
        "program_state": program.get("state", "none"),
        "step": step.get("name"),
        "step_text": str(step.get("name", "none"))[:TEXT_STATE_LIMIT],
        "time_left_s": program.get("time_left_s"),
        "rest_in_s": program.get("rest_in_s"),
        "next_step": program.get("next"),
        "message": program.get("message"),
        "mash": mash.get("celsius"),
        "hlt_setpoint": mash.get("hlt_setpoint"),
        "mash_phase": mash.get("phase") or "none",
        "pump": status.get("pump"),
        "pump_start_in": mash.get("pump_start_in"),
        "pump_turn_in": mash.get("pump_turn_in"),
        "element_amps": current.get("amps"),
        **brewday.state_fields(program or None),
    }


def encode(message: dict[str, Any]) -> bytes:
    return json.dumps(message, allow_nan=False, ensure_ascii=False, sort_keys=True).encode()


def setpoint_range(config: Config) -> tuple[float, float]:
    """The setpoints taken over MQTT, the climate card's range: the config's bounds for a
    setpoint, up to the last step below the over-temperature cut-out (the setpoint must stay
    under it). The one source of both: a command outside what the card offers is refused."""
    low, high = read.key_range("control.setpoint")
    below_cut_out = (config.safety.max_temp - 1e-9) // TEMP_STEP * TEMP_STEP
    return low, min(high, below_cut_out)


def discovery_messages(
    topics: Topics, config: Config, programs: list[str] | None = None
) -> list[tuple[str, dict[str, Any] | None]]:
    """(topic, payload) of each entity Home Assistant should make for this tun: a climate
    entity, sensors (the second element's duty when it is fitted; with a mash sensor the
    mash's temperature, the HLT's setpoint the outer loop chose and its phase), the pump's
    switch and its timer's next turn when one is fitted (a binary sensor when hermsd only
    sees it: `pump.sense`), and
    binary sensors on while an alarm stands and while a warning does (the log or a save
    failing), and the brew day's
    (hermsd/mqtt/brewday.py; `programs`: the program folder's files). A payload of None is
    an entity this config has not: sent empty, it removes one an earlier config made."""
    node = topics.node_id
    device = {
        "identifiers": [f"hermsd_{node}"],
        "name": f"hermsd {config.tun.name}",
        "manufacturer": "hermsd",
        "model": "HERMS Hot Liquor Tank controller",
        "sw_version": __version__,
    }
    low, high = setpoint_range(config)

    def entity(object_id: str, name: str | None, **fields: Any) -> dict[str, Any]:
        return {
            "name": name,
            "unique_id": f"hermsd_{node}_{object_id}",
            "device": device,
            "origin": {"name": "hermsd", "sw_version": __version__},
            "availability_topic": topics.availability,
            "payload_available": ONLINE,
            "payload_not_available": OFFLINE,
            **fields,
        }

    def sensor(object_id: str, name: str, field: str, **fields: Any) -> tuple[str, Any]:
        return topics.discovery("sensor", object_id), entity(
            object_id,
            name,
            state_topic=topics.state,
            value_template=f"{{{{ value_json.{field} }}}}",
            **fields,
        )

    def problem(field: str, name: str) -> tuple[str, Any]:
        """A binary sensor of the problem class, on while the state's `field` is true."""
        return topics.discovery("binary_sensor", field), entity(
            field,
            name,
            state_topic=topics.state,
            value_template=f"{{{{ 'ON' if value_json.{field} else 'OFF' }}}}",
            payload_on="ON",
            payload_off="OFF",
            device_class="problem",
        )

    percent = {"unit_of_measurement": "%", "state_class": "measurement"}
    celsius = {
        "device_class": "temperature",
        "unit_of_measurement": "°C",
        "state_class": "measurement",
    }
    # A second element's duty is a sensor of its own; without one, its topic gets an empty
    # payload, which removes the entity a config with one left retained on the broker.
    element2 = (
        sensor("output2", "Element 2 output", "output2", **percent)
        if config.element2.backend != "none"
        else (topics.discovery("sensor", "output2"), None)
    )
    # The element's current where a current transformer measures it (not a mains-present
    # optocoupler, which says no amps): removed as element2's is where none is.
    amps = (
        sensor(
            "element_amps",
            "Element current",
            "element_amps",
            device_class="current",
            unit_of_measurement="A",
            state_class="measurement",
            suggested_display_precision=1,
        )
        if config.current.kind in ("ads1115", "sim")
        else (topics.discovery("sensor", "element_amps"), None)
    )
    herms = config.mash_sensor.fitted
    mash_side = [
        sensor(object_id, name, field, **fields)
        if herms
        else (topics.discovery("sensor", object_id), None)
        for object_id, name, field, fields in (
            ("mash", "Mash temperature", "mash", {"suggested_display_precision": 1, **celsius}),
            (
                "hlt_setpoint",
                "HLT setpoint (outer loop)",
                "hlt_setpoint",
                {"suggested_display_precision": 1, **celsius},
            ),
            ("mash_phase", "Mash phase", "mash_phase", {}),
        )
    ]
    pump = (
        topics.discovery("switch", "pump"),
        entity(
            "pump",
            "Pump",
            state_topic=topics.state,
            # On from the command: a start prepared (the coil's load sent ahead) is asked on.
            value_template=PUMP_TEMPLATE,
            command_topic=topics.set_pump,
            payload_on="ON",
            payload_off="OFF",
            icon="mdi:pump",
            qos=1,
        )
        if config.pump.backend != "none"
        else None,
    )
    # The program's pump timer (`pump_off_every`): s until it next turns the pump.
    pump_timer = (
        sensor(
            "pump_turn_in",
            "Pump timer: next turn in",
            "pump_turn_in",
            device_class="duration",
            unit_of_measurement="s",
            suggested_display_precision=0,
        )
        if config.pump.backend != "none"
        else (topics.discovery("sensor", "pump_turn_in"), None)
    )
    # A pump hermsd does not switch but sees (pump.sense): its state, read-only.
    pump_seen = (
        topics.discovery("binary_sensor", "pump_seen"),
        entity(
            "pump_seen",
            "Pump",
            state_topic=topics.state,
            value_template="{{ 'ON' if value_json.pump else 'OFF' }}",
            payload_on="ON",
            payload_off="OFF",
            device_class="running",
            icon="mdi:pump",
        )
        if config.pump.backend == "none" and config.pump.sense != "none"
        else None,
    )
    return [
        (
            topics.discovery("climate", "tun"),
            entity(
                "tun",
                None,  # the device's own name
                current_temperature_topic=topics.state,
                # with a mash sensor the setpoint is the mash's: the card shows the mash
                current_temperature_template=f"{{{{ value_json.{'mash' if herms else 'pv'} }}}}",
                temperature_state_topic=topics.state,
                temperature_state_template="{{ value_json.setpoint }}",
                temperature_command_topic=topics.set_setpoint,
                mode_state_topic=topics.state,
                mode_state_template="{{ value_json.climate_mode }}",
                mode_command_topic=topics.set_mode,
                modes=list(HA_MODES),
                action_topic=topics.state,
                action_template="{{ value_json.action }}",
                min_temp=low,
                max_temp=high,
                temp_step=TEMP_STEP,
                precision=0.1,
                temperature_unit="C",
                qos=1,
            ),
        ),
        sensor("temperature", "Temperature", "pv", suggested_display_precision=2, **celsius),
        sensor("output", "Output", "output", **percent),
        sensor("applied", "Applied", "applied", **percent),
        element2,
        amps,
        *mash_side,
        pump,
        pump_timer,
        sensor("mode", "Mode", "mode_text"),
        sensor("state", "State", "state"),
        sensor("step", "Program step", "step_text"),
        sensor(
            "time_left",
            "Step time left",
            "time_left_s",
            device_class="duration",
            unit_of_measurement="s",
        ),
        sensor(
            "rest_in",
            "Rest starts in",
            "rest_in_s",
            device_class="duration",
            unit_of_measurement="s",
            suggested_display_precision=0,
        ),
        sensor("alarms", "Alarms", "alarm_text"),
        sensor("warnings", "Warnings", "warning_text"),
        *brewday.discovery(
            brewday.BrewdayTopics.of(topics.prefix),
            topics.discovery,
            entity,
            topics.state,
            programs,
        ),
        pump_seen,  # with the other binary sensors, the alarm's last (a broker's retained order)
        problem("warning", "Warning"),
        problem("alarm", "Alarm"),
    ]


def parse_command(topics: Topics, topic: str, payload: bytes, config: Config) -> Command:
    """The command a message on a command topic holds, checked as strictly as the config
    file checks the key it sets; Refused says what is wrong and what would be right."""
    if len(payload) > MAX_PAYLOAD:
        raise Refused(f"{len(payload)} bytes is not a command (a number or a mode: a few bytes)")
    try:
        text = payload.decode("utf-8").strip()
    except UnicodeDecodeError:
        raise Refused("the payload is not UTF-8 text") from None
    if topic == topics.set_setpoint:
        if not _NUMBER.fullmatch(text):
            raise Refused(f"setpoint: expected a number in °C such as 66.5, got {text!r}")
        celsius = float(text)
        command: Command = SetSetpoint(celsius)
        problems = rules.runtime_problems(config, {"control.setpoint": celsius})
        low, high = setpoint_range(config)
        if not problems and not low <= celsius <= high:
            problems = [
                f"setpoint: {celsius:g} °C is outside the thermostat's range, {low:g} to "
                f"{high:g} °C (the config's bounds, in {TEMP_STEP:g} °C steps below "
                f"safety.max_temp {config.safety.max_temp:g} °C)"
            ]
    elif topic == topics.set_mode:
        if text not in HA_MODES:
            raise Refused(f"mode: expected heat (auto) or off (manual at 0 %), got {text!r}")
        command = HA_MODES[text]
        changes: dict[str, object] = {"control.mode": command.mode}
        if command.output is not None:
            changes["control.manual_output"] = command.output
        problems = rules.runtime_problems(config, changes)
    elif topic == topics.set_pump:
        if text not in PUMP_PAYLOADS:
            raise Refused(f"pump: expected ON (run it) or OFF (stop it), got {text!r}")
        command = PUMP_PAYLOADS[text]
        problems = [pump_refusal(config)] if config.pump.backend == "none" else []
    else:
        raise Refused(
            f"{topic} is not a command topic ({topics.set_setpoint}, {topics.set_mode} or "
            f"{topics.set_pump})"
        )
    if problems:
        raise Refused("; ".join(problems))
    return command
