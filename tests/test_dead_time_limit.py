"""One limit on the dead time, from the config file to the predictive controller's history.

The controller keeps the outputs still in flight for up to pid.MAX_DEAD_TIME; a config that
accepted more passed `check-config` and then crashed the loop on its first period. Every way
a dead time reaches the loop (the file, a live edit, a scenario's config event, replay's
what-if) is checked at 1800 s (taken), 1800 s + one period and 3600 s (refused, said).
"""

from __future__ import annotations

from pathlib import Path

import pytest
from test_reload import BASE, edited, rename_over, run_for, start

from hermsd.cli import commands as cli
from hermsd.control import laws, pid
from hermsd.log import reader, replay
from hermsd.sim import scenario
from hermsd.sim.scenario import Scenario, ScenarioError, parse_scenario

LIMIT = 1800.0  # s, pid.MAX_DEAD_TIME restated
PERIOD = 5.0  # s, the shipped control period
REFUSED = [LIMIT + PERIOD, 3600.0]


def test_the_limit_is_half_an_hour() -> None:
    assert pid.MAX_DEAD_TIME == LIMIT


@pytest.mark.parametrize("ts", [1.0, 5.0, 7.0, 60.0])
def test_the_predictive_controller_runs_at_the_limit_for_any_period(ts: float) -> None:
    model = pid.PlantModel(1.689, 14961.0, LIMIT, 20.0)
    controller = laws.create("predictive", kc=120.0, ti=800.0, ts=ts, model=model)
    controller.reset(pv=20.0, output=0.0)
    for k in range(round(2 * LIMIT / ts) + 5):  # past a whole dead time of history, twice
        output = controller.step(66.0, 20.0 + 0.01 * k)
        assert 0.0 <= output <= 100.0


@pytest.mark.parametrize("dead_time", REFUSED)
def test_a_model_beyond_the_limit_is_refused_by_the_controller(dead_time: float) -> None:
    model = pid.PlantModel(1.689, 14961.0, dead_time, 20.0)
    with pytest.raises(ValueError, match=r"model\.dead_time.*1800 s"):
        laws.create("predictive", kc=120.0, ti=800.0, ts=PERIOD, model=model)


@pytest.mark.parametrize("dead_time", [LIMIT, *REFUSED])
def test_check_config_takes_the_limit_and_refuses_beyond_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], dead_time: float
) -> None:
    path = tmp_path / "c.yaml"
    path.write_text(f"control:\n  dead_time: {dead_time:g}\n", encoding="utf-8")
    code = cli.main(["check-config", "--simulate", str(path)])
    _out, err = capsys.readouterr()
    if dead_time <= LIMIT:
        assert code == 0
    else:
        assert code != 0
        assert f"{path}:2" in err and "control.dead_time" in err and "1800" in err
        assert "Traceback" not in err


@pytest.mark.parametrize("dead_time", REFUSED)
def test_a_live_edit_beyond_the_limit_is_rejected_and_the_loop_goes_on(
    tmp_path: Path, dead_time: float
) -> None:
    daemon, _world, path, events = start(tmp_path, edited(BASE, control__dead_time=f"{LIMIT:g}"))
    run_for(daemon, 600.0)
    rename_over(path, edited(BASE, control__dead_time=f"{dead_time:g}"))
    run_for(daemon, 600.0)
    assert daemon.config.control.dead_time == LIMIT
    assert events.periods[-1].t >= 1195.0, "the loop went on"
    rejection = [m for m in events.logged() if m.startswith("config rejected")]
    assert len(rejection) == 1 and "control.dead_time" in rejection[0]
    assert daemon.status_text().endswith("ok, config rejected (see journal)")


def _with_config_event(dead_time: float) -> Scenario:
    change = {"control": {"dead_time": dead_time}}
    return parse_scenario({"duration": "30m", "events": [{"at": "10m", "config": change}]})


def test_a_scenario_config_event_at_the_limit_runs() -> None:
    result = scenario.run(_with_config_event(LIMIT))
    assert result.summary["alarms"] == []


@pytest.mark.parametrize("dead_time", REFUSED)
def test_a_scenario_config_event_beyond_the_limit_is_refused(dead_time: float) -> None:
    with pytest.raises(ScenarioError, match=r"events\[0\]\.config.*control\.dead_time"):
        scenario.run(_with_config_event(dead_time))


@pytest.fixture(scope="module")
def short_log(tmp_path_factory: pytest.TempPathFactory) -> reader.Log:
    directory = tmp_path_factory.mktemp("short")
    scenario.run(Scenario(name="short", duration=900.0, events=()), log_dir=directory)
    return reader.load(sorted(directory.glob("*.mcap")))


def test_what_if_at_the_limit_runs(short_log: reader.Log) -> None:
    result = replay.what_if(short_log, replay.parse_what_if(f"dead_time={LIMIT:g}"))
    assert result.settings["what_if"]["dead_time"] == LIMIT


@pytest.mark.parametrize("dead_time", REFUSED)
def test_what_if_beyond_the_limit_is_refused(short_log: reader.Log, dead_time: float) -> None:
    with pytest.raises(reader.ReplayError, match=r"--what-if.*control\.dead_time"):
        replay.what_if(short_log, replay.parse_what_if(f"dead_time={dead_time:g}"))
