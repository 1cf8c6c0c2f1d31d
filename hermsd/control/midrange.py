"""Mid-ranging control: one measured output y, two inputs, each driven by its own PI.

The fast input u1 (limited, e.g. an SSR element) holds y at the setpoint; the slow input u2
(wide range, e.g. a contactor element) moves so that u1 returns to its reference u1_ref,
keeping u1 in the middle of its range while u2 carries the bulk of the load.

In continuous time (the structure of the anti-windup-in-mid-ranging seed, with C1 and C2 PI):

    v1 = K1·e + I1,   u1 = sat1(v1),   dI1/dt = K1/Ti1·e + (u1 − v1)/Tt1,     e = sp − y
    ũ1 = v1 + Ks·(v1 − u1)                                      (the modified scheme)
    v2 = K2·(u1_ref − ũ1) + I2,   u2 = sat2(v2),   dI2/dt = K2/Ti2·(u1_ref − ũ1) + (u2 − v2)/Tt2

C2 sees the unlimited controller output v1 ("u1" in the seed, whose sat(u1) is our u1), so
when u1 saturates the loop through u2 still works. Tt1 is C1's tracking time (Tt1 = inf: no
anti-windup, the windup case); Ks = 0 is the standard scheme, bit for bit (v1 + 0·x = v1).
The tracking signal fed back to C1's integral is the same v1 − sat1(v1) that Ks amplifies.

Discretisation, period h: the integrals by forward Euler, with e and v sampled at t_k and the
outputs held over [t_k, t_k + h) (zero-order hold):

    I_{k+1} = I_k + (K·h/Ti)·e_k + (h/Tt)·(a_k − v_k)

a_k being what the actuator really delivered in period k (`applied`, external tracking;
without it the limiter model sat(v_k); ũ1 always uses the limiter model, since the
actuator's output of the period being computed is not known yet). Each step first
completes the previous period's update, because a_k arrives with the next step. As h → 0
the discrete loop converges to the continuous one with an error O(h). Tt ≥ h is required:
in saturation v − a shrinks by the factor 1 − h/Tt each period, which alternates in sign for
Tt < h and grows for Tt < h/2.

Start and bumpless transfer: `reset(pv0, u1, u2)` (or, on a new controller, pv0 = the pv of
the first step and outputs (u1_ref, 0) clamped) makes the next step act as if PV had stood at
pv0, the setpoint at its present value and the outputs at (u1, u2): with PV unchanged the
next outputs are (u1, u2) to rounding. So a setpoint that changes together with that first
step gives no proportional kick (as in hermsd.control.pid); a step response from rest needs one step
at the old setpoint first. Gains may be negative (a process with negative gain,
as the cooling system of the seed); units are whatever the process uses. Pure code: nothing
here reads a clock or touches hardware.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

_INF = math.inf


@dataclass(frozen=True, slots=True)
class MidRangeParams:
    """The settings of C1 (fast, limited u1) and C2 (slow u2), time in the process's unit."""

    k1: float
    ti1: float
    tt1: float
    k2: float
    ti2: float
    tt2: float
    ks: float
    u1_ref: float
    u1_min: float
    u1_max: float
    u2_min: float
    u2_max: float
    h: float


class TwoOutputController(Protocol):
    """What a loop needs of a controller with one measurement and two outputs."""

    @property
    def params(self) -> MidRangeParams: ...

    @property
    def outputs(self) -> tuple[float, float]:
        """The last (u1, u2) (before the first step: the outputs it will start from)."""
        ...

    @property
    def terms(self) -> tuple[float, float, float, float]:
        """(P1, I1, P2, I2) of the last step; P1 + I1 is the unlimited fast output."""
        ...

    def step(
        self, sp: float, pv: float, applied: tuple[float, float] | None = None
    ) -> tuple[float, float]:
        """One period: the new (u1, u2), each within its limits."""
        ...

    def reset(self, pv: float, u1: float, u2: float) -> None:
        """Continue from (u1, u2) (clamped to the limits) with PV history `pv`: no kick."""
        ...


def _finite(label: str, value: object, rule: str = "finite") -> float:
    if not isinstance(value, bool) and isinstance(value, int | float) and math.isfinite(value):
        return float(value)
    raise ValueError(f"{label}={value!r} is invalid: must be {rule}")


def create(
    *,
    k1: float,
    ti1: float,
    k2: float,
    ti2: float,
    h: float,
    u1_ref: float,
    u1_min: float,
    u1_max: float,
    tt1: float | None = None,
    tt2: float | None = None,
    ks: float = 0.0,
    u2_min: float = -_INF,
    u2_max: float = _INF,
) -> MidRange:
    """A mid-ranging controller; ValueError names any parameter that is wrong.

    tt1/tt2 default to ti1/ti2 (the rule-of-thumb upper end Tt = Ti); pass math.inf for no
    anti-windup. Limits may be infinite (an unlimited input).
    """
    h = _finite("h", h, "finite and > 0")
    if h <= 0.0:
        raise ValueError(f"h={h!r} is invalid: must be finite and > 0")
    gains = {"k1": k1, "k2": k2}
    for label, value in gains.items():
        if _finite(label, value, "finite and not 0") == 0.0:
            raise ValueError(f"{label}={value!r} is invalid: must be finite and not 0")
    times = {"ti1": ti1, "ti2": ti2}
    for label, value in times.items():
        if _finite(label, value, "finite and > 0") <= 0.0:
            raise ValueError(f"{label}={value!r} is invalid: must be finite and > 0")
    tracking = {"tt1": ti1 if tt1 is None else tt1, "tt2": ti2 if tt2 is None else tt2}
    for label, value in tracking.items():
        if isinstance(value, bool) or not isinstance(value, int | float) or not value >= h:
            raise ValueError(f"{label}={value!r} is invalid: must be ≥ h={h:g} (inf: none)")
    ks = _finite("ks", ks, "finite and ≥ 0")
    if ks < 0.0:
        raise ValueError(f"ks={ks!r} is invalid: must be finite and ≥ 0")
    for label, lo, hi in (("u1", u1_min, u1_max), ("u2", u2_min, u2_max)):
        for name, value in ((f"{label}_min", lo), (f"{label}_max", hi)):
            if isinstance(value, bool) or not isinstance(value, int | float) or math.isnan(value):
                raise ValueError(f"{name}={value!r} is invalid: must be a number (±inf allowed)")
        if not lo < hi:
            raise ValueError(f"{label}_min={lo!r} is invalid: must be < {label}_max={hi!r}")
    u1_ref = _finite("u1_ref", u1_ref)
    if not u1_min < u1_ref < u1_max:
        raise ValueError(
            f"u1_ref={u1_ref!r} is invalid: must lie strictly between u1_min={u1_min!r} "
            f"and u1_max={u1_max!r}"
        )
    params = MidRangeParams(
        k1=float(k1),
        ti1=float(ti1),
        tt1=float(tracking["tt1"]),
        k2=float(k2),
        ti2=float(ti2),
        tt2=float(tracking["tt2"]),
        ks=ks,
        u1_ref=u1_ref,
        u1_min=float(u1_min),
        u1_max=float(u1_max),
        u2_min=float(u2_min),
        u2_max=float(u2_max),
        h=h,
    )
    return MidRange(params)


class MidRange:
    """The discrete mid-ranging controller of the module docstring."""

    __slots__ = (
        "_ar1",
        "_ar2",
        "_bi1",
        "_bi2",
        "_e1",
        "_e2",
        "_i1",
        "_i2",
        "_outputs",
        "_params",
        "_primed",
        "_start_pv",
        "_terms",
        "_v1",
        "_v2",
    )

    def __init__(self, params: MidRangeParams) -> None:
        """Use `create()`, which checks the parameters."""
        p = params
        self._params = p
        self._bi1 = p.k1 * p.h / p.ti1
        self._bi2 = p.k2 * p.h / p.ti2
        self._ar1 = p.h / p.tt1
        self._ar2 = p.h / p.tt2
        self._outputs = (
            min(max(p.u1_ref, p.u1_min), p.u1_max),
            min(max(0.0, p.u2_min), p.u2_max),
        )
        self._primed = False
        self._start_pv: float | None = None
        self._terms = (0.0, 0.0, 0.0, 0.0)
        self._i1 = self._i2 = self._e1 = self._e2 = self._v1 = self._v2 = 0.0

    @property
    def params(self) -> MidRangeParams:
        return self._params

    @property
    def outputs(self) -> tuple[float, float]:
        return self._outputs

    @property
    def terms(self) -> tuple[float, float, float, float]:
        return self._terms

    def reset(self, pv: float, u1: float, u2: float) -> None:
        p = self._params
        _finite("pv", pv)
        _finite("u1", u1)
        _finite("u2", u2)
        self._outputs = (min(max(u1, p.u1_min), p.u1_max), min(max(u2, p.u2_min), p.u2_max))
        self._start_pv = pv
        self._primed = False
        self._terms = (0.0, 0.0, 0.0, 0.0)

    def _prime(self, sp: float, pv0: float) -> None:
        # Integrals that reproduce the start outputs at (sp, pv0); the pending update is zero
        # (no error yet, and the unlimited outputs equal what the actuators hold).
        p = self._params
        u1, u2 = self._outputs
        self._i1 = u1 - p.k1 * (sp - pv0)
        self._i2 = u2 - p.k2 * (p.u1_ref - u1)
        self._e1 = self._e2 = 0.0
        self._v1, self._v2 = u1, u2

    def step(
        self, sp: float, pv: float, applied: tuple[float, float] | None = None
    ) -> tuple[float, float]:
        p = self._params
        _finite("sp", sp)
        _finite("pv", pv)
        if self._primed:
            if applied is None:
                a1, a2 = self._outputs
            else:
                a1 = min(max(_finite("applied u1", applied[0]), p.u1_min), p.u1_max)
                a2 = min(max(_finite("applied u2", applied[1]), p.u2_min), p.u2_max)
        else:
            self._prime(sp, pv if self._start_pv is None else self._start_pv)
            self._primed = True
            a1, a2 = self._outputs
        i1 = self._i1 + self._bi1 * self._e1 + self._ar1 * (a1 - self._v1)
        i2 = self._i2 + self._bi2 * self._e2 + self._ar2 * (a2 - self._v2)
        e1 = sp - pv
        p1 = p.k1 * e1
        v1 = p1 + i1
        u1 = p.u1_min if v1 < p.u1_min else (p.u1_max if v1 > p.u1_max else v1)
        e2 = p.u1_ref - (v1 + p.ks * (v1 - u1))
        p2 = p.k2 * e2
        v2 = p2 + i2
        u2 = p.u2_min if v2 < p.u2_min else (p.u2_max if v2 > p.u2_max else v2)
        self._i1, self._i2, self._e1, self._e2, self._v1, self._v2 = i1, i2, e1, e2, v1, v2
        self._terms = (p1, i1, p2, i2)
        self._outputs = (u1, u2)
        return u1, u2
