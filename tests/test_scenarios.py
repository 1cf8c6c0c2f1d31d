"""Whole brew days and faults through the daemon on the virtual clock: the figures that matter."""

from __future__ import annotations

import dataclasses
import itertools
import math
from pathlib import Path

import pytest

from hermsd.cli import commands as cli
from hermsd.config import schema as config_module
from hermsd.log.mcap_file import LogFile
from hermsd.sim import scenario
from hermsd.sim.scenario import Event, Scenario, ScenarioError, parse_scenario

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"
PERIOD = 5.0  # s, the default control period

# Seed 001's FOPTD tun from 20 °C at full power enters the band (65.5 °C) at
# θ − τ·ln(1 − 45.5 / (K·100)) = 115 − 14961·ln(1 − 45.5/168.9).
PHYSICAL_MIN = 115.0 - 14961.0 * math.log(1.0 - 45.5 / 168.9)


@pytest.fixture(scope="module")
def default_run() -> scenario.Result:
    return scenario.run(scenario.DEFAULT, keep_records=True)


def test_the_default_brew_day_meets_the_goals(default_run: scenario.Result) -> None:
    s = default_run.summary
    assert s["physical_min_s"] == pytest.approx(PHYSICAL_MIN, abs=0.5)
    assert s["overshoot_c"] <= 0.1
    assert s["settle_s"] <= 1.01 * s["physical_min_s"]
    assert s["recovery_s"] <= 1.02 * s["recovery_min_s"]
    assert s["in_band_fraction"] == 1.0
    assert s["max_output_jump"] <= 10.0
    assert s["ssr_edges_per_hour"] <= 720.0
    assert s["alarms"] == [] and s["overruns"] == 0


def test_the_recovery_minimum_is_full_power_from_the_water(default_run: scenario.Result) -> None:
    # 90 L at 66 °C + 10 L at 15 °C mix to 60.9 °C; at full power the water then heats at
    # (K·100 − (T − 20)) / τ' with τ' = τ·100/90, but only after the dead time, during which
    # the holding duty keeps it where it is: the minimum lies between these two bounds.
    mixed = (90 * 66.0 + 10 * 15.0) / 100
    tau = 14961.0 * 100 / 90
    full = -tau * math.log((168.9 - (65.5 - 20)) / (168.9 - (mixed - 20)))
    assert full < default_run.summary["recovery_min_s"] <= full + 115.0


@pytest.mark.parametrize(
    ("name", "kind"),
    [
        ("sensor-nack", "sensor_fault"),
        ("sensor-timeout", "sensor_fault"),
        ("sensor-gone", "sensor_fault"),
        ("sensor-wrong-id", "sensor_fault"),
        ("sensor-stuck", "sensor_stuck"),
        ("element-dead", "heater_not_heating"),
        ("ssr-stuck-on", "ssr_stuck_on"),
        ("dry-fire", "dry_fire"),
        ("over-temperature", "over_temperature"),
    ],
)
def test_every_fault_turns_the_heater_off_at_once(name: str, kind: str) -> None:
    result = scenario.run(scenario.load_scenario(SCENARIOS / f"{name}.yaml"))
    alarms = result.summary["alarms"]
    assert alarms, f"{name} raised no alarm"
    assert alarms[0]["kind"] == kind
    for alarm in alarms:
        assert alarm["heater_off_after_s"] is not None
        assert alarm["heater_off_after_s"] <= PERIOD
    # A sensor fault is seen by the second failed read after it starts.
    if kind == "sensor_fault":
        assert alarms[0]["detected_after_s"] <= PERIOD


def test_a_single_spike_causes_no_alarm_and_no_bump() -> None:
    spiked = scenario.load_scenario(SCENARIOS / "sensor-spike.yaml")
    clean = Scenario(name="clean", duration=spiked.duration, setpoint=spiked.setpoint, events=())
    with_spike = scenario.run(spiked, keep_records=True)
    without = scenario.run(clean, keep_records=True)
    assert with_spike.summary["alarms"] == []
    spike_at = spiked.events[0].at
    pairs = list(zip(with_spike.records, without.records, strict=True))
    # Until the spike, the same day; in its period, the same readings less one: the spike,
    # dropped before the controller saw it.
    assert all(a.output == b.output for a, b in pairs if a.t <= spike_at)
    spiked_period = next((a, b) for a, b in pairs if a.t > spike_at)
    kept, clean_readings = spiked_period[0].readings, spiked_period[1].readings
    assert len(kept) == len(clean_readings) - 1
    assert any(kept == clean_readings[:i] + clean_readings[i + 1 :] for i in range(len(kept) + 1))
    # A period's mean of one reading fewer is no bump: the output moves as it does in the
    # hold anyway (one LSB in a period's mean of five readings is worth ~0.1 %).
    assert abs(spiked_period[0].output - spiked_period[1].output) < 0.1
    near = [r.output for r in with_spike.records if spike_at - 60.0 <= r.t <= spike_at + 60.0]
    assert max(abs(b - a) for a, b in itertools.pairwise(near)) < 0.5


@pytest.mark.parametrize(
    "events",
    [
        (Event(3 * 3600.0, "mode", "manual"), Event(3 * 3600.0 + 5, "output", 100.0)),
        (Event(2 * 3600.0, "setpoint", 52.0),),
        (Event(2 * 3600.0, "add_water", {"litres": 10.0, "temp": 15.0}),),
        (Event(2 * 3600.0, "ambient", 5.0),),
    ],
    ids=["manual-100", "setpoint-down", "cold-water", "cold-room"],
)
def test_normal_brewing_raises_no_alarm(events: tuple[Event, ...]) -> None:
    result = scenario.run(Scenario(name="normal", duration=4 * 3600.0, events=events))
    assert result.summary["alarms"] == []


def test_scenario_errors_name_the_key() -> None:
    with pytest.raises(ScenarioError, match=r"events\[0\].*sensor"):
        parse_scenario({"events": [{"at": "1h", "sensor": "melted"}]})
    with pytest.raises(ScenarioError, match="duration"):
        parse_scenario({"duration": "forever"})
    with pytest.raises(ScenarioError, match="unknown key"):
        parse_scenario({"durration": "1h"})


def test_every_shipped_scenario_parses() -> None:
    for path in sorted(SCENARIOS.glob("*.yaml")):
        assert scenario.load_scenario(path).duration > 0


def test_config_events_reload_at_the_next_period_without_a_bump() -> None:
    brew_day = scenario.load_scenario(SCENARIOS / "brew-day.yaml")
    result = scenario.run(brew_day, keep_records=True)
    by_t = {r.t: r for r in result.records}
    # 1h15m: the rest's setpoint arrives with the period at that very instant.
    assert by_t[4495.0].setpoint == 52.0 and by_t[4500.0].setpoint == 66.0
    # 2h30m: the retune resets the new controller to the output in force.
    retuned = by_t[9000.0]
    assert retuned.reset_from == by_t[8995.0].output
    assert abs(retuned.output - by_t[8995.0].output) < 1.0
    assert by_t[13500.0].setpoint == 76.0
    kinds = {a["kind"] for a in result.summary["alarms"]}
    assert kinds == {"sensor_fault", "stale_reading"}


def test_an_invalid_config_event_names_the_event() -> None:
    bad = parse_scenario({"events": [{"at": "1h", "config": {"control": {"ti": -1}}}]})
    with pytest.raises(ScenarioError, match=r"events\[0\]\.config.*control\.ti"):
        scenario.run(bad)


def test_a_config_override_is_refused_at_its_line_in_the_scenario(tmp_path: Path) -> None:
    path = tmp_path / "day.yaml"
    path.write_text(
        "duration: 1h\nconfig:\n  control:\n    kc: -5\nevents:\n  - at: 10m\n"
        "    config: {control: {ti: -1}}\n",
        encoding="utf-8",
    )
    day = scenario.load_scenario(path)
    with pytest.raises(ScenarioError) as caught:
        scenario.effective_config(config_module.DEFAULT, day)
    assert str(caught.value).startswith(f"{path}:4:9: config.control.kc: -5 %/°C is out of range")
    with pytest.raises(ScenarioError) as caught:  # the override fixed, the event is next
        scenario.run(dataclasses.replace(day, config={}))
    assert str(caught.value).startswith(f"{path}:7:28: events[0].config.control.ti: -1 s")


def test_a_simulated_log_is_named_after_its_first_record(tmp_path: Path) -> None:
    # The virtual clock starts at 2026-01-01T00:00:00Z and the daemon records its config at
    # once; the writer thread, meanwhile, falls minutes of simulated time behind.
    scenario.run(Scenario(duration=1800.0, events=()), log_dir=tmp_path)
    [log] = tmp_path.iterdir()
    assert log.name == "hermsd-20260101T000000Z.mcap"
    assert LogFile(log).metadata()["hermsd"]["started_utc"] == "2026-01-01T00:00:00Z"


def test_a_sensor_fault_at_full_power_leaves_no_offset_in_the_hold() -> None:
    """Control resumes at 100 % with the water at 50 °C: the model must start from the water,
    not from an equilibrium with 100 % (which would predict a cooling of about 1 °C that
    fades only over τ, and hold the tun 0.3 to 0.65 °C high for hours)."""
    fault = Event(1800.0, "sensor", ("nack", None), 30.0)
    result = scenario.run(Scenario(name="fault-in-heat-up", events=(fault,)), keep_records=True)
    resumed = next(r for r in result.records if r.t > 1830.0 and r.reset_from is not None)
    assert resumed.reset_from == 100.0
    hold = [r.pv for r in result.records if r.t >= 3 * 3600.0 and r.pv is not None]
    assert max(abs(pv - 66.0) for pv in hold) <= 0.0625  # one LSB of the LM92


@pytest.mark.parametrize(
    ("event", "value", "key", "expected"),
    [
        ("setpoint: 150", "150", "events[0].setpoint", "0 to 100 °C"),
        ("output: -1", "-1", "events[0].output", "0 to 100 %"),
        ("ambient: 400", "400", "events[0].ambient", "-20 to 50 °C"),
        ("add_water: {litres: -5, temp: 15}", "-5", "events[0].add_water.litres", "0.1 to 1000 L"),
        (
            "add_water: {litres: 5, temp: 120}",
            "120",
            "events[0].add_water.temp",
            "0 to 100 °C (liquid water)",
        ),
    ],
)
def test_an_event_out_of_range_is_refused_with_file_line_and_column(
    tmp_path: Path,
    event: str,
    value: str,
    key: str,
    expected: str,
    capsys: pytest.CaptureFixture[str],
) -> None:
    path = tmp_path / "bad.yaml"
    line = f"    {event}"
    path.write_text(f"duration: 1h\nevents:\n  - at: 10m\n{line}\n", encoding="utf-8")

    assert cli.main(["simulate", "--scenario", str(path)]) == 2

    where = f"{path}:4:{line.index(value) + 1}"
    message = f"{value} is out of range (expected {expected})"
    assert capsys.readouterr().err == f"hermsd: {where}: {key}: {message}\n"


@pytest.mark.parametrize(
    ("fault", "value", "needs"),
    [
        ("slow", "", "a positive number of seconds"),
        ("slow", "\n    value: 0", "a positive number of seconds"),
        ("spike", "", "a finite temperature"),
        ("wrong_id", "\n    value: 32769", "a 16-bit word other than 0x8001"),  # the LM92's own
    ],
)
def test_a_sensor_fault_without_the_value_it_needs_is_refused_before_the_run(
    tmp_path: Path, fault: str, value: str, needs: str, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "fault.yaml"
    path.write_text(
        f"duration: 1h\nevents:\n  - at: 10m\n    sensor: {fault}{value}\n", encoding="utf-8"
    )

    assert cli.main(["simulate", "--scenario", str(path)]) == 2

    err = capsys.readouterr().err
    where = "5:12" if value else "3:5"  # the value given, else the event
    assert err.startswith(
        f"hermsd: {path}:{where}: events[0].value: the '{fault}' fault needs {needs}"
    )
    assert err.count("\n") == 1  # one line, no traceback


def test_the_config_sections_setpoint_is_used_when_the_scenario_gives_none() -> None:
    doc = {"duration": "1h", "config": {"control": {"setpoint": 70}}}

    config = scenario.effective_config(config_module.DEFAULT, parse_scenario(doc))

    assert config.control.setpoint == 70.0


def test_a_setpoint_given_twice_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "twice.yaml"
    path.write_text("setpoint: 66\nconfig:\n  control: {setpoint: 70}\n", encoding="utf-8")

    with pytest.raises(ScenarioError) as error:
        scenario.load_scenario(path)

    assert str(error.value) == (
        f"{path}:3:23: config.control.setpoint: the setpoint is given twice "
        "(keep the top-level setpoint, or this one)"
    )


def test_a_scenario_nested_too_deeply_is_one_line(tmp_path: Path) -> None:
    path = tmp_path / "deep.yaml"
    path.write_text("events: " + "[" * 100_000 + "]" * 100_000 + "\n", encoding="utf-8")

    with pytest.raises(ScenarioError, match=f"^{path}: nested too deeply to be a scenario$"):
        scenario.load_scenario(path)
