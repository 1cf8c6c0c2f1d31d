"""The simulated DS18B20 and MAX31865 that `hermsd sensor --simulate` reads: cold water in
the physical tun, with a little sensor noise, behind the fake w1 tree or the fake spidev."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from hermsd.sim.clock import VirtualClock
from hermsd.sim.hlt import make_plant
from hermsd.sim.spi import FakeMAX31865, FakeSpiDev
from hermsd.sim.w1 import FakeW1Tree
from hermsd.sim.world import sensor_reading


def _cold_water() -> tuple[Callable[[], float], VirtualClock]:
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
