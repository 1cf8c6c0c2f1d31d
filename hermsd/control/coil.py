"""The HERMS coil's conductance K (W/K), learned from the day's own data (docs/mash-control.md).

The coil passes Q = K·(T_hlt − T_in) from the HLT's water to the wort. The HLT's heat balance
over a run of periods with the pump on says how much it gave:

    C_h·(T_h(t) − T_h(t0)) = ∫ P·u(s − θ) ds − ∫ UA_h·(T_h − T_room) ds − K·∫ (T_h − T_m) ds

with C_h and UA_h the HLT's heat capacity and losses (the HLT law's model: C_h = P / rate),
u the duty applied a dead time θ before (the element's heat reaches the sensor then), and
the mash's reading T_m for the coil's inlet. The left side less the element's heat plus the
losses, y, falls against x = ∫ (T_h − T_m) ds with slope −K. Summed over the run, noise on a
reading enters y once (at its end) instead of once per difference, and a hose's delay or a
sensor's lag shifts only the ends of the sums (the learner's balance fit does the same for
the losses, `learning.Learner`).

One line is fitted per block of BLOCK_S (its own intercept, so an offset carried in from
before the block does not count). A block in the climb, where T_h − T_m is several degrees,
pins K to a few W/K; one in the hold (T_h − T_m under a degree) barely, and an error of the
HLT's loss model biases it. Blocks are combined weighted by the spread of their x (inverse
variance, as the noise on y is the same in every block), and the uncertainty is the weighted
scatter of the blocks about the mean, so a model error that differs between climb and hold
shows in it, not only the sensor's noise; never under SD_FLOOR of K (the HLT model's own
error: C_h from the element's rated power). With one or two blocks the day's K stands with
FEW_SD of itself; before any, the prior.

The HLT's losses are the model's, UA_h·(T_h − T_room) with its room: a room unlike the model's
(a garage in winter, the model measured in summer) or a loss prior off puts a steady power
into y that the fit reads as K, (P_err)/(T_h − T_m) of it: in a hold, where T_h − T_m is a
degree or two, 150 W of it is K off by 100 W/K. With the pump stopped the coil draws nothing,
and the same balance shows that power alone, so it is measured there (`_learn_offset`: the
strike water's hold before mash-in, a stir, a timer's stop) and taken off y while the pump
runs (docs/mash-control.md, "Learning K").
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from hermsd.control.watches import LineFit

BLOCK_S = 120.0
"""s of pump run per fitted line: long against the sensors' lags and the hose's delay, short
enough that the first step's climb holds several (the prior's wide K costs that step time)."""
SETTLE_S = 60.0
"""s after the pump starts before a block opens: the coil and hoses still hold the stagnant
wort's temperature, which the mash's reading does not show."""
MIN_BLOCKS = 3
"""Blocks that show their own scatter; with fewer (one or two) the day's K stands with
FEW_SD of itself, wider than a block's noise says, for what one block cannot show."""
FEW_SD = 0.15
OFFSET_MEMORY_S = 3600.0
"""s of the pump's stopped time over which the HLT model's error is remembered (the room's
drift over a brew day is slower; the noise of a reading's ends over it is a few W)."""
OFFSET_LEAST_S = 300.0
"""s of stopped time before that error is used: the ends' noise, C_h·0.06 °C over it, is then
under 50 W on a 60 L HLT (with less, none is taken)."""
SD_FLOOR = 0.05
"""The least relative uncertainty claimed: the HLT's heat capacity comes from the element's
rated power, which is known to a few percent."""
PRIOR_SD_SHARE = 0.5
"""The prior's sd as a share of itself: a HERMS coil is 100–400 W/K, so a prior of 200 W/K
± 100 covers the family's middle."""
MAX_CONDUCTANCE = 5000.0
"""W/K: more than any HERMS coil (a 12 m coil of ½" copper at a fast pump is under 1000)."""


@dataclass(frozen=True, slots=True)
class Exchange:
    """One period's exchange over the coil as the HLT's heat balance shows it: `drive`, the
    integral of T_h − T_m (K·s), and `heat`, the heat (J) the HLT's water gave the coil (its
    element's heat less its losses and the heat it gained); `heat` ≈ K·`drive` while the
    wort flows, 0 while it does not."""

    drive: float
    heat: float


@dataclass(frozen=True, slots=True)
class CoilEstimate:
    """The coil's conductance K (W/K), its standard uncertainty (W/K) and where it comes
    from ("prior", "stored", "learned")."""

    conductance: float
    sd: float
    source: str = "prior"

    @property
    def high(self) -> float:
        """K one sd high: the side that errs early when deciding to stop heating the mash."""
        return self.conductance + self.sd

    @property
    def low(self) -> float:
        """K one sd low (never below 0): the side that errs late when judging that no wort
        flows (`flow_watch.FlowWatch`)."""
        return max(0.0, self.conductance - self.sd)


def prior_estimate(conductance: float) -> CoilEstimate:
    """The prior K a config gives (W/K), with PRIOR_SD_SHARE of itself for its sd."""
    if not (math.isfinite(conductance) and 0.0 < conductance <= MAX_CONDUCTANCE):
        raise ValueError(
            f"coil conductance {conductance!r} W/K is invalid: must be > 0 and "
            f"≤ {MAX_CONDUCTANCE:g} W/K"
        )
    return CoilEstimate(conductance, PRIOR_SD_SHARE * conductance, "prior")


class CoilEstimator:
    """Learns K from the HLT's heat balance while the pump runs and the readings are good."""

    __slots__ = (
        "_arrived",
        "_block",
        "_blocks",
        "_capacity",
        "_flowing_s",
        "_h0",
        "_last",
        "_loss",
        "_offset_fade",
        "_offset_heat",
        "_offset_time",
        "_period",
        "_prior",
        "_room",
        "_run_s",
        "_since_full",
        "_stopped",
        "_watts",
        "_x",
        "_y",
    )

    def __init__(
        self,
        *,
        hlt_capacity: float,
        hlt_loss: float,
        room: float,
        element_watts: float,
        dead_time: float,
        period: float,
        prior: CoilEstimate,
    ) -> None:
        self._capacity = hlt_capacity  # J/K
        self._loss = hlt_loss  # W/K
        self._room = room
        self._watts = element_watts
        self._period = period
        self._prior = prior
        # The duties applied over the last dead time, the one reaching the water now first.
        self._arrived: deque[float] = deque(maxlen=max(0, round(dead_time / period)) + 1)
        self._blocks: list[tuple[float, float]] = []  # (K, weight) of each finished block
        self._block = LineFit()
        self._last: tuple[float, float] | None = None  # (T_h, T_m) of the last good period
        self._run_s = 0.0
        self._flowing_s = math.inf  # s since the wort was last known not to flow
        self._h0 = self._x = self._y = 0.0
        # The balance's error with the pump stopped (J, over s), forgotten over
        # OFFSET_MEMORY_S; the HLT's PV of the stopped period before and s since the stop.
        self._offset_heat = self._offset_time = 0.0
        self._offset_fade = math.exp(-period / OFFSET_MEMORY_S)
        self._stopped: tuple[float, float] | None = None
        self._since_full = 0.0  # s since the element was last at full power

    def period(
        self,
        *,
        hlt: float,
        mash: float | None,
        applied: float,
        pump: bool,
        stopped: bool = False,
    ) -> Exchange | None:
        """One period: the HLT's and the mash's PV (None: no good mash reading), the duty
        applied over the period just ended (% of the element) and whether the pump ran;
        `stopped`: the pump known to stand (switched off, or seen off: one run by hand unseen
        may not), when the balance measures the HLT model's own error. The period's exchange
        as the HLT's balance shows it (None while the pump is stopped, a reading failed or
        the coil still settles)."""
        self._arrived.append(applied)
        self._since_full = 0.0 if applied >= 100.0 else self._since_full + self._period
        self._learn_offset(hlt if stopped else None)
        if not pump or mash is None:
            self._interrupt()
            return None
        self._run_s += self._period
        if self._run_s < SETTLE_S:
            return None
        last, self._last = self._last, (hlt, mash)
        if last is None:
            self._h0, self._x, self._y = hlt, 0.0, 0.0
            self._block = LineFit()
            self._block.add(0.0, 0.0)
            return None
        ts = self._period
        h_mean = 0.5 * (last[0] + hlt)
        dx = ts * (h_mean - 0.5 * (last[1] + mash))
        self._x += dx
        dy = self._balance(h_mean) - self.offset * ts
        self._y += dy
        point = (self._x, self._capacity * (hlt - self._h0) + self._y)
        self._flowing_s += ts
        if self._flowing_s < SETTLE_S:  # no flow lately: nothing of K to learn yet
            self._block = LineFit()
        self._block.add(*point)
        if self._block.n * ts > BLOCK_S:
            self._close_block(point)
        return Exchange(dx, -(dy + self._capacity * (hlt - last[0])))

    def _balance(self, h_mean: float) -> float:
        """J the model says left the HLT over the period besides its own change: the losses
        at `h_mean` less the element's heat that arrived."""
        heat = self._watts * self._arrived[0] / 100.0 * self._period
        return self._loss * (h_mean - self._room) * self._period - heat

    def _learn_offset(self, hlt: float | None) -> None:
        """With the pump known stopped (`hlt` its PV; None: not), from SETTLE_S after the
        stop (the coil's standing wort takes the HLT's temperature, heat the balance does not
        count) and two dead times after full power (a heat-up's ramp and its end, where the
        rate's error and the dead time's would read as a loss: 50 s of the heat's way
        misjudged at the end of a heat-up is 250 kJ of a 5.5 kW element, 140 W over half an
        hour's hold): the heat the HLT gained beyond the model's balance, per second."""
        if hlt is None:
            self._stopped = None
            return
        last, self._stopped = (
            self._stopped,
            (hlt, 0.0 if self._stopped is None else self._stopped[1] + self._period),
        )
        dead = self._period * ((self._arrived.maxlen or 1) - 1)
        if last is None or last[1] < SETTLE_S or self._since_full < 2.0 * dead:
            return
        gained = self._capacity * (hlt - last[0]) + self._balance(0.5 * (hlt + last[0]))
        fade = self._offset_fade
        self._offset_heat = fade * self._offset_heat + gained
        self._offset_time = fade * self._offset_time + self._period

    def carry(self, before: CoilEstimator) -> None:
        """The HLT model's error as `before` (the estimator a reload replaces) measured it,
        where the model is the same (its heat capacity, losses, room and element): of
        another model it says nothing."""
        same = (self._capacity, self._loss, self._room, self._watts)
        if same == (before._capacity, before._loss, before._room, before._watts):
            self._offset_heat, self._offset_time = before._offset_heat, before._offset_time

    @property
    def offset(self) -> float:
        """W the HLT gains beyond its model's balance, as its stopped pump showed it (the
        room's or the losses' error, `_learn_offset`); 0 until OFFSET_LEAST_S of it."""
        if self._offset_time < OFFSET_LEAST_S:
            return 0.0
        return self._offset_heat / self._offset_time

    def no_flow(self) -> None:
        """The pump runs but no wort flows (`flow_watch.FlowWatch`): what the HLT showed
        meanwhile is no measure of K, so the open block is dropped, and learning waits
        SETTLE_S once the wort flows again (the coil then holds standing wort)."""
        self._flowing_s = 0.0

    def _interrupt(self) -> None:
        """The pump stopped or a reading failed: the open block is dropped, a new run starts."""
        self._run_s = 0.0
        self._last = None
        self._block = LineFit()

    def _close_block(self, point: tuple[float, float]) -> None:
        line = self._block
        slope = line.slope()
        spread = line.stt - line.st * line.st / line.n  # Σ(x − x̄)²
        if slope is not None and spread > 0.0:
            self._blocks.append((-slope, spread))
        # The next block starts where this one ended, with an intercept of its own.
        self._block = LineFit()
        self._block.add(*point)

    def flow_low(self, estimate: CoilEstimate) -> float:
        """K one sd low to judge whether wort flows by (`flow_watch.FlowWatch`), from the
        day's `estimate` (this period's): its low, and while fewer than MIN_BLOCKS are in, no
        more than the prior's low: one block across a step of the element's duty on a dead
        time the HLT's model misjudges reads K far high (417 W/K for 189 with a model's dead
        time twice the tun's: the heat sent ahead of a pump start landed before the model
        said), and judged by it a flowing coil looked like none."""
        low = estimate.low
        return low if len(self._blocks) >= MIN_BLOCKS else min(low, self._prior.low)

    def estimate(self) -> CoilEstimate:
        """The day's K once a block is in (see the module's docstring), else the prior."""
        blocks = self._blocks
        if not blocks:
            return self._prior
        total = math.fsum(w for _, w in blocks)
        mean = math.fsum(k * w for k, w in blocks) / total
        k = min(max(mean, 0.0), MAX_CONDUCTANCE)
        if len(blocks) < MIN_BLOCKS:
            return CoilEstimate(k, FEW_SD * k, "learned")
        scatter = math.fsum(w * (k - mean) ** 2 for k, w in blocks) / total
        sd = math.sqrt(scatter / (len(blocks) - 1))
        return CoilEstimate(k, max(sd, SD_FLOOR * k), "learned")
