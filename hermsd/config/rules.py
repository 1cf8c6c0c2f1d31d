"""The rules across a config's keys and sections, the control laws' own among them.

A Config that passes them is consistent, so the rest of the daemon never checks it again."""

from __future__ import annotations

import dataclasses
import math
import re

import yaml

from hermsd.config.schema import (
    _RESOLVER,
    _SCHEMA,
    _SERIAL_LINES,
    MIDRANGE,
    ROLE_SENSORS,
    Config,
    ContactorConfig,
    ControlConfig,
    Element2Config,
    MqttConfig,
    OutputConfig,
    PumpConfig,
    RoleSensorConfig,
    SensorKeys,
    WebConfig,
    _convert,
    _fmt,
    _Invalid,
    _quote,
    _Violation,
)
from hermsd.control.factory import make_controller, measured_model
from hermsd.control.learning import implausible


def _sensor_violations(sensor: SensorKeys, section: str = "sensor") -> list[_Violation]:
    """What a sensor kind needs of the other keys of its section."""
    id_ = sensor.id
    if sensor.kind == "ds18b20" and id_ is not None and not re.fullmatch(r"28-[0-9a-f]{12}", id_):
        return [
            _Violation(
                (f"{section}.id", f"{section}.kind"),
                f"{_quote(id_)} is not a DS18B20's id (28- and 12 hexadecimal digits, as in "
                "28-0316a2795bff)",
            )
        ]
    if sensor.kind == "lm92" and sensor.offset != 0:
        why = (
            "the LM92's T_CRIT pin compares the chip's own value with safety.max_temp: an "
            "offset would move the two apart"
            if section == "sensor"
            else "hermsd reads an LM92 without one (a ds18b20 or a max31865 takes an offset)"
        )
        return [
            _Violation(
                (f"{section}.offset", f"{section}.kind"),
                f"is not 0, but {why} (leave it at 0)",
                f"{_fmt(sensor.offset)} °C",
            )
        ]
    if sensor.kind == "max31865" and sensor.rref <= sensor.r0:
        return [
            _Violation(
                (f"{section}.rref", f"{section}.r0"),
                f"is not above {section}.r0 ({_fmt(sensor.r0)} Ω): the reference resistor must "
                "exceed the RTD's (430 for a PT100, 4300 for a PT1000)",
                f"{_fmt(sensor.rref)} Ω",
            )
        ]
    return []


def _sensor_identity(sensor: SensorKeys) -> tuple[object, ...]:
    """What tells one sensor from another of its kind: an I2C address, a DS18B20's id (null:
    the only one found, the same for every section that leaves it null), an SPI device."""
    if sensor.kind == "ds18b20":
        return ("ds18b20", sensor.id)
    if sensor.kind == "max31865":
        return ("max31865", sensor.bus, sensor.device)
    return ("lm92", sensor.bus, sensor.address)


_IDENTITY_KEYS = {"lm92": ("bus", "address"), "ds18b20": ("id",), "max31865": ("bus", "device")}


def _role_sensor_violations(config: Config) -> list[_Violation]:
    """The sensors beside the HLT's: each kind's own rules, and no two sections naming one
    device (it would stand for two places at once)."""
    found: list[_Violation] = []
    seen: dict[tuple[object, ...], str] = {_sensor_identity(config.sensor): "sensor"}
    for section in ROLE_SENSORS:
        sensor: RoleSensorConfig = getattr(config, section)
        if not sensor.fitted:
            continue
        found.extend(_sensor_violations(sensor, section))
        identity = _sensor_identity(sensor)
        other = seen.setdefault(identity, section)
        if other != section:
            keys = [f"{section}.{key}" for key in _IDENTITY_KEYS[sensor.kind]]
            which = " and ".join(keys)
            found.append(
                _Violation(
                    (*keys, f"{section}.kind"),
                    f"{section} and {other} name the same {sensor.kind.upper()} ({which} as "
                    f"{other}'s): one device cannot be read in two places (give each its "
                    "own device"
                    + (
                        "; a null id takes the only one found, so name each by its id)"
                        if sensor.kind == "ds18b20"
                        else ")"
                    ),
                )
            )
    return found


def _violations(config: Config) -> list[_Violation]:
    """Every rule between keys that `config` breaks."""
    found: list[_Violation] = []
    control, output, contactor, safety = (
        config.control,
        config.output,
        config.contactor,
        config.safety,
    )

    found.extend(_sensor_violations(config.sensor))
    found.extend(_role_sensor_violations(config))
    if output.window is not None:
        window_key, window, what = (
            "output.window",
            output.window,
            f"the {_fmt(output.window)} s window",
        )
    else:
        window_key, window = "control.period", control.period
        what = f"the {_fmt(window)} s period (the SSR window while output.window is null)"
    pulses = output.min_on + output.min_off
    if window <= pulses:
        found.append(
            _Violation(
                (window_key, "output.min_on", "output.min_off", "output.window"),
                f"{what} is not longer than output.min_on + output.min_off = {_fmt(pulses)} s "
                "(lengthen the window or shorten min_on/min_off)",
            )
        )

    half_cycle = 1 / (2 * output.mains_hz)
    at_least = math.ceil(half_cycle * 1e4) / 1e4
    for name in ("min_on", "min_off"):
        pulse = getattr(output, name)
        if 0 < pulse < half_cycle:
            found.append(
                _Violation(
                    (f"output.{name}", "output.mains_hz"),
                    "is shorter than one mains half-cycle "
                    f"({_fmt(round(half_cycle * 1000, 2))} ms at {output.mains_hz} Hz), the "
                    "shortest pulse a zero-cross SSR delivers "
                    f"(use 0 or at least {_fmt(at_least)})",
                    f"{_fmt(pulse)} s",
                )
            )

    if control.setpoint >= safety.max_temp:
        found.append(
            _Violation(
                ("control.setpoint", "safety.max_temp"),
                "is not below safety.max_temp "
                f"({_fmt(safety.max_temp)} °C), where the over-temperature cut-out switches the "
                f"heater off (set it below {_fmt(safety.max_temp)} °C or raise safety.max_temp)",
                f"{_fmt(control.setpoint)} °C",
            )
        )
    if safety.plausible_min >= safety.plausible_max:
        found.append(
            _Violation(
                ("safety.plausible_min", "safety.plausible_max"),
                f"is not below safety.plausible_max ({_fmt(safety.plausible_max)} °C): the "
                "believable readings run from plausible_min up to plausible_max (lower "
                "plausible_min or raise plausible_max)",
                f"{_fmt(safety.plausible_min)} °C",
            )
        )
    if safety.max_temp >= safety.plausible_max:
        found.append(
            _Violation(
                ("safety.max_temp", "safety.plausible_max"),
                f"is not below safety.plausible_max ({_fmt(safety.plausible_max)} °C), so an "
                "overheat would read as a broken sensor (lower max_temp or raise plausible_max)",
                f"{_fmt(safety.max_temp)} °C",
            )
        )
    if safety.stale_after is not None and safety.stale_after <= config.sensor.read_interval:
        found.append(
            _Violation(
                ("safety.stale_after", "sensor.read_interval"),
                "is not longer than sensor.read_interval "
                f"({_fmt(config.sensor.read_interval)} s), so every reading would go stale "
                f"before the next (make it a few read intervals, e.g. "
                f"{_fmt(3 * config.sensor.read_interval)})",
                f"{_fmt(safety.stale_after)} s",
            )
        )
    if control.manual_output > control.max_output:
        found.append(
            _Violation(
                ("control.manual_output", "control.max_output"),
                f"is above control.max_output ({_fmt(control.max_output)} %) (lower "
                "manual_output or raise max_output)",
                f"{_fmt(control.manual_output)} %",
            )
        )

    for section, device in (
        ("output", output),
        ("contactor", contactor),
        ("element2", config.element2),
        ("pump", config.pump),
    ):
        if device.backend == "gpio" and device.line is None:
            found.append(
                _Violation(
                    (f"{section}.backend", f"{section}.line"),
                    f"the gpio backend needs {section}.line, the line offset on {device.chip} "
                    f"(add 'line: 17' under {section}: for GPIO17, with your line number)",
                )
            )
    if output.backend in _SERIAL_LINES and output.port == contactor.port:
        if contactor.backend == output.backend:
            found.append(
                _Violation(
                    ("contactor.backend", "contactor.port", "output.backend", "output.port"),
                    "the contactor and the SSR output would both switch the "
                    f"{output.backend.removeprefix('serial-').upper()} line of {output.port} "
                    "(give the contactor its own port, or the other line of this one)",
                )
            )
        elif contactor.backend == "relay-board":
            found.append(
                _Violation(
                    ("contactor.backend", "contactor.port", "output.backend", "output.port"),
                    f"the relay board needs {output.port} to itself, but the SSR output switches "
                    f"a line of it (give the relay board its own port)",
                )
            )
    if (
        output.backend == contactor.backend == "gpio"
        and output.line is not None
        and (output.chip, output.line) == (contactor.chip, contactor.line)
    ):
        found.append(
            _Violation(
                (
                    "contactor.line",
                    "contactor.chip",
                    "output.line",
                    "output.chip",
                    "output.backend",
                ),
                f"the contactor and the SSR output would both drive line {output.line} of "
                f"{output.chip} (give the contactor its own line)",
            )
        )
    found.extend(_element2_violations(config))
    found.extend(_pump_violations(config))
    found.extend(_current_violations(config))
    found.extend(_controller_violations(control))
    measured = measured_model(config)
    why = implausible(measured) if measured is not None else None
    if why is not None:
        found.append(
            _Violation(
                ("control.model_litres", *(f"control.{key}" for key in _MODEL_KEYS)),
                f"the measured tun (model_litres set) cannot be a water tun: {why} (set "
                "model_litres to null, or write the model again with `hermsd tune --write`)",
            )
        )
    found.extend(_mqtt_violations(config.mqtt))
    found.extend(_web_violations(config.web))
    return found


def split_listen(text: str) -> tuple[str, int] | None:
    """`web.listen`'s host and port (`127.0.0.1:8080`, `[::1]:8080`), or None if malformed."""
    host, colon, port = text.rpartition(":")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    if not colon or not host or not port.isdigit() or not 1 <= int(port) <= 65535:
        return None
    return host, int(port)


def _web_violations(web: WebConfig) -> list[_Violation]:
    from hermsd.web.passwords import EXAMPLE, parse_hash

    found: list[_Violation] = []
    if split_listen(web.listen) is None:
        found.append(
            _Violation(
                ("web.listen",),
                f"{_quote(web.listen)} is not HOST:PORT (e.g. 127.0.0.1:8080, or 0.0.0.0:8080 "
                "for every interface; a port 1 to 65535)",
            )
        )
    if web.password_hash is not None and parse_hash(web.password_hash) is None:
        found.append(
            _Violation(("web.password_hash",), f"not a password hash (expected {EXAMPLE})")
        )
    for name in web.allowed_hosts or ():
        if not _HOST_NAME.fullmatch(name):
            found.append(
                _Violation(
                    ("web.allowed_hosts",),
                    f"{_quote(name)} is not a host name (a name alone, no scheme or port: "
                    "e.g. brew.example.org, or *.example.org for every name under it; IP "
                    "addresses need no entry)",
                )
            )
    return found


_HOST_NAME = re.compile(r"(\*\.)?[A-Za-z0-9_-]+(\.[A-Za-z0-9_-]+)*\.?")


_Switched = OutputConfig | ContactorConfig | Element2Config | PumpConfig


def _device(section: _Switched) -> tuple[object, ...]:
    """What a section's switch occupies: a serial port (a relay board or a line of it), or a
    gpio line; two sections that occupy the same thing would drive one device."""
    if section.backend == "gpio":
        return ("gpio", section.chip, section.line)
    if section.backend == "relay-board":
        return ("serial", section.port, "relay", getattr(section, "channel", None))
    return ("serial", section.port, section.backend)


def _element2_violations(config: Config) -> list[_Violation]:
    """The second element: the mid-ranging controller only with one (any other controller
    drives the total of both), on a device of its own, its minimum times whole periods at
    least (it switches at periods)."""
    element2, control = config.element2, config.control
    found = []
    fitted = element2.backend != "none"
    if not fitted and control.algorithm == MIDRANGE:
        found.append(
            _Violation(
                ("control.algorithm", "element2.backend"),
                f"control.algorithm {control.algorithm} with element2.backend "
                f"{element2.backend}: the mid-ranging controller drives two elements (give "
                "element2 a backend, or choose another algorithm)",
            )
        )
    if not fitted:
        return found
    for name in ("min_on", "min_off"):
        value = getattr(element2, name)
        if value < control.period:
            found.append(
                _Violation(
                    (f"element2.{name}", "control.period"),
                    f"is shorter than control.period ({_fmt(control.period)} s); the second "
                    f"element switches only at periods (make it at least {_fmt(control.period)})",
                    f"{_fmt(value)} s",
                )
            )
    found.extend(_shared_devices(config, "element2", ("output", "contactor")))
    return found


def _shared_devices(config: Config, name: str, others: tuple[str, ...]) -> list[_Violation]:
    """The output section `name` on a device one of `others` drives already."""
    section: _Switched = getattr(config, name)
    found = []
    mine = _device(section)
    for other_name in others:
        other: _Switched = getattr(config, other_name)
        if other.backend in ("none", "sim") or section.backend == "sim":
            continue
        theirs = _device(other)
        if mine[:2] != theirs[:2]:
            continue
        relays = ("relay" in mine, "relay" in theirs)
        if mine[2:] == theirs[2:] or relays[0] != relays[1]:
            where = f"line {section.line} of {section.chip}" if mine[0] == "gpio" else mine[1]
            found.append(
                _Violation(
                    (f"{name}.backend", f"{name}.port", f"{name}.line", f"{name}.channel"),
                    f"{name} and {other_name} would both drive {where} (give {name} its "
                    "own port, line or relay channel; a relay board needs its port to itself)",
                )
            )
    return found


def _pump_violations(config: Config) -> list[_Violation]:
    """The pump on a device of its own; its sense only for a pump hermsd does not switch (a
    switched pump is known by its switch, and two accounts of it would need a rule for when
    they disagree), a gpio sense with its line, on a line no output drives."""
    pump = config.pump
    found = []
    if pump.backend != "none":
        found.extend(_shared_devices(config, "pump", ("output", "contactor", "element2")))
    if pump.sense == "none":
        return found
    if pump.backend != "none":
        found.append(
            _Violation(
                ("pump.sense", "pump.backend"),
                f"a pump sense with pump.backend {pump.backend}: hermsd knows the pump it "
                "switches, the sense is for a pump it does not (set sense: none, or "
                "backend: none for a pump switched by hand)",
            )
        )
    if pump.sense == "gpio" and pump.sense_line is None:
        found.append(
            _Violation(
                ("pump.sense", "pump.sense_line"),
                f"the gpio sense needs pump.sense_line, the input line's offset on "
                f"{pump.sense_chip} (add 'sense_line: 27' under pump: for GPIO27, with your "
                "line number)",
            )
        )
    elif pump.sense == "gpio":
        keys = ("pump.sense_line", "pump.sense_chip")
        line, chip = pump.sense_line, pump.sense_chip
        found += _input_on_an_output(config, "the pump sense", keys, line, chip)
    return found


def _input_on_an_output(
    config: Config, what: str, keys: tuple[str, str], line: int | None, chip: str
) -> list[_Violation]:
    """`what`'s input line (`keys`: its line's and chip's) that an output drives."""
    outputs = ("output", "contactor", "element2", "pump")
    found = []
    for name in outputs:
        other: _Switched = getattr(config, name)
        if other.backend == "gpio" and (other.chip, other.line) == (chip, line):
            found.append(
                _Violation(
                    keys,
                    f"line {line} of {chip} is {name}'s output: {what} needs an input line of "
                    "its own",
                )
            )
    return found


def _current_violations(config: Config) -> list[_Violation]:
    """The element's current input: a gpio one with its line, on a line no output drives; an
    ADS1115 at an address no I2C sensor on its bus answers at."""
    current = config.current
    found = []
    if current.kind == "gpio" and current.line is None:
        found.append(
            _Violation(
                ("current.kind", "current.line"),
                f"the gpio current input needs current.line, the optocoupler's input line on "
                f"{current.chip} (add 'line: 23' under current: for GPIO23, with your line)",
            )
        )
    elif current.kind == "gpio":
        keys = ("current.line", "current.chip")
        found += _input_on_an_output(config, "the current input", keys, current.line, current.chip)
    if current.kind == "ads1115":
        for name in ("sensor", *ROLE_SENSORS):
            sensor: SensorKeys = getattr(config, name)
            if sensor.kind == "lm92" and (sensor.bus, sensor.address) == (
                current.bus,
                current.address,
            ):
                found.append(
                    _Violation(
                        ("current.address", "current.bus"),
                        f"address {current.address:#04x} on I2C bus {current.bus} is {name}'s "
                        "LM92: the ADS1115 needs an address of its own (its ADDR pin to GND "
                        "0x48, VDD 0x49, SDA 0x4A, SCL 0x4B)",
                    )
                )
    return found


_MODEL_KEYS = ("model_gain", "model_tau", "dead_time", "model_ambient")


def _mqtt_violations(mqtt: MqttConfig) -> list[_Violation]:
    """A topic prefix MQTT would refuse or misread, and TLS or login keys left without the
    key they go with."""
    found = []
    for name in ("topic_prefix", "discovery_prefix"):
        prefix: str = getattr(mqtt, name)
        wrong = topic_prefix_problem(prefix)
        if wrong:
            found.append(_Violation((f"mqtt.{name}",), f"{_quote(prefix)} {wrong}"))
    if mqtt.password_file is not None and mqtt.username is None:
        found.append(
            _Violation(
                ("mqtt.password_file", "mqtt.username"),
                "a password goes with a user name (add mqtt.username, or remove the password)",
            )
        )
    for name in ("ca_file", "cert_file", "key_file"):
        if getattr(mqtt, name) is not None and not mqtt.tls:
            found.append(
                _Violation(
                    (f"mqtt.{name}", "mqtt.tls"),
                    "is used only over TLS (set mqtt.tls: true, or remove it)",
                )
            )
    if mqtt.key_file is not None and mqtt.cert_file is None:
        found.append(
            _Violation(
                ("mqtt.key_file", "mqtt.cert_file"),
                "a client key goes with its certificate (add mqtt.cert_file)",
            )
        )
    return found


def topic_prefix_problem(prefix: str) -> str | None:
    """What makes `prefix` unfit to start MQTT topic names, or None when it is fit."""
    if "+" in prefix or "#" in prefix:
        return "holds a wildcard, + or # (use letters, digits, - and _, levels split by /)"
    if prefix.startswith("$"):
        return "starts with $, which brokers keep for themselves (e.g. 'hermsd')"
    if "" in prefix.split("/"):
        return "has an empty level: a / at either end or two together (e.g. 'brewery/hlt')"
    return None


def _controller_violations(control: ControlConfig) -> list[_Violation]:
    """The algorithm's own rules on its parameters (tt only for back_calculation, …)."""
    try:
        make_controller(control)
    except ValueError as error:
        named = str(error).split("=", 1)[0]
        key = f"control.{named}" if named in _CONTROL_PARAMETERS else "control.algorithm"
        return [_Violation((key, "control.algorithm"), f"{error} (algorithm {control.algorithm})")]
    return []


_CONTROL_PARAMETERS = (
    "kc",
    "ti",
    "td",
    "tf",
    "tt",
    *("k1", "ti1", "tt1", "k2", "ti2", "tt2", "ks", "u1_ref", "u2_min", "u2_max"),
)


def broken_rules(config: Config) -> list[str]:
    """The rules between keys that `config` breaks, as 'key: what is wrong' lines."""
    return [f"{v.keys[0]}: {v.said(v.keys[0])}" for v in _violations(config)]


def runtime_problems(running: Config, changes: dict[str, object]) -> list[str]:
    """Why an operator's runtime change of keys cannot apply to `running`; [] when it can.

    Each value is checked as the file's would be (the same bounds, choices and messages),
    then the rules across keys with every other value as in `running` (the config with the
    values in force). 'key: what is wrong (what would be right)' lines.
    """
    problems: list[str] = []
    values: dict[str, dict[str, object]] = {}
    for path, value in changes.items():
        section, name = path.split(".")
        try:
            checked = _convert(_SCHEMA[section][name], _runtime_node(value))
        except _Invalid as error:
            problems.append(f"{path}: {error}")
            continue
        values.setdefault(section, {})[name] = checked
    if problems:
        return problems
    candidate = dataclasses.replace(
        running,
        **{
            section: dataclasses.replace(getattr(running, section), **fields)
            for section, fields in values.items()
        },
    )
    return broken_rules(candidate)


def _runtime_node(value: object) -> yaml.ScalarNode:
    """A value given at runtime as the file would hold it: a number plain, text quoted."""
    style = "'" if isinstance(value, str) else None
    text = (
        value if isinstance(value, str) else _fmt(value) if isinstance(value, float) else str(value)
    )
    implicit = (style is None, style is not None)
    tag = _RESOLVER.resolve(yaml.ScalarNode, text, implicit)  # type: ignore[no-untyped-call]
    return yaml.ScalarNode(tag, text, style=style)
