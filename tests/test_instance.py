"""One daemon per log and state directory; a simulated run never writes into `log.dir`."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hermsd.api.server import ControlServer
from hermsd.cli import commands as cli
from hermsd.cli import run as cli_run
from hermsd.log.topics import PART_SUFFIX
from hermsd.runtime.instance import LOCK_FILE, DirectoryLock, InstanceError

TIMEOUT_S = 30.0


def test_a_held_directory_is_refused_naming_the_holder(tmp_path: Path) -> None:
    first, second = DirectoryLock(tmp_path), DirectoryLock(tmp_path)
    first.acquire("log directory")
    assert (tmp_path / LOCK_FILE).read_text() == f"{os.getpid()}\n"
    with pytest.raises(InstanceError, match=rf"pid {os.getpid()}\b.*one daemon per log directory"):
        second.acquire("log directory")
    first.release()
    second.acquire("log directory")  # free again once released (or its process gone)
    second.release()


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "hermsd.cli", *args]


def _run(directory: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        _cli(*args), capture_output=True, text=True, timeout=TIMEOUT_S, cwd=directory
    )


def _wait_for_part(proc: subprocess.Popen[bytes], directory: Path) -> Path:
    deadline = time.monotonic() + TIMEOUT_S
    while time.monotonic() < deadline:
        assert proc.poll() is None, "the first daemon died"
        parts = list(directory.glob(f"*.mcap{PART_SUFFIX}"))
        if parts:
            return parts[0]
        time.sleep(0.02)
    raise AssertionError("the first daemon wrote no log")


def test_a_second_daemon_on_the_same_directories_touches_nothing_and_says_who(
    tmp_path: Path,
) -> None:
    logs, state = tmp_path / "logs", tmp_path / "state"
    first = subprocess.Popen(
        _cli("run", "--simulate", "--log", str(logs), "--state", str(state)),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        cwd=tmp_path,
    )
    try:
        part = _wait_for_part(first, logs)
        # On the same log directory: refused before recovering the live .part.
        second = _run(tmp_path, "run", "--simulate", "--duration", "5s", "--log", str(logs))
        assert second.returncode == 2
        assert second.stderr.splitlines() == [
            f"hermsd: {logs} is the log directory of another hermsd (pid {first.pid}): one "
            "daemon per log directory; stop that one first, or give this one another"
        ]
        assert part.exists() and not list(logs.glob("*.mcap"))
        # A real (not simulated) daemon on the same state directory: refused before it opens
        # its outputs (this SSR port does not exist; opening it would be the error said).
        config = tmp_path / "hermsd.yaml"
        config.write_text(
            "output:\n  backend: serial-rts\n  port: /dev/ttyUSB-absent\n"
            f"log:\n  dir: {tmp_path / 'other-logs'}\n"
        )
        third = _run(tmp_path, "run", "--config", str(config), "--state", str(state))
        assert third.returncode == 2
        assert third.stderr.splitlines() == [
            f"hermsd: {state} is the state directory of another hermsd (pid {first.pid}): one "
            "daemon per state directory; stop that one first, or give this one another"
        ]
        assert first.poll() is None
    finally:
        first.terminate()
        first.wait(TIMEOUT_S)
    assert first.returncode == 0
    assert [p.name for p in logs.glob("*.mcap")] == [part.name.removesuffix(PART_SUFFIX)]


def test_a_simulated_run_writes_no_log_into_the_configs_log_dir(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    production = tmp_path / "var-log-hermsd"
    config = tmp_path / "hermsd.yaml"
    config.write_text(f"log:\n  dir: {production}\n")
    monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
    monkeypatch.delenv("STATE_DIRECTORY", raising=False)
    run = ["run", "--simulate", "--speed", "max", "--duration", "1m", "--config", str(config)]
    assert cli.main(run) == 0
    assert not production.exists()
    assert cli.main([*run, "--log", str(production)]) == 0  # named explicitly: written
    assert len(list(production.glob("*.mcap"))) == 1


def test_a_simulated_day_is_not_logged_into_a_held_directory(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    held = DirectoryLock(tmp_path)
    held.acquire("log directory")
    try:
        assert cli.main(["simulate", "--log", str(tmp_path)]) == 2
    finally:
        held.release()
    assert f"(pid {os.getpid()})" in capsys.readouterr().err
    assert not list(tmp_path.glob("*.mcap*"))


class _Output:
    """A hardware output that records being opened and driven."""

    def __init__(self, touched: list[str], name: str) -> None:
        self.touched, self.name = touched, name
        touched.append(f"open {name}")

    def set(self, on: bool) -> None:
        self.touched.append(f"set {self.name} {on}")

    def close(self) -> None:
        self.touched.append(f"close {self.name}")


def test_a_second_daemon_on_the_tuns_socket_opens_no_output_before_it_is_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    socket_path = tmp_path / "hermsd.sock"
    first = ControlServer(socket_path, lambda: b"")  # the daemon that owns the tun
    first.start()
    touched: list[str] = []
    monkeypatch.setattr(
        cli_run, "open_hardware_switch", lambda backend, **where: _Output(touched, backend)
    )
    monkeypatch.setattr(
        cli_run, "open_sensor", lambda sensor, clock: touched.append(f"open {sensor.kind}")
    )
    monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
    config = tmp_path / "hermsd.yaml"
    config.write_text(
        "output:\n  backend: gpio\n  line: 17\ncontactor:\n  backend: gpio\n  line: 27\n"
    )
    # Other log and state directories: only the socket tells the tun is taken.
    second = ["run", "--config", str(config), "--socket", str(socket_path)]
    second += ["--state", str(tmp_path / "state"), "--log", str(tmp_path / "logs")]
    try:
        assert cli.main(second) == 2
        assert socket_path.exists()  # still the first one's
    finally:
        first.close()
    assert capsys.readouterr().err.splitlines() == [
        f"hermsd: cannot open the control socket {socket_path}: another hermsd "
        f"(pid {os.getpid()}) answers on {socket_path} (another hermsd on this tun? else "
        "choose a place with --socket PATH)"
    ]
    assert touched == []
