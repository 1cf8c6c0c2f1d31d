"""Where `run --simulate` listens, and how the commands find it: one fixed place per user,
found without --socket when no service's socket exists, said when used; a second simulated
daemon refused naming the first. And `hermsd run` by hand where /run/hermsd is missing."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest

from hermsd.api import client
from hermsd.api.server import ControlServer
from hermsd.cli import commands as cli
from hermsd.cli import run as cli_run

TIMEOUT_S = 30.0


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "hermsd.cli", *args]


@pytest.fixture
def runtime(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Path:
    """This test's $XDG_RUNTIME_DIR, and a service socket path that does not exist."""
    directory = tmp_path / "runtime"
    directory.mkdir()
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(directory))
    monkeypatch.delenv("RUNTIME_DIRECTORY", raising=False)
    monkeypatch.setattr(client, "DEFAULT_SOCKET", tmp_path / "run-hermsd" / "control.sock")
    return directory


@pytest.fixture
def simulated(runtime: Path, tmp_path: Path) -> Iterator[subprocess.Popen[str]]:
    """`hermsd run --simulate` as the Quick start runs it, once its socket is served."""
    proc = subprocess.Popen(
        _cli("run", "--simulate", "--speed", "60"),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=tmp_path,
    )
    try:
        assert proc.stdout is not None
        first = proc.stdout.readline()  # blocks until the socket is served (or it died)
        where = runtime / "hermsd-sim" / "control.sock"
        assert first == f"control socket {where} (hermsd status, set, web and mqtt find it)\n"
        yield proc
    finally:
        proc.terminate()
        proc.communicate(timeout=TIMEOUT_S)


def test_status_in_a_second_terminal_finds_the_simulated_daemon_and_says_so(
    simulated: subprocess.Popen[str], runtime: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert cli.main(["status", "--json"]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["setpoint"] == 66.0  # the built-in config's
    where = runtime / "hermsd-sim" / "control.sock"
    assert err.splitlines() == [
        f"hermsd: using the simulated daemon's socket {where} (there is no "
        f"{client.DEFAULT_SOCKET}; --socket PATH for another)"
    ]


def test_set_reaches_the_simulated_daemon_without_options(
    simulated: subprocess.Popen[str], capsys: pytest.CaptureFixture[str]
) -> None:
    assert cli.main(["set", "setpoint", "70"]) == 0
    capsys.readouterr()
    assert cli.main(["status", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["setpoint"] == 70.0


def test_a_second_simulated_daemon_is_refused_in_one_line_naming_the_first(
    simulated: subprocess.Popen[str], runtime: Path, tmp_path: Path
) -> None:
    second = subprocess.run(
        _cli("run", "--simulate", "--speed", "max", "--duration", "10s"),
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
        cwd=tmp_path,
    )
    where = runtime / "hermsd-sim" / "control.sock"
    assert second.returncode == 2
    assert second.stdout == ""
    assert second.stderr.splitlines() == [
        f"hermsd: cannot open the control socket {where}: another hermsd (pid {simulated.pid}) "
        f"answers on {where} (a simulated hermsd runs: stop it first (Ctrl-C in its "
        "terminal), or give this one --socket PATH)"
    ]


def test_the_service_socket_wins_over_a_simulated_one(runtime: Path, tmp_path: Path) -> None:
    simulated_path = runtime / "hermsd-sim" / "control.sock"
    simulated_path.parent.mkdir()
    simulated_path.touch()
    assert client.find_socket() == simulated_path
    client.DEFAULT_SOCKET.parent.mkdir()
    client.DEFAULT_SOCKET.touch()  # a service's socket, even one left by a crash
    assert client.find_socket() == client.DEFAULT_SOCKET
    given = tmp_path / "elsewhere.sock"
    assert client.find_socket(given) == given


def test_with_no_daemon_at_all_the_commands_name_the_service_socket(
    runtime: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert cli.main(["status"]) == 1
    assert capsys.readouterr().err.splitlines() == [
        f"hermsd: no hermsd is running: nothing answers on {client.DEFAULT_SOCKET}"
    ]


def test_without_xdg_runtime_dir_the_socket_is_in_the_temporary_directory_by_uid(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.delenv("XDG_RUNTIME_DIR")
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    expected = tmp_path / f"hermsd-sim-{os.getuid()}" / "control.sock"
    assert client.simulated_socket_path() == expected


def test_a_foreign_thing_at_the_fallback_directory_is_refused(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """/tmp is everyone's: a directory planted there (here a symlink to one) is not used."""
    monkeypatch.delenv("XDG_RUNTIME_DIR")
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    elsewhere = tmp_path / "planted"
    elsewhere.mkdir()
    planted = tmp_path / f"hermsd-sim-{os.getuid()}"
    planted.symlink_to(elsewhere)
    assert cli.main(["run", "--simulate", "--speed", "max", "--duration", "10s"]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert err.splitlines() == [
        f"hermsd: {planted} is not a directory of this user's (uid {os.getuid()}): it cannot "
        "hold the simulated daemon's control socket (remove it, or choose a place with "
        "--socket PATH)"
    ]
    assert list(elsewhere.iterdir()) == []


def test_run_by_hand_without_run_hermsd_says_the_directory_is_missing_and_how_to_make_it(
    runtime: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    opened: list[str] = []
    monkeypatch.setattr(
        cli_run, "open_hardware_switch", lambda backend, **where: opened.append(backend)
    )
    monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
    config = tmp_path / "hermsd.yaml"
    config.write_text("output:\n  backend: gpio\n  line: 17\n")
    argv = ["run", "--config", str(config), "--state", str(tmp_path / "state")]
    assert cli.main([*argv, "--log", str(tmp_path / "logs")]) == 2
    directory = client.DEFAULT_SOCKET.parent
    assert capsys.readouterr().err.splitlines() == [
        f"hermsd: cannot open the control socket {client.DEFAULT_SOCKET}: its directory "
        f"{directory} does not exist (the service's RuntimeDirectory= makes it; by hand: "
        f"`sudo install -d -o hermsd -g hermsd -m 0750 {directory}`, or choose a place with "
        "--socket PATH)"
    ]
    assert opened == []  # refused before any output is opened
    assert not directory.exists()


def test_a_socket_already_served_is_named_with_its_pid(tmp_path: Path) -> None:
    path = tmp_path / "control.sock"
    first = ControlServer(path, lambda: b"")
    first.start()
    try:
        with pytest.raises(OSError, match=rf"another hermsd \(pid {os.getpid()}\) answers on"):
            ControlServer(path).bind()
    finally:
        first.close()
