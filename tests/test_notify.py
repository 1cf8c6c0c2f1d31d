"""sd_notify on real datagram sockets, and the watchdog rule on a virtual clock."""

from __future__ import annotations

import os
import secrets
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from hermsd.runtime.notify import Notifier, NotifyEnvironmentError, WatchdogGate, status_line
from hermsd.sim.clock import VirtualClock


@pytest.fixture
def path_receiver(tmp_path: Path) -> Iterator[tuple[socket.socket, str]]:
    """A datagram socket bound at a filesystem path, as systemd binds /run/systemd/notify."""
    address = str(tmp_path / "notify")
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as receiver:
        receiver.bind(address)
        receiver.settimeout(2.0)
        yield receiver, address


@pytest.fixture
def abstract_receiver() -> Iterator[tuple[socket.socket, str]]:
    """A datagram socket in the abstract namespace; returns the '@name' form systemd uses."""
    name = "hermsd-test-" + secrets.token_hex(8)
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as receiver:
        receiver.bind("\0" + name)
        receiver.settimeout(2.0)
        yield receiver, "@" + name


def _received(receiver: socket.socket) -> bytes:
    return receiver.recv(4096)


@pytest.mark.parametrize("receiver_fixture", ["path_receiver", "abstract_receiver"])
def test_each_message_is_one_datagram_with_the_exact_bytes(
    receiver_fixture: str, request: pytest.FixtureRequest
) -> None:
    receiver, notify_socket = request.getfixturevalue(receiver_fixture)
    notifier = Notifier.from_environment({"NOTIFY_SOCKET": notify_socket})
    assert notifier.enabled

    notifier.ready()
    notifier.status("HLT 65.94 °C → 66.00 °C, out 27 %, ok")
    notifier.watchdog()
    notifier.stopping()

    assert _received(receiver) == b"READY=1"
    # The status travels as UTF-8: '°' is C2 B0, '→' is E2 86 92.
    assert _received(receiver) == (
        b"STATUS=HLT 65.94 \xc2\xb0C \xe2\x86\x92 66.00 \xc2\xb0C, out 27 %, ok"
    )
    assert _received(receiver) == b"WATCHDOG=1"
    assert _received(receiver) == b"STOPPING=1"
    assert notifier.failed_sends == 0


def test_reloading_carries_the_monotonic_time_in_microseconds(
    path_receiver: tuple[socket.socket, str],
) -> None:
    receiver, notify_socket = path_receiver
    notifier = Notifier.from_environment({"NOTIFY_SOCKET": notify_socket})

    before_usec = time.clock_gettime_ns(time.CLOCK_MONOTONIC) // 1000
    notifier.reloading()
    after_usec = time.clock_gettime_ns(time.CLOCK_MONOTONIC) // 1000

    first, second = _received(receiver).split(b"\n")
    assert first == b"RELOADING=1"
    key, value = second.split(b"=")
    assert key == b"MONOTONIC_USEC"
    assert before_usec <= int(value) <= after_usec


def test_a_newline_in_the_status_cannot_smuggle_in_another_assignment(
    path_receiver: tuple[socket.socket, str],
) -> None:
    receiver, notify_socket = path_receiver
    notifier = Notifier.from_environment({"NOTIFY_SOCKET": notify_socket})

    notifier.status("HLT\nREADY=1")

    assert _received(receiver) == b"STATUS=HLT READY=1"


def test_without_notify_socket_nothing_is_sent(monkeypatch: pytest.MonkeyPatch) -> None:
    def no_socket_allowed(*args: object) -> socket.socket:
        raise AssertionError("a socket was opened although NOTIFY_SOCKET is unset")

    monkeypatch.setattr(socket, "socket", no_socket_allowed)
    notifier = Notifier.from_environment({})

    notifier.ready()
    notifier.reloading()
    notifier.status("HLT -- °C → 66.00 °C, out 0 %, sensor lost")
    notifier.watchdog()
    notifier.stopping()

    assert not notifier.enabled
    assert notifier.failed_sends == 0
    assert notifier.last_error is None
    assert notifier.watchdog_interval() is None


def test_the_default_environment_is_the_process_environment(
    monkeypatch: pytest.MonkeyPatch, path_receiver: tuple[socket.socket, str]
) -> None:
    receiver, notify_socket = path_receiver
    monkeypatch.setenv("NOTIFY_SOCKET", notify_socket)
    monkeypatch.setenv("WATCHDOG_USEC", "4000000")
    monkeypatch.setenv("WATCHDOG_PID", str(os.getpid()))

    notifier = Notifier.from_environment()
    notifier.ready()

    assert _received(receiver) == b"READY=1"
    assert notifier.watchdog_interval() == 2.0


def test_a_vanished_path_socket_is_counted_not_raised(tmp_path: Path) -> None:
    address = tmp_path / "notify"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as receiver:
        receiver.bind(str(address))
    address.unlink()
    notifier = Notifier.from_environment({"NOTIFY_SOCKET": str(address)})

    notifier.watchdog()
    notifier.ready()

    assert notifier.failed_sends == 2
    assert isinstance(notifier.last_error, FileNotFoundError)


def test_a_closed_abstract_socket_is_counted_not_raised() -> None:
    name = "hermsd-test-" + secrets.token_hex(8)
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as receiver:
        receiver.bind("\0" + name)
    notifier = Notifier.from_environment({"NOTIFY_SOCKET": "@" + name})

    notifier.watchdog()

    assert notifier.failed_sends == 1
    assert isinstance(notifier.last_error, ConnectionRefusedError)


def test_a_receiver_that_stops_reading_never_blocks_the_sender(
    path_receiver: tuple[socket.socket, str],
) -> None:
    """Linux queues at most net.unix.max_dgram_qlen unread datagrams per socket; a blocking
    send beyond that would stall the control loop."""
    receiver, notify_socket = path_receiver
    notifier = Notifier.from_environment({"NOTIFY_SOCKET": notify_socket})
    messages = int(Path("/proc/sys/net/unix/max_dgram_qlen").read_text()) + 100

    def send_all() -> None:
        for _ in range(messages):
            notifier.watchdog()

    sender = threading.Thread(target=send_all, daemon=True)
    sender.start()
    sender.join(timeout=5.0)
    blocked = sender.is_alive()
    receiver.close()  # unblocks a sender stuck in sendto, should the assertion fail
    sender.join(timeout=5.0)

    assert not blocked
    assert 0 < notifier.failed_sends < messages
    assert isinstance(notifier.last_error, BlockingIOError)


@pytest.mark.parametrize(
    ("environment", "interval"),
    [
        ({"WATCHDOG_USEC": "15000000"}, 7.5),  # WatchdogSec=15s → ping every 7.5 s
        ({"WATCHDOG_USEC": "15000000", "WATCHDOG_PID": "4242"}, 7.5),
        ({"WATCHDOG_USEC": "15000000", "WATCHDOG_PID": "4243"}, None),  # meant for another
        ({"WATCHDOG_PID": "4242"}, None),
        ({}, None),
    ],
)
def test_watchdog_interval_is_half_of_watchdog_usec_for_our_pid_only(
    environment: dict[str, str], interval: float | None
) -> None:
    notifier = Notifier.from_environment({"NOTIFY_SOCKET": "@x", **environment}, pid=4242)

    assert notifier.watchdog_interval() == interval


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("NOTIFY_SOCKET", "run/systemd/notify"),
        ("NOTIFY_SOCKET", "@"),
        ("WATCHDOG_USEC", "15s"),
        ("WATCHDOG_USEC", "0"),
        ("WATCHDOG_USEC", "-1"),
        ("WATCHDOG_PID", "self"),
    ],
)
def test_a_malformed_environment_is_refused_with_the_variable_named(name: str, value: str) -> None:
    with pytest.raises(NotifyEnvironmentError, match=f"^{name}="):
        Notifier.from_environment({name: value})


def _run_loop(gate: WatchdogGate, clock: VirtualClock, until: float, healthy: bool) -> list[float]:
    """One cycle per simulated second: note the cycle if healthy, then ping if due."""
    pings = []
    while clock.monotonic() < until:
        if healthy:
            gate.note_healthy_cycle()
        if gate.due(clock.monotonic()):
            pings.append(clock.monotonic())
        clock.sleep(1.0)
    return pings


def test_no_ping_without_a_healthy_cycle() -> None:
    clock = VirtualClock()
    gate = WatchdogGate(interval=7.5)

    assert _run_loop(gate, clock, until=100.0, healthy=False) == []


def test_a_healthy_loop_pings_at_most_once_per_interval() -> None:
    clock = VirtualClock()
    gate = WatchdogGate(interval=7.5)

    pings = _run_loop(gate, clock, until=100.0, healthy=True)

    # By hand: the first healthy cycle pings at 0 s; on a 1 s grid the next cycle at least
    # 7.5 s later is 8 s later, so pings fall on 0, 8, …, 96.
    assert pings == [float(t) for t in range(0, 100, 8)]


def test_a_stalled_loop_stops_pinging() -> None:
    clock = VirtualClock()
    gate = WatchdogGate(interval=7.5)

    healthy_pings = _run_loop(gate, clock, until=21.0, healthy=True)
    stalled_pings = _run_loop(gate, clock, until=300.0, healthy=False)

    # By hand: pings at 0, 8, 16; the healthy cycles 17..20 s are still unvouched, so one
    # more ping at 24 s (16 + 7.5 rounded up to the 1 s grid) — then silence, and systemd's
    # 15 s watchdog fires at 39 s.
    assert healthy_pings == [0.0, 8.0, 16.0]
    assert stalled_pings == [24.0]


def test_a_recovered_loop_pings_again_at_once() -> None:
    clock = VirtualClock()
    gate = WatchdogGate(interval=7.5)
    _run_loop(gate, clock, until=10.0, healthy=False)

    assert _run_loop(gate, clock, until=11.0, healthy=True) == [10.0]


@pytest.mark.parametrize("interval", [0.0, -1.0, float("nan")])
def test_a_gate_needs_a_positive_interval(interval: float) -> None:
    with pytest.raises(ValueError, match="must be > 0"):
        WatchdogGate(interval)


def test_status_line_shows_pv_setpoint_output_and_state() -> None:
    # 65.9375 °C is 1055 LM92 steps of 0.0625 °C; shown to two decimals it is 65.94.
    assert status_line("HLT", 65.9375, 66.0, 27.2, "ok") == (
        "HLT 65.94 °C → 66.00 °C, out 27 %, ok"
    )


def test_status_line_without_a_reading_shows_dashes() -> None:
    assert status_line("HLT", None, 66.0, 0.0, "sensor lost") == (
        "HLT -- °C → 66.00 °C, out 0 %, sensor lost"
    )
