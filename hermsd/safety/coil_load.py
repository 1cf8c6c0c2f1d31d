"""The HERMS coil's load on the HLT, as the safety supervisor counts it: bounds, not a guess.

The coil passes Q = ε·ṁc·(T_hlt − T_in) from the HLT's water to the wort (ε ≤ 1, the wort's
capacity rate ṁc; docs/herms.md, "The coil and the safety"), in either direction: a mash
warmer than the HLT gives heat back. Whatever the coil, ε ≤ 1, so the most it can exchange is
the whole flow brought to the HLT's temperature: |Q| ≤ ṁc·|T_hlt − T_mash|, with ṁc from the
most the pump can move (`herms.max_coil_flow`). A conductance learned on the day (K, the
ε·ṁc the HLT's heat balance shows, with its uncertainty) narrows that, never widens it.

The supervisor judges a dead element by the most the coil can take (a fall the coil can
explain is no verdict) and a shorted SSR by the most it can give back, so the bounds err
wide: the mash's reading may be off from the HLT's by `SENSOR_MARGIN` either way. Without a
mash reading (its sensor faulty) the mash is bounded from its last good one (`MashWatch`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from hermsd.safety.limits import (
    COLDEST_ROOM,
    FILL_RANGE,
    OPEN_POT_EVAPORATION_W,
    OPEN_POT_UA_PER_L23,
    WATER_HEAT_CAPACITY,
    vapour_pressure_ratio,
)

SENSOR_MARGIN = 1.0
"""°C the mash's and the HLT's sensors may disagree by: two sensors' tolerances (an LM92's
±0.33 °C and a DS18B20's ±0.5 °C, or a class B PT100's ±0.6 at 66 °C with either)."""

MASH_RANGE = (0.0, 100.0)
"""°C: where liquid wort may be while the mash was never read (its sensor faulty from the
start)."""


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


@dataclass(frozen=True, slots=True)
class MashSpan:
    """°C the mash may be at, coldest and warmest, the sensors' tolerances counted."""

    coldest: float
    warmest: float


def flow_capacity_rate(litres_per_minute: float) -> float:
    """W/K: the capacity rate ṁc of wort (taken as water, 1 kg/L) at `litres_per_minute`."""
    return litres_per_minute / 60.0 * WATER_HEAT_CAPACITY


def fastest_mash_cooling(celsius: float, litres: float) -> float:
    """°C/s: the fastest a mash of `litres` (its water) at `celsius` may cool with no heat in.

    The smallest mash the brewer's figure allows (half of it, its grain left out: grain only
    slows the cooling) in an open, uninsulated pot in the coldest room: the HLT's envelope
    (`SafetyLimits.derive`): losses through the wetted area, OPEN_POT_UA_PER_L23·V^⅔·(T − 5 °C),
    and evaporation from the open surface, OPEN_POT_EVAPORATION_W·(V/90 L)^⅔ at 66 °C, growing
    with the vapour pressure. 15 L at 66 °C: (10.7 W/K·61 K + 303 W) / 62.8 kJ/K = 0.015 °C/s.
    """
    least = litres / FILL_RANGE
    conduction = OPEN_POT_UA_PER_L23 * math.pow(least, 2.0 / 3.0) * max(0.0, celsius - COLDEST_ROOM)
    evaporation = OPEN_POT_EVAPORATION_W * math.pow(least / 90.0, 2.0 / 3.0)
    return (conduction + evaporation * vapour_pressure_ratio(celsius)) / (
        least * WATER_HEAT_CAPACITY
    )


def coil_load(
    hlt: float,
    mash: float | MashSpan,
    pump: bool | None,
    max_flow: float,
    conductance: tuple[float, float] | None = None,
) -> CoilLoad:
    """The coil's load with the HLT at `hlt` °C and the mash at `mash` (a reading, or where it
    may be while its sensor is faulty).

    `pump`: True running, False stopped (NO_LOAD), None not known (a pump hermsd does not
    switch: it may be running, so the bounds are counted; the estimate is None).
    `max_flow`: L/min, the most the pump moves. `conductance`: (K, its highest plausible
    value) in W/K, learned on the day, or None before it is known.
    """
    if pump is False:
        return NO_LOAD
    watts = None
    if conductance is not None and pump and not isinstance(mash, MashSpan):
        watts = conductance[0] * (hlt - mash)
    if not isinstance(mash, MashSpan):
        mash = MashSpan(mash - SENSOR_MARGIN, mash + SENSOR_MARGIN)
    taken_dt = max(0.0, hlt - mash.coldest)
    given_dt = max(0.0, mash.warmest - hlt)
    most = flow_capacity_rate(max_flow)
    if conductance is not None:
        most = min(most, max(0.0, conductance[1]))
    return CoilLoad(watts, -most * given_dt, most * taken_dt)


class MashWatch:
    """The mash's last good reading and the HLT's hottest since: where the mash may be while
    its sensor is faulty."""

    __slots__ = ("_hottest", "_last")

    def __init__(self) -> None:
        self._last: tuple[float, float] | None = None  # (t, °C) of the last good reading
        self._hottest = -math.inf  # the HLT's hottest PV since

    def span(self, t: float, hlt: float, mash: float | None, litres: float) -> MashSpan:
        """Where the mash may be at `t`: its reading ± SENSOR_MARGIN; without one, from the
        last good reading: no warmer than it or the hottest the HLT has been since (the coil
        is the mash's only heat source), no colder than it less the fastest a mash of the
        brewer's `litres` may cool since (`fastest_mash_cooling`); never read: MASH_RANGE."""
        if mash is not None:
            self._last, self._hottest = (t, mash), hlt
            return MashSpan(mash - SENSOR_MARGIN, mash + SENSOR_MARGIN)
        self._hottest = max(self._hottest, hlt)
        if self._last is None:
            return MashSpan(*MASH_RANGE)
        then, last = self._last
        cooled = fastest_mash_cooling(last, litres) * (t - then)
        return MashSpan(
            max(MASH_RANGE[0], last - SENSOR_MARGIN - cooled),
            max(last + SENSOR_MARGIN, self._hottest),
        )
