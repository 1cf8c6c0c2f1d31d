"""A family of brewers' tuns: what every control or safety change is judged on.

No two tuns are alike (20–150 L, 1.5–11 kW, a lidded keggle to an open pot in a cold garage,
a sensor touching the element or in a thermowell on the far side), so a change that only
works on the tun the defaults were fitted to proves nothing. Each member is a physical tun
for the simulator; its brew day is the reference one scaled to its volume: start at the
room's temperature, setpoint 66 °C, a tenth of the volume of 15 °C water at 4 h, 6 h in all.
Every member reaches the band at full power within 3.2 h and holds 66 °C at 70 % of its
element or less (the open pot in the garage, which loses 0.36 kW to evaporation alone).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from hermsd.config.schema import Config
from hermsd.sim.scenario import Event, Scenario

SEED_UA_W_PER_K = 3000.0 / 168.9
"""The seed's 90 L tun: 3 kW for a steady-state gain of 1.689 °C/%."""

SEED_LITRES = 90.0
NOISE_C = 0.03
"""Sensor noise (standard deviation) before the LM92's 0.0625 °C truncation."""


@dataclass(frozen=True, slots=True)
class TunSpec:
    """One brewer's tun. UA scales with the wetted surface (volume^⅔) around the seed's."""

    name: str
    litres: float
    element_watts: float
    ua_factor: float  # × the seed tun's UA scaled to this volume
    transport_delay_s: float  # element → water at the sensor
    sensor_lag_s: float  # the sensor's (or its well's) own first-order lag
    ambient_c: float
    lid_off: bool = False  # the open surface also evaporates (hermsd.sim.hlt.evaporation_w)

    @property
    def ua_w_per_k(self) -> float:
        scale: float = (self.litres / SEED_LITRES) ** (2.0 / 3.0)
        return SEED_UA_W_PER_K * self.ua_factor * scale

    def plant(self, *, noise_c: float = NOISE_C, seed: int = 1) -> dict[str, Any]:
        """The scenario's `plant:` mapping for this tun."""
        return {
            "model": "physical",
            "litres": self.litres,
            "element_watts": self.element_watts,
            "ua_w_per_k": self.ua_w_per_k,
            "transport_delay_s": self.transport_delay_s,
            "sensor_lag_s": self.sensor_lag_s,
            "ambient_c": self.ambient_c,
            "lid": not self.lid_off,
            "noise_c": noise_c,
            "seed": seed,
        }

    def brew_day(self, *, noise_c: float = NOISE_C, seed: int = 1) -> Scenario:
        """Ambient → 66 °C, a tenth of the volume of 15 °C water at 4 h, 6 h in all."""
        water = Event(4 * 3600.0, "add_water", {"litres": self.litres / 10.0, "temp": 15.0})
        return Scenario(
            name=self.name,
            duration=6 * 3600.0,
            plant=self.plant(noise_c=noise_c, seed=seed),
            setpoint=66.0,
            events=(water,),
        )

    def config(self, base: Config) -> Config:
        """`base` with the tun's true litres, watts and lid, as a brewer would set them."""
        tun = dataclasses.replace(
            base.tun,
            litres=self.litres,
            element_watts=self.element_watts,
            lid="off" if self.lid_off else "on",
        )
        return dataclasses.replace(base, tun=tun)


FAMILY: tuple[TunSpec, ...] = (
    TunSpec("seed 90 L 3 kW", 90, 3000, 1.0, 60, 10, 20),
    TunSpec("small 30 L 5.5 kW", 30, 5500, 1.0, 20, 10, 20),
    TunSpec("far sensor 90 L 3 kW", 90, 3000, 1.0, 200, 40, 20),
    TunSpec("big 150 L 5.5 kW lid off", 150, 5500, 1.5, 90, 20, 12, lid_off=True),
    TunSpec("big 150 L 11 kW", 150, 11000, 1.0, 45, 15, 20),
    TunSpec("keggle 50 L 3.5 kW", 50, 3500, 0.5, 30, 10, 25),
    TunSpec("garage 70 L 2.5 kW lid off", 70, 2500, 1.5, 60, 20, 5, lid_off=True),
    TunSpec("thermowell 120 L 3 kW", 120, 3000, 1.0, 180, 120, 15),
    TunSpec("small 30 L 1.5 kW", 30, 1500, 1.0, 30, 5, 20),
    TunSpec("warm room 90 L 6 kW", 90, 6000, 0.5, 45, 10, 30),
    TunSpec("open 120 L 3.5 kW", 120, 3500, 1.5, 60, 10, 20, lid_off=True),
    TunSpec("thermowell 40 L 2 kW", 40, 2000, 1.2, 90, 60, 18),
)
