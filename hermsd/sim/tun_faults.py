"""The family's days that judge the supervisor: fills the config does not know, and faults.

The config states each tun's litres and watts, but the water in it is anywhere from half to
twice that on a brew day; the supervisor must stay quiet through such a day and still catch
an element that dies and an SSR that shorts. Lid-off tuns evaporate in the simulator;
`extra_loss_w` adds a loss on top (a larger UA, so much more at 66 °C), as a draught, a
colder room or a wider pot would.
"""

from __future__ import annotations

import dataclasses

from hermsd.control.pid import PlantModel
from hermsd.sim.hlt import WATER_J_PER_LITRE_K
from hermsd.sim.scenario import Event, Scenario
from hermsd.sim.tuns import TunSpec

FAULT_AT = 5 * 3600.0
"""s: an hour into the hold, after the cold water has been recovered from."""
SETPOINT = 66.0
CONTACTOR = {"contactor": {"backend": "gpio", "line": 27}}
"""A series contactor the supervisor can open, as `scenarios/ssr-stuck-on.yaml` fits it."""


def normal_day(spec: TunSpec, fill: float = 1.0, extra_loss_w: float = 0.0) -> Scenario:
    """The tun's brew day with `fill` × its litres in it and `extra_loss_w` more loss at 66 °C.

    The wetted area, hence UA, grows with the fill as the family's UA does (volume^⅔).
    """
    day = dataclasses.replace(spec, litres=spec.litres * fill).brew_day()
    plant = dict(day.plant)
    plant["ua_w_per_k"] += extra_loss_w / (SETPOINT - spec.ambient_c)
    name = f"{spec.name} ×{fill:g}" + (f" +{extra_loss_w:g} W" if extra_loss_w else "")
    return dataclasses.replace(day, name=name, plant=plant)


def element_dies(spec: TunSpec, at: float = FAULT_AT) -> Scenario:
    """The element goes open circuit in the hold."""
    day = spec.brew_day()
    events = (*day.events, Event(at, "heater", "open"))
    return dataclasses.replace(day, name=f"{spec.name} element dies", events=events)


def ssr_shorts(spec: TunSpec, at: float = FAULT_AT) -> Scenario:
    """The SSR fails shorted in the hold; a contactor is fitted."""
    day = spec.brew_day()
    events = (*day.events, Event(at, "ssr", "stuck_on"))
    return dataclasses.replace(day, name=f"{spec.name} SSR shorts", config=CONTACTOR, events=events)


def measured(spec: TunSpec) -> PlantModel:
    """The tun as a step test would find it: K = P/(100·UA), τ = m·c/UA, θ = delay + lag."""
    ua = spec.ua_w_per_k
    return PlantModel(
        gain=spec.element_watts / (100.0 * ua),
        tau=spec.litres * WATER_J_PER_LITRE_K / ua,
        dead_time=spec.transport_delay_s + spec.sensor_lag_s,
        ambient=spec.ambient_c,
    )
