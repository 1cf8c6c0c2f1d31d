"""Whether the SSR's element draws current (`current.kind`, docs/current.md): a current
transformer into an ADS1115 ADC on I2C, or a mains-present optocoupler on a GPIO input line.

The ADS1115 (TI SBAS444) runs in continuous-conversion mode at 860 samples/s; a read polls its
conversion register for two whole mains cycles and takes the RMS of the samples with their
mean taken off (a single-ended CT is biased to mid-supply, and a sine's mean over whole cycles
is zero). RMS rather than peak-to-peak/2/√2: it uses every sample, so one noisy sample moves
it by 1/√n of its error, and it does not depend on catching a peak, which 17 samples a cycle
miss by up to 1.7 %.

Time cost: a read holds its caller for the sampling window (40 ms at 50 Hz, 33 ms at 60 Hz)
plus one register read to check the config; each poll is one I2C transfer (about 0.2 ms at
400 kHz, 0.5 ms at 100 kHz), paced to the data rate, so a read is 28 to 35 transfers and ends
at most one poll after its window. `bench/current_read.py` measures it on the fake bus. The
daemon reads only far from any SSR edge (`runtime/current_side.py`), so it delays none.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Final, Protocol

from hermsd.config.schema import ADS1115_INPUTS, ADS1115_RANGES, CurrentConfig
from hermsd.hardware.gpio_line import GpioLine
from hermsd.hardware.lm92 import I2CBus, SensorError

REG_CONVERSION: Final = 0x00
REG_CONFIG: Final = 0x01
MUX_SHIFT: Final = 12  # config bits 14:12
PGA_SHIFT: Final = 9  # bits 11:9
MODE_SINGLE_SHOT: Final = 1 << 8  # bit 8: 0 continuous conversion, 1 single-shot
DR_860_SPS: Final = 0b111 << 5  # bits 7:5
COMP_QUE_DISABLE: Final = 0b11  # bits 1:0: the comparator and its ALERT/RDY pin off
SAMPLES_PER_S: Final = 860
FULL_SCALE_COUNTS: Final = 32768
"""An LSB is the range's ±volts over 2^15 (datasheet table 3: 31.25 µV at ±1.024 V)."""
CYCLES: Final = 2
"""Mains cycles a read samples: whole cycles, so a sine's mean and RMS come out true."""
EDGE_SLACK_S: Final = 0.01
"""Beyond the zero-cross SSR's half-cycle (it conducts to the next zero crossing after it is
told off), how far from an edge a sample stays: the loop's own lateness on a busy Pi."""


def read_and_margin(mains_hz: int) -> tuple[float, float]:
    """A read's length (CYCLES mains cycles, s) and the room it keeps from its part's edges (a
    half-cycle and EDGE_SLACK_S)."""
    half_cycle = 0.5 / mains_hz
    return CYCLES / mains_hz, half_cycle + EDGE_SLACK_S


def two_reads_part(mains_hz: int) -> float:
    """The shortest part of a window (on, or off) that takes two reads with their margins,
    and a half-cycle more for the planner's grid: its least pulse and gap where a current input
    is fitted, so that the first pulse after an element goes open shows it, and the first gap
    after a short (docs/current.md)."""
    read, margin = read_and_margin(mains_hz)
    return 3 * (read + margin) + 0.5 / mains_hz


@dataclass(frozen=True, slots=True)
class CurrentRead:
    """What the input says: the element draws or not, and the amps a CT measured (None for
    the optocoupler, which measures none)."""

    drawing: bool
    amps: float | None


class CurrentSense(Protocol):
    """One read of the element's current; SensorError or OSError when it cannot be read."""

    def read(self) -> CurrentRead: ...

    def close(self) -> None: ...


def ads1115_config(mux: int, pga: int) -> int:
    """The config register's word: continuous conversion at 860 SPS of input `mux` at range
    `pga` (their indexes in ADS1115_INPUTS and ADS1115_RANGES), the comparator disabled."""
    return mux << MUX_SHIFT | pga << PGA_SHIFT | DR_860_SPS | COMP_QUE_DISABLE


class ADS1115Current:
    """A CT's output through an ADS1115; `now` and `pause` pace the polls (the clock's)."""

    def __init__(
        self,
        bus: I2CBus,
        address: int,
        current: CurrentConfig,
        mains_hz: int,
        now: Callable[[], float],
        pause: Callable[[float], object],
        bus_name: str = "",
        close_bus: Callable[[], object] | None = None,
    ) -> None:
        self._bus, self._address, self._bus_name = bus, address, bus_name
        self._close_bus = close_bus
        self._config = ads1115_config(
            ADS1115_INPUTS.index(current.input), ADS1115_RANGES.index(current.range)
        )
        self._volts_per_count = current.range / FULL_SCALE_COUNTS
        self._amps_per_volt, self._threshold = current.amps_per_volt, current.threshold
        self._window_s = CYCLES / mains_hz
        self._now, self._pause = now, pause
        self._write_config()

    def read(self) -> CurrentRead:
        """The RMS amps over two mains cycles (the config written again first if the chip
        lost it: a power dip leaves it single-shot, whose register would read a stale 0)."""
        config = self._register(REG_CONFIG)
        if config & 0x7FFF != self._config:  # bit 15 (OS) reads the conversion state
            self._write_config()
        counts = []
        start = self._now()
        due = start
        while self._now() - start < self._window_s:
            counts.append(_signed(self._register(REG_CONVERSION)))
            due += 1.0 / SAMPLES_PER_S
            rest = due - self._now()
            if rest > 0:
                self._pause(rest)
        if len(counts) < 2:
            raise SensorError(
                "the ADS1115's sampling window held under two samples (the bus is too slow)",
                bus=self._bus_name,
                address=self._address,
            )
        mean = sum(counts) / len(counts)
        rms_counts = math.sqrt(sum((c - mean) ** 2 for c in counts) / len(counts))
        amps = rms_counts * self._volts_per_count * self._amps_per_volt
        return CurrentRead(amps > self._threshold, amps)

    def close(self) -> None:
        if self._close_bus is not None:
            self._close_bus()

    def _write_config(self) -> None:
        self._bus.write_i2c_block_data(self._address, REG_CONFIG, list(self._config.to_bytes(2)))

    def _register(self, register: int) -> int:
        high, low = self._bus.read_i2c_block_data(self._address, register, 2)
        return high << 8 | low  # the ADS1115 sends the high byte first


def _signed(word: int) -> int:
    return word - 0x10000 if word & 0x8000 else word


class GpioCurrentSense:
    """A mains-present optocoupler across the element, on a GPIO input line: voltage across
    the element, which an open element has too (it tells a shorted SSR, and a dead SSR,
    contactor or fuse, not an open element). Biased to its inactive level: a module
    unplugged reads no current."""

    def __init__(self, chip: str, line: int, active_low: bool = False) -> None:
        self._line = GpioLine(
            chip, line, output=False, active_low=active_low, what="the gpio current input"
        )

    def read(self) -> CurrentRead:
        return CurrentRead(self._line.active(), None)

    def close(self) -> None:
        self._line.release()


def open_current_sense(
    current: CurrentConfig,
    mains_hz: int,
    now: Callable[[], float],
    pause: Callable[[float], object],
    bus: I2CBus | None = None,
) -> CurrentSense | None:
    """The input the config fits on hardware (None: none); `bus` the ADS1115's when opened
    elsewhere. The simulated one is the simulator's (`sim/world.py`)."""
    if current.kind == "none":
        return None
    if current.kind == "gpio" and current.line is not None:
        return GpioCurrentSense(current.chip, current.line, current.active_low)
    if current.kind == "ads1115":
        name = f"/dev/i2c-{current.bus}"
        if bus is not None:
            return ADS1115Current(bus, current.address, current, mains_hz, now, pause, name)
        from smbus2 import SMBus

        opened = SMBus(current.bus)
        try:
            return ADS1115Current(
                opened, current.address, current, mains_hz, now, pause, name, opened.close
            )
        except OSError:
            opened.close()
            raise
    raise ValueError(f"current.kind {current.kind!r} cannot be opened on hardware")
