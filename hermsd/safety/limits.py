"""The safety limits: every threshold the supervisor judges by, derived from the tun (litres,
watts, dead time) or measured, each with where it came from."""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass, field
from typing import Any, Protocol

WATER_HEAT_CAPACITY = 4186.0  # J/(kg·K); a litre of water is taken as 1 kg


FULL_POWER = 80.0  # % of full power at or above which the element is expected to heat visibly


SUDDEN_DROP = 0.25  # °C: least fall in a window, faster than losses allow, that is water added


AUTO_KINDS = ("sensor_fault", "stale_reading", "over_temperature", "loop_stall")


LATCHED_KINDS = (
    "heater_not_heating",
    "ssr_stuck_on",
    "dry_fire",
    "sensor_stuck",
    "controller_fault",
)


# The envelope every limit holds for before the tun is measured (see `SafetyLimits.derive`).
FILL_RANGE = 2.0
"""The water in the tun is anywhere from half to twice the configured litres."""


MAINS_POWER_MARGIN = 1.21
"""An element draws (1.1)² = 1.21× its rating at +10 % mains (253 V on a 230 V element)."""


MAINS_LOW = 0.81
"""… and (0.9)² = 0.81× at −10 % mains."""


DEAD_TIME_MAX = 300.0
"""s: transport from element to sensor plus a thermowell's lag, the far end of real tuns."""


SENSOR_LAG_MAX = 150.0
"""s: a thermowell's own first-order lag, the far end; heat keeps showing this much longer."""


COLDEST_ROOM = 5.0
"""°C: a garage in winter; losses are bounded as if the room were this cold."""


WARMEST_ROOM = 40.0
"""°C: a brewery in summer sun; water colder than this may warm from the room unheated."""


CREEP_WATCHES = (900.0, 3600.0)
"""s: the longer watches for heat nothing switched on. With nothing delivered, a rise of
`ssr_max_rise` (0.5 °C) in W is a heater left on that outpaces the losses by 0.5/W: 2 °C/h
in 900 s, 0.5 °C/h in an hour. One that outpaces them by less at the setpoint (net rate r)
settles where the losses catch up, r·τ above it, τ the time constant of the losses there:
the 150 L open pot's shorted 3.5 kW contactor settled 4 °C over with ~1 kW net at the
setpoint, so its losses grow ~250 W/K there, τ = 150·4186/250 ≈ 2500 s; at the hour's 0.5 °C/h
that pot ends at most 0.35 °C over, a lidded 90 L tun (τ = 14961 s) 2.1 °C. The 900 s watch
catches a faster creep sooner (the 300 s one alone, 6 °C/h, missed that contactor: 0.3 °C
per 5 min with every output off, 4 °C over the setpoint in an hour). Water colder than the
warmest room may warm from it unheated: that rise is allowed on top."""


QUICK_WATCH = 120.0
"""s: the SSR watch's quicker twin, tolerating `ssr_max_rise` scaled to it (the same rate,
never under twice `NOISE_FLOOR`): a short on a hold's small duty rises several times faster
than that duty's heat can explain, and stands out over 120 s sooner (a 5.5 kW element in
30 L holding on 8 %: 30 s after its heat first shows, where over 300 s 71 s;
tests/test_hot_water.py, docs/heat-balance.md "A shorted SSR")."""


OPEN_POT_UA_PER_L23 = 2.0 * (3000.0 / 168.9) / 90.0 ** (2.0 / 3.0)
"""W/(K·L^⅔): twice the identified 90 L tun's UA per wetted area (an open, uninsulated pot)."""


OPEN_POT_EVAPORATION_W = 1000.0
"""W from an open 90 L pot at 66 °C in still air (0.5–1 kW measured); scaled by area."""


EVAPORATION_REFERENCE_C = 66.0


NOISE_FLOOR = 0.1
"""°C: a rise smaller than this (1.6 LSB of the LM92) is not told from noise and LSB flips."""


MODEL_MARGIN = 1.5
"""A measured gain, time constant or dead time is trusted to within this factor."""


HOLD_SPAN_S = 1800.0
"""s of steady water whose mean duty is taken as the day's hold (its losses there)."""


HOLD_BAND = 0.5
"""°C the PV may span over HOLD_SPAN_S and still be a hold."""


HOLD_DUTY_SPREAD = 2.0
"""% of output the duty's means at a hold's two ends may differ by (or a fifth of them)."""


HOLD_ENDS_S = 300.0
"""s at each end of the span whose mean PVs must agree within the noise: the water neither
gained nor lost heat to speak of, so the duty balanced the losses."""


DRY_FIRE_WINDOWS = 3
"""Consecutive windows a dry fire must show in (see `Supervisor._check_dry_fire`)."""


class MeasuredTun(Protocol):
    """The tun as measured (a FOPTD model, e.g. `pid.PlantModel`): °C/%, s, s, °C."""

    @property
    def gain(self) -> float: ...
    @property
    def tau(self) -> float: ...
    @property
    def dead_time(self) -> float: ...
    @property
    def ambient(self) -> float: ...


HEAT_UP_ORIGIN = "measured in the day's heat-up"


@dataclass(frozen=True, slots=True)
class _Measured:
    """What a measured full-power rate and dead time set: each trusted to within ×1.5."""

    weakest_rise: float
    fastest_rise: float
    rise_per_joule: float
    dead: float
    heat_memory: float

    @classmethod
    def of(cls, rate: float, dead_time: float, limit: float, element_watts: float) -> _Measured:
        """From the tun's `rate` (°C/s at 100 %) and `dead_time`, under the power `limit`
        (share of full power)."""
        # θ·1.5 (and a minute of lag's tail), but never longer than the envelope the
        # unmeasured limits already trust unless θ itself lies beyond it, and never past
        # twice that envelope: a wild (or damaged) θ of half an hour would let a shorted
        # SSR heat the water for as long before it is judged.
        theta = min(dead_time, 2.0 * DEAD_TIME_MAX)
        return cls(
            weakest_rise=FULL_POWER / 100.0 * limit * MAINS_LOW * rate / MODEL_MARGIN,
            fastest_rise=MAINS_POWER_MARGIN * rate * MODEL_MARGIN,
            rise_per_joule=MODEL_MARGIN * rate / element_watts,
            dead=max(60.0, min(MODEL_MARGIN * theta, max(DEAD_TIME_MAX, theta))),
            heat_memory=min(
                MODEL_MARGIN * theta + 60.0, max(DEAD_TIME_MAX, theta) + SENSOR_LAG_MAX
            ),
        )


def vapour_pressure_ratio(celsius: float) -> float:
    """Saturation pressure of water at `celsius` over that at 66 °C (Magnus; within 1.5 %
    of the steam tables from 20 to 90 °C).

    Evaporation from an open surface grows with it: ×0.09 at 20 °C, ×1 at 66, ×2.9 at 90.
    """

    def magnus(c: float) -> float:
        return math.exp(17.625 * c / (c + 243.04))

    return magnus(celsius) / magnus(EVAPORATION_REFERENCE_C)


@dataclass(frozen=True, slots=True)
class SafetyLimits:
    """Every threshold the supervisor uses, in SI units (°C, s, %).

    `origins` says where each derived value came from (configured, derived from the
    configured litres and watts, or measured), for `format_limits`.
    """

    max_temp: float = 95.0
    hysteresis: float = 5.0
    plausible_min: float = -10.0
    plausible_max: float = 110.0
    max_step: float = 2.0
    fault_reads: int = 2
    resume_reads: int = 5
    stale_after: float = 3.0
    dead_time: float = DEAD_TIME_MAX
    heater_watch: float = 300.0
    heater_max_fall: float = 0.25
    heater_rise_rate: float = 0.00258
    heater_min_rise: float | None = None
    heating_output_per_k: float | None = None
    loss_per_k: float = 1.188e-4
    loss_room: float = COLDEST_ROOM
    evaporation_rate: float = 0.00531
    water_ratio: float = 1.0  # the least water the losses cool, over half the configured
    ssr_watch: float = 300.0
    ssr_max_rise: float = 0.5
    creep_watches: tuple[float, ...] = CREEP_WATCHES
    heat_memory: float = DEAD_TIME_MAX + SENSOR_LAG_MAX
    heat_rate: float = 0.0193
    full_rate: float = 0.008
    rise_per_joule: float = FILL_RANGE / (90.0 * WATER_HEAT_CAPACITY)
    dry_fire_rate: float = 0.024
    dry_fire_window: float = 60.0
    stuck_time: float = 600.0
    stuck_output_change: float = 40.0
    stall_after: float = 10.0
    max_output: float = 100.0
    two_elements: bool = False
    origins: tuple[tuple[str, str], ...] = ()

    @property
    def short_watches(self) -> tuple[float, ...]:
        """The SSR watches shorter than `ssr_watch` (`QUICK_WATCH`, where it is shorter)."""
        return (QUICK_WATCH,) if self.ssr_watch > QUICK_WATCH else ()

    def tolerated_rise(self, watch: float) -> float:
        """°C an SSR watch of `watch` s tolerates beyond the heat given: `ssr_max_rise` (the
        creep watches too, whatever `ssr_watch` is), or for a `short_watches` one that rate
        over it, never under twice the noise."""
        if watch not in self.short_watches:
            return self.ssr_max_rise
        return max(self.ssr_max_rise * watch / self.ssr_watch, 2.0 * NOISE_FLOOR)

    def loss_rate(self, celsius: float) -> float:
        """°C/s: the fastest the water at `celsius` can cool with the element off.

        Conduction and convection to the coldest room, plus evaporation from an open surface,
        which grows with the vapour pressure (steeply: ×0.09 at 20 °C, ×2.9 at 90 °C).
        """
        # The pot's wetted area grows as the water's ⅔ power, its heat capacity as the water.
        per_k = self.loss_per_k / math.pow(self.water_ratio, 1.0 / 3.0)
        return per_k * max(0.0, celsius - self.loss_room) + self.evaporation(celsius)

    def evaporation(self, celsius: float) -> float:
        """°C/s an open surface may evaporate away from the least water at `celsius` (the
        least the day's heat-up allows, once measured: `water_ratio`): all of it starts when
        a lid is taken off."""
        return self.evaporation_rate * vapour_pressure_ratio(celsius) / self.water_ratio

    def evaporation_share(self, celsius: float) -> float:
        """% of the element's full power an open surface may evaporate away at `celsius`
        (the pot's, at its configured size): its heat over what full power gives, whatever
        the water."""
        share = self.evaporation_rate * vapour_pressure_ratio(celsius)
        return 100.0 * share / (FILL_RANGE * self.full_rate)

    @property
    def full_output(self) -> float:
        """% of output that is near full power: 80 % of what the element may give (of
        `max_output`, the power limit; of 100 % without one)."""
        return FULL_POWER / 100.0 * self.max_output

    def heating_output(self, celsius: float) -> float:
        """% of output at or above which a working element cannot let the water fall.

        Before the tun is measured, 80 % (of the power limit): its losses may be anything up
        to what the element gives, and a tun that loses more cannot be held at all.
        Measured, the output that beats the largest losses the model allows at `celsius`
        (never below 20 %, where a slow fall is lost in the noise): a dead element is then
        seen as soon as the output climbs past what holding needs, not only at 80 %. The
        model's losses are those of the day it was measured (×1.5, a room 10 °C colder): a
        lid taken off since, on a tun that then needs more than this, is not covered.
        """
        if self.heating_output_per_k is None:
            return self.full_output
        needed = self.heating_output_per_k * (celsius - self.loss_room)
        return min(self.full_output, max(20.0, needed))

    def least_heating(self, applied: float) -> float:
        """°C/s the least a working element at `applied` % heats the least water the tun may
        hold (at −10 % mains): in the units the coil's load is counted in, so that a coil
        that may take this much explains water that does not move."""
        return applied / 100.0 * MAINS_LOW * self.full_rate * FILL_RANGE

    def least_rise(self, held_for: float, peak: float) -> float | None:
        """°C the PV must have risen after `held_for` s at `full_output` or more (past the
        dead time).

        Half of what the weakest working element makes against the largest losses at the
        highest temperature reached (losses only grow with it). None when that is lost in
        the noise: the hot side is judged by the fall instead (`heater_max_fall`).
        """
        if self.heater_min_rise is not None:
            return self.heater_min_rise
        rise = 0.5 * held_for * (self.heater_rise_rate - self.loss_rate(peak))
        return rise if rise >= NOISE_FLOOR else None

    def with_heat_up(self, rate: float, dead_time: float, element_watts: float) -> SafetyLimits:
        """The limits tightened by what the day's own heat-up measured: the full-power `rate`
        (°C/s at 100 %) and the `dead_time` (s), as a measured model tightens them in
        `derive` (the fastest and the weakest rise, a joule's rise, the dead time and the
        heat's memory). A heat-up does not measure the losses: their bounds in W stay the
        pot's, but the water they cool is the least the rate allows, no longer half the
        configured (`water_ratio`: a joule's rise, ×1.5, over the config's). Limits already
        from a measured model, and configured values, are kept; a rate that is no rise
        measures nothing."""
        origins = dict(self.origins)
        if origins.get("heat_rate") == "measured" or not rate > 0.0:
            return self
        timed = _Measured.of(rate, dead_time, self.max_output / 100.0, element_watts)
        per_joule = min(self.rise_per_joule, timed.rise_per_joule)
        changes: dict[str, Any] = {
            "heater_rise_rate": timed.weakest_rise,
            "heat_rate": min(self.heat_rate, timed.fastest_rise),
            "rise_per_joule": per_joule,
            "water_ratio": self.water_ratio * self.rise_per_joule / per_joule,
            "heat_memory": timed.heat_memory,
        }
        if origins.get("dead_time") != "configured":
            changes["dead_time"] = timed.dead
            origins["dead_time"] = HEAT_UP_ORIGIN
        for key in ("heater_rise_rate", "heat_memory", "heat_rate", "rise_per_joule"):
            origins[key] = HEAT_UP_ORIGIN
        origins["loss_rate"] = "the pot's, on the water the day's heat-up measured"
        if origins.get("heater_min_rise") != "configured":
            origins["heater_min_rise"] = HEAT_UP_ORIGIN
        return dataclasses.replace(self, **changes, origins=tuple(sorted(origins.items())))

    @classmethod
    def derive(
        cls,
        *,
        litres: float,
        element_watts: float,
        period: float,
        read_interval: float,
        model: MeasuredTun | None = None,
        max_temp: float = 95.0,
        hysteresis: float = 5.0,
        plausible_min: float = -10.0,
        plausible_max: float = 110.0,
        max_step: float | None = None,
        fault_reads: int = 2,
        resume_reads: int = 5,
        stale_after: float | None = None,
        dead_time: float | None = None,
        heater_watch: float | None = None,
        heater_min_rise: float | None = None,
        ssr_watch: float | None = None,
        ssr_max_rise: float | None = None,
        dry_fire_factor: float = 3.0,
        stuck_time: float = 600.0,
        stuck_output_change: float = 40.0,
        stall_periods: float = 2.0,
        max_output: float = 100.0,
        two_elements: bool = False,
    ) -> SafetyLimits:
        """Limits for the tun: from `model` where measured, else safe for any fill from half
        to twice `litres`, any dead time up to 300 s, an open pot in a 5 °C room; an explicit
        (not None) argument wins over both.

        `max_output`: the power limit, % of `element_watts` that full power gives. What a
        working element must make (`heater_rise_rate`, judged from 80 % of it) and the dry
        fire's rate are of that heat; `heat_rate` stays per second at 100 %, since the duty
        it is multiplied by (the applied one) is already within the limit.

        Worked for the shipped 90 L, 3 kW tun (r = P/(m·c) = 3000/(90·4186) = 7.96e-3 °C/s):
        rise rate 0.8·0.81·r/2 = 2.58e-3 °C/s; loss per K 2·17.76 W/K·(45/90)^⅔ / (45·4186)
        = 1.19e-4 /s; evaporation 1 kW / (45·4186) = 5.31e-3 °C/s at 66 °C; heat rate
        2·1.21·r = 1.93e-2 °C per full-power second; dry fire 3·r = 2.39e-2 °C/s (1.43 °C/min).
        """
        origins: dict[str, str] = {}

        def pick(name: str, given: float | None, value: float, origin: str) -> float:
            origins[name] = "configured" if given is not None else origin
            return given if given is not None else value

        tun = "derived from litres and watts"
        envelope = "built in: any tun to 300 s"
        measured = "measured"
        full_rate = element_watts / (litres * WATER_HEAT_CAPACITY)  # °C/s at 100 %, rated
        least_water = litres / FILL_RANGE
        # An open pot loses through its wetted area (∝ fill^⅔) and evaporates through its
        # mouth (∝ the configured size^⅔); the least water cools fastest from both.
        ua_bound = OPEN_POT_UA_PER_L23 * least_water ** (2.0 / 3.0)
        evaporation_w = OPEN_POT_EVAPORATION_W * (litres / 90.0) ** (2.0 / 3.0)
        least_capacity = least_water * WATER_HEAT_CAPACITY
        rise_per_joule = 1.0 / least_capacity
        limit = max_output / 100.0
        # 80 % of full power at −10 % mains (0.81 P) into twice the water.
        weakest_rise = FULL_POWER / 100.0 * limit * MAINS_LOW * full_rate / FILL_RANGE
        # Full power at +10 % mains into half the water.
        fastest_rise = FILL_RANGE * MAINS_POWER_MARGIN * full_rate
        dead, heat_memory = DEAD_TIME_MAX, DEAD_TIME_MAX + SENSOR_LAG_MAX
        loss_per_k, loss_room = ua_bound / least_capacity, COLDEST_ROOM
        heating_output_per_k: float | None = None
        origin, timing = tun, envelope
        if model is not None:
            # The tun as measured: its rate 100·K/τ, loss 1/τ and dead time θ, each trusted
            # to within ×1.5, and a room up to 10 °C colder than on the day it was measured.
            timed = _Measured.of(
                100.0 * model.gain / model.tau, model.dead_time, limit, element_watts
            )
            weakest_rise, dead, heat_memory = timed.weakest_rise, timed.dead, timed.heat_memory
            # A measurement only tightens: never faster than the envelope's half fill.
            fastest_rise = min(fastest_rise, timed.fastest_rise)
            rise_per_joule = min(rise_per_joule, timed.rise_per_joule)
            loss_per_k = MODEL_MARGIN / model.tau
            loss_room = model.ambient - 10.0
            # u·0.81·K/1.5 heating against 1.5·(T − T_room) of loss, K the °C per %.
            heating_output_per_k = MODEL_MARGIN * MODEL_MARGIN / (MAINS_LOW * model.gain)
            origin = timing = measured
        limits = cls(
            max_temp=max_temp,
            hysteresis=hysteresis,
            plausible_min=plausible_min,
            plausible_max=plausible_max,
            # Only a dump of cold water moves the sensor this far within one read.
            max_step=max_step if max_step is not None else 2.0,
            fault_reads=fault_reads,
            resume_reads=resume_reads,
            stale_after=stale_after if stale_after is not None else 3.0 * read_interval,
            # The element's heat shows at the sensor only after the transport delay and the
            # well's lag: nothing is judged before that.
            dead_time=pick("dead_time", dead_time, dead, timing),
            heater_watch=pick("heater_watch", heater_watch, 300.0, "built in"),
            # A working element at 80 % cannot let the water fall once its heat shows, unless
            # the tun loses more than the element gives (then it cannot be held at all). The
            # PV's period means scatter by ~0.016 °C (0.03 °C noise and 1 LSB over 5 reads),
            # a difference of two by 0.023: 0.125 °C in each half-watch is over 5 of those.
            # The slowest-cooling tun in the family (a lidded 50 L keggle, UA 6 W/K, at 66 °C
            # in a 25 °C room) falls 41 K / 34800 s = 0.18 °C per 150 s when its element dies.
            heater_max_fall=0.25,
            heater_rise_rate=weakest_rise,
            heater_min_rise=heater_min_rise,
            heating_output_per_k=heating_output_per_k,
            loss_per_k=loss_per_k,
            loss_room=loss_room,
            # An open pot's, measured or not: the lid may be off today.
            evaporation_rate=evaporation_w / least_capacity,
            ssr_watch=pick("ssr_watch", ssr_watch, 300.0, "built in"),
            # Margin over what the delivered heat can explain: eight LSBs are not noise.
            ssr_max_rise=pick("ssr_max_rise", ssr_max_rise, 0.5, "built in"),
            heat_memory=heat_memory,
            heat_rate=fastest_rise,
            full_rate=full_rate,
            # A joule into (or out of) the least water the tun may hold: what the HERMS coil's
            # load is judged by (`hermsd.safety.coil_load`).
            rise_per_joule=rise_per_joule,
            # Half the water at +10 % mains rises 2·1.21 = 2.42× faster than the config
            # says; 3× leaves 24 % for noise over the 60 s window (±0.001 °C/s). Kept on the
            # configured litres when measured too: the fill is the config's to state. Under a
            # power limit, of the heat the limit lets through: the same share of the water.
            dry_fire_rate=dry_fire_factor * full_rate * limit,
            dry_fire_window=max(60.0, 4 * period),
            stuck_time=stuck_time,
            stuck_output_change=stuck_output_change,
            stall_after=stall_periods * period,
            max_output=max_output,
            two_elements=two_elements,
        )
        origins |= {
            "heater_max_fall": "built in",
            "heater_min_rise": "configured" if heater_min_rise is not None else origin,
            "heater_rise_rate": origin,
            "heating_output": timing,
            "loss_rate": origin,
            "heat_memory": timing,
            "heat_rate": origin,
            "rise_per_joule": origin,
            "dry_fire_rate": tun,
        }
        return dataclasses.replace(limits, origins=tuple(sorted(origins.items())))


@dataclass(frozen=True, slots=True)
class Alarm:
    """A fault raised or cleared: what, when, and the values that showed it."""

    kind: str
    at: float
    message: str
    latched: bool
    raised: bool = True
    values: dict[str, Any] = field(default_factory=dict)


RAISED_ALARM = re.compile(r"(?:ALARM|fault) (?P<kind>\w+): (?P<message>.*); heater off")
"""The event text of a raised alarm, as replay reads it back from the log."""


def raised_alarm_text(alarm: Alarm) -> str:
    """The event logged when `alarm` is raised; RAISED_ALARM matches it."""
    what = "ALARM" if alarm.latched else "fault"
    return f"{what} {alarm.kind}: {alarm.message}; heater off"


def format_limits(limits: SafetyLimits, setpoint: float) -> list[str]:
    """The limits in force, one line each: value, and where it comes from.

    Temperature-dependent limits are given at `setpoint`. For `check-config` and the
    status command.
    """
    lim, origin = limits, dict(limits.origins)
    configured = "configured"

    def source(key: str) -> str:
        return origin.get(key, configured)

    cool = 20.0  # °C: where the least rise is shown; it shrinks as losses grow with heat
    least = lim.least_rise(3 * lim.heater_watch, cool)
    rows = [
        (
            "over-temperature cut-out",
            f"{lim.max_temp:g} °C, back below {lim.max_temp - lim.hysteresis:g} °C",
            configured,
        ),
        (
            "plausible readings",
            f"{lim.plausible_min:g} to {lim.plausible_max:g} °C, jumps up to {lim.max_step:g} °C",
            configured,
        ),
        ("stale reading after", f"{lim.stale_after:g} s", configured),
        ("loop stall after", f"{lim.stall_after:g} s", configured),
        ("heat shows at the sensor within", f"{lim.dead_time:.0f} s", source("dead_time")),
        (
            "element judged from output",
            f"{lim.heating_output(setpoint):.0f} % (at {setpoint:g} °C)",
            source("heating_output"),
        ),
        (
            "element not heating: steady fall",
            f"{lim.heater_max_fall:g} °C in {lim.heater_watch:.0f} s",
            source("heater_max_fall"),
        ),
        (
            "element not heating: least rise",
            "none judged"
            if least is None
            else (f"{least:.2f} °C in {3 * lim.heater_watch:.0f} s at {cool:g} °C"),
            source("heater_min_rise"),
        ),
        (
            f"weakest heating at {lim.full_output:g} %",
            f"{lim.heater_rise_rate * 60:.3f} °C/min",
            source("heater_rise_rate"),
        ),
        (
            f"largest loss at {setpoint:g} °C",
            f"{lim.loss_rate(setpoint) * 60:.3f} °C/min (room {lim.loss_room:g} °C)",
            source("loss_rate"),
        ),
        (
            "SSR stuck on: rise beyond heat given",
            "".join(f"{lim.tolerated_rise(w):g} °C in {w:.0f} s, " for w in lim.short_watches)
            + f"{lim.ssr_max_rise:g} °C in "
            + ", ".join(f"{w:.0f}" for w in (lim.ssr_watch, *lim.creep_watches))
            + f" s, heat counted "
            f"{lim.heat_memory:.0f} s back, {lim.heat_rate * 60:.2f} °C per full-power minute",
            source("heat_rate"),
        ),
        (
            "dry fire above",
            f"{lim.dry_fire_rate * 60:.2f} °C/min for {DRY_FIRE_WINDOWS} × "
            f"{lim.dry_fire_window:.0f} s, not slowing as a pour does",
            source("dry_fire_rate"),
        ),
        (
            "stuck sensor",
            f"unchanged {lim.stuck_time:g} s while the output moves {lim.stuck_output_change:g} %",
            configured,
        ),
    ]
    width = max(len(label) for label, _, _ in rows)
    return [f"{label:<{width}}  {value}  [{where}]" for label, value, where in rows]
