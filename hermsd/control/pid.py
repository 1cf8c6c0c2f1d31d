"""PID controllers for the HLT, each one a direct transcription of its discrete-time equation.

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
  still in the dead time: the PV that will be. Output = the holding duty at the setpoint
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

import copy
import math
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

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
FAR_BAND = 0.5
"""°C below the setpoint (the hold band) beyond which predictive heats time-optimally."""
FULL_MARGIN = 0.15
"""°C (5 noise sd): a PV this far below the band is surely out of it. Full power may run on
into the gentle zone only while the PV is there; the step down from it must not fall in the
hold, where the output moves by a few % a period at most."""
OBSERVER_BIAS_S = 800.0
"""The bias's time constant when ti = 0."""
STEP_INNOVATION = 0.25
"""°C (4 LSB) in one period: the PV estimate takes such an innovation whole. A period's PV is
the mean of its readings, so noise of 0.03 °C never moves it that far."""
DROP_READINGS = 2
"""Readings in a row that must show a drop below the last period's PV before predictive acts
inside a period (`full_power_now`, by `DROP_RULE`)."""
DROP_ONSET = 0.125
"""°C (2 LSB) below the last period's PV the reading before the latest must lie (at least, by
`DROP_RULE`; more than, by the rules before it)."""
DROP_FALL = 0.1875
"""°C (3 LSB) below the last period's PV the latest reading must lie at least, by `DROP_RULE`.
One reading differs from the last period's mean by 0.04 °C sd (noise sd 0.03 °C and the
LM92's truncation): 2 LSB is 3 sd and 3 LSB 4.7 sd, and noise does not give both in a row
(none in 3.2 million simulated periods of hold, the true temperature anywhere within an LSB).
Behind the sensor's lag cold water shows as readings that fall further each time, the first
of them often by less than 0.25 °C; a one-reading glitch (the supervisor drops only jumps
beyond safety.max_step) has a steady reading before it, so it never does it, however deep."""


@dataclass(frozen=True, slots=True)
class DropRule:
    """What a period's readings must show before predictive acts on them (`full_power_now`):
    the latest more than `fall` below the last period's PV and the one before it more than
    `onset` below (at least, if `inclusive`); then either the controller's trial step on the
    latest reading (`on_latest`) or on the mean of the two gives full power, or (`deficit`)
    the latest reading lies below the setpoint and the fall both readings show is more than
    full power for a whole period could add back by the model's rate (`full_power_adds`):
    acting on it cannot lift the water above where it stood, nor heat water the brewer is
    cooling to a lower setpoint, and a lone glitch that follows a reading noise put 2 LSB
    low (about 1 in 700 at the bench's noise) adds less than those 2 LSB."""

    onset: float
    on_latest: bool
    fall: float = STEP_INNOVATION
    inclusive: bool = False
    deficit: bool = False


DROP_RULE = DropRule(DROP_ONSET, on_latest=True, fall=DROP_FALL, inclusive=True, deficit=True)
"""The rule in force; its `onset` and `fall` are logged with every config record
(`drop_onset_c`, `drop_fall_c`). Behind a slow sensor (a thermowell) cold water shows as
readings that fall by less than 0.1 °C a second at first, and the law, on the PV it sees,
answers a fall of less than half a degree with a few % more: the rules before it lost the
seconds until the readings lay that far down."""
LAW_DROP_RULE = DropRule(DROP_ONSET, on_latest=True)
"""The rule before it (both thresholds strict, the latest more than STEP_INNOVATION down,
only the law's answer counts): logs with `drop_onset_c` and no `drop_fall_c`."""
FIRST_DROP_RULE = DropRule(STEP_INNOVATION, on_latest=False)
"""The first rule (both readings beyond STEP_INNOVATION, the trial on their mean): logs with
`drop_readings` and no `drop_onset_c` were written under it. It lost a reading, a second of
full power, to a first reading that the sensor's lag kept within 0.25 °C."""
DROP_CARRY = True
"""Logged with every config record (`drop_carry`): cold water that a period's readings showed
by `DROP_RULE` (its `full_from`; acted on, or not where heating was held off at that reading)
carries full power across the period's end while the PV falls (`cold_water_seen`). Behind a slow
sensor the period's PV, a mean, lies only a few tenths below the last while the water is
degrees below: the law asked 30–50 % again at each boundary and the element waited for the
period's readings to show the drop anew, 8 s of full power lost over the first four periods
after a tenth of the volume of cold water on a thermowell of 120 s lag."""
MAX_DEAD_TIME = 1800.0
"""s: the longest dead time a heat-up may show (a sensor far down a long pipe), and so the
longest the config (`control.dead_time`) and the predictive controller take: its history of
the outputs still in flight is sized by it once, so a period's work stays bounded."""
FIT_FROM = 1.0
FIT_TO = 3.0
"""°C of rise between which a heat-up's ramp is fitted: past the first bend of the sensor's
lag, and over enough rise that LSB and noise matter little."""
RECOVERY_FIT_SPAN = 1.0
"""°C of rise a recovery's ramp is fitted over: a tenth of the volume of cold water drops the
PV some 4.5 °C, and the heat in flight on a slow sensor takes up to 2 °C of what is left."""
RECOVERY_FIT_PERIODS = 12
"""Periods a recovery's line takes in at least (logged with every config record,
`recovery_fit_periods`): where the first RECOVERY_FIT_SPAN holds fewer, each further
full-power period adds its PV and the line is taken anew, up to these or the cut, whichever
comes first. A line's slope over n periods of noise σ has the sd σ·√(12/(n³ − n))/Ts: on
30 L at 5.5 kW (0.2 °C a period, the span's 5 periods; σ ≈ 0.016 °C, a period's mean of 5
readings) that is 2.5 % of the rate, and the cut lands the water some 0.05 °C off; over 12,
0.7 %. Every other tun of the bench's family climbs under 0.1 °C a period, so its span holds
12 or more and it is fitted as before: there the span's later points would only add the
sensor lag's bend (a thermowell's rate came out higher and its cut earlier)."""
MAX_RECOVERY_HOLD = 90.0
"""% of holding duty above which a recovery's rate is not measured: the step to full power is
too small for its slope to tell the rate."""
STEADY_SPAN_S = 60.0
STEADY_BAND = 0.25
"""A step from a PV that moved at most STEADY_BAND °C over the last STEADY_SPAN_S s."""
STEADY_DUTY_SHARE = 0.05
"""The share of a step to full power by which the duty may have moved over the dead time and
STEADY_SPAN_S before it, for the step to measure the tun (logged with every config record,
`steady_duty_share`). The fit divides its slope by the step and takes its crossing for the
dead time, both true only of a step from a duty the PV had settled on: a duty that climbed
over the last periods (a program's ramp, the output following its setpoint up to full power)
hides the step's real size from the PV's steady minute, since the climb has not reached the
sensor yet. The duty the PV settled on lies within the span's, so the step, and the rate,
are then known to within 5 %."""
BIAS_INNOVATION_CLIP = 0.125
"""°C (two LSB): the bias learns from innovations up to this size only. A step (cold water)
is a change of state, not of heat flow: the PV estimate follows it whole, the bias barely."""

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


def create(
    name: str,
    *,
    kc: float,
    ti: float,
    td: float = 0.0,
    ts: float = 5.0,
    tf: float | None = None,
    tt: float | None = None,
    out_min: float = 0.0,
    out_max: float = 100.0,
    model: PlantModel = SEED_HLT,
) -> Controller:
    """A new controller of algorithm `name`; ValueError names any parameter that is wrong.

    `model` is used by `predictive` only.
    """
    params = _resolve(name, kc=kc, ti=ti, td=td, ts=ts, tf=tf, tt=tt, lo=out_min, hi=out_max)
    controller: Controller
    if name == "predictive":
        _number("model.gain", model.gain, *MODEL_GAIN_RANGE, "> 0 °C/%")
        _number("model.tau", model.tau, MIN_TIME, MAX_TIME, f"≥ {MIN_TIME:g} s")
        _number(
            "model.dead_time", model.dead_time, 0.0, MAX_DEAD_TIME, f"≥ 0 and ≤ {MAX_DEAD_TIME:g} s"
        )
        _number("model.ambient", model.ambient, *AMBIENT_RANGE, "within −100…100 °C")
        controller = _Predictive(params, model)
    elif name == "type_a":
        controller = _TypeA(params)
    elif name == "type_a_filtered":
        controller = _TypeAFiltered(params)
    elif name == "back_calculation":
        controller = _BackCalculation(params)
    else:
        controller = _Takahashi(params)
    return controller


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


def _resolve(
    name: str,
    *,
    kc: float,
    ti: float,
    td: float,
    ts: float,
    tf: float | None,
    tt: float | None,
    lo: float,
    hi: float,
) -> Params:
    if name not in ALGORITHMS:
        raise ValueError(f"algorithm {name!r} is unknown: must be one of {', '.join(ALGORITHMS)}")
    kc = _number("kc", kc, math.ulp(0.0), MAX_KC, f"> 0 and ≤ {MAX_KC:g} %/°C")
    ti_rule = f"0 (no integral) or ≥ {MIN_TIME:g} and ≤ {MAX_TIME:g} s"
    ti = _number("ti", ti, 0.0, MAX_TIME, ti_rule)
    if 0.0 < ti < MIN_TIME:
        raise ValueError(f"ti={ti!r} is invalid: must be {ti_rule}")
    td = _number("td", td, 0.0, MAX_TIME, f"≥ 0 and ≤ {MAX_TIME:g} s (0 = no derivative)")
    ts = _number("ts", ts, MIN_TIME, MAX_TIME, f"≥ {MIN_TIME:g} and ≤ {MAX_TIME:g} s")
    limit_rule = f"finite and within ±{MAX_ABS_OUTPUT_LIMIT:g} %"
    lo = _number("out_min", lo, -MAX_ABS_OUTPUT_LIMIT, MAX_ABS_OUTPUT_LIMIT, limit_rule)
    hi = _number("out_max", hi, -MAX_ABS_OUTPUT_LIMIT, MAX_ABS_OUTPUT_LIMIT, limit_rule)
    if lo >= hi:
        raise ValueError(f"out_min={lo!r} is invalid: must be < out_max={hi!r}")
    if name in ("takahashi", "velocity_pi") and ti == 0.0:
        raise ValueError(
            f"ti=0 is invalid for {name}: P and D act on PV only, so the integral is the "
            "only path from the setpoint; must be > 0 s"
        )
    if name == "velocity_pi":
        if td != 0.0:
            raise ValueError(f"td={td!r} is invalid for velocity_pi (a PI): must be 0")
        if tf is not None:
            raise ValueError(f"tf={tf!r} is invalid for velocity_pi (no D term): leave it unset")
    owes_kicks = tf is None and td > 0.0 and name in ("type_a", "type_a_filtered", "takahashi")
    if tf is None:
        tf = 0.0 if name == "predictive" else default_tf(kc, td)
    tf = _number("tf", tf, 0.0, MAX_TIME, f"≥ 0 and ≤ {MAX_TIME:g} s (0 = no filter)")
    tracking = name == "back_calculation" and ti > 0.0
    if tt is not None and not tracking:
        raise ValueError(
            f"tt={tt!r} is invalid here: only back_calculation with ti > 0 tracks through Tt; "
            "leave it unset"
        )
    if tracking:
        if tt is None:
            tt = max(ts, math.sqrt(ti * td) if td > 0.0 else ti)
        tt = _number("tt", tt, ts, MAX_TIME, f"≥ ts={ts:g} and ≤ {MAX_TIME:g} s")
    return Params(name, kc, ti, td, ts, tf, tt, lo, hi, owes_kicks)


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


class _TypeA(_Base):
    """Eq. 08: u_k = p1·u_{k−1} + p2·u_{k−2} + k0·e_k + k1·e_{k−1} + k2·e_{k−2}.

    `terms` are the increments of the three branches of eq. 05-3 (P, trapezoidal I, filtered
    D); in linear operation without `applied` they add up to u_k − u_{k−1}.
    """

    __slots__ = (
        "_ci",
        "_d1",
        "_e1",
        "_e2",
        "_half_ci",
        "_k0",
        "_k1",
        "_k2",
        "_kc",
        "_kdd",
        "_p1",
        "_p2",
        "_u2",
    )

    def __init__(self, params: Params) -> None:
        super().__init__(params)
        kc, ti, td, ts = params.kc, params.ti, params.td, params.ts
        gamma = params.tf if params.tf > 0.0 else 0.5 * ts
        inv_ti = 1.0 / ti if ti > 0.0 else 0.0
        alpha = ts + 2.0 * gamma
        # eq. 06, with 1/Ti = 0 when there is no integral
        self._k0 = kc * (1.0 + ts * inv_ti / 2.0 + 2.0 * td / alpha)
        self._k1 = kc * (ts * ts * inv_ti - 4.0 * gamma - 4.0 * td) / alpha
        self._k2 = (
            kc
            * (2.0 * gamma - ts + ts * ts * inv_ti / 2.0 - gamma * ts * inv_ti + 2.0 * td)
            / alpha
        )
        self._p1 = 4.0 * gamma / alpha
        self._p2 = (ts - 2.0 * gamma) / alpha
        self._kc = kc
        self._ci = kc * ts * inv_ti
        self._half_ci = 0.5 * self._ci
        self._kdd = 2.0 * kc * td / alpha
        self._e1 = self._e2 = self._u2 = self._d1 = 0.0

    def _prime(self, sp: float, pv0: float) -> None:
        self._e1 = self._e2 = sp - pv0
        self._u2 = self._output - self._ci * self._e1
        self._d1 = 0.0

    def _advance(self, sp: float, pv: float, previous: float) -> float:
        e = sp - pv
        e1 = self._e1
        v = (
            self._p1 * previous
            + self._p2 * self._u2
            + self._k0 * e
            + self._k1 * e1
            + self._k2 * self._e2
        )
        d = self._kdd * (e - e1) - self._p2 * self._d1
        self._terms = (self._kc * (e - e1), self._half_ci * (e + e1), d - self._d1)
        self._d1 = d
        self._e2 = e1
        self._e1 = e
        self._u2 = previous
        return v


class _TypeAFiltered(_Base):
    """Eq. 11c + 12: velocity form, D on the low-pass filtered error."""

    __slots__ = ("_ci", "_e1", "_fa", "_fb", "_filtered", "_kc", "_kd", "_lpf1", "_lpf2")

    def __init__(self, params: Params) -> None:
        super().__init__(params)
        self._kc = params.kc
        self._ci = params.kc * params.ts / params.ti if params.ti > 0.0 else 0.0
        self._kd = params.kc * params.td / params.ts
        self._filtered = params.tf > 0.0
        self._fa, self._fb = _lowpass(params.tf, params.ts)
        self._e1 = self._lpf1 = self._lpf2 = 0.0

    def _prime(self, sp: float, pv0: float) -> None:
        self._e1 = self._lpf1 = self._lpf2 = sp - pv0

    def _advance(self, sp: float, pv: float, previous: float) -> float:
        e = sp - pv
        e1 = self._e1
        lpf1 = self._lpf1
        lpf = self._fa * lpf1 + self._fb * (e + e1) if self._filtered else e
        p = self._kc * (e - e1)
        i = self._ci * e
        d = self._kd * (lpf - 2.0 * lpf1 + self._lpf2)
        self._terms = (p, i, d)
        self._e1 = e
        self._lpf2 = lpf1
        self._lpf1 = lpf
        return previous + p + i + d


class _Takahashi(_Base):
    """Eq. 14 (type C): P and D on PV, I on the error; D optionally on eq. 11c-filtered PV."""

    __slots__ = ("_ci", "_f1", "_f2", "_fa", "_fb", "_filtered", "_kc", "_kd", "_pv1")

    def __init__(self, params: Params) -> None:
        super().__init__(params)
        self._kc = params.kc
        self._ci = params.kc * params.ts / params.ti
        self._kd = params.kc * params.td / params.ts
        self._filtered = params.tf > 0.0
        self._fa, self._fb = _lowpass(params.tf, params.ts)
        self._pv1 = self._f1 = self._f2 = 0.0

    def _prime(self, sp: float, pv0: float) -> None:
        self._pv1 = self._f1 = self._f2 = pv0

    def _advance(self, sp: float, pv: float, previous: float) -> float:
        pv1 = self._pv1
        f1 = self._f1
        f = self._fa * f1 + self._fb * (pv + pv1) if self._filtered else pv
        p = self._kc * (pv1 - pv)
        i = self._ci * (sp - pv)
        d = self._kd * (2.0 * f1 - f - self._f2)
        self._terms = (p, i, d)
        self._pv1 = pv
        self._f2 = f1
        self._f1 = f
        return previous + p + i + d


class _BackCalculation(_Base):
    """Positional PID with back-calculation anti-windup; `terms` are (P_k, I_k, D_k).

    The integral update of period k needs that period's actual output, which arrives with
    the next step: so each step first completes the previous period's update.
    """

    __slots__ = (
        "_e",
        "_f1",
        "_fa",
        "_fb",
        "_filtered",
        "_i",
        "_kc",
        "_kd",
        "_ki",
        "_kt",
        "_pv1",
        "_v",
    )

    def __init__(self, params: Params) -> None:
        super().__init__(params)
        self._kc = params.kc
        self._ki = params.kc * params.ts / params.ti if params.ti > 0.0 else 0.0
        self._kt = params.ts / params.tt if params.tt is not None else 0.0
        self._kd = params.kc * params.td / params.ts
        self._filtered = params.tf > 0.0
        self._fa, self._fb = _lowpass(params.tf, params.ts)
        self._e = self._v = self._i = self._f1 = self._pv1 = 0.0

    def _prime(self, sp: float, pv0: float) -> None:
        # the pending update becomes exactly zero: no error yet, and v equals the start output
        self._pv1 = self._f1 = pv0
        self._i = self._output - self._kc * (sp - pv0)
        self._e = 0.0
        self._v = self._output

    def _advance(self, sp: float, pv: float, previous: float) -> float:
        i = self._i + self._ki * self._e + self._kt * (previous - self._v)
        f1 = self._f1
        f = self._fa * f1 + self._fb * (pv + self._pv1) if self._filtered else pv
        e = sp - pv
        p = self._kc * e
        d = -self._kd * (f - f1)
        v = p + i + d
        self._terms = (p, i, d)
        self._i = i
        self._e = e
        self._v = v
        self._pv1 = pv
        self._f1 = f
        return v


@dataclass(frozen=True, slots=True)
class HeatUpFit:
    """What one full-power heat-up showed: the rate (°C/s at 100 %) and the dead time (s),
    or why it was refused."""

    rate: float
    dead_time: float
    refused: str | None = None
    span: float = 0.0  # s from the step to full power until the fit: the data it rests on


class LineFit:
    """Least squares of a line through (t, x) points, kept as running sums."""

    __slots__ = ("n", "st", "stt", "stx", "sx")

    def __init__(self) -> None:
        self.n = 0
        self.st = self.sx = self.stt = self.stx = 0.0

    def add(self, t: float, x: float) -> None:
        self.n += 1
        self.st += t
        self.sx += x
        self.stt += t * t
        self.stx += t * x

    def slope(self) -> float | None:
        """dx/dt, or None on fewer than 4 points (too few to tell noise from slope)."""
        spread = self.n * self.stt - self.st * self.st
        if self.n < 4 or spread <= 0.0:
            return None
        return (self.n * self.stx - self.st * self.sx) / spread


class _RampWatch:
    """A line fit over one full-power run, armed when the run starts."""

    __slots__ = ("_line", "_n", "active")

    def __init__(self) -> None:
        self.active = False
        self._n = 0
        self._line = LineFit()

    def _start(self) -> None:
        self.active = True
        self._n = 0
        self._line = LineFit()


class _HeatUpWatch(_RampWatch):
    """Measures the rate and the dead time on a full-power step from a steady PV.

    The PV's rise above pv0 is fitted by a line between FIT_FROM and FIT_TO °C of rise (least
    squares over the periods there): its slope is the rate, and where it crosses pv0 is the
    dead time (for a delay D plus a sensor lag τs the ramp's asymptote crosses at D + τs,
    which is the dead time a predictor wants for a ramp).
    """

    __slots__ = ("_du", "_pv0")

    def __init__(self) -> None:
        super().__init__()
        self._pv0 = self._du = 0.0

    def arm(self, pv0: float, step: float) -> None:
        self._start()
        self._pv0, self._du = pv0, step

    def add(self, pv: float, ts: float, loss: float, model_rate: float) -> HeatUpFit | None:
        """One more full-power period; the fit once the PV has risen FIT_TO °C."""
        self._n += 1
        rise = pv - self._pv0
        if rise < FIT_FROM:
            return None
        line = self._line
        if rise <= FIT_TO:
            line.add((self._n - 0.5) * ts, rise)  # the PV is the mean over the period just ended
            return None
        self.active = False
        span = self._n * ts
        slope = line.slope()
        if slope is None:
            why = f"too few periods ({line.n}) between the rises"
            return HeatUpFit(model_rate, 0.0, why, span)
        if slope <= 0.0:
            return HeatUpFit(model_rate, 0.0, "the PV did not rise", span)
        crossing = (line.st - line.sx / slope) / line.n  # mean t − mean rise / slope
        mid_rise = line.sx / line.n
        rate = (slope + loss * mid_rise) * 100.0 / self._du
        if not RATE_BAND[0] * model_rate <= rate <= RATE_BAND[1] * model_rate:
            why = f"rate {rate:.3g} °C/s is not within ¼–4× the model's {model_rate:.3g}"
            return HeatUpFit(rate, crossing, why, span)
        if not 0.0 <= crossing <= MAX_DEAD_TIME:
            why = f"dead time {crossing:.0f} s is not within 0–{MAX_DEAD_TIME:g} s"
            return HeatUpFit(rate, crossing, why, span)
        return HeatUpFit(rate, crossing, None, span)


class _RecoveryWatch(_RampWatch):
    """Re-measures the rate on a full-power run that did not start from a steady PV (cold
    water in the hold): added water lowers the rate in proportion to the heat capacity, and
    a predictor that keeps the old rate leaves full power too early and creeps up the rest.

    The PV's rise above its lowest point in the run is fitted by a line between FIT_FROM and
    FIT_FROM + RECOVERY_FIT_SPAN °C of rise (past the dip's bend, and early enough that full
    power still runs when the new rate is taken), and where that span holds fewer than the
    periods asked (`RECOVERY_FIT_PERIODS`, a fast tun), refitted over each later full-power
    period too, up to those or the cut. Relative to the hold at the setpoint sp
    with duty u_h, dx/dt = rate·(100 − u_h)/100 − loss·(x − sp): a fill other than the
    model's scales rate and heat flows alike, so u_h, which the bias made exact in the hold,
    stays, and the model's ambient (a guess) does not enter. The dead time is not measured:
    the dip hides where the ramp starts.
    """

    __slots__ = ("_hold", "_low")

    def __init__(self) -> None:
        super().__init__()
        self._hold = self._low = 0.0

    def arm(self, pv: float, hold: float) -> None:
        self._start()
        self._hold, self._low = hold, pv

    def add(
        self, pv: float, ts: float, sp: float, loss: float, periods: int = 0
    ) -> tuple[float, float] | None:
        """One more full-power period; once the PV has risen FIT_FROM + RECOVERY_FIT_SPAN °C
        from its lowest, the rate (°C/s at 100 %) and the line's PV a period ago (where the
        estimate stands before this period's step), or None. While the line holds fewer than
        `periods` points (`RECOVERY_FIT_PERIODS`), each further full-power period adds its PV
        and gives the line anew."""
        self._n += 1
        line = self._line
        if line.n == 0 and pv < self._low + FIT_FROM:
            self._low = min(self._low, pv)
            return None
        past = pv > self._low + FIT_FROM + RECOVERY_FIT_SPAN
        if not past or line.n < periods:
            line.add((self._n - 0.5) * ts, pv)
        if not past:
            return None
        self.active = line.n < periods
        slope = line.slope()
        if slope is None or slope <= 0.0:
            return None
        mean = line.sx / line.n
        before = mean + slope * ((self._n - 1.5) * ts - line.st / line.n)
        return (slope + loss * (mean - sp)) * 100.0 / (100.0 - self._hold), before


class _Predictive(_Base):
    """P on the PV the observer predicts one dead time ahead, plus the holding duty."""

    __slots__ = (
        "_ambient",
        "_bias",
        "_carried",
        "_cold_water",
        "_dead_time",
        "_duty_share",
        "_estimate",
        "_fa",
        "_filtered",
        "_fit",
        "_fpv",
        "_inputs",
        "_kc",
        "_kc_far",
        "_kc_near",
        "_kd",
        "_l1",
        "_l2",
        "_lag",
        "_loss",
        "_rate",
        "_recent",
        "_recovery",
        "_recovery_periods",
        "_steady_with_pv",
        "_step_is_loops",
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
        self._rate = self._kc_near = self._kc_far = self._dead_time = 0.0
        self._lag = 0
        self._use(model.rate, model.dead_time)
        # Observer poles: the PV estimate follows the sensor within OBSERVER_TRACK_S, the bias
        # (what the model gets wrong) within ti; see `observer_gains`.
        self._l1, self._l2 = observer_gains(ts, OBSERVER_TRACK_S, params.ti or OBSERVER_BIAS_S)
        # u_{k-1-lag} … u_{k-1} at the right end; room for any dead time a heat-up may show
        self._inputs: deque[float] = deque(maxlen=math.ceil(MAX_DEAD_TIME / ts) + 2)
        self._recent: deque[float] = deque(maxlen=max(2, round(STEADY_SPAN_S / ts)))
        self._watch = _HeatUpWatch()
        self._recovery = _RecoveryWatch()
        # Whether a step's own PV counts in judging it steady (see `_watch_heat_up`); replay
        # clears it for logs of the daemons before it (`predating_drop_fall`).
        self._steady_with_pv = True
        # How far the duty before a step may have moved, as a share of the step
        # (`_duty_was_steady`); replay sets the share a log names, and no bound for the
        # daemons before it (`logged_duty_share`).
        self._duty_share = STEADY_DUTY_SHARE
        # The fewest periods a recovery's line takes in; replay sets the number a log names,
        # and none for the daemons before it (`logged_recovery_periods`).
        self._recovery_periods = RECOVERY_FIT_PERIODS
        # Whether the next step's change of power is the loop's own (`loops_own_step`).
        self._step_is_loops = False
        # Whether the readings of the period the next step closes showed cold water
        # (`cold_water_seen`), and whether the last step carried full power on for it.
        self._cold_water = self._carried = False
        self._fit: HeatUpFit | None = None
        self._estimate = self._bias = self._fpv = 0.0

    @property
    def fit(self) -> HeatUpFit | None:
        """The last heat-up's measurement (taken into the model unless refused)."""
        return self._fit

    def _use(self, rate: float, dead_time: float) -> None:
        """Take a rate and a dead time, and the gains that follow from them: near the setpoint
        the predicted loop's time constant 100/(rate·Kc) is at least PREDICTED_LOOP_FACTOR·θ
        (and 2·Ts), so a real dead time, gain or τ twice the model's leaves it damped; far
        below it the gain that closes the predicted error in one period (time-optimal)."""
        ts = self._ts
        self._rate = rate
        self._dead_time = dead_time
        self._lag = max(0, round(dead_time / ts))
        settle = PREDICTED_LOOP_FACTOR * max(dead_time, 2.0 * ts)
        self._kc_near = min(self._kc, 100.0 / (rate * settle))
        self._kc_far = max(self._kc, 100.0 / (rate * ts))

    def full_power_adds(self) -> float:
        """°C that full power instead of the last output adds to the water over a whole
        period, by the model's rate: the most that acting on a drop inside a period adds."""
        return self._ts * self._rate * (100.0 - self._output) / 100.0

    def _drift(self, x: float, u: float) -> float:
        """The model's change of PV over one period at duty u from x (Euler; λ·Ts ≪ 1)."""
        return self._ts * (self._rate * u / 100.0 - self._loss * (x - self._ambient) + self._bias)

    def _predicted(self) -> float:
        """Where the PV will be once the inputs already sent (still in the dead time) arrive."""
        x = self._estimate
        inputs = self._inputs
        for j in range(len(inputs) - self._lag, len(inputs)):
            x += self._drift(x, inputs[j])
        return x

    def _holding(self, sp: float) -> float:
        """The duty that holds `sp` by the model and its bias (may lie outside the limits)."""
        return 100.0 * (self._loss * (sp - self._ambient) - self._bias) / self._rate

    def _law(self, sp: float, full: bool = False) -> float:
        """P on the predicted error plus the holding duty (D apart)."""
        return self._proportional(sp - self._predicted(), full) + self._holding(sp)

    def _proportional(self, e: float, full: bool) -> float:
        """kc_near up to LINEAR_BAND below the setpoint and anywhere above it (above, nothing
        is gained by cutting harder: the water only cools); kc up to FAR_BAND below it; and
        beyond that the gain that closes the predicted error in one period, i.e. full power
        until the heat in flight will carry the water there: time-optimal. Coming from full
        power (`full`), that gain holds down to LINEAR_BAND: the heat-up or recovery runs at
        full power until the gentle zone, and only a hold ever sees the kc zone."""
        if e <= LINEAR_BAND:
            return self._kc_near * e
        far = LINEAR_BAND if full else FAR_BAND
        p = self._kc_near * LINEAR_BAND + self._kc * (min(e, far) - LINEAR_BAND)
        return p + self._kc_far * max(0.0, e - far)

    def _prime(self, sp: float, pv0: float) -> None:
        # As if PV had stood at pv0 with the output at u0 for a dead time. The output is
        # affine in the bias: the bias that makes the first step give u0 (bumpless) is taken
        # when it is physical (no more than the element's whole rate); a cold start far below
        # the setpoint would need far more, and there the model is trusted (no bias).
        u0 = self._output
        inputs = self._inputs
        inputs.clear()
        inputs.extend([u0] * (inputs.maxlen or 1))
        self._recent.clear()
        self._recent.extend([pv0] * (self._recent.maxlen or 1))
        self._watch.active = self._recovery.active = False
        self._carried = False
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
        self._bias = bias if abs(bias) <= self._rate else 0.0
        # The first step's model prediction lands on pv0: no innovation from the start itself.
        self._estimate = pv0 - self._drift(pv0, u0)

    def _advance(self, sp: float, pv: float, previous: float) -> float:
        fell = self._recent[-1] - pv  # since the last period's PV
        inputs = self._inputs
        inputs.append(previous)
        self._watch_heat_up(sp, pv, previous, inputs[-2])
        before = self._estimate + self._drift(self._estimate, inputs[-1 - self._lag])
        innovation = pv - before
        # A jump beyond what noise and the model's drift can make (cold water) is taken whole.
        step = innovation if abs(innovation) > STEP_INNOVATION else self._l1 * innovation
        self._estimate = before + step
        if abs(innovation) <= BIAS_INNOVATION_CLIP and self._lo < previous < self._hi:
            self._bias += self._l2 * innovation
        # D acts on the measured PV, filtered by tf (first order).
        fpv1 = self._fpv
        fpv = self._fa * fpv1 + (1.0 - self._fa) * pv if self._filtered else pv
        self._fpv = fpv
        full = previous >= self._hi and pv < sp - FAR_BAND - FULL_MARGIN
        p = self._proportional(sp - self._predicted(), full)

        i = self._holding(sp)
        d = -self._kd * (fpv - fpv1)
        # Cold water behind a slow sensor: full power goes on while the PV falls by more than
        # a period of it adds (acting on the fall cannot lift the water above where it was),
        # by the gain that puts back in one period what this one fell (more than 100 %).
        cold, self._cold_water = self._cold_water, False
        self._carried = (cold or self._carried) and pv < sp and fell > self._ts * self._rate
        if self._carried:
            p = max(p, self._kc_far * fell)
        self._terms = (p, i, d)
        return p + i + d

    def _duty_was_steady(self, step: float) -> bool:
        """Whether the duties sent over the dead time and STEADY_SPAN_S before this period's
        `step` to full power (the step itself aside) moved by at most STEADY_DUTY_SHARE of it:
        the PV's steady minute shows the duty sent a dead time before it, and the duties sent
        since are still on their way to the sensor."""
        inputs = self._inputs
        span = min(len(inputs) - 1, self._lag + (self._recent.maxlen or 1))
        duties = [inputs[j] for j in range(len(inputs) - 1 - span, len(inputs) - 1)]
        return max(duties) - min(duties) <= self._duty_share * step

    def _watch_heat_up(self, sp: float, pv: float, applied: float, before: float) -> None:
        """Arm on a step to full power: from a steady PV the heat-up watch, else (cold water)
        the recovery's; take the fit when it comes."""
        recent = self._recent
        watch = self._watch
        recovery = self._recovery
        full = applied >= self._hi
        if not full:
            watch.active = recovery.active = False  # the step ended before the PV rose enough
        # This period's PV too: cold water that the readings showed within the period (and
        # answered there) has a steady minute before it, but is no step from a steady PV.
        seen = (*recent, pv) if self._steady_with_pv else tuple(recent)
        steady = max(seen) - min(seen) <= STEADY_BAND
        loops, self._step_is_loops = self._step_is_loops, False
        if full and not (watch.active or recovery.active) and before < self._hi and not loops:
            if steady:
                # A duty that climbed to full power (a ramp) is no step of a known size.
                if self._duty_was_steady(applied - before):
                    watch.arm(recent[-1], applied - before)
            else:
                hold = self._holding(sp)
                if self._lo <= hold <= MAX_RECOVERY_HOLD:
                    recovery.arm(pv, hold)
        recent.append(pv)
        if full and recovery.active:
            measured = recovery.add(pv, self._ts, sp, self._loss, self._recovery_periods)
            if measured is not None and 0.5 * self._rate <= measured[0] <= 2.0 * self._rate:
                rate, self._estimate = measured
                self._loss *= rate / self._rate  # as for a heat-up: the fill changed
                self._use(rate, self._dead_time)
        if not (full and watch.active):
            return
        fit = watch.add(pv, self._ts, self._loss, self._rate)
        if fit is None:
            return
        self._fit = fit
        if fit.refused is None:
            # A rate other than the model's is most likely a fill other than the config's:
            # heat capacity scales rate and loss rate alike, so the gain (°C/%) stays.
            self._loss *= fit.rate / self._rate
            self._use(fit.rate, fit.dead_time)


def full_power_now(
    controller: Controller,
    sp: float,
    last_pv: float,
    readings: Sequence[float],
    rule: DropRule = DROP_RULE,
) -> bool:
    """Whether the readings so far in a period show a sudden drop (cold water) that the
    controller would answer with full power, so that the loop need not wait for the period's
    end: the last DROP_READINGS of them below the last period's PV (`last_pv`) as `rule`
    asks, and the step the controller would take now, on the latest of them (or their mean,
    as `rule` asks) with its last output as applied, gives its upper limit, or (as `rule`
    asks) the fall is more than full power can add back within a period. The element's
    heat reaches the sensor a dead time later whatever is done, so every second of the old
    duty after the water is a second of recovery lost; a period is 5 of them. Only
    predictive acts inside a period (the textbook forms are their seeds' equations, once a
    period), only when it may ask for full power (an upper limit below 100 % is a power
    limit the window must keep), and not when its output is already there. The controller
    is not changed (its next step is taken on a copy), so the answer follows from what a
    period record logs: its readings, and the controller as the period before left it."""
    if not (isinstance(controller, _Predictive) and controller._primed):
        return False
    if len(readings) < DROP_READINGS:
        return False
    before, latest = readings[-DROP_READINGS], readings[-1]
    if controller.params.out_max < 100.0 or controller.output >= 100.0:
        return False
    fell, first = last_pv - latest, last_pv - before
    if rule.inclusive:
        if fell < rule.fall or first < rule.onset:
            return False
    elif fell <= rule.fall or first <= rule.onset:
        return False
    if rule.deficit and latest < sp and controller.full_power_adds() < min(fell, first):
        return True
    pv = latest if rule.on_latest else (before + latest) / 2.0
    trial = copy.deepcopy(controller)
    return trial.step(sp, pv, controller.output) >= 100.0


def loops_own_step(controller: Controller) -> None:
    """Tell `controller` (predictive) that the step to full power its next step sees is the
    loop's return from a spell it held the power down for itself (the heat-up's check of
    two elements), not a step whose response measures the tun: no watch is armed on it."""
    if isinstance(controller, _Predictive):
        controller._step_is_loops = True


def cold_water_seen(controller: Controller) -> None:
    """Tell `controller` (predictive) that the readings of the period its next step closes
    showed cold water (`full_power_now`, the period's `full_from`): full power carries on
    across the step while the PV falls by more than a period of full power adds
    (`DROP_CARRY`). It is told whether or not the element could act on it in the period, as
    the log says only what the readings showed; the fall bounds the carry all the same."""
    if isinstance(controller, _Predictive):
        controller._cold_water = True


def predating_drop_fall(controller: Controller) -> None:
    """Make `controller` (predictive) judge a step to full power steady as the daemons before
    `drop_fall_c` did, by the minute before the step alone: replay of their logs."""
    if isinstance(controller, _Predictive):
        controller._steady_with_pv = False


def logged_duty_share(controller: Controller, share: float | None) -> None:
    """Make `controller` (predictive) measure a step to full power from a steady PV as the
    daemon that logged `share` (`steady_duty_share`) did: None, a daemon from before it, which
    measured the step whatever the duty did before it. Replay of its log."""
    if isinstance(controller, _Predictive):
        controller._duty_share = math.inf if share is None else share


def logged_recovery_periods(controller: Controller, periods: int | None) -> None:
    """Make `controller` (predictive) fit a recovery's rate as the daemon that logged
    `periods` (`recovery_fit_periods`) did: None, a daemon from before it, which took the
    rate once, over the first RECOVERY_FIT_SPAN alone. Replay of its log."""
    if isinstance(controller, _Predictive):
        controller._recovery_periods = 0 if periods is None else periods


def heat_up_fit(controller: Controller) -> HeatUpFit | None:
    """The last heat-up a predictive controller measured (None for the other forms)."""
    return controller.fit if isinstance(controller, _Predictive) else None


def observer_gains(ts: float, track: float, bias: float) -> tuple[float, float]:
    """(L1, L2) of the PV/bias observer with poles e^(−Ts/track) and e^(−Ts/bias).

    Error dynamics of predict-then-correct on x = (PV, bias), A = [[1, Ts], [0, 1]]:
    z² − (2 − L1 − Ts·L2)·z + (1 − L1), so L1 = 1 − p1·p2 and Ts·L2 = (1 − p1)·(1 − p2).
    """
    p1 = math.exp(-ts / track)
    p2 = math.exp(-ts / bias)
    return 1.0 - p1 * p2, (1.0 - p1) * (1.0 - p2) / ts


# Tuning: Table 1 of the HERMS PID calculus document, from the identified FOPTD model.


def table1(
    K: float, tau: float, theta: float, a_star: float
) -> dict[str, tuple[float, float, float]]:
    """(kc, ti, td) of every Table 1 rule, by name; td = 0 for the PI rules.

    K: process gain [°C/%], tau: time constant [s], theta: dead time [s], a_star: normalised
    slope of the open-loop step response [°C/(%·s)]. Kc comes out in %/°C, Ti and Td in s.
    """
    gain = _number("K", K, math.ulp(0.0), _INF, "> 0 °C/% and finite")
    tau = _number("tau", tau, math.ulp(0.0), _INF, "> 0 s and finite")
    theta = _number("theta", theta, math.ulp(0.0), _INF, "> 0 s and finite")
    slope = _number("a_star", a_star, math.ulp(0.0), _INF, "> 0 °C/(%·s) and finite")
    ratio = theta / tau
    process = tau / (gain * theta)
    return {
        "zn_open_pid": (1.2 / (theta * slope), 2.0 * theta, 0.5 * theta),
        "zn_open_pi": (0.9 / (theta * slope), 3.33 * theta, 0.0),
        "zn_closed_pid": (1.2 * process, 2.0 * theta, 0.5 * theta),
        "zn_closed_pi": (0.9 * process, 3.33 * theta, 0.0),
        "cohen_coon_pid": (
            process * (theta / (4.0 * tau) + 4.0 / 3.0),
            theta * (32.0 * tau + 6.0 * theta) / (13.0 * tau + 8.0 * theta),
            theta * 4.0 * tau / (2.0 * theta + 11.0 * tau),
        ),
        "cohen_coon_pi": (
            process * (theta / (12.0 * tau) + 9.0 / 10.0),
            theta * (30.0 * tau + 3.0 * theta) / (9.0 * tau + 20.0 * theta),
            0.0,
        ),
        "itae_load_pid": (
            1.357 / gain * ratio**-0.947,
            tau / 0.842 * ratio**0.738,
            0.381 * tau * ratio**0.995,
        ),
        "itae_load_pi": (0.859 / gain * ratio**-0.977, tau / 0.674 * ratio**0.680, 0.0),
    }
