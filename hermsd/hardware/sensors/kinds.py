"""The tun's sensor as the config's `sensor` section names it: each kind opened on the real
hardware, and described in one phrase for the log."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

from hermsd.hardware.lm92 import LM92, SensorError, open_bus
from hermsd.hardware.sensors import ds18b20
from hermsd.hardware.sensors.base import Sensor, ThreadedConversions
from hermsd.hardware.sensors.max31865 import MAX31865, SpiDevice, open_spi

if TYPE_CHECKING:
    from hermsd.config.schema import SensorConfig


def describe(sensor: SensorConfig) -> str:
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


def the_ds18b20(sensor: SensorConfig) -> str:
    """The configured id, or the only DS18B20 under the w1 root (SensorError otherwise)."""
    if sensor.id is not None:
        return sensor.id
    found = ds18b20.find(sensor.w1_root)
    if len(found) != 1:
        said = ", ".join(found) if found else "none"
        raise SensorError(
            f"sensor.id is null and {len(found)} DS18B20 are under {sensor.w1_root} ({said}): "
            "set sensor.id to the tun's (`hermsd sensor --kind ds18b20` lists them)",
            bus=sensor.w1_root,
            address=None,
        )
    return found[0]


def open_sensor(sensor: SensorConfig, now: Callable[[], float]) -> Sensor:
    """The real sensor; SensorError when it cannot be opened."""
    if sensor.kind == "ds18b20":
        chip = ds18b20.DS18B20(the_ds18b20(sensor), sensor.w1_root)
        return ds18b20.DS18B20Sensor(
            chip, lambda convert: ThreadedConversions(convert, now), now, sensor.offset
        )
    if sensor.kind == "max31865":
        where = f"MAX31865 on /dev/spidev{sensor.bus}.{sensor.device}"
        return max31865_on(open_spi(sensor.bus, sensor.device), sensor, where)
    return LM92(open_bus(sensor.bus), sensor.address, bus_name=f"/dev/i2c-{sensor.bus}")


def max31865_on(spi: SpiDevice, sensor: SensorConfig, where: str) -> MAX31865:
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
