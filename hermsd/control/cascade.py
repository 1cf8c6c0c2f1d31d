"""The HERMS's outer loop: the HLT's setpoint that brings the mash to its rest and holds it
there, and the coil's load for the HLT law to feed forward (derivation: docs/mash-control.md).

Pure and clock-free, as the laws are: `Cascade.step` once a control period.

The mash gains K·(T_hlt − T_m) through the coil and loses UA_m·(T_m − T_room), so in a hold the HLT
must stand at T_hold = T_sp + UA_m·(T_sp − T_room)/K, above the rest by the losses' share (why a
mash "levels out below" its HLT). Heat cannot be taken back from the mash, so a step runs as the
HLT law's own approach does, one level up: the HLT's setpoint stays at the limit (mash setpoint +
`max_hlt_above_mash`, less HLT_MARGIN for the HLT law's own overshoot or, where it is more, the
heat in flight for the coil that a pump stop nobody announced lands in the HLT, `stop_room`, with
the SSR's ripple and a step of the HLT's sensor on top; never above the HLT's maximum) until the
heat stored in the HLT above T_hold and in flight in the hose will carry the mash to its setpoint
as the two tanks coast together (`coast_peak`: the linear two-tank model run forward with the
element off until the HLT is down at T_hold). Then the HLT's setpoint is the HLT from which the
coast carries the mash to its setpoint (`coast_start`, judged again every period: below the HLT
while the coast holds, above it where it falls short), down to T_hold as the mash arrives, and from
there on the setpoint is T_hold plus a PI on the mash's error. UA_m is a guess; the mash's rise
against the model's once the climb is over, and the PI's integral, learn it, and what they learn
serves the next rest's T_hold and coast. With the pump stopped nothing flows, and the HLT is
readied: the setpoint is the temperature whose stored heat above T_hold just covers the mash's
shortfall (capped by the limit). A step down is the climb's mirror: the element off while the mash
falls, then T_hold as soon as full power must lift the HLT back to it for the mash to land on its
rest (`descent_trough`), the hold's PI once it is there.

The coast is judged with K one sd high (`CoilEstimate.high`): more heat in the hose and a
lower T_hold, so it stops early rather than late; the load fed forward is K's estimate (one
sd low was the prior's half of the pull at a pump start, met late; the HLT law learns the
share of it the water shows, `predictive.known_load`). A mash reading that is missing,
faulty or older than MAX_MASH_AGE holds the HLT at its last setpoint (flagged `held`, for
the daemon to warn), never at the limit on a guess.
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

from hermsd.control.coil import CoilEstimate
from hermsd.control.pid import SENSOR_LSB
from hermsd.control.watches import LineFit

HLT_MARGIN = 0.15
"""°C the HLT's setpoint stays below the limit: the HLT law overshoots its setpoint by up to
a tenth (its bench's bound), and the limit is one the HLT must never pass."""
COAST_AIM = 0.05
"""°C below its setpoint the coast's HLT aims the mash, under one of the LM92's steps: the HLT
law lets the coil's draw act through the coast (`Decision.load_met`), so no heat lands after
the aim but noise's; the hold's PI closes the rest (docs/mash-control.md, "The coast's
aim")."""
COAST_BISECTIONS = 16
"""Halvings of the HLT's range when solving for the coast's start (10 °C to 0.00015 °C)."""
REHEAT_BAND = 1.0
"""°C below its setpoint a mash in its hold must fall before the climb starts again (a stuck
pump, a cold addition): smaller falls are the hold's."""
RESTORED_BAND = 0.1
"""°C below its rest within which a held mash brought back after a pump stop is the hold's
error again (the integral learns from it): a tenth, near two of the LM92's steps. Over the
HERMS family, 0.05 and 0.1 °C gave the same days (docs/mash-control.md, "The hold")."""
SETPOINT_MOVE = 0.01
"""°C: a mash setpoint that moves by more starts a new step."""
MAX_MASH_AGE = 30.0
"""s: a mash reading older than this is none (the HLT is held, not steered on it)."""
COAST_STEPS = 40
"""Integration steps per coupled time constant of the coast (Heun: error ~1e-4 of the step)."""
COAST_SPAN = 10.0
"""Coupled time constants the coast is followed for at most (e^−10 of the gap is left)."""
HOLD_SPEEDUP = 2.0
"""How much faster than the mash's own time constant the hold's PI closes its loop, at most."""
DELAY_SHARE = 3.0
"""The hold's closed loop is at least this many times the delays around it (the mash sensor's
lag, the hose, the HLT's own response)."""
HLT_RESPONSE_S = 60.0
"""s: what the HLT law takes to follow its setpoint, counted in the hold's delays."""
LOSS_LEARN_S = 600.0
"""s: the time over which the mash's rise teaches its losses (noise of a period's mean, 0.013
°C, then moves them by under 1 W/K)."""
STARVED_FALL = 0.1
"""°C the mash, below its setpoint, must fall over its starved span (twice the delays between
the coil and its sensor, and a minute) for the outer loop to stop learning its losses: a mash
that gets the coil's heat stops falling once the hold's proportional part has raised the HLT
enough, where one that gets none (a stuck bed, a pump hermsd does not see stopped) falls at
its losses' rate, which taken for losses would be carried, as too hot an HLT, past the rest
once the wort flows again. Two steps of the LM92's 0.0625 °C: more than noise of 0.03 °C
makes between two readings."""
MASH_CAPACITY_SD = 0.05
"""The mash's heat capacity as the config gives it (water and grain) is good to this share: the
tun's own 0–5 kJ/K is not in it, nor is the grain's specific heat exact. Its error reads as loss
in proportion to the mash's rise, so the losses are learned the slower the faster it rises
(`Cascade._observe`)."""
MAX_LOSS_FACTOR = 4.0
"""The mash's losses as learned stay within 0 and this many times the config's (or 20 W/K,
whichever is more)."""
MASH_LINE_S = 60.0
"""s of mash readings the outer loop reads the mash through, as the least-squares line through
them (its level at the newest, and its rise): reading by reading, one 0.0625 °C step of the
LM92 moved the losses' observer by 0.5 W/K and a coast's HLT near its end by up to 0.7 °C a
period (bench/herms.py seed 8's 72 °C rest), the law's duty 0 → 47 % → 0. Over 13 readings
(noise 0.03 °C on the LM92's steps) the level's noise is about half a reading's and the rise's
a twentieth of a one-period difference's; the mash's slow rise bends little in a minute."""
FALL = "fall"
"""A step down's first stage: the element off, the mash falling to its rest."""
LAND = "land"
"""A step down's last stage: the HLT lifted to T_hold at full power as the mash arrives."""
STRIKE = "strike"
"""The phase of a program's step before the mash is in: the HLT held at the step's setpoint
itself (`MashControl.strike`), the outer loop not stepped."""
PAST_REST = 0.1
"""°C past its rest that a pump start's coast may carry the mash before the program's start
waits for the HLT to cool (`Cascade.start_waits_for`): half the overshoot's goal, the coast's
model and the mash's reading being what they are."""
MIN_CONDUCTANCE = 10.0
"""W/K: the least K the outer loop steers by. A K learned lower is a coil with no flow (a
stuck bed), where no HLT holds the mash; the hold's HLT then stays finite, at the limit."""


@dataclass(frozen=True, slots=True)
class Tanks:
    """The two tanks and the hose between them, as the outer loop's model.

    hlt_capacity, mash_capacity in J/K (water 4186 J/(L·K), grain about 1700 J/(kg·K));
    hlt_loss, mash_loss in W/K to the room at `room` °C; hose_delay in s (the wort's round trip
    outside the tun, mash → coil → mash, half each way); mash_lag in s (the mash sensor's lag
    behind the mash); hlt_dead_time in s (the HLT law's, between its duty and its sensor:
    the heat sent for the coil's load that is still on its way, and how far ahead the law's
    prediction of the HLT looks); hlt_ripple in °C (how far the water stands above its mean
    at the top of the SSR's pulses, half its swing: `TimeProportionalPlanner.swing`; 0 for
    an element whose power is steady); hlt_power in W (the element's full power, which lifts
    the HLT back to its hold at the end of a step down: `descent_trough`; 0: not known, the
    HLT then kept at the hold through a step down).
    """

    hlt_capacity: float
    hlt_loss: float
    mash_capacity: float
    mash_loss: float
    room: float
    hose_delay: float = 0.0
    mash_lag: float = 0.0
    hlt_dead_time: float = 0.0
    hlt_ripple: float = 0.0
    hlt_power: float = 0.0

    def __post_init__(self) -> None:
        for name in ("hlt_capacity", "mash_capacity"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) > 0.0):
                raise ValueError(f"{name}={getattr(self, name)!r} J/K is invalid: must be > 0")
        for name in (
            "hlt_loss",
            "mash_loss",
            "hose_delay",
            "mash_lag",
            "hlt_dead_time",
            "hlt_ripple",
            "hlt_power",
        ):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) >= 0.0):
                raise ValueError(f"{name}={getattr(self, name)!r} is invalid: must be ≥ 0")
        if not math.isfinite(self.room):
            raise ValueError(f"room={self.room!r} °C is invalid: must be finite")


@dataclass(frozen=True, slots=True)
class Decision:
    """One period's answer: the HLT's setpoint, the coil's load (W) to feed forward (or,
    `load_met` False, to let act), the phase ("climb", "coast" down to the hold, "hold",
    "ready" with the pump stopped, "no flow" with the pump running and nothing flowing,
    "held" without a mash reading, "strike" on a program's step before the mash is in)
    and, when held, why."""

    hlt_setpoint: float
    load_watts: float
    phase: str
    held: str | None = None
    load_met: bool = True  # False: a draw the HLT law lets act (the coast above its setpoint)


def line_through(readings: Sequence[float]) -> tuple[float, float | None]:
    """The newest of evenly spaced `readings` where the least-squares line through them puts
    it, and the line's rise a reading (the reading itself and None while there are too few to
    tell noise from a rise: `LineFit.slope`)."""
    line = LineFit()
    for i, reading in enumerate(readings):
        line.add(float(i), reading)
    slope = line.slope()
    if slope is None:
        return readings[-1], None
    return line.sx / line.n + slope * (line.n - 1 - line.st / line.n), slope


def holding_hlt(mash_sp: float, tanks: Tanks, conductance: float) -> float:
    """The HLT temperature that holds the mash at `mash_sp` through a coil of `conductance`
    (W/K): T_sp + UA_m·(T_sp − T_room)/K."""
    return mash_sp + tanks.mash_loss * (mash_sp - tanks.room) / conductance


def stop_room(hlt: float, mash: float, k: float, tanks: Tanks) -> float:
    """°C an HLT at `hlt` rises when the pump stops unannounced (a brewer's stir, a pump the
    daemon only sees, an operator's off): the heat sent for the coil's load K·(T_h − T_m)
    over the HLT law's dead time lands in water nothing draws from. A climb's setpoint
    stays that far under the limit where it exceeds HLT_MARGIN (the law's overshoot
    belongs to a climb that goes on, the landing to one that stops: they do not add)."""
    return k * max(0.0, hlt - mash) * tanks.hlt_dead_time / tanks.hlt_capacity


def coast_peak(hlt: float, mash: float, hold: float, tanks: Tanks, conductance: float) -> float:
    """The mash's highest temperature if the element stops now and the HLT coasts from `hlt`
    down to `hold` (°C), giving its heat through a coil of `conductance` (W/K), after which
    the HLT is held at `hold`. The linear two-tank model, integrated by Heun's method, with
    the hoses: the heat already in the return leg (K·(T_h − T_m) for half the round trip)
    arrives first, and the coil sees the mash as it was half the round trip before."""
    return _coast(hlt, mash, hold, tanks, conductance, 0.0, 1.0)


def descent_trough(hlt: float, mash: float, hold: float, tanks: Tanks, conductance: float) -> float:
    """The mirror of `coast_peak` for a step down: the mash's lowest temperature if the
    element goes to full power (`Tanks.hlt_power`) now and lifts the HLT from `hlt` up to
    `hold`, the coil meanwhile drawing the mash's heat into the colder HLT; after that the
    HLT is held at `hold`."""
    return _coast(hlt, mash, hold, tanks, conductance, tanks.hlt_power, -1.0)


def _coast(
    hlt: float,
    mash: float,
    hold: float,
    tanks: Tanks,
    conductance: float,
    power: float,
    sign: float,
) -> float:
    """The two tanks run forward with the element at `power` (W) until the HLT reaches
    `hold`: `sign` 1, the HLT falling to it from above and the mash's peak (`coast_peak`);
    −1, the HLT rising to it from below and the mash's trough (`descent_trough`)."""
    k = conductance
    ch, cm = tanks.hlt_capacity, tanks.mash_capacity
    leg = 0.5 * tanks.hose_delay
    mash += k * (hlt - mash) * leg / cm
    if sign * (hlt - hold) <= 0.0 or k <= 0.0:
        return mash
    coupled = 1.0 / (k * (1.0 / ch + 1.0 / cm))
    dt = coupled / COAST_STEPS
    room, uah, uam = tanks.room, tanks.hlt_loss, tanks.mash_loss

    # The inlet lags the mash by a leg, m − leg·dm/dt; with dm/dt = (flow − UA_m·(m − room))/C_m
    # that gives flow·(1 − a) = K·(h − m) − a·UA_m·(m − room), a = K·leg/C_m (a < 1 for any
    # real hose: a minute's leg on a 400 W/K coil and 24 kJ/K of mash).
    a = k * leg / cm if k * leg < 0.5 * cm else 0.0

    def rates(h: float, m: float) -> tuple[float, float]:
        mash_loss = uam * (m - room)
        flow = (k * (h - m) - a * mash_loss) / (1.0 - a)
        return (power - flow - uah * (h - room)) / ch, (flow - mash_loss) / cm

    extreme = mash
    for _ in range(round(COAST_STEPS * COAST_SPAN)):
        dh1, dm1 = rates(hlt, mash)
        if sign * dm1 <= 0.0:
            break
        dh2, dm2 = rates(hlt + dt * dh1, mash + dt * dm1)
        dh, dm = 0.5 * dt * (dh1 + dh2), 0.5 * dt * (dm1 + dm2)
        if sign * (hlt + dh - hold) <= 0.0:  # at the hold within this step: the mash then
            reached = mash + dm * (hold - hlt) / dh
            return reached if sign * (reached - extreme) > 0.0 else extreme
        hlt += dh
        mash += dm
        if sign * (mash - extreme) > 0.0:
            extreme = mash
    return extreme


def coast_start(
    mash: float, hold: float, tanks: Tanks, conductance: float, target: float, ceiling: float
) -> float:
    """The HLT (between `hold` and `ceiling`) from which the coast carries the mash from `mash`
    to a peak of `target` (bisection: the peak rises with the HLT it starts from)."""
    low, high = hold, ceiling
    if coast_peak(high, mash, hold, tanks, conductance) <= target:
        return high
    for _ in range(COAST_BISECTIONS):
        middle = 0.5 * (low + high)
        if coast_peak(middle, mash, hold, tanks, conductance) < target:
            low = middle
        else:
            high = middle
    return low


def descent_floor(
    mash: float, hold: float, tanks: Tanks, conductance: float, target: float
) -> float:
    """The lowest HLT (between the room and `hold`) from which full power, from now, lifts the
    HLT to `hold` before the mash falling to its rest passes below `target`
    (`descent_trough`, by bisection: the trough rises with the HLT it starts from)."""
    low, high = min(tanks.room, hold), hold
    if descent_trough(low, mash, hold, tanks, conductance) >= target:
        return low
    for _ in range(COAST_BISECTIONS):
        middle = 0.5 * (low + high)
        if descent_trough(middle, mash, hold, tanks, conductance) >= target:
            high = middle
        else:
            low = middle
    return high


def ready_hlt(mash_sp: float, mash: float, hold: float, tanks: Tanks) -> float:
    """With the pump stopped: the HLT whose heat above `hold` covers the mash's shortfall,
    C_h·(T − T_hold) = C_m·(T_sp − T_m) (losses and the coast's time aside)."""
    return hold + tanks.mash_capacity * max(0.0, mash_sp - mash) / tanks.hlt_capacity


class Cascade:
    """The outer loop: mash setpoint and readings in, the HLT's setpoint and the coil's load
    out (see the module's docstring)."""

    __slots__ = (
        "_after_stop",
        "_climbing",
        "_descent",
        "_hlt_max",
        "_last_mash",
        "_last_sp",
        "_letting",
        "_limit",
        "_mash_line",
        "_mash_loss",
        "_mash_sp",
        "_mash_span",
        "_pairs",
        "_period",
        "_room_read",
        "_seen",
        "_settled",
        "_tanks",
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
        # (HLT, mash) readings back to those the mash's rise answers (`_observe`): the HLT the
        # wort met in the coil half the hose, the mash sensor's lag and half the line before
        # (the line's middle lies that far back), and the mash it left the tun as, as read
        # the whole hose and half the line before (the reading a lag behind the mash).
        behind = 0.5 * tanks.hose_delay + tanks.mash_lag + 0.5 * MASH_LINE_S
        inlet = tanks.hose_delay + 0.5 * MASH_LINE_S
        self._pairs = (round(behind / period), round(inlet / period))
        self._seen: deque[tuple[float, float]] = deque(maxlen=max(self._pairs) + 1)
        span = 2.0 * (tanks.hose_delay + tanks.mash_lag) + 60.0  # `STARVED_FALL`
        self._mash_span: deque[float] = deque(maxlen=round(span / period) + 1)
        self._mash_line: deque[float] = deque(maxlen=round(MASH_LINE_S / period) + 1)
        self._climbing = True
        self._descent: str | None = None  # a step down's stage: FALL, then LAND
        self._settled = False  # the HLT has come down to its hold since the climb ended
        self._after_stop = False  # the held mash is brought back after a pump stop
        self._letting = True  # the coast lets the coil's draw act (`Decision.load_met`)
        self._mash_loss = tanks.mash_loss
        self._room_read: float | None = None  # °C, the room as the empty tun read it

    @property
    def coasting(self) -> bool:
        """Whether the climb is over and the HLT not yet down at its hold: the coast, the pump
        running or stopped a while within it."""
        return not (self._climbing or self._settled)

    @property
    def descending(self) -> bool:
        """Whether a step down is under way (the mash falling to a lower rest, the HLT
        lifted back as it arrives): the mash's fall is the step's, not the coil's."""
        return self._descent is not None

    @property
    def mash_loss(self) -> float:
        """The mash's losses (W/K) as the holds so far showed them (the config's before)."""
        return self._mash_loss

    @mash_loss.setter
    def mash_loss(self, loss: float) -> None:
        """Back to losses learned before (the ones since came of a mash that got no heat)."""
        self._mash_loss = loss

    @property
    def room(self) -> float:
        """°C the tanks' losses are reckoned to: the HLT model's, or the one read (`room_seen`)."""
        return self._tanks.room

    def room_seen(self, room: float) -> None:
        """The room as the mash tun's sensor read it empty (`MashControl.strike`): the tanks'
        losses reckoned to it, not to the HLT model's room (bench/herms.py seed 3, 32 °C
        where the model says 20: the first rest 0.38 °C over)."""
        self._room_read = room
        self._tanks = dataclasses.replace(self._tanks, room=room)

    def carry(self, before: Cascade) -> None:
        """What `before` (the outer loop a reload replaces) measured of the day, where the
        config still means what it did: the room as read, and the mash's losses as the holds
        showed them unless their guess or the mash changed (a brewer raising the limit on
        the reach warning's word would otherwise lose both mid-mash, and the hold's HLT
        with them). The step itself starts afresh."""
        if before._room_read is not None:
            self.room_seen(before._room_read)
        kept = before._tanks
        if (kept.mash_loss, kept.mash_capacity) == (
            self._tanks.mash_loss,
            self._tanks.mash_capacity,
        ):
            self._mash_loss = before._mash_loss

    def start_waits_for(
        self, mash_sp: float, mash_pv: float, hlt: float, coil: CoilEstimate
    ) -> float | None:
        """None where the wort flowing from now lands the mash within PAST_REST of its rest on
        the HLT's heat alone, the element off (`coast_peak`, K one sd high: more heat in the
        hose, a lower T_hold); else the HLT (°C) from which that coast lands it on its rest,
        which a start waits for: an HLT held at a strike hotter than the rest's HLT has more
        stored heat above T_hold than the mash lacks, and heat cannot be taken back."""
        if mash_pv >= mash_sp:
            return None  # a mash at or over its rest (a step down) comes down with the wort
        tanks, high, hold = self._judged(mash_sp, coil)
        if coast_peak(hlt, mash_pv, hold, tanks, high) <= mash_sp + PAST_REST:
            return None
        return coast_start(mash_pv, hold, tanks, high, mash_sp, hlt)

    def _judged(self, mash_sp: float, coil: CoilEstimate) -> tuple[Tanks, float, float]:
        """The tanks with the mash's losses as learned, and K one sd high with the T_hold it
        gives: what the climb's end, the coast and a start's wait are judged on."""
        tanks = dataclasses.replace(self._tanks, mash_loss=self._mash_loss)
        high = max(coil.high, MIN_CONDUCTANCE)
        return tanks, high, holding_hlt(mash_sp, tanks, high)

    def ceiling(self, mash_sp: float) -> float:
        """The highest HLT setpoint for `mash_sp`: the limit less HLT_MARGIN, at most the
        HLT's maximum."""
        return min(mash_sp + self._limit - HLT_MARGIN, self._hlt_max)

    def most(self, mash_sp: float, mash_pv: float, k: float) -> float:
        """The climb's HLT setpoint for a mash at `mash_pv` through a coil of `k` W/K: the
        ceiling, less the room an unannounced stop needs beyond HLT_MARGIN: its landing
        (`stop_room`) lifts the water's mean, and the SSR's pulses lift the water above
        that by `Tanks.hlt_ripple` (bench/herms.py seed 13's 72 °C rest, a 7.9 kW element on
        68 L: a stir's landing 0.0035 °C over the limit without it), on water up to a step
        of its sensor above the reading (`_over_reading`). A climb that goes on has them
        within HLT_MARGIN's spare (docs/mash-control.md, "The limit")."""
        ceiling = self.ceiling(mash_sp)
        landing = stop_room(ceiling, mash_pv, k, self._tanks) + self._over_reading()
        room = max(HLT_MARGIN, landing) - HLT_MARGIN
        return ceiling - room

    def _over_reading(self) -> float:
        """°C the water may stand above the HLT's reading at the top of the SSR's pulses:
        half their swing (`Tanks.hlt_ripple`) and one of the sensor's steps (the LM92 and the
        DS18B20 truncate to 0.0625 °C; the law holds the reading, the water stands up to a
        step above it: bench/herms.py --step-down seed 26's 70 °C rest, a stop's landing
        0.002 °C over the limit without it)."""
        return self._tanks.hlt_ripple + SENSOR_LSB

    def step(
        self,
        *,
        mash_sp: float,
        mash_pv: float | None,
        mash_age: float,
        hlt_pv: float,
        pump: bool,
        coil: CoilEstimate,
        flowing: bool = True,
        paused: bool = False,
        starting: bool = False,
        waiting: bool = False,
        hlt_reading: float | None = None,
    ) -> Decision:
        """One period. `mash_pv` None (a fault) or older than MAX_MASH_AGE (`mash_age`, s):
        the HLT held at its last setpoint. `hlt_pv` is best the HLT law's predicted PV (the
        heat already sent counted). `flowing` False (the pump runs, no wort flows:
        `flow_watch.FlowWatch`): as with the pump stopped, the HLT readied with the heat the
        mash lacks, nothing learned of the mash's losses, no load fed forward; the phase is
        "no flow". `paused`: the pump stopped for a while by the program's timer, its restart
        due: the HLT's setpoint kept where it stood (a stop of a minute or two is no reason
        to ready the HLT for another mash; the restart, prepared, meets the HLT it left), in
        a climb no higher than the HLT from which the restart's coast carries the mash to
        its rest. `starting`: a pump start hermsd prepares (the pump switched a dead time
        on): the HLT readied no higher than the climb's setpoint the start begins (`most`),
        so that it is let down to it as the coil draws, not held at the ceiling with the
        whole draw's heat in flight (`prepared_load`). `waiting`: a start held while the HLT's heat
        would carry the mash past its rest (`start_waits_for`): the HLT readied no higher than
        the HLT from which the start's coast carries the mash to its rest, so that it cools
        to where the start is made (readied as for any stop, the heat the mash lacks above
        T_hold, the hose's heat would keep it above that for good). `hlt_reading`: the HLT
        sensor's own reading, where `hlt_pv` is the law's prediction (None: not known
        apart)."""
        stood = pump and not flowing
        pump = pump and flowing
        ceiling = self.ceiling(mash_sp)
        if mash_pv is None or not mash_age <= MAX_MASH_AGE:
            why = "no mash reading" if mash_pv is None else f"mash reading {mash_age:.0f} s old"
            last = self._last_sp if self._last_sp is not None else min(mash_sp, ceiling)
            setpoint = min(last, ceiling)
            self._last_sp = setpoint
            load = self._load(hlt_pv, self._last_mash, pump, coil)
            self._mash_line.clear()  # the readings after the gap are not evenly spaced with it
            return Decision(setpoint, load, "held", why)
        if self._mash_sp is None or abs(mash_sp - self._mash_sp) > SETPOINT_MOVE:
            self._climbing = mash_pv < mash_sp
            self._descent = FALL if mash_pv > mash_sp + RESTORED_BAND else None
            self._settled = self._settled and self._descent is None
            self._after_stop = False
        self._mash_sp = mash_sp
        self._last_mash = mash_pv
        tanks, high, hold_high = self._judged(mash_sp, coil)
        k = max(coil.conductance, MIN_CONDUCTANCE)
        hold = holding_hlt(mash_sp, tanks, k)
        # The mash as read: the line through its last readings (MASH_LINE_S; a stop of the
        # pump begins a new one), its level at the newest and its rise a period.
        line = self._mash_line
        if not pump:
            line.clear()
        line.append(mash_pv)
        read, rose = line_through(line)
        # The mash as it is now: its sensor lags it by mash_lag while it rises at the model's
        # rate (and while it falls, in a step down: there the late side is the low one).
        flow = k * (hlt_pv - read) if pump else 0.0
        rise = (flow - tanks.mash_loss * (read - tanks.room)) / tanks.mash_capacity
        mash = read + tanks.mash_lag * (rise if self._descent else max(0.0, rise))
        if pump:
            # And as it will be when the HLT is at `hlt_pv`, the law's prediction a dead time
            # ahead: that prediction takes the coil's draw off the HLT over the dead time, and
            # the mash takes it in (at the span's mean, the mash rising meanwhile; what is in
            # the hose's return leg then, `coast_peak` counts). Paired with the mash as read,
            # the coast missed that heat: bench/herms.py seed 66's first rest 0.64 °C over.
            ahead = tanks.hlt_dead_time
            reaching = max(0.0, ahead - 0.5 * tanks.hose_delay)
            gained = k * (hlt_pv - mash) * reaching - tanks.mash_loss * (mash - tanks.room) * ahead
            mash += gained / (tanks.mash_capacity + 0.5 * k * reaching)
        # The peak aimed at the rest itself: K one sd high (and the mash's losses, a low prior)
        # already stop the climb early, and a coast that ends short closes its last tenths
        # on the mash's own slow time constant.
        target = mash_sp
        if not self._climbing and mash_pv < mash_sp - REHEAT_BAND:
            # From the hold; from the coast only where even the ceiling would not carry the
            # mash there (a stuck bed, a cold addition): a coast that falls a little short
            # raises its own setpoint (`coast_start`), where a climb of a period or two
            # would send the HLT's setpoint to the ceiling and back.
            self._climbing = self._settled or (
                pump and coast_peak(ceiling, mash, hold_high, tanks, high) < target
            )
        if self._climbing and pump:
            self._climbing = coast_peak(hlt_pv, mash, hold_high, tanks, high) < target
        self._settled = self._settled and not self._climbing
        self._descent = None if self._climbing else self._descent
        if self._descent is None and not self._climbing and mash_pv > mash_sp + REHEAT_BAND:
            # A mash a degree over its rest (the strike water's heat landed with a pump
            # nobody could hold, a hot addition) comes down as a step down does: by the
            # hold's PI the HLT lay under T_hold as it arrived, it sank under its rest, and
            # the flow watch read its fall as no flow (tests/test_mash.py).
            self._descent, self._settled = FALL, False
        window = self._mash_span
        if not pump:
            window.clear()
        window.append(mash_pv)
        starved = (
            len(window) == window.maxlen
            and mash_pv < mash_sp
            and window[0] - mash_pv >= STARVED_FALL
        )
        whole = rose if len(line) == line.maxlen else None  # a rise centred where `_seen` pairs it
        # The HLT as its sensor reads it, as the coil's K was learned (the law's prediction
        # runs a dead time's heat ahead of the water in a climb).
        hlt_read = hlt_pv if hlt_reading is None else hlt_reading
        self._observe(read, whole, hlt_read, pump and not starved, k, high)
        # A stop once the climb is over (a stir, a timer; in the hold or in the coast, which
        # may give way to the hold as the wort flows again) cools the mash by what the stop
        # lasted, not by an error of the model: the hold's integral does not take it for
        # losses until the mash is back within RESTORED_BAND of its rest.
        if not pump and not self._climbing:
            self._after_stop = True
        elif mash_pv >= mash_sp - RESTORED_BAND:
            self._after_stop = False
        if not pump:
            setpoint = min(ready_hlt(mash_sp, mash, hold, tanks), ceiling)
            kept = self._last_sp if paused else None  # a timer's stop keeps the setpoint
            if kept is not None:
                setpoint = kept
                if self._climbing:
                    # What the HLT takes in the stop its restart's coast gives the mash: no
                    # more than from where that coast carries it to its rest, as the climb
                    # would have ended with the pump running.
                    peak = coast_start(mash, hold_high, tanks, high, target, ceiling)
                    setpoint = min(setpoint, peak)
            if starting and not (kept is not None and self._climbing):
                # A start prepared (due in a dead time; a timer's restart in the coast or the
                # hold too, its stop having cooled the mash): readied to the HLT from which its
                # coast carries the mash to its rest, where that is above the setpoint so far
                # (the stored heat's estimate, the mash's losses over the coast counted): a
                # start whose coast falls short begins a climb, and from the lower HLT the
                # climb's first dead time is the coil's draw unmet (bench/herms.py seed 19: a
                # stir's restart into a climb from 0.9 °C under its setpoint, the HLT 0.3 °C
                # down; seed 71's 63 °C coast, seeds 41–80: 0.19 °C down). Not for a stop of
                # unknown length: an HLT readied high asks the element for heat a shorted SSR
                # then gives unseen (docs/mash-control.md, "The hold").
                setpoint = max(setpoint, coast_start(mash, hold_high, tanks, high, target, ceiling))
            if starting:
                setpoint = min(setpoint, self.most(mash_sp, mash_pv, k))
            if waiting:
                setpoint = min(setpoint, coast_start(mash, hold_high, tanks, high, target, ceiling))
            if hlt_reading is not None and hlt_reading > mash_sp + self._limit:
                # The water above the limit (a strike left above the first rest + limit): no
                # heat until it reads at or below it. The law lands on a setpoint from above
                # sending heat from when its prediction a dead time ahead meets it, the water
                # itself still its fall over the dead time above, and that heat's pulses ride
                # on water falling slowly through the limit (bench/herms.py seeds 28, 34 and
                # 50: 0.001 °C back over it); let fall, it passes the limit once, whatever the
                # stop (a timer's, a start being prepared).
                setpoint = min(setpoint, mash_sp)
            phase = "no flow" if stood else "ready"
        elif self._climbing:
            setpoint, phase = self.most(mash_sp, mash_pv, k), "climb"
        elif self._descent and read > mash_sp + RESTORED_BAND:
            # A step down: the element off while the mash falls, the HLT with it (the coil
            # draws the mash's heat into it once it is the colder), until full power must lift
            # the HLT back to T_hold for the mash to land on its rest (`descent_trough`); then
            # T_hold, the law's way there at full power, until the mash is at its rest. Judged
            # with K one sd either side, whichever lands the mash the lower: K high draws it
            # down the faster, K low needs the HLT the further above it to stop its fall (a
            # lossy mash). Held at T_hold throughout, the mash would come down on its own slow
            # time constant; held by the hold's PI, whose error is degrees, the HLT lay
            # degrees under T_hold as the mash arrived, which went on falling (1.4 °C under a
            # 64 °C rest, and no flow seen: docs/mash-control.md, "A step down").
            low = max(coil.low, MIN_CONDUCTANCE)
            sides = ((hold_high, high), (holding_hlt(mash_sp, tanks, low), low))
            if self._descent == FALL and any(
                descent_trough(hlt_pv, mash, at, tanks, c) < mash_sp for at, c in sides
            ):
                self._descent = LAND
            setpoint = hold
            if self._descent == FALL:  # the lowest HLT the lift may start from: the element off
                floor = max(descent_floor(mash, at, tanks, c, mash_sp) for at, c in sides)
                setpoint = min(floor, hlt_pv)
            setpoint, phase = min(setpoint, ceiling), "coast"
        else:
            if self._descent:  # the mash is at its rest: the hold's PI from here
                self._descent, self._settled = None, True
            setpoint = self._hold(
                mash_sp,
                read,
                mash,
                hlt_pv,
                tanks,
                (k, high),
                learn=not (starved or self._after_stop),
            )
            phase = "hold" if self._settled else "coast"
            if not self._settled:
                # The HLT from which the coast carries the mash to its rest, judged again each
                # period (below the HLT while the coast holds, the element off; above it where
                # the coast falls short, the losses more than the model's, which the observer
                # is learning): one setpoint that moves with the tanks, not a hold and a raise
                # taken in turn as the HLT's prediction crosses between them.
                aim = target - COAST_AIM
                setpoint = max(setpoint, coast_start(mash, hold_high, tanks, high, aim, ceiling))
            setpoint = min(setpoint, ceiling)
        self._last_sp = setpoint
        load = self._load(hlt_pv, read, pump, coil)
        # The coast lets the coil's draw act until the HLT is down at its setpoint, and again
        # once it stands HLT_MARGIN above it: the prediction moves with the heat sent for the
        # draw, and judged without the margin the draw would be met and let act in turn.
        # Outside the coast the next one is armed to begin letting it act.
        coast = phase == "coast"
        if not coast or hlt_pv > setpoint + HLT_MARGIN:
            self._letting = True
        elif hlt_pv <= setpoint:
            self._letting = False
        return Decision(setpoint, load, phase, load_met=not (coast and self._letting))

    def _observe(
        self, mash: float, rose: float | None, hlt: float, pump: bool, k: float, high: float
    ) -> None:
        """Learn the mash's losses from its rise while the wort flows (`pump` False: no heat
        reaches the mash, a stopped pump or a starved mash, and its rise says nothing until
        a delay after it does): the rise a period (`rose`, the line's through the last
        MASH_LINE_S) against the model's, from the HLT (`hlt`, as read) and the mash as read
        that it answers (`_pairs`), the miss taken as loss with the time LOSS_LEARN_S, slowed
        where K's uncertainty or the mash's heat capacity's stands out of the losses."""
        seen = self._seen
        if not pump:
            seen.clear()
            return
        seen.append((hlt, mash))
        tanks = self._tanks
        if len(seen) < (seen.maxlen or 0) or rose is None:
            return
        h, m = seen[-1 - self._pairs[0]][0], seen[-1 - self._pairs[1]][1]
        above_room = m - tanks.room
        if above_room < 1.0:
            return
        modelled = self._period * (k * (h - m) - self._mash_loss * above_room)
        miss = modelled - tanks.mash_capacity * rose  # J the model gave the mash too many
        # Taught as fast as the losses stand out of the balance's other uncertain terms (a
        # gain of 1/(1 + s²), s = √((σ_K·(T_h − T_m))² + (σ_C·dT_m/dt)²)/(UA_m·(T_m − T_room))):
        # in a climb or a coast the coil's kilowatts, K a prior's ±50 %, would teach its error
        # as losses, and a climb's fast rise the heat capacity's (`MASH_CAPACITY_SD`).
        stored = MASH_CAPACITY_SD * tanks.mash_capacity * rose / self._period
        uncertain = math.hypot((high - k) * (h - m), stored)
        spread = uncertain / (max(self._mash_loss, 1.0) * above_room)
        rate = self._period / LOSS_LEARN_S / (1.0 + spread * spread)
        learned = self._mash_loss + rate * miss / (self._period * above_room)
        self._mash_loss = min(max(learned, 0.0), max(MAX_LOSS_FACTOR * tanks.mash_loss, 20.0))

    def _hold(
        self,
        mash_sp: float,
        mash_pv: float,
        mash: float,
        hlt_pv: float,
        tanks: Tanks,
        ks: tuple[float, float],
        learn: bool,
    ) -> float:
        """T_hold, and once the HLT has come down to it (before, the coast still carries the
        mash up and its error says nothing of the model) a PI on the mash's error: the
        mash is a first order of gain G = K/(K + UA_m) and time constant τ_m = C_m/(K + UA_m),
        so Ti = τ_m cancels its pole and Kp·G = λ closes the loop λ times faster, λ at most
        HOLD_SPEEDUP and slow enough for the delays around it. The integral is kept as the
        mash's losses: ΔUA_m = ΔI·K/(T_sp − T_room), so the next rest starts from them.
        Never above the HLT from which a coast carries `mash` (the mash as it is now) to its
        rest (`coast_start`, K one sd high as the coast takes it; `ks`: K and that): heat
        stored in the HLT cannot be taken back, and a mash that does not follow the coil (a
        stuck bed, a pump hermsd does not see stopped) would have the PI raise the HLT by
        degrees that land in the mash past its rest once the wort flows again. The integral
        stands still at the ceiling, at that bound where it stands above T_hold, and while
        the mash is starved (`learn` False: `STARVED_FALL`)."""
        k, high = ks
        hold = holding_hlt(mash_sp, tanks, k)
        self._settled = self._settled or hlt_pv <= hold + HLT_MARGIN
        if not self._settled:
            return hold
        total = k + tanks.mash_loss
        gain, tau = k / total, tanks.mash_capacity / total
        delays = tanks.mash_lag + tanks.hose_delay + HLT_RESPONSE_S
        speedup = min(HOLD_SPEEDUP, tau / (DELAY_SHARE * delays))
        kp = speedup / gain
        error = mash_sp - mash_pv
        above_room = mash_sp - tanks.room
        ceiling = self.ceiling(mash_sp)
        bound = ceiling
        short = False  # the coast from T_hold falls short of the rest: the bound is the coast's
        if error > 0.0:  # the coast's own model: down to T_hold with K high, then held there
            hold_high = holding_hlt(mash_sp, tanks, high)
            short = coast_start(mash, hold_high, tanks, high, mash_sp, ceiling) > hold
            bound = hold
            if short:
                # Aimed COAST_AIM short, as the coast's own setpoint is: after a pump's stop
                # the HLT law's heat in flight and the hose land in the mash after the aim
                # (bench/herms.py seed 4: aimed at the rest, 0.33 °C over it after a stir).
                aim = mash_sp - COAST_AIM
                bound = max(hold, coast_start(mash, hold_high, tanks, high, aim, ceiling))
        # Held at the coast's bound the output does not follow the integral, which would
        # only wind up (anti-windup); held at T_hold itself where the coast from there reaches
        # the rest (the bound no higher) it does: it moves T_hold, which may be too low (a K
        # too high that is never learned).
        bounded = short and hold + kp * error >= bound
        at_ceiling = hold + kp * error >= ceiling and error > 0.0
        if learn and above_room > 1.0 and not (at_ceiling or bounded):
            integral = kp * self._period / tau * error
            most = max(MAX_LOSS_FACTOR * self._tanks.mash_loss, 20.0)
            loss = self._mash_loss + integral * k / above_room
            self._mash_loss = min(max(loss, 0.0), most)
        learned = dataclasses.replace(tanks, mash_loss=self._mash_loss)
        return min(holding_hlt(mash_sp, learned, k) + kp * error, bound)

    def _load(self, hlt: float, mash: float | None, pump: bool, coil: CoilEstimate) -> float:
        """The coil's draw on the HLT (W) for the HLT law: K's estimate times the HLT over
        the mash; none with the pump stopped (or nothing flowing through it: `flowing`) or
        no mash reading yet. Fed forward with the HLT above its setpoint too: the law then
        waits for the draw to bring it down, and sends the heat a dead time ahead of that
        instant rather than after it. In the coast above its setpoint it is a draw to let
        act (`Decision.load_met` False): the coast is the element off (`coast_peak`'s
        model); fed forward, the law would hold the HLT at the coast's setpoint against the
        coil, heat the model does not count, that lands in the mash past its rest (bench
        seed 4: the element at full power 2 min into the coast, the mash 0.89 °C over); told
        no draw at all, its bias learned the coil's as losses and kept the element at a tenth
        through the coast (seed 35's first rest, the mash 0.21 °C over)."""
        if not pump or mash is None:
            return 0.0
        return coil.conductance * (hlt - mash)

    def prepared_load(
        self, hlt: float, mash: float, setpoint: float, k: float, mash_sp: float
    ) -> float:
        """The coil's draw (W) a pump start being prepared will make, told the HLT law ahead
        of it: K times the HLT over the mash; none in the coast above its setpoint (a timer's
        stop within it), where the draw, once the pump runs, is let act (`_load`), not met
        (bench/herms.py seed 35: the restart's heat sent while the HLT stood 0.7 °C above
        the coast's setpoint, the mash 0.27 °C over). No more than the HLT at `hlt` takes
        under its limit for `mash_sp` (`_over_reading` on top) if the coil drew none of it:
        the law sends it a dead time ahead, and a draw less than told (K a prior, a mash
        sensor still catching up with the dough-in, the wort's first hose-length) lands it
        in the HLT (seed 13: told 8.4 kW of a 3.3 kW draw, the HLT 0.01 °C over)."""
        if self.coasting and hlt > setpoint:
            return 0.0
        draw = max(0.0, k * (hlt - mash))
        dead = self._tanks.hlt_dead_time
        if dead <= 0.0:
            return draw
        room = max(0.0, self.ceiling(mash_sp) + HLT_MARGIN - self._over_reading() - hlt)
        return min(draw, room * self._tanks.hlt_capacity / dead)
