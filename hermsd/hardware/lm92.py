"""LM92 temperature sensor on I2C: the word format, the registers, and a driver that never guesses.

Every bus failure becomes one typed `SensorError` that names the bus, the address and what the
kernel said, so the safety supervisor can count failures and the user reads one clear line.
Values are decoded from the chip's own words only; nothing here makes up a temperature.
"""

from __future__ import annotations

import errno
import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final, Literal, Protocol

from smbus2 import SMBus

ADDRESSES: Final = range(0x48, 0x4C)
"""The four addresses the chip's A0/A1 pins can select."""

REG_TEMPERATURE: Final = 0x00
REG_CONFIG: Final = 0x01
REG_T_HYST: Final = 0x02
REG_T_CRIT: Final = 0x03
REG_T_LOW: Final = 0x04
REG_T_HIGH: Final = 0x05
REG_MANUFACTURER_ID: Final = 0x07
REGISTER_ALIAS_PERIOD: Final = 8
"""The chip decodes only the low three pointer bits: register n answers at n + 8, n + 16…"""

MANUFACTURER_ID: Final = 0x8001

CONFIG_SHUTDOWN: Final = 0x01
CONFIG_INT_MODE: Final = 0x02
CONFIG_T_CRIT_A_POLARITY: Final = 0x04
CONFIG_INT_POLARITY: Final = 0x08
CONFIG_FAULT_QUEUE: Final = 0x10

FLAG_T_CRIT: Final = 0x04
FLAG_T_HIGH: Final = 0x02
FLAG_T_LOW: Final = 0x01
STATUS_MASK: Final = 0x07
"""D2..D0 of the temperature word are status flags, not temperature."""

STEP_CELSIUS: Final = 0.0625
MIN_CELSIUS: Final = -55.0
MAX_CELSIUS: Final = 150.0

POWER_UP_LIMITS: Final = {"hyst": 2.0, "low": 10.0, "high": 64.0, "crit": 80.0}
"""What the limit registers hold after power-up (datasheet), in °C."""

LimitName = Literal["crit", "high", "low", "hyst"]
LIMIT_REGISTERS: Final[dict[str, int]] = {
    "hyst": REG_T_HYST,
    "crit": REG_T_CRIT,
    "low": REG_T_LOW,
    "high": REG_T_HIGH,
}

_STEPS_MIN: Final = -4096
_STEPS_MAX: Final = 4095


def unpack_steps(word: int) -> int:
    """The 13-bit two's complement in D15..D3 of a 16-bit word, in 0.0625 °C steps."""
    if not 0 <= word <= 0xFFFF:
        raise ValueError(f"an LM92 word is 16 bits (0..0xffff), got {word:#x}")
    steps = word >> 3
    return steps - 8192 if steps & 0x1000 else steps


def pack_steps(steps: int) -> int:
    """A count of 0.0625 °C steps as D15..D3 of a word, D2..D0 zero."""
    if not _STEPS_MIN <= steps <= _STEPS_MAX:
        raise ValueError(f"{steps} steps do not fit the LM92's 13-bit two's complement")
    return (steps & 0x1FFF) << 3


def decode_temperature(word: int) -> float:
    """°C from a temperature or limit word (MSB first); the status bits D2..D0 are ignored."""
    return unpack_steps(word) * STEP_CELSIUS


def encode_temperature(celsius: float) -> int:
    """The word for a limit register: `celsius` rounded to the nearest 0.0625 °C step.

    Ties go to the even step (Python's `round`). Values the chip cannot measure are refused
    rather than wrapped, so a limit can never silently become a different temperature.
    """
    if not MIN_CELSIUS <= celsius <= MAX_CELSIUS:  # also refuses NaN
        raise ValueError(
            f"{celsius} °C is outside the LM92's range {MIN_CELSIUS:g}..{MAX_CELSIUS:g} °C"
        )
    return pack_steps(round(celsius / STEP_CELSIUS))


@dataclass(frozen=True, slots=True)
class Reading:
    """One temperature conversion: the value, the word it came from, and the chip's flags."""

    celsius: float
    raw: int
    crit: bool
    high: bool
    low: bool


_ERRNO_MEANINGS: Final = {
    errno.EREMOTEIO: "no answer (NACK, errno 121): check wiring, power and address",
    errno.ETIMEDOUT: "bus timeout (errno 110): a line is held low, check wiring and pull-ups",
    errno.EIO: "I/O error (EIO, errno 5)",
    errno.ENXIO: "no such device or address (ENXIO, errno 6)",
    errno.EBUSY: "address claimed by a kernel driver (EBUSY, errno 16): unload the lm92 module",
}


def describe_errno(code: int | None) -> str:
    """What a bus errno means to someone holding the wires."""
    if code is None:
        return "failed without an error number"
    return _ERRNO_MEANINGS.get(code, f"{os.strerror(code)} (errno {code})")


class SensorError(Exception):
    """Any failure to get a true value from the sensor; `errno` is None when the bus worked.

    `address` is None only when the bus itself could not be opened.
    """

    def __init__(
        self, message: str, *, bus: str, address: int | None, errno: int | None = None
    ) -> None:
        super().__init__(message)
        self.bus = bus
        self.address = address
        self.errno = errno


class WrongChipError(SensorError):
    """Something answers at the address, but it is not an LM92."""


class I2CBus(Protocol):
    """The part of smbus2.SMBus the driver uses; `FakeSMBus` offers the same."""

    def read_i2c_block_data(self, i2c_addr: int, register: int, length: int) -> list[int]: ...

    def write_i2c_block_data(self, i2c_addr: int, register: int, data: Sequence[int]) -> None: ...

    def read_byte_data(self, i2c_addr: int, register: int) -> int: ...

    def write_byte_data(self, i2c_addr: int, register: int, value: int) -> None: ...


class LM92:
    """One LM92 on a bus.

    Words are read with block reads because the chip sends its MSB first and SMBus word reads
    assume the opposite order.
    """

    def __init__(self, bus: I2CBus, address: int = 0x48, bus_name: str = "/dev/i2c-1") -> None:
        if address not in ADDRESSES:
            raise ValueError(f"an LM92 answers at 0x48..0x4b, not at {address:#04x}")
        self._bus = bus
        self._address = address
        self._bus_name = bus_name

    def read(self) -> Reading:
        """The latest conversion.

        Each read restarts the chip's conversion: read about once a second, not faster.
        """
        word = self._read_word(REG_TEMPERATURE, "reading the temperature")
        celsius = decode_temperature(word)
        if not MIN_CELSIUS <= celsius <= MAX_CELSIUS:
            raise self._error(
                f"temperature word {word:#06x} ({celsius:g} °C) is outside the chip's range "
                f"{MIN_CELSIUS:g}..{MAX_CELSIUS:g} °C: the bus corrupted it"
            )
        return Reading(
            celsius,
            word,
            bool(word & FLAG_T_CRIT),
            bool(word & FLAG_T_HIGH),
            bool(word & FLAG_T_LOW),
        )

    def identify(self) -> None:
        """Refuse to go on unless the manufacturer ID says LM92 (another chip may sit at 0x48)."""
        seen = self._read_word(REG_MANUFACTURER_ID, "reading the manufacturer ID")
        if seen != MANUFACTURER_ID:
            raise WrongChipError(
                f"{self._where()}: manufacturer ID reads {seen:#06x}, an LM92 gives "
                f"{MANUFACTURER_ID:#06x}: another chip sits at this address",
                bus=self._bus_name,
                address=self._address,
            )

    def limit(self, name: LimitName) -> float:
        """A limit register (°C): T_CRIT, T_HIGH, T_LOW or the hysteresis T_HYST."""
        register = _limit_register(name)
        return decode_temperature(self._read_word(register, f"reading limit {name}"))

    def set_limit(self, name: LimitName, celsius: float) -> None:
        """Program a limit and read it back; the chip's comparators must act on what was meant."""
        register = _limit_register(name)
        if name == "hyst" and celsius < 0:
            raise ValueError(f"hysteresis must be >= 0 °C, got {celsius} °C")
        word = encode_temperature(celsius)
        action = f"writing limit {name}"
        try:
            self._bus.write_i2c_block_data(self._address, register, [word >> 8, word & 0xFF])
        except OSError as exc:
            raise self._bus_error(action, exc) from exc
        readback = self._read_word(register, f"reading back limit {name}")
        if readback & ~STATUS_MASK != word:
            raise self._error(
                f"limit {name} reads back {decode_temperature(readback):g} °C "
                f"after writing {decode_temperature(word):g} °C"
            )

    def config(self) -> int:
        """The configuration byte (see the CONFIG_* bits)."""
        return self._read_config("reading the configuration")

    def wake(self) -> None:
        """Leave shutdown, keeping the other configuration bits.

        Until the next conversion completes the temperature register still holds the value
        converted before shutdown.
        """
        config = self._read_config("reading the configuration")
        if not config & CONFIG_SHUTDOWN:
            return
        try:
            self._bus.write_byte_data(self._address, REG_CONFIG, config & ~CONFIG_SHUTDOWN)
        except OSError as exc:
            raise self._bus_error("writing the configuration", exc) from exc
        after = self._read_config("reading back the configuration")
        if after & CONFIG_SHUTDOWN:
            raise self._error(f"still in shutdown after wake: configuration reads {after:#04x}")

    def _read_word(self, register: int, action: str) -> int:
        try:
            msb, lsb = self._bus.read_i2c_block_data(self._address, register, 2)
        except OSError as exc:
            raise self._bus_error(action, exc) from exc
        return msb << 8 | lsb

    def _read_config(self, action: str) -> int:
        try:
            return self._bus.read_byte_data(self._address, REG_CONFIG)
        except OSError as exc:
            raise self._bus_error(action, exc) from exc

    def _where(self) -> str:
        return f"LM92 at {self._address:#04x} on {self._bus_name}"

    def _error(self, detail: str) -> SensorError:
        return SensorError(f"{self._where()}: {detail}", bus=self._bus_name, address=self._address)

    def _bus_error(self, action: str, exc: OSError) -> SensorError:
        return SensorError(
            f"{self._where()}: {action} failed: {describe_errno(exc.errno)}",
            bus=self._bus_name,
            address=self._address,
            errno=exc.errno,
        )


def _limit_register(name: str) -> int:
    try:
        return LIMIT_REGISTERS[name]
    except KeyError:
        raise ValueError(
            f"unknown LM92 limit {name!r}: expected one of {', '.join(LIMIT_REGISTERS)}"
        ) from None


def open_bus(bus_number: int) -> SMBus:
    """Open /dev/i2c-N, turning the usual set-up mistakes into one line that says what to do."""
    path = f"/dev/i2c-{bus_number}"
    try:
        return SMBus(bus_number)
    except FileNotFoundError as exc:
        message = f"no I2C bus {path}: enable I2C (raspi-config) or check --bus"
        raise SensorError(message, bus=path, address=None, errno=exc.errno) from exc
    except PermissionError as exc:
        message = f"permission denied on {path}: add the user to group i2c"
        raise SensorError(message, bus=path, address=None, errno=exc.errno) from exc
    except OSError as exc:
        message = f"cannot open {path}: {describe_errno(exc.errno)}"
        raise SensorError(message, bus=path, address=None, errno=exc.errno) from exc
