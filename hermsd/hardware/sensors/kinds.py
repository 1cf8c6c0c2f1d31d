"""A sensor as the config's `sensor` section names it (or `mash_sensor`, `coil_sensor`): each
kind opened on the real hardware, and described in one phrase for the log."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

from hermsd.hardware.lm92 import LM92, LimitName, Reading, SensorError, open_bus
from hermsd.hardware.sensors import ds18b20
from hermsd.hardware.sensors.base import Sensor, ThreadedConversions
from hermsd.hardware.sensors.max31865 import MAX31865, SpiDevice, open_spi

if TYPE_CHECKING:
    from hermsd.config.schema import SensorKeys


def describe(sensor: SensorKeys) -> str:
    """'DS18B20 28-0316a2795bff under /sys/bus/w1/devices, offset +0.10 °C' and the like."""
    if sensor.kind == "ds18b20":
        what = f"DS18B20 {sensor.id or '(the one found)'} under {sensor.w1_root}"
    elif sensor.kind == "max31865":
        what = (
            f"PT{sensor.r0:g} ({sensor.wires}-wire) on a MAX31865 at "
            f"/dev/spidev{sensor.bus}.{sensor.device}, reference {sensor.rref:g} Ω, "
            f"{sensor.filter_hz} Hz filter"
        )
    else:
        what = f"LM92 at {sensor.address:#04x} on /dev/i2c-{sensor.bus}"
    return what + (f", offset {sensor.offset:+.2f} °C" if sensor.offset else "")


def the_ds18b20(sensor: SensorKeys, section: str = "sensor") -> str:
    """The configured id, or the only DS18B20 under the w1 root (SensorError otherwise)."""
    if sensor.id is not None:
        return sensor.id
    found = ds18b20.find(sensor.w1_root)
    if len(found) != 1:
        said = ", ".join(found) if found else "none"
        raise SensorError(
            f"{section}.id is null and {len(found)} DS18B20 are under {sensor.w1_root} ({said}): "
            f"set {section}.id to its own (`hermsd sensor --kind ds18b20` lists them)",
            bus=sensor.w1_root,
            address=None,
        )
    return found[0]


def open_sensor(sensor: SensorKeys, now: Callable[[], float], section: str = "sensor") -> Sensor:
    """The real sensor the config's `section` names; SensorError when it cannot be opened."""
    if sensor.kind == "ds18b20":
        chip = ds18b20.DS18B20(the_ds18b20(sensor, section), sensor.w1_root)
        return ds18b20.DS18B20Sensor(
            chip, lambda convert: ThreadedConversions(convert, now), now, sensor.offset
        )
    if sensor.kind == "max31865":
        where = f"MAX31865 on /dev/spidev{sensor.bus}.{sensor.device}"
        return max31865_on(open_spi(sensor.bus, sensor.device), sensor, where)
    return LM92(open_bus(sensor.bus), sensor.address, bus_name=f"/dev/i2c-{sensor.bus}")


class Unopened:
    """A sensor that could not be opened: every use raises the error it failed with, so a
    sensor beside the HLT's that is missing is a fault the loop says, not a refused start."""

    def __init__(self, error: SensorError) -> None:
        self._error = error

    def read(self) -> Reading:
        raise self._error

    def identify(self) -> None:
        raise self._error

    def wake(self) -> None:
        raise self._error

    def set_limit(self, name: LimitName, celsius: float) -> None:
        raise self._error

    def limit(self, name: LimitName) -> float:
        raise self._error


def open_role_sensor(sensor: SensorKeys, now: Callable[[], float], section: str) -> Sensor:
    """The sensor of `section` (`mash_sensor`, `coil_sensor`), or `Unopened`."""
    try:
        return open_sensor(sensor, now, section)
    except SensorError as error:
        return Unopened(error)


def max31865_on(spi: SpiDevice, sensor: SensorKeys, where: str) -> MAX31865:
    """The MAX31865 the config describes, on `spi` (the real spidev, or the fake one)."""
    return MAX31865(
        spi,
        r0=sensor.r0,
        rref=sensor.rref,
        wires=sensor.wires,
        filter_hz=sensor.filter_hz,
        offset_c=sensor.offset,
        where=where,
    )
