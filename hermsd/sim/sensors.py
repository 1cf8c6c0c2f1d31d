"""The simulated sensor of each kind, at the OS boundary: the LM92 on the fake I2C bus, the
DS18B20 in a fake w1 sysfs tree (a temporary directory), the MAX31865 behind a fake spidev;
each read by its real driver, each fed by the tun model and switched into its faults."""

from __future__ import annotations

import math
import random
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from hermsd.hardware.lm92 import LM92
from hermsd.hardware.sensors import ds18b20
from hermsd.hardware.sensors.base import ClockedConversions
from hermsd.hardware.sensors.kinds import max31865_on
from hermsd.runtime.clock import Clock
from hermsd.sim.bus import FakeLM92, FakeSMBus
from hermsd.sim.bus import Fault as LM92Fault
from hermsd.sim.clock import VirtualClock
from hermsd.sim.spi import FakeMAX31865, FakeSpiDev, RtdFault
from hermsd.sim.w1 import FakeW1Tree, W1Fault

if TYPE_CHECKING:
    from hermsd.config.schema import SensorKeys
    from hermsd.hardware.sensors.base import Sensor
    from hermsd.sim.hlt import Plant

SIMULATED_ID = "28-00000a1b2c3d"
FAULTS: dict[str, tuple[str, ...]] = {
    "lm92": tuple(f.value for f in LM92Fault),
    "ds18b20": tuple(f.value for f in W1Fault),
    "max31865": tuple(f.value for f in RtdFault),
}
"""The faults each kind's fake can be switched into (a scenario's `sensor:` events)."""


class FakeChip(Protocol):
    """What a scenario does to a fake sensor: switch it into a fault and out again."""

    def set_fault(self, kind: str, value: float | None = None) -> None: ...


def fake_sensor(
    sensor: SensorKeys,
    now: Callable[[], float],
    source: Callable[[], float],
    advance: Callable[[float], None] | None,
) -> tuple[Sensor, FakeChip]:
    """The driver of `sensor.kind` on its fake hardware, converting `source()` (°C)."""
    if sensor.kind == "ds18b20":
        owner = tempfile.TemporaryDirectory(prefix="hermsd-w1-")
        device_id = sensor.id or SIMULATED_ID
        tree = FakeW1Tree(owner.name)
        tree.owner = owner  # the directory lives as long as the tree, the tree as the chip
        fake = tree.add(device_id, source)
        chip = ds18b20.DS18B20(device_id, tree.root)

        def convert() -> tuple[float, int]:
            fake.convert()  # on a Pi, reading w1_slave is what converts
            return chip.convert()

        driver = ds18b20.DS18B20Sensor(
            chip,
            lambda c: ClockedConversions(c, now, ds18b20.CONVERSION_S),
            now,
            sensor.offset,
            convert=convert,
        )
        return driver, fake
    if sensor.kind == "max31865":
        rtd = FakeMAX31865(source, r0=sensor.r0, rref=sensor.rref)
        spi = FakeSpiDev({(sensor.bus, sensor.device): rtd})
        spi.open(sensor.bus, sensor.device)
        spi.mode = 1
        return max31865_on(spi, sensor, "MAX31865 on a simulated SPI bus"), rtd
    lm92 = FakeLM92(source, advance=advance)
    bus = FakeSMBus()
    bus.attach(sensor.address, lm92)
    return LM92(bus, sensor.address, bus_name="sim"), lm92


def _cold_water() -> tuple[Callable[[], float], VirtualClock]:
    from hermsd.sim.hlt import make_plant

    clock = VirtualClock()
    tun = make_plant("physical", start_c=17.3)
    return sensor_reading(tun, clock, noise_c=0.04, seed=1), clock


def simulated_w1_tree(
    root: Path, device_id: str
) -> tuple[Path, Callable[[], None], Callable[[float], None]]:
    """A fake w1 tree holding one DS18B20: (its root, a conversion, the clock's advance)."""
    source, clock = _cold_water()
    chip = FakeW1Tree(root).add(device_id, source)
    return root, chip.convert, clock.advance


def simulated_spi(r0: float, rref: float) -> FakeSpiDev:
    """A fake spidev, opened and set up, with a MAX31865 and a PT of `r0` Ω behind it."""
    source, _ = _cold_water()
    spi = FakeSpiDev({(0, 0): FakeMAX31865(source, r0=r0, rref=rref)})
    spi.open(0, 0)
    spi.mode = 1
    return spi


def sensor_reading(tun: Plant, clock: Clock, noise_c: float, seed: int) -> Callable[[], float]:
    """What the LM92 converts: the tun's sensor temperature now, plus Gaussian noise of
    standard deviation `noise_c` from a generator seeded with `seed` (the chip then
    truncates it to its 0.0625 °C steps)."""
    if not 0.0 <= noise_c < math.inf:
        raise ValueError(f"noise_c = {noise_c!r} is invalid: it must be a number ≥ 0")
    if noise_c == 0.0:
        return lambda: tun.temperature(clock.monotonic())
    rng = random.Random(seed)
    return lambda: tun.temperature(clock.monotonic()) + rng.gauss(0.0, noise_c)
