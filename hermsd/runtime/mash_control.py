"""The HERMS's outer loop in the daemon: with a mash sensor fitted the brewer's (and the
program's) setpoint is the mash's, and the HLT law holds the HLT at the setpoint the outer
loop chooses (`control/cascade.py`), with the coil's load fed forward
(`predictive.known_load`) and the coil's conductance learned from the day's pump runs
(`control/coil.py`). Derivation: docs/mash-control.md.

A mash reading that is missing, faulty or stale holds the HLT at its last setpoint, said in
the status: never full heat on a guess.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

from hermsd.config.schema import Config
from hermsd.control import pid, predictive
from hermsd.control.cascade import (
    MIN_CONDUCTANCE,
    SETPOINT_MOVE,
    STRIKE,
    Cascade,
    Decision,
    Tanks,
)
from hermsd.control.coil import CoilEstimate, CoilEstimator, prior_estimate
from hermsd.control.factory import total_watts
from hermsd.control.flow_watch import FlowWatch
from hermsd.control.learning import LearnedModel
from hermsd.control.reach import ReachWatch, Said
from hermsd.metrics import BAND
from hermsd.runtime.build import water_swing
from hermsd.safety.coil_load import mash_capacity

CUT_OUT_MARGIN = 1.0
"""°C the HLT's setpoint stays below safety.max_temp: the HLT law's overshoot is a tenth."""
MASH_PREFIX = "the mash levels out"
"""How every event of the mash's reach warning begins (replay finds them by it)."""
MOST_SLACK = 0.01
"""°C under the HLT's most that an HLT setpoint may lie and still be at it (two reckonings
of one float)."""
STEERED = ("climb", "coast", "hold")
"""The outer loop's phases in which the coil's heat reaches the mash as the HLT is steered."""


def mash_short_words(config: Config, cascade: Cascade) -> Callable[[float, float, float], str]:
    """The mash's reach warning in the brewer's words, (level, rest, the HLT's most) in,
    naming the key that sets `cascade`'s ceiling for the rest: the limit over the mash's
    rest, or safety.max_temp where that is lower."""
    limit, hlt_max = config.herms.max_hlt_above_mash, config.safety.max_temp - CUT_OUT_MARGIN

    def words(level: float, rest: float, most: float) -> str:
        key = (
            f"herms.max_hlt_above_mash ({limit:g} °C)"
            if cascade.ceiling(rest) < hlt_max
            else f"safety.max_temp ({config.safety.max_temp:g} °C)"
        )
        return (
            f"{MASH_PREFIX} near {level:.1f} °C with the HLT at its most ({most:.1f} °C), "
            f"{rest - level:.1f} °C short of its rest {rest:g} °C: raise {key}, insulate "
            "the mash tun, or lower the rest"
        )

    return words


ROOM_SEEN = (-5.0, 40.0)
"""°C: an empty mash tun's reading taken for the room (a brewery's, winter garage to summer
kitchen); one above it is a tun preheated, or the grain in."""


class MashControl:
    """The outer loop, the coil's estimator and the last period's decision."""

    def __init__(
        self,
        cascade: Cascade,
        coil: CoilEstimator,
        flow: FlowWatch,
        element_watts: float,
        reach: ReachWatch,
        delays: float,
    ) -> None:
        """`reach`: the mash's reach watch; `delays`: s between the coil and the mash's
        sensor (the hoses' round trip and the sensor's lag), its rise's dead time."""
        self.cascade = cascade
        self.coil = coil
        self.flow = flow
        self.element_watts = element_watts
        self.reach = reach
        self.delays = delays
        self._rest: float | None = None  # the mash's setpoint the reach watch last had
        self.reach_said: Said | None = None  # what the reach watch said this period
        self.short: str | None = None  # the reach warning's words while it stands
        self.decision: Decision | None = None  # None until the first period with a PV
        self.load_in = 0.0  # s until the load fed forward begins (a prepared pump start)
        self.load_until = math.inf  # s until it ends (a stop the program's timer announces)
        self.load_basis = 0.0  # the coil's K (W/K) the load was reckoned on (0: no load)
        # The coil's load began this period, the last fed none and no start prepared for it
        # (a pump hermsd only sees, wort flowing again): the law's heat for it comes late.
        self.unannounced = False
        self._room_seen = math.inf  # °C, the empty tun's lowest reading (`strike`)

    def period(
        self,
        controller: pid.Controller,
        *,
        mash_sp: float,
        mash_pv: float | None,
        mash_age: float,
        hlt_pv: float,
        pump: bool,
        pump_known: bool,
        applied: float,
        t: float,
        pump_in: float | None = None,
        pump_stop_in: float | None = None,
        timer_stop: bool = False,
        start_held: bool = False,
    ) -> Decision:
        """One control period, before the HLT law's step: the coil's estimator fed the
        period just ended (only with a pump hermsd switches or sees: one run by hand unseen
        may stand, and a K learned while it did would be none), the flow through the coil
        judged from it (while none flows nothing is learned of K, the outer loop takes the
        pump as stopped, and the mash's losses it learned since the flow stopped are
        forgotten), the outer loop stepped (on the law's predicted PV where it has one: the
        heat already sent counted), the coil's load fed forward to the law. `pump_in`: a
        pump start prepared, due in so many s: the load it will draw, K (its estimate, not
        one sd low: half the pull unmet would be the prior's) times the HLT over the mash,
        told the law now to begin then, so the heat sent meanwhile arrives as the load
        begins. `pump_stop_in`: a stop the program's pump timer makes, due in so many s: the
        load told the law to end then, so the heat sent from a dead time before it is the
        water's alone and the HLT does not rise past its limit as the coil stops drawing.
        `timer_stop`: the pump stopped by that timer, its restart due (`Cascade.step`'s
        `paused`). `start_held`: a program's start held while the HLT's heat would carry the
        mash past its rest (`start_waits_for`; `Cascade.step`'s `waiting`). `t`: the loop's
        clock (s), for the mash's reach watch."""
        before, preparing = self.decision, self.load_in > 0.0
        self._room_seen = math.inf  # the mash is in: a later strike step reads the room afresh
        known = pump and pump_known
        exchange = self.coil.period(
            hlt=hlt_pv, mash=mash_pv, applied=applied, pump=known, stopped=not pump
        )
        coil = self.coil.estimate()
        # A step down's stretch is not judged: the coil's heat goes one way and back as the
        # HLT falls under the mash and is lifted again, and over the stretch it nets to
        # less than the tanks' models misjudge (docs/mash-control.md, "A step down").
        changed = self.flow.period(
            None if self.cascade.descending else exchange,
            mash_pv,
            pump=known,
            mash_loss=self.cascade.mash_loss,
            room=self.cascade.room,
            k=self.coil.flow_low(coil),
        )
        if self.flow.stuck:
            self.coil.no_flow()
            if changed and self.flow.loss_before is not None:
                self.cascade.mash_loss = self.flow.loss_before
        ahead = predictive.predicted_pv(controller)
        hlt = hlt_pv if ahead is None else ahead
        decision = self.cascade.step(
            mash_sp=mash_sp,
            mash_pv=mash_pv,
            mash_age=mash_age,
            hlt_pv=hlt,
            pump=pump,
            coil=coil,
            flowing=not self.flow.stuck,
            paused=timer_stop,
            starting=pump_in is not None,
            waiting=start_held,
            hlt_reading=hlt_pv,
        )
        if not pump_known:  # a pump run by hand may stand: no load fed that may not be drawn
            decision = dataclasses.replace(decision, load_watts=0.0)
        starts_in = 0.0
        if pump_in is not None and mash_pv is not None and decision.held is None:
            prepared = self.cascade.prepared_load(
                hlt, mash_pv, decision.hlt_setpoint, coil.conductance, mash_sp
            )
            decision = dataclasses.replace(decision, load_watts=prepared)
            starts_in = pump_in
        ends_in = math.inf if pump_stop_in is None else max(pump_stop_in, starts_in)
        predictive.known_load(
            controller,
            decision.load_watts,
            self.element_watts,
            starts_in,
            ends_in,
            basis=coil.conductance,
            met=decision.load_met,
        )
        self.load_in, self.load_until, self.load_basis = starts_in, ends_in, coil.conductance
        k = max(coil.conductance, MIN_CONDUCTANCE)
        self._watch_reach(t, decision, mash_sp, mash_pv, hlt_pv, k, timer_stop or not pump)
        self.decision = decision
        fed = before is not None and before.load_watts > 0.0
        acts = decision.load_watts > 0.0 and starts_in == 0.0
        self.unannounced = acts and not (fed or preparing)
        return decision

    def start_waits_for(self, mash_sp: float, mash_pv: float, hlt: float) -> float | None:
        """The HLT (°C) a pump start waits for lest the HLT's stored heat carry the mash past
        `mash_sp`, None where it need not wait (`Cascade.start_waits_for`, on the coil's K as
        the day knows it)."""
        return self.cascade.start_waits_for(mash_sp, mash_pv, hlt, self.coil.estimate())

    def carry(self, before: MashControl) -> None:
        """What `before`, the mash control a reload replaces, measured of the day: the room
        read, the mash's losses, the HLT model's error (`Cascade.carry`,
        `CoilEstimator.carry`) and the empty tun's lowest reading so far."""
        self.cascade.carry(before.cascade)
        self.coil.carry(before.coil)
        self._room_seen = before._room_seen

    def _watch_reach(
        self,
        t: float,
        decision: Decision,
        mash_sp: float,
        mash_pv: float | None,
        hlt_pv: float,
        k: float,
        paused: bool,
    ) -> None:
        """Feed the mash's reach watch: "full power" is the HLT steered to its most
        (`Cascade.most`) and standing within the band of it, so that the mash's rise is
        the most the limit allows; a rest changed restarts it (the HLT's most moves with
        the rest); the pump stopped pauses its run (a timer's stop, a stir, a pump run outside
        hermsd stopped a while: the mash's rise goes on as before once the wort flows again,
        and a run ended at each of a timer's stops would never be measured whole)."""
        said = None
        if self._rest is not None and abs(mash_sp - self._rest) > SETPOINT_MOVE:
            said = self.reach.restart("the rest changed")
        self._rest = mash_sp
        most = None if mash_pv is None else self.cascade.most(mash_sp, mash_pv, k)
        full = (
            most is not None
            and decision.held is None
            and decision.phase in STEERED
            and decision.hlt_setpoint >= most - MOST_SLACK
            and hlt_pv >= decision.hlt_setpoint - BAND
        )
        news = self.reach.period(t, mash_sp, mash_pv, full, self.delays, most or 0.0, paused=paused)
        self.reach_said = news or said
        if self.reach_said is not None:
            self.short = self.reach_said.message if self.reach_said.raised else None

    def strike(
        self,
        controller: pid.Controller,
        setpoint: float,
        *,
        hlt_pv: float,
        applied: float,
        stopped: bool,
        mash_pv: float | None = None,
    ) -> Decision:
        """A program's step before the mash is in (the strike water): the step's setpoint
        is the HLT's own, no load fed forward. The mash sensor then reads an empty tun (the
        room), which the outer loop would take for a mash far below its rest and ready the
        HLT to the limit above the strike: heat that coasts the mash past its first rest.
        The coil's estimator is fed the HLT (`stopped`: the pump known to stand), whose hold
        there shows its model's error (`CoilEstimator.offset`). The empty tun's lowest reading
        in ROOM_SEEN (`mash_pv`; a grain doughed in reads warmer) is the room the outer loop
        reckons the tanks' losses to (`Cascade.room_seen`)."""
        self.coil.period(hlt=hlt_pv, mash=None, applied=applied, pump=False, stopped=stopped)
        low, high = ROOM_SEEN
        if mash_pv is not None and low <= mash_pv <= min(high, self._room_seen):
            self._room_seen = mash_pv
            self.cascade.room_seen(mash_pv)
        self.decision = Decision(setpoint, 0.0, STRIKE)
        self.unannounced = False
        predictive.known_load(controller, 0.0, self.element_watts)
        self.load_in, self.load_until, self.load_basis = 0.0, math.inf, 0.0
        return self.decision


def coil_prior(
    config: Config, stored: LearnedModel | None, alone: tuple[float, float] | None = None
) -> CoilEstimate:
    """The coil's K before today's pump runs: the one learned on an earlier day (with the
    tun's model, else `alone`: `ModelStore.load_coil`), else the config's `herms.coil_w_per_k`."""
    if stored is not None and stored.coil > 0.0:
        return CoilEstimate(stored.coil, stored.coil_sd, "stored")
    if alone is not None:
        return CoilEstimate(*alone, "stored")
    return prior_estimate(config.herms.coil_w_per_k)


def mash_control(config: Config, model: pid.PlantModel, prior: CoilEstimate) -> MashControl:
    """The outer loop for `config`, on the HLT law's `model` (its heat capacity and losses:
    C_h = P/rate, UA_h = C_h/τ, and the water's swing under the SSR's pulses), the coil's K
    starting from `prior`."""
    herms, period = config.herms, config.control.period
    watts = total_watts(config)
    hlt_capacity = watts / model.rate
    hlt_loss = hlt_capacity / model.tau
    tanks = Tanks(
        hlt_capacity=hlt_capacity,
        hlt_loss=hlt_loss,
        mash_capacity=mash_capacity(herms.mash_litres, herms.grain_kg),
        mash_loss=herms.mash_loss_w_per_k,
        room=model.ambient,
        hose_delay=herms.hose_s,
        mash_lag=herms.mash_sensor_lag,
        hlt_dead_time=model.dead_time,
        hlt_ripple=0.5 * water_swing(config, model),
        hlt_power=watts,
    )
    cascade = Cascade(
        tanks,
        limit=herms.max_hlt_above_mash,
        hlt_max=config.safety.max_temp - CUT_OUT_MARGIN,
        period=period,
    )
    coil = CoilEstimator(
        hlt_capacity=hlt_capacity,
        hlt_loss=hlt_loss,
        room=model.ambient,
        element_watts=watts,
        dead_time=model.dead_time,
        period=period,
        prior=prior,
    )
    flow = FlowWatch(
        hlt_capacity=hlt_capacity,
        mash_capacity=tanks.mash_capacity,
        delays=herms.hose_s + herms.mash_sensor_lag,
        period=period,
    )
    reach = ReachWatch(MASH_PREFIX, "the mash", mash_short_words(config, cascade))
    return MashControl(cascade, coil, flow, watts, reach, tanks.hose_delay + tanks.mash_lag)
