"""The HERMS coil's load on the HLT, as the safety supervisor counts it: bounds, not a guess.

The coil passes Q = ε·ṁc·(T_hlt − T_in) from the HLT's water to the wort (ε ≤ 1, the wort's
capacity rate ṁc; docs/herms.md, "The coil and the safety"), in either direction: a mash
warmer than the HLT gives heat back. Whatever the coil, ε ≤ 1, so the most it can exchange is
the whole flow brought to the HLT's temperature: |Q| ≤ ṁc·|T_hlt − T_mash|, with ṁc from the
most the pump can move (`herms.max_coil_flow`). A conductance learned on the day (K, the
ε·ṁc the HLT's heat balance shows, with its uncertainty) narrows that, never widens it.

The supervisor judges a dead element by the most the coil can take (a fall the coil can
explain is no verdict) and a shorted SSR by the most it can give back, so the bounds err
wide: the mash's reading may be off from the HLT's by `SENSOR_MARGIN` either way, and without
a mash reading the mash may be anywhere from 0 to 100 °C (liquid wort).
"""

from __future__ import annotations

from dataclasses import dataclass

from hermsd.safety.limits import WATER_HEAT_CAPACITY

SENSOR_MARGIN = 1.0
"""°C the mash's and the HLT's sensors may disagree by: two sensors' tolerances (an LM92's
±0.33 °C and a DS18B20's ±0.5 °C, or a class B PT100's ±0.6 at 66 °C with either)."""

MASH_RANGE = (0.0, 100.0)
"""°C: where liquid wort may be while the mash's reading is unknown (its sensor faulty)."""


@dataclass(frozen=True, slots=True)
class CoilLoad:
    """W the coil takes from the HLT's water this period (negative: it gives heat back):
    the best estimate (None when the coil's conductance is not known) and the lowest and
    highest plausible values (`low` ≤ 0 ≤ `high` while the pump may run)."""

    watts: float | None
    low: float
    high: float

    @property
    def most_taken(self) -> float:
        """W: the most the coil may take from the HLT (what may explain a fall)."""
        return max(0.0, self.high)

    @property
    def most_given(self) -> float:
        """W: the most the coil may give back to the HLT (what may explain a rise)."""
        return max(0.0, -self.low)


NO_LOAD = CoilLoad(0.0, 0.0, 0.0)
"""The pump stopped (or no mash known): the coil exchanges nothing."""


def flow_capacity_rate(litres_per_minute: float) -> float:
    """W/K: the capacity rate ṁc of wort (taken as water, 1 kg/L) at `litres_per_minute`."""
    return litres_per_minute / 60.0 * WATER_HEAT_CAPACITY


def coil_load(
    hlt: float,
    mash: float | None,
    pump: bool | None,
    max_flow: float,
    conductance: tuple[float, float] | None = None,
) -> CoilLoad:
    """The coil's load with the HLT at `hlt` °C and the mash at `mash` (None: no reading).

    `pump`: True running, False stopped (NO_LOAD), None not known (a pump hermsd does not
    switch: it may be running, so the bounds are counted; the estimate is None).
    `max_flow`: L/min, the most the pump moves. `conductance`: (K, its highest plausible
    value) in W/K, learned on the day, or None before it is known.
    """
    if pump is False:
        return NO_LOAD
    coldest, warmest = (mash, mash) if mash is not None else MASH_RANGE
    taken_dt = max(0.0, hlt - coldest + SENSOR_MARGIN)
    given_dt = max(0.0, warmest + SENSOR_MARGIN - hlt)
    most = flow_capacity_rate(max_flow)
    if conductance is not None:
        most = min(most, max(0.0, conductance[1]))
    watts = None
    if conductance is not None and mash is not None and pump:
        watts = conductance[0] * (hlt - mash)
    return CoilLoad(watts, -most * given_dt, most * taken_dt)
