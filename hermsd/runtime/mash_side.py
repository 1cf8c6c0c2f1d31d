"""The mash side of a HERMS in the loop: the sensors beside the HLT's (the mash's, the coil
outlet's), read with the HLT's at its read interval, and the pump, switched as commanded.

With a mash sensor fitted, the brewer's setpoint is the mash's and the HLT's is the outer
loop's (`mash_control.py`); a mash sensor's fault holds the HLT at its last setpoint, a
warning in the status, not an alarm (the HLT's own sensor guards the heater). Every change
of the pump is an event in the log and a journal line; the pump is off at the start and at
the stop (docs/herms.md).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from typing import TYPE_CHECKING, TypedDict

from hermsd.config.schema import NOT_FITTED, ROLE_SENSORS, Config, SafetyConfig
from hermsd.control import predictive
from hermsd.control.cascade import HLT_MARGIN
from hermsd.control.learning import LearnedModel, ModelStore
from hermsd.hardware.lm92 import SensorError
from hermsd.program.runner import MashReading
from hermsd.runtime.loop_state import LoopState
from hermsd.runtime.mash_control import MashControl, coil_prior, mash_control
from hermsd.runtime.notify import mash_side_words
from hermsd.safety.coil_load import NO_LOAD, CoilLoad, MashWatch

if TYPE_CHECKING:
    from hermsd.hardware.pump_sense import PumpSense
    from hermsd.hardware.sensors.base import Sensor
    from hermsd.runtime.parts import Parts


class PumpNotFitted(ValueError):
    """The pump was commanded, but the config fits none."""


Said = tuple[int, str]
"""What a role's sensor has to say: a logging level and the message."""
COIL_SAFETY_SDS = 3.0
"""The learned K's uncertainties above it that the safety's bound on the coil's load takes as
its highest plausible value (a bound too narrow latches a false heater_not_heating)."""
NO_PUMP = "pump: no pump is fitted (set pump.backend in the config file and restart hermsd)"
SEEN_PUMP = (
    "pump: hermsd only sees this pump (pump.sense), it does not switch it (switch it where it "
    "is switched, or set pump.backend in the config file and restart hermsd)"
)


def pump_refusal(config: Config) -> str:
    """Why `set pump` is refused where no pump is fitted: none at all, or one only seen."""
    return SEEN_PUMP if config.pump.sense != NOT_FITTED else NO_PUMP


NO_FLOW = (
    "no flow through the coil: the pump runs but the mash does not take the coil's heat "
    "(a stuck bed, a pump running dry, a closed valve?)"
)
PUMP_SENSE_FAULT = "pump sense fault"
PUMP_UNSEEN = "(the pump taken as running unseen, as without a sense)"
FLOW_SEEN_C = 2.0
"""°C the coil outlet's reading must stand below the HLT's for wort to be seen flowing through
a pump hermsd does not switch: standing wort in the coil is at the HLT's temperature, and the
two sensors' tolerances are about 1 °C between them."""


class RoleSensor:
    """One sensor in a role beside the HLT's: its latest good reading, and its fault, said
    when it begins (after `safety.fault_reads` failed or implausible reads in a row, as the
    HLT's, by the safety section in force) and when it ends."""

    def __init__(self, role: str, sensor: Sensor) -> None:
        self.role = role
        self.sensor = sensor
        self.celsius: float | None = None  # None while faulty, or before a good read
        self.read_at = -math.inf  # when `celsius` was read (the loop's clock)
        self.fault: str | None = None
        self._failures = 0

    def start(self, safety: SafetyConfig, t: float = 0.0) -> Said | None:
        """Check the chip and read it once; what there is to say (a fault), else None. A
        chip that is wrong or missing is a fault from the start: the HLT does not need it."""
        try:
            self.sensor.identify()
            self.sensor.wake()
        except SensorError as error:
            self._failures = safety.fault_reads - 1
            return self._failed(str(error), safety)
        return self.read(safety, t)

    def read(self, safety: SafetyConfig, t: float = 0.0) -> Said | None:
        """Read once (at `t`); a fault begun or ended, else None."""
        try:
            celsius = self.sensor.read().celsius
        except SensorError as error:
            return self._failed(str(error), safety)
        low, high = safety.plausible_min, safety.plausible_max
        if not low <= celsius <= high:
            return self._failed(
                f"{celsius:.2f} °C is outside safety.plausible_min to plausible_max "
                f"({low:g} to {high:g} °C)",
                safety,
            )
        self._failures = 0
        self.celsius, self.read_at = celsius, t
        if self.fault is None:
            return None
        self.fault = None
        return logging.INFO, f"{self.role} sensor reads again: {celsius:.2f} °C"

    def _failed(self, why: str, safety: SafetyConfig) -> Said | None:
        self._failures += 1
        if self.fault is not None or self._failures < safety.fault_reads:
            return None  # the last good reading stands until the fault is declared
        self.fault, self.celsius = why, None
        return logging.WARNING, f"{self.role} sensor fault: {why} (the HLT is held as before)"


class SeenPump:
    """A pump hermsd does not switch, seen through its sense (`pump.sense`), read with the
    sensors: every change seen said; a sense that fails `safety.fault_reads` reads in a row
    is a fault, said when it begins and when it ends, and while it stands the pump is unseen
    (taken as hermsd takes a pump without a sense: never heat on a guess)."""

    def __init__(self, sense: PumpSense) -> None:
        self.sense = sense
        self.running: bool | None = None  # the last good read's (None before one)
        self.fault: str | None = None
        self._failures = 0

    @property
    def seen(self) -> bool | None:
        """The pump as seen now: None while the sense is faulty or before its first read."""
        return None if self.fault is not None else self.running

    def read(self, safety: SafetyConfig) -> list[Said]:
        """Read once; what there is to say (a change seen, a fault begun or ended)."""
        try:
            running = self.sense.running()
        except (SensorError, OSError) as error:
            self._failures += 1
            if self.fault is not None or self._failures < safety.fault_reads:
                return []  # the last good read stands until the fault is declared
            self.fault = str(error) or type(error).__name__
            return [(logging.WARNING, f"{PUMP_SENSE_FAULT}: {self.fault} {PUMP_UNSEEN}")]
        self._failures = 0
        said: list[Said] = []
        if self.fault is not None:
            self.fault = None
            said.append((logging.INFO, f"pump sense reads again: pump {_on_off(running)}"))
        if running != self.running:
            said.append((logging.INFO, f"pump seen {_on_off(running)}"))
        self.running = running
        return said


def _on_off(on: bool) -> str:
    return "on" if on else "off"


def role_sensors(parts: Parts) -> dict[str, RoleSensor]:
    """The fitted sensors beside the HLT's, by their config section."""
    given = {"mash_sensor": parts.mash_sensor, "coil_sensor": parts.coil_sensor}
    return {
        section: RoleSensor(ROLE_SENSORS[section], sensor)
        for section, sensor in given.items()
        if sensor is not None
    }


class MashSideFields(TypedDict):
    """What a period record holds of the mash side (`PeriodRecord`'s fields)."""

    mash: float | None
    coil: float | None
    pump: bool | None
    hlt_setpoint: float | None
    coil_load: float | None
    coil_load_met: bool | None
    cascade: str | None
    pump_in: float | None
    pump_stop_in: float | None
    coil_k: float | None


class MashSide(LoopState):
    """The Daemon's sensors beside the HLT's and its pump."""

    _roles: dict[str, RoleSensor]
    _seen_pump: SeenPump | None
    _pump_on: bool
    _mash_control: MashControl | None
    _mash_watch: MashWatch
    models: ModelStore | None

    if TYPE_CHECKING:  # the Daemon's

        @property
        def learned_model(self) -> LearnedModel | None: ...

        def _store_model(
            self, models: ModelStore, model: LearnedModel | None, refused: str | None, t: float
        ) -> None: ...

    # What the program last set the pump for: its step, the step's timer's turn, on or off.
    _program_pump_step: tuple[int, int, bool] | None
    # A prepared pump start: when the pump is switched on, why it was asked for, and the HLT's
    # PV when its preparation began.
    _pump_start_at: float | None = None
    _pump_start_reason = ""
    _pump_start_from: float | None = None
    # A program's pump start held while the HLT's heat would carry the mash past its rest
    # (`_program_pump`): why it was asked for, None when none is held; and whether it is
    # held on for want of a mash reading to judge it by (said once).
    _pump_held: str | None = None
    _held_unjudged = False

    @property
    def pump_fitted(self) -> bool:
        return self.outputs.pump is not None

    def set_pump(self, on: bool, reason: str, within: float = math.inf) -> None:
        """Run or stop the pump, said with `reason` (on the loop's thread: an operator's
        command at a period boundary, a program's step); PumpNotFitted when the config fits
        none. A start is prepared where the outer loop steers the HLT law: the coil's load
        is told the law at once, to begin a dead time on, and the pump runs then
        (`_pump_due`), so the heat sent meanwhile arrives as the load begins; a stop, or the
        daemon's, cancels a start still being prepared (docs/herms.md, "The pump start").
        `within`: the most s a start may be prepared for (a pump timer's turn due then)."""
        if self.outputs.pump is None:
            raise PumpNotFitted(pump_refusal(self.config))
        self._pump_held = None  # whoever asks now decides: a held start is not made later
        now = self._now()
        if on and not self._pump_on and self._pump_start_at is None:
            lead = min(self._pump_lead(), within)
            if lead > 0.0:
                self._pump_start_at, self._pump_start_reason = now + lead, reason
                self._event(
                    logging.INFO,
                    f"pump starting in {lead:.0f} s: {reason} (the coil's load sent ahead to "
                    "the element)",
                    now,
                )
                return
        if not on and self._pump_start_at is not None:
            self._pump_start_at = self._pump_start_from = None
            self._event(logging.INFO, f"pump start cancelled: {reason}", now)
        if on == self._pump_on or (on and self._pump_start_at is not None):
            return
        self._switch_pump(on, reason, now)

    def _switch_pump(self, on: bool, reason: str, t: float) -> None:
        pump = self.outputs.pump
        assert pump is not None  # set_pump and _pump_due switch only a fitted pump
        self._pump_on = on
        pump.set(on)
        self._event(logging.INFO, f"pump {'on' if on else 'off'}: {reason}", t)
        if not on:
            self._keep_coil(t)

    def _pump_lead(self) -> float:
        """s a pump start is prepared for: the HLT law's dead time where the outer loop
        steers it (a mash reading, the law predictive and stepped, auto, the heater allowed),
        else 0 (started at once: nothing would send the heat ahead). Where the coil's load
        exceeds the element the full dead time still serves: the element at full power
        from then is the most that can meet the load as it begins."""
        mash = self._roles.get("mash_sensor")
        lead = predictive.dead_time(self.controller)
        ready = (
            self._mash_control is not None
            and mash is not None
            and mash.celsius is not None
            and self.mode == "auto"
            and self.supervisor.heater_allowed
            and predictive.predicted_pv(self.controller) is not None
        )
        return lead if ready and lead is not None else 0.0

    def _pump_due(self, t: float, pv: float | None) -> float | None:
        """At a period: the prepared pump switched on once its start is due (within half a
        period), or as soon as the HLT's PV stands HLT_MARGIN above both its setpoint and
        where it stood as the preparation began (the heat sent ahead arrived before the
        law's dead time: a model's longer than the tun's would otherwise heat the HLT past
        its setpoint, over the limit in a climb); else the s still to go (None: no start
        pending). An HLT already above its setpoint as the start is asked (the heat of a
        climb still arriving while the pump stood) is no heat sent ahead: the start is
        prepared all the same, or the load would go unmet for the dead time."""
        due = self._pump_start_at
        if due is None:
            return None
        if self._pump_start_from is None:
            # Where the HLT was heading as the preparation began: heat still landing then (a
            # stop's, in a climb) is none sent ahead for the start.
            ahead = predictive.predicted_pv(self.controller)
            self._pump_start_from = pv if pv is None or ahead is None else max(pv, ahead)
        stood = self._pump_start_from if self._pump_start_from is not None else -math.inf
        arrived = pv is not None and pv > max(self.hlt_target(), stood) + HLT_MARGIN
        if t < due - 0.5 * self.config.control.period and not arrived:
            return due - t
        self._pump_start_at = self._pump_start_from = None
        self._switch_pump(True, self._pump_start_reason, t)
        return None

    def mash_reading(self) -> MashReading | None:
        """What a program times its rests on the mash by (None: no mash sensor fitted)."""
        mash = self._roles.get("mash_sensor")
        return None if mash is None else MashReading(mash.celsius)

    def _program_pump(self) -> None:
        """Switch the pump as the program's step says, once when the step begins (and once
        after a restart) and at each turn of its pump timer: `hermsd set pump` within a step
        stands until the next one, or the timer's next turn. A turn of the timer that starts
        the pump is prepared ahead of it like any start (`set_pump`), a dead time early; a
        step's first start waits while the HLT's heat would carry the mash past its rest
        (`_hold_or_start`)."""
        wanted = self.program.pump_step()
        runner = self.program.runner
        if runner is None or not self.pump_fitted:
            if runner is not None and wanted is not None and wanted[2]:
                self._warn_hand_start(wanted, runner.step.setpoint)
            self._program_pump_step, self._pump_held = wanted, None
            return
        reason = f"program {runner.program.name!r}, step {runner.step.name!r}"
        timer = runner.step.pump_timer
        if timer is not None:
            reason += f", pump off {timer[1] / 60.0:g} min every {timer[0] / 60.0:g} min"
        if wanted != self._program_pump_step:
            begins = wanted is not None and (
                self._program_pump_step is None or wanted[0] != self._program_pump_step[0]
            )
            self._program_pump_step, self._pump_held = wanted, None
            if wanted is not None and wanted[2] and begins and not self._pump_on:
                self._hold_or_start(reason, runner.step.setpoint)
            elif wanted is not None:
                self.set_pump(wanted[2], reason)
        elif self._pump_held is not None and not self._pump_on:
            self._hold_or_start(self._pump_held, runner.step.setpoint)
        turn_in = runner.pump_turn_in()
        if (
            turn_in is not None
            and not runner.pump
            and not self._pump_on
            and self._pump_start_at is None
            and turn_in <= self._pump_lead()
        ):
            self.set_pump(True, reason, within=turn_in)

    def _hold_or_start(self, reason: str, rest: float) -> None:
        """A step's pump start, held while the wort flowing would carry the mash past its
        `rest` on the HLT's stored heat alone (`_start_waits_for`), said once as it is held and
        once as it starts; else started (`set_pump`). The HLT cools meanwhile, readied no
        higher than the start's coast allows; `hermsd set pump on` starts it at once. A
        start held stays held while nothing can judge it (the mash's reading lost): heat
        carried into the mash cannot be taken back, a start made late can be made by hand."""
        waits = self._start_waits_for(rest)
        now = self._now()
        if waits is not None and self._pump_held is None:
            self._event(logging.WARNING, f"pump held: {waits}; it starts then", now)
        if waits is not None:
            self._pump_held, self._held_unjudged = reason, False
            return
        if self._pump_held is not None and self._start_inputs() is None:
            if not self._held_unjudged:
                self._held_unjudged = True
                self._event(
                    logging.WARNING,
                    "pump held on: no mash reading to judge its start by; it starts once one "
                    "says the HLT has cooled enough (`hermsd set pump on` starts it now)",
                    now,
                )
            return
        if self._pump_held is not None:
            hlt = predictive.predicted_pv(self.controller)
            at = "" if hlt is None else f": the HLT at {hlt:.1f} °C"
            self._event(logging.INFO, f"pump held no longer{at}", now)
        self.set_pump(True, reason)

    def _warn_hand_start(self, wanted: tuple[int, int, bool], rest: float) -> None:
        """A step whose pump hermsd does not switch (run by hand, only seen or not at all):
        where starting it now would carry the mash past its rest, the brewer is told once, as
        the step begins, what HLT to wait for (`_start_waits_for`)."""
        begun = self._program_pump_step
        if (begun is not None and begun[0] == wanted[0]) or self.pump_state:
            return  # not a step's beginning, or the pump seen running already
        waits = self._start_waits_for(rest)
        if waits is not None:
            self._event(logging.WARNING, f"wait to start the pump: {waits}", self._now())

    def _start_waits_for(self, rest: float) -> str | None:
        """Whether a pump start now would carry the mash past its `rest` on the HLT's stored
        heat (`MashControl.start_waits_for`: a strike held hotter than the rest needs, with
        more heat above the rest's HLT than the mash lacks): the words that say so, with the
        HLT to wait for; None where it would not, or nothing tells (`_start_inputs`)."""
        inputs = self._start_inputs()
        if inputs is None:
            return None
        control, reading, hlt = inputs
        below = control.start_waits_for(rest, reading, hlt)
        if below is None:
            return None
        return (
            f"the HLT at {hlt:.1f} °C holds more heat than the mash at {reading:.1f} °C needs "
            f"for its rest {rest:g} °C, and wort flowing now would carry the mash past it: "
            f"the HLT below {below:.1f} °C lands it there"
        )

    def _start_inputs(self) -> tuple[MashControl, float, float] | None:
        """What a pump start is judged by: the outer loop, the mash's reading and the HLT's
        prediction; None where any is missing (no mash reading, a law with no prediction)."""
        control, mash = self._mash_control, self._roles.get("mash_sensor")
        hlt = predictive.predicted_pv(self.controller)
        reading = None if mash is None else mash.celsius
        if control is None or reading is None or hlt is None:
            return None
        return control, reading, hlt

    def _timer_stopped(self) -> bool:
        """Whether the program's pump timer has the pump stopped now (its restart due)."""
        runner = self.program.runner
        return (
            runner is not None
            and not self._pump_on
            and not runner.pump
            and runner.pump_turn_in() is not None
        )

    def _timer_stop_in(self) -> float | None:
        """s until the program's pump timer stops the running pump, once that is within the
        HLT law's dead time (`_pump_lead`): the coil's load told to end then. None: no stop
        that near."""
        runner = self.program.runner
        if runner is None or not self._pump_on or not runner.pump:
            return None
        turn_in = runner.pump_turn_in()
        return turn_in if turn_in is not None and turn_in <= self._pump_lead() else None

    def _start_mash_side(self) -> None:
        self._pump_on = False
        self._pump_held = None
        self._program_pump_step = None
        self._mash_watch = MashWatch()
        for role in self._roles.values():
            self._say_role(role.start(self.config.safety, self._now()))
        self._read_pump_sense()

    def _read_mash_side(self) -> None:
        """Read each sensor beside the HLT's, and refresh the pump's switch (a relay board's
        off is said again now and then: `GuardedSwitch`)."""
        for role in self._roles.values():
            self._say_role(role.read(self.config.safety, self._now()))
        self._read_pump_sense()
        if self.outputs.pump is not None:
            self.outputs.pump.set(self._pump_on)

    def _read_pump_sense(self) -> None:
        if self._seen_pump is not None:
            for said in self._seen_pump.read(self.config.safety):
                self._say_role(said)

    def _say_role(self, said: Said | None) -> None:
        if said is not None:
            self._event(*said, self._now())

    def _stop_mash_side(self, reason: str, t: float) -> None:
        """Said when the stop switched a running pump off (with every output), or cancelled
        a start still being prepared; the coil's K learned so far kept, as at any pump stop
        (a day ended with the pump running taught it as well)."""
        if self._pump_start_at is not None:
            self._pump_start_at = self._pump_start_from = None
            self._event(logging.INFO, f"pump start cancelled: {reason}", t)
        if self._pump_on:
            self._pump_on = False
            self._event(logging.INFO, f"pump off: {reason}", t)
        self._keep_coil(t)

    @property
    def pump_state(self) -> bool | None:
        """The pump as hermsd knows it: as switched, or as seen through its sense; None when
        it is not known (none fitted and none seen, or the sense faulty)."""
        if self.pump_fitted:
            return self._pump_on
        return None if self._seen_pump is None else self._seen_pump.seen

    @property
    def pump_running(self) -> bool:
        """The pump as the outer loop takes it: as known, or, not known, running (the brewer
        runs it by hand; a stopped one leaves the HLT at the limit at most)."""
        state = self.pump_state
        return True if state is None else state

    def _draw_began_unannounced(self) -> bool:
        """Whether the coil began to draw in the period just stepped with no start prepared
        for it (`MashControl.unannounced`), told once: the window after it sends its pulse
        from its start (`TimeProportionalPlanner.plan`'s `at_once`)."""
        control = self._mash_control
        if control is None or not control.unannounced:
            return False
        control.unannounced = False
        return True

    def _steer(self, pv: float | None, applied: float, t: float) -> float:
        """The HLT law's setpoint for this period: with a mash sensor fitted the outer
        loop's, stepped on this period's HLT PV (none: the last decision stands), the coil's
        load fed forward to the law (a prepared pump start's ahead of it, one hermsd does not
        switch as soon as it is seen); without one, the brewer's, as on a program's step
        before the mash is in (the strike water is the HLT's). A mash reading lost or stale
        holds the HLT at its last setpoint, said when it begins and ends."""
        pump_in = self._pump_due(t, pv)
        control = self._mash_control
        if control is None or pv is None:
            return self.hlt_target()
        runner = self.program.runner
        if runner is not None and not runner.on_mash(self.mash_reading()):
            stopped = self.pump_state is False
            strike = control.strike(
                self.controller,
                self.setpoint,
                hlt_pv=pv,
                applied=applied,
                stopped=stopped,
                mash_pv=self._roles["mash_sensor"].celsius,
            )
            return strike.hlt_setpoint
        mash = self._roles["mash_sensor"]
        before, was_stuck = control.decision, control.flow.stuck
        seen = self._flow_seen(pv)
        decision = control.period(
            self.controller,
            mash_sp=self.setpoint,
            mash_pv=mash.celsius,
            mash_age=t - mash.read_at,
            hlt_pv=pv,
            pump=self.pump_running,
            pump_known=self.pump_state is not None or seen,
            applied=applied,
            t=t,
            pump_in=pump_in,
            pump_stop_in=self._timer_stop_in(),
            timer_stop=self._timer_stopped(),
            start_held=self._pump_held is not None,
        )
        was_held = before is not None and before.held is not None
        if decision.held is not None and not was_held:
            self._event(
                logging.WARNING,
                f"{decision.held}: the HLT is held at {decision.hlt_setpoint:.2f} °C",
                t,
            )
        elif decision.held is None and was_held:
            self._event(logging.INFO, "mash reading again: the HLT steered by the mash", t)
        if control.flow.stuck and not was_stuck:
            self._event(
                logging.WARNING,
                f"{NO_FLOW}: the HLT readied at {decision.hlt_setpoint:.2f} °C till it flows",
                t,
            )
        elif was_stuck and not control.flow.stuck:
            why = "the wort flows again" if self.pump_running else "the pump stopped"
            self._event(logging.INFO, f"no flow through the coil ended: {why}", t)
        self._say_reach(control.reach_said, t)
        return decision.hlt_setpoint

    def _flow_seen(self, hlt: float) -> bool:
        """Wort seen flowing through a pump hermsd does not switch: the coil outlet's good
        reading more than FLOW_SEEN_C below the HLT's (`hlt`), where standing wort would be
        at the HLT's temperature. False with the pump known (switched, or its sense read), without
        a coil outlet sensor, or while the two stand too close to tell (the HLT near the
        mash: little load to feed then)."""
        coil = self._roles.get("coil_sensor")
        if self.pump_state is not None or coil is None or coil.celsius is None:
            return False
        return hlt - coil.celsius > FLOW_SEEN_C

    def with_coil(self, model: LearnedModel) -> LearnedModel:
        """`model` to be stored, with the coil's K: today's once the pump runs taught it,
        else the one stored before, with a tun's model or alone (the next day's prior)."""
        control = self._mash_control
        coil = None if control is None else control.coil.estimate()
        if coil is not None and coil.source != "prior":
            return dataclasses.replace(model, coil=coil.conductance, coil_sd=coil.sd)
        kept = self.learned_model
        if kept is None or model.coil > 0.0:
            return model
        return dataclasses.replace(model, coil=kept.coil, coil_sd=kept.coil_sd)

    def _keep_coil(self, t: float) -> None:
        """Store the coil's K learned so far, as the pump stops: with the tun's model, or
        alone while none is stored (`ModelStore.save_coil`: no tun's fields made up)."""
        models = self.models
        if models is None or self.config.control.learn != "on":
            return
        pending = "model" in self.saver.waiting()  # looked at first: one done since is taken
        self._take_saves(t)
        kept = self.learned_model
        if kept is None:
            coil = None if self._mash_control is None else self._mash_control.coil.estimate()
            if not pending and coil is not None and coil.source == "learned":
                k, sd, wall_ns = coil.conductance, coil.sd, self.clock.wall_ns()
                self.saver.save("coil", lambda: models.save_coil(k, sd, wall_ns), coil)
                self._take_saves(t)
            return
        model = self.with_coil(kept)
        if (model.coil, model.coil_sd) != (kept.coil, kept.coil_sd):
            self._store_model(models, model, None, t)

    def _remake_mash_control(self, config: Config) -> None:
        """A reload that changed the herms section, the tun, its model or the SSR's output
        (its pulses' swing, `Tanks.hlt_ripple`): the outer loop made again for them (its step
        starts afresh), the coil's K as learned so far kept, and what else the day measured
        that the new config does not change (`MashControl.carry`)."""
        control = self._mash_control
        if control is None:
            return
        coil = control.coil.estimate()
        prior = coil if coil.source != "prior" else coil_prior(config, self.learned_model)
        self._mash_control = mash_control(config, self.model, prior)
        self._mash_control.carry(control)
        if control.flow.stuck:  # the new outer loop's watch judges the flow afresh
            why = "the outer loop made again for the reloaded config, the flow judged afresh"
            self._event(logging.INFO, f"no flow through the coil ended: {why}", self._now())
        # The HLT's most may have moved (the limit, safety.max_temp): its level measured afresh.
        why = "the outer loop made again for the reloaded config"
        self._say_reach(control.reach.restart(why), self._now())

    def hlt_target(self) -> float:
        """The HLT law's setpoint in force: the outer loop's last, else the brewer's."""
        decision = None if self._mash_control is None else self._mash_control.decision
        return self.setpoint if decision is None else decision.hlt_setpoint

    def mash_side_fields(self) -> MashSideFields:
        """The period record's mash, coil outlet and pump (None: not fitted, or faulty; the
        pump as switched or seen, `pump_state`), and the outer loop's HLT setpoint, coil load
        and phase (None: no mash sensor)."""
        mash, coil = self._roles.get("mash_sensor"), self._roles.get("coil_sensor")
        control = self._mash_control
        decision = None if control is None else control.decision
        return {
            "mash": None if mash is None else mash.celsius,
            "coil": None if coil is None else coil.celsius,
            "pump": self.pump_state,
            "hlt_setpoint": None if decision is None else decision.hlt_setpoint,
            "coil_load": None if decision is None else decision.load_watts,
            "coil_load_met": None if decision is None or decision.load_met else False,
            "cascade": None if decision is None else decision.phase,
            "pump_in": None if control is None or not control.load_in else control.load_in,
            "pump_stop_in": (
                None if control is None or math.isinf(control.load_until) else control.load_until
            ),
            "coil_k": None if control is None or not control.load_basis else control.load_basis,
        }

    def coil_load(self, hlt: float | None) -> CoilLoad:
        """The coil's load on the HLT at `hlt` °C, for the supervisor's heat balances: none
        without a mash sensor (no HERMS known) or with the pump known stopped; counted with a
        pump not known (not switched, not seen), which may be running; a faulty mash sensor's
        mash bounded from its last good reading (docs/herms.md, "The coil and the safety")."""
        mash = self._roles.get("mash_sensor")
        if mash is None or hlt is None:
            return NO_LOAD
        pump = self.pump_state
        learned = None  # the day's K narrows the bound; a prior or yesterday's does not
        coil = None if self._mash_control is None else self._mash_control.coil.estimate()
        if coil is not None and coil.source == "learned":
            learned = (coil.conductance, coil.conductance + COIL_SAFETY_SDS * coil.sd)
        herms = self.config.herms
        return self._mash_watch.load(
            self._now(),
            hlt,
            mash.celsius,
            pump,
            max_flow=herms.max_coil_flow,
            litres=herms.mash_litres,
            grain_kg=herms.grain_kg,
            lags=(herms.hose_s, herms.mash_sensor_lag),
            conductance=learned,
        )

    def mash_words(self) -> str:
        """The status line's 'mash 64.8 → 65.0 °C (climb), pump on' (`notify.mash_side_words`)."""
        return mash_side_words(
            self.role_status()["mash"], self.mash_side_fields()["pump"], self.setpoint
        )

    def role_status(self) -> dict[str, dict[str, object] | None]:
        """The status reply's `mash` and `coil`: null when not fitted, else the reading (°C,
        null while faulty) and the fault in words (null when there is none); the mash's also
        the HLT's setpoint the outer loop chose and its phase (null before its first period),
        and where the mash levels out while that is short of its rest (`levels_at`)."""
        status: dict[str, dict[str, object] | None] = {}
        for section, role in ROLE_SENSORS.items():
            sensor = self._roles.get(section)
            key = role.split()[0]
            status[key] = (
                None if sensor is None else {"celsius": sensor.celsius, "fault": sensor.fault}
            )
        mash, control = status["mash"], self._mash_control
        if mash is not None and control is not None:
            decision = control.decision
            mash["hlt_setpoint"] = None if decision is None else decision.hlt_setpoint
            mash["phase"] = None if decision is None else decision.phase
            mash["warning"] = NO_FLOW if control.flow.stuck else control.short
            mash["levels_at"] = control.reach.ceiling
            due = self._pump_start_at
            mash["pump_start_in"] = None if due is None else max(0.0, due - self._now())
            runner = self.program.runner
            turn = None if runner is None or not self.pump_fitted else runner.pump_turn_in()
            mash["pump_turn_in"] = turn
        return status

    def _now(self) -> float:
        return self.clock.monotonic()
