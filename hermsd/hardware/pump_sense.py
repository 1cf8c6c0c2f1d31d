"""The pump sense: a contact that says whether a pump hermsd does not switch runs (a
mains-present optocoupler module on the pump's supply, or an auxiliary contact of its switch)
on a GPIO input line, read once per read interval (a request's get_value: microseconds)."""

from __future__ import annotations

from typing import Protocol

from hermsd.config.schema import PumpConfig
from hermsd.hardware.gpio_line import GpioLine


class PumpSense(Protocol):
    """Whether the pump runs, as its contact says; SensorError or OSError when it cannot be
    read."""

    def running(self) -> bool: ...

    def close(self) -> None: ...


class GpioPumpSense:
    """The contact on a GPIO input line through the `gpiod` 2.x bindings (the `gpio` extra),
    biased to its inactive level so a module unplugged reads a stopped pump."""

    def __init__(self, chip: str, line: int, active_low: bool = False) -> None:
        self._line = GpioLine(
            chip, line, output=False, active_low=active_low, what="the gpio pump sense"
        )

    def running(self) -> bool:
        return self._line.active()

    def close(self) -> None:
        self._line.release()


def open_pump_sense(pump: PumpConfig) -> PumpSense | None:
    """The sense the config fits on hardware (None: none); a simulated one is the
    simulator's (`sim/world.py`)."""
    if pump.sense == "none":
        return None
    if pump.sense != "gpio" or pump.sense_line is None:  # the config's rules refuse both
        raise ValueError(f"pump.sense {pump.sense!r} cannot be opened on hardware")
    return GpioPumpSense(pump.sense_chip, pump.sense_line, pump.sense_active_low)
