"""The mash program: its file, the pure runner's rules, its stored progress, local time.

Golden values are worked out by hand from the rules in hermsd/program/runner.py: 5 s
periods, the hold counting only periods whose PV is within ±0.5 °C of the setpoint.
"""

from __future__ import annotations

import datetime as dt
import json
import math
import threading
from pathlib import Path

import pytest

from hermsd.cli import main
from hermsd.control.pid import PlantModel
from hermsd.program import model
from hermsd.program import store as store_module
from hermsd.program.driver import ProgramDriver, local_iso, next_local_time
from hermsd.program.model import Program, ProgramError, Step
from hermsd.program.readiness import Tun
from hermsd.program.runner import Progress, Refused, Runner, heat_up_s
from hermsd.program.store import PROGRAM_FILE, PROGRESS_FILE, ProgressStore, ProgressWriter
from hermsd.safety.latches import StateError
from hermsd.sim import scenario

STEP_MASH = """\
# a step mash
name: Step mash
ready_by: "06:30"
steps:
  - name: Strike
    setpoint: 72
    hold: 0s
    confirm: Mash in
  - name: Beta rest
    setpoint: 64
    hold: 30m
  - name: Alpha rest
    setpoint: 72
    hold: 1h5m
    ramp: 0.5
  - name: Mash out
    setpoint: 78
    hold: until told
"""
EXPECTED = Program(
    "Step mash",
    (
        Step("Strike", 72.0, 0.0, None, "Mash in"),
        Step("Beta rest", 64.0, 1800.0),
        Step("Alpha rest", 72.0, 3900.0, 0.5),
        Step("Mash out", 78.0, None),
    ),
    "06:30",
)
PERIOD = 5.0
NS = 1_000_000_000


# -- the file -------------------------------------------------------------------------------


def test_a_program_file_is_read_as_written() -> None:
    assert model.parse(STEP_MASH, "mash.yaml") == EXPECTED
    assert model.from_data(model.to_data(EXPECTED)) == EXPECTED  # what the socket carries


def test_the_name_defaults_to_the_files_stem(tmp_path: Path) -> None:
    path = tmp_path / "hefeweizen.yaml"
    path.write_text("steps:\n  - {name: Rest, setpoint: 66, hold: 1m}\n", encoding="utf-8")
    assert model.load(path) == Program("hefeweizen", (Step("Rest", 66.0, 60.0),))


BAD = """\
name: Bad
ready_by: 6:30
steps:
  - name: Strike
    setpoint: 172
    hold: 1:30
  - name: Rest
    setpont: 66
    hold: until told
    confirm: Go
  - name: Rest
    setpoint: 066
    hold: 10m
    ramp: 0
"""


def test_every_problem_is_said_with_file_line_and_column() -> None:
    with pytest.raises(ProgramError) as caught:
        model.parse(BAD, "bad.yaml")
    lines = str(caught.value).splitlines()
    assert lines == [
        "bad.yaml:2:11: ready_by: '6:30' is not a local time (HH:MM on a 24 h clock, e.g. '06:30')",
        "bad.yaml:5:15: steps[0].setpoint: 172 °C is out of range (a number from 0 to 100 °C)",
        "bad.yaml:6:11: steps[0].hold: '1:30' is not a hold (a duration such as 90s, 60m or "
        "1h30m (at most 24 h), or 'until told')",
        "bad.yaml:7:5: steps[1].setpoint: missing (°C, e.g. 66)",
        "bad.yaml:8:5: steps[1].setpont: unknown key (did you mean 'setpoint'?)",
        "bad.yaml:10:14: steps[1].confirm: a step held 'until told' ends with `hermsd program "
        "next`, never waits (give the hold a time, or leave confirm out)",
        "bad.yaml:12:15: steps[2].setpoint: expected a number, got the string '066' (a number "
        "from 0 to 100 °C; drop the leading zeros, which YAML 1.1 reads as octal)",
        "bad.yaml:14:11: steps[2].ramp: 0 °C/min is out of range (a number from 0.07 to 10 "
        "°C/min, or null for at once)",
    ]


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("name: x\n", "bad.yaml:1:1: steps: missing (a list of 1 to 50 steps)"),
        ("steps: []\n", "bad.yaml:1:8: steps: expected a list of 1 to 50 steps"),
        ("- 1\n", "bad.yaml:1:1: a program is a mapping with steps, got a list"),
        (
            "steps:\n  - {name: A, setpoint: 60, hold: 1m}\n"
            "  - {name: A, setpoint: 61, hold: 1m}\n",
            "bad.yaml:3:5: steps[1].name: 'A' names an earlier step too (line 2;",
        ),
        (
            "steps:\n  - {name: A, setpoint: 60, hold: 25h}\n",
            "bad.yaml:2:35: steps[0].hold: '25h' is not a hold",
        ),
        ("steps: [\n", "bad.yaml:2:1: invalid YAML"),
    ],
)
def test_what_a_program_is_not(text: str, says: str) -> None:
    with pytest.raises(ProgramError) as caught:
        model.parse(text, "bad.yaml")
    assert str(caught.value).startswith(says)


@pytest.mark.parametrize(
    ("hold", "number"), [("60", "60"), ("'60'", "60"), ("5", "5"), ("1.5", "1.5"), ("0", "0")]
)
def test_a_hold_without_its_unit_is_refused_with_both_readings(hold: str, number: str) -> None:
    """60 may be the hour-long rest meant or one minute: the brewer says which."""
    text = (
        "steps:\n  - {name: A, setpoint: 60, hold: 1m}\n"
        f"  - {{name: B, setpoint: 66, hold: {hold}}}\n"
    )
    with pytest.raises(ProgramError) as caught:
        model.parse(text, "mash.yaml")
    assert str(caught.value) == (
        f"mash.yaml:3:35: steps[1].hold: {number} has no unit "
        f"(write {number}m for {number} minutes, or {number}s for {number} seconds)"
    )


def test_a_scenarios_inline_program_needs_the_units_its_data_form_does_not() -> None:
    typed = {"steps": [{"name": "A", "setpoint": 66, "hold": 60}]}
    assert model.from_data(typed).steps[0].hold == 60.0  # what `to_data` writes: seconds
    with pytest.raises(ProgramError) as caught:
        model.from_data(typed, typed=True)
    assert model.one_line(caught.value) == (
        "steps[0].hold: 60 has no unit (write 60m for 60 minutes, or 60s for 60 seconds)"
    )
    with pytest.raises(scenario.ScenarioError, match=r"program: steps\[0\]\.hold: 60 has no unit"):
        scenario.parse_scenario({"program": typed}, "day.yaml")


@pytest.mark.parametrize(("ramp", "valid"), [("1e-300", False), ("0.069", False), ("0.07", True)])
def test_a_ramp_ends_within_the_day_a_hold_may_last(ramp: str, valid: bool) -> None:
    """0.07 °C/min crosses the widest span, 0 to 100 °C, in 1428.6 min: within 24 h (1440)."""
    text = (
        "steps:\n  - {name: A, setpoint: 0, hold: 1m}\n"
        f"  - {{name: B, setpoint: 100, hold: 1m, ramp: {ramp}}}\n"
    )
    if valid:
        assert model.parse(text).steps[1].ramp == 0.07
        return
    with pytest.raises(ProgramError) as caught:
        model.parse(text, "mash.yaml")
    assert str(caught.value) == (
        f"mash.yaml:3:46: steps[1].ramp: {ramp} °C/min is out of range "
        "(a number from 0.07 to 10 °C/min, or null for at once)"
    )


def test_a_key_without_a_value_is_told_what_leaving_it_out_would_do() -> None:
    """A step's name, setpoint and hold have no default: leaving them out is no way out."""
    text = "name:\nsteps:\n  - name:\n    setpoint:\n    hold:\n    confirm:\n"
    with pytest.raises(ProgramError) as caught:
        model.parse(text, "mash.yaml")
    assert str(caught.value).splitlines() == [
        "mash.yaml:1:6: name: has no value (text of 1 to 40 printable characters; or leave the "
        "key out for the file's name)",
        "mash.yaml:3:10: steps[0].name: has no value (text of 1 to 40 printable characters)",
        "mash.yaml:4:14: steps[0].setpoint: has no value (a number from 0 to 100 °C)",
        "mash.yaml:5:10: steps[0].hold: has no value (a duration such as 90s, 60m or 1h30m (at "
        "most 24 h), or 'until told')",
        "mash.yaml:6:13: steps[0].confirm: has no value (text of 1 to 120 printable characters; "
        "or leave the key out for a step that does not wait)",
    ]


def _said(data: object) -> str:
    with pytest.raises(ProgramError) as caught:
        model.from_data(data)
    return model.one_line(caught.value)


@pytest.mark.parametrize(
    ("file_text", "data"),
    [
        (
            "steps:\n  - {name: '66', setpoint: '66', hold: 1m, ramp: 0, confirm: 5}\n",
            {"steps": [{"name": "66", "setpoint": "66", "hold": 60, "ramp": 0, "confirm": 5}]},
        ),
        (
            "name: [1]\nsteps:\n  - {name: A, setpoint: 101, hold: true, colour: red}\n",
            {"name": [1], "steps": [{"name": "A", "setpoint": 101, "hold": True, "colour": "red"}]},
        ),
        ("steps: 3\nready_by: '7:00'\n", {"steps": 3, "ready_by": "7:00"}),
    ],
)
def test_a_program_sent_as_data_is_refused_in_the_files_words(
    file_text: str, data: dict[str, object]
) -> None:
    with pytest.raises(ProgramError) as from_file:
        model.parse(file_text, "program")
    with pytest.raises(ProgramError) as from_data:
        model.from_data(data)
    said = [
        sorted((p.key_path, p.message) for p in e.value.problems) for e in (from_data, from_file)
    ]
    assert said[0] == said[1]


def test_a_repeated_step_name_sent_as_data_points_at_the_step_not_a_line() -> None:
    step = {"name": "A", "setpoint": 60, "hold": 60}
    assert _said({"steps": [step, step]}) == (
        "steps[1].name: 'A' names an earlier step too (steps[0]; give each step its own name)"
    )


def test_deeply_nested_data_is_refused_without_walking_it() -> None:
    nested: object = "x"
    for _ in range(5000):  # deeper than the interpreter's recursion limit
        nested = [nested]
    said = _said({"steps": [{"name": nested, "setpoint": 60, "hold": 60}]})
    assert said == (
        "steps[0].name: expected a single value, got a list (text of 1 to 40 printable characters)"
    )


def test_fifty_steps_at_most() -> None:
    steps = "".join(f"  - {{name: s{i}, setpoint: 60, hold: 1m}}\n" for i in range(51))
    with pytest.raises(ProgramError, match="expected a list of 1 to 50 steps"):
        model.parse("steps:\n" + steps)
    model.parse("steps:\n" + steps.split("\n", 1)[1])  # 50 are fine


def test_program_check_prints_the_steps_or_every_problem(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    good, bad = tmp_path / "good.yaml", tmp_path / "bad.yaml"
    good.write_text(STEP_MASH, encoding="utf-8")
    bad.write_text(BAD, encoding="utf-8")
    assert main(["program", "check", str(good)]) == 0
    out = capsys.readouterr().out
    assert "program 'Step mash', 4 steps, valid" in out
    assert "3. Alpha rest: 72 °C, hold 65 min, ramp 0.5 °C/min" in out
    assert main(["program", "check", str(bad)]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 8 and err.startswith(f"{bad}:2:11: ready_by")


STRIKE_72 = Program(
    "Strike high",
    (
        Step("Strike", 72.0, 0.0, confirm="Mash in"),
        Step("Protein rest", 63.0, 1200.0),
        Step("Mash out", 78.0, 600.0),
    ),
)


def test_a_strike_above_the_first_rest_plus_the_limit_is_warned_of() -> None:
    """72 °C against 63 + 8 = 71 °C: the HLT cannot be cooled to the limit for the pump start."""
    assert model.strike_warnings(STRIKE_72, 8.0) == [
        "steps[0].setpoint: Strike 72 °C is above the first rest Protein rest 63 °C + "
        "herms.max_hlt_above_mash 8 °C = 71 °C: the HLT will stand above the limit when the "
        "pump starts; lower the strike or raise herms.max_hlt_above_mash"
    ]
    assert model.strike_warnings(STRIKE_72, 9.0) == []  # 72 = 63 + 9: at the limit, not above
    # Without a mash-in wait every step is on the mash: no strike to judge.
    mashed_in = Program("Mashed in", STRIKE_72.steps[1:])
    assert model.strike_warnings(mashed_in, 1.0) == []


def test_program_check_with_a_herms_config_warns_of_a_strike_above_the_limit(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    program, herms, plain = tmp_path / "p.yaml", tmp_path / "herms.yaml", tmp_path / "hlt.yaml"
    program.write_text(STEP_MASH, encoding="utf-8")  # strike 72 °C, first rest 64 °C
    sensor = "mash_sensor:\n  kind: lm92\n  address: 0x49\n"
    herms.write_text(sensor + "herms:\n  max_hlt_above_mash: 5\n", encoding="utf-8")
    plain.write_text("herms:\n  max_hlt_above_mash: 5\n", encoding="utf-8")
    assert main(["program", "check", str(program), "--config", str(herms)]) == 0
    out = capsys.readouterr().out
    assert "valid" in out
    assert (
        f"warning: {program}: steps[0].setpoint: Strike 72 °C is above the first rest Beta rest "
        "64 °C + herms.max_hlt_above_mash 5 °C = 69 °C: the HLT will stand above the limit"
    ) in out
    # No mash sensor: the HLT is the brewer's, no limit above a mash.
    assert main(["program", "check", str(program), "--config", str(plain)]) == 0
    assert "warning" not in capsys.readouterr().out
    assert main(["program", "check", str(program)]) == 0
    assert "warning" not in capsys.readouterr().out


# -- the runner ------------------------------------------------------------------------------


def run(runner: Runner, pvs: list[float | None], t0: float = 0.0) -> float:
    """One period per PV, from t0; the time of the last."""
    t = t0
    for index, pv in enumerate(pvs):
        t = t0 + index * PERIOD
        runner.period(t, pv)
    return t


def started(program: Program) -> Runner:
    runner = Runner.start(program, max_step_s=2 * PERIOD)
    runner.take_events()
    return runner


REST = Program("Rest", (Step("Rest", 66.0, 20.0), Step("Out", 78.0, 60.0)))


def test_the_hold_counts_only_periods_in_the_band_from_the_first_one() -> None:
    runner = started(REST)
    # t=0 64.0 (out), 5 65.5 (in: reached), 10 66.4 (+5), 15 66.6 (out), 20 None (no PV),
    # 25 65.6 (+5), 30 66.0 (+5): 15 s held, 5 s left.
    run(runner, [64.0, 65.5, 66.4, 66.6, None, 65.6, 66.0])
    assert (runner.state, runner.progress.held_s, runner.time_left_s()) == ("holding", 15.0, 5.0)
    assert [e.event for e in runner.take_events()] == ["step_started", "step_reached"]
    runner.period(35.0, 66.1)  # 20 s: done, and the next step starts at once
    assert [e.event for e in runner.take_events()] == ["step_done", "step_started"]
    assert (runner.step.name, runner.setpoint, runner.state) == ("Out", 78.0, "heating")


def test_pause_holds_the_setpoint_and_stops_the_hold_time() -> None:
    runner = started(REST)
    run(runner, [66.0, 66.0])  # reached at 0, 5 s held
    runner.command("pause", 66.0)
    run(runner, [66.0] * 10, t0=10.0)
    assert (runner.state, runner.progress.held_s, runner.setpoint) == ("paused", 5.0, 66.0)
    runner.command("resume", 66.0)
    run(runner, [66.0, 66.0], t0=60.0)  # the first period after resuming counts its 5 s
    assert runner.progress.held_s == 15.0
    assert [e.event for e in runner.take_events()][-2:] == ["paused", "resumed"]


def test_a_ramp_moves_the_setpoint_at_its_rate_then_the_step_is_reached() -> None:
    program = Program("Ramp", (Step("Beta", 64.0, 0.0), Step("Alpha", 72.0, 60.0, ramp=1.0)))
    runner = started(program)
    runner.period(0.0, 64.0)  # Beta reached and done: Alpha ramps from 64 °C
    assert (runner.state, runner.setpoint) == ("ramping", 64.0)
    t = run(runner, [64.0] * 12, t0=5.0)  # 60 s later: 1 °C/min → 65 °C
    assert t == 60.0
    assert runner.setpoint == pytest.approx(65.0)
    t = run(runner, [70.0] * 85, t0=65.0)  # 8 °C take 480 s; then heating until in the band
    assert t == 485.0
    assert (runner.state, runner.setpoint) == ("heating", 72.0)
    runner.period(490.0, 71.6)
    assert runner.state == "holding"


def test_a_confirmation_waits_holding_the_setpoint_and_moves_on_when_given() -> None:
    runner = started(EXPECTED)
    with pytest.raises(Refused, match="nothing waits for a confirmation"):
        runner.command("confirm", 20.0)
    runner.period(0.0, 72.0)
    assert (runner.state, runner.setpoint, runner.time_left_s()) == ("waiting", 72.0, 0.0)
    run(runner, [72.0] * 100, t0=5.0)
    assert runner.state == "waiting"
    runner.command("confirm", 72.0)
    assert (runner.step.name, runner.setpoint) == ("Beta rest", 64.0)
    events = [(e.event, e.message) for e in runner.take_events()]
    assert ("waiting", "Mash in") in events and ("confirmed", "Mash in") in events


def test_until_told_holds_until_next_and_the_program_then_holds_its_last_setpoint() -> None:
    program = Program("Told", (Step("Out", 78.0, None),))
    runner = started(program)
    run(runner, [78.0] * 1000)
    assert (runner.state, runner.time_left_s()) == ("holding", None)
    runner.command("next", 78.0)
    assert (runner.state, runner.setpoint) == ("done", 78.0)
    assert [e.event for e in runner.take_events()][-2:] == ["skipped", "finished"]
    with pytest.raises(Refused, match="the program is done"):
        runner.command("next", 78.0)


def test_a_scheduled_program_keeps_the_heater_off_until_its_heat_up_is_due() -> None:
    runner = Runner.start(REST, max_step_s=2 * PERIOD, ready_at_ns=10_000 * NS)
    runner.period(0.0, 20.0)  # not due: no setpoint, the heater stays off
    assert (runner.state, runner.setpoint) == ("scheduled", None)
    with pytest.raises(Refused, match="has not started heating yet"):
        runner.command("next", 20.0)
    runner.period(5.0, 19.9, ready_setpoint=64.0)  # due: the waiting temperature
    assert (runner.state, runner.setpoint) == ("heating", 64.0)
    runner.period(10.0, 63.9, ready_setpoint=66.0)  # released
    assert runner.setpoint == 66.0
    runner.period(15.0, 65.6, ready_setpoint=66.0)  # in the band: reached, timing over
    assert (runner.state, runner.progress.ready_at_ns) == ("holding", None)


def test_heat_up_time_is_the_dead_time_and_the_first_order_rise() -> None:
    # From the room: y = Ta + K·u·(1 − e^(−(t−θ)/τ)); halfway to K·u is θ + τ·ln 2.
    tun = PlantModel(gain=1.0, tau=1000.0, dead_time=100.0, ambient=20.0)
    assert heat_up_s(tun, 100.0, 20.0, 70.0) == pytest.approx(100.0 + 1000.0 * math.log(2))
    assert heat_up_s(tun, 100.0, 71.0, 70.0) == 0.0
    assert heat_up_s(tun, 40.0, 20.0, 70.0) is None  # 40 % holds 60 °C at most


# -- local time ------------------------------------------------------------------------------

CET = dt.timezone(dt.timedelta(hours=1))
AT_4 = 1_795_834_800 * NS  # 2026-11-28T03:00:00Z = 04:00 CET


def test_ready_by_is_the_next_such_local_time() -> None:
    assert local_iso(AT_4, CET) == "2026-11-28T04:00:00+01:00"
    assert next_local_time(AT_4, "06:30", CET) == AT_4 + 9_000 * NS
    assert next_local_time(AT_4, "04:00", CET) == AT_4 + 86_400 * NS  # now is past: tomorrow
    assert next_local_time(AT_4, "03:59", dt.UTC) == AT_4 + 3_540 * NS


# -- the stored progress ---------------------------------------------------------------------


def test_progress_saved_in_another_boot_is_not_resumed_however_recent(tmp_path: Path) -> None:
    """A Pi without a clock chip boots at the time it last saved: the boot, not the age,
    tells a power cut (set aside) from a crash or a restart of the service (resumed)."""
    runner = started(REST)
    run(runner, [66.0, 66.0, 66.0])
    before = ProgressStore(tmp_path, boot="boot-1")
    before.save_program(REST, AT_4 - 60 * NS)
    before.save_progress(runner.progress, AT_4 - 60 * NS, AT_4)
    for boot, resumed in (("boot-1", True), ("boot-2", False)):
        driver = ProgramDriver(ProgressStore(tmp_path, boot=boot), dt.UTC, PERIOD)
        said = driver.restore(20.0, AT_4 + NS) or ""
        assert (driver.runner is not None) == resumed, said
        assert ("before the machine last started" in said) == (not resumed)


def test_progress_survives_a_restart_and_nothing_counts_from_before_it(tmp_path: Path) -> None:
    store = ProgressStore(tmp_path)
    runner = started(REST)
    run(runner, [66.0, 66.0, 66.0])  # 10 s held
    store.save_program(REST, AT_4 - 60 * NS)
    store.save_progress(runner.progress, AT_4 - 60 * NS, AT_4)
    program, progress, saved_at, _started, _boot = store.load() or (None, None, None, None, None)
    assert saved_at == AT_4
    assert program == REST and progress is not None
    again = Runner(REST, progress, max_step_s=2 * PERIOD)
    again.period(5000.0, 66.0)  # the first period after a restart counts nothing
    assert (again.state, again.progress.held_s, again.time_left_s()) == ("holding", 10.0, 10.0)


@pytest.mark.parametrize(
    "damage",
    [
        "{",
        '{"program": {"steps": []}, "progress": {}}',
        json.dumps({"program": model.to_data(REST), "progress": {"index": 7}}),
    ],
)
def test_damaged_progress_is_said_discarded_and_not_resumed(tmp_path: Path, damage: str) -> None:
    (tmp_path / PROGRAM_FILE).write_text(damage, encoding="utf-8")
    with pytest.raises(StateError):
        ProgressStore(tmp_path).load()
    driver = ProgramDriver(ProgressStore(tmp_path), dt.UTC, PERIOD)
    said = driver.restore(66.0, AT_4)
    assert said is not None and said.startswith("program progress not resumed")
    assert not driver.active and not (tmp_path / PROGRAM_FILE).exists()


BAD_PROGRESS_FIELDS = {
    "ready_at_ns past any clock": ("ready_at_ns", 99999999999999999999999, "ready_at_ns"),
    "ready_at_ns before 1970": ("ready_at_ns", -1, "ready_at_ns"),
    "ready_at_ns as a boolean": ("ready_at_ns", True, "ready_at_ns"),
    "a step it does not have": ("index", 99, "step index 99"),
    "a step as a boolean": ("index", True, "step index True"),
    "held_s beyond a float": ("held_s", 10**400, "held_s"),
    "held_s as a boolean": ("held_s", True, "held_s"),
    "a setpoint as a boolean": ("setpoint", False, "setpoint"),
}


@pytest.mark.parametrize(
    ("key", "value", "said"), BAD_PROGRESS_FIELDS.values(), ids=BAD_PROGRESS_FIELDS
)
def test_a_progress_field_out_of_bounds_is_said_in_its_file_and_kept_aside(
    tmp_path: Path, key: str, value: object, said: str
) -> None:
    store = ProgressStore(tmp_path)
    store.save_program(REST, AT_4)
    store.save_progress(started(REST).progress, AT_4, AT_4)
    path = tmp_path / PROGRESS_FILE
    record = json.loads(path.read_text(encoding="utf-8"))
    record["progress"][key] = value
    path.write_text(json.dumps(record), encoding="utf-8")

    with pytest.raises(StateError, match=f"^{path}: not a program's progress \\({said}"):
        ProgressStore(tmp_path).load()
    driver = ProgramDriver(ProgressStore(tmp_path), dt.UTC, PERIOD)
    told = driver.restore(20.0, AT_4 + NS) or ""

    assert told.startswith(f"program progress not resumed: {path}: not a program's progress")
    assert told.endswith(f"; kept as {tmp_path / PROGRAM_FILE}.stale; the setpoint is 20 °C")
    assert not driver.active
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [f"{PROGRAM_FILE}.stale", f"{PROGRESS_FILE}.stale"]
    )


def saved_then_restored(
    tmp_path: Path, runner: Runner, later_s: float
) -> tuple[ProgramDriver, str]:
    """`runner`'s progress saved at AT_4, then a driver started `later_s` after that."""
    store = ProgressStore(tmp_path)
    store.save_program(runner.program, AT_4)
    store.save_progress(runner.progress, AT_4, AT_4)
    driver = ProgramDriver(ProgressStore(tmp_path), CET, PERIOD)
    said = driver.restore(66.0, AT_4 + round(later_s * NS))
    return driver, said or ""


@pytest.mark.parametrize("later_s", [-899.0, 0.0, 899.0])
def test_a_rest_saved_within_15_minutes_resumes(tmp_path: Path, later_s: float) -> None:
    runner = started(REST)
    run(runner, [66.0, 66.0, 66.0])
    driver, _said = saved_then_restored(tmp_path, runner, later_s)
    assert driver.active and driver.runner is not None
    assert driver.runner.progress.held_s == 10.0


@pytest.mark.parametrize(
    ("later_s", "why"),
    [
        (901.0, "it was saved 15 min ago, more than the 15 min a restart may take"),
        (3 * 86400.0, "it was saved 4320 min ago, more than the 15 min a restart may take"),
        (-3600.0, "it was saved 60 min ahead of this clock, more than the 15 min"),
    ],
)
def test_a_rest_saved_long_ago_is_set_aside_and_not_resumed(
    tmp_path: Path, later_s: float, why: str
) -> None:
    runner = started(REST)
    run(runner, [66.0, 66.0, 66.0])
    driver, said = saved_then_restored(tmp_path, runner, later_s)
    assert not driver.active and driver.after is None
    assert said.startswith(f"program 'Rest' not resumed: {why}")
    assert said.endswith(f"kept as {tmp_path / PROGRAM_FILE}.stale; the setpoint is 66 °C")
    assert not (tmp_path / PROGRAM_FILE).exists()
    stale = json.loads((tmp_path / f"{PROGRESS_FILE}.stale").read_text())
    assert stale["progress"]["held_s"] == 10.0


def test_a_finished_program_is_not_resumed(tmp_path: Path) -> None:
    runner = started(Program("One", (Step("Out", 78.0, 10.0),)))
    run(runner, [78.0, 78.0, 78.0, 78.0])
    assert runner.progress.phase == "done"
    _driver, said = saved_then_restored(tmp_path, runner, 10.0)
    assert said.startswith("program 'One' not resumed: it had finished; kept as ")


def test_a_scheduled_program_past_its_ready_by_time_is_not_resumed(tmp_path: Path) -> None:
    runner = Runner.start(REST, max_step_s=2 * PERIOD, ready_at_ns=AT_4 + 60 * NS)
    runner.period(0.0, 20.0)  # not due yet: it waits
    assert runner.progress.phase == "scheduled"
    assert saved_then_restored(tmp_path, runner, 30.0)[0].active  # before 04:01 CET: resumes
    driver, said = saved_then_restored(tmp_path, runner, 61.0)
    assert not driver.active
    assert said.startswith(
        "program 'Rest' not resumed: its ready-by time 2026-11-28T04:01:00+01:00 has passed"
    )


def test_a_removed_program_stays_removed_after_a_power_cut(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    synced: list[Path] = []
    monkeypatch.setattr(store_module, "fsync_directory", synced.append)
    store = ProgressStore(tmp_path)
    store.save_program(REST, AT_4)
    store.save_progress(started(REST).progress, AT_4, AT_4)
    synced.clear()
    store.clear()
    assert synced == [tmp_path] and not store.path.exists()
    assert not store.progress_path.exists()


def test_progress_that_cannot_be_removed_does_not_stop_the_start(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / PROGRAM_FILE).write_text("{", encoding="utf-8")

    def refuse(_self: ProgressStore) -> None:
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(ProgressStore, "clear", refuse)
    driver = ProgramDriver(ProgressStore(tmp_path), dt.UTC, PERIOD)
    said = driver.restore(66.0, AT_4)
    assert said is not None and said.startswith("program progress not resumed")
    assert not driver.active


class CountingStore(ProgressStore):
    """Counts the writes and the threads they ran on; `refuse` makes them fail."""

    def __init__(self, directory: Path) -> None:
        super().__init__(directory)
        self.programs = 0
        self.records: list[tuple[float, str]] = []  # (held_s, phase) of each progress write
        self.threads: set[str] = set()
        self.refuse = False

    def save_program(self, program: Program, started_at_ns: int) -> None:
        self._check()
        self.programs += 1
        super().save_program(program, started_at_ns)

    def save_progress(self, progress: Progress, started_at_ns: int, wall_ns: int) -> None:
        self._check()
        self.records.append((progress.held_s, progress.phase))
        super().save_progress(progress, started_at_ns, wall_ns)

    def _check(self) -> None:
        self.threads.add(threading.current_thread().name)
        if self.refuse:
            raise OSError(28, "No space left on device")


LONG_REST = Program("Long", (Step("Rest", 66.0, 3600.0), Step("Out", 78.0, 600.0)))


def drive(driver: ProgramDriver, seconds: float, pv: float, t0: float = 0.0) -> None:
    for k in range(round(seconds / PERIOD)):
        t = t0 + k * PERIOD
        driver.period(t, pv, AT_4 + round(t * NS), PRIOR, 100.0 if pv < 60.0 else 30.0, pv < 60.0)


PRIOR = Tun(PlantModel(), 100.0, measured=False, fit=None)


def test_a_rest_writes_the_program_once_and_its_progress_once_a_minute_off_the_loop(
    tmp_path: Path,
) -> None:
    store = CountingStore(tmp_path)
    driver = ProgramDriver(store, dt.UTC, PERIOD)
    driver.start(LONG_REST, None, setpoint=66.0, wall_ns=AT_4, pv=66.0, tun=PRIOR)
    for minute in range(10):  # ten minutes of rest, the writer keeping up each minute
        drive(driver, 60.0, 66.0, t0=60.0 * minute)
        assert driver.flush(5.0)
    assert store.programs == 1
    # reached in the first period (held 0 s): saved then; then once a minute, 10 in all
    assert store.records == [(60.0 * minute, "holding") for minute in range(10)]
    assert store.threads == {"hermsd-program"}  # never the loop's thread
    assert 595.0 - store.records[-1][0] == 55.0  # a crash now would cost 55 s of the rest


def test_a_failed_save_is_told_in_the_status_and_once_in_the_log(tmp_path: Path) -> None:
    store = CountingStore(tmp_path)
    driver = ProgramDriver(store, dt.UTC, PERIOD)
    store.refuse = True
    driver.start(LONG_REST, None, setpoint=66.0, wall_ns=AT_4, pv=66.0, tun=PRIOR)
    drive(driver, PERIOD, 66.0)
    assert driver.flush(5.0)
    failing, said = driver.store_news() or (False, "")
    assert failing and said.endswith("No space left on device")
    assert driver.store_news() is None  # said once
    status = driver.status(AT_4)
    assert status is not None and status["save_failed"] == "[Errno 28] No space left on device"
    assert driver.status_words(AT_4).endswith(", progress NOT SAVED")
    store.refuse = False
    driver.command("next", 66.0)  # a new step: saved at once, the program first
    drive(driver, PERIOD, 66.0, t0=PERIOD)
    assert driver.flush(5.0)
    assert driver.store_news() == (False, "the program's progress is saved again")
    assert store.programs == 1 and store.load() is not None
    assert "NOT SAVED" not in driver.status_words(AT_4)


def test_the_writer_outlives_a_fault_that_is_not_an_os_error(tmp_path: Path) -> None:
    """Any fault in a write is said, and the thread goes on to write the next record."""
    store = ProgressStore(tmp_path)
    writer = ProgressWriter(store)
    calls: list[str] = []

    def broken() -> None:
        calls.append("broken")
        raise TypeError("not serialisable")

    writer._put("progress", broken)
    assert writer.flush(5.0)
    assert writer.failure == "TypeError: not serialisable"
    writer.program(REST, AT_4)
    assert writer.flush(5.0) and writer.failure is None
    assert store.path.exists() and calls == ["broken"]
    writer.close(5.0)


def test_a_clear_that_failed_is_tried_again_until_the_stopped_program_is_gone(
    tmp_path: Path,
) -> None:
    """A stopped program left on disk would resume after a crash and heat unattended."""
    store = ProgressStore(tmp_path)
    writer = ProgressWriter(store, clear_retry_s=0.0)
    writer.program(REST, AT_4)
    assert writer.flush(5.0) and store.path.exists()
    failures = iter([OSError(5, "Input/output error")] * 3)
    clear, landed = store.clear, threading.Event()

    def flaky() -> None:
        error = next(failures, None)
        if error is not None:
            raise error
        clear()
        landed.set()

    store.clear = flaky  # type: ignore[method-assign]
    writer.clear()  # the brewer's `program stop`
    assert landed.wait(5.0)  # three failures, then it lands
    assert writer.flush(5.0)
    assert not store.path.exists() and writer.failure is None
    writer.close(5.0)


def test_a_clear_that_keeps_failing_neither_holds_up_nor_outlives_the_shutdown(
    tmp_path: Path,
) -> None:
    store = ProgressStore(tmp_path)
    writer = ProgressWriter(store, clear_retry_s=3600.0)
    tried = threading.Event()
    attempts = []

    def refused() -> None:
        attempts.append(1)
        tried.set()
        raise OSError(30, "Read-only file system")

    store.clear = refused  # type: ignore[method-assign]
    writer.clear()
    assert tried.wait(5.0)
    assert writer.flush(5.0)  # a retry waiting is no write in progress
    assert writer.failure == "[Errno 30] Read-only file system"
    writer.close(5.0)
    assert writer._thread is not None
    writer._thread.join(5.0)
    assert not writer._thread.is_alive() and len(attempts) == 1  # no spinning on the way out
