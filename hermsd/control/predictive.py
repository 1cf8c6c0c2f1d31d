"""The predictive controller: a model of the tun and an observer of it, the PV that will be
after the dead time, and the duty that holds it; the daemon's default (see hermsd/control/pid.py
for the equations)."""

from __future__ import annotations

import copy
import math
from collections import deque
from collections.abc import Sequence

from hermsd.control.linsys import observer_gains
from hermsd.control.pid import (
    BIAS_INNOVATION_CLIP,
    COLDEST_POUR,
    DROP_FALL,
    DROP_ONSET,
    DROP_READINGS,
    DROP_SD,
    FAR_BAND,
    FULL_MARGIN,
    LANDING_BAND,
    LANDING_TRUST,
    LINEAR_BAND,
    LOAD_SHARE_RANGE,
    LOAD_SHARE_S,
    MAX_DEAD_TIME,
    MAX_RECOVERY_HOLD,
    MISSING_HEAT_BIAS_S,
    OBSERVER_BIAS_S,
    OBSERVER_TRACK_S,
    PREDICTED_LOOP_FACTOR,
    PULSE_AIM_SHARE,
    PULSE_LEAST_STEP,
    PULSE_MARGIN,
    PULSE_RATE_MARGIN,
    RATE_BAND,
    RUNAWAY_SHARE,
    SCATTER_CAP,
    SCATTER_PERIODS,
    SENSOR_LSB,
    STEADY_BAND,
    STEADY_DUTY_SHARE,
    STEADY_SPAN_S,
    STEP_INNOVATION,
    TRAILING_S,
    Controller,
    Params,
    PlantModel,
    _Base,
)
from hermsd.control.watches import (
    GAP_GONE,
    HEAT_SHOWS_S,
    HeatUpFit,
    LineFit,
    _HeatUpWatch,
    _PourGap,
    _PulseWatch,
    _RecoveryStall,
    _RecoveryWatch,
)


class _Predictive(_Base):
    """P on the PV the observer predicts one dead time ahead, plus the holding duty."""

    __slots__ = (
        "_above",
        "_ambient",
        "_arm_rate",
        "_arrival",
        "_bias",
        "_carried",
        "_cold_water",
        "_dead_time",
        "_estimate",
        "_fa",
        "_fade",
        "_filtered",
        "_fit",
        "_fpv",
        "_gains",
        "_held_sp",
        "_inputs",
        "_kc",
        "_kc_far",
        "_kc_near",
        "_kd",
        "_l2_share",
        "_lag",
        "_lag_share",
        "_landing_sp",
        "_load",
        "_load_basis",
        "_load_in",
        "_load_met",
        "_load_past",
        "_load_share",
        "_load_until",
        "_loss",
        "_measured",
        "_missing_gains",
        "_pour_gap",
        "_poured",
        "_pulse",
        "_pulse_sp",
        "_pulsed",
        "_pvs",
        "_rate",
        "_recent",
        "_recovering",
        "_recovery",
        "_scatter",
        "_sensor_lag",
        "_stall",
        "_stalled_gains",
        "_step_is_loops",
        "_trailing",
        "_ts",
        "_watch",
    )

    def __init__(self, params: Params, model: PlantModel) -> None:
        super().__init__(params)
        ts = params.ts
        self._ts = ts
        self._kc = params.kc
        self._kd = params.kc * params.td / ts
        self._filtered = params.tf > 0.0
        self._fa = params.tf / (params.tf + ts)
        self._loss = 1.0 / model.tau  # 1/s
        self._ambient = model.ambient
        self._measured = model.measured
        self._rate = self._kc_near = self._kc_far = self._dead_time = 0.0
        self._lag, self._lag_share = 0, 0.0
        # The sensor's first-order lag (s) inside the dead time, the duty its filter passes
        # on now, and the share of a gap to it that survives a period (0: a pure delay).
        self._sensor_lag = self._fade = self._arrival = 0.0
        self._use(model.rate, model.dead_time)
        # Observer poles: the PV estimate follows the sensor within OBSERVER_TRACK_S, the bias
        # (what the model gets wrong) within ti; see `observer_gains`.
        bias_s = params.ti or OBSERVER_BIAS_S
        self._gains = observer_gains(ts, OBSERVER_TRACK_S, bias_s)
        self._missing_gains = observer_gains(ts, OBSERVER_TRACK_S, min(bias_s, MISSING_HEAT_BIAS_S))
        # A landing that stalls short (`_landing_stalled`) is learned at that pace on two
        # elements too: `on_two_elements` leaves these.
        self._stalled_gains = self._missing_gains
        # The setpoint the water last reached with nothing the law knows of since (NaN:
        # none): a fall from it is heat missing (`_heat_missing`).
        self._held_sp = math.nan
        # The setpoint of the heat-up whose landing is under way (NaN: none): one that stalls
        # short of it is heat missing too.
        self._landing_sp = math.nan
        # u_{k-1-lag} … u_{k-1} at the right end; room for any dead time a heat-up may show
        self._inputs: deque[float] = deque(maxlen=math.ceil(MAX_DEAD_TIME / ts) + 2)
        self._recent: deque[float] = deque(maxlen=max(2, round(STEADY_SPAN_S / ts)))
        # The PVs of the last two steady spans: whether a landing still climbs.
        self._pvs: deque[float] = deque(maxlen=2 * (self._recent.maxlen or 1))
        self._stall = _RecoveryStall()
        self._watch = _HeatUpWatch()
        self._recovery = _RecoveryWatch()
        # Whether the full power running began as the PV fell from the hold (cold water).
        self._recovering = False
        # A heat-up cut short to measure the tun, while its heat arrives (`_pulse_due`), and
        # the model's rate when that heat-up began.
        self._pulse: _PulseWatch | None = None
        self._pulse_sp = 0.0
        self._pulsed = False
        self._arm_rate = 0.0
        # Whether the next step's change of power is the loop's own (`loops_own_step`).
        self._step_is_loops = False
        # Whether the readings of the period the next step closes showed cold water
        # (`cold_water_seen`), and whether the last step carried full power on for it.
        self._cold_water = self._carried = self._above = False
        self._fit: HeatUpFit | None = None
        # s the innovation has lain beyond the bias's clip on one side (signed by it).
        self._trailing = 0.0
        # Cold water poured in, while its drop unfolds (`_follow_pour`): the PV before it,
        # the lowest since, and the share of heat capacity it added that is taken.
        self._poured: tuple[float, float, float] | None = None
        # What of that cold water the sensor has yet to show through its lag (`_PourGap`).
        self._pour_gap: _PourGap | None = None
        self._estimate = self._bias = self._fpv = 0.0
        # A heat flow the caller knows (a HERMS coil's draw), in % of full power: the one in
        # force from `_load_in` s on until `_load_until` s (`_load`) and the one over the
        # period the next step closes.
        self._load = self._load_past = self._load_in = 0.0
        self._load_until = math.inf
        # False: the load is a draw to let act (a HERMS coast), not one to send heat for.
        self._load_met = True
        # The share of that load the water shows, learned by the observer (`_advance`), and
        # what the load was reckoned from (a new basis restarts it at the whole).
        self._load_share, self._load_basis = 1.0, 0.0
        self._l2_share = observer_gains(ts, OBSERVER_TRACK_S, LOAD_SHARE_S)[1]
        # °C²: a reading's variance about the last period's PV (`readings_seen`), DROP_SD's
        # until the readings say more.
        self._scatter = DROP_SD * DROP_SD

    @property
    def fit(self) -> HeatUpFit | None:
        """The last heat-up's measurement (taken into the model unless refused)."""
        return self._fit

    def _use(self, rate: float, dead_time: float, sensor_lag: float | None = None) -> None:
        """Take a rate and a dead time (of it `sensor_lag` s the sensor's first-order lag, the
        rest a delay; None: the lag kept), and the gains that follow: near the setpoint
        the predicted loop's time constant 100/(rate·Kc) is at least PREDICTED_LOOP_FACTOR·θ
        (and 2·Ts), so a real dead time, gain or τ twice the model's leaves it damped; far
        below it the gain that closes the predicted error in one period (time-optimal)."""
        ts = self._ts
        self._rate = rate
        self._dead_time = dead_time
        if sensor_lag is not None:
            self._sensor_lag = sensor_lag
        self._sensor_lag = min(self._sensor_lag, max(0.0, dead_time))
        self._fade = math.exp(-ts / self._sensor_lag) if self._sensor_lag > 0.0 else 0.0
        # Whole periods and the share of one: rounded to whole periods, a dead time lost up
        # to Ts/2 of the heat in flight, e.g. 2.5 s of full power on a fast tun at Ts 5 s.
        whole, self._lag_share = divmod(max(0.0, (dead_time - self._sensor_lag) / ts), 1.0)
        self._lag = int(whole)
        settle = PREDICTED_LOOP_FACTOR * max(dead_time, 2.0 * ts)
        self._kc_near = min(self._kc, 100.0 / (rate * settle))
        self._kc_far = max(self._kc, 100.0 / (rate * ts))

    def full_power_adds(self) -> float:
        """°C that full power instead of the last output adds to the water over a whole
        period, by the model's rate: the most that acting on a drop inside a period adds."""
        return self._ts * self._rate * (100.0 - self._output) / 100.0

    def _drift(self, x: float, u: float, share: float = 1.0) -> float:
        """The model's change of PV over `share` of a period at duty u from x (Euler;
        λ·Ts ≪ 1); a known load (`known_load`) enters as a duty taken off u."""
        heat = self._rate * u / 100.0 - self._loss * (x - self._ambient) + self._bias
        return share * self._ts * heat

    def _arriving(self) -> float:
        """The duty whose heat ends its delay in the period just ended: the delay falls
        `_lag_share` of the way into an earlier period's."""
        inputs, lag, share = self._inputs, self._lag, self._lag_share
        return share * inputs[-2 - lag] + (1.0 - share) * inputs[-1 - lag]

    def _lagged(self, arrival: float, duty: float, share: float = 1.0) -> tuple[float, float]:
        """(the duty the sensor shows on average over `share` of a period, and the filter's
        duty at its end) where `duty` ends its delay and the sensor's lag filter starts from
        `arrival`: first order, exact for a duty held over the stretch."""
        if self._sensor_lag <= 0.0:
            return duty, duty
        if share <= 0.0:
            return arrival, arrival
        fade = self._fade if share == 1.0 else math.exp(-share * self._ts / self._sensor_lag)
        end = duty + (arrival - duty) * fade
        mean = duty + (arrival - duty) * (1.0 - fade) * self._sensor_lag / (share * self._ts)
        return mean, end

    def _predicted(self) -> float:
        """Where the PV will be once the inputs already sent arrive: the last `_lag` whole
        and `_lag_share` of the one before them still in the delay, through the sensor's lag
        (what its filter holds: `_sensor_lag` s of its duty), under the known load (which
        acts now, not a dead time late)."""
        inputs, ts, share = self._inputs, self._ts, self._lag_share
        first = len(inputs) - self._lag
        load = self._load_over(0.0, share * ts)
        shown, arrival = self._lagged(self._arrival, inputs[first - 1], share)
        x = self._estimate + self._drift(self._estimate, shown - load, share)
        for n, j in enumerate(range(first, len(inputs))):
            shown, arrival = self._lagged(arrival, inputs[j])
            x += self._drift(x, shown - self._load_over((share + n) * ts, ts))
        if self._sensor_lag > 0.0:
            tail = self._sensor_lag / ts
            x += self._drift(x, arrival - self._load_over((share + self._lag) * ts, ts), tail)
        return x

    def _ahead(self) -> float:
        """`_predicted`, less what of cold water's drop the sensor has yet to show."""
        gap = self._pour_gap
        return self._predicted() - (0.0 if gap is None else gap.unseen(self._fade))

    def _load_over(self, start: float, length: float) -> float:
        """The known load's mean (% of full power) over `length` s from `start` s on: it acts
        from `_load_in` s on (a pump start prepared a dead time ahead) until `_load_until` s
        (a pump stop the program's timer announces), the whole of it between."""
        end = start + length
        load = self._load * self._load_share
        if self._load_in <= start and end <= self._load_until:
            return load
        if length <= 0.0:
            return 0.0
        acting = min(end, self._load_until) - max(start, self._load_in)
        return load * min(max(acting / length, 0.0), 1.0)

    def _holding(self, sp: float) -> float:
        """The duty that holds `sp` by the model and its bias (may lie outside the limits),
        the known load added: the feed-forward."""
        hold = 100.0 * (self._loss * (sp - self._ambient) - self._bias) / self._rate
        if not self._load_met:  # a draw let act: it brings the water down, no heat is sent
            return hold
        load = self._load_over(self._dead_time, self._ts)  # when this duty's heat arrives
        return hold + load if load else hold

    def _law(self, sp: float) -> float:
        """P on the predicted error plus the holding duty (D apart), not coming from full
        power."""
        return self._proportional(sp - self._ahead(), None) + self._holding(sp)

    def _proportional(self, e: float, landing: float | None) -> float:
        """kc_near up to LINEAR_BAND below the setpoint and anywhere above it (above, nothing
        is gained by cutting harder: the water only cools); kc up to FAR_BAND below it; and
        beyond that the gain that closes the predicted error in one period, i.e. full power
        until the heat in flight will carry the water there: time-optimal; so above it too
        where a draw let act (`known_load`'s `met` False) will take the water down, the
        element off until the prediction, the draw counted, lands at the setpoint. Coming from full
        power, that gain holds down to `landing` °C (`_landing_short`: LINEAR_BAND, or less on
        a measured recovery): the heat-up or recovery runs at full power until the gentle
        zone, and only a hold ever sees the kc zone."""
        if landing is not None:
            return self._kc_near * min(e, landing) + self._kc_far * max(0.0, e - landing)
        if e < 0.0 and not self._load_met and self._load > 0.0:
            return self._kc_far * e  # the draw brings it down: off until it lands there
        if e <= LINEAR_BAND:
            return self._kc_near * e
        p = self._kc_near * LINEAR_BAND + self._kc * (min(e, FAR_BAND) - LINEAR_BAND)
        return p + self._kc_far * max(0.0, e - FAR_BAND)

    def _landing_short(self, flight: float) -> float:
        """°C below the setpoint full power brings the predicted PV to. A recovery on a
        measured model: LANDING_TRUST of the heat in flight (`flight` °C, the predicted PV
        over the estimate: the rate's error over it), at least LANDING_BAND and at most
        LINEAR_BAND. Else LINEAR_BAND: the config's prior
        understates the losses (the water lands short by their error over the dead time),
        and a heat-up crosses tens of degrees where the losses are not the hold's (an open
        pot's evaporation grows ×10 from 20 to 66 °C), where a recovery starts from them."""
        if not (self._measured and self._recovering):
            return LINEAR_BAND
        return min(LINEAR_BAND, max(LANDING_BAND, LANDING_TRUST * max(0.0, flight)))

    def _prime(self, sp: float, pv0: float) -> None:
        # As if PV had stood at pv0 with the output at u0 for a dead time. The output is
        # affine in the bias: the bias that makes the first step give u0 (bumpless) is taken
        # when it is physical (no more than the element's whole rate) and the PV holds; a
        # cold start far below the setpoint is the model's to judge (no bias).
        u0 = self._output
        inputs = self._inputs
        inputs.clear()
        inputs.extend([u0] * (inputs.maxlen or 1))
        self._arrival = u0
        self._recent.clear()
        self._recent.extend([pv0] * (self._recent.maxlen or 1))
        self._pvs.clear()
        self._pvs.extend([pv0] * (self._pvs.maxlen or 1))
        self._stall.end()
        self._watch.active = self._recovery.active = self._recovering = False
        self._pulse = None
        self._carried = self._above = False
        self._trailing = 0.0
        self._poured = None
        self._held_sp = self._landing_sp = math.nan
        self._estimate = self._fpv = pv0
        # Newton on the bias: the law is piecewise linear and falling in it (three pieces),
        # so a few steps land on the bias that gives u0 exactly when one exists.
        bias = 0.0
        for _ in range(4):
            self._bias = bias
            miss = u0 - self._law(sp)
            if miss == 0.0:
                break
            probe = 1e-3 * self._rate
            self._bias = bias + probe
            slope = (u0 - self._law(sp) - miss) / -probe
            bias += miss / slope
        # Only within the hold's band: far from the setpoint the law is time-optimal and
        # has nothing to smooth, and behind a long dead time a bias under the element's
        # whole rate could "explain" a cold tun as heat in flight (and never heat it).
        bumpless = abs(bias) <= self._rate and abs(sp - pv0) <= FAR_BAND
        self._bias = bias if bumpless else 0.0
        # The first step's model prediction lands on pv0: no innovation from the start itself.
        self._load_past = self._load_over(0.0, self._ts)
        self._estimate = pv0 - self._drift(pv0, u0 - self._load)

    def _advance(self, sp: float, pv: float, previous: float) -> float:
        fell = self._recent[-1] - pv  # since the last period's PV
        inputs = self._inputs
        inputs.append(previous)
        self._follow_pulse(sp, pv)
        self._watch_heat_up(sp, pv, previous, inputs[-2])
        # The load of the period just ended is the model's, not an error for the bias to learn.
        past, self._load_past = self._load_past, self._load_over(0.0, self._ts)
        shown, self._arrival = self._lagged(self._arrival, self._arriving())
        before = self._estimate + self._drift(self._estimate, shown - past)
        gap = self._pour_gap
        if gap is not None:  # the water's own change goes on as the model has it
            before -= gap.advance(before - self._estimate, self._fade)
            if not gap.following and gap.unseen(self._fade) < GAP_GONE:
                self._pour_gap = None
        innovation = pv - before
        self._pvs.append(pv)
        if self._stall.active:
            self._stall.add(pv, self._heat_way())
        missing = self._heat_missing(sp, pv)
        ramp = self._ramp_shows_losses(previous, sp, pv)
        if missing or ramp:
            l1, l2 = self._missing_gains
        else:
            l1, l2 = self._stalled_gains if self._landing_stalled(sp, pv) else self._gains
        # A jump beyond what noise and the model's drift can make (cold water) is taken whole:
        # beyond a step more than the period's drift (heat that comes a little later than the
        # model has it leaves the PV short by up to all of it: on a fast tun more than a step
        # a period), or a step where the PV itself moved its way by more than noise moves a
        # period's mean (2 LSB: cold water behind a thermowell, the PV a step under a rise).
        clip = BIAS_INNOVATION_CLIP
        its_way = -fell if innovation > 0.0 else fell
        beyond = abs(innovation) - abs(before - self._estimate)
        jumped = abs(innovation) > STEP_INNOVATION and (its_way > clip or beyond > STEP_INNOVATION)
        self._estimate = before + (innovation if jumped else l1 * innovation)
        trailing = clip < abs(innovation) and not jumped
        if trailing and (self._trailing == 0.0 or (self._trailing > 0.0) == (innovation > 0.0)):
            self._trailing += math.copysign(self._ts, innovation)
        else:
            self._trailing = 0.0
        if abs(innovation) <= clip:
            self._learn_share(past, innovation)
        # Heat missing from a hold is learned beyond the clip too, at once, where it is learned
        # fast (one element; on two it may be one element's: `on_two_elements`): losses tripled
        # on a small tun fell the water a degree a minute, the estimate trailing it in a saw
        # of jumps that broke every trail, and the law held it 4 °C low for hours
        # (docs/heat-balance.md, "The law's pace").
        chase = missing and not jumped and self._missing_gains != self._gains
        # At a limit the duty says nothing of the holding duty, but for a water held at 0 % out
        # of the band above (`_above`): there the model errs only by the losses it knows (and
        # a heat nothing asked for), which the bias is, and learned there, a holding duty
        # above the losses of a tun that loses little does not start the rise again. So on a
        # heat-up's ramp once its fit has measured the rate (`_ramp_shows_losses`).
        if self._lo < previous < self._hi or self._above or ramp:
            if abs(innovation) <= clip:
                self._bias += l2 * innovation
            elif chase or abs(self._trailing) >= TRAILING_S:
                # A model that errs by more than the clip over the tracking gain (a prior's
                # loss a quarter of the truth) keeps every innovation above it, the estimate
                # trailing the PV: the bias learns from it clipped, or never would.
                self._bias += l2 * math.copysign(clip, innovation)
        # D acts on the measured PV, filtered by tf (first order).
        fpv1 = self._fpv
        fpv = self._fa * fpv1 + (1.0 - self._fa) * pv if self._filtered else pv
        self._fpv = fpv
        full = previous >= self._hi and pv < sp - FAR_BAND - FULL_MARGIN
        landing = self._landing_short(self._predicted() - self._estimate) if full else None
        p = self._proportional(sp - self._ahead(), landing)

        i = self._holding(sp)
        d = -self._kd * (fpv - fpv1)
        # Out of the band above and running away (RUNAWAY_SHARE): no heat until back in it.
        # Heat nothing asked for (a shorted SSR) runs the PV away from the model, the
        # prediction trailing it by degrees until the bias has learned it, and the gentle gain
        # above the setpoint would cut the hold's duty only degrees over (100/(rate·2θ) %/°C):
        # any heat then lands on a rise, and the supervisor tells heat nobody asked for only
        # once the duty asked has stopped (docs/heat-balance.md, "A shorted SSR"). Not under
        # a told load (a HERMS coil's draw, or one prepared): its heat is sent for the draw
        # that brings the water down, a dead time ahead of it.
        recent = self._recent
        runaway = RUNAWAY_SHARE * self._rate * (len(recent) - 1) * self._ts
        away = self._above or pv - recent[0] > runaway
        self._above = not self._load and pv > sp + FAR_BAND and away
        if self._above:  # no heat: 0 %, or the least the limits allow
            p = min(p, max(self._lo, 0.0) - i - d)
        # Cold water behind a slow sensor: full power goes on while the PV falls by more than
        # a period of it adds (acting on the fall cannot lift the water above where it was),
        # by the gain that puts back in one period what this one fell (more than 100 %).
        # A jump down is water only where the PV itself fell beyond the clip: an estimate
        # that trails a steady fall (losses the model lacks) catches up in jumps that fell
        # the PV no more than a period's slope.
        cold, self._cold_water = self._cold_water, False
        poured = cold or (jumped and innovation < 0.0 and fell > clip)
        self._follow_pour(pv, poured, cold or fell > clip, before)
        self._carried = (cold or self._carried) and pv < sp and fell > self._ts * self._rate
        if self._carried:
            p = max(p, self._kc_far * fell)
        if self._pulse is not None:  # the pulse's heat, then its tail's until it has arrived
            p, d = self._lo + (self._hi - self._lo) * self._pulse.duty(self._ts) - i, 0.0
        self._terms = (p, i, d)
        return p + i + d

    def _ramp_shows_losses(self, previous: float, sp: float, pv: float) -> bool:
        """Whether the period just ended ran a heat-up's full power after its fit, on the
        prior's losses: the bias then learns them (at MISSING_HEAT_BIAS_S) before the landing
        pays a dead time of their error twice. Only from a start nearer the room than the
        setpoint (the fit's rate is then the tun's), within LINEAR_BAND / (loss · dead time)
        of the setpoint, and with nothing else moving the water (docs/heat-up-fit.md, "The
        losses on the ramp")."""
        fit = self._fit
        if self._measured or previous < self._hi or fit is None or fit.refused is not None:
            return False
        if 2.0 * self._watch.reach(self._ts)[0] > sp + self._ambient:
            return False
        if (sp - pv) * self._loss * self._dead_time > LINEAR_BAND:
            return False
        poured = self._poured is not None or self._recovering or self._recovery.active
        return not (self._load or poured or self._pulse is not None or self._watch.active)

    def _heat_missing(self, sp: float, pv: float) -> bool:
        """Whether the water fell LINEAR_BAND below the setpoint it last reached (kept in
        `_held_sp`, forgotten at a heat-up or its pulse and a told load; not at full power
        the law runs for a fall without water, which is the heat missing) and has not risen
        over the last STEADY_SPAN_S: heat the model counts on does not arrive, which the bias
        learns at MISSING_HEAT_BIAS_S. Not while cold water's drop unfolds or carries the
        water down, that fall being the water's, and from then until the water is back at
        the setpoint only where the recovery stopped rising over a whole way of the heat to
        the sensor (`watches._RecoveryStall`): its landing creeps up as its heat arrives, which a
        minute's reading, behind noise, takes for a stall (docs/heat-balance.md, "The law's
        pace")."""
        if self._load:
            self._held_sp = self._landing_sp = math.nan
        elif self._pulse is not None or self._watch.active:
            self._held_sp, self._landing_sp = math.nan, sp
        elif pv >= sp:
            self._held_sp, self._landing_sp = sp, math.nan
            self._stall.end()
        if self._poured is not None or self._carried:
            self._stall.start()
            return False
        if sp != self._held_sp or pv >= sp - LINEAR_BAND:
            return False
        if self._stall.active:
            return self._stall.stalled(self._heat_way(), len(self._recent))
        return pv <= self._recent[0]

    def _heat_way(self) -> int:
        """Periods the heat takes to show at the sensor (the dead time and the sensor's lag),
        at least STEADY_SPAN_S."""
        way = math.ceil((self._dead_time + self._sensor_lag) / self._ts)
        return max(way, len(self._recent))

    def _landing_stalled(self, sp: float, pv: float) -> bool:
        """Whether the landing of a heat-up to `sp` (`_landing_sp`) stopped LINEAR_BAND short
        of it with no heat in flight: no pulse's tail (it holds short by design), no full
        power over the last dead time and STEADY_SPAN_S, the duties sent over the last dead
        time within half LINEAR_BAND's worth of heat of the last span's (a step the law sent
        is still on its way), and the PV's mean over the last STEADY_SPAN_S no higher than over
        the one before (a minute's means: single readings, on a landing that still creeps up
        behind 0.06 °C of noise, rose and fell often enough to learn the creep as heat
        missing). The model's losses are then understated (a prior's, another fill's), which
        the bias learns at MISSING_HEAT_BIAS_S, also on two elements: at ti the water sat
        under the band for half an hour, and the element watch takes no hold reference there
        (docs/heat-balance.md, "The law's pace")."""
        if sp != self._landing_sp or pv >= sp - LINEAR_BAND or self._pulse is not None:
            return False
        inputs, pvs, span = self._inputs, self._pvs, len(self._recent)
        end, back = len(inputs), math.ceil(self._dead_time / self._ts)
        shown = min(end, back + span)
        if max(inputs[j] for j in range(end - shown, end)) >= self._hi:
            return False
        duty = sum(inputs[j] for j in range(end - span, end)) / span
        sent = sum(inputs[j] - duty for j in range(end - min(end, back), end))
        if abs(sent) * self._ts * self._rate / 100.0 > 0.5 * LINEAR_BAND:
            return False
        last = len(pvs)
        now = sum(pvs[j] for j in range(last - span, last))
        return now <= sum(pvs[j] for j in range(last - 2 * span, last - span))

    def _follow_pour(self, pv: float, dropped: bool, fell: bool, free: float) -> None:
        """Cold water poured in (a drop the readings showed, or a step taken whole where the
        PV itself fell): the tun's heat capacity grew by at least the share its drop says
        (`COLDEST_POUR`), so the rate, the losses and the bias per °C fell by that share.
        Followed while the PV sinks through the sensor's lag; done once it rises again.
        Where the PV itself `fell` (a step of the model alone, a measured dead time or lag
        taken in a heat-up, is no water), the drop is then taken as the sensor's lag says it
        is (`_PourGap`). Not under a told load (a HERMS coil's draw is no water). `free`: the
        period's PV by the model, the pour aside."""
        if self._poured is None:
            if not dropped or self._load:
                return
            self._poured = (max(self._recent), math.inf, 0.0)
            shown = fell and self._sensor_lag > 0.0
            self._pour_gap = _PourGap(free) if shown else None
        gap = self._pour_gap
        if gap is not None:
            gap.seen(pv, self._fade, self._poured[0])
        before, low, taken = self._poured
        if pv >= low + BIAS_INNOVATION_CLIP:
            self._poured = None  # rising again: the drop is all seen but the lag's tail
            if gap is not None:
                gap.settle(self._fade)
            return
        low = min(low, pv)
        # The drop the lag says the water made, or the PV's own where it shows more; at most
        # as much again: more than doubling the water is no pour (a glitch).
        drop = max(before - low, 0.0 if gap is None else gap.drop)
        share = min(drop / max(before - drop - COLDEST_POUR, 1.0), 1.0)
        self._poured = (before, low, share)
        if share == taken:
            return
        scale = (1.0 + taken) / (1.0 + share)
        self._loss *= scale
        self._bias *= scale
        self._use(self._rate * scale, self._dead_time)

    def _learn_share(self, past: float, innovation: float) -> None:
        """The known load's share the water shows, learned from the period's innovation as
        the bias is but LOAD_SHARE_S fast, also at full power: a load fed on a prior K (a
        coil's, ±50 %) is the model's largest error until K is measured, and one fed too
        high holds the HLT above its setpoint (`_predicted` waits for a fall that never
        comes) by as much as the limit's margin."""
        drawn = past / self._load_share  # % of full power the told load drew last period
        if drawn > 0.0:
            share = self._load_share - self._l2_share * innovation * 100.0 / (self._rate * drawn)
            self._load_share = min(max(share, LOAD_SHARE_RANGE[0]), LOAD_SHARE_RANGE[1])

    def _duty_was_steady(self, step: float) -> bool:
        """Whether the duties sent over the dead time and STEADY_SPAN_S before this period's
        `step` to full power (the step itself aside) moved by at most STEADY_DUTY_SHARE of it:
        the PV's steady minute shows the duty sent a dead time before it, and the duties sent
        since are still on their way to the sensor."""
        inputs = self._inputs
        in_flight = math.ceil(self._dead_time / self._ts)  # periods, the last one in part
        span = min(len(inputs) - 1, in_flight + (self._recent.maxlen or 1))
        duties = [inputs[j] for j in range(len(inputs) - 1 - span, len(inputs) - 1)]
        return max(duties) - min(duties) <= STEADY_DUTY_SHARE * step

    def _watch_heat_up(self, sp: float, pv: float, applied: float, before: float) -> None:
        """Arm on a step to full power: from a steady PV the heat-up watch, else (cold water)
        the recovery's; take the fit when it comes."""
        recent = self._recent
        watch = self._watch
        recovery = self._recovery
        if self._load and (watch.active or recovery.active):
            # A coil began to draw during the run (a pump started in a HERMS's heat-up to its
            # readied HLT): the rise since is the element's less the coil's, which taken for
            # the tun's would put its rate and dead time low for the rest of the day.
            watch.active = recovery.active = False
        full = applied >= self._hi
        if not full:  # the step ended before the PV rose enough
            recovery.active = self._recovering = False
            if watch.active:
                self._fit = watch.ended(self._ts, self._rate) or self._fit
        # This period's PV too: cold water that the readings showed within the period (and
        # answered there) has a steady minute before it, but is no step from a steady PV.
        seen = (*recent, pv)
        steady = max(seen) - min(seen) <= STEADY_BAND
        loops, self._step_is_loops = self._step_is_loops, False
        # Under a known load (a coil drawing) the rise is not the element's alone, and a
        # pulse measures itself: no fit.
        loops = loops or bool(self._load) or self._pulse is not None
        if full and before < self._hi:
            # Cold water into the hold: the PV fell from the band within the last minute.
            self._recovering = not steady and max(recent) >= sp - FAR_BAND
        if full and not (watch.active or recovery.active) and before < self._hi and not loops:
            if steady:
                # A duty that climbed to full power (a ramp) is no step of a known size.
                if self._duty_was_steady(applied - before):
                    watch.arm(recent[-1], applied - before)
                    self._arm_rate = self._rate
            else:
                hold = self._holding(sp)
                if self._lo <= hold <= MAX_RECOVERY_HOLD:
                    recovery.arm(pv, hold)
        recent.append(pv)
        if full and recovery.active:
            measured = recovery.add(pv, self._ts, sp, self._loss)
            if measured is not None and 0.5 * self._rate <= measured[0] <= 2.0 * self._rate:
                rate, self._estimate = measured
                self._scale_losses(rate)  # as for a heat-up: the fill changed
                self._use(rate, self._dead_time)
        if not (full and watch.active):
            return
        fit = watch.add(pv, self._ts, self._loss, self._rate)
        if fit is None:
            self._at_least(watch.least)
            if self._pulse_due(sp, watch):
                pv0, du, on_s, rise = watch.reach(self._ts)
                watch.active = False
                self._pulse = _PulseWatch(pv0, du, on_s, on_s, rise)
                self._pulse.expect(self._arm_rate)
                self._pulse_sp = sp
                self._pulsed = True  # once a run: a refused one is not tried again
            return
        self._fit = fit
        if fit.refused is None:
            self._scale_losses(fit.rate)
            self._use(fit.rate, fit.dead_time, fit.lag)

    def _scale_losses(self, rate: float) -> None:
        """The losses per second for a measured `rate` in place of the model's. A rate other
        than the model's is most likely a fill other than the config's. Where it is slower
        (more water) the heat capacity scales the losses per second down by the rate's ratio,
        the least they can be (the wetted walls grow less). Where it is faster (less water)
        they go up by less than the rate: the walls shrink with the water, as the prior's own
        lidded pot has its UA go as the litres' 2/3 power, so by the ratio's cube root; by
        the whole ratio a half fill held the prior's whole duty and crept over the setpoint
        for an hour (docs/heat-up-fit.md, "The losses of another fill")."""
        ratio = rate / self._rate
        self._loss *= ratio if ratio <= 1.0 else ratio ** (1.0 / 3.0)

    def _pulse_due(self, sp: float, watch: _HeatUpWatch) -> bool:
        """Whether this heat-up's full power must end now, unmeasured: nothing measured the
        tun yet this run, the heat-up is long and from the heat off, and the water may
        already hold all the heat that even the fastest tun the model may be
        (`PULSE_RATE_MARGIN` × its rate) needs to come within `PULSE_MARGIN` of `sp`. Behind
        a slow sensor a fast tun's ramp does not straighten before then, and what is in
        flight is the rate × (delay + lag): tens of degrees, on a rate the config knows only
        to ×½–×2. Cut there, the water cannot pass the setpoint, and once the heat has all
        arrived it measures the tun (`_PulseWatch`, docs/heat-up-fit.md)."""
        if self._pulsed or (self._fit is not None and self._fit.refused is None):
            return False
        pv0, du, on_s, _ = watch.reach(self._ts)
        if du < self._hi - self._lo or sp - pv0 < PULSE_LEAST_STEP:
            return False
        if not watch.moved and on_s > HEAT_SHOWS_S:
            return False  # no heat shows at all: the supervisor's to judge, not a pulse's
        most = pv0 + PULSE_RATE_MARGIN * self._arm_rate * du / 100.0 * on_s
        return most >= sp - PULSE_MARGIN

    def _follow_pulse(self, sp: float, pv: float) -> None:
        """A pulse's PV this period. Once its heat has all arrived, the tun as it measured it
        is taken as a heat-up's fit is, and where the water is still far below `sp`, a
        second pulse is planned that delivers what is missing to LINEAR_BAND below it, less
        PULSE_AIM_SHARE of that climb, by that rate (a rate measured so is good to a few
        percent; a law on a model of pure delay misplaces the heat a slow sensor spreads
        out); then the law resumes."""
        pulse = self._pulse
        if pulse is None:
            return
        if self._load:  # a coil draws now: the rise is not the element's, the law holds
            self._pulse = None
            return
        first = self._fit is None or self._fit.refused is not None
        # A second pulse stops short of the setpoint, its tail holding the water until the PV
        # passes LINEAR_BAND below it: heat off at its lower aim, a landing above that would
        # fall back out of the band while the law's heat is on its way.
        ceiling = sp if first else sp - LINEAR_BAND + 2.0 * SENSOR_LSB
        if sp != self._pulse_sp or pv >= ceiling:
            # Planned for another setpoint, or sending more than the rate it was planned on
            # said (the PV at the setpoint, or past a second pulse's aim, while heat still
            # goes in): what ran still measures.
            pulse.stop()
        fit = pulse.add(pv, self._ts, self._loss, self._ambient, self._arm_rate)
        if fit is None:
            return
        self._pulse = None
        if fit.refused is not None:
            if first:  # a second pulse's refusal leaves the first's measurement standing
                self._fit = fit
            return
        self._fit = fit
        self._scale_losses(fit.rate)  # as for a heat-up's fit: the fill
        if pulse.room is not None:
            self._ambient = pulse.room
        self._use(fit.rate, fit.dead_time, fit.lag)
        missing = sp - LINEAR_BAND - pv
        if not first or missing <= FAR_BAND:
            return
        # Short of the gentle zone by what the first pulse's rate may be off over the climb.
        missing -= PULSE_AIM_SHARE * missing
        aim = pv + missing
        # The water loses on the way up as much as at its middle, for the pulse and its
        # delay; from then on the tail's heat, the holding duty at the aim, meets the losses.
        du = self._hi - self._lo
        delay = fit.dead_time - fit.lag
        middle = pv + 0.5 * missing - self._ambient
        missing += self._loss * middle * (missing / self._rate * 100.0 / du + delay)
        on_s = missing / (self._rate * du / 100.0)
        hold = (self._holding(aim) - self._lo) / du
        tail = (min(max(hold, 0.0), 1.0), delay, fit.lag)
        self._pulse = _PulseWatch(pv, du, on_s, tail=tail)
        self._pulse.expect(self._rate)
        self._pulse_sp, self._arm_rate = sp, self._rate

    def _at_least(self, least: tuple[float, float] | None) -> None:
        """Before its fit, a heat-up's ramp already proves a rate and a dead time at least
        (`_HeatUpWatch.least`): a model below them (a config's dead time on a slow sensor, its
        litres on a half fill) would leave full power on while a whole dead time's heat is
        still in flight, so it is raised to them at once. Only a ramp that climbs like this
        tun's heat (within RATE_BAND of the model's rate) proves anything: under a load the
        loop does not know of (a pump it does not see, a lid off) the PV barely climbs and
        its line crosses the start far off (beyond twice the latest any tun the limits allow
        for shows its heat, HEAT_SHOWS_S, it is no tun's heat alone: a HERMS pump unseen
        raised herms-day's dead time from 70 s to that); and no further than HEAT_SHOWS_S,
        unless the model's own is longer."""
        if least is None or least[0] < RATE_BAND[0] * self._rate or least[1] > 2.0 * HEAT_SHOWS_S:
            return
        rate = max(self._rate, least[0])
        dead_time = max(self._dead_time, min(least[1], HEAT_SHOWS_S))
        if rate == self._rate and dead_time == self._dead_time:
            return
        self._scale_losses(rate)  # as for a fit: a faster rise is less water
        self._use(rate, dead_time)


def on_two_elements(controller: Controller, *, one_left: bool = False) -> None:
    """Tell the predictive law `controller` is (if it is one) that it drives two elements'
    total: heat it counts on that does not arrive may be one element's, which the element
    watch judges while the other holds the water; its bias keeps ti's pace then. At
    MISSING_HEAT_BIAS_S the population's two-element tuns held worse on the other element
    and were warned later (docs/heat-balance.md, "The law's pace"). A heat-up's landing that
    stalls short of the band keeps the fast pace: no hold has measured the tun yet there.
    `one_left`: one of them is said dead and no longer asked (`runtime.build.said_dead`), so
    heat missing is the other's, learned at the fast pace again: at ti the law took over an
    hour to ask a dead contactor on for good (tests/test_element_watch.py)."""
    law = _law(controller)
    if law is not None:
        law._missing_gains = law._stalled_gains if one_left else law._gains


def _law(controller: Controller) -> _Predictive | None:
    """The predictive law `controller` is or drives: itself, or the one a second element's
    split wraps (`element2.SplitController.inner`, on both elements' total power); None for
    the other forms."""
    law = getattr(controller, "inner", controller)
    return law if isinstance(law, _Predictive) else None


def full_power_now(
    controller: Controller, sp: float, last_pv: float, readings: Sequence[float]
) -> bool:
    """Whether the readings so far in a period show a sudden drop (cold water) that the
    controller would answer with full power, so that the loop need not wait for the period's
    end: the latest of them at least DROP_FALL below the last period's PV (`last_pv`) and the
    one before it at least DROP_ONSET below (DROP_READINGS of them), and then either the step
    the controller would take now on the latest, with its last output as applied, gives its
    upper limit, or the latest lies below the setpoint and the fall both readings show is
    more than full power for a whole period could add back by the model's rate
    (`full_power_adds`): acting on it cannot lift the water above where it stood, nor heat
    water the brewer is cooling to a lower setpoint, and a lone glitch that follows a
    reading noise put 2 LSB low (about 1 in 700 at the bench's noise) adds less than those
    2 LSB. The element's heat reaches the sensor a dead time later whatever is done, so
    every second of the old duty after the water is a second of recovery lost; a period is
    5 of them. Only predictive acts inside a period (the textbook forms are their seeds'
    equations, once a period), only when it may ask for full power (an upper limit below
    100 % is a power limit the window must keep), and not when its output is already there.
    The controller is not changed (its next step is taken on a copy), so the answer follows
    from what a period record logs: its readings, and the controller as the period before
    left it."""
    law = _law(controller)
    if law is None or not law._primed:
        return False
    if law._pulse is not None:
        return False  # a pulse sends its own heat until it has arrived (water ends it)
    if len(readings) < DROP_READINGS:
        return False
    before, latest = readings[-DROP_READINGS], readings[-1]
    if law.params.out_max < 100.0 or law.output >= 100.0:
        return False
    fell, first = last_pv - latest, last_pv - before
    noise = noise_scale(controller)
    if fell < noise * DROP_FALL or first < noise * DROP_ONSET:
        return False
    if latest < sp and law.full_power_adds() < min(fell, first):
        return True
    trial = copy.deepcopy(law)
    return trial.step(sp, latest, law.output) >= 100.0


def noise_scale(controller: Controller) -> float:
    """The readings' scatter (as `readings_seen` measured it) over the bench's (`pid.DROP_SD`),
    at least 1: a fall must be that much larger to be more than noise. 1 for the other
    forms, which measure no scatter."""
    law = _law(controller)
    return 1.0 if law is None else max(1.0, math.sqrt(law._scatter) / DROP_SD)


def readings_seen(controller: Controller, readings: Sequence[float]) -> None:
    """Tell `controller` (predictive) the readings of the period its next step closes: their
    scatter about the period's straight line (a ramp is no noise), as a reading's variance
    about the period's mean, joins the SCATTER_PERIODS mean that scales `full_power_now`'s
    thresholds (`pid.DROP_SD`). Each period counts for at most SCATTER_CAP times the mean."""
    law = _law(controller)
    if law is None:
        return
    line = LineFit()
    for k, reading in enumerate(readings):
        line.add(float(k), reading)
    scatter = line.scatter()
    if scatter is None or not math.isfinite(scatter):
        return  # too few readings to scatter about a line, or one that is no number
    variance = scatter * (1.0 + 1.0 / line.n)
    law._scatter += (min(variance, SCATTER_CAP * law._scatter) - law._scatter) / SCATTER_PERIODS


def loops_own_step(controller: Controller) -> None:
    """Tell `controller` (predictive) that the step to full power its next step sees is the
    loop's return from a spell it held the power down for itself (the heat-up's check of
    two elements), not a step whose response measures the tun: no watch is armed on it."""
    law = _law(controller)
    if law is not None:
        law._step_is_loops = True


def cold_water_seen(controller: Controller) -> None:
    """Tell `controller` (predictive) that the readings of the period its next step closes
    showed cold water (`full_power_now`, the period's `full_from`): full power carries on
    across the step while the PV falls by more than a period of full power adds. Behind a
    slow sensor the period's PV, a mean, lies only a few tenths below the last while the
    water is degrees below: without the carry the law asked 30–50 % again at each boundary
    and the element waited for the period's readings to show the drop anew, 8 s of full
    power lost over the first four periods after a tenth of the volume of cold water on a
    thermowell of 120 s lag. It is told whether or not the element could act on it in the
    period, as the log says only what the readings showed; the fall bounds the carry all
    the same."""
    law = _law(controller)
    if law is not None:
        law._cold_water = True


def known_load(
    controller: Controller,
    watts: float,
    element_watts: float,
    starts_in: float = 0.0,
    ends_in: float = math.inf,
    basis: float = 0.0,
    *,
    met: bool = True,
) -> None:
    """Tell `controller` (predictive) the heat flow `watts` drawn from the water besides its
    losses from `starts_in` s on until `ends_in` s (a HERMS coil's load, W; negative when it
    gives heat back; a pump stop announced ahead ends it: the heat sent from a dead time
    before it meets the water alone),
    of an element of `element_watts`: its model and observer take it as a duty of
    watts/element_watts·100 % taken off the element's, so the holding duty rises by that for
    the heat that arrives once it acts (feed-forward: the loop does not wait for the sensor
    to show the load; a load a dead time ahead is met by heat sent now), the prediction
    counts it from when it acts, and the bias does not learn it as a loss; the observer
    learns the share of it the water shows (`_learn_share`) until `basis`, what `watts` was
    reckoned from (a HERMS coil's K, W/K), changes or the load ends (a pump's run is its
    own: a stop's standing wort, and what a small load's share took up of other errors, are
    not the next run's). 0 is no load: the law is then exactly the one without. `met` False:
    a draw to let act, not to send heat for (a HERMS coast: the HLT's heat above its
    setpoint is the mash's): counted by the prediction and the observer alike, but the
    holding duty is the losses' alone, and above the setpoint the element stays off until
    the prediction, the draw counted, comes down to it (`_proportional`)."""
    law = _law(controller)
    if law is not None:
        if not (math.isfinite(watts) and math.isfinite(element_watts) and element_watts > 0.0):
            raise ValueError(
                f"load {watts!r} W of an element of {element_watts!r} W is invalid: "
                "must be finite, the element's power > 0"
            )
        if not (math.isfinite(starts_in) and starts_in >= 0.0):
            raise ValueError(f"a load starting in {starts_in!r} s is invalid: must be ≥ 0 s")
        if not ends_in >= starts_in:  # NaN refused too; inf: no end announced
            raise ValueError(
                f"a load ending in {ends_in!r} s is invalid: must be ≥ its start, {starts_in!r} s"
            )
        law._load = 100.0 * watts / element_watts
        if basis != law._load_basis or watts == 0.0:
            law._load_share, law._load_basis = 1.0, basis
        law._load_in = starts_in
        law._load_until = ends_in
        law._load_met = met


def dead_time(controller: Controller) -> float | None:
    """The dead time (s) predictive's model holds between its duty and the PV's answer (None
    for the other forms): how far ahead of a load the heat that meets it must be sent."""
    law = _law(controller)
    return None if law is None else law._dead_time


def predicted_pv(controller: Controller) -> float | None:
    """Where predictive expects its PV once the heat already sent arrives (None for the other
    forms, or before its first step): what the HLT will hold whatever is decided now."""
    law = _law(controller)
    if law is not None and law._primed:
        return law._ahead()
    return None


def predicted_after(
    controller: Controller, seconds: float, *duties: float
) -> tuple[float, list[float]] | None:
    """(the PV once the heat already sent has arrived, and where `seconds` of each of
    `duties` % after that leave it) by predictive's model, its losses and bias counted (None
    for the other forms, or before its first step: they hold no model to judge by). Cold
    water's drop counts only as far as the PV has shown it: a minimum on-time commits heat
    that cannot be taken back, and the lag's estimate of the rest (`_PourGap`) may be high
    (a 40 s contactor on a 43 L tun at 11.5 kW is 2 °C; population tun 36 went 0.74 °C over
    on such an estimate, 0.52 without it)."""
    law = _law(controller)
    if law is None or not law._primed:
        return None
    ahead = law._predicted()
    return ahead, [ahead + law._drift(ahead, duty) * seconds / law._ts for duty in duties]


def pulse_running(controller: Controller) -> bool:
    """Whether a predictive controller sends a planned pulse (or its tail, or none) while
    a measured pulse's heat arrives (docs/heat-up-fit.md)."""
    law = _law(controller)
    return law is not None and law._pulse is not None


def heat_up_fit(controller: Controller) -> HeatUpFit | None:
    """The last heat-up a predictive controller measured (None for the other forms)."""
    law = _law(controller)
    return None if law is None else law.fit
