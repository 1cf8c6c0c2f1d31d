"""The HERMS's sections of the config: the sensors by role (`mash_sensor`, `coil_sensor`),
the pump's output (`pump`) and `herms`; a file written before them reads as it did."""

from __future__ import annotations

from pathlib import Path

import pytest

from hermsd.config.read import parse
from hermsd.config.schema import ConfigError, RoleSensorConfig, SensorConfig

OLD_FILE = (
    "sensor:\n  bus: 1\n  address: 0x49\n  read_interval: 2\n  kind: lm92\n"
    "output:\n  backend: sim\n"
)


def problems(text: str) -> list[str]:
    with pytest.raises(ConfigError) as caught:
        parse(text, "hermsd.yaml")
    return [str(problem) for problem in caught.value.problems]


def test_a_file_with_the_hlt_s_sensor_alone_reads_as_before() -> None:
    config = parse(OLD_FILE)
    assert config.sensor == SensorConfig(bus=1, address=0x49, read_interval=2.0, kind="lm92")
    assert not config.mash_sensor.fitted and not config.coil_sensor.fitted
    assert config.pump.backend == "none"
    assert config.herms.max_hlt_above_mash == 10.0


@pytest.mark.parametrize(
    "text",
    [
        "mash_sensor:\n  kind: lm92\n  address: 0x49\n",
        "mash_sensor:\n  kind: ds18b20\n  id: 28-0316a2795bff\n  offset: -0.3\n",
        "coil_sensor:\n  kind: max31865\n  r0: 1000\n  rref: 4300\n  wires: 4\n",
        # Two DS18B20 beside an LM92: each named by its id.
        "mash_sensor:\n  kind: ds18b20\n  id: 28-0316a2795bff\n"
        "coil_sensor:\n  kind: ds18b20\n  id: 28-000000000001\n",
        # Two MAX31865 on the two chip selects of one bus.
        "mash_sensor:\n  kind: max31865\n  bus: 0\ncoil_sensor:\n  kind: max31865\n  bus: 0\n"
        "  device: 1\n",
    ],
    ids=["lm92", "ds18b20", "max31865", "two-ds18b20", "two-max31865"],
)
def test_a_sensor_of_any_kind_may_sit_in_a_role(text: str) -> None:
    config = parse(text)
    assert config.mash_sensor.fitted or config.coil_sensor.fitted
    assert config.sensor == SensorConfig()


def test_a_role_sensor_takes_the_keys_of_sensor_but_the_read_interval() -> None:
    [problem] = problems("mash_sensor:\n  kind: ds18b20\n  read_interval: 2\n")
    assert problem.startswith("hermsd.yaml:3:3: mash_sensor.read_interval: unknown key")
    assert "it belongs in the 'sensor' section" in problem


@pytest.mark.parametrize(
    ("text", "said"),
    [
        (
            "mash_sensor:\n  kind: lm92\n  address: 0x48\n",
            "hermsd.yaml:3:12: mash_sensor.address: mash_sensor and sensor name the same LM92 "
            "(mash_sensor.bus and mash_sensor.address as sensor's): one device cannot be read "
            "in two places (give each its own device)",
        ),
        (
            "sensor:\n  kind: ds18b20\nmash_sensor:\n  kind: ds18b20\n",
            "hermsd.yaml:4:9: mash_sensor.kind: mash_sensor and sensor name the same DS18B20 "
            "(mash_sensor.id as sensor's): one device cannot be read in two places (give each "
            "its own device; a null id takes the only one found, so name each by its id)",
        ),
        (
            "mash_sensor:\n  kind: max31865\n  device: 1\n"
            "coil_sensor:\n  kind: max31865\n  device: 1\n",
            "hermsd.yaml:6:11: coil_sensor.device: coil_sensor and mash_sensor name the same "
            "MAX31865 (coil_sensor.bus and coil_sensor.device as mash_sensor's): one device "
            "cannot be read in two places (give each its own device)",
        ),
    ],
    ids=["lm92-as-the-hlt-s", "ds18b20-both-null", "max31865-mash-and-coil"],
)
def test_two_roles_on_one_device_are_refused(text: str, said: str) -> None:
    assert problems(text) == [said]


def test_the_same_place_in_two_kinds_is_two_devices() -> None:
    # Bus 1 and 0x48 mean the HLT's LM92 only to an LM92: a MAX31865 at bus 1 is an SPI device.
    config = parse("mash_sensor:\n  kind: max31865\n  bus: 1\n")
    assert config.mash_sensor == RoleSensorConfig(kind="max31865", bus=1)


def test_an_unfitted_role_s_keys_are_checked_but_clash_with_nothing() -> None:
    assert not parse("mash_sensor:\n  address: 0x48\n").mash_sensor.fitted
    [problem] = problems("coil_sensor:\n  offset: 6\n")
    assert "coil_sensor.offset: 6 °C is out of range (a number from -5 to 5 °C)" in problem


def test_a_role_s_kind_rules_name_its_section() -> None:
    said = problems(
        "mash_sensor:\n  kind: lm92\n  address: 0x49\n  offset: 0.5\n"
        "coil_sensor:\n  kind: ds18b20\n  id: 28-xyz\n"
    )
    assert said == [
        "hermsd.yaml:4:11: mash_sensor.offset: 0.5 °C is not 0, but hermsd reads an LM92 "
        "without one (a ds18b20 or a max31865 takes an offset) (leave it at 0)",
        "hermsd.yaml:7:7: coil_sensor.id: '28-xyz' is not a DS18B20's id (28- and 12 "
        "hexadecimal digits, as in 28-0316a2795bff)",
    ]


def test_a_role_sensor_s_kind_may_not_be_misspelt() -> None:
    [problem] = problems("mash_sensor:\n  kind: DS18B20\n")
    assert "did you mean 'ds18b20'?" in problem


@pytest.mark.parametrize(
    ("text", "said"),
    [
        (
            "pump:\n  backend: gpio\n",
            "pump.backend: the gpio backend needs pump.line, the line offset on /dev/gpiochip0",
        ),
        (
            "output:\n  backend: gpio\n  line: 17\npump:\n  backend: gpio\n  line: 17\n",
            "pump.backend: pump and output would both drive line 17 of /dev/gpiochip0",
        ),
        (
            "contactor:\n  backend: relay-board\npump:\n  backend: relay-board\n  channel: 1\n",
            "pump.backend: pump and contactor would both drive /dev/ttyUSB1",
        ),
        (
            "contactor:\n  backend: serial-rts\npump:\n  backend: relay-board\n",
            "pump.backend: pump and contactor would both drive /dev/ttyUSB1 (give pump its own "
            "port, line or relay channel; a relay board needs its port to itself)",
        ),
        ("pump:\n  backend: serial-rts\n", "pump.backend: 'serial-rts' is not one of the choices"),
    ],
    ids=["gpio-without-line", "ssr-s-line", "contactor-s-relay", "contactor-s-port", "serial"],
)
def test_the_pump_needs_a_device_of_its_own(text: str, said: str) -> None:
    [problem] = problems(text)
    assert said in problem


def test_the_pump_may_share_the_contactor_s_relay_board_on_its_own_channel() -> None:
    config = parse("contactor:\n  backend: relay-board\npump:\n  backend: relay-board\n")
    assert (config.pump.port, config.pump.channel) == ("/dev/ttyUSB1", 3)
    assert (config.contactor.port, config.contactor.channel) == ("/dev/ttyUSB1", 1)


@pytest.mark.parametrize(
    ("value", "ok"), [("1", True), ("0.9", False), ("20", True), ("21", False)]
)
def test_max_hlt_above_mash_within_its_range(value: str, ok: bool) -> None:
    text = f"herms:\n  max_hlt_above_mash: {value}\n"
    if ok:
        assert parse(text).herms.max_hlt_above_mash == float(value)
    else:
        [problem] = problems(text)
        assert "a number from 1 to 20 °C" in problem


def test_check_config_names_the_clash(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from hermsd.cli import main

    path = tmp_path / "hermsd.yaml"
    path.write_text("mash_sensor:\n  kind: lm92\n", encoding="utf-8")
    assert main(["check-config", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"{path}:2:9: mash_sensor.kind: mash_sensor and sensor name the same")
    assert "Traceback" not in err
