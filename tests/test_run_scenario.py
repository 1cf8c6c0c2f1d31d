"""`hermsd run --simulate --scenario FILE`: a scenario's tun, config and events run live, so a
brewer can try a HERMS (the status line with the mash and the pump, the pump and the outer
loop in the log) as on a brew day; refused in one line without --simulate or for a bad file.

`scenarios/herms-live.yaml`: the HLT at 66 °C, 50 L of strike water at 39.75 °C and 12 kg of
grain at 20 °C doughed in at 2 min (mixing at (50·4186·39.75 + 12·1700·20) / (50·4186 +
12·1700) = 38.0 °C), the pump started through hermsd at 5 min."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from hermsd.cli import commands as cli
from hermsd.config import schema as config_module
from hermsd.log import reader
from hermsd.sim.live import scenario_daemon
from hermsd.sim.scenario import effective_config, load_scenario

LIVE = Path(__file__).resolve().parents[1] / "scenarios" / "herms-live.yaml"
MIXED_C = (50 * 4186 * 39.75 + 12 * 1700 * 20) / (50 * 4186 + 12 * 1700)  # 38.0 °C
DOUGH_IN_S, PUMP_S = 120.0, 300.0
PREPARED_S = 115.0  # the start is prepared for the HLT law's dead time: control.dead_time's


def test_the_status_line_of_a_live_herms_shows_the_mash_its_aim_and_the_pump() -> None:
    scenario = load_scenario(LIVE)
    lines: list[str] = []
    daemon = scenario_daemon(
        scenario,
        effective_config(config_module.DEFAULT, scenario),
        math.inf,
        on_status=lines.append,
    )
    with daemon:
        daemon.start()
        daemon.run(until=20 * 60.0)
    # before the dough-in the empty tun reads the room, the pump off; after it the mash
    # (near the mix, warming) against the brewer's 66 °C, the pump on through hermsd
    assert "mash 20.0 → 66.0 °C (" in lines[0] and lines[0].endswith("pump off, ok")
    last = lines[-1]
    mash = float(last.split("mash ")[1].split(" →")[0])
    assert MIXED_C - 0.5 < mash < 66.0 and "→ 66.0 °C (" in last and "pump on" in last
    assert last.startswith("HLT ") and "°C → " in last.split(",")[0]  # the HLT's aim first


def test_run_simulate_scenario_logs_the_mash_the_pump_and_the_outer_loop(tmp_path: Path) -> None:
    logs = tmp_path / "logs"
    argv = ["run", "--simulate", "--speed", "max", "--duration", "20m", "--scenario", str(LIVE)]
    assert cli.main([*argv, "--log", str(logs)]) == 0
    day = reader.load(sorted(logs.glob("*.mcap")))
    periods = day.periods
    before = [p for p in periods if p.t < DOUGH_IN_S]
    preparing = [p for p in periods if PUMP_S + 10.0 < p.t < PUMP_S + PREPARED_S - 5.0]
    pumped = [p for p in periods if p.t > PUMP_S + PREPARED_S + 10.0]
    assert before and pumped and periods[-1].t > 19 * 60.0
    assert all(p.mash == pytest.approx(20.0, abs=0.1) and p.pump is False for p in before)
    assert preparing and all(p.pump is False and (p.coil_load or 0.0) > 0.0 for p in preparing)
    assert all(p.pump is True and p.mash is not None and p.mash > MIXED_C - 0.5 for p in pumped)
    # the setpoint is the scenario's, the mash's; the HLT's is the outer loop's, within the limit
    assert {p.setpoint for p in periods} == {66.0}
    assert all(p.hlt_setpoint is not None and p.hlt_setpoint <= 76.0 for p in periods)
    said = [event.message for event in day.events]
    assert "pump on: by the operator" in said
    assert (
        "pump starting in 115 s: by the operator (the coil's load sent ahead to the element)"
        in said
    )


def test_a_scenario_without_simulate_is_refused_in_one_line(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert cli.main(["run", "--scenario", str(LIVE), "--duration", "1s"]) == 2
    assert capsys.readouterr().err.strip().endswith("--scenario goes with --simulate")


def test_a_bad_scenario_is_refused_in_one_line_naming_its_place(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("duration: 1h\nplant:\n  mash: {coil_w_per_k: 5}\n", encoding="utf-8")
    argv = ["run", "--simulate", "--speed", "max", "--duration", "1m", "--scenario", str(bad)]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and f"{bad}:3:" in err and "plant.mash.coil_w_per_k" in err
