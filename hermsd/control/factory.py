"""The controller a config describes, the tun's models in force, the power of two elements.

Here, beside the control laws and above the configuration: the schema says what a config may
hold; this says what the laws make of it."""

from __future__ import annotations

from hermsd.config.schema import MIDRANGE, Config, ControlConfig
from hermsd.control import laws, midrange, pid
from hermsd.control.element2 import MidRangeController, PowerSplit, SplitController, total_share
from hermsd.control.learning import LearnedModel
from hermsd.control.reach import FullPower
from hermsd.safety.element_probe import ElementProbe

WATER_J_PER_LITRE_K = 4186.0


LIDDED_UA_W_PER_K = 3000.0 / (100.0 * 1.689)
"""Heat loss of a lidded 90 L tun (the seed's step test: 3 kW for 1.689 °C/%), W/K; it
scales with the wetted surface, (V/90 L)^⅔."""


LIDDED_LITRES = 90.0


def prior_model(config: Config) -> pid.PlantModel:
    """The tun's model before anything is learned: physics where it can, the keys elsewhere.

    The full-power rate P/(ρ·c·V) follows from `tun.element_watts` and `tun.litres`. The
    losses UA: the smaller of what `control.model_gain` says (UA = P/(100·K)) and a lidded
    tun of this size, since a model that overstates the losses holds too much power and
    overshoots, while one that understates them approaches from below and learns. The
    FOPTD follows (τ = ρ·c·V/UA, K = P/(100·UA)); dead time and room from their keys.
    """
    c, tun = config.control, config.tun
    watts = total_watts(config)
    capacity = WATER_J_PER_LITRE_K * tun.litres
    lidded = LIDDED_UA_W_PER_K * (tun.litres / LIDDED_LITRES) ** (2.0 / 3.0)
    ua = min(watts / (100.0 * c.model_gain), lidded)
    return pid.PlantModel(watts / (100.0 * ua), capacity / ua, c.dead_time, c.model_ambient)


def total_watts(config: Config) -> float:
    """Both elements' power: what 100 % of the controller's output means with two fitted."""
    e2 = config.element2
    return config.tun.element_watts + (e2.watts if e2.backend != "none" else 0.0)


def measured_model(config: Config) -> LearnedModel | None:
    """The tun as `hermsd tune` measured it: the control.model_* keys once model_litres says
    with how much water (None before: the keys are the seed's tun, a guess)."""
    c = config.control
    if c.model_litres is None:
        return None
    foptd = pid.PlantModel(c.model_gain, c.model_tau, c.dead_time, c.model_ambient)
    return LearnedModel.from_plant(foptd, c.model_litres)


def make_controller(control: ControlConfig, model: pid.PlantModel | None = None) -> pid.Controller:
    """The controller a control section describes (ValueError if the algorithm refuses it).

    `model` is the tun's model for predictive; without it, the one the control keys give.
    """
    c = control
    if c.algorithm == MIDRANGE:
        return _midrange_controller(c)
    return laws.create(
        c.algorithm,
        kc=c.kc,
        ti=c.ti,
        td=c.td,
        ts=c.period,
        tf=c.tf,
        tt=c.tt,
        out_min=0.0,
        out_max=c.max_output,
        model=model or pid.PlantModel(c.model_gain, c.model_tau, c.dead_time, c.model_ambient),
    )


def shared_out(config: Config, controller: pid.Controller) -> pid.Controller:
    """The controller the loop runs, given `make_controller`'s: with a second element fitted
    and any algorithm but midrange, that controller on the total power of both elements,
    shared out each period by a `PowerSplit`; else the controller itself."""
    e2 = config.element2
    if e2.backend == "none" or config.control.algorithm == MIDRANGE:
        return controller
    c = config.control
    split = PowerSplit(
        config.tun.element_watts, e2.watts, c.period, e2.min_on, e2.min_off, c.max_output
    )
    probe = ElementProbe(config.tun.element_watts, e2.watts, c.period, c.dead_time)
    return SplitController(controller, split, probe if e2.check else None)


def full_power(config: Config) -> FullPower:
    """The duties that are full power on the tun `config` describes (the reach watch and a
    ready_by heat-up judge by them; replay can from the logged config): the SSR's element at
    control.max_output and a second element on, as mid-ranging gives them at its most (a
    u2_max under 100 % pulses it: never full); shared out, control.max_output limits both
    elements' total instead (`PowerSplit.full_power`)."""
    c, e2 = config.control, config.element2
    if e2.backend == "none":
        return FullPower(c.max_output)
    if c.algorithm == MIDRANGE:
        return FullPower(c.max_output, True)
    watts1 = config.tun.element_watts
    return PowerSplit(watts1, e2.watts, c.period, e2.min_on, e2.min_off, c.max_output).full_power()


def full_power_share(config: Config) -> float:
    """Full power as a % of all the elements' power (the controller's 100 % with two, and
    what the tun's model rate is of): what a ready_by heat-up plans its climb with. Mid-
    ranging under a power limit gives the second element in full (at u2_max on average) and
    the SSR's at control.max_output, more of the total than the limit's %."""
    full, c = full_power(config), config.control
    if full.on2 is None:
        return full.duty1
    duty2 = (c.u2_max if c.algorithm == MIDRANGE else 100.0) if full.on2 else 0.0
    watts1 = config.tun.element_watts
    return total_share(watts1, total_watts(config) - watts1, full.duty1, duty2)


def _midrange_controller(c: ControlConfig) -> MidRangeController:
    """C1 on the SSR's element within 0..max_output; C2 on the second element. A heater's u2
    must rise when u1 sits above u1_ref, so C2's gain is −k2 (k2 is written positive)."""
    inner = midrange.create(
        k1=c.k1,
        ti1=c.ti1,
        tt1=c.tt1,
        k2=-c.k2,
        ti2=c.ti2,
        tt2=c.tt2,
        ks=c.ks,
        h=c.period,
        u1_ref=c.u1_ref,
        u1_min=0.0,
        u1_max=c.max_output,
        u2_min=c.u2_min,
        u2_max=c.u2_max,
    )
    p = inner.params
    params = pid.Params(MIDRANGE, c.k1, c.ti1, 0.0, c.period, 0.0, p.tt1, 0.0, c.max_output)
    return MidRangeController(inner, params)
