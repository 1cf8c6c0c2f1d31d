"""Time-proportional output: a duty per window becomes SSR edges, and the outputs that carry them.

A zero-cross SSR switches only at mains zero crossings, so on-times are whole half-cycles.
The planner quantises each window's on-time to that grid and to the minimum on and off
times, and carries what it could not deliver into the next window, so the energy delivered
over many windows is exactly what the controller asked for. It reports the duty its edges
give (`applied`); the daemon feeds back the duty the SSR was then driven at, as switched.

On-times alternate between the end of one window and the start of the next, so at a steady
duty two windows share one pulse: half the edges (and the flicker) of a pulse per window.
With a `band`, a run goes on across whole windows until the water is owed (or has been given
ahead) that much heat: fewer edges for a bounded swing of the water (docs/ssr-band.md).

The outputs start off, turn off on close, and sit behind a dead-man (`GuardedSwitch`) that
switches them off when the control loop stops refreshing them.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import threading
from dataclasses import dataclass
from typing import Any, Protocol

from hermsd.hardware.gpio_line import GpioLine


@dataclass(frozen=True, slots=True)
class WindowPlan:
    """One window: when the SSR goes on and off, and the duty that timing gives (`applied`)."""

    start: float
    length: float
    on_at: float
    off_at: float
    requested: float
    applied: float
    # Heat (s at full power) asked in this window that the band carries to later ones
    # (negative: given ahead of asking); 0 where nothing is carried on purpose.
    deferred: float = 0.0

    @property
    def on_time(self) -> float:
        return self.off_at - self.on_at

    def is_on(self, t: float) -> bool:
        return self.on_at <= t < self.off_at


class TimeProportionalPlanner:
    """Turns a duty (0–100 %) per window into an on interval, exact on average."""

    def __init__(
        self,
        window: float,
        mains_hz: int = 50,
        min_on: float = 0.0,
        min_off: float = 0.0,
        band: float = 0.0,
    ) -> None:
        if not window > 0:
            raise ValueError(f"window must be positive, got {window}")
        if mains_hz not in (50, 60):
            raise ValueError(f"mains_hz must be 50 or 60, got {mains_hz}")
        if min_on < 0 or min_off < 0 or min_on + min_off >= window:
            raise ValueError("min_on and min_off must be >= 0 and together shorter than window")
        if not 0.0 <= band <= window:
            raise ValueError(f"band must be within 0..window ({window} s), got {band}")
        self.window = window
        self.half_cycle = 1.0 / (2 * mains_hz)
        self.slots = round(window / self.half_cycle)
        if self.slots < 2:
            raise ValueError(f"window {window} s is shorter than two mains half-cycles")
        # Minimum times in whole half-cycles; an on-time shorter than that is not delivered.
        self.min_on_slots = math.ceil(min_on / self.half_cycle - 1e-9)
        self.min_off_slots = math.ceil(min_off / self.half_cycle - 1e-9)
        # Heat (half-cycles at full power) owed or given ahead before a run of windows ends.
        self.band_slots = round(band / self.half_cycle)
        self._carry = 0.0  # half-cycles owed to (positive) or by (negative) the next window
        self._ends_on = False  # the SSR is on as the window before ends

    def reset(self) -> None:
        """Forget any carried error (after a forced off the debt is not paid back); the SSR
        is off now."""
        self._carry = 0.0
        self._ends_on = False

    def plan(
        self, start: float, duty: float, at_once: bool = False, gap: bool = False
    ) -> WindowPlan:
        """The window that begins at `start` with `duty` % requested; `at_once`: its pulse
        from its start where it would end it (a load just begun unannounced, its heat already
        late: sent as early as the window allows, at the cost of an edge pair once); `gap`: a
        window that would be fully on is off for the minimum off time at one end (a current
        input's proof that the SSR still opens, docs/current.md), what it withholds carried as
        any shortfall is."""
        if not 0.0 <= duty <= 100.0:
            raise ValueError(f"duty must be within 0..100 %, got {duty}")
        slots = self.slots
        carried, deferred = self._carry, 0.0
        if duty <= 0.0 or duty >= 100.0:
            # Fully off or fully on: no edges inside the window (but a gap's) and nothing owed
            # (what was carried is forgotten, not deferred).
            on = 0 if duty <= 0.0 else (slots - self.min_off_slots if gap else slots)
            self._carry = 0.0
        else:
            wanted = duty / 100.0 * slots + self._carry
            on = self._run(wanted)
            if gap and on == slots:
                on -= self.min_off_slots
            # The debt stays within the band and what the minimum times can withhold.
            limit = max(self.min_on_slots, self.min_off_slots, 1) + self.band_slots
            self._carry = max(-limit, min(limit, wanted - on))
            if self.band_slots:
                deferred = (self._carry - carried) * self.half_cycle
        on_time = on * self.half_cycle
        # The pulse joins the state the window before ended in: on, it starts the window;
        # off, it ends it. One edge a window (the windows alternate by themselves), also
        # after a window fully on or off, where a fixed alternation spent two.
        at_end = not (self._ends_on or at_once)
        self._ends_on = on == slots or (at_end and on > 0)
        if on == 0:
            on_at = off_at = start + self.window
        elif on == slots:
            on_at, off_at = start, start + self.window
        elif at_end:
            on_at, off_at = start + self.window - on_time, start + self.window
        else:
            on_at, off_at = start, start + on_time
        return WindowPlan(start, self.window, on_at, off_at, duty, 100.0 * on / slots, deferred)

    def swing(self, rate: float) -> float:
        """°C the water swings at most under these pulses, heated at `rate` °C/s at full
        power: the band's 2·r·B and a joined pulse's r·W/2 at 50 % (docs/ssr-band.md)."""
        return rate * (2.0 * self.band_slots * self.half_cycle + 0.5 * self.window)

    def full_from(self, plan: WindowPlan, at: float) -> WindowPlan:
        """`plan` with the element on from `at` to the window's end (cold water seen inside
        the window): from the next half-cycle of the window's grid, or on as it already is,
        and not before the SSR has been off for the minimum off time (counted from the
        window's start when it was off all along: it may have been on until then). When less
        than the minimum on time is left, the plan stays as it was (the next window comes
        at once). What was carried is forgotten: this window delivers more than was asked.
        `applied` counts a pulse that already ended in this window as well."""
        end = plan.start + plan.length
        if plan.is_on(at):
            on_at, before = plan.on_at, 0.0
        else:
            ended = plan.on_at < plan.off_at <= at
            before = plan.on_time if ended else 0.0
            off_since = plan.off_at if ended else plan.start
            earliest = max(at, off_since + self.min_off_slots * self.half_cycle)
            slots = math.ceil((earliest - plan.start) / self.half_cycle - 1e-9)
            on_at = plan.start + slots * self.half_cycle
            if end - on_at < max(self.min_on_slots, 1) * self.half_cycle - 1e-9:
                return plan
        self._carry = 0.0
        self._ends_on = True
        applied = 100.0 * (before + end - on_at) / plan.length
        return WindowPlan(plan.start, plan.length, on_at, end, 100.0, applied)  # nothing carried

    def _run(self, wanted: float) -> int:
        """This window's on-time: an off run lasts whole windows until the water is owed more
        than the band, then the pulse at the window's end gives all but the band; an on run
        lasts whole windows until a window would leave more than the band given ahead, and
        then stops where it has. With no band: what is owed, each window."""
        band = self.band_slots
        if self._ends_on:
            return self.slots if wanted + band >= self.slots else self._deliverable(wanted + band)
        return 0 if wanted <= band else self._deliverable(wanted - band)

    def _deliverable(self, wanted: float) -> int:
        """Whole half-cycles nearest to `wanted` that respect the minimum on and off times."""
        slots = self.slots
        on = max(0, min(slots, round(wanted)))
        if 0 < on < self.min_on_slots:
            on = self.min_on_slots if wanted >= self.min_on_slots / 2 else 0
        off = slots - on
        if 0 < off < self.min_off_slots:
            on = slots - self.min_off_slots if slots - wanted >= self.min_off_slots / 2 else slots
        return on


def cut(plan: WindowPlan, at: float) -> WindowPlan:
    """The plan with the heater forced off from `at` on; applied is what was really delivered,
    and nothing is carried (the planner forgets its debt after a forced off)."""
    if at >= plan.off_at:
        return dataclasses.replace(plan, deferred=0.0)
    off_at = max(plan.on_at, at)
    on_at = plan.on_at if off_at > plan.on_at else off_at
    applied = 100.0 * (off_at - on_at) / plan.length
    return WindowPlan(plan.start, plan.length, on_at, off_at, plan.requested, applied)


class CarriedHeat:
    """The heat the band carried out of the windows that have ended (s at full power), each
    window counted once, whichever of its end and the period that reads it comes first."""

    def __init__(self) -> None:
        self._counted = 0.0
        self._last: float | None = None  # the start of the last window counted

    def count(self, plan: WindowPlan | None, now: float) -> None:
        """Count `plan`'s carried heat if its window has ended by `now`."""
        if plan is None or plan.start == self._last or plan.start + plan.length > now + 1e-9:
            return
        self._counted += plan.deferred
        self._last = plan.start

    def take(self, plan: WindowPlan | None, now: float) -> float:
        """What was counted since the last take, with `plan`'s if its window has ended."""
        self.count(plan, now)
        taken, self._counted = self._counted, 0.0
        return taken


class SwitchedDuty:
    """The share of time an output was switched on between one reading and the next, %:
    the heat it let through, which its controller tracks and the supervisor counts."""

    def __init__(self) -> None:
        self._on_since: float | None = None
        self._on_seconds = 0.0
        self._last: float | None = None  # the reading before; None: nothing to measure from

    def begin(self, now: float) -> None:
        """Measure from `now` (the first reading then covers the time since)."""
        self._last = now

    def switched(self, on: bool, now: float) -> None:
        """The output was switched on or off (as it was already: nothing changes)."""
        if on and self._on_since is None:
            self._on_since = now
        elif not on and self._on_since is not None:
            self._on_seconds += now - self._on_since
            self._on_since = None

    def read(self, now: float, deferred: float = 0.0) -> float:
        """% of the time since the reading before (0 for none) that the output was on, with
        `deferred` seconds more counted as on (a band's carried heat), within 0..100 %."""
        if self._on_since is not None:
            self._on_seconds += now - self._on_since
            self._on_since = now
        last = self._last if self._last is not None else now
        self._last = now
        span = now - last
        on, self._on_seconds = self._on_seconds + deferred, 0.0
        return min(100.0, max(0.0, 100.0 * on / span)) if span > 0 else 0.0


class Switch(Protocol):
    """A two-state output: the SSR's drive, or a contactor's coil."""

    def set(self, on: bool) -> None: ...

    def close(self) -> None: ...


class GuardedSwitch:
    """A switch that starts off, counts its edges, and turns itself off when not refreshed.

    The loop refreshes it at least once a window; `check()` (called from a watchdog thread
    on the Pi, or by the scheduler in the simulator) forces it off when the loop has been
    silent longer than `timeout`. Safe to call from two threads. An inner switch whose
    commands can be lost on the way (a relay board's serial frame) says so with
    `repeat_off_s`: while off, a refresh says off again that often, so one lost frame
    cannot leave a contactor closed that the loop believes open.
    """

    def __init__(self, inner: Switch, now: Any, timeout: float, name: str = "output") -> None:
        self._inner = inner
        self._now = now
        self.timeout = timeout
        self.name = name
        self._lock = threading.Lock()
        self._last_refresh = now()
        self.state = False
        self.edges = 0
        self.tripped = 0
        self._repeat_off: float | None = getattr(inner, "repeat_off_s", None)
        self._inner.set(False)
        self._last_sent = self._last_refresh

    def set(self, on: bool) -> None:
        with self._lock:
            now = self._last_refresh = self._now()
            if on != self.state:
                self._inner.set(on)
                self._last_sent = now
                self.state = on
                self.edges += 1
            elif (
                not on
                and self._repeat_off is not None
                and now - self._last_sent >= self._repeat_off
            ):
                self._inner.set(False)
                self._last_sent = now

    def check(self) -> bool:
        """Force off when the loop has not refreshed within `timeout`; True when it did so."""
        with self._lock:
            if self.state and self._now() - self._last_refresh > self.timeout:
                self._inner.set(False)
                self.state = False
                self.edges += 1
                self.tripped += 1
                return True
            return False

    def close(self) -> None:
        """Off, then release the hardware; the off is attempted even if releasing fails."""
        with self._lock:
            try:
                self._inner.set(False)
                self.state = False
            finally:
                self._inner.close()


class DeadManThread:
    """Calls `check()` on guarded outputs every `interval` seconds of real time."""

    def __init__(self, outputs: list[GuardedSwitch], interval: float = 0.1) -> None:
        self._outputs = outputs
        self._interval = interval
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="hermsd-deadman", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)

    def _run(self) -> None:
        while not self._stop.wait(self._interval):
            for output in self._outputs:
                with contextlib.suppress(Exception):
                    output.check()


class SerialLineSwitch:
    """A USB-serial adapter's RTS or DTR line driving the SSR input.

    The lines are set low before the port is opened, and HUPCL is set so that the kernel
    drops them on the last close: a process that dies leaves the SSR off. For that reason a
    serial line is active-high only: an inverted one would switch the SSR on at a crash.
    """

    def __init__(self, port: str, line: str) -> None:
        import termios

        import serial

        if line not in ("rts", "dtr"):
            raise ValueError(f"line must be 'rts' or 'dtr', got {line!r}")
        self._line = line
        self._serial = serial.Serial()
        self._serial.port = port
        self._serial.rts = False
        self._serial.dtr = False
        self._serial.open()
        fd = self._serial.fileno()
        attrs = termios.tcgetattr(fd)
        attrs[2] |= termios.HUPCL
        termios.tcsetattr(fd, termios.TCSANOW, attrs)

    def set(self, on: bool) -> None:
        setattr(self._serial, self._line, on)

    def close(self) -> None:
        self._serial.close()


class GpioSwitch:
    """A GPIO line through the `gpiod` 2.x bindings (the `gpio` extra)."""

    def __init__(self, chip: str, line: int, active_low: bool = False) -> None:
        self._line = GpioLine(
            chip, line, output=True, active_low=active_low, what="the gpio backend"
        )

    def set(self, on: bool) -> None:
        self._line.set(on)

    def close(self) -> None:
        self._line.release()


def relay_board_frame(channel: int, on: bool) -> bytes:
    """The common serial relay board's 4-byte command: A0, channel, state, checksum."""
    if not 1 <= channel <= 8:
        raise ValueError(f"relay channel must be 1..8, got {channel}")
    state = 1 if on else 0
    return bytes((0xA0, channel, state, (0xA0 + channel + state) & 0xFF))


class RelayBoardSwitch:
    """A serial relay board (fit for a contactor, never for time-proportioning)."""

    repeat_off_s = 10.0
    """The board acknowledges nothing, so off is said again this often (4 bytes, ~4 ms at
    9600 baud): a frame lost to noise or a board's reset leaves the relay closed no longer."""

    def __init__(self, port: str, channel: int, baud: int = 9600) -> None:
        import serial

        self._channel = channel
        self._serial = serial.Serial(port, baudrate=baud, timeout=1.0, write_timeout=1.0)

    def set(self, on: bool) -> None:
        self._serial.write(relay_board_frame(self._channel, on))
        self._serial.flush()

    def close(self) -> None:
        self._serial.close()


def describe_output(
    backend: str, *, port: str, chip: str, line: int | None, channel: int | None = None
) -> str:
    """The device an output's keys name, in words: its port, its chip and line, or its relay."""
    if backend == "gpio":
        return f"gpio line {line} of {chip}"
    if backend == "relay-board":
        relay = f" channel {channel}" if channel is not None else ""
        return f"relay-board{relay} on {port}"
    return f"{backend} on {port}"


def open_hardware_switch(
    backend: str,
    *,
    port: str,
    chip: str,
    line: int | None,
    active_low: bool,
    channel: int = 1,
    baud: int = 9600,
) -> Switch:
    """The hardware output a config names (the simulated one is wired in from outside)."""
    if backend in ("serial-rts", "serial-dtr"):
        if active_low:
            raise ValueError("a serial line must be active-high: HUPCL drops it when hermsd dies")
        return SerialLineSwitch(port, backend.removeprefix("serial-"))
    if backend == "gpio":
        if line is None:
            raise ValueError("a gpio output needs a line")
        return GpioSwitch(chip, line, active_low)
    if backend == "relay-board":
        return RelayBoardSwitch(port, channel, baud)
    raise ValueError(f"no hardware output named {backend!r}")
