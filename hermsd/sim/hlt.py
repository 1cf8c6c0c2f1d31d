"""The Hot Liquor Tank as a plant, integrated exactly between input changes.

The SSR switches at arbitrary instants inside a control period, so the heater's power is
piecewise constant. Between two changes (an SSR edge reaching the water, a new ambient, water
poured in) every input is constant and the model has a closed form: the state jumps from
change to change with a few exponentials. The answer therefore does not depend on how often
anyone looks, and a six-hour brew day costs milliseconds.

One lumped model serves both views. The water (heat capacity C in J/K) receives the element's
power P (with a second element, `element2_watts`, the sum of those switched on) after a
delay and loses heat to the room through UA (W/K):

    C·dT_w/dt = P(t − delay) − UA·(T_w − T_amb)

and the sensor follows the water with its own time constant τ_s:

    τ_s·dT_s/dt = T_w − T_s          (or T_s = T_w when there is no sensor lag)

`FoptdPlant` is the first-order-plus-dead-time model identified on a real 90 L tun
(τ·dT/dt = −(T − T_amb) + K·u(t − θ), u in %): it is the same equation with UA = P/(100·K),
C = τ·UA, delay θ and no sensor lag. `PhysicalPlant` starts from litres, watts and UA
instead, and adds the sensor lag and, with the lid off, evaporation from the open surface
(see `evaporation_w`). Neither lets the water rise above its boiling point: heat beyond it
boils water off. The sensor's noise is not the tun's: the simulated LM92 adds it
(`hermsd.sim.world`), so `temperature()` is what a perfect sensor at the sensor's place reads.

Evaporation is not linear in the water's temperature, so it breaks the closed form. The
model replaces it by its tangent, taken afresh on a fixed grid of simulation time
(`RELINEARIZE_S`) and at every change of water or room; between two such instants the
equation is linear again and integrated exactly. The tangent is an input of the model like
the heater's power, so the answer still does not depend on how often anyone looks, and the
energy books still close to rounding. Against the nonlinear equation the tangent costs
about 2e-5 °C over half an hour of heating at 50 K/h, less while holding
(tests/test_simulator.py checks it against a fine Runge-Kutta run).

A HERMS coil in the water (`set_coil_load`, driven by `hermsd.sim.mash.HermsTun`) is one
more linear load of the same kind: wort entering at T_in through a coil of effectiveness ε
takes ε·ṁc·(T_w − T_in), constant inputs between two changes of its inlet, so it is folded
into G and T_rest like the evaporation's tangent and booked apart (`coil_energy`).
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import math
import typing
from collections import deque
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

WATER_J_PER_LITRE_K = 4186.0
"""Specific heat of water at 1 kg/L."""

BOILING_C = 100.0
"""The water boils here (sea level): it gets no hotter, and any surplus power leaves as steam."""

RELINEARIZE_S = 10.0
"""How often (simulation seconds) the evaporation's tangent is taken afresh."""

EVAPORATION_W_PER_M2_KPA = 89.0
"""Evaporative heat flux from an open water surface into still room air, per kPa of vapour
pressure difference: w = A·(p_w − p_a)·(0.089 + 0.0782·V)/Y kg/s (A m², p kPa, V air speed
m/s, Y latent heat kJ/kg), the Carrier correlation of the ASHRAE Handbook (HVAC
Applications, natatoriums); the heat flux w·Y is then (89 + 78.2·V) W per m² and kPa, and
V = 0 in a still room. Over a hot pot the moist air rises by itself, which a correlation
made for pools leaves out: the usual engineering table for open tanks in still 15.6 °C air
(Engineering ToolBox, "Heat loss from open water tanks": 860 Btu/(ft²·h) = 2.7 kW/m² at
150 °F) lies some 20 % above it at 66 °C, so this is a low estimate, not a high one."""

ROOM_RELATIVE_HUMIDITY = 0.5
"""The room air's relative humidity φ: p_a = φ·p_sat(T_amb)."""

_MMHG_KPA = 0.133322
_ANTOINE_A, _ANTOINE_B, _ANTOINE_C = 8.07131, 1730.63, 233.426
"""Antoine's constants for water, 1–100 °C, p in mmHg: log10 p = A − B/(C + T)."""


def saturation_kpa(temp_c: float) -> float:
    """Water's saturation vapour pressure (Antoine): 2.34 kPa at 20 °C, 101.3 kPa at 100 °C."""
    return _MMHG_KPA * math.pow(10.0, _ANTOINE_A - _ANTOINE_B / (_ANTOINE_C + temp_c))


def saturation_slope_kpa_per_k(temp_c: float) -> float:
    """d p_sat / dT, from the same Antoine equation."""
    return saturation_kpa(temp_c) * math.log(10.0) * _ANTOINE_B / (_ANTOINE_C + temp_c) ** 2


def pot_surface_m2(litres: float) -> float:
    """The open surface of `litres` in the usual brewing pot, as tall as it is wide:
    V = π·r²·2r, so r = (V/2π)^⅓ (50 L: a 40 cm pot, 0.126 m²)."""
    radius = math.pow(litres / 1000.0 / (2.0 * math.pi), 1.0 / 3.0)
    return math.pi * radius * radius


def evaporation_w(water_c: float, ambient_c: float, surface_m2: float) -> float:
    """Heat carried off by evaporation from an open surface: 89 W/(m²·kPa) ×
    (p_sat(T_w) − φ·p_sat(T_amb)) (see `EVAPORATION_W_PER_M2_KPA`). A 40 cm pot at 66 °C in a
    20 °C room loses about 0.28 kW this way; at 80 °C about 0.51 kW; at the boil 1.1 kW."""
    room_kpa = ROOM_RELATIVE_HUMIDITY * saturation_kpa(ambient_c)
    return EVAPORATION_W_PER_M2_KPA * surface_m2 * (saturation_kpa(water_c) - room_kpa)


class Plant(Protocol):
    """What the simulator needs of a tun: any object with these methods can be simulated
    (`hermsd simulate --plant FILE.py:FACTORY`, a factory called with no arguments).

    Times are seconds on the simulation's monotonic clock, starting at 0 and never
    decreasing from one call to the next. The heater's power and everything else are inputs
    that hold from the time given until they change; temperatures are in °C. The simulator
    adds the sensor's noise and the LM92's 0.0625 °C steps itself, so `temperature` is what
    a perfect sensor reads. To find the physical minimums (full power from the start, and
    from each event) the simulator runs full power on copies made with `copy.deepcopy`: a
    plant must survive it (plain attributes do; open files, locks or threads do not).
    """

    def set_heater(self, on: bool, t: float) -> None:
        """The element is switched on (full power) or off from `t` on."""
        ...

    def set_element_ok(self, ok: bool, t: float) -> None:
        """An open-circuit element (`ok` False) delivers nothing whatever the SSR does."""
        ...

    def set_ambient(self, temp_c: float, t: float) -> None:
        """The room's temperature from `t` on."""
        ...

    def add_water(self, litres: float, temp_c: float, t: float) -> None:
        """Pour water in at `t`; it mixes at once."""
        ...

    def temperature(self, t: float) -> float:
        """What the sensor reads at `t`, without noise."""
        ...

    def water_temperature(self, t: float) -> float:
        """The bulk water's temperature at `t`."""
        ...


@runtime_checkable
class TwoElementPlant(Plant, Protocol):
    """A tun with a second element on its own switch (a relay or contactor); the power that
    reaches the water is the sum of the elements switched on and whole."""

    def set_heater2(self, on: bool, t: float) -> None: ...

    def set_element2_ok(self, ok: bool, t: float) -> None: ...


PLANT_METHODS = (
    "set_heater",
    "set_element_ok",
    "set_ambient",
    "add_water",
    "temperature",
    "water_temperature",
)
"""The protocol's methods, for checking an object from outside before it is run."""

HERMS_METHODS = (
    "set_pump",
    "set_recirculation_ok",
    "dough_in",
    "mash_temperature",
    "coil_outlet_temperature",
    "coil_watts",
)
"""A HERMS plant's own methods (`hermsd.sim.mash.HermsPlant`): a plant has all or none."""


def _require(name: str, value: float, valid: bool, rule: str) -> None:
    if not valid:
        raise ValueError(f"{name} = {value!r} is invalid: it must be {rule}")


def _validated_time(t: float, last: float) -> None:
    if not last <= t < math.inf:
        if t < last:
            raise ValueError(
                f"time {t!r} s is before the plant's last time {last!r} s; "
                "time must not go backwards"
            )
        raise ValueError(f"time {t!r} s is invalid: it must be a finite number of seconds")


class _LumpedTun:
    """The engine both views share: state, delayed power, exact pieces, energy books.

    The start state (water and sensor at `start_c`, heater off, element ok) belongs to time
    `start_s`. Heat counts as in once it reaches the water, the delay after the element made
    it, so that heat in = stored + lost + boiled holds at every instant. Losses are linear in
    the water's temperature between two changes: G·(T_w − T_rest), with G = UA and
    T_rest = T_amb when the lid is on, and the evaporation's tangent folded in when it is off.
    """

    __slots__ = (
        "_ambient_c",
        "_boiling_c",
        "_capacity_per_litre",
        "_coil_inlet_c",
        "_coil_w_per_k",
        "_delay_s",
        "_element2_ok",
        "_element2_watts",
        "_element_ok",
        "_element_watts",
        "_energy_boiled",
        "_energy_coil",
        "_energy_in",
        "_energy_lost",
        "_heater2_on",
        "_heater_on",
        "_last_scheduled_w",
        "_litres",
        "_loss_rate",
        "_loss_w_per_k",
        "_next_tangent_s",
        "_open_surface_m2",
        "_pending",
        "_power_w",
        "_rest_c",
        "_room_rest_c",
        "_room_w_per_k",
        "_sensor_c",
        "_sensor_rate",
        "_t",
        "_ua",
        "_water_c",
    )

    def __init__(
        self,
        *,
        litres: float,
        capacity_per_litre: float,
        element_watts: float,
        ua_w_per_k: float,
        delay_s: float,
        sensor_lag_s: float,
        open_surface_m2: float,
        ambient_c: float,
        start_c: float,
        start_s: float,
        element2_watts: float = 0.0,
    ) -> None:
        self._litres = litres
        self._capacity_per_litre = capacity_per_litre
        self._element_watts = element_watts
        self._element2_watts = element2_watts
        self._ua = ua_w_per_k
        self._open_surface_m2 = open_surface_m2
        self._delay_s = delay_s
        self._sensor_rate = 1.0 / sensor_lag_s if sensor_lag_s > 0.0 else math.inf
        self._boiling_c = BOILING_C
        self._ambient_c = ambient_c
        self._water_c = start_c
        self._sensor_c = start_c
        self._t = start_s
        self._next_tangent_s = start_s + RELINEARIZE_S if open_surface_m2 > 0.0 else math.inf
        self._heater_on = False
        self._element_ok = True
        self._heater2_on = False
        self._element2_ok = True
        self._power_w = 0.0
        self._last_scheduled_w = 0.0
        # (time the power reaches the water, power in W); times never decrease.
        self._pending: deque[tuple[float, float]] = deque()
        self._energy_in = 0.0
        self._energy_lost = 0.0
        self._energy_boiled = 0.0
        self._energy_coil = 0.0
        self._coil_w_per_k = 0.0
        self._coil_inlet_c = 0.0
        self._room_w_per_k = ua_w_per_k
        self._room_rest_c = ambient_c
        self._loss_w_per_k = ua_w_per_k
        self._rest_c = ambient_c
        self._loss_rate = 0.0
        self._update_losses()

    # ----------------------------------------------------------------- inputs

    def set_heater(self, on: bool, t: float) -> None:
        self._advance(t)
        self._heater_on = on
        self._schedule_power(t)

    def set_element_ok(self, ok: bool, t: float) -> None:
        self._advance(t)
        self._element_ok = ok
        self._schedule_power(t)

    def set_heater2(self, on: bool, t: float) -> None:
        """The second element (on its relay or contactor) is switched on or off from `t` on."""
        self._advance(t)
        self._heater2_on = on
        self._schedule_power(t)

    def set_element2_ok(self, ok: bool, t: float) -> None:
        """The second element open circuit (`ok` False) or whole again."""
        self._advance(t)
        self._element2_ok = ok
        self._schedule_power(t)

    def set_ambient(self, temp_c: float, t: float) -> None:
        _require("temp_c", temp_c, math.isfinite(temp_c), "a finite temperature in °C")
        self._advance(t)
        self._ambient_c = temp_c
        self._update_losses()

    def add_water(self, litres: float, temp_c: float, t: float) -> None:
        _require("litres", litres, 0.0 < litres < math.inf, "a finite number > 0")
        _require(
            "temp_c",
            temp_c,
            0.0 <= temp_c <= BOILING_C,
            f"the temperature of liquid water, 0 to {BOILING_C:g} °C",
        )
        self._advance(t)
        total = self._litres + litres
        self._water_c = (self._litres * self._water_c + litres * temp_c) / total
        self._litres = total
        self._update_losses()
        if self._sensor_rate == math.inf:
            self._sensor_c = self._water_c

    def set_coil_load(self, w_per_k: float, inlet_c: float, t: float) -> None:
        """A heat exchanger's coil in the water takes `w_per_k`·(T_w − `inlet_c`) from `t`
        on (0 W/K: nothing flows through it); negative when the wort is the warmer."""
        _require("w_per_k", w_per_k, 0.0 <= w_per_k < math.inf, "a number of W/K ≥ 0")
        _require("inlet_c", inlet_c, math.isfinite(inlet_c), "a finite temperature in °C")
        self._advance(t)
        self._coil_w_per_k = w_per_k
        self._coil_inlet_c = inlet_c
        self._combine_losses()

    # ---------------------------------------------------------------- outputs

    @property
    def ambient_c(self) -> float:
        """The room's temperature now."""
        return self._ambient_c

    @property
    def time_s(self) -> float:
        """The time the state belongs to: the latest given to or asked of the plant."""
        return self._t

    @property
    def litres(self) -> float:
        """Water in the tun now."""
        return self._litres

    @property
    def gain_c_per_pct(self) -> float:
        """Steady-state rise per % of heater duty with the lid on: P/(100·UA); adding water
        leaves it."""
        return self._element_watts / (100.0 * self._ua)

    @property
    def time_constant_s(self) -> float:
        """The water's time constant C/G now; it grows with the water's mass."""
        return 1.0 / self._loss_rate

    def temperature(self, t: float) -> float:
        self._advance(t)
        return self._sensor_c

    def water_temperature(self, t: float) -> float:
        self._advance(t)
        return self._water_c

    def energy_in(self, t: float) -> float:
        """Joules of the element's heat that have reached the water up to `t`."""
        self._advance(t)
        return self._energy_in

    def heat_in_flight(self, t: float) -> float:
        """Joules the elements were switched to send by `t` that reach the water after it:
        the power as scheduled over the next transport delay (what an ideal controller that
        knows its own heat counts; bench/herms.py's fastest step)."""
        self._advance(t)
        joules, power, since = 0.0, self._power_w, t
        for arrives, then in self._pending:
            joules += power * (arrives - since)
            power, since = then, arrives
        return joules + power * (t + self._delay_s - since)

    def energy_lost(self, t: float) -> float:
        """Joules lost to the room (through the walls, and by evaporation) up to `t`."""
        self._advance(t)
        return self._energy_lost

    def coil_energy(self, t: float) -> float:
        """Joules a HERMS coil has taken from the water up to `t` (negative: given to it)."""
        self._advance(t)
        return self._energy_coil

    def energy_boiled(self, t: float) -> float:
        """Joules that went into boiling up to `t`."""
        self._advance(t)
        return self._energy_boiled

    # ------------------------------------------------------------ integration

    def _update_losses(self) -> None:
        """The room's G and T_rest for the water and room now: with an open surface, the
        evaporation's tangent at the water's temperature, E(T) ≈ E0 + E1·(T − T0)."""
        if self._open_surface_m2 > 0.0:
            water = self._water_c
            e0 = evaporation_w(water, self._ambient_c, self._open_surface_m2)
            e1 = (
                EVAPORATION_W_PER_M2_KPA * self._open_surface_m2 * saturation_slope_kpa_per_k(water)
            )
            self._room_w_per_k = self._ua + e1
            self._room_rest_c = (self._ua * self._ambient_c - e0 + e1 * water) / (self._ua + e1)
        else:
            self._room_w_per_k = self._ua
            self._room_rest_c = self._ambient_c
        self._combine_losses()

    def _combine_losses(self) -> None:
        """G and T_rest of the room and the coil together: two linear loads are one."""
        room, coil = self._room_w_per_k, self._coil_w_per_k
        self._loss_w_per_k = room + coil
        self._rest_c = (room * self._room_rest_c + coil * self._coil_inlet_c) / (room + coil)
        self._loss_rate = self._loss_w_per_k / (self._capacity_per_litre * self._litres)

    def _schedule_power(self, t: float) -> None:
        """Queue the element's new power for the moment it reaches the water."""
        power = self._element_watts if self._heater_on and self._element_ok else 0.0
        if self._heater2_on and self._element2_ok:
            power += self._element2_watts
        if power != self._last_scheduled_w:
            self._last_scheduled_w = power
            self._pending.append((t + self._delay_s, power))

    def _advance(self, t: float) -> None:
        _validated_time(t, self._t)
        pending = self._pending
        while True:
            arrives = pending[0][0] if pending else math.inf
            when = min(arrives, self._next_tangent_s)
            if when > t:
                break
            if when > self._t:
                self._integrate(when - self._t)
                self._t = when
            if arrives == when:
                self._power_w = pending.popleft()[1]
            else:
                self._next_tangent_s += RELINEARIZE_S
                self._update_losses()
        if t > self._t:
            self._integrate(t - self._t)
            self._t = t

    def _integrate(self, duration: float) -> None:
        """Move the state `duration` seconds on under constant inputs."""
        boiling = self._boiling_c
        heading_for = self._rest_c + self._power_w / self._loss_w_per_k
        if heading_for <= boiling:
            self._free_piece(duration, heading_for)
            return
        water = self._water_c
        if water < boiling:
            to_boil = math.log((heading_for - water) / (heading_for - boiling)) / self._loss_rate
            if to_boil >= duration:
                self._free_piece(duration, heading_for)
                return
            self._free_piece(to_boil, heading_for)
            self._water_c = boiling
            duration -= to_boil
        self._boiling_piece(duration)

    def _free_piece(self, duration: float, heading_for: float) -> None:
        """Water relaxes exponentially towards `heading_for`; the sensor chases it."""
        rate = self._loss_rate
        offset = self._water_c - heading_for
        water_decay_m1 = math.expm1(-rate * duration)  # e^(−t/τ_w) − 1, exact for small t
        water_integral = heading_for * duration - offset * water_decay_m1 / rate  # ∫T_w dt
        self._energy_in += self._power_w * duration
        self._energy_lost += self._room_w_per_k * (water_integral - self._room_rest_c * duration)
        self._energy_coil += self._coil_w_per_k * (water_integral - self._coil_inlet_c * duration)
        self._water_c += offset * water_decay_m1
        if self._sensor_rate == math.inf:
            self._sensor_c = self._water_c
        else:
            self._sensor_c = lagged_sensor(
                self._sensor_c, heading_for, offset, rate, self._sensor_rate, duration
            )

    def _boiling_piece(self, duration: float) -> None:
        """Water held at the boil: losses at the boiling point, the rest goes to steam."""
        boiling = self._boiling_c
        room_w = self._room_w_per_k * (boiling - self._room_rest_c)
        coil_w = self._coil_w_per_k * (boiling - self._coil_inlet_c)
        self._energy_in += self._power_w * duration
        self._energy_lost += room_w * duration
        self._energy_coil += coil_w * duration
        self._energy_boiled += (self._power_w - room_w - coil_w) * duration
        if self._sensor_rate == math.inf:
            self._sensor_c = boiling
        else:
            self._sensor_c = boiling + (self._sensor_c - boiling) * math.exp(
                -self._sensor_rate * duration
            )


def lagged_sensor(
    sensor_c: float,
    heading_c: float,
    offset: float,
    rate: float,
    sensor_rate: float,
    duration: float,
) -> float:
    """A first-order sensor (rate 1/τ_s, finite) after `duration` s on a body whose
    temperature is heading_c + offset·e^(−rate·t): the sensor's own decay towards heading_c
    plus its response to the body's exponential, b·(e^(−a·t) − e^(−b·t))/(b − a), written so
    that it stays exact when the two time constants are equal or close."""
    gap_t = abs(sensor_rate - rate) * duration
    spread = -math.expm1(-gap_t) / gap_t if gap_t > 0.0 else 1.0
    follow = sensor_rate * duration * math.exp(-min(rate, sensor_rate) * duration) * spread
    return heading_c + (sensor_c - heading_c) * math.exp(-sensor_rate * duration) + offset * follow


def _require_element2(watts: float) -> None:
    rule = "a number ≥ 0 (0: no second element)"
    _require("element2_watts", watts, 0.0 <= watts < math.inf, rule)


def _validated_start(start_c: float) -> float:
    _require(
        "start_c",
        start_c,
        0.0 <= start_c <= BOILING_C,
        f"the temperature of liquid water, 0 to {BOILING_C:g} °C",
    )
    return start_c


class FoptdPlant(_LumpedTun):
    """First order plus dead time: τ·dT/dt = −(T − T_amb) + K·u(t − θ), u = 100 % when on.

    Defaults are the tun identified by step tests (90 L, 3 kW): K = 1.689 °C/%,
    τ = 14961 s, θ = 115 s. The model is linear up to the boil, where the water stops and
    the surplus boils off. Water added scales τ with the mass and leaves K. The element's
    watts only set the energy books (UA = P/(100·K)).
    """

    __slots__ = ()

    def __init__(
        self,
        *,
        gain_c_per_pct: float = 1.689,
        tau_s: float = 14961.0,
        dead_time_s: float = 115.0,
        ambient_c: float = 20.0,
        start_c: float | None = None,
        start_s: float = 0.0,
        litres: float = 90.0,
        element_watts: float = 3000.0,
        element2_watts: float = 0.0,
    ) -> None:
        _require("gain_c_per_pct", gain_c_per_pct, 0.0 < gain_c_per_pct < math.inf, "a number > 0")
        _require("tau_s", tau_s, 0.0 < tau_s < math.inf, "a finite number > 0")
        _require("dead_time_s", dead_time_s, 0.0 <= dead_time_s < math.inf, "a number ≥ 0")
        _require("ambient_c", ambient_c, math.isfinite(ambient_c), "a finite temperature")
        start = _validated_start(ambient_c if start_c is None else start_c)
        _require("litres", litres, 0.0 < litres < math.inf, "a finite number > 0")
        _require("element_watts", element_watts, 0.0 < element_watts < math.inf, "a number > 0")
        _require("start_s", start_s, math.isfinite(start_s), "a finite time in seconds")
        _require_element2(element2_watts)
        ua = element_watts / (100.0 * gain_c_per_pct)
        super().__init__(
            litres=litres,
            capacity_per_litre=tau_s * ua / litres,
            element_watts=element_watts,
            ua_w_per_k=ua,
            delay_s=dead_time_s,
            sensor_lag_s=0.0,
            open_surface_m2=0.0,
            ambient_c=ambient_c,
            start_c=start,
            start_s=start_s,
            element2_watts=element2_watts,
        )


class PhysicalPlant(_LumpedTun):
    """Water, element, losses, a transport delay, a lagging sensor, an open lid, the boil.

    `ua_w_per_k` is the loss through walls, bottom and lid (W per K above the room); a
    cooling measurement gives it as UA = C·(dT/dt)/(T − T_amb) with C = 4186 J/(L·K) × litres,
    taken with the lid on. The default puts the steady-state gain at the identified
    1.689 °C/%. The transport delay is the time the element's heat takes to reach the water
    around the sensor; `sensor_lag_s` is the sensor's (or its well's) own first-order lag.
    With `lid` False the open surface (`surface_m2`, by default that of a pot as tall as it
    is wide holding the starting litres) also loses heat by evaporation (`evaporation_w`).
    At the boil the water is held at 100 °C and the surplus power is booked as boiled. The
    water that evaporates or boils is not taken out of the tun (0.4 L/h from a 40 cm pot at
    66 °C: a brew day changes the mass by a few %).
    """

    __slots__ = ()

    def __init__(
        self,
        *,
        litres: float = 90.0,
        element_watts: float = 3000.0,
        ua_w_per_k: float = 3000.0 / 168.9,
        transport_delay_s: float = 60.0,
        sensor_lag_s: float = 10.0,
        lid: bool = True,
        surface_m2: float | None = None,
        ambient_c: float = 20.0,
        start_c: float | None = None,
        start_s: float = 0.0,
        element2_watts: float = 0.0,
    ) -> None:
        _require("litres", litres, 0.0 < litres < math.inf, "a finite number > 0")
        _require("element_watts", element_watts, 0.0 < element_watts < math.inf, "a number > 0")
        _require_element2(element2_watts)
        _require("ua_w_per_k", ua_w_per_k, 0.0 < ua_w_per_k < math.inf, "a number > 0")
        _require(
            "transport_delay_s",
            transport_delay_s,
            0.0 <= transport_delay_s < math.inf,
            "a number ≥ 0",
        )
        _require("sensor_lag_s", sensor_lag_s, 0.0 <= sensor_lag_s < math.inf, "a number ≥ 0")
        _require("lid", lid, isinstance(lid, bool), "on (True) or off (False)")
        surface = pot_surface_m2(litres) if surface_m2 is None else surface_m2
        _require("surface_m2", surface, 0.0 < surface < math.inf, "a number of m² > 0")
        _require("ambient_c", ambient_c, math.isfinite(ambient_c), "a finite temperature")
        start = _validated_start(ambient_c if start_c is None else start_c)
        _require("start_s", start_s, math.isfinite(start_s), "a finite time in seconds")
        super().__init__(
            litres=litres,
            capacity_per_litre=WATER_J_PER_LITRE_K,
            element_watts=element_watts,
            ua_w_per_k=ua_w_per_k,
            delay_s=transport_delay_s,
            sensor_lag_s=sensor_lag_s,
            open_surface_m2=0.0 if lid else surface,
            ambient_c=ambient_c,
            start_c=start,
            start_s=start_s,
            element2_watts=element2_watts,
        )


PLANT_KINDS: dict[str, type[FoptdPlant] | type[PhysicalPlant]] = {
    "foptd": FoptdPlant,
    "physical": PhysicalPlant,
}


def make_plant(kind: str, **params: Any) -> Plant:
    """Build a plant by name (`foptd` or `physical`), e.g. from a scenario file."""
    try:
        plant_class = PLANT_KINDS[kind]
    except KeyError:
        known = ", ".join(sorted(PLANT_KINDS))
        raise ValueError(f"plant kind {kind!r} is unknown: it must be one of {known}") from None
    return plant_class(**params)


def plant_parameters(kind: str) -> tuple[str, ...]:
    """The keyword parameters a plant kind takes (what a scenario's `plant:` may set)."""
    return tuple(inspect.signature(PLANT_KINDS[kind]).parameters)


class PlantLoadError(ValueError):
    """An outside plant that cannot be loaded or lacks the protocol; the message says which."""


class PlantFailed(RuntimeError):
    """An outside plant that raised, or read what no sensor reads, during a run: the daemon
    stops (heater off) and the message names the plant, the call and what came of it."""


_READINGS = {
    "temperature": "°C",
    "water_temperature": "°C",
    "mash_temperature": "°C",
    "coil_outlet_temperature": "°C",
    "coil_watts": "W",
}


class _CheckedPlant:
    """An outside plant whose every call either gives what the protocol promises or raises
    PlantFailed naming it: a NaN, an infinity or a text read as a temperature would otherwise
    surface as an error far from its cause, or as an Infinity in the summary."""

    def __init__(self, plant: object, reference: str) -> None:
        self._plant = plant
        self._reference = reference

    def __getattr__(self, name: str) -> Any:
        if name.startswith("_"):  # copy.deepcopy's probes: the plant's own, not delegated
            raise AttributeError(name)
        attribute = getattr(self._plant, name)
        if not callable(attribute):
            return attribute

        def checked(*args: Any) -> Any:
            call = f"plant {self._reference!r}: {name}({', '.join(map(repr, args))})"
            try:
                result = attribute(*args)
            except (Exception, SystemExit) as error:
                raise PlantFailed(f"{call} raised {type(error).__name__}: {error}") from None
            if name not in _READINGS:
                return result
            real = isinstance(result, int | float) and not isinstance(result, bool)
            if not real or not math.isfinite(result):
                raise PlantFailed(
                    f"{call} returned {result!r}; expected a finite number of {_READINGS[name]}"
                )
            return float(result)

        return checked


def load_plant(reference: str) -> Plant:
    """The plant that `FILE.py:FACTORY` or `package.module:FACTORY` makes, called with no
    arguments, checked against the protocol (`Plant`; a HERMS plant's methods all or none)."""
    where, _, factory_name = reference.rpartition(":")
    if not where or not factory_name:
        raise PlantLoadError(
            f"plant {reference!r}: expected FILE.py:FACTORY or package.module:FACTORY"
        )
    try:
        if where.endswith(".py") or "/" in where:
            path = Path(where)
            if not path.is_file():
                raise PlantLoadError(f"plant {reference!r}: no file {where}")
            spec = importlib.util.spec_from_file_location(f"hermsd_plant_{path.stem}", path)
            if spec is None or spec.loader is None:
                raise PlantLoadError(f"plant {reference!r}: {where} is not a Python file")
            module = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(module)
        else:
            module = importlib.import_module(where)
    except PlantLoadError:
        raise
    except (Exception, SystemExit) as error:  # the module failed to import: say how, in a line
        raise PlantLoadError(
            f"plant {reference!r}: cannot load {where}: {type(error).__name__}: {error}"
        ) from None
    factory = getattr(module, factory_name, None)
    if not callable(factory):
        raise PlantLoadError(f"plant {reference!r}: {where} has no function {factory_name}")
    try:
        plant = factory()
    except (Exception, SystemExit) as error:
        raise PlantLoadError(
            f"plant {reference!r}: {factory_name}() failed: {type(error).__name__}: {error}"
        ) from None
    missing = [name for name in PLANT_METHODS if not callable(getattr(plant, name, None))]
    if missing:
        raise PlantLoadError(
            f"plant {reference!r}: the {type(plant).__name__} that {factory_name}() made lacks "
            f"{', '.join(missing)} (the plant protocol: hermsd.sim.hlt.Plant)"
        )
    herms = [name for name in HERMS_METHODS if callable(getattr(plant, name, None))]
    if herms and len(herms) < len(HERMS_METHODS):
        lacking = ", ".join(name for name in HERMS_METHODS if name not in herms)
        raise PlantLoadError(
            f"plant {reference!r}: the {type(plant).__name__} that {factory_name}() made has "
            f"{herms[0]} but lacks {lacking} (the HERMS plant protocol: "
            "hermsd.sim.mash.HermsPlant)"
        )
    checked: Plant = typing.cast(Plant, _CheckedPlant(plant, reference))
    return checked
