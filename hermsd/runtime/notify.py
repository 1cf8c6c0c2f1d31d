"""Tell systemd how the daemon is doing: the sd_notify datagram protocol, without libsystemd.

A `Type=notify` unit learns that the loop is up (READY=1), reloading, stopping, what it is
doing (STATUS=…) and that it is still alive (WATCHDOG=1) from single AF_UNIX datagrams sent
to the socket named in $NOTIFY_SOCKET. Outside systemd the variable is unset and every call
does nothing, so the same daemon runs by hand, in the simulator and under systemd.

Sending never raises and never blocks: a notification is worth less than a control period,
so a vanished or congested socket is counted and remembered, not propagated.
"""

from __future__ import annotations

import math
import os
import socket
import time
from collections.abc import Mapping


class NotifyEnvironmentError(ValueError):
    """The environment names a notify socket or watchdog that cannot be used as written."""


class Notifier:
    """Sends sd_notify messages to one socket; a no-op when there is no socket.

    `address` is what `socket.sendto` takes: a filesystem path, or a name starting with a
    NUL byte for the Linux abstract namespace. `watchdog_usec` is WATCHDOG_USEC when the
    watchdog is meant for this process, else None.
    """

    def __init__(self, address: str | None, watchdog_usec: int | None = None) -> None:
        self._address = address
        self._watchdog_usec = watchdog_usec
        self._failed_sends = 0
        self._last_error: OSError | None = None

    @classmethod
    def from_environment(
        cls, env: Mapping[str, str] = os.environ, *, pid: int | None = None
    ) -> Notifier:
        """Read NOTIFY_SOCKET, WATCHDOG_USEC and WATCHDOG_PID as systemd 252 sets them.

        `pid` is the process the watchdog must belong to (default: this one); a watchdog
        addressed to another pid is ignored, as sd_watchdog_enabled(3) does.
        """
        address = _socket_address(env.get("NOTIFY_SOCKET", ""))
        watchdog_usec = _positive_int(env, "WATCHDOG_USEC")
        watchdog_pid = _positive_int(env, "WATCHDOG_PID")
        own_pid = os.getpid() if pid is None else pid
        if watchdog_pid is not None and watchdog_pid != own_pid:
            watchdog_usec = None
        return cls(address, watchdog_usec)

    @property
    def enabled(self) -> bool:
        """True when messages go somewhere (the daemon runs under a `Type=notify` unit)."""
        return self._address is not None

    @property
    def failed_sends(self) -> int:
        """How many messages could not be delivered."""
        return self._failed_sends

    @property
    def last_error(self) -> OSError | None:
        """Why the most recent failed message failed (None if none has failed)."""
        return self._last_error

    @property
    def watchdog_timeout(self) -> float | None:
        """WatchdogSec= in seconds; None when no watchdog is set for this process."""
        return None if self._watchdog_usec is None else self._watchdog_usec / 1e6

    def watchdog_interval(self) -> float | None:
        """Seconds between WATCHDOG=1 pings: half of WATCHDOG_USEC, as sd_watchdog_enabled(3)
        advises; None when no watchdog is set for this process."""
        if self._watchdog_usec is None:
            return None
        return self._watchdog_usec / 2 / 1e6

    def ready(self) -> None:
        """Start-up (or a reload) is complete; systemd moves the unit to 'active'."""
        self._send("READY=1")

    def reloading(self) -> None:
        """A reload has begun; send `ready()` when it is done.

        MONOTONIC_USEC is ignored by systemd 252 and required with RELOADING=1 by the
        `Type=notify-reload` of later versions; sending it costs nothing and keeps the
        message right for both.
        """
        monotonic_usec = time.clock_gettime_ns(time.CLOCK_MONOTONIC) // 1000
        self._send(f"RELOADING=1\nMONOTONIC_USEC={monotonic_usec}")

    def stopping(self) -> None:
        """The daemon is shutting down on its own or on request."""
        self._send("STOPPING=1")

    def status(self, text: str) -> None:
        """One line shown by `systemctl status`.

        Newlines separate assignments in the protocol, so any in `text` become spaces: a
        status line must never be able to say READY=1 or WATCHDOG=1 on its own.
        """
        self._send("STATUS=" + " ".join(text.splitlines()))

    def watchdog(self) -> None:
        """Keep-alive; send only when `WatchdogGate.due` says the loop has earned it."""
        self._send("WATCHDOG=1")

    def _send(self, message: str) -> None:
        if self._address is None:
            return
        payload = message.encode("utf-8")
        try:
            with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
                # MSG_DONTWAIT: a full receive queue must cost one failed message, not a
                # blocked control loop.
                sock.sendto(payload, socket.MSG_DONTWAIT | socket.MSG_NOSIGNAL, self._address)
        except OSError as error:
            self._failed_sends += 1
            self._last_error = error


class WatchdogGate:
    """Decides when the loop has earned a WATCHDOG=1 ping.

    A ping vouches for a healthy cycle (a fresh sensor reading that led to a fresh decision,
    heating or held off by an alarm or a waiting program) that no earlier ping vouched for,
    and pings are at least `interval` seconds apart. A loop that keeps running but stops
    producing healthy cycles (no readings) therefore stops pinging, and systemd kills and
    restarts it; `ExecStopPost=` then forces the element off.
    """

    def __init__(self, interval: float) -> None:
        if not interval > 0:
            raise ValueError(f"watchdog ping interval is {interval} s; it must be > 0 s")
        self._interval = interval
        self._last_ping: float | None = None
        self._unvouched_healthy_cycle = False

    def note_healthy_cycle(self) -> None:
        """A fresh sensor reading has just produced a fresh decision of the outputs."""
        self._unvouched_healthy_cycle = True

    def due(self, now: float) -> bool:
        """True means: send WATCHDOG=1 now. The gate records the ping as sent."""
        if not self._unvouched_healthy_cycle:
            return False
        if self._last_ping is not None and now - self._last_ping < self._interval:
            return False
        self._last_ping = now
        self._unvouched_healthy_cycle = False
        return True


def check_watchdog(notifier: Notifier, period: float) -> None:
    """Refuse a watchdog that one late control period could trip.

    WATCHDOG=1 goes out at most once per healthy period, so a timeout shorter than three
    periods would have systemd kill a loop that merely missed one reading.
    """
    timeout = notifier.watchdog_timeout
    if timeout is not None and timeout < 3 * period:
        raise NotifyEnvironmentError(
            f"WatchdogSec={timeout:g}s is shorter than three control periods "
            f"(3 × {period:g} s): set WatchdogSec={math.ceil(3 * period)}s or more in the "
            "unit, or shorten control.period"
        )


def status_line(
    name: str,
    pv: float | None,
    setpoint: float,
    output: float,
    state: str,
    output2: float | None = None,
    mash_side: str = "",
) -> str:
    """The STATUS text: 'HLT 65.94 °C → 66.00 °C, out 27 %, ok'; '--' when PV is unknown;
    'out 27 % + element 2 100 %' with a second element (it may be on at 0 % on the SSR);
    `mash_side` (`mash_side_words`) before the state.

    Two decimals show the LM92's 0.0625 °C steps; the output is a whole percent.
    """
    measured = "--" if pv is None else f"{pv:.2f}"
    second = "" if output2 is None else f" + element 2 {output2:.0f} %"
    herms = f", {mash_side}" if mash_side else ""
    return f"{name} {measured} °C → {setpoint:.2f} °C, out {output:.0f} %{second}{herms}, {state}"


def mash_side_words(mash: dict[str, object] | None, pump: bool | None, setpoint: float) -> str:
    """'mash 64.8 °C, pump on': what of the two is fitted ('mash sensor fault' while it is
    faulty; '' when neither is fitted); 'mash 64.8 → 65.0 °C (climb)' while the outer loop
    steers the HLT for the mash's `setpoint`, and '(climb, levels out near 60.0 °C)' while
    the HLT at its most cannot bring it there. `mash` as the status reply gives it."""
    words = []
    if mash is not None:
        shown = role_words("mash", mash)
        phase = mash.get("phase")
        if phase is not None and mash["fault"] is None:
            level = mash.get("levels_at")
            if isinstance(level, float):
                phase = f"{phase}, levels out near {level:.1f} °C"
            shown = shown.replace(" °C", "") + f" → {setpoint:.1f} °C ({phase})"
        words.append(shown)
    if pump is not None:
        words.append(pump_words(pump, mash))
    return ", ".join(words)


def pump_words(pump: bool, mash: dict[str, object] | None) -> str:
    """'pump on', 'pump off', or 'pump starting in 65 s' while a start is prepared (the
    status reply's `mash.pump_start_in`); with the program's pump timer, its next turn too:
    'pump on, off in 4 min (timer)' (`mash.pump_turn_in`)."""
    starting = None if mash is None else mash.get("pump_start_in")
    if not pump and isinstance(starting, int | float):
        return f"pump starting in {starting:.0f} s"
    words = f"pump {'on' if pump else 'off'}"
    turn = None if mash is None else mash.get("pump_turn_in")
    if isinstance(turn, int | float):
        when = f"{turn:.0f} s" if turn < 120.0 else f"{turn / 60.0:.0f} min"
        words += f", {'off' if pump else 'on'} in {when} (timer)"
    return words


def current_words(current: dict[str, object]) -> str:
    """'element current 13.0 A (SSR on)' of the status reply's `current`: the latest sample's
    amps, or 'powered'/'off' from an input that measures none, against the SSR's command then;
    'not judging' while its warning stands (the warning itself is among the warnings)."""
    if current.get("warning") is not None:
        return "element current: not judging"
    amps, drawing, on = current.get("amps"), current.get("drawing"), current.get("on")
    if isinstance(amps, float):
        shown = f"{amps:.1f} A"
    else:
        shown = "--" if drawing is None else "powered" if drawing else "off"
    return f"element current {shown}" + ("" if on is None else f" (SSR {'on' if on else 'off'})")


def role_words(role: str, reading: dict[str, object]) -> str:
    """'mash 64.8 °C' of a role's sensor as the status reply gives it; 'mash sensor fault'
    while it is faulty, 'mash --' before its first good reading."""
    if reading["fault"] is not None:
        return f"{role} sensor fault"
    celsius = reading["celsius"]
    return f"{role} {celsius:.1f} °C" if isinstance(celsius, float) else f"{role} --"


def _socket_address(value: str) -> str | None:
    if value == "":
        return None
    if value.startswith("@") and len(value) > 1:
        return "\0" + value[1:]
    if value.startswith("/"):
        return value
    raise NotifyEnvironmentError(
        f"NOTIFY_SOCKET={value!r} is neither an absolute path nor '@' + an abstract name"
    )


def _positive_int(env: Mapping[str, str], name: str) -> int | None:
    value = env.get(name)
    if value is None:
        return None
    if not (value.isascii() and value.isdigit()) or int(value) == 0:
        raise NotifyEnvironmentError(f"{name}={value!r} is not a positive whole number")
    return int(value)
