"""DS18B20 on 1-Wire, read through the Linux w1 driver's sysfs files (no extra dependency).

`w1_slave` gives the nine scratchpad bytes, the kernel's CRC verdict and `t=` millidegrees;
the CRC is checked here again, and the value is decoded from the bytes themselves. The chip's
traps each become a `SensorError` naming the trap and what to check on the wiring, never a
temperature: a CRC mismatch, the 85.000 °C power-on value, an all-zero scratchpad (CRC passes,
reads 0 °C: a shorted data line), an all-ones one (nobody answered), the 127.94 and −127
markers, a resolution other than 12 bits, a device gone from the bus, a family other than 28.

85.000 °C is also a temperature an HLT heating past 85 °C reads, and its scratchpad is the
power-on one but for the reserved byte 6, which clones do not keep as the datasheet does (and
the `temperature` file has no bytes at all). So the reading before it decides: 85.000 °C is
taken as a temperature when the last good reading was within POWER_ON_NEAR_C of it (the water
moves hundredths of a degree between conversions), and as the power-on value when it jumps
from further away, or comes first, or after a failed read (a chip back on the bus was powered
up afresh). A chip near 85 °C that resets at every conversion then reads 85.000 steadily: the
supervisor's stuck-sensor check is what says so.

A 12-bit conversion takes up to 750 ms, and reading `w1_slave` waits for it: `DS18B20Sensor`
takes the latest conversion that a reader beside the loop keeps (base.ThreadedConversions).
"""

from __future__ import annotations

import errno
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from hermsd.hardware.lm92 import Reading, SensorError
from hermsd.hardware.sensors.base import Conversions, SoftLimits, calibrated

DEFAULT_ROOT: Final = "/sys/bus/w1/devices"
FAMILY: Final = 0x28
OTHER_FAMILIES: Final = {0x10: "DS18S20", 0x22: "DS1822", 0x3B: "DS1825", 0x42: "DS28EA00"}
STEP_CELSIUS: Final = 0.0625
CONVERSION_S: Final = 0.75
"""The datasheet's longest 12-bit conversion (tCONV)."""
MIN_CELSIUS: Final = -55.0
MAX_CELSIUS: Final = 125.0
FIRST_WAIT_S: Final = 2 * CONVERSION_S
POWER_ON_WORD: Final = 0x0550
"""85.000 °C: what the temperature register holds before the first conversion."""
POWER_ON_NEAR_C: Final = 2.0
"""°C: how near 85 the last good reading must be for 85.000 °C to be a temperature (the
supervisor's built-in safety.max_step: a jump it would take)."""
MARKER_127_94_WORD: Final = 0x07FF
MARKER_MINUS_127_WORD: Final = 0xF810
CONFIG_12_BIT: Final = 0x7F
SCRATCHPAD_BYTES: Final = 9


def _shifted_eight_times(crc: int) -> int:
    """The CRC-8 shift register after a byte's eight shifts, from `crc` (the byte already
    added in): each bit shifted out feeds the polynomial back in."""
    for _ in range(8):
        crc = crc >> 1 ^ 0x8C if crc & 1 else crc >> 1  # x^8 + x^5 + x^4 + 1 reflected
    return crc


_CRC8_TABLE: Final = bytes(_shifted_eight_times(value) for value in range(256))


def crc8(data: bytes) -> int:
    """Dallas/Maxim CRC-8 (x^8 + x^5 + x^4 + 1, LSB first, initial 0): the ROM's and the
    scratchpad's; over the eight data bytes and the CRC byte it is 0. A byte at a time from
    a table of the register's eight shifts (a tenth of the time of bit by bit)."""
    crc = 0
    for byte in data:
        crc = _CRC8_TABLE[crc ^ byte]
    return crc


def family_of(device_id: str) -> int | None:
    """The family code an id such as '28-0316a2795bff' begins with, or None if it has none."""
    head, _, serial = device_id.partition("-")
    if len(head) != 2 or not serial:
        return None
    try:
        return int(head, 16)
    except ValueError:
        return None


def _signed(word: int) -> int:
    return word - 0x10000 if word & 0x8000 else word


def word_celsius(word: int) -> float:
    """°C from the 16-bit temperature register (two's complement, 1/16 °C steps)."""
    return _signed(word) * STEP_CELSIUS


class TrapError(SensorError):
    """A value the chip gave that is a known trap, not a temperature; `trap` names it."""

    def __init__(self, trap: str, message: str, *, bus: str) -> None:
        super().__init__(message, bus=bus, address=None)
        self.trap = trap


@dataclass(frozen=True, slots=True)
class Scratchpad:
    """The nine bytes as the w1 driver printed them, and its CRC verdict."""

    data: bytes
    kernel_crc_ok: bool


def parse_w1_slave(text: str) -> Scratchpad:
    """The scratchpad in a `w1_slave` text ('72 01 … 57 : crc=57 YES' then '… t=23125');
    ValueError when the text is not that."""
    lines = text.splitlines()
    if not lines:
        raise ValueError("w1_slave is empty")
    left, sep, verdict = lines[0].partition(":")
    words = verdict.split()
    if (
        not sep
        or len(words) != 2
        or not words[0].startswith("crc=")
        or words[1]
        not in (
            "YES",
            "NO",
        )
    ):
        raise ValueError(f"w1_slave's first line is not 'bytes : crc=xx YES|NO': {lines[0]!r}")
    try:
        data = bytes(int(part, 16) for part in left.split())
    except ValueError:
        raise ValueError(f"w1_slave's bytes are not hexadecimal: {left!r}") from None
    if len(data) != SCRATCHPAD_BYTES:
        raise ValueError(f"w1_slave holds {len(data)} bytes, a scratchpad is {SCRATCHPAD_BYTES}")
    return Scratchpad(data, words[1] == "YES")


def _power_on_value(previous: float | None) -> bool:
    """Whether 85.000 °C after the good reading `previous` (None: none since the start or a
    failed read) is the chip's power-on value rather than a temperature."""
    return previous is None or abs(previous - word_celsius(POWER_ON_WORD)) > POWER_ON_NEAR_C


def decode_scratchpad(
    pad: Scratchpad, where: str, previous: float | None = None
) -> tuple[float, int]:
    """(°C, temperature word) of a scratchpad, or the TrapError it is; `previous`: the last
    good reading, which decides whether 85.000 °C is the power-on value."""
    data = pad.data

    def trap(name: str, detail: str) -> TrapError:
        return TrapError(name, f"{where}: {detail}", bus=where)

    if data == bytes(SCRATCHPAD_BYTES):
        return_trap = "all-zero scratchpad (its CRC passes and reads 0 °C): the data line is "
        raise trap("zeros", return_trap + "shorted to ground, check DQ against GND")
    if data == bytes([0xFF] * SCRATCHPAD_BYTES):
        raise trap(
            "ones", "all-ones scratchpad: nothing answered, check DQ, GND and the 4.7 kΩ pull-up"
        )
    if crc8(data[:8]) != data[8] or not pad.kernel_crc_ok:
        raise trap(
            "crc",
            f"CRC mismatch (computed {crc8(data[:8]):#04x}, sent {data[8]:#04x}): noise on the "
            "line, check the pull-up (4.7 kΩ, less on a long cable) and the cable's length",
        )
    word = data[0] | data[1] << 8
    if word == POWER_ON_WORD and _power_on_value(previous):
        raise trap(
            "power_on",
            "85.000 °C, the power-on value: the chip reset before converting (a supply dip, or "
            "parasitic power too weak), check VDD wired to 3.3 V, not to GND",
        )
    if data[4] != CONFIG_12_BIT:
        bits = 9 + (data[4] >> 5 & 3)
        raise trap(
            "resolution",
            f"resolution {bits} bits (config byte {data[4]:#04x}), not 12: write 12 to the "
            "device's 'resolution' file",
        )
    return _checked_word(word, where), word


def _checked_word(word: int, where: str) -> float:
    celsius = word_celsius(word)
    if word in (MARKER_127_94_WORD, MARKER_MINUS_127_WORD):
        raise TrapError(
            "marker",
            f"{where}: {celsius:g} °C is a marker for a failed read, not a temperature: check "
            "the cable and its connectors",
            bus=where,
        )
    if not MIN_CELSIUS <= celsius <= MAX_CELSIUS:
        raise TrapError(
            "range",
            f"{where}: {celsius:g} °C is outside the chip's {MIN_CELSIUS:g}..{MAX_CELSIUS:g} °C: "
            "a corrupted read, check the cable",
            bus=where,
        )
    return celsius


def decode_millidegrees(text: str, where: str, previous: float | None = None) -> tuple[float, int]:
    """(°C, the word it stands for) of a `temperature` file ('23125'), trapped as the bytes
    are (`previous` as for `decode_scratchpad`); an all-zero scratchpad cannot be told from
    0 °C here, so `w1_slave` comes first."""
    try:
        milli = int(text.strip())
    except ValueError:
        message = f"{where}: temperature reads {text.strip()!r}"
        raise SensorError(message, bus=where, address=None) from None
    if milli == 85000 and _power_on_value(previous):
        raise TrapError(
            "power_on",
            f"{where}: 85.000 °C, the power-on value: a supply dip or weak parasitic power",
            bus=where,
        )
    word = round(milli * 16 / 1000) & 0xFFFF
    return _checked_word(word, where), word


class DS18B20:
    """One DS18B20 under a w1 root (`/sys/bus/w1/devices`, or a fake tree in a directory).

    `convert` blocks for the chip's conversion (up to 750 ms): call it beside the loop.
    """

    def __init__(self, device_id: str, root: str | os.PathLike[str] = DEFAULT_ROOT) -> None:
        self.device_id = device_id
        self.path = Path(root) / device_id
        self.where = f"DS18B20 {device_id}"
        self._previous: float | None = None  # the last good reading; None after a failed one

    def identify(self) -> None:
        """Refuse a family other than 28, and a device no longer on the bus."""
        family = family_of(self.device_id)
        if family != FAMILY:
            other = OTHER_FAMILIES.get(family or -1, "not a DS18B20")
            raise TrapError(
                "family",
                f"{self.where}: family code {self.device_id[:2]!r} is {other}, a DS18B20 is 28: "
                "name the right device id",
                bus=self.where,
            )
        if not self.path.is_dir():
            raise self._gone(None)

    def convert(self) -> tuple[float, int]:
        """(°C, temperature word) of a fresh conversion, or the SensorError it is."""
        try:
            celsius, word = self._converted()
        except SensorError:
            self._previous = None
            raise
        self._previous = celsius
        return celsius, word

    def _converted(self) -> tuple[float, int]:
        try:
            slave = (self.path / "w1_slave").read_text(encoding="ascii")
        except FileNotFoundError as error:
            if self.path.is_dir() and (self.path / "temperature").exists():
                return self._read_temperature_file()
            raise self._gone(error.errno) from error
        except (OSError, UnicodeDecodeError) as error:
            code = getattr(error, "errno", None)
            raise self._gone(code) from error
        try:
            pad = parse_w1_slave(slave)
        except ValueError as error:
            raise SensorError(f"{self.where}: {error}", bus=self.where, address=None) from None
        return decode_scratchpad(pad, self.where, self._previous)

    def _read_temperature_file(self) -> tuple[float, int]:
        try:
            text = (self.path / "temperature").read_text(encoding="ascii")
        except (OSError, UnicodeDecodeError) as error:
            raise self._gone(getattr(error, "errno", None)) from error
        return decode_millidegrees(text, self.where, self._previous)

    def _gone(self, code: int | None) -> SensorError:
        said = f" ({os.strerror(code)})" if code not in (None, errno.ENOENT) else ""
        return SensorError(
            f"{self.where}: gone from the bus{said}: check its three wires and the pull-up, "
            "and that w1-gpio is loaded",
            bus=self.where,
            address=None,
            errno=code,
        )


def find(root: str | os.PathLike[str] = DEFAULT_ROOT) -> list[str]:
    """The DS18B20 ids under a w1 root (family 28), sorted; [] when there is none."""
    try:
        names = os.listdir(root)
    except OSError:
        return []
    return sorted(name for name in names if family_of(name) == FAMILY)


class DS18B20Sensor(SoftLimits):
    """The loop's `Sensor` for a DS18B20: the latest conversion kept beside the loop, refused
    when it is older than `max_age_s` (a stalled reader is a failed read, not the last value).
    """

    def __init__(
        self,
        chip: DS18B20,
        conversions: Callable[[Callable[[], Reading]], Conversions],
        now: Callable[[], float],
        offset_c: float = 0.0,
        max_age_s: float = 2.5,
        convert: Callable[[], tuple[float, int]] | None = None,
    ) -> None:
        """`convert` (default `chip.convert`) is one conversion; the simulator's first has
        its fake chip write the files."""
        super().__init__()
        self.chip = chip
        self._chip_convert = chip.convert if convert is None else convert
        self.kind = "ds18b20"
        self._offset_c = offset_c
        self._now = now
        self._max_age_s = max_age_s
        self._conversions = conversions(self._convert)
        self._conversions.start()

    def _convert(self) -> Reading:
        celsius, word = self._chip_convert()
        return calibrated(celsius, word, self._offset_c)

    def identify(self) -> None:
        self.chip.identify()

    def wake(self) -> None:
        """At the start, wait for the reader's first conversion (a second at most), so that
        the loop's first read finds one; later it is there and this returns at once."""
        self._conversions.wait_first(FIRST_WAIT_S)

    def read(self) -> Reading:
        latest = self._conversions.latest()
        where = self.chip.where
        if latest is None:
            raise SensorError(f"{where}: no conversion finished yet", bus=where, address=None)
        age = self._now() - latest.done_at
        if age > self._max_age_s:
            raise SensorError(
                f"{where}: the latest conversion is {age:.1f} s old (the reader is stuck)",
                bus=where,
                address=None,
            )
        if latest.error is not None:
            raise latest.error
        assert latest.reading is not None
        return latest.reading

    def close(self) -> None:
        self._conversions.close()
