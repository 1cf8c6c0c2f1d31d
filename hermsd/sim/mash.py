"""The mash side of a HERMS as a plant: a mash tun whose wort a pump carries through a coil in
the HLT and back.

The HLT's water gives the coil's load up to the wort; the wort returns to the mash. With the
pump stopped the coil exchanges nothing, and a stuck recirculation (the pump running, no flow
through the bed) exchanges nothing either: the mash then no longer follows the coil.

`HermsTun` is such a plant, built around one of the HLT plants of `hermsd.sim.hlt`:

- **The mash** is well mixed (6 L/min turns a 60 L mash over in ten minutes) with heat
  capacity C_m = 4186 J/(L·K)·water + 1700 J/(kg·K)·grain + the tun's own (`GRAIN_J_PER_KG_K`:
  malt's specific heat, 0.41 that of water, the constant of the infusion equation in J. Palmer's
  *How to Brew*, T_w = (0.41/r)·(T_2 − T_1) + T_2 with r in L/kg). Wort is taken as water
  (4186 J/(L·K), 1 kg/L): a 1.050 wort holds about 1 % less heat per litre. It loses
  UA_mash·(T_m − T_room) to the room. Until dough-in the tun is empty, at the room's
  temperature; grain, water and tun mix at once (the heat of wetting left out).
- **The coil** in the HLT's well-mixed water at T_h: wort entering at T_in with capacity rate
  ṁc leaves at T_out = T_h − (T_h − T_in)·e^(−UA/ṁc) (a tube at uniform surface temperature,
  Incropera & DeWitt, *Fundamentals of Heat and Mass Transfer*, eq. 8.42; the ε-NTU relation
  ε = 1 − e^(−NTU) for C_r = 0, §11.4). The HLT gives Q = ṁc·(T_out − T_in) =
  ε·ṁc·(T_h − T_in), in either direction: a mash warmer than the HLT gives heat back. A 10 to
  15 m coil of ½" copper or stainless has UA of about 100–400 W/K (0.4–0.6 m², the free
  convection outside the tube limiting, 300–700 W/(m²·K)); a brewing pump throttled for
  recirculation moves 4–8 L/min.
- **The hoses**: wort takes `hose_to_coil_s` from the tun's outlet to the coil and
  `hose_to_mash_s` from the coil back (the coil's own hold-up, ~1.4 L in 15 m of ½" tube,
  14 s at 6 L/min, belongs in these: its wort and copper hold some 7 kJ/K against a 90 L
  HLT's 377 kJ/K, so the coil is taken as a delay, not a store). The wort in them (flow ×
  delays, part of the strike water) keeps its heat while the pump stops; the hoses lose none.
- **No flow, no exchange**: the pump off, the recirculation stuck (the bed set, the pump
  running dry) or the tun empty.
- **The mash sensor** at the tun's outlet (or in the bed: the mash is well mixed) follows the
  mash with its own first-order lag, `mash_sensor_lag_s`.

Integration. The coupling runs through the hoses' delays, so the two vessels have no closed
form together. The wort moves in parcels of `STEP_S` seconds of pumping: during one parcel
the coil's inlet and the mash's return are constant (each a parcel's mean temperature), so
the HLT, with the coil as one more linear load (`_LumpedTun.set_coil_load`), and the mash
each integrate exactly between parcels, the heater's edges and every other input kept where
they fall. Each parcel leaving the coil carries exactly the heat the HLT's books say the
coil took, and the mash's outflow the mean of the mash over the parcel, so the energy books
close to rounding. The delays are whole parcels (at least one each way). Holding each
parcel's inlet for one step costs less than 3e-7 °C against a fine Runge-Kutta run of the
continuous delayed equations over the hour after a pump start at 28 K, element off or on
(tests/test_mash.py). Nothing depends on how often anyone looks: the parcels are counted in
pumping time, and a reading between two parcel ends only splits an exact piece in two.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from typing import Protocol, cast, runtime_checkable

from hermsd.sim.hlt import (
    HERMS_METHODS,
    WATER_J_PER_LITRE_K,
    FoptdPlant,
    PhysicalPlant,
    Plant,
    _require,
    _validated_time,
    lagged_sensor,
    make_plant,
)


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


def as_herms_plant(plant: Plant) -> HermsPlant | None:
    """`plant` as a HERMS plant if it has the methods (an outside plant too, whose methods
    its checking wrapper lends it), else None."""
    if all(callable(getattr(plant, name, None)) for name in HERMS_METHODS):
        return cast(HermsPlant, plant)
    return None


GRAIN_J_PER_KG_K = 1700.0
"""Malt's specific heat: 0.41 × water's (How to Brew's infusion equation), 1.7 kJ/(kg·K)."""

STEP_S = 1.0
"""Seconds of pumping per parcel of wort: the coil's inlet and the mash's return are held for
one parcel, and the hoses' delays are whole parcels."""

MASH_RANGES: dict[str, tuple[float, float, str]] = {
    "coil_w_per_k": (10.0, 2000.0, 'W/K; a 10–15 m ½" coil: 100–400'),
    "flow_l_per_min": (0.5, 30.0, "L/min; recirculation: 4–8"),
    "hose_to_coil_s": (0.0, 600.0, "s"),
    "hose_to_mash_s": (0.0, 600.0, "s"),
    "mash_ua_w_per_k": (0.0, 200.0, "W/K; insulated 2–5, bare steel with a lid 8–15"),
    "mash_sensor_lag_s": (0.0, 600.0, "s"),
    "tun_heat_capacity_j_per_k": (0.0, 100000.0, "J/K; 10 kg of stainless: 5000"),
}
"""A `HermsTun`'s parameters (a scenario's `plant: mash:` keys): the range each must lie in."""

DOUGH_IN_RANGES: dict[str, tuple[float, float, str]] = {
    "grain_kg": (0.0, 200.0, "kg"),
    "grain_c": (-20.0, 60.0, "°C"),
    "water_litres": (0.1, 1000.0, "L"),
    "water_c": (0.0, 100.0, "°C (liquid water)"),
}
"""What a dough-in (or a later infusion: grain 0 kg) may put in the tun."""


def _in_range(name: str, value: float, ranges: Mapping[str, tuple[float, float, str]]) -> None:
    low, high, unit = ranges[name]
    real = isinstance(value, int | float) and not isinstance(value, bool)
    _require(name, value, real and low <= value <= high, f"{low:g} to {high:g} {unit}")


def _relax(start: float, rest: float, rate: float, duration: float) -> tuple[float, float]:
    """A body relaxing from `start` towards `rest` at `rate` (1/s, ≥ 0): its temperature after
    `duration` s and the integral of its temperature over them."""
    if rate == 0.0:
        return start, start * duration
    decay_m1 = math.expm1(-rate * duration)
    offset = start - rest
    return start + offset * decay_m1, rest * duration - offset * decay_m1 / rate


class HermsTun:
    """An HLT plant (`PhysicalPlant` or `FoptdPlant`; by default the 90 L 3 kW
    `PhysicalPlant()`, so that `--plant hermsd.sim.mash:HermsTun` is one) with a mash tun, a
    coil and a pump.

    The coil: `coil_w_per_k` (UA), the pump's `flow_l_per_min`; the hoses' delays
    `hose_to_coil_s` and `hose_to_mash_s`; the tun: `mash_ua_w_per_k` to the room,
    `tun_heat_capacity_j_per_k` (0: preheated, or allowed for in the strike temperature);
    the mash sensor's `mash_sensor_lag_s`. Ranges in `MASH_RANGES`. The pump starts off,
    the recirculation ok, the tun empty.
    """

    __slots__ = (
        "_ambient_c",
        "_coil_load_w_per_k",
        "_coil_mark_j",
        "_coil_passes",
        "_flow_w_per_k",
        "_flowing",
        "_hlt",
        "_hose_j_per_k",
        "_mash_c",
        "_mash_capacity",
        "_mash_lost",
        "_mash_ua",
        "_parcel_integral",
        "_pump_on",
        "_pumped_s",
        "_recirculation_ok",
        "_sensor_c",
        "_sensor_rate",
        "_t",
        "_to_coil",
        "_to_mash",
        "_tun_capacity",
    )

    def __init__(
        self,
        hlt: PhysicalPlant | FoptdPlant | None = None,
        *,
        coil_w_per_k: float = 250.0,
        flow_l_per_min: float = 6.0,
        hose_to_coil_s: float = 10.0,
        hose_to_mash_s: float = 10.0,
        mash_ua_w_per_k: float = 10.0,
        mash_sensor_lag_s: float = 10.0,
        tun_heat_capacity_j_per_k: float = 0.0,
    ) -> None:
        for name, value in (
            ("coil_w_per_k", coil_w_per_k),
            ("flow_l_per_min", flow_l_per_min),
            ("hose_to_coil_s", hose_to_coil_s),
            ("hose_to_mash_s", hose_to_mash_s),
            ("mash_ua_w_per_k", mash_ua_w_per_k),
            ("mash_sensor_lag_s", mash_sensor_lag_s),
            ("tun_heat_capacity_j_per_k", tun_heat_capacity_j_per_k),
        ):
            _in_range(name, value, MASH_RANGES)
        if hlt is None:
            hlt = PhysicalPlant()
        self._hlt = hlt
        self._t = hlt.time_s
        self._ambient_c = hlt.ambient_c
        self._flow_w_per_k = flow_l_per_min / 60.0 * WATER_J_PER_LITRE_K
        self._coil_passes = math.exp(-coil_w_per_k / self._flow_w_per_k)  # e^(−NTU)
        self._coil_load_w_per_k = (1.0 - self._coil_passes) * self._flow_w_per_k  # ε·ṁc
        to_coil = max(1, round(hose_to_coil_s / STEP_S))
        to_mash = max(1, round(hose_to_mash_s / STEP_S))
        self._hose_j_per_k = self._flow_w_per_k * STEP_S * (to_coil + to_mash)
        self._to_coil = deque([self._ambient_c] * to_coil)  # [0]: the parcel in the coil
        self._to_mash = deque([self._ambient_c] * to_mash)  # [0]: the parcel coming back
        self._mash_ua = mash_ua_w_per_k
        self._tun_capacity = tun_heat_capacity_j_per_k
        self._mash_capacity = 0.0  # J/K in the tun (the hoses' wort apart); 0: empty
        self._mash_c = self._ambient_c
        self._sensor_c = self._ambient_c
        self._sensor_rate = 1.0 / mash_sensor_lag_s if mash_sensor_lag_s > 0.0 else math.inf
        self._mash_lost = 0.0
        self._pump_on = False
        self._recirculation_ok = True
        self._flowing = False
        self._pumped_s = 0.0  # of the parcel now in the coil
        self._parcel_integral = 0.0  # ∫T_m dt over it, the outflow's mean × its time
        self._coil_mark_j = hlt.coil_energy(self._t)  # when the parcel entered the coil

    # ----------------------------------------------------------- the mash side

    def set_pump(self, on: bool, t: float) -> None:
        self._advance(t)
        self._pump_on = on
        self._update_flow(t)

    def pump_running(self) -> bool:
        """Whether the pump runs now, as a contact on its supply says (`pump.sense: sim`)."""
        return self._pump_on

    def set_recirculation_ok(self, ok: bool, t: float) -> None:
        self._advance(t)
        self._recirculation_ok = ok
        self._update_flow(t)

    def dough_in(
        self, grain_kg: float, grain_c: float, water_litres: float, water_c: float, t: float
    ) -> None:
        """Grain and water mix at once with what the tun holds (the first time: the tun at
        the room's temperature, and the hoses fill from the mash); later ones are infusions."""
        for name, value in (
            ("grain_kg", grain_kg),
            ("grain_c", grain_c),
            ("water_litres", water_litres),
            ("water_c", water_c),
        ):
            _in_range(name, value, DOUGH_IN_RANGES)
        self._advance(t)
        first = self._mash_capacity == 0.0
        held = self._tun_capacity if first else self._mash_capacity
        water = WATER_J_PER_LITRE_K * water_litres
        grain = GRAIN_J_PER_KG_K * grain_kg
        total = held + water + grain
        mixed = (held * self._mash_c + water * water_c + grain * grain_c) / total
        if first:
            if total <= self._hose_j_per_k:
                hoses = self._hose_j_per_k / WATER_J_PER_LITRE_K
                _require(
                    "water_litres",
                    water_litres,
                    False,
                    f"more than the hoses and coil hold ({hoses:g} L)",
                )
            total -= self._hose_j_per_k
            self._to_coil = deque([mixed] * len(self._to_coil))
            self._to_mash = deque([mixed] * len(self._to_mash))
        self._mash_capacity = total
        self._mash_c = mixed
        if self._sensor_rate == math.inf:
            self._sensor_c = mixed
        self._update_flow(t)

    def mash_temperature(self, t: float) -> float:
        self._advance(t)
        return self._sensor_c

    def coil_outlet_temperature(self, t: float) -> float:
        """With no flow the wort standing in the coil is at the HLT's water temperature."""
        water = self._hlt.water_temperature(self._advanced(t))
        if not self._flowing:
            return water
        return water - (water - self._to_coil[0]) * self._coil_passes

    def coil_watts(self, t: float) -> float:
        water = self._hlt.water_temperature(self._advanced(t))
        return self._coil_load_w_per_k * (water - self._to_coil[0]) if self._flowing else 0.0

    # ------------------------------------------------------------ the HLT side

    def set_heater(self, on: bool, t: float) -> None:
        self._hlt.set_heater(on, self._advanced(t))

    def set_element_ok(self, ok: bool, t: float) -> None:
        self._hlt.set_element_ok(ok, self._advanced(t))

    def set_heater2(self, on: bool, t: float) -> None:
        """The HLT's second element (`TwoElementPlant`): none unless its plant has one."""
        self._hlt.set_heater2(on, self._advanced(t))

    def set_element2_ok(self, ok: bool, t: float) -> None:
        """The HLT's second element open circuit (`ok` False) or whole again."""
        self._hlt.set_element2_ok(ok, self._advanced(t))

    def set_ambient(self, temp_c: float, t: float) -> None:
        """The room's temperature, for the HLT and the mash tun alike."""
        self._hlt.set_ambient(temp_c, self._advanced(t))
        self._ambient_c = temp_c

    def add_water(self, litres: float, temp_c: float, t: float) -> None:
        """Water poured into the HLT (the mash takes its water at `dough_in`)."""
        self._hlt.add_water(litres, temp_c, self._advanced(t))

    def temperature(self, t: float) -> float:
        return self._hlt.temperature(self._advanced(t))

    def water_temperature(self, t: float) -> float:
        return self._hlt.water_temperature(self._advanced(t))

    # ------------------------------------------------------------------ books

    @property
    def hose_litres(self) -> float:
        """The wort the hoses and coil hold: flow × both delays, in whole parcels."""
        return self._hose_j_per_k / WATER_J_PER_LITRE_K

    def energy_in(self, t: float) -> float:
        """Joules of the HLT's elements' heat that have reached its water up to `t`."""
        return self._hlt.energy_in(self._advanced(t))

    def heat_in_flight(self, t: float) -> float:
        """Joules the HLT's elements were switched to send by `t` that reach its water after
        it (`PhysicalPlant.heat_in_flight`)."""
        return self._hlt.heat_in_flight(self._advanced(t))

    def energy_lost(self, t: float) -> float:
        """Joules the HLT has lost to the room up to `t`."""
        return self._hlt.energy_lost(self._advanced(t))

    def energy_boiled(self, t: float) -> float:
        """Joules that have boiled the HLT's water off up to `t`."""
        return self._hlt.energy_boiled(self._advanced(t))

    def coil_energy(self, t: float) -> float:
        """Joules the coil has taken from the HLT up to `t` (negative: given back to it)."""
        return self._hlt.coil_energy(self._advanced(t))

    def mash_energy_lost(self, t: float) -> float:
        """Joules the mash tun has lost to the room up to `t`."""
        self._advance(t)
        return self._mash_lost

    def mash_heat(self, t: float) -> float:
        """Joules above 0 °C in the mash, its tun and the wort in the hoses and coil at `t`:
        it grows by the coil's heat, less the tun's losses, and by what a dough-in brings."""
        self._advance(t)
        flow = self._flow_w_per_k
        in_hoses = flow * STEP_S * (math.fsum(self._to_coil) + math.fsum(self._to_mash))
        # The parcel under way: the mash has sent ∫T_m and taken back the return's share;
        # the coil's heat so far is on its way (its inlet's in and out cancel).
        under_way = (
            flow * (self._parcel_integral - self._pumped_s * self._to_mash[0])
            + self._hlt.coil_energy(t)
            - self._coil_mark_j
        )
        return self._mash_capacity * self._mash_c + in_hoses + under_way

    # ------------------------------------------------------------ integration

    def _advanced(self, t: float) -> float:
        self._advance(t)
        return t

    def _update_flow(self, t: float) -> None:
        """Wort flows with the pump on, the recirculation ok and wort in the tun."""
        self._flowing = self._pump_on and self._recirculation_ok and self._mash_capacity > 0.0
        load = self._coil_load_w_per_k if self._flowing else 0.0
        self._hlt.set_coil_load(load, self._to_coil[0], t)

    def _advance(self, t: float) -> None:
        _validated_time(t, self._t)
        if self._flowing:
            while (end := self._t + (STEP_S - self._pumped_s)) <= t:
                self._mash_piece(end)
                self._next_parcel(end)
        self._mash_piece(t)

    def _mash_piece(self, t: float) -> None:
        """The mash and its sensor `t` − now seconds on, the return's temperature held."""
        duration = t - self._t
        if duration <= 0.0:
            return
        self._t = t
        ambient, ua = self._ambient_c, self._mash_ua
        if self._mash_capacity == 0.0:  # the empty tun, at the room's temperature
            self._mash_c = ambient
            start, rest, rate = ambient, ambient, 0.0
        else:
            start = self._mash_c
            conductance = ua + (self._flow_w_per_k if self._flowing else 0.0)
            rest = ambient
            if self._flowing:
                rest = (ua * ambient + self._flow_w_per_k * self._to_mash[0]) / conductance
            rate = conductance / self._mash_capacity
            self._mash_c, integral = _relax(start, rest, rate, duration)
            self._mash_lost += ua * (integral - ambient * duration)
            if self._flowing:
                self._parcel_integral += integral
                self._pumped_s += duration
        if self._sensor_rate == math.inf:
            self._sensor_c = self._mash_c
        else:
            self._sensor_c = lagged_sensor(
                self._sensor_c, rest, start - rest, rate, self._sensor_rate, duration
            )

    def _next_parcel(self, t: float) -> None:
        """A parcel's pumping is done: every parcel moves one place on at `t`."""
        carried = self._flow_w_per_k * STEP_S
        coil_j = self._hlt.coil_energy(t)
        inlet = self._to_coil.popleft()
        self._to_mash.popleft()  # it has entered the mash
        self._to_mash.append(inlet + (coil_j - self._coil_mark_j) / carried)
        self._to_coil.append(self._parcel_integral / STEP_S)
        self._coil_mark_j = coil_j
        self._parcel_integral = 0.0
        self._pumped_s = 0.0
        self._hlt.set_coil_load(self._coil_load_w_per_k, self._to_coil[0], t)


def make_herms_plant(kind: str, mash: Mapping[str, float], **params: float) -> HermsTun:
    """A HERMS plant by the HLT's kind (`foptd` or `physical`) and its parameters, with the
    mash side's (`MASH_RANGES`), e.g. from a scenario's `plant:` and its `mash:`."""
    hlt = make_plant(kind, **params)
    assert isinstance(hlt, PhysicalPlant | FoptdPlant)
    return HermsTun(hlt, **mash)
