"""The mash side of a HERMS as a plant: a mash tun whose wort a pump carries through a coil in
the HLT and back.

The HLT's water gives the coil's load up to the wort; the wort returns to the mash. With the
pump stopped the coil exchanges nothing, and a stuck recirculation (the pump running, no flow
through the bed) exchanges nothing either: the mash then no longer follows the coil.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from hermsd.sim.hlt import Plant


@runtime_checkable
class HermsPlant(Plant, Protocol):
    """An HLT (the `Plant` protocol) with a mash tun, a coil and a pump.

    Times and temperatures as in `Plant`. `temperature` stays the HLT sensor's reading; the
    mash has its own sensor, read by `mash_temperature`.
    """

    def set_pump(self, on: bool, t: float) -> None:
        """The pump runs (wort through the coil) or stops from `t` on."""
        ...

    def set_recirculation_ok(self, ok: bool, t: float) -> None:
        """A stuck recirculation (`ok` False): the pump runs but no wort flows."""
        ...

    def dough_in(
        self, grain_kg: float, grain_c: float, water_litres: float, water_c: float, t: float
    ) -> None:
        """Grain and strike water go into the mash tun at `t`; they mix at once."""
        ...

    def mash_temperature(self, t: float) -> float:
        """What a perfect sensor at the mash's place (the tun's outlet or its bed) reads."""
        ...

    def coil_outlet_temperature(self, t: float) -> float:
        """The wort's temperature as it leaves the coil, where a coil-outlet sensor sits."""
        ...

    def coil_watts(self, t: float) -> float:
        """The heat the coil takes from the HLT's water at `t` (negative when the wort is the
        warmer and gives heat back)."""
        ...
