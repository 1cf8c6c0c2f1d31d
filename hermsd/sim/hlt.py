"""The Hot Liquid Tun as a plant, integrated exactly between input changes.

The SSR switches at arbitrary instants inside a control period, so the heater's power is
piecewise constant. Between two changes (an SSR edge reaching the water, a new ambient, water
poured in) every input is constant and the model has a closed form: the state jumps from
change to change with a few exponentials. The answer therefore does not depend on how often
anyone looks, and a six-hour brew day costs milliseconds.

One lumped model serves both views. The water (heat capacity C in J/K) receives the element's
power P after a delay and loses heat to the room through UA (W/K):

    C·dT_w/dt = P(t − delay) − UA·(T_w − T_amb)

and the sensor follows the water with its own time constant τ_s:

    τ_s·dT_s/dt = T_w − T_s          (or T_s = T_w when there is no sensor lag)

`FoptdPlant` is the first-order-plus-dead-time model identified on a real 90 L tun
(τ·dT/dt = −(T − T_amb) + K·u(t − θ), u in %): it is the same equation with UA = P/(100·K),
C = τ·UA, delay θ, no sensor lag and no boiling. `PhysicalPlant` starts from litres, watts and
UA instead, and adds the sensor lag, the boiling cap and optional sensor noise.
"""

from __future__ import annotations

import math
import random
from collections import deque
from typing import Any, Protocol

WATER_J_PER_LITRE_K = 4186.0
"""Specific heat of water at 1 kg/L."""

BOILING_C = 100.0
"""The water boils here: it gets no hotter, and any surplus power leaves as steam."""


class Plant(Protocol):
    """What a simulation needs of the tun. Times are seconds on the simulation's monotonic
    scale and must never decrease from one call to the next."""

    @property
    def litres(self) -> float:
        """Water in the tun now."""
        ...

    def set_heater(self, on: bool, t: float) -> None:
        """The SSR's state from `t` on."""
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
        """What the sensor reads at `t`."""
        ...

    def water_temperature(self, t: float) -> float:
        """The bulk water's temperature at `t`."""
        ...

    def energy_in(self, t: float) -> float:
        """Joules of the element's heat that have reached the water up to `t`."""
        ...

    def energy_lost(self, t: float) -> float:
        """Joules lost to the room up to `t`."""
        ...

    def energy_boiled(self, t: float) -> float:
        """Joules that went into boiling up to `t`."""
        ...


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
    it, so that heat in = stored + lost + boiled holds at every instant.
    """

    __slots__ = (
        "_ambient_c",
        "_boiling_c",
        "_capacity_per_litre",
        "_delay_s",
        "_element_ok",
        "_element_watts",
        "_energy_boiled",
        "_energy_in",
        "_energy_lost",
        "_heater_on",
        "_last_scheduled_w",
        "_litres",
        "_loss_rate",
        "_noise_c",
        "_pending",
        "_power_w",
        "_rate_gap",
        "_rng",
        "_sensor_c",
        "_sensor_rate",
        "_slower_rate",
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
        boiling_c: float,
        ambient_c: float,
        start_c: float,
        start_s: float,
        noise_c: float,
        seed: int,
    ) -> None:
        self._litres = litres
        self._capacity_per_litre = capacity_per_litre
        self._element_watts = element_watts
        self._ua = ua_w_per_k
        self._delay_s = delay_s
        self._sensor_rate = 1.0 / sensor_lag_s if sensor_lag_s > 0.0 else math.inf
        self._boiling_c = boiling_c
        self._ambient_c = ambient_c
        self._water_c = start_c
        self._sensor_c = start_c
        self._noise_c = noise_c
        self._rng = random.Random(seed)
        self._t = start_s
        self._heater_on = False
        self._element_ok = True
        self._power_w = 0.0
        self._last_scheduled_w = 0.0
        # (time the power reaches the water, power in W); times never decrease.
        self._pending: deque[tuple[float, float]] = deque()
        self._energy_in = 0.0
        self._energy_lost = 0.0
        self._energy_boiled = 0.0
        self._loss_rate = 0.0
        self._slower_rate = 0.0
        self._rate_gap = 0.0
        self._update_rates()

    # ----------------------------------------------------------------- inputs

    def set_heater(self, on: bool, t: float) -> None:
        self._advance(t)
        self._heater_on = on
        self._schedule_power(t)

    def set_element_ok(self, ok: bool, t: float) -> None:
        self._advance(t)
        self._element_ok = ok
        self._schedule_power(t)

    def set_ambient(self, temp_c: float, t: float) -> None:
        _require("temp_c", temp_c, math.isfinite(temp_c), "a finite temperature in °C")
        self._advance(t)
        self._ambient_c = temp_c

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
        self._update_rates()
        if self._sensor_rate == math.inf:
            self._sensor_c = self._water_c

    # ---------------------------------------------------------------- outputs

    @property
    def litres(self) -> float:
        return self._litres

    @property
    def gain_c_per_pct(self) -> float:
        """Steady-state rise per % of heater duty: P/(100·UA); adding water leaves it."""
        return self._element_watts / (100.0 * self._ua)

    @property
    def time_constant_s(self) -> float:
        """The water's time constant C/UA now; it grows with the water's mass."""
        return 1.0 / self._loss_rate

    def temperature(self, t: float) -> float:
        self._advance(t)
        if self._noise_c > 0.0:
            return self._sensor_c + self._rng.gauss(0.0, self._noise_c)
        return self._sensor_c

    def water_temperature(self, t: float) -> float:
        self._advance(t)
        return self._water_c

    def energy_in(self, t: float) -> float:
        self._advance(t)
        return self._energy_in

    def energy_lost(self, t: float) -> float:
        self._advance(t)
        return self._energy_lost

    def energy_boiled(self, t: float) -> float:
        self._advance(t)
        return self._energy_boiled

    # ------------------------------------------------------------ integration

    def _update_rates(self) -> None:
        self._loss_rate = self._ua / (self._capacity_per_litre * self._litres)
        self._slower_rate = min(self._loss_rate, self._sensor_rate)
        self._rate_gap = abs(self._sensor_rate - self._loss_rate)

    def _schedule_power(self, t: float) -> None:
        """Queue the element's new power for the moment it reaches the water."""
        power = self._element_watts if self._heater_on and self._element_ok else 0.0
        if power != self._last_scheduled_w:
            self._last_scheduled_w = power
            self._pending.append((t + self._delay_s, power))

    def _advance(self, t: float) -> None:
        _validated_time(t, self._t)
        pending = self._pending
        while pending and pending[0][0] <= t:
            when, power = pending.popleft()
            if when > self._t:
                self._integrate(when - self._t)
                self._t = when
            self._power_w = power
        if t > self._t:
            self._integrate(t - self._t)
            self._t = t

    def _integrate(self, duration: float) -> None:
        """Move the state `duration` seconds on under constant inputs."""
        boiling = self._boiling_c
        heading_for = self._ambient_c + self._power_w / self._ua
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
        power = self._power_w
        rate = self._loss_rate
        offset = self._water_c - heading_for
        water_decay_m1 = math.expm1(-rate * duration)  # e^(−t/τ_w) − 1, exact for small t
        self._energy_in += power * duration
        self._energy_lost += self._ua * (
            (heading_for - self._ambient_c) * duration - offset * water_decay_m1 / rate
        )
        self._water_c += offset * water_decay_m1
        sensor_rate = self._sensor_rate
        if sensor_rate == math.inf:
            self._sensor_c = self._water_c
            return
        # The sensor's response to the water's exponential, b·(e^(−a·t) − e^(−b·t))/(b − a),
        # written so that it stays exact when the two time constants are equal or close.
        gap_t = self._rate_gap * duration
        spread = -math.expm1(-gap_t) / gap_t if gap_t > 0.0 else 1.0
        follow = sensor_rate * duration * math.exp(-self._slower_rate * duration) * spread
        self._sensor_c = (
            heading_for
            + (self._sensor_c - heading_for) * math.exp(-sensor_rate * duration)
            + offset * follow
        )

    def _boiling_piece(self, duration: float) -> None:
        """Water held at the boil: losses at the boiling point, the rest goes to steam."""
        boiling = self._boiling_c
        loss_w = self._ua * (boiling - self._ambient_c)
        self._energy_in += self._power_w * duration
        self._energy_lost += loss_w * duration
        self._energy_boiled += (self._power_w - loss_w) * duration
        if self._sensor_rate == math.inf:
            self._sensor_c = boiling
        else:
            self._sensor_c = boiling + (self._sensor_c - boiling) * math.exp(
                -self._sensor_rate * duration
            )


class FoptdPlant(_LumpedTun):
    """First order plus dead time: τ·dT/dt = −(T − T_amb) + K·u(t − θ), u = 100 % when on.

    Defaults are the tun identified by step tests (90 L, 3 kW): K = 1.689 °C/%,
    τ = 14961 s, θ = 115 s. The model is linear: it does not boil. Water added scales τ with
    the mass and leaves K. The element's watts only set the energy books (UA = P/(100·K)).
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
        noise_c: float = 0.0,
        seed: int = 0,
    ) -> None:
        _require("gain_c_per_pct", gain_c_per_pct, 0.0 < gain_c_per_pct < math.inf, "a number > 0")
        _require("tau_s", tau_s, 0.0 < tau_s < math.inf, "a finite number > 0")
        _require("dead_time_s", dead_time_s, 0.0 <= dead_time_s < math.inf, "a number ≥ 0")
        _require("ambient_c", ambient_c, math.isfinite(ambient_c), "a finite temperature")
        start = ambient_c if start_c is None else start_c
        _require("start_c", start, math.isfinite(start), "a finite temperature")
        _require("litres", litres, 0.0 < litres < math.inf, "a finite number > 0")
        _require("element_watts", element_watts, 0.0 < element_watts < math.inf, "a number > 0")
        _require("start_s", start_s, math.isfinite(start_s), "a finite time in seconds")
        _require("noise_c", noise_c, 0.0 <= noise_c < math.inf, "a number ≥ 0")
        ua = element_watts / (100.0 * gain_c_per_pct)
        super().__init__(
            litres=litres,
            capacity_per_litre=tau_s * ua / litres,
            element_watts=element_watts,
            ua_w_per_k=ua,
            delay_s=dead_time_s,
            sensor_lag_s=0.0,
            boiling_c=math.inf,
            ambient_c=ambient_c,
            start_c=start,
            start_s=start_s,
            noise_c=noise_c,
            seed=seed,
        )


class PhysicalPlant(_LumpedTun):
    """Water, element, losses, a transport delay, a lagging sensor, and the boil.

    The default UA puts the steady-state gain at the identified 1.689 °C/%. The transport
    delay is the time the element's heat takes to reach the water around the sensor. At the
    boil the water is held at 100 °C and the surplus power is booked as boiled; the
    evaporated mass is not removed. Noise (standard deviation `noise_c`) is added to
    `temperature()` only, from a generator seeded with `seed`.
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
        ambient_c: float = 20.0,
        start_c: float | None = None,
        start_s: float = 0.0,
        noise_c: float = 0.0,
        seed: int = 0,
    ) -> None:
        _require("litres", litres, 0.0 < litres < math.inf, "a finite number > 0")
        _require("element_watts", element_watts, 0.0 < element_watts < math.inf, "a number > 0")
        _require("ua_w_per_k", ua_w_per_k, 0.0 < ua_w_per_k < math.inf, "a number > 0")
        _require(
            "transport_delay_s",
            transport_delay_s,
            0.0 <= transport_delay_s < math.inf,
            "a number ≥ 0",
        )
        _require("sensor_lag_s", sensor_lag_s, 0.0 <= sensor_lag_s < math.inf, "a number ≥ 0")
        _require("ambient_c", ambient_c, math.isfinite(ambient_c), "a finite temperature")
        start = ambient_c if start_c is None else start_c
        _require(
            "start_c",
            start,
            0.0 <= start <= BOILING_C,
            f"the temperature of liquid water, 0 to {BOILING_C:g} °C",
        )
        _require("start_s", start_s, math.isfinite(start_s), "a finite time in seconds")
        _require("noise_c", noise_c, 0.0 <= noise_c < math.inf, "a number ≥ 0")
        super().__init__(
            litres=litres,
            capacity_per_litre=WATER_J_PER_LITRE_K,
            element_watts=element_watts,
            ua_w_per_k=ua_w_per_k,
            delay_s=transport_delay_s,
            sensor_lag_s=sensor_lag_s,
            boiling_c=BOILING_C,
            ambient_c=ambient_c,
            start_c=start,
            start_s=start_s,
            noise_c=noise_c,
            seed=seed,
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
