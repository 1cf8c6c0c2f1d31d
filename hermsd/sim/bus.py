"""A fake I2C bus with a fake LM92: the driver's code path, byte for byte, without a Raspberry Pi.

`FakeSMBus` has smbus2.SMBus's method names and signatures and fails the way i2c-dev does
(an absent address NACKs with errno 121). `FakeLM92` serves the chip's registers from a
temperature source (the HLT model) and can be told to misbehave as real sensors do.

The fake refuses, with ValueError, the transfers the datasheet leaves undefined (a 2-byte read
of the 8-bit configuration register, a write to a read-only register, register 6): a driver
mistake then fails loudly instead of meeting an invented answer.
"""

from __future__ import annotations

import errno
import math
import os
from collections.abc import Callable, Sequence
from enum import StrEnum
from types import TracebackType
from typing import Final, Protocol

from hermsd.hardware.lm92 import (
    CONFIG_SHUTDOWN,
    FLAG_T_CRIT,
    FLAG_T_HIGH,
    FLAG_T_LOW,
    MANUFACTURER_ID,
    MAX_CELSIUS,
    MIN_CELSIUS,
    POWER_UP_LIMITS,
    REG_CONFIG,
    REG_MANUFACTURER_ID,
    REG_T_CRIT,
    REG_T_HIGH,
    REG_T_HYST,
    REG_T_LOW,
    REG_TEMPERATURE,
    REGISTER_ALIAS_PERIOD,
    STEP_CELSIUS,
    pack_steps,
    unpack_steps,
)

_BLOCK_MAX: Final = 32
"""smbus2 and the kernel's I2C block transfers carry at most 32 bytes."""

_CONFIG_BITS: Final = 0x1F
"""Bits 7..5 of the configuration register read 0 (Linux's lm92 detection relies on it)."""


def _steps(celsius: float) -> int:
    return round(celsius / STEP_CELSIUS)


_STEPS_MIN: Final = _steps(MIN_CELSIUS)
_STEPS_MAX: Final = _steps(MAX_CELSIUS)

_LIMIT_REGISTERS: Final = (REG_T_HYST, REG_T_CRIT, REG_T_LOW, REG_T_HIGH)

OTHER_CHIP_ID: Final = 0x0190
"""What `wrong_id` shows by default in the ID register: a word an LM92 never gives."""


class Fault(StrEnum):
    """How the fake sensor misbehaves; one at a time, switched by tests and scenarios."""

    OK = "ok"
    NACK = "nack"
    """Every transfer is NACKed (errno 121): a bus glitch; registers are kept."""
    TIMEOUT = "timeout"
    """Every transfer times out (errno 110): a line held low."""
    STUCK = "stuck"
    """No more conversions: the temperature register keeps the word it had when this began."""
    SPIKE = "spike"
    """The next conversion yields `value` °C instead of the source, then the fault clears."""
    WRONG_ID = "wrong_id"
    """The ID register reads `value` (default OTHER_CHIP_ID): another chip at the address."""
    GONE = "gone"
    """Unplugged: errno 121 on every transfer; when it ends the chip powers up afresh."""
    SLOW = "slow"
    """Every transfer first advances the injected clock by `value` seconds, then succeeds."""


def _bus_error(code: int) -> OSError:
    return OSError(code, os.strerror(code))


class FakeDevice(Protocol):
    """A chip on the fake bus: register reads and writes, raising OSError as the kernel would."""

    def read(self, register: int, length: int) -> list[int]: ...

    def write(self, register: int, data: Sequence[int]) -> None: ...


class FakeSMBus:
    """smbus2.SMBus's register transfers over devices attached in memory.

    Arguments out of range raise ValueError (smbus2 would truncate or let the kernel refuse):
    the fake is stricter so that driver mistakes show.
    """

    def __init__(self) -> None:
        self._devices: dict[int, FakeDevice] = {}
        self._closed = False

    def attach(self, address: int, device: FakeDevice) -> None:
        """Put `device` on the bus at the 7-bit `address`."""
        if not 0 <= address <= 0x7F:
            raise ValueError(f"I2C addresses are 7 bits, got {address:#x}")
        if address in self._devices:
            raise ValueError(f"address {address:#04x} is taken")
        self._devices[address] = device

    def read_i2c_block_data(
        self, i2c_addr: int, register: int, length: int, force: bool | None = None
    ) -> list[int]:
        if not 1 <= length <= _BLOCK_MAX:
            raise ValueError(f"block length must be 1..{_BLOCK_MAX}, got {length}")
        return self._device(i2c_addr, register).read(register, length)

    def write_i2c_block_data(
        self, i2c_addr: int, register: int, data: Sequence[int], force: bool | None = None
    ) -> None:
        if not 1 <= len(data) <= _BLOCK_MAX:
            raise ValueError(f"block length must be 1..{_BLOCK_MAX}, got {len(data)}")
        for value in data:
            _check_byte(value)
        self._device(i2c_addr, register).write(register, data)

    def read_byte_data(self, i2c_addr: int, register: int, force: bool | None = None) -> int:
        return self._device(i2c_addr, register).read(register, 1)[0]

    def write_byte_data(
        self, i2c_addr: int, register: int, value: int, force: bool | None = None
    ) -> None:
        _check_byte(value)
        self._device(i2c_addr, register).write(register, [value])

    def close(self) -> None:
        self._closed = True

    def __enter__(self) -> FakeSMBus:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc_val: BaseException | None,
        exc_tb: TracebackType | None,
    ) -> None:
        self.close()

    def _device(self, i2c_addr: int, register: int) -> FakeDevice:
        if self._closed:
            raise ValueError("I2C bus used after close()")
        _check_byte(register)
        device = self._devices.get(i2c_addr)
        if device is None:
            if not 0 <= i2c_addr <= 0x7F:
                raise ValueError(f"I2C addresses are 7 bits, got {i2c_addr:#x}")
            raise _bus_error(errno.EREMOTEIO)
        return device


def _check_byte(value: int) -> None:
    if not 0 <= value <= 0xFF:
        raise ValueError(f"an I2C byte is 0..0xff, got {value:#x}")


class FakeLM92:
    """An LM92 converting `temperature_source()` (°C) whenever its temperature register is read.

    The ADC model: the source is truncated toward −∞ onto the 0.0625 °C grid (a sigma-delta
    converter's two's complement result loses its low bits that way) and clamped to the chip's
    −55..150 °C. The fake is otherwise ideal: no ±0.33 °C error, no noise (put those in the
    source). Each conversion updates the T_CRIT/T_HIGH/T_LOW flags with the datasheet's
    hysteresis: T_CRIT and T_HIGH set at ≥ limit and clear below limit − T_HYST; T_LOW sets
    below T_LOW and clears above T_LOW + T_HYST. In shutdown, or while `stuck`, there are no
    conversions and the register keeps its last word. `advance` moves the injected clock for
    the `slow` fault.
    """

    def __init__(
        self,
        temperature_source: Callable[[], float],
        advance: Callable[[float], None] | None = None,
    ) -> None:
        self._source = temperature_source
        self._advance = advance
        self._fault = Fault.OK
        self._fault_value = 0.0
        self._power_up()

    @property
    def fault(self) -> Fault:
        """The fault in force (a spent spike shows as OK)."""
        return self._fault

    def power_dip(self) -> None:
        """A dip in the supply resets the chip between two reads: every register is back at
        its power-up value, and no read fails to say so."""
        self._power_up()

    def set_fault(self, kind: str, value: float | None = None) -> None:
        """Start misbehaving as `kind` (a Fault or its name), or stop with "ok"."""
        try:
            fault = Fault(kind)
        except ValueError:
            names = ", ".join(f.value for f in Fault)
            raise ValueError(f"unknown fault {kind!r}: expected one of {names}") from None
        if fault is Fault.SLOW and self._advance is None:
            raise ValueError("the 'slow' fault needs FakeLM92(..., advance=clock.advance)")
        self._fault_value = fault_value(fault, value)
        previous = self._fault
        self._fault = fault
        if previous is Fault.GONE and fault is not Fault.GONE:
            self._power_up()
        if fault is Fault.STUCK and previous is not Fault.STUCK and not self._shutdown():
            self._convert()

    def read(self, register: int, length: int) -> list[int]:
        if self._fault is not Fault.OK:
            self._start_faulty_transfer()
        register %= REGISTER_ALIAS_PERIOD
        if register == REG_TEMPERATURE:
            if not (self._config & CONFIG_SHUTDOWN or self._fault is Fault.STUCK):
                self._convert()
            word = self._word
        elif register == REG_CONFIG:
            if length != 1:
                raise ValueError(f"the LM92 configuration register is 1 byte, not {length}")
            return [self._config]
        elif register == REG_MANUFACTURER_ID:
            word = int(self._fault_value) if self._fault is Fault.WRONG_ID else MANUFACTURER_ID
        else:
            word = pack_steps(self._limit_steps(register))
        if length == 2:
            return [word >> 8, word & 0xFF]
        if length == 1:
            return [word >> 8]
        raise ValueError(
            f"LM92 register {register:#04x} is 2 bytes; a {length}-byte read is undefined"
        )

    def write(self, register: int, data: Sequence[int]) -> None:
        if self._fault is not Fault.OK:
            self._start_faulty_transfer()
        register %= REGISTER_ALIAS_PERIOD
        if register == REG_CONFIG:
            if len(data) != 1:
                raise ValueError(f"the LM92 configuration register is 1 byte, not {len(data)}")
            self._write_config(data[0])
            return
        if register not in _LIMIT_REGISTERS:
            raise ValueError(f"LM92 register {register:#04x} is not writable")
        if len(data) != 2:
            raise ValueError(f"LM92 limit register {register:#04x} takes 2 bytes, not {len(data)}")
        steps = unpack_steps(data[0] << 8 | data[1])
        if register == REG_T_HYST:
            self._hyst = steps
        elif register == REG_T_CRIT:
            self._crit = steps
        elif register == REG_T_LOW:
            self._low = steps
        else:
            self._high = steps

    def _power_up(self) -> None:
        self._config = 0
        self._hyst = _steps(POWER_UP_LIMITS["hyst"])
        self._crit = _steps(POWER_UP_LIMITS["crit"])
        self._low = _steps(POWER_UP_LIMITS["low"])
        self._high = _steps(POWER_UP_LIMITS["high"])
        self._flags = 0
        self._word = 0  # never served: the chip is awake, so the first read converts

    def _shutdown(self) -> bool:
        return bool(self._config & CONFIG_SHUTDOWN)

    def _write_config(self, value: int) -> None:
        entering_shutdown = value & CONFIG_SHUTDOWN and not self._shutdown()
        if entering_shutdown and self._fault is not Fault.STUCK:
            self._convert()  # the register keeps the conversion made as the chip stops
        self._config = value & _CONFIG_BITS

    def _limit_steps(self, register: int) -> int:
        if register == REG_T_HYST:
            return self._hyst
        if register == REG_T_CRIT:
            return self._crit
        if register == REG_T_LOW:
            return self._low
        if register == REG_T_HIGH:
            return self._high
        raise ValueError(f"LM92 register {register:#04x} is not defined by the datasheet")

    def _start_faulty_transfer(self) -> None:
        fault = self._fault
        if fault is Fault.NACK or fault is Fault.GONE:
            raise _bus_error(errno.EREMOTEIO)
        if fault is Fault.TIMEOUT:
            raise _bus_error(errno.ETIMEDOUT)
        if fault is Fault.SLOW and self._advance is not None:
            self._advance(self._fault_value)

    def _convert(self) -> None:
        if self._fault is Fault.SPIKE:
            self._fault = Fault.OK
            scaled = self._fault_value / STEP_CELSIUS
        else:
            scaled = self._source() / STEP_CELSIUS
        if scaled >= _STEPS_MAX:
            steps = _STEPS_MAX
        elif scaled <= _STEPS_MIN:
            steps = _STEPS_MIN
        else:
            steps = math.floor(scaled)  # NaN from the source raises here, loudly
        flags = self._flags
        if steps >= self._crit:
            flags |= FLAG_T_CRIT
        elif steps < self._crit - self._hyst:
            flags &= ~FLAG_T_CRIT
        if steps >= self._high:
            flags |= FLAG_T_HIGH
        elif steps < self._high - self._hyst:
            flags &= ~FLAG_T_HIGH
        if steps < self._low:
            flags |= FLAG_T_LOW
        elif steps > self._low + self._hyst:
            flags &= ~FLAG_T_LOW
        self._flags = flags
        self._word = pack_steps(steps) | flags


def fault_value(fault: Fault, value: float | None) -> float:
    """Check the value a fault takes: spike °C, slow seconds, wrong_id word; none for the rest
    (a scenario checks its events by it before the run, the fake chip when the fault starts)."""
    if fault is Fault.SPIKE:
        if value is None or not math.isfinite(value):
            raise ValueError(f"the 'spike' fault needs a finite temperature in °C, got {value}")
        return value
    if fault is Fault.SLOW:
        if value is None or not (math.isfinite(value) and value > 0):
            raise ValueError(f"the 'slow' fault needs a positive number of seconds, got {value}")
        return value
    if fault is Fault.WRONG_ID:
        if value is None:
            return OTHER_CHIP_ID
        if not (float(value).is_integer() and 0 <= value <= 0xFFFF) or value == MANUFACTURER_ID:
            raise ValueError(
                f"the 'wrong_id' fault needs a 16-bit word other than 0x8001, got {value}"
            )
        return value
    if value is not None:
        raise ValueError(f"the {fault.value!r} fault takes no value, got {value}")
    return 0.0


ADS1115_POWER_UP_CONFIG: Final = 0x8583
"""The ADS1115's config register at power-up (datasheet 9.6.3): single-shot, ±2.048 V, 128 SPS,
the comparator disabled."""
_ADS1115_RATES: Final = (8, 16, 32, 64, 128, 250, 475, 860)
_ADS1115_RANGES: Final = (6.144, 4.096, 2.048, 1.024, 0.512, 0.256, 0.256, 0.256)


class FakeADS1115:
    """An ADS1115 serving `volts(t)` (the input's differential volts at `t` on `now`'s clock):
    in continuous mode the conversion register holds the latest conversion completed at the
    configured data rate, at the configured range, clipped to full scale; in single-shot mode
    it keeps the last one (0 after power-up). `failing` NACKs every transfer."""

    def __init__(self, volts: Callable[[float], float], now: Callable[[], float]) -> None:
        self._volts, self._now = volts, now
        self.config = ADS1115_POWER_UP_CONFIG
        self._held = 0
        self.failing = False
        self.transfers = 0

    def read(self, register: int, length: int) -> list[int]:
        self._transfer()
        if length != 2 or register > 3:
            raise ValueError(f"the ADS1115 has 16-bit registers 0..3, got {length} of {register}")
        if register == 1:
            word = self.config & 0x7FFF if self._continuous else self.config | 0x8000
        elif register == 0:
            word = self._conversion() & 0xFFFF
        else:
            word = 0x8000 if register == 2 else 0x7FFF  # the Lo/Hi thresholds' power-up values
        return [word >> 8, word & 0xFF]

    def write(self, register: int, data: Sequence[int]) -> None:
        self._transfer()
        if register != 1 or len(data) != 2:
            raise ValueError(f"only the 16-bit config register is written here, got {register}")
        self.config = data[0] << 8 | data[1]

    @property
    def _continuous(self) -> bool:
        return not self.config & 0x0100

    def _conversion(self) -> int:
        if not self._continuous:
            return self._held
        rate = _ADS1115_RATES[self.config >> 5 & 0b111]
        full_scale = _ADS1115_RANGES[self.config >> 9 & 0b111]
        done_at = math.floor(self._now() * rate) / rate  # the last conversion completed
        counts = round(self._volts(done_at) / full_scale * 32768)
        self._held = max(-32768, min(32767, counts))
        return self._held

    def _transfer(self) -> None:
        self.transfers += 1
        if self.failing:
            raise _bus_error(errno.EREMOTEIO)
