"""Latched alarms survive restarts and crashes, and clear only by an explicit act."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from test_reload import BASE, Events, edited, rename_over, run_for, start

from hermsd.cli import commands as cli
from hermsd.runtime.daemon import Daemon
from hermsd.safety.latches import LATCHED_FILE, RESET_FILE, Latches, LatchStore, StateError
from hermsd.sim.world import World

KIND = "sensor_stuck"


def boot(state: Path, text: str = BASE, *, watch: bool = False) -> tuple[Daemon, World, Events]:
    """A daemon keeping its latches in `state` (a start, or a restart after a crash)."""
    daemon, world, _path, events = start(state, text, latches=LatchStore(state), watch=watch)
    return daemon, world, events


def latch_a_dead_element(state: Path, config_text: str = BASE) -> None:
    """Run until a watch latches an alarm over a dead element, then die without a word.

    In this still, noiseless tun the sensor's word never moves while the output does, so
    the stuck-sensor watch is the one that latches first.
    """
    daemon, world, _events = boot(state, config_text)
    world.plant.set_element_ok(False, daemon.clock.monotonic())
    run_for(daemon, 1200.0)
    assert daemon.supervisor.latched == [KIND]


def test_a_latched_alarm_is_stored_and_raised_again_after_a_restart(tmp_path: Path) -> None:
    latch_a_dead_element(tmp_path)
    stored = json.loads((tmp_path / LATCHED_FILE).read_text())
    assert [a["kind"] for a in stored["alarms"]] == [KIND]
    assert stored["reset"] == 0
    daemon, world, events = boot(tmp_path)  # Restart=always after a crash
    assert daemon.supervisor.latched == [KIND]
    assert any("before a restart" in m for m in events.logged())
    run_for(daemon, 600.0)
    assert world.plant.energy_in(daemon.clock.monotonic()) == 0.0
    assert {r.state for r in events.periods} == {"alarm"}


def test_bumping_safety_reset_before_a_start_clears_them(tmp_path: Path) -> None:
    latch_a_dead_element(tmp_path)
    daemon, _world, events = boot(tmp_path, edited(BASE, safety__reset="1"))
    assert daemon.supervisor.latched == []
    assert f"alarms reset by safety.reset: {KIND}" in events.logged()
    assert LatchStore(tmp_path).load() == Latches((), 1)


def test_bumping_safety_reset_in_a_reload_clears_them(tmp_path: Path) -> None:
    latch_a_dead_element(tmp_path)
    daemon, _world, events = boot(tmp_path, watch=True)
    assert daemon.supervisor.latched == [KIND]
    rename_over(tmp_path / "hermsd.yaml", edited(BASE, safety__reset="1"))
    run_for(daemon, 5.0)
    assert daemon.supervisor.latched == []
    assert f"alarms reset: {KIND}" in events.logged()
    assert LatchStore(tmp_path).load() == Latches((), 1)
    run_for(daemon, 600.0)
    assert events.periods[-1].state == "ok"


def test_a_config_reload_alone_keeps_them(tmp_path: Path) -> None:
    latch_a_dead_element(tmp_path)
    daemon, _world, _events = boot(tmp_path, watch=True)
    rename_over(tmp_path / "hermsd.yaml", edited(BASE, control__setpoint="70.0"))
    run_for(daemon, 60.0)
    assert daemon.setpoint == 70.0
    assert daemon.supervisor.latched == [KIND]


def test_reset_alarm_clears_only_the_alarms_it_names(tmp_path: Path) -> None:
    latch_a_dead_element(tmp_path)
    daemon, _world, _events = boot(tmp_path)
    LatchStore(tmp_path).request_reset(["dry_fire"])  # seen before this alarm was raised
    run_for(daemon, 5.0)
    assert daemon.supervisor.latched == [KIND]
    assert not (tmp_path / RESET_FILE).exists()
    LatchStore(tmp_path).request_reset([KIND])
    run_for(daemon, 5.0)
    assert daemon.supervisor.latched == []
    assert LatchStore(tmp_path).load().alarms == ()


def test_the_reset_alarm_command(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["reset-alarm", "--state", str(tmp_path)]) == 0
    assert f"no latched alarm in {tmp_path}" in capsys.readouterr().out
    assert not (tmp_path / RESET_FILE).exists()
    latch_a_dead_element(tmp_path)
    assert cli.main(["reset-alarm", "--state", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"{KIND}, latched ") and "UTC" in out
    # A stopped daemon clears them when it starts.
    daemon, _world, events = boot(tmp_path)
    assert daemon.supervisor.latched == []
    assert f"alarms reset: {KIND}" in events.logged()


def test_a_disk_that_refuses_the_latch_file_is_said_and_control_goes_on(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def refuse(self: LatchStore, latches: Latches) -> None:
        raise OSError(30, "Read-only file system")

    monkeypatch.setattr(LatchStore, "save", refuse)
    daemon, world, events = boot(tmp_path)
    world.plant.set_element_ok(False, daemon.clock.monotonic())
    run_for(daemon, 1200.0)
    assert daemon.supervisor.latched == [KIND]
    failures = [m for m in events.logged() if m.startswith("saving latched alarms failed")]
    assert len(failures) == 1 and "Read-only" in failures[0]
    assert events.periods[-1].t >= daemon.clock.monotonic() - 5.0


def _latch_document(**alarm: object) -> dict[str, object]:
    entry = {"kind": KIND, "wall_ns": 1_767_225_600_000_000_000, "message": "stuck", "values": {}}
    return {"alarms": [{**entry, **alarm}], "reset": 0}


DEEP = "[" * 100_000 + "]" * 100_000
CRAFTED_LATCH_FILES = {
    "cut short": '{"alarms": [',
    "nested 100,000 deep": '{"alarms": ' + DEEP + ', "reset": 0}',
    "a number beyond a float": json.dumps(_latch_document()).replace(
        "1767225600000000000", "1e400"
    ),
    "NaN": json.dumps(_latch_document()).replace("1767225600000000000", "NaN"),
    "wall_ns as text": json.dumps(_latch_document(wall_ns="1767225600000000000")),
    "wall_ns past any clock": json.dumps(_latch_document(wall_ns=10**30)),
    "wall_ns as a boolean": json.dumps(_latch_document(wall_ns=True)),
    "a message that is not text": json.dumps(_latch_document(message=5)),
    "values as a list": json.dumps(_latch_document(values=[])),
    "nested values": json.dumps(_latch_document(values={"a": {"b": 1}})),
    "reset as text": json.dumps({**_latch_document(), "reset": "0"}),
    "alarms as an object": json.dumps({"alarms": {KIND: 1}, "reset": 0}),
    "a list": "[]",
    "over 1 MiB": json.dumps(_latch_document(message="x" * (1 << 20))),
}


@pytest.mark.parametrize("text", CRAFTED_LATCH_FILES.values(), ids=CRAFTED_LATCH_FILES)
def test_a_crafted_latch_file_stops_the_start_in_one_line_and_reset_alarm_replaces_it(
    tmp_path: Path, text: str, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / LATCHED_FILE).write_text(text, encoding="utf-8")

    with pytest.raises(StateError, match=str(tmp_path / LATCHED_FILE)):
        LatchStore(tmp_path).load()
    code = cli.main(
        ["run", "--simulate", "--speed", "max", "--duration", "10s", "--state", str(tmp_path)]
    )
    err = capsys.readouterr().err
    assert code == 2
    assert "Traceback" not in err and "started" not in err
    assert err.splitlines()[-1].startswith(f"hermsd: {tmp_path / LATCHED_FILE}: ")
    assert "reset-alarm" in err.splitlines()[-1]
    assert cli.main(["reset-alarm", "--state", str(tmp_path)]) == 0
    assert LatchStore(tmp_path).load() == Latches()


def test_a_fifo_in_place_of_the_latch_file_cannot_hang_the_start(tmp_path: Path) -> None:
    os.mkfifo(tmp_path / LATCHED_FILE)
    args = ["run", "--simulate", "--speed", "max", "--duration", "10s", "--state", str(tmp_path)]

    proc = subprocess.run(
        [sys.executable, "-m", "hermsd.cli", *args], capture_output=True, text=True, timeout=30
    )

    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert proc.stderr.splitlines()[-1] == (
        f"hermsd: {tmp_path / LATCHED_FILE}: is a FIFO (named pipe), not a regular file "
        "(inspect it; `hermsd reset-alarm` replaces it)"
    )


CRAFTED_RESET_REQUESTS = {
    "nested 100,000 deep": '{"kinds": ' + DEEP + "}",
    "a number beyond a float": '{"kinds": [1e400]}',
    "kinds as text": '{"kinds": "all"}',
    "kinds that are not names": '{"kinds": [1, null]}',
    "a list": f'["{KIND}"]',
    "over 1 MiB": json.dumps({"kinds": [KIND] * 200_000}),
    "not UTF-8": b'{"kinds": ["\xff"]}'.decode("latin-1"),
}


@pytest.mark.parametrize("text", CRAFTED_RESET_REQUESTS.values(), ids=CRAFTED_RESET_REQUESTS)
def test_a_crafted_reset_request_is_discarded_with_an_error_and_the_alarm_stays(
    tmp_path: Path, text: str
) -> None:
    (tmp_path / LATCHED_FILE).write_text(json.dumps(_latch_document()), encoding="utf-8")
    (tmp_path / RESET_FILE).write_bytes(text.encode("latin-1"))

    daemon, _world, events = boot(tmp_path)
    run_for(daemon, 10.0)

    assert daemon.supervisor.latched == [KIND]
    assert not (tmp_path / RESET_FILE).exists()
    errors = [m for m in events.logged() if m.startswith("reading the reset request failed")]
    assert len(errors) == 1 and errors[0].endswith("; discarded")


def test_a_restored_alarm_is_stored_with_its_first_message_however_often_it_restarts(
    tmp_path: Path,
) -> None:
    (tmp_path / LATCHED_FILE).write_text(json.dumps(_latch_document()), encoding="utf-8")

    for _start in range(3):
        daemon, _world, events = boot(tmp_path)
        run_for(daemon, 10.0)

    assert [a.message for a in LatchStore(tmp_path).load().alarms] == ["stuck"]
    shown = [m for m in events.logged() if m.startswith(f"ALARM {KIND}")]
    assert shown == [
        f"ALARM {KIND}: stuck (latched 2026-01-01 00:00:00 UTC, before a restart); heater off"
    ]


@pytest.mark.parametrize("name", ["cut short", "wall_ns past any clock"])
def test_check_config_refuses_a_state_directory_that_run_refuses_in_the_same_words(
    tmp_path: Path, name: str, capsys: pytest.CaptureFixture[str]
) -> None:
    state = tmp_path / "state"
    state.mkdir()
    (state / LATCHED_FILE).write_text(CRAFTED_LATCH_FILES[name], encoding="utf-8")
    config = tmp_path / "hermsd.yaml"
    config.write_text("output: {backend: sim}\n", encoding="utf-8")
    run = ["run", "--simulate", "--speed", "max", "--duration", "10s", "--config", str(config)]

    assert cli.main([*run, "--state", str(state)]) == 2
    refused = capsys.readouterr().err.splitlines()[-1]
    checked = ["check-config", str(config), "--simulate", "--state", str(state)]
    assert cli.main(checked) == 2
    out, err = capsys.readouterr()

    assert refused.startswith(f"hermsd: {state / LATCHED_FILE}: ")
    assert err.splitlines() == [refused]
    assert "Traceback" not in err and "safety limits" not in out
