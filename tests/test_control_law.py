"""A log names its control law, and `hermsd replay --verify` re-runs only its own law's logs.

A log written by another law (`pid.CONTROL_LAW_VERSION` bumped since) or by a daemon from
before the version was logged is not wrong, only not this hermsd's to re-run: its decisions
would come out otherwise. `--verify` says so in one line, exits 0 and never says "verified";
the summary, the CSV, the plot and `hermsd tune FILE` read it as they read any log.
"""

from __future__ import annotations

import csv
import dataclasses
import json
from pathlib import Path
from typing import Any

import pytest
from test_replay import rewritten, run_cli, stepped, without_marker

from hermsd.cli import main
from hermsd.control import pid
from hermsd.log import reader, replay
from hermsd.log.mcap_file import LogFile
from hermsd.log.topics import CONFIG_TOPIC
from hermsd.sim import scenario

LAW = pid.CONTROL_LAW_VERSION


@pytest.fixture(scope="module")
def fresh_log(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """The reference tun heated from 20 °C and held at 66 °C for 2.5 h (enough for tune),
    in files rotated every hour, so that rotated files open with the config record again."""
    directory = tmp_path_factory.mktemp("fresh")
    day = dataclasses.replace(scenario.DEFAULT, duration=2.5 * 3600.0, events=())
    scenario.run(day, log_dir=directory)
    paths = sorted(directory.glob("*.mcap"))
    again = tmp_path_factory.mktemp("rotated")
    return rewritten(paths, again, rotate_s=3600.0)


@pytest.fixture(scope="module")
def unnamed_log(fresh_log: list[Path], tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """The day as a daemon from before the law was logged wrote it: config records without."""
    return without_marker(fresh_log, tmp_path_factory.mktemp("unnamed") / "log", "control_law")


@pytest.fixture(scope="module")
def next_law_log(fresh_log: list[Path], tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """The day as a daemon of the next control law wrote it."""

    def next_law(topic: str, message: dict[str, Any]) -> dict[str, Any]:
        return {**message, "control_law": LAW + 1} if topic == CONFIG_TOPIC else message

    return rewritten(fresh_log, tmp_path_factory.mktemp("next"), next_law)


def logged_laws(paths: list[Path]) -> list[object]:
    """The `control_law` of every config record in the files, as written."""
    return [
        message.get("control_law", "absent")
        for path in paths
        for topic, _, message in LogFile(path).messages()
        if topic == CONFIG_TOPIC
    ]


def test_every_config_record_of_a_fresh_log_names_this_law(fresh_log: list[Path]) -> None:
    assert len(fresh_log) == 3  # 2.5 h in files of an hour: two repeats of the record
    assert logged_laws(fresh_log) == [LAW, LAW, LAW]
    log = reader.load(fresh_log)
    assert [(c.control_law, c.repeat) for c in log.configs] == [
        (LAW, False),
        (LAW, True),
        (LAW, True),
    ]


def test_a_fresh_log_is_re_run_and_verified(
    fresh_log: list[Path], capsys: pytest.CaptureFixture[str]
) -> None:
    log = reader.load(fresh_log)
    assert replay.verify(log.entries) == replay.Verification(len(stepped(log)), 0, None)
    code, out, err = run_cli(capsys, *fresh_log, "--verify")
    assert (code, out, err) == (0, f"{len(stepped(log))} periods verified\n", "")


@pytest.mark.parametrize(
    ("fixture", "written"),
    [
        ("unnamed_log", "a control law before law 1 (its log names none)"),
        ("next_law_log", f"control law {LAW + 1}"),
    ],
)
def test_a_log_of_another_law_is_named_and_not_re_run(
    fixture: str, written: str, request: pytest.FixtureRequest, capsys: pytest.CaptureFixture[str]
) -> None:
    paths: list[Path] = request.getfixturevalue(fixture)
    log = reader.load(paths)
    assert log.periods and stepped(log)
    other = replay.OtherLaw(None if fixture == "unnamed_log" else LAW + 1, LAW, False)
    assert replay.verify(log.entries) == replay.Verification(0, 0, None, other)
    code, out, err = run_cli(capsys, *paths, "--verify")
    assert (code, err) == (0, "")
    assert out == f"written by {written}, not re-run (this hermsd runs control law {LAW})\n"
    assert "verified" not in out
    code, out, _ = run_cli(capsys, *paths, "--verify", "--json")
    assert code == 0
    said = json.loads(out)["verify"]
    assert (said["verified"], said["other_law"]) == (0, dataclasses.asdict(other))


@pytest.mark.parametrize("fixture", ["unnamed_log", "next_law_log"])
def test_a_log_of_another_law_is_still_summarised_tabled_plotted_and_tuned(
    fixture: str,
    fresh_log: list[Path],
    request: pytest.FixtureRequest,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    paths: list[Path] = request.getfixturevalue(fixture)
    summary = replay.summarise(reader.load(fresh_log))
    code, out, _ = run_cli(capsys, *paths, "--json")
    assert code == 0
    files = ("files", "runs")  # the rewritten log's own files: the rest is the day's
    assert {k: v for k, v in json.loads(out).items() if k not in files} == {
        k: v for k, v in summary.items() if k not in files
    }
    table, picture = tmp_path / "day.csv", tmp_path / "day.png"
    code, _, _ = run_cli(capsys, *paths, "--csv", table, "--plot", picture)
    assert code == 0
    with table.open(encoding="utf-8") as f:
        assert len(list(csv.reader(f))) == 1 + summary["periods"]
    assert picture.read_bytes().startswith(b"\x89PNG")
    assert main(["tune", *map(str, fresh_log), "--json"]) == 0
    tuned = json.loads(capsys.readouterr().out)
    assert main(["tune", *map(str, paths), "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == tuned


def test_a_day_of_two_laws_is_named_as_the_other_law_in_part() -> None:
    """A restart into a hermsd of another law: one run's decisions are that law's, so the
    day is not re-run, and the line says the log is that law's in part."""
    ours = reader.LoggedConfig(0.0, "start", {}, control_law=LAW)
    theirs = reader.LoggedConfig(900.0, "start", {}, control_law=LAW + 1)
    unnamed = reader.LoggedConfig(1800.0, "start", {})
    assert replay.other_law([ours, theirs]) == replay.OtherLaw(LAW + 1, LAW, True)
    assert replay.other_law([theirs, ours]) == replay.OtherLaw(LAW + 1, LAW, True)
    assert replay.other_law([unnamed, ours]) == replay.OtherLaw(None, LAW, True)
    assert replay.other_law([theirs, unnamed]) == replay.OtherLaw(LAW + 1, LAW, False)
    assert replay.other_law([ours, ours]) is None
    assert replay.verify([ours, theirs]).other_law == replay.OtherLaw(LAW + 1, LAW, True)


@pytest.mark.parametrize(
    ("logged", "read"), [(LAW, LAW), (7, 7), (True, None), ("1", None), (1.0, None)]
)
def test_a_control_law_is_an_integer_or_none_is_named(logged: object, read: int | None) -> None:
    record = {"t": 0.0, "config": {}, "control_law": logged}
    assert reader._config(record, Path("day.mcap")).control_law == read
