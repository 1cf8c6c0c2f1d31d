"""What every sensor driver here shares: limits kept in software, a calibration offset, and
conversions read beside the loop (a DS18B20 takes up to 750 ms; the loop never waits)."""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from hermsd.hardware.lm92 import (
    LimitName,
    Reading,
    SensorError,
    decode_temperature,
    encode_temperature,
)


class SoftLimits:
    """The loop sets the chip's alarm limits and reads them back; these chips have no
    comparator pin gating the SSR, so the limits live here and the supervisor alone acts on
    the over-temperature (as it does for the LM92 too)."""

    def __init__(self) -> None:
        self._limits: dict[str, float] = {}

    def wake(self) -> None:
        """Nothing to wake: these chips convert whenever they are read."""

    def set_limit(self, name: LimitName, celsius: float) -> None:
        """Kept on the 1/16 °C grid the loop checks a read-back on (the LM92's registers')."""
        self._limits[name] = decode_temperature(encode_temperature(celsius))

    def limit(self, name: LimitName) -> float:
        return self._limits[name]


def calibrated(celsius: float, raw: int, offset_c: float) -> Reading:
    """A reading with the brewer's calibration offset added (after every trap was checked on
    the chip's own value); no flags, since these chips have no comparator."""
    return Reading(celsius + offset_c, raw, crit=False, high=False, low=False)


@dataclass(frozen=True, slots=True)
class Conversion:
    """One finished conversion: its reading or its fault, and when it finished."""

    reading: Reading | None
    error: SensorError | None
    done_at: float


def convert_once(convert: Callable[[], Reading], now: Callable[[], float]) -> Conversion:
    try:
        return Conversion(convert(), None, now())
    except SensorError as error:
        return Conversion(None, error, now())


CONVERSION_PACE_S = 0.75
"""Least time from one conversion's start to the next's: a DS18B20's 12-bit conversion. A
failing device answers at once (gone from the bus: no such file), and without this pace the
reader would spin, holding the interpreter lock the control loop needs."""


class ThreadedConversions:
    """A thread that converts again and again, at most one conversion per
    CONVERSION_PACE_S, and keeps the latest result with its time; `latest` takes it without
    blocking (the loop's read)."""

    def __init__(
        self,
        convert: Callable[[], Reading],
        now: Callable[[], float],
        pause: Callable[[float], object] | None = None,
    ) -> None:
        self._convert = convert
        self._now = now
        self._latest: Conversion | None = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._pause = self._stop.wait if pause is None else pause
        self._first = threading.Event()
        self._thread = threading.Thread(target=self._run, name="sensor-reader", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def close(self) -> None:
        self._stop.set()

    def latest(self) -> Conversion | None:
        with self._lock:
            return self._latest

    def wait_first(self, timeout_s: float) -> None:
        self._first.wait(timeout_s)

    def _run(self) -> None:
        while not self._stop.is_set():
            started = self._now()
            done = convert_once(self._convert, self._now)
            with self._lock:
                self._latest = done
            self._first.set()
            rest = CONVERSION_PACE_S - (done.done_at - started)
            if rest > 0:
                self._pause(rest)


class ClockedConversions:
    """The same on a virtual clock, without a thread: a conversion begun at t is done at
    t + `conversion_s`, when the next begins (the simulator's DS18B20)."""

    def __init__(
        self, convert: Callable[[], Reading], now: Callable[[], float], conversion_s: float
    ) -> None:
        self._convert = convert
        self._now = now
        self._conversion_s = conversion_s
        self._latest: Conversion | None = None
        self._pending: Conversion | None = None

    def start(self) -> None:
        """The first conversion is done at once: the reader ran before the loop began."""
        self._latest = convert_once(self._convert, self._now)
        self._begin()

    def close(self) -> None:
        self._pending = None

    def wait_first(self, timeout_s: float) -> None:
        """The first is there since `start`."""

    def latest(self) -> Conversion | None:
        pending = self._pending
        if pending is not None and self._now() >= pending.done_at:
            self._latest = pending
            self._begin()
        return self._latest

    def _begin(self) -> None:
        begun = convert_once(self._convert, self._now)
        self._pending = Conversion(begun.reading, begun.error, begun.done_at + self._conversion_s)


class Conversions(Protocol):
    """Where a driver's conversions come from: `ThreadedConversions` or `ClockedConversions`."""

    def start(self) -> None: ...

    def close(self) -> None: ...

    def latest(self) -> Conversion | None: ...

    def wait_first(self, timeout_s: float) -> None:
        """Until the first conversion is done (good or not), `timeout_s` at most."""


class Sensor(Protocol):
    """What the loop needs of a temperature sensor (the LM92 driver, or a replayed one)."""

    def read(self) -> Reading: ...

    def identify(self) -> None: ...

    def wake(self) -> None: ...

    def set_limit(self, name: LimitName, celsius: float) -> None: ...

    def limit(self, name: LimitName) -> float: ...
