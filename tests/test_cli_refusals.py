"""Command-line input a library below would have raised on (or hung on), refused up front
with one clear line; and the simulated sensor read at the real sensor's pace."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import pytest

from hermsd.cli import commands as cli
from hermsd.cli import common
from hermsd.cli import hardware as cli_hardware
from hermsd.sim.scenario import ScenarioError, load_scenario, parse_scenario


@pytest.mark.parametrize("name", ["day.xyz", "day.mcap"])
def test_replay_refuses_a_plot_format_matplotlib_cannot_write_before_reading_the_log(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], name: str
) -> None:
    plot = tmp_path / name
    code = cli.main(["replay", str(tmp_path / "missing.mcap"), "--plot", str(plot)])
    _out, err = capsys.readouterr()
    assert code == common.EXIT_USAGE
    suffix = name.rpartition(".")[2]
    assert err.startswith(f"hermsd: --plot {plot}: cannot draw a .{suffix} file")
    assert ".png" in err and ".svg" in err and ".pdf" in err
    assert not plot.exists()


@pytest.mark.parametrize(
    "table",
    [
        "K=1e308,tau=1e308,theta=1e308",  # overflows the rules to inf
        "K=1,tau=1e30,theta=1",  # finite, but past the 28 digits a setting is rounded in
        "K=1,tau=10,theta=1,a_star=1e-300",  # Kc from a*: 1/(a*·θ)
    ],
)
def test_tune_table_refuses_a_tun_whose_settings_no_tun_needs(
    capsys: pytest.CaptureFixture[str], table: str
) -> None:
    code = cli.main(["tune", "--table", table])
    out, err = capsys.readouterr()
    assert code != 0 and out == ""
    assert err.startswith(f"hermsd: --table: {table}: the rules give settings beyond 1e+12")


def _fifo(tmp_path: Path) -> Path:
    path = tmp_path / "pipe"
    os.mkfifo(path)
    return path


@pytest.mark.parametrize("command", ["simulate --scenario", "replay"])
@pytest.mark.parametrize(
    ("where", "kind"),
    [(_fifo, "a FIFO (named pipe)"), (lambda _: Path("/dev/zero"), "a character device")],
)
def test_a_fifo_or_device_is_refused_without_being_read(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    command: str,
    where: Callable[[Path], Path],
    kind: str,
) -> None:
    path = where(tmp_path)
    code = cli.main([*command.split(), str(path)])  # a read would wait, or never end
    _out, err = capsys.readouterr()
    assert code == common.EXIT_USAGE
    assert err.startswith(f"hermsd: {path}: ") and f"is {kind}, not a regular file" in err


WEEK = 7 * 86400.0  # s, the longest scenario


def test_a_scenario_runs_a_week_at_most() -> None:
    assert parse_scenario({"duration": "168h"}).duration == WEEK
    with pytest.raises(ScenarioError, match=r"duration: 604801 s is longer than a scenario runs"):
        parse_scenario({"duration": "168h0m1s"})
    with pytest.raises(ScenarioError, match=r"duration: 3\.6e\+08 s is longer"):
        parse_scenario({"duration": "100000h"})


def test_an_event_after_the_scenarios_end_is_refused_with_its_place(tmp_path: Path) -> None:
    path = tmp_path / "late.yaml"
    text = "duration: 1h\nevents:\n  - at: 1h\n    setpoint: 70\n  - at: 1h0m1s\n    mode: manual\n"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ScenarioError) as refused:
        load_scenario(path)
    assert str(refused.value).startswith(f"{path}:5:")
    assert "events[1].at: 3601 s lies after the scenario's end (3600 s)" in str(refused.value)


def test_the_simulated_sensor_prints_a_reading_a_second_of_wall_clock(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    slept: list[float] = []
    monkeypatch.setattr(cli_hardware.time, "sleep", slept.append)
    assert cli.main(["sensor", "--simulate", "--count", "4"]) == 0
    out, _err = capsys.readouterr()
    assert len(out.splitlines()) == 1 + 4  # the chip found, then the readings
    assert slept == [1.0, 1.0, 1.0]  # between the readings, on the wall clock
