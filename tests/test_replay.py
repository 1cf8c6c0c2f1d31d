"""Replay: logs of simulated brew days read back, measured, re-run bit for bit, and re-tuned."""

from __future__ import annotations

import csv
import dataclasses
import datetime
import errno
import math
import os
import random
import re
import shutil
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from hermsd.cli import main
from hermsd.commissioning import identify
from hermsd.config import read
from hermsd.config import schema as config_module
from hermsd.control import laws, pid
from hermsd.log import reader, replay
from hermsd.log.mcap_file import LogFile
from hermsd.log.recorder import Recorder
from hermsd.log.topics import (
    CONFIG_TOPIC,
    LOG_TOPIC,
    PERIOD_TOPIC,
    TIMING_TOPIC,
    LogLevel,
    log_message,
)
from hermsd.runtime.period import PeriodRecord
from hermsd.sim import scenario
from hermsd.sim.clock import DEFAULT_EPOCH_NS, VirtualClock
from hermsd.sim.scenario import Event, Scenario

S = 1_000_000_000  # ns per second
PERIOD = 5.0  # s, the default control period

# The seed-001 tun the default scenario simulates (hermsd.sim.hlt.FoptdPlant's defaults).
TRUE_GAIN, TRUE_TAU, TRUE_DEAD_TIME = 1.689, 14961.0, 115.0

EVENTFUL = Scenario(
    name="eventful",
    duration=7800.0,
    events=(
        Event(3600.0, "mode", "manual"),
        Event(3605.0, "output", 30.0),
        Event(4500.0, "mode", "auto"),
        Event(5400.0, "sensor", ("nack", None), 60.0),
        Event(6300.0, "setpoint", 70.0),
    ),
)


def simulated_log(directory: Path, scene: Scenario) -> list[Path]:
    scenario.run(scene, log_dir=directory)
    return sorted(directory.glob("*.mcap"))


@pytest.fixture(scope="module")
def default_day(tmp_path_factory: pytest.TempPathFactory) -> tuple[list[Path], dict[str, Any]]:
    """The reference brew day's log, and what `hermsd simulate` said of it."""
    directory = tmp_path_factory.mktemp("default")
    summary = scenario.run(scenario.DEFAULT, log_dir=directory).summary
    return sorted(directory.glob("*.mcap")), summary


@pytest.fixture(scope="module")
def default_log(default_day: tuple[list[Path], dict[str, Any]]) -> list[Path]:
    return default_day[0]


@pytest.fixture(scope="module")
def eventful_log(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    return simulated_log(tmp_path_factory.mktemp("eventful"), EVENTFUL)


@pytest.fixture(scope="module")
def short_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    [path] = simulated_log(
        tmp_path_factory.mktemp("short"), Scenario(name="short", duration=900.0, events=())
    )
    return path


def rewritten(
    paths: list[Path],
    directory: Path,
    change: Callable[[str, dict[str, Any]], dict[str, Any]] = lambda topic, m: m,
    rotate_s: float = 86400.0,
) -> list[Path]:
    """The messages of `paths` written again (through `change`) by a recorder, in order."""
    clock = VirtualClock()
    recorder = Recorder(directory, now=clock.monotonic, rotate_s=rotate_s, lossless=True)
    for path in paths:
        for topic, log_time_ns, message in LogFile(path).messages():
            recorder.write(topic, log_time_ns, change(topic, message))
    recorder.close()
    return sorted(directory.glob("*.mcap"), key=lambda p: next(LogFile(p).messages()).log_time_ns)


def without_marker(paths: list[Path], directory: Path, marker: str) -> list[Path]:
    """The log as a daemon from before `marker` wrote it: its config records without it."""

    def older(topic: str, message: dict[str, Any]) -> dict[str, Any]:
        if topic == CONFIG_TOPIC:
            return {k: v for k, v in message.items() if k != marker}
        return message

    directory.mkdir()
    return rewritten(paths, directory, older)


def run_cli(capsys: pytest.CaptureFixture[str], *argv: str | Path) -> tuple[int, str, str]:
    code = main(["replay", *map(str, argv)])
    out, err = capsys.readouterr()
    return code, out, err


# -- reading ------------------------------------------------------------------------------------


def test_a_simulated_brew_day_is_logged_whole(default_log: list[Path]) -> None:
    log = reader.load(default_log)
    # 6 h at one period every 5 s, the first at t = 0: nothing dropped on the way.
    assert [p.k for p in log.periods] == list(range(1, 4321))
    assert replay.timing(log)["dropped"] == 0


def test_the_summary_measures_the_day_the_simulator_measured(
    default_day: tuple[list[Path], dict[str, Any]],
) -> None:
    paths, simulated = default_day
    summary = replay.summarise(reader.load(paths))
    [file] = summary["files"]
    assert file["finished"] and file["cut_at"] is None
    assert file["periods"] == summary["periods"] == 4320
    assert summary["duration_s"] == 21595.0
    assert summary["cold_water_at_s"] == [14400.0]  # the default scenario's 10 L at 4 h
    # The simulator measures the sensor's exact temperature, replay the logged PV (mean of
    # 0.0625 °C readings); each says so, and the simulator gives the PV's overshoot too.
    assert summary["temperature"] == "the logged PV (the mean of each period's LM92 readings)"
    assert simulated["temperature"].startswith("the simulated sensor's exact temperature")
    assert summary["overshoot_c"] == simulated["pv_overshoot_c"]
    assert summary["overshoot_c"] == pytest.approx(simulated["overshoot_c"], abs=0.0625)
    assert summary["settle_s"] == pytest.approx(simulated["settle_s"], abs=2 * PERIOD)
    assert summary["recovery_s"] == pytest.approx(simulated["recovery_s"], abs=2 * PERIOD)
    assert summary["mean_applied_pct"] == pytest.approx(simulated["mean_output"], abs=0.05)
    assert summary["alarms"] == []
    assert summary["timing"]["overruns"] == 0


def test_files_are_joined_and_a_rotated_file_repeats_its_config(
    eventful_log: list[Path], tmp_path: Path
) -> None:
    hourly = rewritten(eventful_log, tmp_path, rotate_s=3600.0)
    assert len(hourly) == 3
    whole, split = reader.load(eventful_log), reader.load(hourly)
    assert split.periods == whole.periods
    assert split.elapsed == whole.elapsed
    assert len(split.configs) == 3  # the start, and its repeat at the head of each new file
    assert replay.verify(split.entries) == replay.verify(whole.entries)


def two_runs(directory: Path, duration: float = 1800.0) -> tuple[list[Path], list[Path]]:
    """Two simulated runs of one scenario, the second started an hour after the first ended:
    both start at t = 0 with the same config record."""
    later = (DEFAULT_EPOCH_NS + round(duration + 3600.0) * S, datetime.UTC)
    first, second = (
        simulated_log(directory / name, Scenario(name="run", duration=duration, clock=clock))
        for name, clock in (("first", None), ("second", later))
    )
    return first, second


def test_two_runs_that_start_alike_are_two_starts_not_a_rotated_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    first, second = two_runs(tmp_path)
    alone = [replay.verify(reader.load(paths).entries) for paths in (first, second)]
    assert alone == [replay.Verification(360, 0, None)] * 2
    log = reader.load([*first, *second])
    [start, restart] = log.configs
    assert dataclasses.replace(restart, repeat=False) == start  # t = 0, reason start, alike
    assert not restart.repeat and len(log.runs) == 2
    # The restart makes a fresh controller, as the daemon's second start did.
    assert replay.verify(log.entries) == replay.Verification(720, 0, None)
    code, out, _ = run_cli(capsys, "--verify", *first, *second)
    assert code == 0 and "720 periods verified" in out


def test_a_rotated_run_then_another_run_tells_the_repeats_from_the_start(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    first, second = two_runs(tmp_path)
    (tmp_path / "rotated").mkdir()
    rotated = rewritten(first, tmp_path / "rotated", rotate_s=700.0)
    assert len(rotated) == 3
    log = reader.load([*rotated, *second])
    assert [c.repeat for c in log.configs] == [False, True, True, False]
    assert replay.verify(log.entries) == replay.Verification(720, 0, None)
    # Files of a recorder without run ids: the second run's periods count from k = 1 again.
    monkeypatch.setattr(reader, "METADATA_NAME", "no such metadata")
    log = reader.load([*rotated, *second])
    assert [c.repeat for c in log.configs] == [False, True, True, False]
    assert replay.verify(log.entries) == replay.Verification(720, 0, None)


def test_a_line_that_opens_a_rotated_file_keeps_its_time(tmp_path: Path) -> None:
    first, _ = two_runs(tmp_path)
    (tmp_path / "rotated").mkdir()
    rotated = rewritten(first, tmp_path / "rotated", rotate_s=600.0)
    # The last file opens with the line of the stop at 1800 s, after the config's repeat.
    last = list(LogFile(rotated[-1]).messages())
    assert [topic for topic, _, _ in last] == [CONFIG_TOPIC, LOG_TOPIC]
    whole = reader.load(first).events
    assert whole[-1].message == "heater off: stopped" and whole[-1].at == 1800.0
    assert reader.load(rotated).events == whole


# -- golden values --------------------------------------------------------------------------


def period(k: int, t: float, pv: float | None, applied: float, **extra: Any) -> dict[str, Any]:
    record = PeriodRecord(
        t=t,
        k=k,
        setpoint=60.0,
        pv=pv,
        readings=[] if pv is None else [pv],
        output=applied,
        applied=applied,
        p=0.0,
        i=0.0,
        d=0.0,
        mode="auto",
        algorithm="predictive",
        state="ok",
        alarms=[],
        heater_allowed=True,
    )
    return dataclasses.asdict(dataclasses.replace(record, **extra))


def logged_config(t: float, reason: str = "start", **control: Any) -> dict[str, Any]:
    config = read.to_dict(config_module.DEFAULT)
    config["tun"]["element_watts"] = 2000.0
    config["control"].update(period=10.0, **control)
    return {"t": t, "config": config, "reason": reason, "control_law": pid.CONTROL_LAW_VERSION}


def write_log(directory: Path, messages: list[tuple[str, float, dict[str, Any]]]) -> Path:
    """Messages at wall-clock seconds after the simulator's epoch, in one finished file."""
    directory.mkdir(exist_ok=True)
    clock = VirtualClock()
    recorder = Recorder(directory, now=clock.monotonic, lossless=True)
    for topic, wall_s, message in messages:
        recorder.write(topic, DEFAULT_EPOCH_NS + round(wall_s * S), message)
    recorder.close()
    [path] = directory.glob("*.mcap")
    return path


def hand_made_day(directory: Path) -> Path:
    """Six periods 10 s apart on a 2 kW element, a sensor fault told and a stale one not."""
    pvs = [58.0, 59.7, 60.2, 60.6, 60.3, 59.9]
    applied = [0.0, 100.0, 50.0, 0.0, 20.0, 30.0]
    alarms = [[], [], [], [], ["sensor_fault"], ["sensor_fault", "stale_reading"]]
    messages: list[tuple[str, float, dict[str, Any]]] = [(CONFIG_TOPIC, 0.0, logged_config(100.0))]
    for k in range(1, 7):
        t = 90.0 + 10.0 * k
        record = period(k, t, pvs[k - 1], applied[k - 1], alarms=alarms[k - 1])
        messages.append((PERIOD_TOPIC, t - 100.0, record))
    event = log_message(LogLevel.WARNING, "fault sensor_fault: read failed: NACK; heater off", 0)
    messages.append((LOG_TOPIC, 35.0, event))
    for i, overruns in enumerate([1, 3, 2]):  # the third follows a restart of the daemon
        timing = {"t": 100.0 + i, "period_lateness_p99": 0.002 * (i + 1), "overruns": overruns}
        messages.append((TIMING_TOPIC, float(i), {**timing, "dropped": 0}))
    return write_log(directory, messages)


def test_golden_summary_of_a_hand_made_day(tmp_path: Path) -> None:
    log = reader.load([hand_made_day(tmp_path)])
    summary = replay.summarise(log)
    assert log.elapsed == [0.0, 10.0, 20.0, 30.0, 40.0, 50.0]
    assert summary["duration_s"] == 50.0
    # In band (60 ± 0.5) from 59.7 on: 5 samples of 10 s, all but 60.6 inside.
    assert summary["in_band_s"] == 40.0
    assert summary["in_band_pct"] == 80.0
    assert summary["overshoots"] == 1
    assert summary["overshoot_c"] == pytest.approx(0.6)
    # IAE from 60.2, the first sample at the setpoint: (0.2 + 0.6 + 0.3 + 0.1)·10 s.
    assert summary["iae"] == pytest.approx(12.0)
    # The first period follows nothing; then 100, 50, 0, 20 and 30 % for 10 s each: 40 %
    # of 50 s at 2 kW is 40 kJ.
    mean, energy = replay.delivered(log)
    assert mean == pytest.approx(40.0)
    assert energy == pytest.approx(40_000.0 / 3.6e6)
    assert summary["alarms"] == [
        {"kind": "sensor_fault", "at_s": 35.0, "message": "read failed: NACK"},
        {"kind": "stale_reading", "at_s": 50.0, "message": None},
    ]
    # Overruns 1, then 3, then 2 after a restart: 3 + 2. The worst p99 is the third's 6 ms.
    assert summary["timing"]["overruns"] == 5
    assert summary["timing"]["period_lateness_p99_ms"] == 6.0


def rebooted_day(directory: Path) -> tuple[Path, Path]:
    """Two runs' files, two periods each: 10 s and 20 s after the epoch, then a reboot
    (monotonic time starts again at 3 s) and 100 s of wall clock later two more."""
    first = write_log(
        directory / "a",
        [(PERIOD_TOPIC, 10.0 * k, period(k, 500.0 + 10.0 * k, 60.0, 0.0)) for k in (1, 2)],
    )
    second = write_log(
        directory / "b",
        [(PERIOD_TOPIC, 120.0 + 10.0 * k, period(k, 3.0 + 10.0 * k, 60.0, 0.0)) for k in (0, 1)],
    )
    return first, second


def test_a_file_whose_clock_starts_again_continues_the_day(tmp_path: Path) -> None:
    first, second = rebooted_day(tmp_path)
    assert reader.load([first, second]).elapsed == [0.0, 10.0, 110.0, 120.0]


# -- verify -------------------------------------------------------------------------------------


def stepped(log: reader.Log) -> list[PeriodRecord]:
    return [p for p in log.periods if p.mode == "auto" and p.heater_allowed and p.pv is not None]


def test_verify_reproduces_a_day_with_manual_spells_and_a_sensor_fault(
    eventful_log: list[Path],
) -> None:
    log = reader.load(eventful_log)
    assert any(p.mode == "manual" for p in log.periods)
    assert any(not p.heater_allowed for p in log.periods)
    assert sum(p.reset_from is not None for p in log.periods) >= 3  # start, auto, after fault
    result = replay.verify(log.entries)
    assert result == replay.Verification(len(stepped(log)), 0, None)


def test_verify_passes_on_the_step_mash_brew_day_with_its_reloads(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Rests and a retune as config reloads, a manual spell and a sensor fault, re-run exactly."""
    brew_day = scenario.load_scenario(Path(__file__).parent.parent / "scenarios" / "brew-day.yaml")
    paths = simulated_log(tmp_path, brew_day)
    log = reader.load(paths)
    reasons = [m["reason"] for topic, _, m in _messages(paths) if topic == "/hermsd/config"]
    assert reasons.count("reload") == 3
    assert any(p.mode == "manual" for p in log.periods)
    assert any(not p.heater_allowed for p in log.periods)
    code, out, err = run_cli(capsys, *paths, "--verify")
    assert code == 0, err
    assert f"{len(stepped(log))} periods verified" in out


def _messages(paths: list[Path]) -> Iterator[tuple[str, int, dict[str, Any]]]:
    for path in paths:
        yield from LogFile(path).messages()


def test_verify_names_the_first_period_that_differs(eventful_log: list[Path]) -> None:
    log = reader.load(eventful_log)
    target = stepped(log)[1000]
    for name, change in (
        ("output", {"output": math.nextafter(target.output, math.inf)}),
        ("output", {"pv": target.pv + 0.0625}),  # an input changed: the output follows it
        ("i", {"i": target.i + 1e-9}),
    ):
        tampered = [dataclasses.replace(e, **change) if e is target else e for e in log.entries]
        result = replay.verify(tampered)
        assert result.mismatch is not None
        assert (result.mismatch.k, result.mismatch.name) == (target.k, name)
        assert result.verified == 1000


def test_the_cli_verifies_and_fails_on_a_tampered_file(
    eventful_log: list[Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, err = run_cli(capsys, *eventful_log, "--verify")
    assert (code, err) == (0, "")
    assert out == f"{len(stepped(reader.load(eventful_log)))} periods verified\n"

    def nudge(topic: str, message: dict[str, Any]) -> dict[str, Any]:
        if topic == PERIOD_TOPIC and message["k"] == 700:
            return {**message, "output": message["output"] + 1e-6}
        return message

    code, out, _ = run_cli(capsys, *rewritten(eventful_log, tmp_path, nudge), "--verify")
    assert code == 1
    assert out.startswith("period k=700 (t 3495.0 s) differs: output logged")


def test_verify_resumes_at_the_next_reset_after_missing_records(eventful_log: list[Path]) -> None:
    log = reader.load(eventful_log)
    missing = {p.k for p in log.periods if 200 <= p.k < 210}
    entries = [e for e in log.entries if not (isinstance(e, PeriodRecord) and e.k in missing)]
    result = replay.verify(entries)
    # From k = 210 on nothing is re-run until manual mode ends with a reset (at 4500 s).
    auto_again = next(p.k for p in log.periods if p.reset_from is not None and p.t >= 4500.0)
    skipped = [p for p in stepped(log) if 210 <= p.k < auto_again]
    assert result.mismatch is None
    assert result.unknown_state == len(skipped) > 0
    assert result.verified == len(stepped(log)) - len(skipped) - len(missing)


def synthetic_reload_day() -> list[dict[str, Any]]:
    """A day's config and period records around a reload, its outputs from pid directly.

    Period 7 runs with the reloaded gains: the reload is recorded in that period, at its t,
    and the period says the new controller was reset to the output it took over.
    """
    setpoint, ts = 60.0, 10.0
    pvs = [50.0, 50.4, 51.0, 51.9, 52.6, 53.5, 54.1, 54.9, 55.4, 56.0]
    gains = [(120.0, 800.0), (40.0, 300.0)]
    records = []
    controller = laws.create("predictive", kc=gains[0][0], ti=gains[0][1], ts=ts)
    output = applied = 0.0
    for k, pv in enumerate(pvs, start=1):
        reset_from = None
        if k in (1, 7):
            if k == 7:
                controller = laws.create("predictive", kc=gains[1][0], ti=gains[1][1], ts=ts)
            reset_from = output
            controller.reset(pv, reset_from)
        output = controller.step(setpoint, pv, applied)
        p, i, d = controller.terms
        records.append(
            period(k, 10.0 * k, pv, applied, output=output, p=p, i=i, d=d, reset_from=reset_from)
        )
        applied = round(output)  # what the SSR delivered, not quite what was asked
    return records


def test_verify_follows_a_reload(tmp_path: Path) -> None:
    records = synthetic_reload_day()
    start = logged_config(0.0, kc=120.0, ti=800.0)
    reload = logged_config(70.0, "reload", kc=40.0, ti=300.0)
    # The reload is handed to the recorder after the period it belongs to: the same t sorts
    # it first all the same.
    messages = [(CONFIG_TOPIC, 0.0, start)]
    for record in records:
        messages.append((PERIOD_TOPIC, record["t"], record))
        if record["k"] == 7:
            messages.append((CONFIG_TOPIC, record["t"] + 0.001, reload))
    log = reader.load([write_log(tmp_path, messages)])
    assert replay.verify(log.entries) == replay.Verification(10, 0, None)
    without_reload = [
        e for e in log.entries if not (isinstance(e, reader.LoggedConfig) and e.reason == "reload")
    ]
    mismatch = replay.verify(without_reload).mismatch
    assert mismatch is not None and mismatch.k == 7


@pytest.mark.parametrize(
    ("at", "tun"),
    [
        (1500.0, {"lid": "off"}),  # in the heat-up, the model as it was
        (6000.0, {"name": "Kettle"}),  # in the hold
        (1500.0, {"litres": 100}),  # a new fill: the model rescaled
        (6000.0, {"litres": 100}),
    ],
)
def test_verify_follows_a_reload_that_changes_only_the_tun(
    tmp_path: Path, at: float, tun: dict[str, Any]
) -> None:
    """The daemon makes a new controller for a new tun (the heat-up's measurement forgotten)
    and logs the reload with the model it then uses: replay does the same."""
    day = Scenario(name="tun", duration=at + 600.0, events=(Event(at, "config", {"tun": tun}),))
    scenario.run(day, log_dir=tmp_path)
    log = reader.load(sorted(tmp_path.glob("*.mcap")))
    configs = [e for e in log.entries if isinstance(e, reader.LoggedConfig)]
    reloads = [e for e in configs if e.reason == "reload"]
    assert len(reloads) == 1 and reloads[0].config["tun"] | tun == reloads[0].config["tun"]
    result = replay.verify(log.entries)
    assert result.mismatch is None and result.verified == len(log.periods)


# -- what if ------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def default_what_if(default_log: list[Path]) -> replay.WhatIf:
    return replay.what_if(reader.load(default_log), {})


def test_the_fitted_model_is_the_simulated_tun(default_what_if: replay.WhatIf) -> None:
    model = default_what_if.model
    assert model.gain == pytest.approx(TRUE_GAIN, rel=0.02)
    assert model.tau == pytest.approx(TRUE_TAU, rel=0.03)
    # PV is the mean of a period's readings, half a period behind its end: θ + 2.5 s.
    assert abs(model.dead_time - TRUE_DEAD_TIME) <= PERIOD
    assert model.ambient == pytest.approx(20.0, abs=0.5)
    assert model.start == pytest.approx(20.0, abs=0.1)
    assert model.rms < 0.02
    assert model.fit_s <= 4 * 3600.0 + PERIOD  # the fit stops at the cold water


def test_what_if_with_the_logged_settings_predicts_the_logged_day(
    default_what_if: replay.WhatIf,
) -> None:
    logged, predicted = default_what_if.logged, default_what_if.what_if
    assert default_what_if.settings["what_if"] == default_what_if.settings["logged"]
    assert predicted["overshoot_c"] == pytest.approx(logged["overshoot_c"], abs=0.1)
    assert predicted["settle_s"] == pytest.approx(logged["settle_s"], rel=0.02)
    # The cold water is poured in again (assumed at the ambient temperature, not 15 °C).
    assert predicted["recovery_s"] == pytest.approx(logged["recovery_s"], rel=0.1)


def test_what_if_runs_other_settings_and_says_so(
    default_log: list[Path], capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, err = run_cli(capsys, *default_log, "--what-if", "kc=40,ti=2000")
    assert (code, err) == (0, "")
    lines = out.splitlines()
    assert lines[0].startswith("tun model: K 1.6")
    assert lines[1].split() == ["logged", "what-if"]
    assert ["kc", "120.0", "40.0"] in [line.split() for line in lines]
    settle = next(line.split() for line in lines if line.startswith("settle_s"))
    assert float(settle[2]) > float(settle[1])  # a gentler loop settles later


def test_what_if_repeats_the_operator_actions_of_the_day(eventful_log: list[Path]) -> None:
    log = reader.load(eventful_log)
    model = identify.TunModel(TRUE_GAIN, TRUE_TAU, TRUE_DEAD_TIME, 20.0, 20.0, 0.0, 0.0)
    events = replay._replayed_events(log, config_module.DEFAULT, model, [])
    # Manual at 3600 s holds the output of the moment (full power), 30 % from 3605 s, auto
    # again at 4500 s, 70 °C at 6300 s: each half a period before the period it took effect
    # in. The sensor fault is no operator action.
    assert events == [
        Event(3597.5, "output", 100.0),
        Event(3602.5, "output", 30.0),
        Event(4497.5, "mode", "auto"),
        Event(6297.5, "setpoint", 70.0),
    ]


@pytest.mark.parametrize(
    ("setting", "complaint"),
    [("gain=2", "not key=value"), ("kc=-5", "control.kc"), ("algorithm=fuzzy", "algorithm")],
)
def test_bad_what_if_settings_are_one_line(
    default_log: list[Path], capsys: pytest.CaptureFixture[str], setting: str, complaint: str
) -> None:
    code, out, err = run_cli(capsys, *default_log, "--what-if", setting)
    assert (code, out) == (2, "")
    assert err.count("\n") == 1 and complaint in err and err.startswith("hermsd: ")


# -- CSV and plot -------------------------------------------------------------------------------


def test_csv_has_every_field_of_every_period(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = hand_made_day(tmp_path)
    target = tmp_path / "day.csv"
    code, _, _ = run_cli(capsys, path, "--csv", target)
    assert code == 0
    with target.open(newline="") as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == [f.name for f in dataclasses.fields(PeriodRecord)]
    assert [float(r["pv"]) for r in rows] == [58.0, 59.7, 60.2, 60.6, 60.3, 59.9]
    assert rows[5]["alarms"] == "sensor_fault stale_reading"
    assert (rows[0]["reset_from"], rows[0]["heater_allowed"]) == ("", "true")


def test_plot_draws_a_png(
    eventful_log: list[Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    target = tmp_path / "day.png"
    code, _, err = run_cli(capsys, *eventful_log, "--plot", target)
    assert (code, err) == (0, "")
    assert target.read_bytes().startswith(b"\x89PNG\r\n\x1a\n")


def test_plot_without_matplotlib_says_how_to_get_it(
    short_log: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib raises ImportError
    code, out, err = run_cli(capsys, short_log, "--plot", tmp_path / "day.png")
    assert (code, out) == (2, "")
    assert err.count("\n") == 1 and "uv sync --extra plot" in err


@pytest.mark.parametrize("option", ["--csv", "--plot"])
def test_an_existing_file_is_never_written_over_the_log_read_least_of_all(
    short_log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], option: str
) -> None:
    first, second = tmp_path / "a.mcap", tmp_path / "b.mcap"
    shutil.copyfile(short_log, first)
    shutil.copyfile(short_log, second)
    data = short_log.read_bytes()
    for argv in ([first, option, first], [option, first, second]):  # the shell's logs/*.mcap
        code, out, err = run_cli(capsys, *argv)
        assert (code, out) == (2, "")
        exists = f"hermsd: {first}: exists; name another file or remove it first\n"
        # --plot refuses a log's name by its suffix before it looks whether it exists
        assert err == exists if option == "--csv" else "cannot draw a .mcap file" in err
        assert first.read_bytes() == data == second.read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.mcap", "b.mcap"]


def test_a_csv_cut_by_a_full_disk_leaves_no_file(
    short_log: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    cells = 0

    def full_after_some_rows(value: object) -> str:
        nonlocal cells
        cells += 1
        if cells > 500:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return str(value)

    monkeypatch.setattr(replay, "_cell", full_after_some_rows)
    code, out, err = run_cli(capsys, short_log, "--csv", tmp_path / "day.csv")
    assert (code, out) == (2, "")
    assert err == f"hermsd: {tmp_path / 'day.csv'}: cannot write: {os.strerror(errno.ENOSPC)}\n"
    assert list(tmp_path.iterdir()) == []


# -- damaged and wrong files --------------------------------------------------------------------


def cut_offsets(size: int, count: int) -> Iterator[int]:
    rng = random.Random(20260101)
    yield from (0, 1, 8, 9, size - 1)
    yield from sorted(rng.sample(range(10, size - 1), count))


def test_a_log_cut_anywhere_is_summarised_or_refused_in_one_line(
    short_log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = short_log.read_bytes()
    part = tmp_path / "hermsd-cut.mcap.part"
    summaries = 0
    for cut in cut_offsets(len(data), 100):
        part.write_bytes(data[:cut])
        periods = sum(1 for _ in LogFile(part).messages([PERIOD_TOPIC]))
        code, out, err = run_cli(capsys, part)
        if periods:
            summaries += 1
            assert (code, err) == (0, ""), cut
            assert f"{periods} control periods" in out, cut
            assert "not finished, complete up to byte" in out, cut
        else:  # cut before the first chunk was complete
            assert (code, out) == (2, ""), cut
            assert err.count("\n") == 1 and err.startswith("hermsd: "), cut
        # What a cut leaves is the day as it was, so far: it verifies.
        code, out, err = run_cli(capsys, part, "--verify")
        assert code == (0 if periods else 2), cut
    assert 0 < summaries < 105  # cuts before and after the first complete chunk were tried


@pytest.mark.parametrize(
    ("content", "complaint"),
    [(None, "no such file"), (b"", "empty"), (b"hello, brewer\n", "not an MCAP file")],
)
def test_wrong_files_are_refused_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], content: bytes | None, complaint: str
) -> None:
    path = tmp_path / "log.mcap"
    if content is not None:
        path.write_bytes(content)
    code, out, err = run_cli(capsys, path)
    assert (code, out) == (2, "")
    assert err == f"hermsd: {path}: " + err.split(": ", 2)[2]
    assert err.count("\n") == 1 and complaint in err


# -- the files of one day -----------------------------------------------------------------------


def test_a_file_named_twice_is_refused(
    short_log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, err = run_cli(capsys, short_log, short_log)
    assert (code, out) == (2, "")
    assert err == f"hermsd: {short_log} is given twice: name each file once\n"
    copy = tmp_path / "copy.mcap"
    copy.write_bytes(short_log.read_bytes())
    code, out, err = run_cli(capsys, short_log, copy)
    assert (code, out) == (2, "")
    assert err.startswith(f"hermsd: {copy} and {short_log} hold the same control periods (k=1 ")


def test_files_named_out_of_order_are_read_in_the_order_of_their_records(
    eventful_log: list[Path], tmp_path: Path
) -> None:
    hourly = rewritten(eventful_log, tmp_path, rotate_s=3600.0)
    in_order, reversed_order = reader.load(hourly), reader.load(hourly[::-1])
    assert [f.path for f in reversed_order.files] == [str(p) for p in hourly]
    assert reversed_order.periods == in_order.periods
    assert reversed_order.elapsed == in_order.elapsed
    assert replay.summarise(reversed_order) == replay.summarise(in_order)
    assert [run["files"] for run in in_order.runs] == [[str(p) for p in hourly]]


def test_two_simulated_runs_in_one_folder_are_not_one_day(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    scene = Scenario(name="short", duration=600.0, events=())
    scenario.run(scene, log_dir=tmp_path)
    scenario.run(dataclasses.replace(scene, setpoint=70.0), log_dir=tmp_path)
    files = sorted(tmp_path.glob("*.mcap"))
    assert len(files) == 2  # both start at the simulator's epoch: -1 names the second
    runs = [LogFile(p).metadata()["hermsd"]["run"] for p in files]
    assert runs[0] != runs[1]
    code, out, err = run_cli(capsys, *files)
    assert (code, out) == (2, "")
    assert err.count("\n") == 1
    assert "overlaps" in err and "replay each run on its own" in err
    for run, path in zip(runs, files, strict=True):
        assert f"run {run} from 2026-01-01T00:00:00Z: {path}" in err


def test_a_restart_is_one_day_in_two_runs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    first, second = rebooted_day(tmp_path)
    code, out, err = run_cli(capsys, second, first)
    assert (code, err) == (0, "")
    runs = [LogFile(p).metadata()["hermsd"]["run"] for p in (first, second)]
    assert f"run 1 of 2 (id {runs[0]}), from 2026-01-01T00:00:10Z: {first}\n" in out
    assert f"run 2 of 2 (id {runs[1]}), from 2026-01-01T00:02:00Z: {second}\n" in out
    assert re.search(r"^periods +4$", out, re.MULTILINE)
    assert re.search(r"^duration_s +120.0$", out, re.MULTILINE)  # joined by the 100 s gap


# -- the command line ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    "argv",
    [("replay", "{log}"), ("replay", "{log}", "--json"), ("check-config", "{config}")],
    ids=["replay", "replay-json", "check-config"],
)
def test_a_reader_that_goes_away_ends_the_command_quietly(
    short_log: Path, tmp_path: Path, argv: tuple[str, ...]
) -> None:
    """As `hermsd replay … | head`: the pipe is closed before the first line is written."""
    config = tmp_path / "hermsd.yaml"
    config.write_text("control:\n  setpoint: 66\n")
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        done = subprocess.run(
            [sys.executable, "-m", "hermsd.cli"]
            + [a.format(log=short_log, config=config) for a in argv],
            stdout=write_end,
            stderr=subprocess.PIPE,
            text=True,
            timeout=60,
        )
    finally:
        os.close(write_end)
    assert done.stderr == ""
    assert done.returncode == 128 + signal.SIGPIPE


def test_what_if_needs_its_settings_and_says_so_when_given_a_file(
    short_log: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    for argv in (("--what-if", short_log), ("--what-if", short_log, short_log)):
        code, out, err = run_cli(capsys, *argv)
        assert (code, out) == (2, ""), argv
        assert err == (
            f"hermsd: --what-if takes settings, not the log file '{short_log}': write "
            "--what-if kc=80,ti=600 (or --what-if logged for the logged ones) after the files\n"
        )
    with pytest.raises(SystemExit) as exit_:
        run_cli(capsys, short_log, "--what-if")
    assert exit_.value.code == 2
    assert "argument --what-if: expected one argument" in capsys.readouterr().err
    assert replay.parse_what_if("logged") == {}


def test_the_logged_model_says_whether_its_losses_were_measured() -> None:
    four = {"gain": 1.689, "tau": 14961.0, "dead_time": 115.0, "ambient": 20.0}

    def entry(model: dict[str, Any]) -> reader.LoggedConfig:
        return reader.LoggedConfig(0.0, "start", {}, model=model)

    assert replay.logged_model(entry({**four, "measured": True})) == pid.PlantModel(
        1.689, 14961.0, 115.0, 20.0, measured=True
    )
    # A log of control law 5 or before has the four figures alone: the prior's landing.
    assert replay.logged_model(entry(four)) == pid.PlantModel(1.689, 14961.0, 115.0, 20.0)
    with pytest.raises(ValueError, match="measured is 'yes'"):
        replay.logged_model(entry({**four, "measured": "yes"}))
