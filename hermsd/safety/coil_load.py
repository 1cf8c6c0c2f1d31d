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

The mash's own heat balance bounds what the coil may take beyond what a working element
makes up anyway (`MashWatch.load`): a working element at 80 % holds both vessels' losses
(or the rest could not be held at all), so the HLT can fall only by the heat the mash gains,
C_m·dT_m/dt, in the least water the HLT may hold. That does not involve the element: a dead
one does not widen it.
"""

from __future__ import annotations

import math
from collections import deque
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

GRAIN_HEAT_CAPACITY = 1700.0
"""J/(kg·K): malt's specific heat, 0.41 of water's (the infusion equation's constant)."""

MASH_CAPACITY_MARGIN = 2.0
"""How far the mash's heat capacity may exceed the brewer's `herms.mash_litres` and
`grain_kg`: half to twice, as the HLT's fill (`FILL_RANGE`). A mash stated more than twice
too small can latch a false heater_not_heating in a climb (the heater off: safe, not silent)."""

SLOPE_WINDOW = 240.0
"""s of mash readings its slope is fitted over: the LM92's 0.0625 °C steps and 0.03 °C noise,
one reading a 5 s period, give the slope a standard error of 0.035/√(48·(48²−1)/12)/5 s =
7.3e-5 °C/s, some 17 W in a 50 L + 12 kg mash (230 kJ/K): small against a climb's kilowatts."""

SETTLE_LAGS = 3.0
"""The mash sensor's lags after the hoses' round trip before its reading shows the coil's
heat (e^−3: 5 % left): with the slope's window, what the pump must have run for before the
mash's balance is trusted."""


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


def mash_capacity(litres: float, grain_kg: float) -> float:
    """J/K: the brewer's mash, its water (taken as water) and its grain."""
    return litres * WATER_HEAT_CAPACITY + grain_kg * GRAIN_HEAT_CAPACITY


def coil_load(
    hlt: float,
    mash: float | MashSpan,
    pump: bool | None,
    max_flow: float,
    conductance: tuple[float, float] | None = None,
    warming: float | None = None,
) -> CoilLoad:
    """The coil's load with the HLT at `hlt` °C and the mash at `mash` (a reading, or where it
    may be while its sensor is faulty).

    `pump`: True running, False stopped (NO_LOAD), None not known (a pump hermsd does not
    switch: it may be running, so the bounds are counted; the estimate is None).
    `max_flow`: L/min, the most the pump moves. `conductance`: (K, its highest plausible
    value) in W/K, learned on the day, or None before it is known. `warming`: W, the most
    heat the mash is gaining (`MashWatch`), the most taken when it is less (None: unknown).
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
    high = most * taken_dt
    if warming is not None:
        high = min(high, max(0.0, warming))
    return CoilLoad(watts, -most * given_dt, high)


class MashWatch:
    """What the supervisor takes of the mash side between periods: the mash's last good
    reading and the HLT's hottest since (where the mash may be while its sensor is faulty),
    and the mash's slope over the pump's run (the heat it gains)."""

    __slots__ = ("_hottest", "_last", "_readings", "_run_from")

    def __init__(self) -> None:
        self._last: tuple[float, float] | None = None  # (t, °C) of the last good reading
        self._hottest = -math.inf  # the HLT's hottest PV since
        self._readings: deque[tuple[float, float]] = deque()  # (t, °C) in the pump's run
        self._run_from: float | None = None  # when the pump was last seen started

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

    def warming(self, t: float, mash: float | None, pump: bool | None, settle: float) -> float:
        """°C/s the mash is warming at (its readings' least-squares slope over SLOPE_WINDOW),
        or NaN while not known: the pump not known to run, a reading missing, the pump's run
        shorter than `settle` s (the hoses' and the sensor's lag and the window), or every
        reading over the window the same (a frozen register shows no warming whatever the
        coil gives; a mash that truly stands still moves again once the element dies)."""
        if not pump or mash is None:
            self._run_from = None
            self._readings.clear()
            return math.nan
        if self._run_from is None:
            self._run_from = t
        readings = self._readings
        readings.append((t, mash))
        while t - readings[0][0] > SLOPE_WINDOW:
            readings.popleft()
        if t - self._run_from < settle or len(readings) < 3:
            return math.nan
        if all(m == mash for _, m in readings):
            return math.nan
        n = len(readings)
        t_mean = math.fsum(when for when, _ in readings) / n
        m_mean = math.fsum(m for _, m in readings) / n
        stt = math.fsum((when - t_mean) ** 2 for when, _ in readings)
        stm = math.fsum((when - t_mean) * (m - m_mean) for when, m in readings)
        return stm / stt

    def load(
        self,
        t: float,
        hlt: float,
        mash: float | None,
        pump: bool | None,
        *,
        max_flow: float,
        litres: float,
        grain_kg: float,
        lags: tuple[float, float],
        conductance: tuple[float, float] | None = None,
    ) -> CoilLoad:
        """The coil's load for the supervisor this period (`coil_load`), its most taken
        bounded by the mash's warming once known: MASH_CAPACITY_MARGIN times the brewer's
        mash (`litres`, `grain_kg`) times its slope. `lags`: s, the hoses' round trip and the
        mash sensor's lag; the pump must have run for them (SETTLE_LAGS of the sensor's) and
        the slope's window before the mash's reading shows the coil's heat."""
        span = self.span(t, hlt, mash, litres)
        hoses, sensor = lags
        slope = self.warming(t, mash, pump, SLOPE_WINDOW + hoses + SETTLE_LAGS * sensor)
        warming = None
        if not math.isnan(slope):
            most_mash = MASH_CAPACITY_MARGIN * mash_capacity(litres, grain_kg)
            warming = most_mash * max(0.0, slope)
        where = span if mash is None else mash
        return coil_load(hlt, where, pump, max_flow, conductance, warming)
