"""The control socket: its protocol, what the loop does with commands at a period boundary,
how runtime changes and config edits interact, the socket's permissions, and the commands.

The daemon runs on the virtual clock, stepped a period at a time; sockets are real, and every
wait on them is bounded by a timeout.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import select
import shutil
import socket
import stat
import subprocess
import sys
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from test_reload import BASE, PERIOD, Events, edited, rename_over, run_for, start

from hermsd.api import server as server_module
from hermsd.api.link import LoopLink
from hermsd.api.protocol import (
    MAX_LINE,
    MAX_PAGE,
    Command,
    History,
    ProgramStart,
    ProtocolError,
    ResetAlarms,
    SetMode,
    SetSetpoint,
    Status,
    parse_request,
)
from hermsd.api.server import ControlServer, Pending, SocketInUseError
from hermsd.cli import main, remote
from hermsd.config import read
from hermsd.config import schema as config_module
from hermsd.control import factory
from hermsd.control.learning import LearnedModel, ModelStore
from hermsd.program.model import Program, Step
from hermsd.program.store import PROGRESS_FILE
from hermsd.runtime.assemble import assemble
from hermsd.runtime.daemon import Daemon
from hermsd.safety.latches import LatchedAlarm, Latches, LatchStore
from hermsd.sim.clock import VirtualClock
from hermsd.sim.hlt import FoptdPlant
from hermsd.sim.world import build_world

NOBODY = 65534
# An interpreter any user may run (the test's own may live under /root).
SYSTEM_PYTHON = shutil.which("python3", path="/usr/bin:/bin")
TIMEOUT = 5.0
STATUS = b'{"v": 1, "cmd": "status"}\n'


# -- the protocol ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("line", "request_"),
    [
        (b'{"v": 1, "cmd": "status"}', Status()),
        (b'{"v": 1, "cmd": "reset-alarm"}', ResetAlarms()),
        (b'{"v": 1, "cmd": "reset-alarm", "kinds": ["dry_fire"]}', ResetAlarms(("dry_fire",))),
        (b'{"v": 1, "cmd": "reset-alarm", "kinds": []}', ResetAlarms(())),
        (b'{"v": 1, "cmd": "set", "setpoint": 72}', SetSetpoint(72.0)),
        (b'{"v": 1, "cmd": "set", "mode": "manual", "output": 40.5}', SetMode("manual", 40.5)),
        (b'{"v": 1, "cmd": "set", "mode": "manual"}', SetMode("manual", None)),
        (b'{"v": 1, "cmd": "set", "mode": "auto"}', SetMode("auto", None)),
        (b'{"v": 1, "cmd": "history"}', History(None, MAX_PAGE)),
        (b'{"v": 1, "cmd": "history", "since": null, "limit": 5}', History(None, 5)),
        (b'{"v": 1, "cmd": "history", "since": 120.5}', History(120.5, MAX_PAGE)),
    ],
)
def test_requests_are_read_as_documented(line: bytes, request_: object) -> None:
    assert parse_request(line) == request_


@pytest.mark.parametrize(
    ("line", "says"),
    [
        (b"\xff\xfe", "not UTF-8"),
        (b"status", "not JSON"),
        (b'["status"]', "a request is a JSON object"),
        (b'{"cmd": "status"}', "protocol version None"),
        (b'{"v": 2, "cmd": "status"}', "protocol version 2"),
        (b'{"v": 1, "cmd": "boil"}', "unknown command 'boil'"),
        (b'{"v": 1, "cmd": "status", "x": 1}', "status does not take x"),
        (b'{"v": 1, "cmd": "set", "setpoint": true}', "setpoint: expected a number, got true"),
        (b'{"v": 1, "cmd": "set", "setpoint": "72"}', 'setpoint: expected a number, got "72"'),
        (b'{"v": 1, "cmd": "set", "setpoint": NaN}', "NaN is not a number here"),
        (b'{"v": 1, "cmd": "set", "setpoint": 1e999}', "is not a usable number"),
        (b'{"v": 1, "cmd": "set", "mode": "auto", "output": 4}', "output goes with mode 'manual'"),
        (b'{"v": 1, "cmd": "set", "mode": 1}', "mode: expected 'auto' or 'manual'"),
        (b'{"v": 1, "cmd": "set"}', "set takes either setpoint, or mode"),
        (b'{"v": 1, "cmd": "set", "setpoint": 70, "mode": "auto"}', "set mode does not take"),
        (b'{"v": 1, "cmd": "history", "limit": 0}', "limit: expected a whole number 1 to 2000"),
        (b'{"v": 1, "cmd": "history", "limit": 2001}', "got 2001"),
        (b'{"v": 1, "cmd": "history", "limit": 5.5}', "got 5.5"),
        (b'{"v": 1, "cmd": "history", "since": "x"}', 'since: expected a number, got "x"'),
        (b'{"v": 1, "cmd": "history", "until": 3}', "history does not take until"),
        (b'{"v": 1, "cmd": "reset-alarm", "kinds": "dry_fire"}', 'got "dry_fire"'),
        (b'{"v": 1, "cmd": "reset-alarm", "kinds": ["boil"]}', "kinds: expected a list of alarms"),
        (b'{"v": 1, "cmd": "reset-alarm", "all": true}', "reset-alarm does not take all"),
        (b"[" * 3000, "the request is nested deeper than 16 levels"),  # not a RecursionError
        (b'{"v": 1, "cmd": "set", "setpoint": -Infinity}', "-Infinity is not a number here"),
    ],
)
def test_a_bad_request_is_refused_with_what_is_wrong(line: bytes, says: str) -> None:
    with pytest.raises(ProtocolError) as caught:
        parse_request(line)
    assert says in str(caught.value)
    assert "\n" not in str(caught.value)


def test_a_negative_zero_is_read_as_zero() -> None:
    request = parse_request(b'{"v": 1, "cmd": "set", "mode": "manual", "output": -0.0}')
    assert isinstance(request, SetMode) and request.output is not None
    assert math.copysign(1.0, request.output) == 1.0  # 0.0 == -0.0: the sign tells them apart


# -- commands at the period boundary --------------------------------------------------------


class Inbox:
    """Stands in for the server thread: commands handed to the loop, and its wake-ups."""

    def __init__(self) -> None:
        self.queue: list[Pending] = []
        self.woken = 0

    def take(self) -> list[Pending]:
        taken, self.queue = self.queue, []
        return taken

    def wake(self) -> None:
        self.woken += 1

    def send(self, command: Command) -> Pending:
        pending = Pending(command)
        self.queue.append(pending)
        return pending


def linked(tmp_path: Path, text: str = BASE, **kwargs: Any) -> tuple[Daemon, Path, Events, Inbox]:
    daemon, _world, path, events = start(tmp_path, text, **kwargs)
    inbox = Inbox()
    LoopLink(daemon).attach(inbox)
    run_for(daemon, 60.0)
    return daemon, path, events, inbox


def status_of(daemon: Daemon) -> dict[str, Any]:
    assert isinstance(daemon.control, LoopLink)
    reply: dict[str, Any] = json.loads(daemon.control.status_line())
    return reply


def operator_lines(events: Events) -> list[str]:
    return [line for line in events.logged() if line.startswith("operator:")]


def test_a_setpoint_is_applied_at_the_next_boundary_answered_after_it_and_logged(
    tmp_path: Path,
) -> None:
    daemon, _path, events, inbox = linked(tmp_path)
    mark = len(events.periods)
    pending = inbox.send(SetSetpoint(72.0))
    assert pending.reply is None  # nothing happens between boundaries

    run_for(daemon, PERIOD)

    assert [r.setpoint for r in events.periods[mark:]] == [72.0]
    assert pending.reply is not None
    assert (pending.reply["ok"], pending.reply["setpoint"]) == (True, 72.0)
    assert inbox.woken == 1
    assert operator_lines(events) == ["operator: set setpoint 72 °C (from the control socket)"]


def test_manual_and_back_to_auto_is_bumpless(tmp_path: Path) -> None:
    daemon, _path, events, inbox = linked(tmp_path)
    inbox.send(SetMode("manual", 40.0))
    run_for(daemon, PERIOD)
    assert (events.periods[-1].mode, events.periods[-1].output) == ("manual", 40.0)

    inbox.send(SetMode("auto"))
    run_for(daemon, PERIOD)

    assert events.periods[-1].mode == "auto"
    assert events.periods[-1].reset_from == 40.0  # the controller takes over from 40 %
    assert operator_lines(events) == [
        "operator: set mode manual at 40 % (from the control socket)",
        "operator: set mode auto (from the control socket)",
    ]


@pytest.mark.parametrize(
    ("command", "says"),
    [
        (SetSetpoint(150.0), "control.setpoint: 150 °C is out of range (a number from 0 to 100"),
        (SetSetpoint(-0.5), "control.setpoint: -0.5 °C is out of range"),
        (SetSetpoint(95.0), "95 °C is not below safety.max_temp (95 °C)"),
        (SetMode("manuel"), "'manuel' is not one of the choices ('auto' or 'manual'; did you"),
        (SetMode("manual", 100.5), "control.manual_output: 100.5 % is out of range"),
        (SetMode("manual", 80.5), "80.5 % is above control.max_output (80 %)"),
    ],
)
def test_a_bad_value_is_refused_in_one_line_and_changes_nothing(
    tmp_path: Path, command: Command, says: str
) -> None:
    daemon, _path, events, inbox = linked(tmp_path, edited(BASE, control__max_output="80.0"))
    before = events.periods[-1]
    pending = inbox.send(command)

    run_for(daemon, 3 * PERIOD)

    assert pending.reply is not None
    assert pending.reply["ok"] is False
    error = pending.reply["error"]
    assert error.startswith("refused, nothing changed: ")
    assert says in error
    assert "\n" not in error
    for record in events.periods[-3:]:
        assert (record.setpoint, record.mode) == (before.setpoint, before.mode)
    assert operator_lines(events) == []
    assert status_of(daemon)["runtime"] == {}


def test_reset_alarm_clears_a_latched_alarm_and_says_what_remains(tmp_path: Path) -> None:
    store = LatchStore(tmp_path / "state")
    store.directory.mkdir()
    store.save(Latches((LatchedAlarm("ssr_stuck_on", 0, "rose 2 °C beyond the heat given"),), 0))
    daemon, _path, events, inbox = linked(tmp_path, latches=store)
    assert "ssr_stuck_on" in events.periods[-1].alarms

    pending = inbox.send(ResetAlarms())
    run_for(daemon, PERIOD)

    assert pending.reply is not None
    assert pending.reply["alarms"] == []
    assert events.periods[-1].heater_allowed
    assert "operator: reset-alarm (from the control socket)" in events.logged()
    assert store.load().alarms == ()


def test_reset_alarm_clears_only_the_alarms_the_brewer_saw(tmp_path: Path) -> None:
    store = LatchStore(tmp_path / "state")
    store.directory.mkdir()
    seen = LatchedAlarm("ssr_stuck_on", 0, "rose 2 °C beyond the heat given")
    since = LatchedAlarm("dry_fire", 0, "rose 1.6 °C/min")  # raised after the page was drawn
    store.save(Latches((seen, since), 0))
    daemon, _path, events, inbox = linked(tmp_path, latches=store)

    pending = inbox.send(ResetAlarms(("ssr_stuck_on",)))
    run_for(daemon, PERIOD)

    assert pending.reply is not None
    assert pending.reply["alarms"] == ["dry_fire"]
    assert not events.periods[-1].heater_allowed
    assert "operator: reset-alarm ssr_stuck_on (from the control socket)" in events.logged()
    assert [alarm.kind for alarm in store.load().alarms] == ["dry_fire"]


def test_a_reset_says_what_it_cleared_and_that_a_hot_over_temperature_stands(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Water at 97 °C over the 95 °C cut-out and a latched SSR alarm: the reset clears the
    latched one, and says the over-temperature stands, does not latch, and clears below
    95 − 5 = 90 °C; not "done" over a heater that stays off. The command line shows the same."""
    store = LatchStore(tmp_path / "state")
    store.directory.mkdir()
    store.save(Latches((LatchedAlarm("ssr_stuck_on", 0, "rose 2 °C beyond the heat given"),), 0))
    daemon, _path, events, inbox = linked(tmp_path, latches=store, tun=FoptdPlant(start_c=97.0))
    assert events.periods[-1].alarms == ["over_temperature", "ssr_stuck_on"]

    pending = inbox.send(ResetAlarms(("over_temperature", "ssr_stuck_on")))
    run_for(daemon, PERIOD)

    assert pending.reply is not None and pending.reply["alarms"] == ["over_temperature"]
    reset = pending.reply["reset"]
    assert reset["cleared"] == ["ssr_stuck_on"]
    assert list(reset["standing"]) == ["over_temperature"]
    why = reset["standing"]["over_temperature"]
    assert why.startswith("does not latch, so no reset clears it: it clears by itself once the "
                          "water is below 90 °C (")  # fmt: skip
    assert "at or above the limit 95.0 °C" in why
    assert reset["text"] == (
        "reset: cleared ssr_stuck_on; still standing, the heater stays off: "
        f"over_temperature: {why}"
    )

    with serve(daemon, tmp_path / "control.sock"):
        assert main(["reset-alarm", "--socket", os.fspath(tmp_path / "control.sock")]) == 0
    said = capsys.readouterr().out
    assert said.startswith("reset: cleared none; still standing, the heater stays off: "
                           "over_temperature: does not latch")  # fmt: skip
    assert "done" not in said


def test_status_holds_the_period_the_limits_in_force_and_the_model(tmp_path: Path) -> None:
    daemon, _path, events, _inbox = linked(tmp_path)
    status = status_of(daemon)
    last = events.periods[-1]

    assert (status["pv"], status["setpoint"], status["output"]) == (
        last.pv,
        last.setpoint,
        last.output,
    )
    assert (status["mode"], status["state"], status["alarms"]) == ("auto", "ok", [])
    assert (
        status["limits"][0]
        == "over-temperature cut-out              95 °C, back below 90 °C  [configured]"
    )
    prior = factory.prior_model(daemon.config)  # nothing learned: the config's model
    assert status["model"] == {
        "gain": prior.gain,
        "tau": prior.tau,
        "dead_time": prior.dead_time,
        "ambient": prior.ambient,
        "from": "prior",
    }
    assert status["learned"] is None


def storing_daemon(config: config_module.Config, store: ModelStore) -> Daemon:
    """A simulated daemon that keeps what it learns in `store`, linked, a period run."""
    clock = VirtualClock()
    world = build_world(config, clock)
    daemon = assemble(config, clock, world.sensor, world.outputs, models=store)
    LoopLink(daemon).attach(Inbox())
    daemon.start()
    run_for(daemon, PERIOD)
    return daemon


def test_status_names_the_learned_model_in_force(tmp_path: Path) -> None:
    config = read.parse(BASE)
    litres = config.tun.litres
    store = ModelStore(tmp_path)
    # 0.5 °C/min at full power, a 12000 s time constant: K = 0.5/60·12000/100 = 1 °C/%.
    store.save(LearnedModel(0.5 / 60.0, 1.0 / 12000.0, 90.0, 18.0, litres, wall_ns=7))
    daemon = storing_daemon(config, store)

    status = status_of(daemon)

    assert status["model"] == pytest.approx(
        {"gain": 1.0, "tau": 12000.0, "dead_time": 90.0, "ambient": 18.0, "from": "learned"}
    )
    assert status["learned"]["rate_c_per_min"] == pytest.approx(0.5)
    assert (status["learned"]["litres"], status["learned"]["learned_at_ns"]) == (litres, 7)


def test_status_shows_what_was_learned_as_soon_as_it_is_stored(tmp_path: Path) -> None:
    """Stored mid-day: the status says so at once, though it is in force from the next start."""
    config = read.parse(BASE)
    store = ModelStore(tmp_path)
    daemon = storing_daemon(config, store)
    assert status_of(daemon)["learned"] is None
    learned = LearnedModel(0.5 / 60.0, 1.0 / 12000.0, 90.0, 18.0, config.tun.litres, wall_ns=9)
    # What the daemon's learner hands over when a hold has taught it the tun.
    daemon.saver.save("model", lambda: store.save(learned), learned)
    assert daemon.saver.flush(5.0)
    run_for(daemon, PERIOD)

    status = status_of(daemon)

    assert status["learned"]["learned_at_ns"] == 9
    assert status["learned"]["text"] == learned.describe()
    assert status["model"]["from"] == "prior"  # used from the next start


# -- the rule: a runtime set holds until the file's same key is edited ----------------------


def set_then_edit(tmp_path: Path, command: Command, **edit: str) -> tuple[Daemon, Path, Events]:
    """A runtime `command`, then an edit of the config file (`edited` keys), each applied."""
    daemon, path, events, inbox = linked(tmp_path)
    inbox.send(command)
    run_for(daemon, PERIOD)
    rename_over(path, edited(BASE, **edit))
    run_for(daemon, 2 * PERIOD)
    return daemon, path, events


def test_a_runtime_setpoint_outlives_edits_of_other_keys_and_shows_in_status(
    tmp_path: Path,
) -> None:
    daemon, _path, events = set_then_edit(tmp_path, SetSetpoint(72.0), control__kc="100.0")

    assert daemon.config.control.kc == 100.0  # the edit was taken
    assert events.periods[-1].setpoint == 72.0  # and the runtime setpoint held
    assert status_of(daemon)["runtime"] == {"control.setpoint": {"running": 72.0, "file": 66.0}}


def test_an_edit_of_the_setpoint_in_the_file_wins_over_the_runtime_one(tmp_path: Path) -> None:
    daemon, _path, events = set_then_edit(tmp_path, SetSetpoint(72.0), control__setpoint="70.0")

    assert events.periods[-1].setpoint == 70.0
    assert status_of(daemon)["runtime"] == {}


def test_a_runtime_mode_holds_until_the_files_mode_or_manual_output_is_edited(
    tmp_path: Path,
) -> None:
    daemon, path, events = set_then_edit(
        tmp_path, SetMode("manual", 40.0), control__setpoint="67.0"
    )
    assert (events.periods[-1].mode, events.periods[-1].output) == ("manual", 40.0)
    assert status_of(daemon)["runtime"] == {
        "control.mode": {"running": "manual", "file": "auto"},
        "control.manual_output": {"running": 40.0, "file": 0.0},
    }

    rename_over(path, edited(BASE, control__setpoint="67.0", control__manual_output="10.0"))
    run_for(daemon, 2 * PERIOD)
    assert events.periods[-1].mode == "auto"  # the file's mode, being the newer intent
    assert status_of(daemon)["runtime"] == {}


def test_an_edit_that_puts_the_cut_out_below_a_runtime_setpoint_brings_back_the_files(
    tmp_path: Path,
) -> None:
    _daemon, _path, events = set_then_edit(tmp_path, SetSetpoint(90.0), safety__max_temp="85.0")

    assert events.periods[-1].setpoint == 66.0
    assert "setpoint 90 °C is not below the new safety.max_temp: back to the file's" in (
        events.logged()
    )


def test_an_edit_that_lowers_the_power_limit_lowers_a_runtime_manual_output_to_it(
    tmp_path: Path,
) -> None:
    _daemon, _path, events = set_then_edit(
        tmp_path, SetMode("manual", 60.0), control__max_output="50.0"
    )

    assert (events.periods[-1].mode, events.periods[-1].output) == ("manual", 50.0)


# -- the socket itself ----------------------------------------------------------------------


@contextlib.contextmanager
def served(
    tmp_path: Path, directory: Path | None = None, text: str = BASE
) -> Iterator[tuple[Daemon, Path]]:
    """A daemon on the virtual clock, stepped a period at a time on a thread, behind a socket."""
    daemon, _world, _path, _events = start(tmp_path, text)
    where = (directory or tmp_path) / "control.sock"
    with serve(daemon, where):
        yield daemon, where


@contextlib.contextmanager
def serve(daemon: Daemon, where: Path) -> Iterator[None]:
    """`daemon` behind a control socket at `where`, stepped a period at a time on a thread."""
    link = LoopLink(daemon)
    server = ControlServer(where)
    server.answer_with(link.status_line, link.history_line, link.arrived)
    server.start()
    link.attach(server)
    stop = threading.Event()

    def step() -> None:
        while not stop.is_set():
            run_for(daemon, PERIOD)
            stop.wait(0.002)  # paces virtual time; nothing here is measured on this clock

    run_for(daemon, PERIOD)  # a period has run before any client asks: status has its answer
    stepping = threading.Thread(target=step)
    stepping.start()
    try:
        yield
    finally:
        stop.set()
        stepping.join(TIMEOUT)
        server.close()


def exchange(sock: socket.socket, line: bytes) -> dict[str, Any]:
    sock.sendall(line)
    reply = b""
    while not reply.endswith(b"\n"):
        chunk = sock.recv(65536)
        assert chunk, "connection closed without a reply"
        reply += chunk
    message: dict[str, Any] = json.loads(reply)
    return message


def connect(where: Path) -> socket.socket:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.settimeout(TIMEOUT)
    sock.connect(os.fspath(where))
    return sock


def test_the_socket_is_for_the_owner_and_group_only(tmp_path: Path) -> None:
    with served(tmp_path) as (_daemon, where):
        info = os.stat(where)
    assert stat.S_ISSOCK(info.st_mode)
    assert stat.S_IMODE(info.st_mode) == 0o660
    assert info.st_gid == os.getegid()


def _connect_as(where: Path, uid: int, gid: int) -> subprocess.CompletedProcess[str]:
    """Try to connect from a child process that has dropped to `uid`/`gid`."""

    def drop() -> None:
        os.setgroups([])
        os.setgid(gid)
        os.setuid(uid)

    probe = (
        "import socket, sys\n"
        "s = socket.socket(socket.AF_UNIX)\n"
        "try:\n"
        f"    s.connect({os.fspath(where)!r})\n"
        "except PermissionError:\n"
        "    sys.exit(13)\n"
    )
    assert SYSTEM_PYTHON is not None
    return subprocess.run(
        [SYSTEM_PYTHON, "-c", probe],
        preexec_fn=drop,
        capture_output=True,
        text=True,
        timeout=TIMEOUT,
    )


@pytest.mark.skipif(os.geteuid() != 0, reason="dropping to another uid needs root")
@pytest.mark.skipif(SYSTEM_PYTHON is None, reason="no python3 in /usr/bin for the probe")
def test_a_user_outside_the_group_cannot_connect_and_one_inside_can(tmp_path: Path) -> None:
    # A directory anyone may enter, so that only the socket's own mode decides.
    directory = Path(tempfile.mkdtemp(prefix="hermsd-socket-"))
    try:
        directory.chmod(0o755)
        with served(tmp_path, directory) as (_daemon, where):
            group = os.stat(where).st_gid
            outside = _connect_as(where, NOBODY, NOBODY)
            inside = _connect_as(where, NOBODY, group)
    finally:
        with contextlib.suppress(OSError):
            (directory / "control.sock").unlink()
        directory.rmdir()
    assert (outside.returncode, outside.stderr) == (13, "")
    assert (inside.returncode, inside.stderr) == (0, "")


def test_a_bad_line_is_answered_and_the_connection_serves_on(tmp_path: Path) -> None:
    with served(tmp_path) as (_daemon, where), connect(where) as sock:
        refused = exchange(sock, b"hello\n")
        status = exchange(sock, b'{"v": 1, "cmd": "status"}\n')
    assert refused["ok"] is False
    assert refused["error"].startswith("the request is not JSON")
    assert status["ok"] is True


def test_an_over_long_line_is_refused_and_the_connection_closed(tmp_path: Path) -> None:
    with served(tmp_path) as (_daemon, where), connect(where) as sock:
        reply = exchange(sock, b"x" * (2 * MAX_LINE))
        rest = sock.recv(100)
    assert reply == {"v": 1, "ok": False, "error": f"request longer than {MAX_LINE} bytes"}
    assert rest == b""


def test_requests_piled_up_behind_an_unanswered_command_end_the_connection(
    tmp_path: Path,
) -> None:
    # No loop takes the command, so its reply never comes while the client sends on.
    server = ControlServer(tmp_path / "control.sock", lambda: b'{"v": 1, "ok": true}\n')
    server.start()
    try:
        with connect(server.path) as sock:
            sock.sendall(b'{"v": 1, "cmd": "set", "setpoint": 70}\n')
            reply = exchange(sock, b'{"v": 1, "cmd": "status"}\n' * (3 * MAX_LINE // 26))
            rest = sock.recv(100)
    finally:
        server.close()
    assert reply == {"v": 1, "ok": False, "error": "one request at a time: read each reply first"}
    assert rest == b""


def test_clients_beyond_the_limit_are_told_so(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # One process may fill every place here, to reach the bound on them all.
    monkeypatch.setattr(server_module, "PER_PROCESS", server_module.MAX_CLIENTS + 1)
    monkeypatch.setattr(server_module, "PER_USER", server_module.MAX_CLIENTS + 1)
    with served(tmp_path) as (_daemon, where), contextlib.ExitStack() as stack:
        clients = [stack.enter_context(connect(where)) for _ in range(server_module.MAX_CLIENTS)]
        for client in clients:  # each one is being served
            assert exchange(client, STATUS)["ok"]
        extra = stack.enter_context(connect(where))
        reply = json.loads(extra.recv(1000))
    assert reply["error"] == (
        f"busy: {server_module.MAX_CLIENTS} clients connected already (try again in a minute)"
    )


_HOLD = """
import json, socket, sys
held, said = [], []
for _ in range(int(sys.argv[2])):
    sock = socket.socket(socket.AF_UNIX)
    sock.settimeout(5.0)
    sock.connect(sys.argv[1])
    try:
        sock.sendall(b'{"v": 1, "cmd": "status"}\\n')
    except BrokenPipeError:  # told "busy" and closed before it sent: the line is there still
        pass
    reply = json.loads(sock.makefile().readline())
    said.append(True if reply["ok"] else reply["error"])
    held.append(sock)
print(json.dumps(said), flush=True)
sys.stdin.read()  # holds them until the test closes its stdin
"""


@contextlib.contextmanager
def holding(where: Path, count: int) -> Iterator[tuple[int, list[Any]]]:
    """Another process that opens `count` connections, asks `status` on each and keeps them
    open: its pid, and each connection's answer (True: served, else the error)."""
    hog = subprocess.Popen(
        [sys.executable, "-c", _HOLD, os.fspath(where), str(count)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert hog.stdout is not None and hog.stdin is not None
        ready, _, _ = select.select([hog.stdout], [], [], TIMEOUT)
        assert ready, "the holding process did not say what it holds"
        yield hog.pid, json.loads(hog.stdout.readline())
    finally:
        hog.kill()
        hog.wait(TIMEOUT)


def test_one_process_holding_connections_leaves_room_for_the_commands(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with served(tmp_path) as (_daemon, where), holding(where, server_module.MAX_CLIENTS) as held:
        code = main(["status", "--json", "--socket", os.fspath(where)])
        out = capsys.readouterr().out
    pid, answers = held
    per = server_module.PER_PROCESS
    assert answers[:per] == [True] * per
    assert answers[per:] == [
        f"busy: this process (pid {pid}) holds {per} connections already, the most one process "
        "may (close one: each request needs one only until its reply)"
    ] * (server_module.MAX_CLIENTS - per)
    assert code == 0
    assert json.loads(out)["ok"] is True


def test_one_users_processes_leave_room_for_the_others(tmp_path: Path) -> None:
    per, uid = server_module.PER_PROCESS, os.getuid()
    assert 2 * per == server_module.PER_USER  # two processes fill one user's share
    with (
        served(tmp_path) as (_daemon, where),
        holding(where, per) as (_, first),
        holding(where, per) as (_, second),
        holding(where, 1) as (_, third),
    ):
        pass
    assert first == second == [True] * per
    assert third == [
        f"busy: the processes of uid {uid} hold {2 * per} connections already, the most one "
        "user's may (close some)"
    ]


def test_the_commands_say_busy_in_one_line_and_exit_1(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with served(tmp_path) as (_daemon, where), contextlib.ExitStack() as stack:
        for _ in range(server_module.PER_PROCESS):  # this process holds all it may
            assert exchange(stack.enter_context(connect(where)), STATUS)["ok"]
        code = main(["status", "--socket", os.fspath(where)])
    captured = capsys.readouterr()
    assert code == 1
    assert captured.err == (
        f"hermsd: busy: this process (pid {os.getpid()}) holds {server_module.PER_PROCESS} "
        "connections already, the most one process may (close one: each request needs one only "
        "until its reply)\n"
    )
    assert captured.out == ""


def test_a_connection_closed_before_the_request_is_sent_is_told_not_a_broken_pipe(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The daemon says "busy" and closes before the command has sent its request: the send
    fails (EPIPE), and the line is read all the same."""
    where = tmp_path / "control.sock"
    busy = b'{"v": 1, "ok": false, "error": "busy: 32 clients connected already"}\n'
    closed = threading.Event()
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind(os.fspath(where))
    listener.listen(1)

    def refuse() -> None:
        conn, _ = listener.accept()
        conn.sendall(busy)
        conn.close()
        closed.set()

    class SendsAfterTheClose(socket.socket):
        def connect(self, address: Any) -> None:
            super().connect(address)
            assert closed.wait(TIMEOUT)

    refusing = threading.Thread(target=refuse)
    refusing.start()
    monkeypatch.setattr(socket, "socket", SendsAfterTheClose)
    try:
        code = main(["set", "setpoint", "70", "--socket", os.fspath(where)])
    finally:
        monkeypatch.undo()
        refusing.join(TIMEOUT)
        listener.close()
    captured = capsys.readouterr()
    assert (code, captured.err) == (1, "hermsd: busy: 32 clients connected already\n")


def test_clients_that_hung_up_unseen_hold_no_place(tmp_path: Path) -> None:
    server = ControlServer(tmp_path / "control.sock", lambda: b'{"v": 1, "ok": true}\n')
    server.start()
    try:
        gone = [connect(server.path) for _ in range(server_module.PER_PROCESS)]
        for client in gone:
            assert exchange(client, STATUS)["ok"]
        # The serving thread stops before it sees them hang up, as when it is not scheduled.
        server._stop = True
        server.wake()
        assert server._thread is not None
        server._thread.join(TIMEOUT)
        for client in gone:
            client.close()
        with connect(server.path):
            server._accept()
            assert len(server._clients) == 1  # taken in, not told "busy"
    finally:
        server.close()


def test_a_line_nested_3000_deep_is_refused_and_the_socket_serves_on(tmp_path: Path) -> None:
    server = ControlServer(tmp_path / "control.sock", lambda: b'{"v": 1, "ok": true}\n')
    server.start()
    try:
        with connect(server.path) as sock:
            refused = exchange(sock, b"[" * 3000 + b"\n")
        with connect(server.path) as sock:
            status = exchange(sock, STATUS)
    finally:
        server.close()
    assert refused == {"v": 1, "ok": False, "error": "the request is nested deeper than 16 levels"}
    assert status == {"v": 1, "ok": True}


def test_an_unexpected_exception_serving_one_client_ends_its_connection_alone(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    asked = 0

    def status_failing_once() -> bytes:
        nonlocal asked
        asked += 1
        if asked == 1:
            raise RuntimeError("an unforeseen fault\nover two lines")
        return b'{"v": 1, "ok": true}\n'

    server = ControlServer(tmp_path / "control.sock", status_failing_once)
    server.start()
    try:
        with connect(server.path) as sock:
            failed = exchange(sock, STATUS)
            after = sock.recv(100)
        with connect(server.path) as sock:
            served_next = exchange(sock, STATUS)
        assert server._thread is not None and server._thread.is_alive()
    finally:
        server.close()
    fault = "RuntimeError: an unforeseen fault over two lines"
    assert failed == {"v": 1, "ok": False, "error": f"hermsd failed to answer ({fault})"}
    assert after == b""  # that connection alone is closed
    assert served_next == {"v": 1, "ok": True}
    said = [r.getMessage() for r in caplog.records if r.name == "hermsd"]
    assert said == [
        f"control socket: serving pid {os.getpid()} failed ({fault}); its connection is "
        "closed, the socket serves on"
    ]


def test_a_socket_left_by_a_crash_is_replaced_and_a_live_one_is_not(tmp_path: Path) -> None:
    stale = socket.socket(socket.AF_UNIX)
    stale.bind(os.fspath(tmp_path / "control.sock"))
    stale.close()  # the file stays, nothing listens: as after a SIGKILL
    with served(tmp_path) as (_daemon, where):
        held_by_this_process = rf"another hermsd \(pid {os.getpid()}\) answers on"
        with pytest.raises(SocketInUseError, match=held_by_this_process):
            ControlServer(where, lambda: b"").start()
        with connect(where) as sock:
            assert exchange(sock, b'{"v": 1, "cmd": "status"}\n')["ok"]


# -- the commands ---------------------------------------------------------------------------


def test_status_and_set_through_the_commands(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with served(tmp_path) as (_daemon, where):
        sock = ["--socket", os.fspath(where)]
        assert main(["set", "setpoint", "72", *sock]) == 0
        assert capsys.readouterr().out == "now: setpoint 72 °C, auto\n"
        assert main(["set", "mode", "manual", "--output", "40", *sock]) == 0
        assert capsys.readouterr().out == "now: setpoint 72 °C, manual at 40 %\n"
        assert main(["status", "--json", *sock]) == 0
        status = json.loads(capsys.readouterr().out)
        assert main(["status", *sock]) == 0
        text = capsys.readouterr().out
    assert (status["setpoint"], status["mode"], status["output"]) == (72.0, "manual", 40.0)
    assert "control.setpoint 72.0 set at runtime (config file: 66.0)" in text
    assert "safety limits in force:" in text


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["set", "setpoint", "150"], "hermsd: refused, nothing changed: control.setpoint: 150 °C"),
        (["set", "setpoint", "hot"], "hermsd: setpoint: expected a number in °C, got 'hot'"),
        (["set", "setpoint", "nan"], "hermsd: setpoint: expected a number in °C, got 'nan'"),
        (["set", "mode", "banana"], "hermsd: mode: expected auto or manual, got 'banana'"),
        (["set", "mode", "auto", "--output", "4"], "hermsd: --output goes with `set mode manual`"),
        (["set", "power", "4"], "hermsd: set: expected setpoint, mode or pump, got 'power'"),
        (
            ["set", "mode", "manual", "--output", "101"],
            "hermsd: refused, nothing changed: control.manual_output: 101 %",
        ),
    ],
)
def test_a_bad_command_gets_one_line_exit_2_and_changes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], says: str
) -> None:
    with served(tmp_path) as (_daemon, where):
        sock = ["--socket", os.fspath(where)]
        assert main([*argv, *sock]) == 2
        err = capsys.readouterr().err
        assert main(["status", "--json", *sock]) == 0
        status = json.loads(capsys.readouterr().out)
    assert err.startswith(says)
    assert err.count("\n") == 1
    assert (status["setpoint"], status["mode"], status["runtime"]) == (66.0, "auto", {})


@pytest.mark.parametrize("argv", [["status"], ["status", "--json"], ["set", "setpoint", "70"]])
def test_no_daemon_is_one_line_naming_the_socket_and_exit_1(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str]
) -> None:
    where = tmp_path / "control.sock"
    assert main([*argv, "--socket", os.fspath(where)]) == 1
    captured = capsys.readouterr()
    assert captured.err == f"hermsd: no hermsd is running: nothing answers on {where}\n"
    assert captured.out == ""


def test_reset_alarm_without_a_daemon_asks_through_the_state_directory(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    store = LatchStore(tmp_path)
    store.save(Latches((LatchedAlarm("ssr_stuck_on", 0, "rose 2 °C beyond the heat given"),), 0))
    argv = ["reset-alarm", "--socket", os.fspath(tmp_path / "none.sock"), "--state"]

    assert main([*argv, os.fspath(tmp_path)]) == 0

    assert store.take_reset_request() == ["ssr_stuck_on"]
    assert "reset asked" in capsys.readouterr().out


def test_a_model_written_by_tune_is_in_force_after_the_edit(tmp_path: Path) -> None:
    daemon, path, _events, _inbox = linked(tmp_path)
    tuned = edited(
        BASE,
        control__model_gain="2.0",
        control__model_tau="12000.0",
        control__dead_time="90.0",
        control__model_ambient="18.0",
        control__model_litres="90.0",
    )
    rename_over(path, tuned)  # as `hermsd tune --write` replaces the file
    run_for(daemon, 2 * PERIOD)

    status = status_of(daemon)

    assert status["model"] == pytest.approx(
        {"gain": 2.0, "tau": 12000.0, "dead_time": 90.0, "ambient": 18.0, "from": "measured"}
    )
    # The supervisor's limits from it: heat shows within 1.5·θ = 135 s, not the 300 s any tun
    # may need.
    shown = [row for row in status["limits"] if row.startswith("heat shows at the sensor")]
    assert len(shown) == 1
    assert shown[0].endswith(" 135 s  [measured]")


def test_reset_alarm_with_nothing_latched_says_so(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with served(tmp_path) as (_daemon, where):
        assert main(["reset-alarm", "--socket", os.fspath(where)]) == 0
    assert capsys.readouterr().out == "no alarm to reset\n"


def _ask_once(where: Path, line: bytes) -> tuple[dict[str, Any], bytes]:
    """A request on a connection of its own, as `hermsd status` sends one: the reply, and
    what came after it before the server closed (b"" once it has)."""
    with connect(where) as sock:
        reply = exchange(sock, line)
        sock.shutdown(socket.SHUT_WR)
        return reply, sock.recv(100)


def test_a_client_flooding_costly_requests_is_refused_until_its_rate_allows(
    tmp_path: Path,
) -> None:
    now = 0.0
    server = ControlServer(
        tmp_path / "control.sock", lambda: b'{"v": 1, "ok": true}\n', clock=lambda: now
    )
    server.start()
    status = b'{"v": 1, "cmd": "status"}\n'
    start = b'{"v": 1, "cmd": "program", "action": "start", "program": {"steps": []}}\n'
    checked = "program: steps: expected a list of 1 to 50 steps"  # parsed and checked
    try:
        for _ in range(3 * server_module.REQUEST_BURST):  # status costs next to nothing
            assert _ask_once(server.path, status)[0]["ok"] is True
        for _ in range(server_module.REQUEST_BURST):
            assert _ask_once(server.path, start)[0]["error"].startswith(checked)
        refused, after = _ask_once(server.path, start)
        asked_status = _ask_once(server.path, status)[0]
        big = start.replace(b"[]", b"[" + b" " * 60000 + b"]")  # never read whole
        refused_big, after_big = _ask_once(server.path, big)
        other = subprocess.run(  # another process: its own allowance
            [sys.executable, "-c", _ONE_REQUEST, os.fspath(server.path), start.decode()],
            capture_output=True,
            text=True,
            timeout=TIMEOUT,
        )
        now += 1.0 / server_module.REQUEST_RATE  # one request's worth later
        again = _ask_once(server.path, start)[0]
        still = _ask_once(server.path, start)[0]
    finally:
        server.close()
    words = (
        f"refused: this client (pid {os.getpid()}) sent more than "
        f"{server_module.REQUEST_BURST} requests at once or {server_module.REQUEST_RATE:g} a "
        "second (status and history aside); try again in "
    )
    assert refused == {"v": 1, "ok": False, "error": words + "0.5 s"}
    assert after == b""  # one line, and the connection is closed
    # Status is answered whatever the rate: the web page serves every browser from one
    # process, and one brewer's taps must not blind the others (or their stop).
    assert asked_status["ok"] is True
    assert (refused_big["error"], after_big) == (words + "0.5 s", b"")
    assert json.loads(other.stdout)["error"].startswith(checked)
    assert again["error"].startswith(checked)
    assert still["error"] == words + "0.5 s"


_ONE_REQUEST = """
import socket, sys
sock = socket.socket(socket.AF_UNIX)
sock.connect(sys.argv[1])
sock.sendall(sys.argv[2].encode())
print(sock.makefile().readline())
"""


def test_status_says_why_each_alarm_stands(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    store = LatchStore(tmp_path / "state")
    store.directory.mkdir()
    why = "controller output nan % is not a duty within 0..100 % (check the control settings)"
    store.save(Latches((LatchedAlarm("controller_fault", 0, why, {"output": "nan"}),), 0))
    daemon, _path, _events, _inbox = linked(tmp_path, latches=store)
    status = status_of(daemon)
    monkeypatch.setattr(remote, "_ask", lambda path, request: status)
    assert main(["status"]) == 0
    text = capsys.readouterr().out
    assert status["alarms"] == ["controller_fault"]
    [(kind, reason)] = status["alarm_reasons"].items()
    assert kind == "controller_fault"
    assert reason.startswith(f"{why} (latched ") and reason.endswith(", before a restart)")
    assert f"alarms: controller_fault\n  controller_fault: {reason}\n" in text


def test_status_warns_of_a_progress_and_a_log_that_are_not_saved(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    state = tmp_path / "state"
    state.mkdir()
    daemon, _path, events, inbox = linked(tmp_path, latches=LatchStore(state))
    (state / PROGRESS_FILE).mkdir()  # nothing can be renamed over a directory
    failing = "creating /var/log/hermsd: [Errno 30] Read-only file system"
    events.failing = failing  # type: ignore[attr-defined]  # as the recorder says it
    started = inbox.send(ProgramStart(Program("One", (Step("Warm", 30.0, 600.0),))))
    run_for(daemon, PERIOD)
    assert started.reply is not None and started.reply["ok"] is True
    assert daemon.program.flush(5.0)
    run_for(daemon, 2 * PERIOD)  # the outcome taken, then shown in the next period's status
    status = status_of(daemon)
    monkeypatch.setattr(remote, "_ask", lambda path, request: status)
    assert main(["status"]) == 0
    shown = [line for line in capsys.readouterr().out.splitlines() if "warning" in line]
    not_saved = status["program"]["save_failed"]
    assert "Is a directory" in not_saved
    assert status["log_failing"] == failing
    assert shown == [
        f"warning: program progress not saved (a restart may not resume it): {not_saved}",
        f"warning: log failing (control goes on, this brew is not recorded): {failing}",
    ]


def test_a_negative_zero_output_shows_as_zero(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with served(tmp_path) as (_daemon, where):
        sock = ["--socket", os.fspath(where)]
        assert main(["set", "mode", "manual", "--output", "-0.0", *sock]) == 0
        said = capsys.readouterr().out
        assert main(["status", "--json", *sock]) == 0
        status = capsys.readouterr().out
    assert said == "now: setpoint 66 °C, manual at 0 %\n"
    assert '"manual_output": 0.0,' in status
