"""PT100/PT1000 through a MAX31865 on SPI: registers, Callendar–Van Dusen, faults.

The chip converts continuously (auto mode, about 20 ms a conversion), so the loop reads it
directly: two short SPI transfers. Every read also reads the fault status register; a fault
(RTD over or under the thresholds, REFIN or RTDIN open, over/under-voltage) is cleared on the
chip and raised as a `SensorError` naming what to check on the wiring, never a temperature.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Final, Protocol

from hermsd.hardware.lm92 import Reading, SensorError
from hermsd.hardware.sensors.base import SoftLimits, calibrated

REG_CONFIG: Final = 0x00
REG_RTD_MSB: Final = 0x01
REG_HIGH_THRESHOLD_MSB: Final = 0x03
REG_LOW_THRESHOLD_MSB: Final = 0x05
REG_FAULT_STATUS: Final = 0x07
WRITE: Final = 0x80
"""A register's write address is its read address with bit 7 set."""

CONFIG_VBIAS: Final = 0x80
CONFIG_AUTO: Final = 0x40
CONFIG_ONE_SHOT: Final = 0x20
CONFIG_3_WIRE: Final = 0x10
CONFIG_FAULT_CYCLE: Final = 0x0C
CONFIG_FAULT_CLEAR: Final = 0x02
CONFIG_FILTER_50HZ: Final = 0x01
CONFIG_SELF_CLEARING: Final = CONFIG_ONE_SHOT | CONFIG_FAULT_CLEAR | CONFIG_FAULT_CYCLE
"""Bits that read back 0 once their action is done."""

FAULT_RTD_HIGH: Final = 0x80
FAULT_RTD_LOW: Final = 0x40
FAULT_REFIN_HIGH: Final = 0x20
FAULT_REFIN_LOW: Final = 0x10
FAULT_RTDIN_LOW: Final = 0x08
FAULT_VOLTAGE: Final = 0x04
FAULT_BITS: Final = (
    (FAULT_RTD_HIGH, "RTD above the high threshold: the RTD is open or a wire is broken"),
    (FAULT_RTD_LOW, "RTD below the low threshold: the RTD or its leads are shorted"),
    (FAULT_REFIN_HIGH, "REFIN- > 0.85 × VBIAS: the reference resistor is open"),
    (FAULT_REFIN_LOW, "REFIN- < 0.85 × VBIAS: FORCE- is open"),
    (FAULT_RTDIN_LOW, "RTDIN- < 0.85 × VBIAS: FORCE- or RTDIN- is open"),
    (FAULT_VOLTAGE, "over- or under-voltage on an input: a lead touches a supply, or 3.3 V is low"),
)

CODE_FULL_SCALE: Final = 1 << 15
"""The RTD register's 15-bit code is R_RTD / R_REF × 2^15."""

# IEC 60751 (ITS-90 platinum, α = 0.00385)
A: Final = 3.9083e-3
B: Final = -5.775e-7
C: Final = -4.183e-12

WIRES: Final = (2, 3, 4)
FILTERS_HZ: Final = (50, 60)
THRESHOLD_LOW_C: Final = -60.0
THRESHOLD_HIGH_C: Final = 250.0
"""The chip's own open/short thresholds: far outside a tun, inside a PT's range."""
SPI_MODE: Final = 1
SPI_MAX_HZ: Final = 1_000_000
"""The chip takes up to 5 MHz; 1 MHz tolerates a longer ribbon."""


def resistance(celsius: float, r0: float) -> float:
    """Callendar–Van Dusen: the PT's resistance (Ω) at `celsius`, C only below 0 °C."""
    t = celsius
    ratio = 1 + A * t + B * t * t
    if t < 0:
        ratio += C * (t - 100) * t**3
    return r0 * ratio


def celsius_of(ohms: float, r0: float) -> float:
    """The inverse: the quadratic's root at or above 0 °C; below, Newton's method on the full
    equation from that root (three steps reach 1e-9 °C at −200 °C)."""
    ratio = ohms / r0
    t = (-A + math.sqrt(A * A - 4 * B * (1 - ratio))) / (2 * B)
    if ratio >= 1:
        return t
    for _ in range(6):
        f = 1 + A * t + B * t * t + C * (t - 100) * t**3 - ratio
        slope = A + 2 * B * t + C * (4 * t**3 - 300 * t * t)
        t -= f / slope
    return t


def code_of(ohms: float, rref: float) -> int:
    """The 15-bit code the ADC gives for `ohms` (truncated; the chip's ratio is exact)."""
    return max(0, min(CODE_FULL_SCALE - 1, math.floor(ohms / rref * CODE_FULL_SCALE)))


def describe_faults(status: int) -> str:
    """The fault status register in words; 'no fault bit set' for 0."""
    said = [text for bit, text in FAULT_BITS if status & bit]
    return "; ".join(said) if said else "no fault bit set"


class SpiDevice(Protocol):
    """The part of spidev.SpiDev the driver uses; `FakeSpiDev` offers the same."""

    max_speed_hz: int
    mode: int

    def open(self, bus: int, device: int) -> None: ...

    def xfer2(self, data: Sequence[int]) -> list[int]: ...

    def close(self) -> None: ...


class MAX31865(SoftLimits):
    """One MAX31865 and its RTD; also the loop's `Sensor` (its `read` raises every fault)."""

    def __init__(
        self,
        spi: SpiDevice,
        *,
        r0: float = 100.0,
        rref: float = 430.0,
        wires: int = 3,
        filter_hz: int = 50,
        offset_c: float = 0.0,
        where: str = "MAX31865",
    ) -> None:
        super().__init__()
        if wires not in WIRES:
            raise ValueError(f"an RTD has 2, 3 or 4 wires, not {wires}")
        if filter_hz not in FILTERS_HZ:
            raise ValueError(f"the mains filter is 50 or 60 Hz, not {filter_hz}")
        if not 0 < r0 < rref:
            raise ValueError(f"the reference resistor ({rref:g} Ω) must exceed R0 ({r0:g} Ω)")
        self.kind = "max31865"
        self._spi = spi
        self.r0, self.rref, self.wires, self.filter_hz = r0, rref, wires, filter_hz
        self._offset_c = offset_c
        self.where = where
        self.config_byte = (
            CONFIG_VBIAS
            | CONFIG_AUTO
            | (CONFIG_3_WIRE if wires == 3 else 0)
            | (CONFIG_FILTER_50HZ if filter_hz == 50 else 0)
        )
        self._configured = False

    def identify(self) -> None:
        """Configure the chip if needed, then check it reads its configuration back: no chip
        (MISO floating or held) reads 0x00 or 0xff."""
        if not self._configured:
            self.configure()
        seen = self._xfer([REG_CONFIG, 0])[1]
        if seen != self.config_byte:  # the self-clearing bits read 0: 0xff is no chip
            self._configured = False
            raise self._error(
                f"configuration reads {seen:#04x}, {self.config_byte:#04x} was written: no "
                "MAX31865 answers, check CS, SCLK, SDI, SDO, and 3.3 V"
            )

    def configure(self) -> None:
        """Bias on, auto conversion, the wiring and the filter; thresholds; faults cleared."""
        low = code_of(resistance(THRESHOLD_LOW_C, self.r0), self.rref) << 1
        high = code_of(resistance(THRESHOLD_HIGH_C, self.r0), self.rref) << 1
        self._xfer([REG_HIGH_THRESHOLD_MSB | WRITE, high >> 8, high & 0xFF, low >> 8, low & 0xFF])
        self._xfer([REG_CONFIG | WRITE, self.config_byte | CONFIG_FAULT_CLEAR])
        self._configured = True

    def read_code(self) -> tuple[int, int]:
        """(RTD register, fault status): read, and the faults cleared if any is set."""
        _, msb, lsb = self._xfer([REG_RTD_MSB, 0, 0])
        _, status = self._xfer([REG_FAULT_STATUS, 0])
        rtd = msb << 8 | lsb
        if status or rtd & 1:
            self._xfer([REG_CONFIG | WRITE, self.config_byte | CONFIG_FAULT_CLEAR])
        return rtd, status

    def read(self) -> Reading:
        if not self._configured:
            self.configure()
        rtd, status = self.read_code()
        celsius = decode(rtd, status, self.r0, self.rref, self.where)
        return calibrated(celsius, rtd >> 1, self._offset_c)

    def close(self) -> None:
        self._spi.close()

    def _xfer(self, data: list[int]) -> list[int]:
        try:
            return self._spi.xfer2(data)
        except OSError as error:
            raise SensorError(
                f"{self.where}: SPI transfer failed: {error}",
                bus=self.where,
                address=None,
                errno=error.errno,
            ) from error

    def _error(self, detail: str) -> SensorError:
        return SensorError(f"{self.where}: {detail}", bus=self.where, address=None)


class RtdFault(SensorError):
    """The chip flagged a fault; `status` is its fault status register."""

    def __init__(self, message: str, status: int, *, bus: str) -> None:
        super().__init__(message, bus=bus, address=None)
        self.status = status


def decode(rtd: int, status: int, r0: float, rref: float, where: str = "MAX31865") -> float:
    """°C of an RTD register value (D15..D1 code, D0 fault) with the fault status register,
    or the RtdFault they say."""
    if not 0 <= rtd <= 0xFFFF:
        raise ValueError(f"the RTD register is 16 bits (0..0xffff), got {rtd:#x}")
    if status or rtd & 1:
        said = describe_faults(status)
        if not status:
            said = "the fault bit is set but the status register is clear: read it again"
        raise RtdFault(f"{where}: fault {status:#04x}: {said}", status, bus=where)
    code = rtd >> 1
    if code == 0:
        raise RtdFault(
            f"{where}: RTD code 0: the RTD is shorted, or the chip is not converting (check "
            "SDO and the bias)",
            0,
            bus=where,
        )
    return celsius_of(code / CODE_FULL_SCALE * rref, r0)


def open_spi(bus: int, device: int) -> SpiDevice:
    """Open /dev/spidevB.D, turning the usual set-up mistakes into one line."""
    path = f"/dev/spidev{bus}.{device}"
    try:
        import spidev  # type: ignore[import-not-found, unused-ignore]
    except ImportError:
        raise SensorError(
            "the spidev module is missing: install hermsd with the spi extra "
            "(pip install 'hermsd[spi]')",
            bus=path,
            address=None,
        ) from None
    spi: SpiDevice = spidev.SpiDev()
    try:
        spi.open(bus, device)
    except OSError as error:
        if isinstance(error, FileNotFoundError):
            said = f"no SPI device {path}: enable SPI (dtparam=spi=on) or check --bus/--device"
        elif isinstance(error, PermissionError):
            said = f"permission denied on {path}: add the user to group spi"
        else:
            said = f"cannot open {path}: {error.strerror or error}"
        raise SensorError(said, bus=path, address=None, errno=error.errno) from error
    spi.max_speed_hz = SPI_MAX_HZ
    spi.mode = SPI_MODE
    return spi
