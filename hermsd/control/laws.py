"""Every control law by name: `create` checks a law's parameters and builds it."""

from __future__ import annotations

import math

from hermsd.control.pid import (
    ALGORITHMS,
    AMBIENT_RANGE,
    MAX_ABS_OUTPUT_LIMIT,
    MAX_DEAD_TIME,
    MAX_KC,
    MAX_TIME,
    MIN_TIME,
    MODEL_GAIN_RANGE,
    SEED_HLT,
    Controller,
    Params,
    PlantModel,
    _number,
    default_tf,
)
from hermsd.control.predictive import _Predictive
from hermsd.control.seed import _BackCalculation, _Takahashi, _TypeA, _TypeAFiltered


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
