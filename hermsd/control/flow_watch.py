"""Whether wort flows through the HERMS coil while the pump runs: a stuck grain bed, a pump
running dry or a closed valve leave the pump on and nothing flowing, and the mash no longer
follows the coil (docs/mash-control.md, "No flow through the coil").

While the wort flows the coil passes K·(T_h − T_m) from the HLT's water to the mash, and
both tanks show it over a stretch of the pump's run:

    the HLT gives it:     ∫P·u(s − θ) ds − ∫UA_h·(T_h − T_room) ds − C_h·ΔT_h
    the mash takes it:    C_m·ΔT_m + ∫UA_m·(T_m − T_room) ds

both K·∫(T_h − T_m) ds (`coil.Exchange` is the HLT's side, period by period). With nothing
flowing both are zero. The sign is raised when both tanks show less than FLOW_SHARE of what
the coil would pass at K one sd low: one tank's model may be off (the mash's losses are a
low guess; the HLT's heat capacity is its law's model's, and its element's heat reaches the
sensor spread over its mixing and lag, not at one dead time), two are seldom off together.
It is cleared when the mash shows more: nothing but the coil heats a mash faster than its
losses cool it, while the HLT's side, its own heat moving as the element and the outer loop
move it, may show the coil's heat where none went. A stretch is judged only once it is long
against the delays between the coil and the mash's sensor (the hose, the sensor's lag; the
HLT's element reaches its water a dead time late, which its side counts, and the coil's pull
shows in the HLT's reading at once) and the heat the coil should have passed over it stands
JUDGE_SDS reading errors (READING_SD times the larger tank's heat capacity) clear of
FLOW_SHARE of it; the shortest such stretch back from now is judged, so the sign comes soon
in a climb (several degrees across the coil) and later in a hold (one or two). The sign is
symmetric: heat flowing back from a mash warmer than the HLT is flow.
"""

from __future__ import annotations

import math
from collections import deque

from hermsd.control.coil import Exchange

FLOW_SHARE = 0.5
"""Share of the coil's least expected heat below which a tank is taken to show none: the
midpoint of flowing (at least K one sd low) and standing (zero)."""
READING_SD = 0.0625
"""°C: the error of a change between two readings, a step of the LM92's resolution (its noise
beyond the step is below it)."""
JUDGE_SDS = 3.0
"""How many times the readings' error (in J, each tank's) the gap between the heat expected
and FLOW_SHARE of it must be before a stretch is judged."""
LAG_SHARE = 2.0
"""A judged stretch is at least this many times the delays between the coil and the mash's
sensor: the heat of its first moments still on its way to be seen is a small share."""
MAX_STRETCH_S = 1800.0
"""s: the longest stretch looked back over; one that does not show the coil's heat clearly
by then (the HLT and the mash level) gives no verdict, and the sign stands as it was."""


class FlowWatch:
    """The no-flow sign: fed each period while the pump runs (see the module's docstring)."""

    __slots__ = (
        "_capacities",
        "_last_mash",
        "_min_periods",
        "_period",
        "_seen",
        "_since_raised",
        "loss_before",
        "stuck",
    )

    def __init__(
        self,
        *,
        hlt_capacity: float,
        mash_capacity: float,
        delays: float,
        period: float,
    ) -> None:
        self._capacities = (hlt_capacity, mash_capacity)  # J/K
        self._period = period
        self._min_periods = max(2, math.ceil(LAG_SHARE * delays / period))
        # Each period's drive (K·s), the HLT's heat (J), the mash's heat gained as its rise
        # shows it (J), its integral above the room (K·s), and the mash's losses (W/K) in
        # force: the newest last.
        self._seen: deque[tuple[float, float, float, float, float]] = deque(
            maxlen=math.ceil(MAX_STRETCH_S / period)
        )
        self._last_mash: float | None = None
        self._since_raised = 0  # periods seen since the sign was raised
        self.stuck = False
        self.loss_before: float | None = None
        """The mash's losses (W/K) as they were before the stretch that raised the sign: what
        was learned of them since came of a mash that got no heat."""

    def period(
        self,
        exchange: Exchange | None,
        mash: float | None,
        *,
        pump: bool,
        mash_loss: float,
        room: float,
        k: float,
    ) -> bool:
        """One period: the coil's estimator's `exchange` (None: not measured: the pump
        stopped, a reading failed, the coil settling), the mash's reading, whether the pump
        runs, the mash's losses (W/K) to `room` (°C: the outer loop's, `Cascade.room`) and K
        one sd low (W/K). Returns whether the sign
        changed (`stuck` says to what). The pump stopped ends the sign."""
        last, self._last_mash = self._last_mash, mash
        if exchange is None or mash is None or last is None:
            self._seen.clear()
            return self._set(self.stuck and pump)
        above_room = (0.5 * (last + mash) - room) * self._period
        rise = self._capacities[1] * (mash - last)
        self._seen.append((exchange.drive, exchange.heat, rise, above_room, mash_loss))
        self._since_raised += 1
        verdict = self._verdict(k)
        return verdict is not None and self._set(verdict)

    def _verdict(self, k: float) -> bool | None:
        """The shortest judgeable stretch back from now: True when neither tank showed the
        coil's heat, False when the mash did, else (and when no stretch is judgeable) None:
        the sign stands as it is. The mash's losses are taken as they were
        at the stretch's start (a mash that gets no heat teaches the outer loop too high a
        loss, which would count as heat it took). A sign that stands is cleared only by a
        stretch wholly after it was raised: one reaching back to before holds the flow that
        was, and a reading's step one way or the other cleared and raised it in turn."""
        least_error = JUDGE_SDS * READING_SD * max(self._capacities) / (1.0 - FLOW_SHARE)
        drive = hlt = rise = above_room = 0.0
        for n, (dx, heat, risen, above, loss) in enumerate(reversed(self._seen), start=1):
            drive, hlt = drive + dx, hlt + heat
            rise, above_room = rise + risen, above_room + above
            expected = k * drive
            if n < self._min_periods or abs(expected) < least_error:
                continue
            share, mash = FLOW_SHARE * expected, rise + loss * above_room
            if hlt / share < 1.0 and mash / share < 1.0:
                self.loss_before = loss
                return True
            cleared = mash / share > 1.0 and not (self.stuck and n > self._since_raised)
            return False if cleared else None
        return None

    def _set(self, stuck: bool) -> bool:
        changed, self.stuck = stuck != self.stuck, stuck
        if changed and stuck:
            self._since_raised = 0
        return changed
