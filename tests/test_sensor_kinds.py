"""The DS18B20 and the MAX31865 in the whole loop: config, simulated runs, scenarios' sensor
faults, the status line and the log naming the kind."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from hermsd.cli import commands as cli
from hermsd.config.read import parse
from hermsd.config.schema import ConfigError
from hermsd.sim import scenario
from hermsd.sim.scenario import Event, Scenario, ScenarioError

KINDS = {
    "ds18b20": {"sensor": {"kind": "ds18b20"}},
    "max31865": {"sensor": {"kind": "max31865", "bus": 0, "r0": 1000, "rref": 4300, "wires": 4}},
}


def test_an_lm92_file_reads_as_it_did() -> None:
    config = parse("sensor:\n  bus: 1\n  address: 0x49\n  read_interval: 1.0\n")
    assert (config.sensor.kind, config.sensor.address, config.sensor.offset) == ("lm92", 0x49, 0)


@pytest.mark.parametrize(
    ("text", "said"),
    [
        ("sensor:\n  kind: ds18b20\n  id: 10-000802b4a8c1\n", "is not a DS18B20's id"),
        ("sensor:\n  kind: max31865\n  r0: 1000\n", "rref (430 Ω) is not above sensor.r0"),
        ("sensor:\n  offset: 0.5\n", "the LM92's T_CRIT pin"),
    ],
)
def test_sensor_settings_that_cannot_work_are_refused(text: str, said: str) -> None:
    with pytest.raises(ConfigError, match=re.escape(said)):
        parse(text)


@pytest.mark.parametrize("kind", KINDS)
def test_a_simulated_day_reaches_and_holds_with_each_kind(kind: str) -> None:
    result = scenario.run(
        Scenario(name=kind, duration=4 * 3600.0, config=KINDS[kind], events=())
    ).summary
    assert result["alarms"] == []
    assert result["settle_s"] is not None


# Each trap, switched on for a minute at full power: a fault, the heater off, never a value.
TRAPS = {
    "ds18b20": ("crc", "power_on", "zeros", "ones", "marker", "gone", "resolution"),
    "max31865": ("open", "short", "refin", "rtdin", "voltage", "gone"),
}


@pytest.mark.parametrize(("kind", "trap"), [(k, t) for k, ts in TRAPS.items() for t in ts])
def test_every_trap_in_a_run_is_a_sensor_fault_with_the_heater_off(kind: str, trap: str) -> None:
    fault = Event(1800.0, "sensor", (trap, None), 60.0)
    result = scenario.run(
        Scenario(name=trap, duration=2700.0, config=KINDS[kind], events=(fault,)),
        keep_records=True,
    )
    alarms = result.summary["alarms"]
    assert alarms[0]["kind"] == "sensor_fault"  # then stale_reading too, as with the LM92
    assert {a["kind"] for a in alarms} <= {"sensor_fault", "stale_reading"}
    assert alarms[0]["heater_off_after_s"] is not None
    assert alarms[0]["detected_after_s"] <= 5.0  # a few reads
    during = [r for r in result.records if 1800.0 < r.t < 1860.0 and r.pv is not None]
    assert all(r.pv < 60.0 for r in during)  # 85 °C, 127.94 °C: never taken for the water


@pytest.mark.parametrize("kind", KINDS)
def test_a_stuck_sensor_latches_as_with_the_lm92(kind: str) -> None:
    fault = Event(600.0, "sensor", ("stuck", None))
    result = scenario.run(
        Scenario(name="stuck", duration=3600.0, config=KINDS[kind], events=(fault,))
    )
    assert "sensor_stuck" in [a["kind"] for a in result.summary["alarms"]]


def test_a_fault_the_kind_has_not_is_refused_before_the_run() -> None:
    fault = Event(600.0, "sensor", ("nack", None))
    with pytest.raises(ScenarioError, match="'nack' at 600 s is not one a ds18b20 has"):
        scenario.run(Scenario(duration=3600.0, config=KINDS["ds18b20"], events=(fault,)))


@pytest.mark.parametrize(
    ("kind", "said"),
    [
        ("ds18b20", "sensor: DS18B20 (the one found) under /sys/bus/w1/devices (simulated)"),
        ("max31865", "sensor: PT1000 (4-wire) on a MAX31865 at /dev/spidev0.0"),
    ],
)
def test_run_simulate_names_the_kind_in_the_status_line_and_the_log(
    kind: str, said: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    lines = [
        f"{section}:" + "".join(f"\n  {k}: {v}" for k, v in keys.items())
        for section, keys in KINDS[kind].items()
    ]
    path = tmp_path / "hermsd.yaml"
    path.write_text("\n".join(lines) + "\noutput:\n  backend: sim\n", encoding="utf-8")
    args = ["run", "--config", str(path), "--simulate", "--speed", "max", "--duration", "10m"]
    assert cli.main([*args, "--state", str(tmp_path / "state")]) == 0
    out, err = capsys.readouterr()
    assert f"HLT ({kind}) " in out
    assert said in err
