"""HERMS family through the daemon: hermsd's outer loop and its peers on the same plants.

Every day runs through `hermsd.sim.scenario.run` (the machinery of `hermsd simulate`: the daemon
on a virtual clock, its log written and re-run with `hermsd replay --verify`'s `replay.verify`),
on a `hermsd.sim.mash.HermsTun`. The set-ups are drawn, one per seed, from the documented
ranges: HLT 40–150 L, 2–9 kW, UA 17.8 W/K at 90 L scaled by the surface (×0.8–1.25), the
element's heat 20–90 s late, the HLT's sensor lag 5–30 s; a coil of 100–400 W/K at 4–8 L/min,
hoses 5–25 s each way; a mash of 20–70 kg (2.5–4 L of water a kg of grain) doughed in at 35–50
°C, the tun's losses 2–15 W/K and its own 0–5 kJ/K, the mash sensor's lag 5–60 s; the limit
(herms.max_hlt_above_mash) 5, 8 or 10 °C, the HLT preheated to a strike setpoint of 60–72 °C;
the brewery's room 0–35 °C (the grain and the tun at it), where hermsd's config keeps the
shipped model room (`control.model_ambient`, 20 °C). An odd seed has the pump fitted
(`pump.backend: sim`, switched by hermsd), an even one runs it outside hermsd (started by hand
2–10 min after dough-in) with a pump sense fitted (`pump.sense: sim`: a switch hermsd only
sees); the seed modulo 3 gives its timer: none, stops for stirring (5 min at 40 min and 100 min
after dough-in) or a recirculation timer (2 min off every 20 min; where hermsd switches the
pump, its program's own timer, `pump_off_every: 20m` and `pump_off_for: 2m` on each rest,
counted from the rest's start, and the peers' listener switches it so from their rests' starts,
as `hermsd set pump` would; outside hermsd, a timer of its own from dough-in). Three more set-
ups are scenarios/herms-day.yaml's plant (90 L 3 kW, 50 L and 12 kg doughed in at 38 °C, limit
10 °C, room 20 °C): its pump outside hermsd and seen, outside and unseen (no sense, no coil
outlet sensor: hermsd takes it as running), and fitted. Every sensor has noise (sd 0.03 °C; the
HLT's and the mash's LM92 truncate to 0.0625 °C).

The day: the HLT held at the strike setpoint, dough-in and "Mash in" confirmed at 20 min, then
rests of 63 °C (30 min), 72 °C (20 min) and 78 °C (10 min) timed on the mash (reached within
±0.5 °C of the mash reading, the hold counting the periods in that band); the day ends 2 min
after the last hold, or at 10 h (a 2.5 kW element under 110 L takes over 7). hermsd runs it as a
mash program with a mash sensor fitted (herms keys: the mash's true litres and grain, its losses
guessed low at 0.7 of the truth, the hoses' round trip and the mash sensor's lag; the HLT law's
prior the true HLT but for its room), the pump started by the program's first rest when fitted.
The peers run in the same daemon with no mash sensor (an HLT thermostat, the same HLT law and
prior): a listener handed the daemon (`scenario.run(attach=...)`) reads the simulated mash
sensor each period (its noise, lag and 0.0625 °C steps), times the rests by the same rule, sets
the daemon's setpoint as `hermsd set setpoint` would and starts the fitted pump at the first
rest as `hermsd set pump on` would. Offset: the HLT at the mash's setpoint + 2 °C (ebrew,
CraftBeerPi users). CascadePID: CraftBeerPi's, a PI on the mash's error (10 °C/°C, Ti 600 s)
gives the HLT's setpoint, clamped to the mash's setpoint + the limit (bench/herms_cascade.py's
peers).

Measured on the true temperatures (the HLT's water, the mash's bulk), per rest: the mash's
worst error from 5 min after it first came within 0.3 °C (goal ≤ 0.3 °C), the pump's stops
aside (one begun in those 5 min too), from the stop until the mash is back within 0.3 °C after
the restart (the brewer's stir, a recirculation timer: no heat reaches the mash, which cools at
its own rate whatever the HLT does; shown counted too), its overshoot (goal ≤ 0.2 °C), the
HLT's highest against the mash's setpoint + limit from its first time at or below it in the
rest (never above; a strike the program leaves above the first rest + limit, which `hermsd
program check` warns of, cannot be cooled, only left to fall: shown counted too), and the step
time from the rest's start to within 0.3 °C against the fastest the limit allows on the same
plant (goal ≤ ×1.15): a copy of the plant itself as the step began (its water, mash and hoses,
and the element's heat already on its way), the pump as the day switched it, the HLT at full
power to the limit and held there, then off at the last instant that keeps the mash at or below
its rest (by bisection) and held at the HLT the rest needs, each mark held by a controller that
knows the heat it has sent (on while the water a delay ahead, that heat landed and the coil's
draw and the losses gone on, is under the mark). Shown beside it, with no goal: the step time
against the same ideal kept, while the pump runs, as far under the limit as a stop nobody
announced would land (the coil's draw over the element's delay, K·(T_h − T_m)·D/C_h): what
"never above the limit" costs a controller that cannot know a brewer's stop in advance, which
the ideal above does not pay. A rest the ideal never reaches (the limit leaves it out of reach
on that plant) is no goal for anyone, nor are the rests the program never begins after it; one
it reaches and a controller does not is a miss ("never"). Per pump start: the HLT's largest
fall below the lesser of its temperature at the start and its setpoint over 10 min (or until
the next rest begins, its setpoint another step's climb); one hermsd commands (goal ≤ 0.3 °C
where the element exceeds the coil's load and the HLT's losses at that instant), one outside
hermsd against the fall at full power from the start's instant on a copy of the plant (goal ≤
×1.2, seen through its sense; the unseen one measured apart; shown where that fall is 0.1 °C or
more). Alarms (goal 0; a latched one is reset by the brewer at once, `hermsd reset`, so that
the day goes on, and each is counted: a peer's are the supervisor's verdict on a HERMS run as a
plain HLT, which counts no coil's load without a mash sensor, not the peer's own), and `replay
--verify` on each day's log (exact: every step re-run bit for bit). Per day, what the mash's
reach watch said ("the mash levels out near …": a rest the HLT at its most cannot bring the
mash to within a degree; docs/mash-control.md), none where every rest is reached, and the
coil's K hermsd's load was last reckoned on against the coil's own (ε·ṁc). hermsd is ahead
of both peers on a measure where a larger share of its rests (pump starts, days) meets the
goal than of either's, or the same share with its worst less far beyond the goal (`standing`):
two that keep a limit on every rest are level, whatever margin each keeps under it.

A step down (`--step-down`; its own section): the same set-ups, peers and measures on a day
whose rests are 70 °C (20 min), 64 °C (30 min) and 76 °C (10 min), the second below the first,
as a program that rests high and then low has it. Heat cannot be taken out: the mash comes
down by its own losses and through the coil once the HLT stands below it. Measured in the
step's direction: the mash's "overshoot" of the 64 °C rest is how far it went under it as it
landed, the wort flowing, up to the pump's first stop once the mash was within 0.3 °C (a
stopped pump's mash cools at its own rate whatever the HLT does, towards the undershoot where
a climb's cools away from its overshoot; a stop before it arrived aside with its way back, as
for the error), and the fastest the plant allows is the mirror of
a climb's: the element off, then at the last instant that keeps the mash at or above its
rest (by bisection) the HLT brought at full power to the HLT the rest needs and held there. A
pump start while the mash is still coming down to that rest is no measure of the start (the
HLT is let fall on purpose then, the element off).

    uv run python bench/herms.py [--seeds 1-40] [--jobs 2] [--step-down] [--write]
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import math
import random
import tempfile
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import sections  # bench/sections.py, beside this file
from herms_cascade import CascadePid, Offset  # the peers' outer loops, beside this file

from hermsd.config.read import parse
from hermsd.log import reader, replay
from hermsd.runtime.daemon import Daemon
from hermsd.runtime.mash_control import MASH_PREFIX as SHORT
from hermsd.runtime.period import PeriodRecord
from hermsd.safety.limits import Alarm
from hermsd.sim import scenario
from hermsd.sim.hlt import WATER_J_PER_LITRE_K, PhysicalPlant
from hermsd.sim.mash import GRAIN_J_PER_KG_K, HermsTun

CONFIG_ROOM = 20.0  # °C: the config's model_ambient, the shipped one (the day's room unmeasured)
RESTS = ((63.0, 30), (72.0, 20), (78.0, 10))  # °C, minutes held
STEP_DOWN = ((70.0, 20), (64.0, 30), (76.0, 10))  # `--step-down`: a rest below the one before
BAND = 0.3  # °C: the measure's band
PROGRAM_BAND = 0.5  # °C: a rest reached and held on the mash (hermsd.program's rule)
SETTLE_S = 300.0  # the mash levelling out before its error counts
PUMP_WINDOW_S = 600.0
DOUGH_AT = 1200.0
PERIOD = 5.0
NOISE_C = 0.03
LM92_STEP = 0.0625
OFFSET = 2.0
DURATION = 10 * 3600.0  # the most a day may take; it ends 2 min after its last hold
HEADING = "## HERMS family through the daemon: hermsd and its peers"
HEADING_DOWN = "## HERMS family through the daemon: a step down"
CONTROLLERS = ("hermsd", "offset", "cascadepid")


@dataclasses.dataclass(frozen=True)
class SetUp:
    label: str
    litres: float
    watts: float
    hlt_ua: float
    delay_s: float
    hlt_lag_s: float
    coil_ua: float
    flow: float
    hose_to_coil: float
    hose_to_mash: float
    mash_ua: float
    mash_lag: float
    tun_j_per_k: float
    water_l: float
    grain_kg: float
    dough_c: float
    strike_c: float
    limit: float
    pump_fitted: bool
    pump_seen: bool  # a pump outside hermsd with its sense fitted
    timer: str  # none, stir or recirculation
    hand_start_s: float  # after dough-in, a pump outside hermsd
    seed: int
    room: float  # °C, the brewery's on the day (the grain and the tun at it too)
    rests: tuple[tuple[float, int], ...] = RESTS  # the program's: °C, minutes held

    @property
    def coil_k(self) -> float:
        """The coil's effective conductance ε·ṁc (docs/mash-control.md, "The coil")."""
        flow = self.flow / 60.0 * WATER_J_PER_LITRE_K
        return flow * (1.0 - math.exp(-self.coil_ua / flow))

    @property
    def mash_capacity(self) -> float:
        return (
            self.tun_j_per_k + WATER_J_PER_LITRE_K * self.water_l + GRAIN_J_PER_KG_K * self.grain_kg
        )

    @property
    def water_c(self) -> float:
        """The strike water's temperature that mixes with the grain (20 °C) and the tun
        (the room's) to `dough_c`."""
        cold = (GRAIN_J_PER_KG_K * self.grain_kg + self.tun_j_per_k) * self.room
        return (self.dough_c * self.mash_capacity - cold) / (WATER_J_PER_LITRE_K * self.water_l)

    def describe(self) -> str:
        pump = "fitted" if self.pump_fitted else f"by hand at +{self.hand_start_s / 60:.0f} min"
        if not self.pump_fitted:
            pump += ", seen" if self.pump_seen else ", unseen"
        return (
            f"{self.litres:.0f} L {self.watts / 1000:.1f} kW (late {self.delay_s:.0f} s, "
            f"lag {self.hlt_lag_s:.0f} s), coil {self.coil_ua:.0f} W/K at {self.flow:.1f} L/min "
            f"(K {self.coil_k:.0f}), {self.water_l:.0f} L + {self.grain_kg:.1f} kg at "
            f"{self.dough_c:.1f} °C (UA {self.mash_ua:.1f}, lag {self.mash_lag:.0f} s), "
            f"strike {self.strike_c:.0f} °C, limit {self.limit:g}, pump {pump}, "
            f"timer {self.timer}, room {self.room:.0f} °C"
        )


def draw(seed: int) -> SetUp:
    """A set-up from the documented ranges (the module's docstring)."""
    rng = random.Random(seed)
    litres = rng.uniform(40.0, 150.0)
    total = rng.uniform(20.0, 70.0)
    grain = total / (1.0 + rng.uniform(2.5, 4.0))
    return SetUp(
        label=f"seed {seed}",
        litres=litres,
        watts=round(rng.uniform(2000.0, 9000.0), -2),
        hlt_ua=3000.0 / 168.9 * (litres / 90.0) ** (2.0 / 3.0) * rng.uniform(0.8, 1.25),
        delay_s=rng.uniform(20.0, 90.0),
        hlt_lag_s=rng.uniform(5.0, 30.0),
        coil_ua=rng.uniform(100.0, 400.0),
        flow=rng.uniform(4.0, 8.0),
        hose_to_coil=rng.uniform(5.0, 25.0),
        hose_to_mash=rng.uniform(5.0, 25.0),
        mash_ua=rng.uniform(2.0, 15.0),
        mash_lag=rng.uniform(5.0, 60.0),
        tun_j_per_k=rng.uniform(0.0, 5000.0),
        water_l=total - grain,
        grain_kg=grain,
        dough_c=rng.uniform(35.0, 50.0),
        strike_c=rng.uniform(60.0, 72.0),
        limit=rng.choice((5.0, 8.0, 10.0)),
        pump_fitted=seed % 2 == 1,
        pump_seen=seed % 2 == 0,
        timer=("none", "stir", "recirculation")[seed % 3],
        hand_start_s=rng.uniform(120.0, 600.0),
        seed=seed,
        room=rng.uniform(0.0, 35.0),
    )


def herms_day(pump_fitted: bool, pump_seen: bool = True) -> SetUp:
    """scenarios/herms-day.yaml's plant and dough-in, its pump 5 min after dough-in (outside
    hermsd: seen through its sense, or unseen)."""
    label = ", pump fitted" if pump_fitted else "" if pump_seen else ", pump outside, unseen"
    return SetUp(
        label="herms-day" + label,
        litres=90.0,
        watts=3000.0,
        hlt_ua=3000.0 / 168.9,
        delay_s=60.0,
        hlt_lag_s=10.0,
        coil_ua=250.0,
        flow=6.0,
        hose_to_coil=10.0,
        hose_to_mash=10.0,
        mash_ua=10.0,
        mash_lag=10.0,
        tun_j_per_k=0.0,
        water_l=50.0,
        grain_kg=12.0,
        dough_c=38.0,
        strike_c=66.0,
        limit=10.0,
        pump_fitted=pump_fitted,
        pump_seen=pump_seen and not pump_fitted,
        timer="none",
        hand_start_s=300.0,
        seed=100 + pump_fitted,
        room=CONFIG_ROOM,
    )


@dataclasses.dataclass
class PumpStart:
    t: float
    water: float  # °C, the HLT's water at the start
    load: float  # W, the coil's and the HLT's losses at that instant
    full_power_fall: float  # °C, the water's largest fall in 10 min at full power from t


class NoisyTun(HermsTun):
    """A `HermsTun` whose mash sensor has noise, that tells its true mash, and that notes
    each pump start with the fall full power from that instant would allow."""

    __slots__ = ("_hlt_ua", "_noise", "_room", "pump_log", "pump_starts")

    def __init__(self, s: SetUp) -> None:
        hlt = PhysicalPlant(
            litres=s.litres,
            element_watts=s.watts,
            ua_w_per_k=s.hlt_ua,
            transport_delay_s=s.delay_s,
            sensor_lag_s=s.hlt_lag_s,
            ambient_c=s.room,
            start_c=s.strike_c,
        )
        super().__init__(hlt, **mash_keys(s))
        self._hlt_ua, self._room = s.hlt_ua, s.room
        self._noise = random.Random(s.seed + 7919)
        self.pump_log: list[tuple[float, bool]] = []
        self.pump_starts: list[PumpStart] = []

    def mash_temperature(self, t: float) -> float:
        return super().mash_temperature(t) + self._noise.gauss(0.0, NOISE_C)

    def true_mash(self, t: float) -> float:
        self._advance(t)
        return self._mash_c

    @property
    def pump_on(self) -> bool:
        return self._pump_on

    def set_pump(self, on: bool, t: float) -> None:
        started = on and not self._pump_on and self._mash_capacity > 0.0
        super().set_pump(on, t)
        self.pump_log.append((t, on))
        if started:
            water = self.water_temperature(t)
            full = copy.deepcopy(self)
            HermsTun.set_heater(full, True, t)
            lowest = min(full.water_temperature(t + s) for s in range(1, int(PUMP_WINDOW_S) + 1))
            load = self.coil_watts(t) + self._hlt_ua * (water - self._room)
            self.pump_starts.append(PumpStart(t, water, load, water - lowest))


def mash_keys(s: SetUp) -> dict[str, float]:
    return {
        "coil_w_per_k": s.coil_ua,
        "flow_l_per_min": s.flow,
        "hose_to_coil_s": s.hose_to_coil,
        "hose_to_mash_s": s.hose_to_mash,
        "mash_ua_w_per_k": s.mash_ua,
        "mash_sensor_lag_s": s.mash_lag,
        "tun_heat_capacity_j_per_k": s.tun_j_per_k,
    }


RECIRCULATION = (1200.0, 120.0)  # s: the pump stopped 2 min every 20 min


def program_timer(s: SetUp) -> bool:
    """Whether the day's recirculation timer is the program's (the pump switched by hermsd)."""
    return s.timer == "recirculation" and s.pump_fitted


def pump_timer(s: SetUp) -> list[dict[str, Any]]:
    """The pump's stops and restarts after dough-in: for stirring, or a recirculation timer
    outside hermsd (one hermsd switches runs the program's, `program_timer`)."""
    if program_timer(s):
        return []
    if s.timer == "stir":
        stops = [(DOUGH_AT + 2400.0, 300.0), (DOUGH_AT + 6000.0, 300.0)]
    elif s.timer == "recirculation":
        every, lasts = RECIRCULATION
        starts = range(int(DOUGH_AT + every), int(DURATION) - 200, int(every))
        stops = [(at, lasts) for at in starts]
    else:
        stops = []
    events: list[dict[str, Any]] = []
    for at, lasts in stops:
        events += [{"at": at, "pump": "off"}, {"at": at + lasts, "pump": "on"}]
    return events


def scenario_doc(s: SetUp, controller: str) -> dict[str, Any]:
    """The day as `hermsd simulate` reads it: plant, config, events, and hermsd's program."""
    dough = {"grain_kg": s.grain_kg, "grain_c": s.room, "water_litres": s.water_l}
    events: list[dict[str, Any]] = [{"at": DOUGH_AT, "dough_in": {**dough, "water_c": s.water_c}}]
    if not s.pump_fitted:
        events.append({"at": DOUGH_AT + s.hand_start_s, "pump": "on"})
    events += pump_timer(s)
    config: dict[str, Any] = {
        "tun": {"litres": s.litres, "element_watts": s.watts},
        "control": {
            "model_gain": s.watts / (100.0 * s.hlt_ua),
            "model_tau": WATER_J_PER_LITRE_K * s.litres / s.hlt_ua,
            "dead_time": s.delay_s + s.hlt_lag_s,
            "model_ambient": CONFIG_ROOM,
        },
        "log": {"dir": None},
        "pump": {
            "backend": "sim" if s.pump_fitted else "none",
            "sense": "sim" if s.pump_seen else "none",
        },
        "herms": {
            "max_hlt_above_mash": s.limit,
            "mash_litres": s.water_l,
            "grain_kg": s.grain_kg,
            "mash_loss_w_per_k": round(0.7 * s.mash_ua, 1),
            "hose_s": s.hose_to_coil + s.hose_to_mash,
            "mash_sensor_lag": s.mash_lag,
        },
    }
    doc: dict[str, Any] = {
        "name": f"{s.label} {controller}",
        "duration": DURATION,
        "setpoint": s.strike_c,
        "plant": {
            "model": "physical",
            "litres": s.litres,
            "element_watts": s.watts,
            "ua_w_per_k": s.hlt_ua,
            "transport_delay_s": s.delay_s,
            "sensor_lag_s": s.hlt_lag_s,
            "start_c": s.strike_c,
            "noise_c": NOISE_C,
            "seed": s.seed,
            "mash": mash_keys(s),
        },
        "config": config,
        "events": events,
    }
    if controller == "hermsd":
        config["mash_sensor"] = {"kind": "lm92", "address": 0x49}
        events.append({"at": DOUGH_AT, "confirm": "Mash in"})
        strike = {"name": "Strike", "setpoint": s.strike_c, "hold": "0s", "confirm": "Mash in"}
        timer = {}
        if program_timer(s):
            every, lasts = RECIRCULATION
            timer = {"pump_off_every": f"{every:g}s", "pump_off_for": f"{lasts:g}s"}
        rests = [
            {"name": f"Rest {sp:g}", "setpoint": sp, "hold": f"{minutes}m", **timer}
            for sp, minutes in s.rests
        ]
        doc["program"] = {"name": "HERMS rests", "steps": [strike, *rests]}
    return doc


@dataclasses.dataclass(frozen=True)
class Sample:
    t: float
    hlt_sp: float
    water: float
    mash: float


class Day:
    """Watches a day each period (the true HLT water and mash, the setpoints, the rests'
    starts) and, for a peer, is its outer loop and its rests' timer."""

    def __init__(self, s: SetUp, controller: str, tun: NoisyTun) -> None:
        self.s, self.controller, self.tun = s, controller, tun
        self.daemon: Daemon | None = None
        self.samples: list[Sample] = []
        self.rest_starts: list[tuple[float, float, float]] = []  # t, water, mash
        self.rest_plants: list[NoisyTun] = []  # the plant as each rest began, for its ideal
        self.done_at: float | None = None
        self.outer: Callable[[float, float, float, bool], tuple[float, float]] | None = None
        if controller == "offset":
            self.outer = Offset(min(OFFSET, s.limit))
        elif controller == "cascadepid":
            self.outer = CascadePid(s.limit, PERIOD)
        self.rest: int | None = None  # the peer's rest (None: the strike water's step)
        self.rest_began = 0.0  # when the peer's rest began (its pump timer's start)
        self.pump_on = False  # the pump as the peer's listener last set it
        self.reached, self.held, self.sent = False, 0.0, s.strike_c
        self.coil_k: float | None = None  # W/K, the K hermsd's load was last reckoned on

    def attach(self, daemon: Daemon) -> None:
        self.daemon = daemon
        daemon.listeners.append(self)

    def period(self, record: PeriodRecord) -> None:
        t = record.t
        if self.outer is None:
            self.coil_k = record.coil_k or self.coil_k
            index = record.step_index
            rest = None if index is None or index == 0 else index - 1
            runner = None if self.daemon is None else self.daemon.program.runner
            if runner is not None and runner.state == "done" and self.done_at is None:
                self.done_at = t
            hlt_sp = record.hlt_target
        else:
            rest = self.steer(t)
            hlt_sp = record.setpoint
        if rest is not None and rest == len(self.rest_starts):
            self.rest_starts.append((t, self.tun.water_temperature(t), self.tun.true_mash(t)))
            self.rest_plants.append(copy.deepcopy(self.tun))
        self.samples.append(Sample(t, hlt_sp, self.tun.water_temperature(t), self.tun.true_mash(t)))
        if self.done_at is not None and t >= self.done_at + 120.0 and self.daemon is not None:
            self.daemon.stop()

    def steer(self, t: float) -> int | None:
        """The peer's period: time the rests on the mash reading, set the HLT's setpoint."""
        assert self.daemon is not None
        assert self.outer is not None
        reading = math.floor(self.tun.mash_temperature(t) / LM92_STEP) * LM92_STEP
        if self.rest is None and t >= DOUGH_AT:
            self.rest, self.rest_began = 0, t
        elif self.rest is not None and self.rest < len(self.s.rests):
            sp, minutes = self.s.rests[self.rest]
            inside = abs(reading - sp) <= PROGRAM_BAND
            self.reached = self.reached or inside
            self.held += PERIOD if self.reached and inside else 0.0
            if self.held >= minutes * 60.0:
                self.rest, self.reached, self.held = self.rest + 1, False, 0.0
                self.rest_began = t
                if self.rest == len(self.s.rests):
                    self.done_at = t
        self.peer_pump(t)
        target = self.s.strike_c
        if self.rest is not None:
            sp = self.s.rests[min(self.rest, len(self.s.rests) - 1)][0]
            target = self.outer(sp, reading, 0.0, True)[0]
        target = min(max(target, 0.0), 100.0)
        if abs(target - self.sent) >= 0.005:
            self.sent = round(target, 2)
            self.daemon.set_setpoint(self.sent)
        return None if self.rest is None or self.rest == len(self.s.rests) else self.rest

    def peer_pump(self, t: float) -> None:
        """The peer's pump, where hermsd switches it: started at dough-in, then stopped as the
        program's timer would (`program_timer`), from each rest's start."""
        assert self.daemon is not None
        if not self.s.pump_fitted or self.rest is None:
            return
        on = True
        if program_timer(self.s) and self.rest < len(self.s.rests):
            every, lasts = RECIRCULATION
            on = (t - self.rest_began) % every < every - lasts
        if on != self.pump_on:
            self.pump_on = on
            self.daemon.set_pump(on, "by the operator")

    def alarm(self, alarm: Alarm) -> None:
        """The brewer resets a latched alarm at once (`hermsd reset`), so that the day goes
        on and the outer loop is still measured; the run's summary counts each."""
        if alarm.raised and alarm.latched and self.daemon is not None:
            self.daemon.reset_alarms([alarm.kind])


def ideal_run(
    s: SetUp,
    plant: NoisyTun,
    t0: float,
    sp: float,
    switch: float,
    pumps: list[tuple[float, bool]],
    reach: bool = True,
    room: bool = False,
) -> tuple[float, float | None]:
    """The ideal HLT on a copy of `plant` (the plant as the rest began at `t0`), off the limit
    at `switch` s: (s until the mash is within BAND, s when it passed `sp`: None if it did
    not). With `switch` finite the run ends once the HLT has been down at the rest's HLT for
    the hoses' time and 2 min (the mash then never passes `sp`), and the mash is within BAND
    if `reach`. `room`: while the pump runs, the HLT no higher than leaves room under the limit
    for what a stop nobody announced would land, the coil's draw over the element's delay
    (`room_top`). Each mark is held on the water a delay ahead (the heat in flight landed, the
    coil's draw and the losses gone on), on the true temperatures. A step down (the mash above
    `sp`) is the mirror: the element off until `switch`, then the HLT held at the rest's, the
    mash not to pass under `sp`."""
    tun = copy.deepcopy(plant)
    way = -1.0 if tun.true_mash(t0) > sp else 1.0  # the step's direction
    running = pump_running(pumps, t0)
    HermsTun.set_pump(tun, running, t0)  # the plant's own switch: no full-power copy of it
    later = [(at, on) for at, on in pumps if at > t0]
    cap, hold = sp + s.limit, sp + s.mash_ua * (sp - s.room) / s.coil_k
    capacity = WATER_J_PER_LITRE_K * s.litres
    settle = s.hose_to_coil + s.hose_to_mash + 120.0
    reached, down_since, t = math.inf, math.inf, t0
    for second in range(4 * 3600):
        while later and later[0][0] <= t:  # a switch within the second: at its end
            running = later.pop(0)[1]
            HermsTun.set_pump(tun, running, t)
        top = room_top(s, cap, tun.true_mash(t)) if room and running else cap
        top = top if way > 0.0 else -math.inf
        water = tun.water_temperature(t)
        going = tun.coil_watts(t) + s.hlt_ua * (water - s.room)
        ahead = water + (tun.heat_in_flight(t) - going * s.delay_s) / capacity
        HermsTun.set_heater(tun, ahead < (top if second < switch else hold), t)
        t += 1.0
        now = tun.true_mash(t)
        if way * (now - sp) > 1e-3:
            return reached, second + 1.0
        if reached == math.inf and way * (now - sp) >= -BAND:
            reached = second + 1.0
        if second >= switch and way * (tun.water_temperature(t) - hold) <= 0.05:
            down_since = min(down_since, t)
            if t - down_since > settle and (reached < math.inf or not reach):
                return reached, None
    return reached, None


def room_top(s: SetUp, cap: float, mash: float) -> float:
    """The highest HLT whose stop, nobody announcing it, lands under `cap`: h + K·(h − m)·D/C_h
    ≤ cap (D the element's delay, C_h the HLT's water), h ≤ (cap + a·m)/(1 + a), a = K·D/C_h."""
    a = s.coil_k * s.delay_s / (WATER_J_PER_LITRE_K * s.litres)
    return (cap + a * mash) / (1.0 + a)


def fastest(
    s: SetUp,
    plant: NoisyTun,
    t0: float,
    sp: float,
    pumps: list[tuple[float, bool]],
    room: bool = False,
) -> float:
    """s from `t0` to within BAND of `sp` with the ideal HLT on a copy of `plant` (the module's
    docstring); `room`: keeping room for an unannounced stop's landing (`ideal_run`)."""
    never = ideal_run(s, plant, t0, sp, math.inf, pumps, room=room)
    if never[1] is None:
        return never[0]
    first = ideal_run(s, plant, t0, sp, 0.0, pumps, reach=False, room=room)
    if first[1] is not None:
        return first[0]
    lo, hi = 0.0, never[1]
    while hi - lo > 4.0:
        mid = 0.5 * (lo + hi)
        if ideal_run(s, plant, t0, sp, mid, pumps, reach=False, room=room)[1] is None:
            lo = mid
        else:
            hi = mid
    return ideal_run(s, plant, t0, sp, lo, pumps, room=room)[0]


def pump_running(pumps: list[tuple[float, bool]], t: float) -> bool:
    """The pump as the day switched it at `t` (off before its first start)."""
    return next((on for at, on in reversed(pumps) if at <= t), False)


def held_samples(
    window: list[Sample], sp: float, reached: float, pumps: list[tuple[float, bool]]
) -> list[Sample]:
    """The rest's samples from 5 min after the mash first came within BAND, less the pump's
    stops (the brewer's stir, a recirculation timer: no heat reaches the mash, and it cools at
    its own rate whatever the HLT does) and the time from each restart until the mash is back
    within BAND, a stop begun in those 5 min too."""
    held, out = [], False
    for x in window:
        running = pump_running(pumps, x.t)
        out = (out or not running) and not (running and abs(x.mash - sp) <= BAND)
        if not out and x.t >= reached + SETTLE_S:
            held.append(x)
    return held


def step_down_landing(
    window: list[Sample], sp: float, reached: float | None, pumps: list[tuple[float, bool]]
) -> list[Sample]:
    """A step down's samples its undershoot is judged on: the landing, the wort flowing, up
    to the pump's first stop once the mash is within BAND. A stopped pump's mash cools at
    its own rate whatever the HLT does, towards the undershoot where a climb's cools away
    from its overshoot, so a stop and its way back are no landing (before the mash arrives,
    the stop and the way back to within BAND aside, as for the error)."""
    stopped = (x.t for x in window if reached is not None and x.t >= reached)
    first = next((t for t in stopped if not pump_running(pumps, t)), math.inf)
    flowing = held_samples(window, sp, -math.inf, pumps)
    return [x for x in flowing if x.t < first] or window


def rests_measured(s: SetUp, day: Day, pumps: list[tuple[float, bool]]) -> list[dict[str, Any]]:
    """Each rest's measures (the module's docstring); a rest never begun is left out."""
    rows = []
    ends = [start[0] for start in day.rest_starts[1:]] + [math.inf]
    begun = zip(s.rests, day.rest_starts, day.rest_plants, ends, strict=False)
    for (sp, _), start, plant, end in begun:
        window = [x for x in day.samples if start[0] <= x.t < end]
        way = -1.0 if start[2] > sp else 1.0  # the step's direction: a step down's is −1
        reached = next((x.t for x in window if way * (x.mash - sp) >= -BAND), None)
        landing = window if way > 0.0 else step_down_landing(window, sp, reached, pumps)
        held = [] if reached is None else held_samples(window, sp, reached, pumps)
        after = [abs(x.mash - sp) for x in held]
        stops = [x.mash - sp for x in window if reached is not None and x.t >= reached + SETTLE_S]
        best = fastest(s, plant, start[0], sp, pumps)
        roomy = fastest(s, plant, start[0], sp, pumps, room=True)
        step = math.inf if reached is None else reached - start[0]
        # Never within BAND: a miss where the ideal gets there, none where nothing can.
        unheld = math.nan if reached is not None or math.isinf(best) else math.inf
        cap = sp + s.limit
        # Above the limit from its first time at or below it: a strike left above the first
        # rest's limit (the program's choice, which `hermsd program check` warns of) cannot
        # be cooled, only left to fall.
        come_down = next((i for i, x in enumerate(window) if x.water <= cap), len(window) - 1)
        rows.append(
            {
                "sp": sp,
                "err": max(after, default=unheld),
                "err_all": max((abs(e) for e in stops), default=unheld),
                "over": max(way * (x.mash - sp) for x in landing),
                "hlt_above": max(x.water for x in window[come_down:]) - cap,
                "hlt_above_all": max(x.water for x in window) - cap,
                "step_s": step,
                "fastest_s": best,
                "ratio": step / best if 0.0 < best < math.inf else math.nan,
                "ratio_room": step / roomy if 0.0 < roomy < math.inf else math.nan,
            }
        )
    return rows


def falling(s: SetUp, day: Day, t: float) -> bool:
    """Whether the mash at `t` is still coming down to a rest below it (a step down): the HLT
    is let fall on purpose then, the element off, and its fall is no measure of a pump start."""
    begun = [(start, sp) for start, (sp, _) in zip(day.rest_starts, s.rests, strict=False)]
    now = [(start, sp) for start, sp in begun if start[0] <= t]
    if not now:
        return False
    (_, _, mash_then), sp = now[-1]
    mash = next((x.mash for x in reversed(day.samples) if x.t <= t), mash_then)
    return mash_then > sp and mash > sp + BAND


def pumps_measured(s: SetUp, day: Day) -> list[dict[str, Any]]:
    """Each pump start with the mash in: the HLT's fall, who started it, the load at that
    instant, and the fall full power from that instant allows."""
    rows = []
    for start in day.tun.pump_starts:
        if falling(s, day, start.t):
            continue
        # Until the next rest begins at the latest: its setpoint is another step's climb.
        until = min((t for t, _, _ in day.rest_starts if t > start.t), default=math.inf)
        end = start.t + PUMP_WINDOW_S
        window = [x for x in day.samples if start.t <= x.t <= end and x.t < until]
        fall = max((min(start.water, x.hlt_sp) - x.water for x in window), default=math.nan)
        fall = max(fall, 0.0)  # the HLT above where it was and where it was wanted: no fall
        rows.append(
            {
                "t": start.t,
                "by_hermsd": s.pump_fitted,
                "seen": s.pump_seen,
                "element_exceeds": s.watts > start.load,
                "load_w": start.load,
                "fall": fall,
                "full_power_fall": start.full_power_fall,
            }
        )
    return rows


def verified(log: reader.Log) -> str:
    """What `hermsd replay --verify` says of the day's log."""
    result = replay.verify(log.entries)
    if result.other_law is not None:
        return "another law's"
    if result.mismatch is not None:
        return f"differs at k={result.mismatch.k} ({result.mismatch.name})"
    if result.verified == 0:
        return "nothing verified"
    skipped = f", {result.unknown_state} not re-run" if result.unknown_state else ""
    return f"exact ({result.verified}{skipped})"


def run_day(task: tuple[SetUp, str]) -> dict[str, Any]:
    """One set-up under one controller through the daemon, measured."""
    s, controller = task
    tun = NoisyTun(s)
    day = Day(s, controller, tun)
    spec = scenario.parse_scenario(scenario_doc(s, controller), f"<{s.label} {controller}>")
    with tempfile.TemporaryDirectory(prefix="hermsd-bench-") as directory:
        result = scenario.run(
            spec, parse(""), log_dir=Path(directory), outside_plant=tun, attach=day.attach
        )
        log = reader.load(sorted(Path(directory).glob("*.mcap*")))
        verify = verified(log)
        short = [e.message for e in log.events if e.message.startswith(SHORT)]
    return {
        "setup": s,
        "controller": controller,
        "rests": rests_measured(s, day, tun.pump_log),
        "pumps": pumps_measured(s, day),
        "alarms": [a["kind"] for a in result.summary["alarms"]],
        "verify": verify,
        "short": short,
        "finished": day.done_at is not None,
        "k_ratio": math.nan if day.coil_k is None else day.coil_k / s.coil_k,
        "wall_s": result.summary["wall_s"],
    }


NAMES = {
    "hermsd": "hermsd",
    "offset": f"offset +{OFFSET:g} °C",
    "cascadepid": "CascadePID",
}


def number(value: float, form: str = ".2f") -> str:
    return "—" if math.isnan(value) else ("never" if math.isinf(value) else format(value, form))


def worst(values: list[float]) -> float:
    """The largest, a rest never reached (inf) the worst of all; nan when there is none."""
    known = [v for v in values if not math.isnan(v)]
    return max(known, default=math.nan)


def standing(values: list[float], goal: float) -> tuple[float, float] | None:
    """How a controller stands on a measure, the larger the better: the share of its rests
    (pump starts, days) within the goal, then how far its worst lies beyond it (nothing where
    every one is within it: a margin kept under a limit met everywhere is no lead); None with
    no values."""
    known = [v for v in values if not math.isnan(v)]
    if not known:
        return None
    return sum(v <= goal for v in known) / len(known), -max(max(known) - goal, 0.0)


MEASURES: tuple[tuple[str, str, float], ...] = (
    ("mash's worst error from 5 min after reaching (the pump's stops aside), °C", "err", 0.3),
    ("the same, the brewer's pump stops and the way back counted", "err_all", 0.3),
    ("mash's overshoot, °C", "over", 0.2),
    ("HLT's highest above the mash's setpoint + limit (once at or below it), °C", "hlt_above", 0.0),
    ("the same, the strike water's own heat counted", "hlt_above_all", 0.0),
    ("step time ÷ the fastest the limit allows", "ratio", 1.15),
    (
        "step time ÷ the fastest that keeps room for a stop's landing (no goal: its cost)",
        "ratio_room",
        1.15,
    ),
    ("HLT's fall at a pump start hermsd commands (element > load), °C", "fall_commanded", 0.3),
    (
        "HLT's fall at a pump start outside hermsd (a switch it only sees) ÷ at full power",
        "fall_ratio",
        1.2,
    ),
    ("the same, a pump outside hermsd unseen (no sense)", "fall_ratio_unseen", 1.2),
    ("alarms on a day", "alarms", 0.0),
)


def day_measures(day: dict[str, Any]) -> dict[str, list[float]]:
    """Per measure of MEASURES, the day's values."""
    rests, pumps = day["rests"], day["pumps"]
    commanded = [p["fall"] for p in pumps if p["by_hermsd"] and p["element_exceeds"]]
    outside = {
        seen: [
            p["fall"] / p["full_power_fall"]
            for p in pumps
            if not p["by_hermsd"] and p["seen"] == seen and p["full_power_fall"] >= 0.1
        ]
        for seen in (True, False)
    }
    keys = ("err", "err_all", "over", "hlt_above", "hlt_above_all", "ratio", "ratio_room")
    values = {key: [r[key] for r in rests] for key in keys}
    # A rest never begun: the program never got there, a miss unless the rest before it is out
    # of the limit's reach on the plant (the ideal never reaches it), which no controller can.
    out_of_reach = bool(rests) and math.isinf(rests[-1]["fastest_s"])
    missing = 0 if out_of_reach else len(day["setup"].rests) - len(rests)
    for key in ("err", "err_all", "ratio", "ratio_room"):
        values[key] += [math.inf] * missing
    return {
        **values,
        "fall_commanded": commanded,
        "fall_ratio": outside[True],
        "fall_ratio_unseen": outside[False],
        "alarms": [float(len(day["alarms"]))],
    }


def summary_table(days: list[dict[str, Any]]) -> str:
    lines = [
        "| measure | goal | " + " | ".join(NAMES.values()) + " | hermsd ahead of both |",
        "|---|---|---|---|---|---|",
    ]
    for title, key, goal in MEASURES:
        values = {
            c: [
                v
                for d in days
                if d["controller"] == c
                for v in day_measures(d)[key]
                if not math.isnan(v)
            ]
            for c in CONTROLLERS
        }
        worsts = {c: worst(values[c]) for c in CONTROLLERS}
        ranks = {c: standing(values[c], goal) for c in CONTROLLERS}
        mine = ranks["hermsd"]
        peers = [ranks[c] for c in CONTROLLERS[1:]]
        if mine is None:
            ahead = "—"
        elif all(p is not None and mine > p for p in peers):
            ahead = "yes"
        elif all(p is None or mine >= p for p in peers):
            ahead = "level"
        else:
            ahead = "no"
        cells = " | ".join(
            f"{number(worsts[c])} ({sum(v <= goal for v in values[c])} of {len(values[c])})"
            for c in CONTROLLERS
        )
        lines.append(f"| {title} | ≤ {goal:g} | {cells} | {ahead} |")
    exact = {
        c: [d["verify"].startswith("exact") for d in days if d["controller"] == c]
        for c in CONTROLLERS
    }
    cells = " | ".join(f"{sum(v)} of {len(v)}" for v in exact.values())
    lines.append(f"| `replay --verify` exact | every day | {cells} | |")
    return "\n".join(lines)


def setups_table(setups: list[SetUp]) -> str:
    lines = [
        "| set-up | plant | coil's load at the first pump start (strike − dough-in) "
        "| strike above the first rest + limit |",
        "|---|---|---|---|",
    ]
    for s in setups:
        load = s.coil_k * (s.strike_c - s.dough_c)
        side = "above" if load > s.watts else "below"
        above = s.strike_c - (s.rests[0][0] + s.limit)
        strike = f"yes, by {above:.2f} °C (warned)" if above > 0.0 else "no"
        lines.append(
            f"| {s.label} | {s.describe()} | {load / 1000:.1f} kW, {side} the element's "
            f"| {strike} |"
        )
    return "\n".join(lines)


def rests_table(days: list[dict[str, Any]]) -> str:
    lines = [
        "| set-up | rest °C | "
        + " | ".join(
            f"{NAMES[c]}: error / overshoot / HLT above / step ÷ fastest" for c in CONTROLLERS
        )
        + " |",
        "|---|---|---|---|---|",
    ]
    by = {(d["setup"].label, d["controller"]): d for d in days}
    setups = {d["setup"].label: d["setup"] for d in days}
    for label, s in setups.items():
        for index, (sp, _) in enumerate(s.rests):
            cells = []
            for c in CONTROLLERS:
                rests = by[(label, c)]["rests"]
                if index >= len(rests):
                    cells.append("not begun")
                    continue
                r = rests[index]
                cells.append(
                    f"{number(r['err'])} / {r['over']:+.2f} / {r['hlt_above']:+.2f} / "
                    f"{number(r['ratio'], '.3f')}"
                )
            lines.append(f"| {label} | {sp:g} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def pumps_table(days: list[dict[str, Any]]) -> str:
    """Per day: its pump starts with the mash in, the worst fall of those hermsd commanded
    where the element exceeds the load, the worst of those outside hermsd against full power."""
    lines = [
        "| set-up | controller | pump starts (element > load) | worst fall commanded, element "
        "> load °C | worst fall outside ÷ at full power (falls °C) |",
        "|---|---|---|---|---|",
    ]
    for d in days:
        pumps = d["pumps"]
        exceeds = sum(p["element_exceeds"] for p in pumps)
        commanded = [p["fall"] for p in pumps if p["by_hermsd"] and p["element_exceeds"]]
        outside = [
            (p["fall"] / p["full_power_fall"], p["fall"], p["full_power_fall"])
            for p in pumps
            if not p["by_hermsd"] and p["full_power_fall"] >= 0.1
        ]
        ratio = "—"
        if outside:
            r, fall, full = max(outside)
            ratio = f"{r:.2f} ({fall:.2f} / {full:.2f})"
        lines.append(
            f"| {d['setup'].label} | {NAMES[d['controller']]} | {len(pumps)} ({exceeds}) "
            f"| {number(worst(commanded))} | {ratio} |"
        )
    return "\n".join(lines)


def days_table(days: list[dict[str, Any]]) -> str:
    lines = [
        "| set-up | controller | program finished | alarms | a rest the limit cannot bring "
        "the mash to (said) | K learned ÷ the coil's | `replay --verify` | wall s |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for d in days:
        lines.append(
            f"| {d['setup'].label} | {NAMES[d['controller']]} | "
            f"{'yes' if d['finished'] else 'NO'} | {', '.join(d['alarms']) or 'none'} | "
            f"{'; '.join(d['short']) or 'none'} | {number(d['k_ratio'], '.3f')} | "
            f"{d['verify']} | {d['wall_s']:.1f} |"
        )
    return "\n".join(lines)


def seeds(text: str) -> list[int]:
    """'1-10' or '1,4,7' (or both: '1-3,9')."""
    found: list[int] = []
    for part in text.split(","):
        low, _, high = part.partition("-")
        found += range(int(low), int(high or low) + 1)
    return found


def main() -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--seeds", default="1-40", help="the drawn set-ups, e.g. 1-40 or 1,4,7")
    parser.add_argument("--jobs", type=int, default=1, help="processes to run the days in")
    parser.add_argument("--write", action="store_true", help="update bench/RESULTS.md")
    parser.add_argument(
        "--step-down", action="store_true", help=f"the rests {STEP_DOWN} (a step down)"
    )
    args = parser.parse_args()
    setups = [
        herms_day(False),
        herms_day(False, pump_seen=False),
        herms_day(True),
        *(draw(seed) for seed in seeds(args.seeds)),
    ]
    if args.step_down:
        setups = [dataclasses.replace(s, rests=STEP_DOWN) for s in setups]
    tasks = [(s, c) for s in setups for c in CONTROLLERS]
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        days = list(pool.map(run_day, tasks))
    text = "\n\n".join(
        [
            setups_table(setups),
            "Worst over the family (per measure, the worst rest, pump start or day; in "
            "brackets, how many of them meet the goal):",
            summary_table(days),
            "Per set-up and rest (error from 5 min °C / overshoot °C / HLT above the limit °C "
            "/ step ÷ fastest):",
            rests_table(days),
            "Pump starts with the mash in (the HLT's fall in 10 min below the lesser of its "
            "temperature at the start and its setpoint; at full power from the start's instant "
            "on a copy of the plant):",
            pumps_table(days),
            days_table(days),
        ]
    )
    print(text)
    if args.write:
        doc = [" ".join(paragraph.split()) for paragraph in (__doc__ or "").split("\n\n")]
        if args.step_down:
            sections.write(HEADING_DOWN, f"{doc[4]}\n\n{text}")
        else:
            sections.write(HEADING, "\n\n".join([*doc[1:4], text]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
