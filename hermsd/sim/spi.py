"""A fake spidev with a fake MAX31865 behind it: the driver's SPI transfers, byte for byte.

`FakeSpiDev` has spidev.SpiDev's names (open, xfer2, max_speed_hz, mode, close) and refuses,
with ValueError, what the chip cannot take (an SPI mode other than 1 or 3, more than 5 MHz, a
transfer before open). `FakeMAX31865` serves the registers: in auto mode with the bias on,
each read of the RTD register is a fresh conversion of `source()` (°C) through
Callendar–Van Dusen and the reference resistor, truncated to the 15-bit code; the
thresholds and the injected faults set the fault status register, which a write of the
fault-clear bit clears.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from enum import StrEnum
from typing import Final

from hermsd.hardware.sensors.max31865 import (
    CODE_FULL_SCALE,
    CONFIG_AUTO,
    CONFIG_FAULT_CLEAR,
    CONFIG_SELF_CLEARING,
    CONFIG_VBIAS,
    FAULT_REFIN_LOW,
    FAULT_RTD_HIGH,
    FAULT_RTD_LOW,
    FAULT_RTDIN_LOW,
    FAULT_VOLTAGE,
    REG_FAULT_STATUS,
    WRITE,
    code_of,
    resistance,
)
from hermsd.sim.fake_faults import chosen

_REGISTERS: Final = 8
_WRITABLE: Final = range(0, 7)
_MAX_HZ: Final = 5_000_000


class RtdFault(StrEnum):
    """How the fake MAX31865 (or its RTD) misbehaves; one at a time."""

    OK = "ok"
    OPEN = "open"
    """The RTD is open: full-scale code, RTD high and FORCE- open."""
    SHORT = "short"
    """The RTD is shorted: code near 0, RTD low."""
    REFIN = "refin"
    """FORCE- open as seen at REFIN-."""
    RTDIN = "rtdin"
    """RTDIN- open."""
    VOLTAGE = "voltage"
    """An input over or under its supply."""
    STUCK = "stuck"
    """No more conversions: the RTD register keeps its value."""
    SPIKE = "spike"
    """The next conversion reads `value` °C, then the fault clears."""
    GONE = "gone"
    """The chip is unplugged: SDO floats high, every byte reads 0xff."""


class FakeMAX31865:
    """The chip's eight registers, from power-up (all zero, the high threshold 0xffff)."""

    def __init__(self, source: Callable[[], float], r0: float = 100.0, rref: float = 430.0):
        self._source = source
        self.r0, self.rref = r0, rref
        self._fault = RtdFault.OK
        self._fault_value = 0.0
        self.registers = [0x00, 0x00, 0x00, 0xFF, 0xFF, 0x00, 0x00, 0x00]

    def set_fault(self, kind: str, value: float | None = None) -> None:
        self._fault, self._fault_value = chosen(RtdFault, kind, value, "MAX31865")

    def transfer(self, data: Sequence[int]) -> list[int]:
        """One chip-select assertion: an address byte, then bytes in or out (auto-increment)."""
        if self._fault is RtdFault.GONE:
            return [0xFF] * len(data)
        address = data[0]
        register = address & 0x7F
        out = [0xFF]  # SDO is high-impedance during the address byte
        for offset, byte in enumerate(data[1:]):
            at = (register + offset) % _REGISTERS
            if address & WRITE:
                self._write(at, byte)
                out.append(0xFF)
            else:
                if at == 1:
                    self._convert()
                out.append(self.registers[at])
        return out

    def _write(self, register: int, byte: int) -> None:
        if register not in _WRITABLE:
            raise ValueError(f"MAX31865 register {register:#04x} is read-only")
        if register == 0:
            if byte & CONFIG_FAULT_CLEAR:
                self.registers[REG_FAULT_STATUS] = 0
                self.registers[2] &= 0xFE
            self.registers[0] = byte & ~CONFIG_SELF_CLEARING
        else:
            self.registers[register] = byte

    def _convert(self) -> None:
        regs = self.registers
        if not (regs[0] & CONFIG_VBIAS and regs[0] & CONFIG_AUTO):
            return  # no bias or no conversion: the register keeps its value
        fault = self._fault
        if fault is RtdFault.STUCK:
            return
        status = 0
        if fault is RtdFault.OPEN:
            code = CODE_FULL_SCALE - 1
            status |= FAULT_REFIN_LOW
        elif fault is RtdFault.SHORT:
            code = 1
        else:
            celsius = self._fault_value if fault is RtdFault.SPIKE else self._source()
            if fault is RtdFault.SPIKE:
                self._fault = RtdFault.OK
            code = code_of(resistance(celsius, self.r0), self.rref)
            status |= {
                RtdFault.REFIN: FAULT_REFIN_LOW,
                RtdFault.RTDIN: FAULT_RTDIN_LOW,
                RtdFault.VOLTAGE: FAULT_VOLTAGE,
            }.get(fault, 0)
        high = (regs[3] << 8 | regs[4]) >> 1
        low = (regs[5] << 8 | regs[6]) >> 1
        if code > high:
            status |= FAULT_RTD_HIGH
        if code < low:
            status |= FAULT_RTD_LOW
        regs[REG_FAULT_STATUS] |= status
        rtd = code << 1 | (1 if regs[REG_FAULT_STATUS] else 0)
        regs[1], regs[2] = rtd >> 8, rtd & 0xFF


class FakeSpiDev:
    """spidev.SpiDev over one fake chip on each (bus, device) given."""

    def __init__(self, chips: dict[tuple[int, int], FakeMAX31865]) -> None:
        self._chips = chips
        self._chip: FakeMAX31865 | None = None
        self.max_speed_hz = 500_000
        self.mode = 0

    def open(self, bus: int, device: int) -> None:
        chip = self._chips.get((bus, device))
        if chip is None:
            raise FileNotFoundError(2, f"No such file or directory: /dev/spidev{bus}.{device}")
        self._chip = chip

    def xfer2(self, data: Sequence[int]) -> list[int]:
        if self._chip is None:
            raise ValueError("SPI transfer before open() or after close()")
        if self.mode not in (1, 3):
            raise ValueError(f"the MAX31865 takes SPI mode 1 or 3, not {self.mode}")
        if not 0 < self.max_speed_hz <= _MAX_HZ:
            raise ValueError(f"the MAX31865 takes at most 5 MHz, not {self.max_speed_hz} Hz")
        if not data or any(not 0 <= b <= 0xFF for b in data):
            raise ValueError(f"an SPI transfer is one or more bytes, got {list(data)}")
        return self._chip.transfer(data)

    def close(self) -> None:
        self._chip = None
