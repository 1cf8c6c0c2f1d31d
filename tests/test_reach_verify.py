"""`hermsd replay --verify` re-derives each period's reach ceiling from the log.

The weak tun of test_reach (922 W against UA 25.6 W/K: full power holds 20 + 922/25.6 =
56.0 °C, 10 °C short of 66 °C) is said past half-way (3400 s) within the 6600 s day; its
log's ceilings must be re-derived bit for bit, and one changed, removed or added must fail
the check at that period.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import pytest
from test_reach import WEAK
from test_replay import rewritten, run_cli, stepped

from hermsd.config import schema as config_module
from hermsd.control.factory import make_controller
from hermsd.control.reach import MARGIN_C
from hermsd.log import reader, replay
from hermsd.log.mcap_file import LogFile
from hermsd.log.recorder import Recorder
from hermsd.log.topics import PERIOD_TOPIC
from hermsd.runtime.build import reach_period
from hermsd.runtime.period import PeriodRecord
from hermsd.sim import scenario
from hermsd.sim.clock import VirtualClock
from hermsd.sim.scenario import Event, Scenario
from hermsd.sim.tuns import TunSpec

TRUE_CEILING = 20.0 + 922.0 / 25.6  # °C, the weak tun's (see test_reach.WEAK)


def weak_day(directory: Path, *events: Event, duration: float = 6600.0) -> list[Path]:
    directory.mkdir(exist_ok=True)
    day = Scenario(
        name=WEAK.name, duration=duration, plant=WEAK.plant(), setpoint=66.0, events=events
    )
    scenario.run(day, WEAK.config(config_module.DEFAULT), log_dir=directory)
    return sorted(directory.glob("*.mcap"))


@pytest.fixture(scope="module")
def weak_log(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    return weak_day(tmp_path_factory.mktemp("weak"))


def said(log: reader.Log) -> list[PeriodRecord]:
    """The periods whose record names a ceiling."""
    return [p for p in log.periods if p.ceiling is not None]


def test_the_untouched_log_of_a_tun_too_weak_verifies_with_its_ceilings(
    weak_log: list[Path], capsys: pytest.CaptureFixture[str]
) -> None:
    log = reader.load(weak_log)
    named = said(log)
    assert named and all(
        abs(p.ceiling - TRUE_CEILING) < MARGIN_C for p in named if p.ceiling is not None
    )
    assert 3400.0 < named[0].t < 6600.0 and named[-1] is log.periods[-1]
    assert replay.verify(log.entries) == replay.Verification(len(stepped(log)), 0, None)
    code, out, err = run_cli(capsys, *weak_log, "--verify")
    assert (code, err) == (0, "")
    assert out == f"{len(stepped(log))} periods verified\n"


@pytest.mark.parametrize("change", ["altered", "removed", "added"])
def test_a_ceiling_changed_removed_or_added_fails_at_its_period(
    weak_log: list[Path], change: str
) -> None:
    log = reader.load(weak_log)
    named = said(log)
    if change == "added":  # an hour in: climbing, nothing said yet
        target = next(p for p in log.periods if p.t >= 3600.0)
        logged = 60.0
    else:
        target = named[len(named) // 2]
        logged = None if change == "removed" else (target.ceiling or 0.0) + 0.5
    tampered = [dataclasses.replace(e, ceiling=logged) if e is target else e for e in log.entries]
    result = replay.verify(tampered)
    assert result.mismatch == replay.Mismatch(target.k, target.t, "ceiling", logged, target.ceiling)


def test_the_cli_names_the_period_whose_ceiling_the_file_changed(
    weak_log: list[Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = reader.load(weak_log)
    target = said(log)[10]
    ceiling = target.ceiling or 0.0

    def lower(topic: str, message: dict[str, Any]) -> dict[str, Any]:
        if topic == PERIOD_TOPIC and message["k"] == target.k:
            return {**message, "ceiling": ceiling - 0.1}
        return message

    (tmp_path / "lower").mkdir()
    code, out, _ = run_cli(capsys, *rewritten(weak_log, tmp_path / "lower", lower), "--verify")
    assert code == 1
    assert out.startswith(
        f"period k={target.k} (t {target.t!r} s) differs: ceiling logged {ceiling - 0.1!r}, "
        f"recomputed {ceiling!r}"
    )

    def drop_one(topic: str, message: dict[str, Any]) -> dict[str, Any]:
        if topic == PERIOD_TOPIC and message["k"] == target.k:
            return {k: v for k, v in message.items() if k != "ceiling"}
        return message

    # One record of a daemon that logs ceilings without its own: taken as saying none.
    (tmp_path / "drop").mkdir()
    code, out, _ = run_cli(capsys, *rewritten(weak_log, tmp_path / "drop", drop_one), "--verify")
    assert code == 1
    assert out.startswith(f"period k={target.k} (t {target.t!r} s) differs: ceiling logged None")


def test_a_normal_day_verifies_and_a_ceiling_added_to_it_does_not(tmp_path: Path) -> None:
    # The seed's 90 L, 3 kW tun, an hour of its 80 min climb to 66 °C at full power: its
    # rates are judged, and put the ceiling far above (20 + 1.689 °C/% × 100 % = 189 °C).
    day = Scenario(name="normal", duration=3600.0, events=())
    scenario.run(day, log_dir=tmp_path)
    log = reader.load(sorted(tmp_path.glob("*.mcap")))
    assert not said(log)
    assert replay.verify(log.entries) == replay.Verification(len(stepped(log)), 0, None)
    target = log.periods[600]
    tampered = [dataclasses.replace(e, ceiling=50.0) if e is target else e for e in log.entries]
    assert replay.verify(tampered).mismatch == replay.Mismatch(
        target.k, target.t, "ceiling", 50.0, None
    )


def test_a_new_power_limit_measures_afresh_in_replay_as_in_the_daemon(tmp_path: Path) -> None:
    # Said by 5400 s (it was at 5105 s on the day above); the limit lowered to 90 % then:
    # another full power, what was said of the old one cleared at that period.
    reload = Event(5400.0, "config", {"control": {"max_output": 90.0}})
    paths = weak_day(tmp_path, reload, duration=6000.0)
    log = reader.load(paths)
    before = [p for p in log.periods if p.t < 5400.0]
    after = [p for p in log.periods if p.t >= 5400.0]
    assert before[-1].ceiling is not None and not said(reader.Log(periods=after))
    assert [c.reason for c in log.configs] == ["start", "reload"]
    assert replay.verify(log.entries).mismatch is None


def test_after_missing_records_the_ceiling_is_not_held_against_the_log(
    weak_log: list[Path],
) -> None:
    # What the ten missing periods told the watch is not known (its blocks, and so the line
    # through them, are others without them): nothing after them is checked until the next
    # start, and so nothing is wrongly failed.
    log = reader.load(weak_log)
    gap_from = said(log)[0].k - 100
    entries = [
        e
        for e in log.entries
        if not (isinstance(e, PeriodRecord) and gap_from <= e.k < gap_from + 10)
    ]
    assert replay.verify(entries).mismatch is None


FAR = TunSpec("weak 30 L, far sensor", 30, 1800, 6.0, 180, 120, 20)
"""UA = 17.76·6·(30/90)^⅔ = 51.2 W/K: 1800 W holds 20 + 1800/51.2 = 55.2 °C at most,
τ = 30·4186/51.2 = 2450 s. Heat takes 180 s to the sensor and its lag 120 s more: the
controller's heat-up measures a dead time near 300 s, over half of RISE_FROM_S, where the
config's prior says 115 s."""


def test_the_dead_time_is_the_controllers_heat_up_measurement_re_run_from_the_log(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Cold water at 1500 s (3 L at 5 °C: some 2 °C down) starts the measurement again, after
    # the heat-up measured the dead time: the new run's blocks start two of those after it.
    water = Event(1500.0, "add_water", {"litres": 3.0, "temp": 5.0})
    day = Scenario(
        name=FAR.name, duration=6000.0, plant=FAR.plant(), setpoint=66.0, events=(water,)
    )
    scenario.run(day, FAR.config(config_module.DEFAULT), log_dir=tmp_path)
    log = reader.load(sorted(tmp_path.glob("*.mcap")))
    named = said(log)
    assert named and all(abs(p.ceiling - 55.2) < MARGIN_C for p in named if p.ceiling is not None)
    assert replay.verify(log.entries).mismatch is None
    # Fed the model's dead time instead (a controller that measured nothing), the blocks of
    # the run after the water are others, and the ceilings differ from the daemon's.
    monkeypatch.setattr(
        replay,
        "reach_period",
        lambda reach, record, model, max_output, _: reach_period(
            reach, record, model, max_output, make_controller(config_module.DEFAULT.control)
        ),
    )
    mismatch = replay.verify(log.entries).mismatch
    assert mismatch is not None and mismatch.name == "ceiling" and mismatch.t > 1500.0


def test_a_restart_makes_a_fresh_watch_in_replay_as_in_the_daemon(
    weak_log: list[Path], tmp_path: Path
) -> None:
    # The weak day (said by its end), then the daemon started again two hours later (its
    # monotonic and wall clocks on by as much): its new watch has measured nothing and says
    # nothing, though the water is as far short.
    second = weak_day(tmp_path / "second", duration=900.0)
    later = tmp_path / "later"
    later.mkdir()
    recorder = Recorder(later, now=VirtualClock().monotonic, lossless=True)
    for path in second:
        for topic, log_time_ns, message in LogFile(path).messages():
            moved = {**message, "t": message["t"] + 7200.0} if "t" in message else message
            recorder.write(topic, log_time_ns + 7200 * 1_000_000_000, moved)
    recorder.close()
    log = reader.load([*weak_log, *later.glob("*.mcap")])
    assert [c.reason for c in log.configs] == ["start", "start"] and len(log.runs) == 2
    assert log.periods[1319].ceiling is not None and log.periods[1320].ceiling is None
    assert replay.verify(log.entries).mismatch is None
