"""The mash program in the daemon: its setpoint drives control, the socket's commands, the
setpoint rule, the step-mash scenario, replay's step listing, and a SIGKILL in a rest.

The daemon runs on the virtual clock except in the SIGKILL test, which kills a real
`hermsd run --simulate` (a real process cannot be killed on a virtual clock).
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from test_control import Inbox, linked, operator_lines, served, status_of
from test_reload import BASE, PERIOD, edited, rename_over, run_for, start

from hermsd.api.link import SEEN_S, LoopLink
from hermsd.api.protocol import (
    ProgramAction,
    ProgramStart,
    ProtocolError,
    SetSetpoint,
    parse_request,
    request_message,
)
from hermsd.cli import main
from hermsd.log import reader, replay
from hermsd.log.topics import PROGRAM_TOPIC
from hermsd.program import model
from hermsd.program.model import Program, Step
from hermsd.program.store import PROGRESS_FILE, SAVE_EVERY_S
from hermsd.runtime.daemon import Daemon
from hermsd.safety.latches import LatchStore
from hermsd.sim import scenario

ROOT = Path(__file__).resolve().parents[1]
TWO_STEPS = Program("Two", (Step("Warm", 30.0, 60.0), Step("Hot", 40.0, None)))


def apply(daemon: Daemon, inbox: Inbox, command: Any) -> dict[str, Any]:
    pending = inbox.send(command)
    run_for(daemon, PERIOD)
    assert pending.reply is not None
    return pending.reply


def test_the_programs_setpoint_drives_control_and_every_period_names_the_step(
    tmp_path: Path,
) -> None:
    daemon, _path, events, inbox = linked(tmp_path)
    reply = apply(daemon, inbox, ProgramStart(TWO_STEPS))
    assert reply["ok"] is True
    assert reply["program"]["state"] == "heating"
    assert reply["program"]["step"] == {"index": 0, "name": "Warm", "setpoint": 30.0}
    record = events.periods[-1]
    assert (record.setpoint, record.step, record.step_index, record.next_step) == (
        30.0,
        "Warm",
        0,
        "Hot",
    )
    run_for(daemon, 3600.0)  # the simulated tun starts at 20 °C: Warm is reached and held
    status = status_of(daemon)["program"]
    assert (status["state"], status["step"]["name"], status["time_left_s"]) == (
        "holding",
        "Hot",
        None,
    )
    assert events.periods[-1].setpoint == 40.0
    kinds = [m["event"] for topic, m in events.written if topic == PROGRAM_TOPIC]
    assert kinds == [
        "started",
        "step_started",
        "step_reached",
        "step_done",
        "step_started",
        "step_reached",
    ]
    assert "operator: program start 'Two' (2 steps) (from the control socket)" in (
        operator_lines(events)
    )
    assert "Warm" in daemon.status_text() or "Hot" in daemon.status_text()


def test_the_brewer_hears_of_steps_reached_done_waiting_and_the_finish(tmp_path: Path) -> None:
    daemon, _path, _events, inbox = linked(tmp_path)
    sent: list[tuple[str, str]] = []
    daemon.alerts.send = lambda event, t: sent.append((event.event, event.kind))  # type: ignore[method-assign]
    program = Program("Short", (Step("Warm", 25.0, 60.0, confirm="Stir"), Step("Hot", 28.0, 0.0)))
    apply(daemon, inbox, ProgramStart(program))
    run_for(daemon, 1800.0)
    apply(daemon, inbox, ProgramAction("confirm"))
    run_for(daemon, 1800.0)
    assert sent == [
        ("step_reached", "Warm"),
        ("step_done", "Warm"),
        ("waiting", "Warm"),
        ("step_reached", "Hot"),
        ("step_done", "Hot"),
        ("finished", ""),
    ]


@pytest.mark.parametrize(
    ("command", "says"),
    [
        (
            ProgramStart(Program("Boil", (Step("Boil", 95.0, 60.0),))),
            "steps[0].setpoint: 95 °C is not below safety.max_temp (95 °C)",
        ),
        (ProgramAction("next"), "no program runs (next has nothing to act on)"),
        (ProgramAction("confirm"), "no program runs (confirm has nothing to act on)"),
        (ProgramAction("resume"), "no program runs"),
    ],
)
def test_a_bad_program_command_is_refused_in_one_line_and_changes_nothing(
    tmp_path: Path, command: Any, says: str
) -> None:
    daemon, _path, events, inbox = linked(tmp_path)
    before = events.periods[-1]
    reply = apply(daemon, inbox, command)
    assert reply["ok"] is False
    assert reply["error"].startswith("refused, nothing changed: ")
    assert says in reply["error"] and "\n" not in reply["error"]
    assert events.periods[-1].setpoint == before.setpoint
    assert events.periods[-1].step is None
    assert status_of(daemon)["program"] is None
    assert operator_lines(events) == []


def test_while_a_program_runs_commands_that_do_not_apply_change_nothing(tmp_path: Path) -> None:
    daemon, _path, events, inbox = linked(tmp_path)
    apply(daemon, inbox, ProgramStart(TWO_STEPS))
    for command, says in [
        (SetSetpoint(50.0), "control.setpoint: a mash program sets the setpoint while it runs"),
        (ProgramStart(TWO_STEPS), "program 'Two' runs (`hermsd program stop` first)"),
        (ProgramAction("confirm"), "nothing waits for a confirmation"),
        (ProgramAction("resume"), "the program is not paused"),
    ]:
        reply = apply(daemon, inbox, command)
        assert reply["ok"] is False and says in reply["error"]
    assert events.periods[-1].setpoint == 30.0
    assert status_of(daemon)["program"]["step"]["index"] == 0


@pytest.mark.parametrize(
    ("line", "says"),
    [
        (b'{"v":1,"cmd":"program","action":"begin"}', "program: action 'begin' is not one of"),
        (b'{"v":1,"cmd":"program","action":"start"}', "program start: the program is missing"),
        (
            b'{"v":1,"cmd":"program","action":"start","program":{"steps":[{"name":"A",'
            b'"setpoint":60}]}}',
            "program: steps[0].hold: missing",
        ),
        (
            b'{"v":1,"cmd":"program","action":"start","program":{"steps":[{"name":"A",'
            b'"setpoint":60,"hold":60}]},"ready_by":"6:30"}',
            'ready_by: "6:30" is not a local time',
        ),
        (b'{"v":1,"cmd":"program","action":"next","x":1}', "program next does not take x"),
        (b'{"v":1,"cmd":"confirm","message":"Mash in"}', "confirm does not take message"),
    ],
)
def test_a_bad_program_request_is_refused_before_it_reaches_the_loop(
    line: bytes, says: str
) -> None:
    with pytest.raises(ProtocolError) as caught:
        parse_request(line)
    assert str(caught.value).startswith(says)
    assert "\n" not in str(caught.value)


def test_the_longest_program_fits_one_request_line() -> None:
    from hermsd.api.protocol import MAX_LINE, encode, request_message

    name = "°" * model.NAME_LENGTH
    steps = tuple(
        Step(f"{i:02d}" + name[2:], 99.9, 86400.0, 9.99, "\U0001f37a" * model.MESSAGE_LENGTH)
        for i in range(model.MAX_STEPS)
    )
    longest = Program(name, steps, "23:59")
    line = encode(request_message(ProgramStart(longest, "23:59")))
    assert len(line) <= MAX_LINE
    assert parse_request(line.rstrip(b"\n")) == ProgramStart(longest, "23:59")


# -- the setpoint rule -----------------------------------------------------------------------


def test_a_program_owns_the_setpoint_and_an_edit_of_the_files_applies_when_it_stops(
    tmp_path: Path,
) -> None:
    daemon, path, events, inbox = linked(tmp_path)
    apply(daemon, inbox, ProgramStart(TWO_STEPS))
    rename_over(path, edited(BASE, control__setpoint="70.0"))
    run_for(daemon, 2 * PERIOD)
    assert daemon.config.control.setpoint == 70.0  # the edit was taken
    assert events.periods[-1].setpoint == 30.0  # the program's step holds the setpoint
    reply = apply(daemon, inbox, ProgramAction("stop"))
    assert (reply["ok"], reply["program"], reply["setpoint"]) == (True, None, 70.0)


def test_an_edit_that_puts_the_cut_out_at_a_programs_setpoint_stops_the_program(
    tmp_path: Path,
) -> None:
    daemon, path, events, inbox = linked(tmp_path)
    apply(daemon, inbox, ProgramStart(TWO_STEPS))
    rename_over(path, edited(BASE, control__setpoint="25.0", safety__max_temp="30.0"))
    run_for(daemon, 2 * PERIOD)
    assert status_of(daemon)["program"] is None
    assert events.periods[-1].setpoint == 25.0
    assert "program stopped: its step's setpoint 30 °C is not below safety.max_temp (30 °C)" in (
        events.logged()
    )


def test_a_setpoint_to_return_to_at_or_above_a_lowered_cut_out_becomes_the_files(
    tmp_path: Path,
) -> None:
    daemon, path, events, inbox = linked(tmp_path)
    apply(daemon, inbox, SetSetpoint(90.0))
    apply(daemon, inbox, ProgramStart(TWO_STEPS))
    rename_over(path, edited(BASE, safety__max_temp="80.0"))  # the file's setpoint stays 66
    run_for(daemon, 2 * PERIOD)
    assert status_of(daemon)["program"]["step"]["name"] == "Warm"  # its 30 °C is allowed
    assert (
        "setpoint 90 °C for when the program stops is not below safety.max_temp (80 °C): "
        "the file's 66 °C instead"
    ) in events.logged()
    reply = apply(daemon, inbox, ProgramAction("stop"))
    assert reply["setpoint"] == 66.0
    assert events.periods[-1].setpoint == 66.0


def test_a_ramp_in_force_at_or_above_a_lowered_cut_out_stops_the_program(
    tmp_path: Path,
) -> None:
    down = Program("Down", (Step("Hot", 40.0, None), Step("Cool", 30.0, 60.0, 1.0)))
    daemon, path, events, inbox = linked(tmp_path)
    apply(daemon, inbox, ProgramStart(down))
    apply(daemon, inbox, ProgramAction("next"))  # Cool ramps down from 40 °C at 1 °C/min
    run_for(daemon, PERIOD)
    in_force = events.periods[-1].setpoint
    assert 39.0 < in_force < 40.0
    rename_over(path, edited(BASE, control__setpoint="25.0", safety__max_temp="35.0"))
    run_for(daemon, PERIOD)
    assert status_of(daemon)["program"] is None
    assert events.periods[-1].setpoint == 25.0
    logged = events.logged()
    assert any(
        line.startswith("program stopped: its setpoint in force 39.")
        and line.endswith("°C is not below safety.max_temp (35 °C)")
        for line in logged
    ), logged
    assert not any("back to the file's" in line for line in logged)


def test_without_an_edit_a_stopped_program_gives_back_the_setpoint_it_found(
    tmp_path: Path,
) -> None:
    daemon, _path, events, inbox = linked(tmp_path)
    apply(daemon, inbox, SetSetpoint(55.0))
    apply(daemon, inbox, ProgramStart(TWO_STEPS))
    assert events.periods[-1].setpoint == 30.0
    reply = apply(daemon, inbox, ProgramAction("stop"))
    assert reply["setpoint"] == 55.0
    assert reply["runtime"] == {"control.setpoint": {"running": 55.0, "file": 66.0}}


def test_the_commands_start_pause_and_stop_a_program(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    program = tmp_path / "mash.yaml"
    # 85 °C is hours of heating away: still heating however fast the daemon's thread steps
    program.write_text("steps:\n  - {name: Rest, setpoint: 85, hold: 60m}\n", encoding="utf-8")
    with served(tmp_path) as (_daemon, where):
        sock = ["--socket", os.fspath(where)]
        assert main(["program", "start", str(program), *sock]) == 0
        assert "program 'mash': heating, step 1/1 'Rest' at 85 °C" in capsys.readouterr().out
        assert main(["status", *sock]) == 0  # when the rest starts, by the tun's model
        said = r"^program 'mash': heating, .*, rest in about (\d+ h )?\d+ min$"
        assert re.search(said, capsys.readouterr().out, re.M)
        assert main(["program", "pause", *sock]) == 0
        assert "paused" in capsys.readouterr().out
        assert main(["confirm", *sock]) == 2
        assert "the program is paused" in capsys.readouterr().err
        assert main(["program", "stop", *sock]) == 0
        assert capsys.readouterr().out == "program stopped; setpoint 66 °C\n"


def test_a_program_stopped_is_logged_as_the_operators_action_then_what_it_brought(
    tmp_path: Path,
) -> None:
    daemon, _path, events, inbox = linked(tmp_path)
    apply(daemon, inbox, ProgramStart(TWO_STEPS))
    apply(daemon, inbox, ProgramAction("stop"))
    lines = events.logged()
    action = lines.index("operator: program stop (from the control socket)")
    assert lines.index("setpoint 66.00 °C (the program stopped)") > action


def test_a_progress_that_cannot_be_saved_is_in_the_log_and_the_status(tmp_path: Path) -> None:
    state = tmp_path / "state"
    state.mkdir()
    daemon, _path, events, inbox = linked(tmp_path, latches=LatchStore(state))
    (state / PROGRESS_FILE).mkdir()  # nothing can be renamed over a directory
    apply(daemon, inbox, ProgramStart(TWO_STEPS))
    assert daemon.program.flush(5.0)
    run_for(daemon, PERIOD)
    errors = [line for line in events.logged() if "progress failed" in line]
    assert len(errors) == 1 and "Is a directory" in errors[0], errors
    failed = status_of(daemon)["program"]["save_failed"]
    assert "Is a directory" in failed
    assert status_of(daemon)["warnings"] == [  # the web page's, MQTT's and `hermsd status`'s
        f"program progress not saved (a restart may not resume it): {failed}"
    ]
    run_for(daemon, 10 * PERIOD)
    assert len([line for line in events.logged() if "progress failed" in line]) == 1


# -- a whole day: the step-mash scenario, its log and replay --------------------------------


def test_the_step_mash_scenario_runs_every_step_and_replay_lists_them(tmp_path: Path) -> None:
    day = scenario.load_scenario(ROOT / "scenarios" / "step-mash.yaml")
    result = scenario.run(day, log_dir=tmp_path)
    summary = result.summary
    program = {"name": "Step mash", "state": "done", "steps_run": 4, "steps": 4}
    assert summary["program"].items() >= program.items()
    assert summary["alarms"] == []
    steps = summary["steps"]
    assert [s["name"] for s in steps] == ["Strike", "Beta rest", "Alpha rest", "Mash out"]
    ready_by = 3 * 3600.0  # 06:30, the scenario's clock starting at 03:30
    assert abs(steps[0]["reached_s"] - ready_by) <= 120.0
    assert summary["program"]["ready_at_s"] == ready_by + 0.0
    assert summary["program"]["ready_error_s"] == steps[0]["reached_s"] - ready_by
    # One setpoint's heat-up and hold measures mean nothing on a day of several.
    assert not {"settle_s", "overshoot_c", "recovery_s", "iae"} & set(summary)
    for step, hold in zip(steps[1:], (1800.0, 1200.0, 600.0), strict=True):
        assert step["reached_s"] is not None
        assert step["in_band_s"] >= hold  # each rest held its full time in the band
    # Beta rest is reached once the water is back from the cold water poured in at mash-in
    # (2.4 °C below it): each rest then holds its band.
    assert all(step["max_deviation_c"] < 0.6 for step in steps[1:])
    log = reader.load(sorted(tmp_path.glob("*.mcap")))
    assert replay.verify(log.entries).mismatch is None  # the scheduled hours are skipped
    logged = replay.summarise(log)
    assert [(s["name"], s["reached_s"] is not None) for s in logged["steps"]] == [
        (s["name"], True) for s in steps
    ]
    # What the schedule decided is read back: the approach released before 06:30, and why.
    [release] = [e for e in logged["schedule"] if e["event"] == "release"]
    assert release["at_s"] < ready_by and "full power for 72 °C" in release["message"]


# -- a SIGKILL in the middle of a rest -------------------------------------------------------

SPEED = 50.0
HOLD_S = 600.0
TIMEOUT_S = 30.0


def _hermsd(state: Path) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "hermsd.cli",
            "run",
            "--simulate",
            "--speed",
            str(SPEED),
            "--state",
            str(state),
            "--socket",
            str(state / "control.sock"),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _status(sock: Path, capsys: pytest.CaptureFixture[str]) -> dict[str, Any] | None:
    if main(["status", "--json", "--socket", str(sock)]) != 0:
        capsys.readouterr()
        return None
    reply: dict[str, Any] = json.loads(capsys.readouterr().out)
    return reply


def _wait_for(sock: Path, capsys: pytest.CaptureFixture[str], done: Any) -> dict[str, Any]:
    deadline = time.monotonic() + TIMEOUT_S
    while time.monotonic() < deadline:
        status = _status(sock, capsys) if sock.exists() else None
        if status is not None and done(status):
            return status
        time.sleep(0.02)
    raise AssertionError("the daemon did not get there in time")


def test_a_sigkill_in_a_rest_resumes_that_rest_with_its_time_left(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    state, sock = tmp_path / "state", tmp_path / "state" / "control.sock"
    program = tmp_path / "rest.yaml"  # the simulated tun starts at 20 °C: in the band at once
    program.write_text(f"steps:\n  - {{name: Rest, setpoint: 20.25, hold: {HOLD_S:g}s}}\n")
    first = _hermsd(state)
    try:
        _wait_for(sock, capsys, lambda s: s["pv"] is not None)
        assert main(["program", "start", str(program), "--socket", str(sock)]) == 0
        capsys.readouterr()
        before = _wait_for(
            sock, capsys, lambda s: (s["program"]["time_left_s"] or HOLD_S) <= HOLD_S - 60.0
        )
        first.send_signal(signal.SIGKILL)
        first.wait(TIMEOUT_S)
    finally:
        first.kill()
        first.communicate()
    stored = json.loads((state / PROGRESS_FILE).read_text())["progress"]
    left_at_kill = HOLD_S - stored["held_s"]
    lost = left_at_kill - before["program"]["time_left_s"]  # the hold counted, not yet saved
    assert -2 * PERIOD <= lost <= SAVE_EVERY_S + 2 * PERIOD

    second = _hermsd(state)
    try:
        after = _wait_for(sock, capsys, lambda s: s["program"] is not None)
        second.send_signal(signal.SIGTERM)
        _out, err = second.communicate(timeout=TIMEOUT_S)
    finally:
        second.kill()
    said = re.search(r"resumed after a restart at step 1/1 'Rest', (\d+) s of its hold left", err)
    assert said is not None, err
    assert int(said[1]) == round(left_at_kill)  # the rest resumed with the time left it had
    assert after["program"]["step"]["name"] == "Rest"
    assert 0.0 <= left_at_kill - after["program"]["time_left_s"] <= after["t"] - 0.0 + PERIOD


# -- a confirm or next ends the step it was meant for, and no other -------------------------

WAITS_TWICE = Program(
    "Two",
    (
        Step("S1", 25.0, 0.0, confirm="Mash in"),
        Step("S2", 25.0, 0.0, confirm="Add the salts"),
        Step("S3", 25.0, 600.0),
    ),
)


@pytest.mark.parametrize("action", ["confirm", "next"])
def test_a_second_command_sent_with_the_first_does_not_end_the_step_the_first_brought(
    tmp_path: Path, action: str
) -> None:
    """Two brewers (or a double tap) answer S1 together. The first ends S1, and S2 waits in
    the period that began it (its hold is 0 s). The second, queued with the first or come
    less than SEEN_S later, was meant for S1 too: it is refused, and S2 still waits."""
    now = [0.0]  # the senders' real clock
    daemon, _world, _path, events = start(tmp_path, BASE)
    inbox = Inbox()
    link = LoopLink(daemon, now=lambda: now[0])
    link.attach(inbox)
    run_for(daemon, 60.0)
    apply(daemon, inbox, ProgramStart(WAITS_TWICE))
    run_for(daemon, 1800.0)  # the simulated tun, from 20 °C, is at 25 °C: S1 waits
    assert status_of(daemon)["program"]["message"] == "Mash in"
    now[0] = 10.0
    first = inbox.send(link.arrived(ProgramAction(action)))
    queued = link.arrived(ProgramAction(action))  # arrived with the first, taken a period later
    run_for(daemon, PERIOD)
    assert first.reply is not None and first.reply["ok"] is True
    assert first.reply["program"]["step"]["name"] == "S2"
    assert first.reply["program"]["message"] == "Add the salts"
    now[0] = 10.0 + SEEN_S / 2  # one sent half a second after the first
    for late in (queued, link.arrived(ProgramAction(action))):
        second = apply(daemon, inbox, late)
        assert second["ok"] is False
        assert second["error"] == (
            f"refused, nothing changed: {action} was for step 1, which is not the current one "
            "(step 2/3 'S2' is waiting; look at the status and send it again for that step if "
            "meant)"
        )
    assert status_of(daemon)["program"]["message"] == "Add the salts"  # S2 still waits
    said = [line for line in events.logged() if "'S2' confirmed" in line or "'S2' ended" in line]
    assert said == []
    now[0] = 10.0 + SEEN_S  # S2 shown long enough to be read: now it is answered
    assert (
        apply(daemon, inbox, link.arrived(ProgramAction(action)))["program"]["step"]["name"] == "S3"
    )
    # Named, a step is answered as meant at once.
    assert apply(daemon, inbox, ProgramAction(action, 2))["ok"] is (action == "next")


def test_the_step_a_confirm_or_next_is_for_is_read_and_written_by_the_protocol() -> None:
    for line, request in [
        (b'{"v": 1, "cmd": "confirm", "step": 2}', ProgramAction("confirm", 2)),
        (b'{"v": 1, "cmd": "program", "action": "next", "step": 0}', ProgramAction("next", 0)),
        (b'{"v": 1, "cmd": "confirm", "step": null}', ProgramAction("confirm")),
    ]:
        assert parse_request(line) == request
        assert parse_request(json.dumps(request_message(request)).encode()) == request
    for line, says in [
        (b'{"v": 1, "cmd": "confirm", "step": -1}', "step: expected the index of a step"),
        (b'{"v": 1, "cmd": "confirm", "step": "S1"}', 'got "S1"'),
        (b'{"v": 1, "cmd": "program", "action": "pause", "step": 0}', "does not take step"),
    ]:
        with pytest.raises(ProtocolError, match=says):
            parse_request(line)


def test_the_command_line_names_the_step_from_one_as_status_shows_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    program = tmp_path / "two.yaml"
    program.write_text(
        "name: Two\nsteps:\n  - {name: S1, setpoint: 25, hold: 0s, confirm: Mash in}\n"
        "  - {name: S2, setpoint: 25, hold: 10m}\n",
        encoding="utf-8",
    )
    with served(tmp_path) as (_daemon, where):
        sock = ["--socket", os.fspath(where)]
        assert main(["program", "start", str(program), *sock]) == 0
        assert main(["program", "next", "--step", "2", *sock]) == 2
        assert "next was for step 2, which is not the current one" in (capsys.readouterr().err)
        assert main(["program", "next", "--step", "1", *sock]) == 0
        assert "step 2/2 'S2'" in capsys.readouterr().out
        assert main(["program", "pause", "--step", "1", *sock]) == 2
        assert "--step goes with `program next`" in capsys.readouterr().err
