"""A fake w1 sysfs tree: real files in a directory that the DS18B20 driver reads as it reads
/sys/bus/w1/devices, written from a temperature source (the tun model) at each conversion
that changes what they show.

`FakeDS18B20.convert` is the conversion: it quantises the source to the chip's 1/16 °C
(truncated toward −∞, as the LM92 fake does) and writes `w1_slave` (the nine scratchpad
bytes, the CRC line, `t=`) and `temperature` as the kernel's w1_therm does. Each of the
chip's traps can be switched on, so that the driver meets them through the same files.
"""

from __future__ import annotations

import functools
import math
import os
import shutil
from collections.abc import Callable
from enum import StrEnum
from pathlib import Path
from typing import Final

from hermsd.hardware.sensors.ds18b20 import (
    CONFIG_12_BIT,
    MARKER_127_94_WORD,
    MAX_CELSIUS,
    MIN_CELSIUS,
    POWER_ON_WORD,
    STEP_CELSIUS,
    crc8,
)
from hermsd.sim.fake_faults import chosen

_TH, _TL = 0x4B, 0x46  # the alarm bytes as shipped (75 °C, 70 °C)


class W1Fault(StrEnum):
    """How the fake DS18B20 misbehaves; one at a time."""

    OK = "ok"
    CRC = "crc"
    """A bit flipped on the wire: the CRC byte does not match, the kernel says NO."""
    POWER_ON = "power_on"
    """The chip reset before converting: 85.000 °C with a good CRC."""
    ZEROS = "zeros"
    """DQ shorted to ground: nine zero bytes, whose CRC (0) passes."""
    ONES = "ones"
    """Nobody answers (DQ open): nine 0xff bytes."""
    MARKER = "marker"
    """127.94 °C (0x07ff), a read gone wrong."""
    GONE = "gone"
    """Unplugged: the kernel removed the device's directory; it comes back when this ends."""
    STUCK = "stuck"
    """No more conversions: the files keep what they held."""
    SPIKE = "spike"
    """The next conversion reads `value` °C, then the fault clears."""
    RESOLUTION = "resolution"
    """The chip was set to 9 bits (config byte 0x1f)."""


@functools.lru_cache(maxsize=4096)
def scratchpad(word: int, config: int = CONFIG_12_BIT) -> bytes:
    """The nine bytes a DS18B20 sends for temperature `word`, with its CRC."""
    lsb, msb = word & 0xFF, word >> 8 & 0xFF
    count_remain = 0x0C if word == POWER_ON_WORD else 0x10 - (lsb & 0x0F)
    data = bytes([lsb, msb, _TH, _TL, config, 0xFF, count_remain, 0x10])
    return data + bytes([crc8(data)])


def w1_slave_text(data: bytes, kernel_crc: int | None = None) -> str:
    """What w1_therm prints for the scratchpad `data`: its computed CRC and verdict, then
    the bytes again with `t=` millidegrees (the C division, toward zero)."""
    hexes = " ".join(f"{b:02x}" for b in data)
    crc = crc8(data[:8]) if kernel_crc is None else kernel_crc
    verdict = "YES" if crc == data[8] else "NO"
    word = data[0] | data[1] << 8
    signed = word - 0x10000 if word & 0x8000 else word
    milli = int(signed * 1000 / 16)
    return f"{hexes} : crc={crc:02x} {verdict}\n{hexes} t={milli}\n"


class FakeDS18B20:
    """One DS18B20 in a fake tree, converting `source()` at each `convert()`."""

    def __init__(self, path: Path, source: Callable[[], float]) -> None:
        self.path = path
        self._source = source
        self._fault = W1Fault.OK
        self._fault_value = 0.0
        self.tree: FakeW1Tree | None = None
        self._shown: bytes | None = None  # what the files hold, None when they are not there
        self._slave_path, self._temperature_path = path / "w1_slave", path / "temperature"
        path.mkdir(parents=True, exist_ok=True)
        self._write(scratchpad(POWER_ON_WORD))

    @property
    def fault(self) -> W1Fault:
        return self._fault

    def set_fault(self, kind: str, value: float | None = None) -> None:
        """Start misbehaving as `kind` (a W1Fault or its name), or stop with "ok"."""
        fault, amount = chosen(W1Fault, kind, value, "DS18B20")
        previous, self._fault, self._fault_value = self._fault, fault, amount
        if fault is W1Fault.GONE:
            shutil.rmtree(self.path, ignore_errors=True)
            self._shown = None
        elif previous is W1Fault.GONE:
            self.path.mkdir(parents=True, exist_ok=True)
            self._write(scratchpad(POWER_ON_WORD))  # powered up afresh

    def convert(self) -> None:
        """One conversion, written to the files as the kernel would show it."""
        fault = self._fault
        if fault is W1Fault.GONE or fault is W1Fault.STUCK:
            return
        if fault is W1Fault.SPIKE:
            self._fault = W1Fault.OK
            word = _word(self._fault_value)
        else:
            word = _word(self._source())
        if fault is W1Fault.CRC:
            good = scratchpad(word)
            self._write(good[:8] + bytes([good[8] ^ 0x01]))
        elif fault is W1Fault.POWER_ON:
            self._write(scratchpad(POWER_ON_WORD))
        elif fault is W1Fault.ZEROS:
            self._write(bytes(9))
        elif fault is W1Fault.ONES:
            self._write(bytes([0xFF] * 9))
        elif fault is W1Fault.MARKER:
            self._write(scratchpad(MARKER_127_94_WORD))
        elif fault is W1Fault.RESOLUTION:
            self._write(scratchpad(word & ~0x07, config=0x1F))
        else:
            self._write(scratchpad(word))

    def _write(self, data: bytes) -> None:
        """The files rewritten when what they show changes, in place: emptying a file first
        (a plain write's O_TRUNC) has ext4 flush it to disk when it is closed, ~2 ms a write."""
        if data == self._shown:
            return
        slave, temperature = _file_texts(data)
        _rewrite(self._slave_path, slave)
        _rewrite(self._temperature_path, temperature)
        self._shown = data


@functools.lru_cache(maxsize=4096)
def _file_texts(data: bytes) -> tuple[bytes, bytes]:
    """`w1_slave` and `temperature` for the scratchpad `data` (a tun holds a few words)."""
    text = w1_slave_text(data)
    return text.encode("ascii"), text.rsplit("t=", 1)[1].encode("ascii")


def _rewrite(path: Path, content: bytes) -> None:
    """`path` holding `content`: written over from its start, then cut to its length."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT, 0o644)
    try:
        os.pwrite(fd, content, 0)
        os.ftruncate(fd, len(content))
    finally:
        os.close(fd)


_STEPS_MIN: Final = round(MIN_CELSIUS / STEP_CELSIUS)
_STEPS_MAX: Final = round(MAX_CELSIUS / STEP_CELSIUS)


def _word(celsius: float) -> int:
    steps = min(_STEPS_MAX, max(_STEPS_MIN, math.floor(celsius / STEP_CELSIUS)))
    return steps & 0xFFFF


class FakeW1Tree:
    """A directory laid out as /sys/bus/w1/devices: a bus master and the devices added."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        self.owner: object = None  # what keeps a temporary root alive, if one does
        (self.root / "w1_bus_master1").mkdir(parents=True, exist_ok=True)

    def add(self, device_id: str, source: Callable[[], float]) -> FakeDS18B20:
        chip = FakeDS18B20(self.root / device_id, source)
        chip.tree = self  # a temporary root lives as long as a chip in it
        return chip
