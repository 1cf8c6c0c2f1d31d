"""The HERMS's outer loop: the HLT's setpoint that brings the mash to its rest and holds it
there, and the coil's load for the HLT law to feed forward (derivation: docs/herms.md).

Pure and clock-free, as the laws are: `Cascade.step` once a control period.

The mash gains K·(T_hlt − T_m) through the coil and loses UA_m·(T_m − T_room), so in a hold
the HLT must stand at T_hold = T_sp + UA_m·(T_sp − T_room)/K, above the rest by the losses'
share (why a mash "levels out below" its HLT). Heat cannot be taken back from the mash, so a
step runs as the HLT law's own approach does, one level up: the HLT's setpoint stays at the
limit (mash setpoint + `max_hlt_above_mash`, less HLT_MARGIN for the HLT law's own
overshoot, never above the HLT's maximum) until the heat stored in the HLT above T_hold and
in flight in the hose will carry the mash to its setpoint as the two tanks coast together
(`coast_peak`: the linear two-tank model run forward with the element off until the HLT is
down at T_hold), and from then on the setpoint is T_hold plus a slow trim on the mash's
error (the mash's losses are a guess). With the pump stopped nothing flows, and the HLT is
readied for it: the setpoint is the temperature whose stored heat above T_hold just covers
the mash's shortfall (capped by the limit).

The coast is judged with K one sd high (`CoilEstimate.high`): more heat in the hose and a
lower T_hold, so it stops early rather than late; the load fed forward is K one sd low, so a
wrong K never heats the HLT past its setpoint on its own. A mash reading that is missing,
faulty or older than MAX_MASH_AGE holds the HLT at its last setpoint (flagged `held`, for
the daemon to warn), never at the limit on a guess.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from hermsd.control.coil import CoilEstimate

HLT_MARGIN = 0.25
"""°C the HLT's setpoint stays below the limit: the HLT law overshoots its setpoint by up to
a tenth and noise adds an LSB, and the limit is one the HLT must never pass."""
REHEAT_BAND = 1.0
"""°C below its setpoint a mash in its hold must fall before the climb starts again (a stuck
pump, a cold addition): smaller falls are the trim's."""
SETPOINT_MOVE = 0.01
"""°C: a mash setpoint that moves by more starts a new step."""
MAX_MASH_AGE = 30.0
"""s: a mash reading older than this is none (the HLT is held, not steered on it)."""
COAST_STEPS = 40
"""Integration steps per coupled time constant of the coast (Heun: error ~1e-4 of the step)."""
COAST_SPAN = 10.0
"""Coupled time constants the coast is followed for at most (e^−10 of the gap is left)."""
TRIM_LIMIT = 3.0
"""°C the hold's trim may move the HLT from the model's T_hold."""


@dataclass(frozen=True, slots=True)
class Tanks:
    """The two tanks and the hose between them, as the outer loop's model.

    hlt_capacity, mash_capacity in J/K (water 4186 J/(L·K), grain about 1700 J/(kg·K));
    hlt_loss, mash_loss in W/K to the room at `room` °C; hose_delay in s (coil outlet to mash);
    mash_lag in s (the mash sensor's lag behind the mash).
    """

    hlt_capacity: float
    hlt_loss: float
    mash_capacity: float
    mash_loss: float
    room: float
    hose_delay: float = 0.0
    mash_lag: float = 0.0


@dataclass(frozen=True, slots=True)
class Decision:
    """One period's answer: the HLT's setpoint, the coil's load (W) to feed forward, the
    phase ("climb", "hold", "ready" with the pump stopped, "held" without a mash reading)
    and, when held, why."""

    hlt_setpoint: float
    load_watts: float
    phase: str
    held: str | None = None


def holding_hlt(mash_sp: float, tanks: Tanks, conductance: float) -> float:
    """The HLT temperature that holds the mash at `mash_sp` through a coil of `conductance`
    (W/K): T_sp + UA_m·(T_sp − T_room)/K."""
    return mash_sp + tanks.mash_loss * (mash_sp - tanks.room) / conductance


def coast_peak(hlt: float, mash: float, hold: float, tanks: Tanks, conductance: float) -> float:
    """The mash's highest temperature if the element stops now and the HLT coasts from `hlt`
    down to `hold` (°C), giving its heat through a coil of `conductance` (W/K), after which
    the HLT is held at `hold`: the heat in the hose (K·(T_h − T_m) for its delay) arrives
    first. The linear two-tank model, integrated by Heun's method."""
    k = conductance
    ch, cm = tanks.hlt_capacity, tanks.mash_capacity
    mash += k * (hlt - mash) * tanks.hose_delay / cm
    if hlt <= hold or k <= 0.0:
        return mash
    coupled = 1.0 / (k * (1.0 / ch + 1.0 / cm))
    dt = coupled / COAST_STEPS
    room, uah, uam = tanks.room, tanks.hlt_loss, tanks.mash_loss

    def rates(h: float, m: float) -> tuple[float, float]:
        flow = k * (h - m)
        return (-flow - uah * (h - room)) / ch, (flow - uam * (m - room)) / cm

    peak = mash
    for _ in range(round(COAST_STEPS * COAST_SPAN)):
        dh1, dm1 = rates(hlt, mash)
        dh2, dm2 = rates(hlt + dt * dh1, mash + dt * dm1)
        hlt += 0.5 * dt * (dh1 + dh2)
        mash += 0.5 * dt * (dm1 + dm2)
        peak = max(peak, mash)
        if hlt <= hold or dm1 <= 0.0:
            break
    return peak


def ready_hlt(mash_sp: float, mash: float, hold: float, tanks: Tanks) -> float:
    """With the pump stopped: the HLT whose heat above `hold` covers the mash's shortfall,
    C_h·(T − T_hold) = C_m·(T_sp − T_m) (losses and the coast's time aside)."""
    return hold + tanks.mash_capacity * max(0.0, mash_sp - mash) / tanks.hlt_capacity


class Cascade:
    """The outer loop: mash setpoint and readings in, the HLT's setpoint and the coil's load
    out (see the module's docstring)."""

    __slots__ = (
        "_climbing",
        "_hlt_max",
        "_last_mash",
        "_last_sp",
        "_limit",
        "_mash_sp",
        "_period",
        "_tanks",
        "_trim",
    )

    def __init__(self, tanks: Tanks, *, limit: float, hlt_max: float, period: float) -> None:
        if not (math.isfinite(limit) and limit > 0.0):
            raise ValueError(f"max_hlt_above_mash={limit!r} °C is invalid: must be > 0 °C")
        self._tanks = tanks
        self._limit = limit
        self._hlt_max = hlt_max
        self._period = period
        self._mash_sp: float | None = None
        self._last_sp: float | None = None
        self._last_mash: float | None = None
        self._climbing = True
        self._trim = 0.0

    @property
    def trim(self) -> float:
        """°C the hold has added to the model's T_hold (the mash's losses as measured)."""
        return self._trim

    def ceiling(self, mash_sp: float) -> float:
        """The highest HLT setpoint for `mash_sp`: the limit less HLT_MARGIN, at most the
        HLT's maximum."""
        return min(mash_sp + self._limit - HLT_MARGIN, self._hlt_max)

    def step(
        self,
        *,
        mash_sp: float,
        mash_pv: float | None,
        mash_age: float,
        hlt_pv: float,
        pump: bool,
        coil: CoilEstimate,
    ) -> Decision:
        """One period. `mash_pv` None (a fault) or older than MAX_MASH_AGE (`mash_age`, s):
        the HLT held at its last setpoint. `hlt_pv` is best the HLT law's predicted PV (the
        heat already sent counted)."""
        tanks = self._tanks
        ceiling = self.ceiling(mash_sp)
        if mash_pv is None or not mash_age <= MAX_MASH_AGE:
            why = "no mash reading" if mash_pv is None else f"mash reading {mash_age:.0f} s old"
            last = self._last_sp if self._last_sp is not None else min(mash_sp, ceiling)
            setpoint = min(last, ceiling)
            self._last_sp = setpoint
            return Decision(setpoint, self._load(hlt_pv, self._last_mash, pump, coil), "held", why)
        if self._mash_sp is None or abs(mash_sp - self._mash_sp) > SETPOINT_MOVE:
            self._climbing = mash_pv < mash_sp
        self._mash_sp = mash_sp
        self._last_mash = mash_pv
        k = coil.conductance
        hold = holding_hlt(mash_sp, tanks, k)
        # The mash as it is now: its sensor lags it by mash_lag while it rises at the model's rate.
        flow = k * (hlt_pv - mash_pv) if pump else 0.0
        rise = (flow - tanks.mash_loss * (mash_pv - tanks.room)) / tanks.mash_capacity
        mash = mash_pv + tanks.mash_lag * max(0.0, rise)
        if not self._climbing and mash_pv < mash_sp - REHEAT_BAND:
            self._climbing = True
        if self._climbing and pump:
            high = coil.high
            peak = coast_peak(hlt_pv, mash, holding_hlt(mash_sp, tanks, high), tanks, high)
            self._climbing = peak < mash_sp
        if not pump:
            setpoint, phase = (
                min(ready_hlt(mash_sp, mash, hold + self._trim, tanks), ceiling),
                "ready",
            )
        elif self._climbing:
            setpoint, phase = ceiling, "climb"
        else:
            self._hold_trim(mash_sp, mash_pv, hlt_pv, hold, k)
            setpoint, phase = min(hold + self._trim, ceiling), "hold"
        self._last_sp = setpoint
        return Decision(setpoint, self._load(hlt_pv, mash_pv, pump, coil), phase)

    def _hold_trim(
        self, mash_sp: float, mash_pv: float, hlt_pv: float, hold: float, k: float
    ) -> None:
        """Integral on the mash's error once the HLT is down at its holding value (before,
        the coast is still carrying the mash up and the error says nothing of the model).
        Ti = 4·G·τ_m for the mash's first order (gain G = K/(K + UA_m), τ_m = C_m/(K + UA_m)):
        the critically damped integral loop."""
        if hlt_pv > hold + self._trim + HLT_MARGIN:
            return
        tanks = self._tanks
        total = k + tanks.mash_loss
        ti = 4.0 * (k / total) * tanks.mash_capacity / total
        trim = self._trim + self._period / ti * (mash_sp - mash_pv)
        self._trim = min(max(trim, -TRIM_LIMIT), TRIM_LIMIT)

    def _load(self, hlt: float, mash: float | None, pump: bool, coil: CoilEstimate) -> float:
        """The coil's draw on the HLT (W) for the HLT law to feed forward: K (one sd low)
        times the HLT over the mash; none with the pump stopped or no mash reading yet."""
        if not pump or mash is None:
            return 0.0
        return coil.low * (hlt - mash)
