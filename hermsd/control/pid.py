"""The HLT's control laws: what they share (the interface, the parameters, the limits), and
the equations of each (seed.py the seed's forms, predictive.py the default; laws.py builds one
by name).

Units throughout: temperatures in °C, the output in % of element power, Kc in %/°C and every
time constant in seconds. `create()` builds a controller by name; all of them share one
interface (`Controller`): `step(sp, pv, applied=None)` once per period Ts, `reset(pv, output)`
to (re)start bumplessly, and `terms` for logging. The code is pure and deterministic: the same
inputs give bit-identical outputs, and nothing here reads a clock or touches hardware.

Algorithms (equation numbers refer to the HERMS PID calculus document):

- ``type_a``: eq. 08 with the coefficients of eq. 06 (bilinear transform, filtered D on the
  error). γ = tf. With γ = 0 eq. 08 has a pole at z = −1 (p2 = 1) that rings undamped
  whenever the clamp or `applied` acts, so tf = 0 ("no filter") is realised with γ = Ts/2:
  there the bilinear D term Kc·2Td/(Ts + 2γ)·(1 − z⁻¹)/(1 + p2·z⁻¹) is exactly the plain
  backward difference Kc·Td/Ts·(1 − z⁻¹), p2 = 0, and a PI (Td = 0) is the trapezoidal one.
  For 0 < γ < Ts/2 the pole −p2 is negative: a decaying alternation, the user's choice.
- ``type_a_filtered``: eq. 12 (velocity form) with its D acting on the eq. 11c low-pass
  filter of the error; tf = 0 means no filter (lpf = e), since eq. 11c has a pole at z = −1
  there.
- ``takahashi``: eq. 14 (type C velocity form: P and D on PV, I on the error). With tf > 0 the
  D term sees PV through the eq. 11b/11c filter; with tf = 0 it is exactly eq. 14.
- ``back_calculation``: positional P + I + D, D on the (optionally eq. 11c-filtered) PV and
  opposing its change, with back-calculation (tracking) anti-windup:
  I_{k+1} = I_k + Kc·Ts/Ti·e_k + Ts/Tt·(u_actual − v_k), where v_k = P_k + I_k + D_k is the
  unlimited output and u_actual the actuator's real output (`applied`; without it the
  actuator model is the clamp). The sign makes the integral shrink while v_k exceeds what the
  actuator delivers.
- ``velocity_pi``: the bumpless PI of the windup/bumpless-transfer notes:
  u_k = clamp(u_{k−1} − Kc·(PV_k − PV_{k−1}) + Kc·Ts/Ti·e_k). That is eq. 14 with Td = 0, so
  it shares the Takahashi implementation.

- ``predictive``: the daemon's default, and not from the seeds: the seeds' loops all see the
  tun through its dead time, so with gains strong enough to settle fast they overshoot, and
  with gains gentle enough not to they brake early and settle late. This one keeps a model
  of the tun (`model`: full-power rate r, loss rate 1/τ to the room, dead time θ) and an
  observer of it: a PV estimate driven by the duty delivered θ ago (`applied`) plus a bias
  (the heat flow the model gets wrong), both corrected every period by the innovation PV −
  estimate (gains from two poles: the estimate follows the sensor within 30 s, the bias
  within ti). From the estimate it runs the model forward over the duty already sent and
  still in the dead time: the PV that will be (the dead time in whole periods and the share
  of one: a reading's age moves it by a second or so, and rounded to whole periods up to
  half a period of heat in flight is lost). Output = the holding duty at the setpoint
  (model and bias) + P on the setpoint minus that predicted PV: within 0.25 °C below the
  setpoint and anywhere above it with a gain that makes the predicted loop no faster than
  2·θ (damped for a real dead time, gain or τ off by 2×); further below, kc and beyond
  0.5 °C a gain that closes the gap in one period: full power until the heat in flight
  will carry the water to the setpoint, then the holding duty (time-optimal). Coming from
  full power with the PV still well below the band, that gain holds down to 0.25 °C (dual
  mode: no slow approach through the kc zone after a heat-up or cold water).
  The bias learns only from periods with the output inside its limits and innovations
  within 2 LSB: cold water is a step of the state, not a change of heat flow, and at full
  power a rate error would pose as one. An innovation beyond 4 LSB in one period (cold
  water) is taken into the estimate whole, so the step is acted on at once.
  A step to full power from a steady PV and a steady duty (a ramp's climb to full power is
  none) is a measurement: the rise between 1 and 3 °C, fitted by a line, gives the rate
  (its slope, losses added back) and the dead time (where it crosses the start); plausible
  values replace the model's (`fit`), so a fill or a sensor position other than the
  config's is known long before the setpoint. D (td) is optional, on the measured PV,
  filtered by tf (first order). Its reset is bumpless when it can be: the bias takes what
  makes the first step continue from u0, unless that would be more than the element's whole
  rate (a cold start), where the model is trusted.

Defaults: tf=None gives γ = 10 % of Td (the document's suggestion), raised so that one
sensor LSB (0.0625 °C) moves the output by at most 10 % (`default_tf`), for type_a,
type_a_filtered, takahashi and back_calculation. On that default the velocity forms (type_a,
type_a_filtered, takahashi) also owe back what the output limits cut from a P or D kick
(`_owed`): in the plain form a one-LSB step's kick is clipped at 0 % on the way down and
kept in full on the way back, a ratchet. In the linear range nothing is owed and the
equation is exact. An explicit tf asks for the seed's equation exactly as written, limits
included (tf = 0: no filter at all). tt=None gives
Tt = sqrt(Ti·Td) when Td > 0, else Ti (inside the rule of thumb Td ≤ Tt ≤ Ti), raised to Ts
if smaller: with Tt < Ts the tracking term would over-correct the integral every period.
ti = 0 means no integral. A parameter that the chosen algorithm has no use for (td, tf for
velocity_pi; tt for anything but back_calculation with an integral) must be left at its
default, so that a configuration never silently loses an action it asked for. takahashi and
velocity_pi need ti > 0: their only path from the setpoint to the output is the integral.

Tracking (`applied`): the value the actuator really delivered last period (after the SSR's
quantisation and minimum on/off times, a manual value, or a safety override), clamped to the
output range. Velocity forms and type_a use it as u_{k−1}; back_calculation uses it as
u_actual. A velocity form restarts every period from `applied`, so if the output stage
rounds the request down to a quantum without carrying the residue, increments smaller than
the quantum are lost and the loop settles off the setpoint; the output stage should carry its
rounding residue into the next period (the long-run average of `applied` then equals the
request), or report `applied` only when it was overridden.

Start and bumpless transfer: `reset(pv0, u0)` (or, on a new controller, pv0 = the pv of the
first step and u0 = clamp(0)) makes the next step treat the past as if PV had stood at pv0,
the setpoint at its present value and the output at u0; that step ignores `applied`, since
u0 already says what the actuator holds. So there is no derivative kick and no setpoint kick.
With e = sp − pv and Δe = pv0 − pv ("within one P-step"):
|u − u0| ≤ Kc·|Δe| + Kc·Ts/Ti·|e| plus the derivative's response to a PV that moved since the
reset. When PV has not moved (Δe = 0): the velocity forms and type_a give u0 + Kc·Ts/Ti·e
(type_a's output history starts on the ramp eq. 08 follows at a constant error,
u_{k−2} = u_{k−1} − Kc·Ts/Ti·e, so no transient of its p2 mode is set off), and
back_calculation gives u0 (its integral advances after the output is formed).

Numeric domain: sp and pv within ±1e6 °C; 0 < Kc ≤ 1e6; Ts, and Ti when not 0, at least
1 ms; every time at most 1e7 s; output limits within ±1e12. Inside it no product can
overflow, so finite inputs never give NaN; anything outside raises ValueError before any
state changes.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Protocol

CONTROL_LAW_VERSION = 13
"""Which laws' decisions a log holds: written with every config record (`control_law`), and
`hermsd replay --verify` re-runs only a log of this version. Bump it whenever a change to any
law, or to what `replay --verify` compares, would make the decisions of a log written before
it come out otherwise: that log is then said to be of another law, not re-run (its summary,
plot and CSV read as ever). Version 1 is the first logged; a log without one predates it.
Version 2: the predictive law counts the part of a period its dead time ends in.
Version 3: it models the sensor's lag, lets the bias learn a long one-sided innovation, and
scales its rate by the heat capacity cold water adds.
Version 4: a measured pulse gives the sensor's lag too, and places the room from the water's
fall (the sensor plus its lag times its slope).
Version 5: a heat-up's fit to the lag's curve integrates the rise twice.
Version 6: a recovery from cold water on a measured model lands short by a share of the heat
in flight.
Version 7: the in-period drop's thresholds grow with the readings' scatter (they are told each
period's readings); and the changes that came under 6's number since: predictive's bias learns
heat missing from a hold at 100 s and the law sends no heat to water running away above the
band, and the HERMS outer loop's decisions (its coast, step downs, pump starts held or
prepared, the room read).
Version 8: an innovation beyond a step is taken whole only beyond a step more than the
period's drift, or where the PV itself moved its way (heat that comes later than the model has
it is no cold water).
Version 9: cold water's drop behind the sensor's lag is taken as the lag says the PV will
show it, in the prediction, the observer and the heat capacity it adds.
Version 10: a measured pulse's dead time is read with the losses added back and a second
pulse stops `PULSE_AIM_SHARE` of its climb short; and the changes that came under 9's number
since: a heat-up's ramp learns the losses, and a second pulse's tail meets them while its heat
arrives, a pulse scaling the loss by its own rate.
Version 11: a measured rate faster than the model's raises its losses per second by the cube
root of their ratio (a slower one scales them by the ratio as before), and a heat-up's landing
that stalls short of the band learns its missing heat at `MISSING_HEAT_BIAS_S`.
Version 12: a jump of the estimate is cold water only where the PV itself fell beyond
`BIAS_INNOVATION_CLIP` (an estimate catching up with a steady fall is no water), a recovery
the law ran without water does not forget the setpoint held, and heat missing from it is
learned from innovations beyond the clip too, clipped, where it is learned fast (one element).
Version 13: the setpoint held is kept through cold water, and a recovery that stops rising
short of the band over the heat's way to the sensor learns its missing heat at
`MISSING_HEAT_BIAS_S`."""

ALGORITHMS = (
    "predictive",
    "type_a",
    "type_a_filtered",
    "takahashi",
    "back_calculation",
    "velocity_pi",
)
DEFAULT_ALGORITHM = "predictive"


@dataclass(frozen=True, slots=True)
class PlantModel:
    """The tun as identified by a step test (FOPTD): gain °C/%, time constant and dead time s,
    and the room temperature °C it loses heat to."""

    gain: float = 1.689
    tau: float = 14961.0
    dead_time: float = 115.0
    ambient: float = 20.0
    measured: bool = False
    """Whether the losses were measured (learned on a brew day, or by `hermsd tune`), not
    the config's prior, which understates them on purpose (`factory.prior_model`)."""

    @property
    def rate(self) -> float:
        """The full-power heating rate, °C/s (K·100 %/τ)."""
        return 100.0 * self.gain / self.tau


SEED_HLT = PlantModel()

OBSERVER_TRACK_S = 30.0
"""How fast predictive's PV estimate follows the sensor (s): cold water is seen within a
minute, and one LSB of noise moves the estimate by a fifth of itself."""
PREDICTED_LOOP_FACTOR = 2.0
"""The predicted loop's time constant near the setpoint, in dead times."""
LINEAR_BAND = 0.25
"""°C around the setpoint where predictive uses its gentle, dead-time-bound gain."""
LANDING_BAND = 0.05
"""°C: the least a recovery's landing from full power stops short of the setpoint, on a
measured model (`_Predictive._landing_short`)."""
LANDING_TRUST = 0.03
"""The share of the heat in flight a recovery's landing from full power stops short of the
setpoint by on a measured model (up to LINEAR_BAND): a measured rate is good to 1–3 % (the
heat-up fit's 5th percentile 0.990, its lowest 0.932: bench/RESULTS.md, "Heat-up fit")."""
FAR_BAND = 0.5
"""°C below the setpoint (the hold band) beyond which predictive heats time-optimally."""
RUNAWAY_SHARE = 0.15
"""Of the model's full-power rate: a PV out of the band above that rose faster than this over
the last minute runs away (predictive then sends no heat until it is back in the band). A
shorted SSR at a hold's duty d adds (1 − d) of it, above this up to d = 85 %. A holding duty
the bias has not yet learned, on a tun that loses little, creeps at a few % of it
(bench/population.py tun 183: 5 % of full power asked for 1 % of losses, the PV 0.05 °C/min
over the band, 1.5 % of its rate): the bias's to learn with the duty on, not a cut's
(docs/heat-balance.md, "A shorted SSR")."""
FULL_MARGIN = 0.15
"""°C (5 noise sd): a PV this far below the band is surely out of it. Full power may run on
into the gentle zone only while the PV is there; the step down from it must not fall in the
hold, where the output moves by a few % a period at most."""
OBSERVER_BIAS_S = 800.0
"""The bias's time constant when ti = 0."""
MISSING_HEAT_BIAS_S = 100.0
"""s: the bias's time constant (ti's, where ti is shorter) while heat the model counts on does
not arrive (`_Predictive._heat_missing`: a dead element, a lid taken off). The bias chases a
missing heat that grows with the duty it adds, so the duty climbs from the hold's u0 at
u0/τ_b a second: 2.6 hours from 8 % at ti's 800 s, 19 minutes at this. Three times
OBSERVER_TRACK_S, so the two poles stay apart (docs/heat-balance.md, "The law's pace"). Also
a heat-up's ramp after its fit, on the prior's losses (`_Predictive._ramp_shows_losses`):
learned before the landing, not over the hold after it; and a landing that stalls short of
the band (`_Predictive._landing_stalled`)."""
LOAD_SHARE_S = 100.0
"""s: how fast predictive's observer learns the share of a known load (`known_load`) the water
shows: well inside the 180 s a HERMS coil's load is fed on the prior's K (±50 %) before its
first block is measured (the choice measured: docs/mash-control.md, "Feeding the load
forward")."""
LOAD_SHARE_RANGE = (0.5, 1.5)
"""The share learned stays within the prior K's own uncertainty (±50 %, `coil.PRIOR_SD_SHARE`):
a run of innovations from something else (a sensor's step, a fill) cannot turn the load into
nothing or double it."""
STEP_INNOVATION = 0.25
"""°C (4 LSB) in one period: the PV estimate takes such an innovation whole. A period's PV is
the mean of its readings, so noise of 0.03 °C never moves it that far. Beyond it by more
than the period's drift, or where the PV itself moved the innovation's way by more than
BIAS_INNOVATION_CLIP: on a fast tun (8 °C/min at full power, 0.7 °C a period) heat that
comes a few seconds later than the model has it leaves the PV a step short of the model's
rise with the PV still rising, and taken whole as cold water it sent a second burst of heat
(population tun 114: 0.41 °C over after the water on day 2; bench/RESULTS.md, "Population:
200 tuns drawn"). Heat that never comes (a dead element) runs the estimate a period's drift
and a step above the PV within a few periods, and is taken whole from there on."""
DROP_READINGS = 2
"""Readings in a row that must show a drop below the last period's PV before predictive acts
inside a period (`full_power_now`)."""
DROP_ONSET = 0.125
"""°C (2 LSB) below the last period's PV the reading before the latest must lie at least."""
DROP_FALL = 0.1875
"""°C (3 LSB) below the last period's PV the latest reading must lie at least.
One reading differs from the last period's mean by 0.04 °C sd (noise sd 0.03 °C and the
LM92's truncation): 2 LSB is 3 sd and 3 LSB 4.7 sd, and noise does not give both in a row
(none in 3.2 million simulated periods of hold, the true temperature anywhere within an LSB).
A noisier sensor's readings scatter more, and both thresholds grow with the scatter measured
(`DROP_SD`). Behind the sensor's lag cold water shows as readings that fall further each
time, the first of them often by less than 0.25 °C; a one-reading glitch (the supervisor
drops only jumps beyond safety.max_step) has a steady reading before it, so it never does
it, however deep.
Behind a slow sensor (a thermowell) cold water shows as readings that fall by less than
0.1 °C a second at first, and the law, on the PV it sees, answers a fall of less than half a
degree with a few % more: a rule that waited for the readings to lie 0.25 °C down, or for
the law to ask for full power, lost those seconds."""
DROP_SD = 0.04
"""°C: the sd of a reading about the last period's PV that DROP_ONSET and DROP_FALL are 3 and
4.7 of. Where the readings scatter more about their periods' lines (`predictive.readings_seen`:
a sensor of 0.06 °C noise, 0.069 °C about the last PV), both thresholds grow by that sd over
this one: at 2 and 3 LSB such noise asked full power in the hold (population tun 80, an LM92
with 0.06 °C of noise, five times in a day; bench/RESULTS.md, "Population: 200 tuns drawn")."""
SCATTER_PERIODS = 60.0
"""Periods the readings' scatter is averaged over (an exponential mean)."""
SCATTER_CAP = 4.0
"""Times the mean scatter one period's may count for at most: a drop within it (cold water) is
no noise."""
MAX_DEAD_TIME = 1800.0
"""s: the longest dead time a heat-up may show (a sensor far down a long pipe), and so the
longest the config (`control.dead_time`) and the predictive controller take: its history of
the outputs still in flight is sized by it once, so a period's work stays bounded."""
FIT_FROM = 1.0
"""°C of rise from its lowest where a recovery's ramp is fitted from: past the dip's bend."""
MOVE_FROM = 0.25
"""°C of rise (eight sd of a period's mean PV) where a heat-up's PV has begun to move: the
start its ramp's halves are counted from."""
FIT_SPAN = 2.0
"""°C the later half of a heat-up's rise spans at least before it is fitted: as before the
first bend of a sensor's lag, enough rise that LSB and noise matter little, and low enough
on the ramp that a loss the model has wrong moves the rate by under 1 %."""
PULSE_RATE_MARGIN = 2.2
"""How much faster than its model a tun may heat on the day: half the configured water
(`FILL_RANGE`) on mains 10 % high. Full power that could have taken even such water to the
setpoint is all a heat-up the model cannot yet vouch for gets (`PULSE_MARGIN` short)."""
PULSE_MARGIN = 0.5
"""°C: full power ends for a measured pulse once the most the water can have reached lies
this close below the setpoint."""
PULSE_LEAST_STEP = 10.0
"""°C: a heat-up shorter than this is not cut to measure (a program's step; the day's first
heat-up measured the tun)."""
PULSE_AIM_SHARE = 0.05
"""The share of a second pulse's climb it stops short of by (beyond `LINEAR_BAND`, where its
tail holds the water): it is sent on the first pulse's rate, which read 0.948–1.038 of the
truth (5th–95th percentile) over the population's 63 first pulses, so a climb of 35 °C
planned on a rate 5 % low lands 1.75 °C high (docs/heat-up-fit.md)."""
PULSE_ROOM_SPAN = 30.0
"""K below the model's room the most a pulse's settled fall may place the room (a garage in
winter against a model's 20 °C)."""
FILL_ROUNDS = 3
"""Rounds of a pulse's rate and the loss it scales (`_PulseWatch`): on population tuns 97
and 1 the third moves the rate by 0.31 % at most."""
ROOM_ROUNDS = 2
"""Rounds of a pulse's room and lag (`_PulseWatch`): the lag measured on the model's room
places the room, and the lag is measured again on it; on the lossy pulse of
tests/test_heat_up_fit.py a third moves the lag by under a second, the room by under 0.5 K."""
PULSE_SETTLE_S = 60.0
"""s (or the mean delay of the rise's arrival so far, if longer) the PV must have gained
under 2 LSB for a pulse's heat to count as all arrived."""
BEND_TOLERANCE = 0.05
"""How much faster the last quarter of a heat-up's rise may climb than the third and still be
called straight (once the two slopes' noise is within it too): a first-order lag's bend is
then over a lag behind, and the rise holds enough of the lag's curve to fit it
(docs/heat-up-fit.md)."""
RECOVERY_FIT_SPAN = 1.0
"""°C of rise a recovery's ramp is fitted over: a tenth of the volume of cold water drops the
PV some 4.5 °C, and the heat in flight on a slow sensor takes up to 2 °C of what is left."""
RECOVERY_FIT_PERIODS = 12
"""Periods a recovery's line takes in at least: where the first RECOVERY_FIT_SPAN holds fewer,
each further full-power period adds its PV and the line is taken anew, up to these or the cut,
whichever comes first. A line's slope over n periods of noise σ has the sd σ·√(12/(n³ − n))/Ts:
on 30 L at 5.5 kW (0.2 °C a period, the span's 5 periods; σ ≈ 0.016 °C, a period's mean of 5
readings) that is 2.5 % of the rate, and the cut lands the water some 0.05 °C off; over 12,
0.7 %. Every other tun of the bench's family climbs under 0.1 °C a period, so its span holds 12
or more and it is fitted as before: there the span's later points would only add the sensor
lag's bend (a thermowell's rate came out higher and its cut earlier)."""
COLDEST_POUR = 5.0
"""°C: the coldest water a brewer pours in (a tap in winter). A drop of the PV from b to p
says the water poured in held at least (b − p)/(p − 5) of the tun's heat capacity (as much
water at 5 °C; warmer water is more of it): the rate and heat flows per °C fall by at least
that share, and a law that kept them (a tenth more water, 9 % too fast) left full power too
early behind a long dead time and crept up the rest."""
MAX_RECOVERY_HOLD = 90.0
"""% of holding duty above which a recovery's rate is not measured: the step to full power is
too small for its slope to tell the rate."""
STEADY_SPAN_S = 60.0
STEADY_BAND = 0.25
"""A step from a PV that moved at most STEADY_BAND °C over the last STEADY_SPAN_S s."""
STEADY_DUTY_SHARE = 0.05
"""The share of a step to full power by which the duty may have moved over the dead time and
STEADY_SPAN_S before it, for the step to measure the tun. The fit divides its slope by the step
and takes its crossing for the dead time, both true only of a step from a duty the PV had
settled on: a duty that climbed over the last periods (a program's ramp, the output following
its setpoint up to full power) hides the step's real size from the PV's steady minute, since the
climb has not reached the sensor yet. The duty the PV settled on lies within the span's, so the
step, and the rate, are then known to within 5 %."""
BIAS_INNOVATION_CLIP = 0.125
"""°C (two LSB): the bias learns from innovations up to this size only. A step (cold water)
is a change of state, not of heat flow: the PV estimate follows it whole, the bias barely."""
TRAILING_S = 600.0
"""s the innovation must lie beyond BIAS_INNOVATION_CLIP on one side, every period, before the
bias learns from it clipped: a model error, not the minutes of a recovery after cold water
(learning from those too put 0.1–0.6 °C on the overshoot after the water on 40 of 200
population tuns)."""

MAX_ABS_TEMPERATURE = 1e6
MAX_TIME = 1e7
MIN_TIME = 1e-3
MAX_KC = 1e6
MODEL_GAIN_RANGE = (1e-6, 1e6)  # °C/%: any tun's, and away from float's ends
AMBIENT_RANGE = (-100.0, 100.0)  # °C: any room a tun stands in
RATE_BAND = (0.25, 4.0)
"""× the model's full-power rate: a heat-up's measured rate outside it is refused (a wrong
step, a dry or half-empty tun, a tun other than the model's), not taken into the model."""
MAX_ABS_OUTPUT_LIMIT = 1e12

_INF = math.inf
_TF_DEFAULT_FRACTION = 0.1
SENSOR_LSB = 0.0625
"""°C: the LM92's resolution, the smallest step the PV takes."""
MAX_LSB_KICK = 10.0
"""% of output at most from one LSB through the default-filtered derivative."""


@dataclass(frozen=True, slots=True)
class Params:
    """The parameters a controller runs with, defaults resolved (for logs and reloads)."""

    algorithm: str
    kc: float
    ti: float
    td: float
    ts: float
    tf: float
    tt: float | None
    out_min: float
    out_max: float
    owes_kicks: bool = False  # a velocity form on its default filter: see `_owed`


class Controller(Protocol):
    """What the scheduler needs of a controller."""

    @property
    def params(self) -> Params: ...

    @property
    def output(self) -> float:
        """The last output (before the first step: the output it will start from)."""
        ...

    @property
    def terms(self) -> tuple[float, float, float]:
        """(p, i, d) of the last step: increments for velocity forms, values for positional."""
        ...

    def step(self, sp: float, pv: float, applied: float | None = None) -> float:
        """One period: the new output in [out_min, out_max]."""
        ...

    def reset(self, pv: float, output: float) -> None:
        """Continue from `output` (clamped to the limits) with PV history `pv`: no kick."""
        ...


def default_tf(kc: float, td: float) -> float:
    """The derivative filter when tf is not given: the document's γ = Td/10, raised so that one
    sensor LSB moves the output by at most MAX_LSB_KICK (eq. 08's first D increment on a step
    δ is 2·Kc·Td·δ/(Ts + 2γ) ≤ Kc·Td·δ/γ; eq. 11c-filtered D moves by half that at most),
    within the longest time a parameter may have."""
    return min(max(_TF_DEFAULT_FRACTION * td, kc * td * SENSOR_LSB / MAX_LSB_KICK), MAX_TIME)


def _lowpass(tf: float, ts: float) -> tuple[float, float]:
    """(a, b) of the eq. 11c filter lpf_k = a·lpf_{k−1} + b·(x_k + x_{k−1}); unity DC gain."""
    return (2.0 * tf - ts) / (2.0 * tf + ts), ts / (ts + 2.0 * tf)


def _owed(v: float, lo: float, hi: float, kicks: float) -> float:
    """The part of what the limits cut from `v` that P and D moved it by (`kicks`, with what
    they were owed before): owed back next period, so a kick the limit took and its return
    a period later cancel as in the linear range. What the integral pushed past a limit is
    cut, as in the plain velocity form; in the linear range nothing is owed."""
    cut = v - (lo if v < lo else (hi if v > hi else v))
    if cut < 0.0 and kicks < 0.0:
        return max(cut, kicks)
    if cut > 0.0 and kicks > 0.0:
        return min(cut, kicks)
    return 0.0


def _reject(sp: float, pv: float, applied: float | None) -> None:
    """Raise the one-line error for whichever step input is out of the domain."""
    for label, value in (("sp", sp), ("pv", pv)):
        if not -MAX_ABS_TEMPERATURE <= value <= MAX_ABS_TEMPERATURE:
            raise ValueError(
                f"{label}={value!r} °C is invalid: must be finite and within "
                f"±{MAX_ABS_TEMPERATURE:g} °C"
            )
    raise ValueError(f"applied={applied!r} % is invalid: must be finite")


class _Base(ABC):
    """What every algorithm shares: input checks, limits, tracking, start and reset.

    A subclass sets its history in `_prime` and computes the unlimited output in `_advance`.
    """

    __slots__ = (
        "_carry",
        "_hi",
        "_lo",
        "_output",
        "_params",
        "_primed",
        "_start_pv",
        "_terms",
    )

    def __init__(self, params: Params) -> None:
        self._params = params
        self._lo = params.out_min
        self._hi = params.out_max
        self._output = min(max(0.0, self._lo), self._hi)
        self._primed = False
        self._start_pv: float | None = None
        self._terms = (0.0, 0.0, 0.0)
        self._carry = 0.0

    @property
    def params(self) -> Params:
        return self._params

    @property
    def output(self) -> float:
        return self._output

    @property
    def terms(self) -> tuple[float, float, float]:
        return self._terms

    def reset(self, pv: float, output: float) -> None:
        if not -MAX_ABS_TEMPERATURE <= pv <= MAX_ABS_TEMPERATURE:
            _reject(0.0, pv, None)
        if not -_INF < output < _INF:
            raise ValueError(f"output={output!r} % is invalid: must be finite")
        self._output = min(max(output, self._lo), self._hi)
        self._start_pv = pv
        self._primed = False
        self._terms = (0.0, 0.0, 0.0)
        self._carry = 0.0

    def step(self, sp: float, pv: float, applied: float | None = None) -> float:
        if not (
            -MAX_ABS_TEMPERATURE <= sp <= MAX_ABS_TEMPERATURE
            and -MAX_ABS_TEMPERATURE <= pv <= MAX_ABS_TEMPERATURE
        ) or (applied is not None and not -_INF < applied < _INF):
            _reject(sp, pv, applied)
        lo, hi = self._lo, self._hi
        if self._primed:
            previous = self._output if applied is None else min(max(applied, lo), hi)
        else:
            self._prime(sp, pv if self._start_pv is None else self._start_pv)
            self._primed = True
            previous = self._output
        v = self._advance(sp, pv, previous)
        if self._params.owes_kicks:
            v += self._carry
            self._carry = _owed(v, lo, hi, self._terms[0] + self._terms[2] + self._carry)
        u = lo if v < lo else (hi if v > hi else v)
        self._output = u
        return u

    @abstractmethod
    def _prime(self, sp: float, pv0: float) -> None:
        """Set the history as if PV had stood at pv0 and the setpoint at sp."""

    @abstractmethod
    def _advance(self, sp: float, pv: float, previous: float) -> float:
        """The unlimited output of this period; `previous` is the actuator's last output."""


# Tuning: Table 1 of the HERMS PID calculus document, from the identified FOPTD model.


def _number(label: str, value: object, low: float, high: float, rule: str) -> float:
    """`value` as a float if it is a finite real number in [low, high]; else a ValueError."""
    if not isinstance(value, bool) and isinstance(value, int | float):
        try:
            number = float(value)
        except OverflowError:
            number = math.nan
        if math.isfinite(number) and low <= number <= high:
            return number
    raise ValueError(f"{label}={value!r} is invalid: must be {rule}")
