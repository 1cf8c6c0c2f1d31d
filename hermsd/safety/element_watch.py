"""Whether each of two elements gives heat: a warning, not an alarm (docs/two-elements.md).

The supervisor judges the total power of both elements against limits that hold for any fill
from half to twice the configured litres. Where one element can hold the tun alone, the loop
holds on it when the other dies, and no limit of that width can tell. This watch compares
stretches of the day with two references measured the same day, so the fill cancels out:

- the full-power rate R (°C/s): the PV's rise with both elements fully on, the last measured
  before the hold at the setpoint in force (nearest the setpoint's losses);
- the hold's power u0 (a part of both elements' total): the mean asked while the PV held the
  setpoint for `HOLD_S`, less what its drift took: the tun's losses there (until then, a
  shorter steady span near it: `STEADY_HOLD_S`).

G = R/(1 − u0) is the rise per unit of total power, and a window that asked u and rose at r
delivered u0 + r/G. R was measured a little below the setpoint, where the losses are a
little less, so G reads high by as much (some 2 % a degree below 66 °C in a 20 °C room):
heat delivered while rising reads a little low. An element whose own part c of u is missing
(and not the other's part: `MISSING`·c ≤ u − delivered ≤ c/`MISSING`) through a window, in
each way of aligning the power with the PV (`WINDOWS`), for the window's confirm time is
reported; it is cleared once a window shows no more than `RESTORED`·c missing.

A heat-up's ramp with both full, which no hold has measured yet, is judged on its own: a
slope that drops at once by an element's part of the heat-up fit's rate, beyond the ramp's
own slowing, names it (`_stall`).

Once the controller has fitted the day's heat-up (`heat_up`), the windows are aligned by the
dead time it measured rather than the configured one (a 350 s tun judged on 115 s blames
power that has not reached the sensor yet, and a recovery's heat still arriving looks like
more than was asked). A fast tun behind a long dead time crosses the approach band before a
spell of full power shows there: G is then that fit's rate (both elements' full power before
the losses take their share, good to 1–3 %).

Pure, fed once a control period with time as an argument; its state is made of what the
period records log, so `hermsd replay --verify` derives the same reports from a log.
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass

from hermsd.safety.heat_balance import pv_slope
from hermsd.safety.limits import MODEL_MARGIN

SPELL_S = 120.0
"""s of PV judged at a time: the means of 3 periods' PV at its ends (each period's of 5
reads: sd 0.016 °C with 0.03 °C noise and the LM92's steps) differ by sd 0.013 °C, 1.1e-4
°C/s over it: 2 % of the full-power rate of 5.5 kW into 150 L, the slowest in the benches."""
HOLD_S = 600.0
"""s the PV must stay within `HOLD_BAND` of the setpoint for the hold's power to be taken:
the mean of 120 periods' power, its drift taken off, so that an element dying in the hold's
first 20 minutes is judged too (bench/population.py's tun 62 died 700 s into its hold)."""
HOLD_BAND = 0.3
"""°C: the hold's band for its reference (0.5 let a law that swings, PIDHerms on population
tuns 31 and 178, give a reference that named a working element)."""
HOLD_DRIFT = 0.1
"""°C: the most the PV may drift over that hold (its mean at either end) …"""
HOLD_DRIFT_SHARE = 0.02
"""… or, once a full-power rate is measured, a drift at this part of it: the drift's heat is
taken off by that rate, whose 3 % error leaves 0.06 % of the total, and a fast tun's slow
creep into its hold is still one (tun 108: 0.3 °C in 20 min at 0.1 °C/s)."""
APPROACH_BAND = (10.0, 0.5)
"""°C below the setpoint: the full-power rate is taken where the PV lies between these, near
the losses of the setpoint and clear of the approach's cut-back."""
SUDDEN_FALL = 0.25
"""°C within `SUDDEN_SPAN`: faster than any loss, water was added; no spell spans it."""
SUDDEN_SPAN = 30.0
SETTLE_S = 300.0
"""s after such a fall and the dead time before a window's PV may start: the sensor's lag (a
thermowell's, up to 150 s) still bends its rise for two lags and more."""
DEAD_TIME_FACTORS = (0.5, 1.0, 2.0)
"""Each spell is judged with its power taken these times the dead time earlier: an element
is blamed only when all agree (a misjudged dead time makes power that changed near the
window's ends look missing at one of them, not at all). The config's dead time may be half
or twice the tun's (a far sensor's 240 s against the default 115 s)."""
FIT_DEAD_TIME_ERROR_S = 30.0
"""s: the heat-up fit's dead time lies within −23/+28 s of the tun's delay and lag
(bench/RESULTS.md, "Heat-up fit"). Once the day's heat-up has measured it (`heat_up`), the
spells are judged at it and at the dead times `MODEL_MARGIN` or this from it, whichever lies
farther (`_dead_times`): the verdict waits half a dead time less than at twice it."""
LEAST_SHARE = 0.1
"""An element giving less than this part of the total in a spell is not judged in it."""
CYCLES_S = 900.0
"""s: a longer window judged whatever the second element did in it (a hold that cycles it
at its minimum times never leaves it in one state for a spell)."""
LEAST_PART = 0.05
"""… where an element's part is judged from this (its missing heat is then still 6× the
noise's 1.5e-5 °C/s over the window on the slowest tun)."""
CYCLES_CONFIRM_S = CYCLES_S / 2.0
"""s such a window's finding must last: one that spans an element's death sees half its heat
missing, as much as the other's part may be, and blames the wrong one until it moves on."""
MISSING = 0.6
"""Missing heat, as a part of an element's own, that reports it (a dead one: 1)."""
STEADY_HOLD_S = 300.0
"""s of a PV steady near the setpoint whose power serves as the hold's until a hold within
`HOLD_BAND` of it comes: two of the slowest sensor's lags (150 s)."""
STEADY_POWER_SPREAD = MISSING * LEAST_SHARE
"""The most the means of that span's power, over its window and the half span before in
three parts, may differ (a part of the total): a power that ramps by as much errs the
window's mean by a third of it, under half the least missing heat reported. A law that swings
is no hold where it stands still a moment: PIDHerms gave population tun 4 a reference from
halves of 0.23 and 0.59, and on tun 99 a burst's heat held the PV still for 9 minutes at a
mean of 2 % (a hold of 3.6 % where the tun loses several times that, and element 2 named).
A landing whose bias learns its missing heat ramps by 0.03–0.04 (tun 62)."""
STEADY_HOLD_BAND = 1.0
"""°C from the setpoint within which that steady PV must stand: a landing stalled short of
the band (understated losses) holds all the same."""
SURPLUS = 0.15
"""Heat delivered beyond what was asked, as a part of the total, that says the references
were measured without an element's heat (a normal day's windows stay within 0.06)."""
RESTORED = 0.3
"""Missing heat, as a part of its own, below which a reported element is cleared."""
CONFIRM_S = 60.0
"""s a finding must last before it is reported or cleared."""
WINDOWS = (
    (SPELL_S, True, LEAST_SHARE, CONFIRM_S, True),
    (CYCLES_S, False, LEAST_PART, CYCLES_CONFIRM_S, False),
)
"""(s judged, the second element steady in it, the least part judged, s to confirm, whether
dead times either side of the dead time are tried too, `_dead_times`): a long window's ends
weigh little, and the ripple of a cycling hold at its ends would make the dead times
disagree by more than misjudging them does."""
PV_MEAN_PERIODS = 3
"""Periods whose PV are averaged at either end of a spell (noise: sd/√3)."""
STALL_S = 300.0
"""s of PV in each of the three windows a heat-up's stall is judged on, each slope fitted
by least squares (0.03 °C of noise on 60 periods: a standard error of 4.5e-5 °C/s, 0.6 % of
1.4 kW into 42 L's rise per unit of power), a dead time apart."""
STALL_SE = 4.0
"""Standard errors of the slopes' difference a stall's drop must clear beyond the bend."""
STALL_BEND = 2.0
"""Times the ramp's own slowing between the first two windows that the last may slow by
with both elements working (the losses grow with the water: evaporation faster near 66 °C)."""


EITHER = 0
"""Reported for the element when heat is missing that either one's could be."""
UNASKED = 3
"""Reported when more heat came than was asked (`SURPLUS`)."""


def named_dead(no_heat: Iterable[int]) -> frozenset[int]:
    """The elements themselves (1, 2) among reports `no_heat`: not EITHER, not UNASKED."""
    return frozenset(e for e in no_heat if e in (1, 2))


def no_heat_words(element: int) -> str:
    """The words of a report on `element` (1, 2, EITHER or UNASKED), as the status shows."""
    if element == UNASKED:
        return "more heat than asked?"
    which = "element 1 or 2" if element == EITHER else f"element {element}"
    return f"{which} gives no heat?"


def report_kind(element: int) -> str:
    """The alert's kind for a report on `element`."""
    return {EITHER: "element1or2", UNASKED: "heat_unasked"}.get(element, f"element{element}")


@dataclass(frozen=True, slots=True)
class ElementReport:
    """A finding on one element (1: the SSR's, 2: the second; EITHER; UNASKED), raised or
    cleared."""

    element: int
    t: float
    raised: bool
    message: str


@dataclass(frozen=True, slots=True)
class _Sample:
    t: float
    pv: float
    duty1: float  # the SSR element's duty in the period before, 0..1
    on2: bool  # the second element was on all through the period before


class ElementWatch:
    """Reports an element of two that gives no heat, from the loop's own spells."""

    def __init__(self, watts1: float, watts2: float, dead_time: float, coil: bool = False) -> None:
        if not (watts1 > 0.0 and watts2 > 0.0 and dead_time >= 0.0):
            raise ValueError(f"watts must be > 0, dead time ≥ 0: {watts1}, {watts2}, {dead_time}")
        self.share1 = watts1 / (watts1 + watts2)
        self.share2 = watts2 / (watts1 + watts2)
        self.dead_time = dead_time
        self.coil = coil  # a HERMS coil in the HLT (a mash sensor fitted) may draw its heat
        self.full_rate: float | None = None  # °C/s with both fully on
        self.fit_rate: float | None = None  # °C/s with both fully on, before the losses
        self.hold_power: float | None = None  # the hold's mean total, 0..1
        self.setpoint: float | None = None
        self.suspect: set[int] = set()  # the elements reported and not cleared
        self.doubtful = False  # heat beyond what was asked: the references lack an element
        self.hold_cycled = False  # the second element was on in the hold's reference
        self.hold_steady = False  # hold_power is a steady span's, till a hold measures it
        self.probed: int | None = None  # the element the heat-up's probe found dead
        self._samples: deque[_Sample] = deque()
        self._since: dict[tuple[int, bool, float], float] = {}  # a finding → first seen
        self._fell_at: float | None = None  # when the PV last fell faster than losses can

    def period(
        self,
        t: float,
        pv: float | None,
        setpoint: float,
        duty1: float,
        duty2: float,
        controlled: bool = True,
        pump: bool | None = None,
    ) -> list[ElementReport]:
        """One control period: the PV, the setpoint, each element's duty (%) as switched in
        the period before, whether the controller drives them (no alarm, no manual, no
        program waiting) and the HERMS pump as known (None: not known). Returns what was
        reported or cleared now. While a coil's pump may run, nothing is judged: its load on
        the HLT would read as an element's missing heat."""
        said: list[ElementReport] = []
        if setpoint != self.setpoint:
            self.setpoint, self.hold_power = setpoint, None  # losses differ at another one
            self.doubtful = False
            if UNASKED in self.suspect:  # judged again, on the new references
                self.suspect.discard(UNASKED)
                said.append(
                    ElementReport(
                        UNASKED, t, False, "heat as asked is judged again, at the new setpoint"
                    )
                )
        if self.coil and pump is not False:
            controlled = False
        if pv is None or not math.isfinite(pv) or not controlled:
            self._samples.clear()  # no window spans an alarm's heater off, or a manual spell
            self._since.clear()
            return said
        samples = self._samples
        samples.append(_Sample(t, pv, duty1 / 100.0, duty2 >= 100.0))
        keep = max(HOLD_S, CYCLES_S, 3.0 * STALL_S) + 3.0 * self.dead_time + SUDDEN_SPAN
        while t - samples[0].t > keep:
            samples.popleft()
        # Faster than any loss: the hold's own (a lid-off tun with no heat falls 0.15 °C in
        # SUDDEN_SPAN, which noise can take past SUDDEN_FALL alone) and SUDDEN_FALL beyond.
        gain, hold = self._gain(), self.hold_power
        losses = 0.0 if gain is None or hold is None else max(0.0, hold * gain)
        fell = max(s.pv for s in samples if s.t >= t - SUDDEN_SPAN) - pv
        if fell >= SUDDEN_FALL + losses * SUDDEN_SPAN:
            self._fell_at = t
        if duty2 > 0.0 and duty2 < 100.0:
            self._since.clear()
            return said  # the second element switched within the period: no spell spans it
        self._take_references(t, setpoint)
        return said + self._judge(t)

    def heat_up(self, rate: float, dead_time: float) -> None:
        """The day's heat-up as the controller fitted it: its `rate` (°C/s at 100 % of both
        elements, before the losses) and `dead_time` (s), taken before the period's step so
        that `hermsd replay --verify` hands in the same."""
        self.fit_rate, self.dead_time = rate, dead_time

    def _dead_times(self) -> tuple[float, float, float]:
        """The dead times a spell is judged at: `DEAD_TIME_FACTORS` of the configured one, or
        around the heat-up's measured one (`FIT_DEAD_TIME_ERROR_S`)."""
        theta = self.dead_time
        if self.fit_rate is None:
            low, mid, high = DEAD_TIME_FACTORS
            return low * theta, mid * theta, high * theta
        error = FIT_DEAD_TIME_ERROR_S
        return (
            max(0.0, min(theta / MODEL_MARGIN, theta - error)),
            theta,
            max(theta * MODEL_MARGIN, theta + error),
        )

    def blame(self, t: float, element: int, message: str) -> ElementReport:
        """An element the heat-up's probe found dead (hermsd/safety/element_probe.py): reported,
        and held, for the references were measured without its heat and cannot clear it."""
        self.suspect.add(element)
        self.probed = element
        return ElementReport(element, t, True, message)

    def keep_probed(self, before: ElementWatch) -> None:
        """Hold what the heat-up's probe found for `before`, the watch of the same tun
        before a reload (hermsd.runtime.daemon.keep_probe): the probe is not tried again."""
        if before.probed is not None:
            self.suspect.add(before.probed)
            self.probed = before.probed

    def _take_references(self, t: float, setpoint: float) -> None:
        samples = self._samples
        if self.hold_power is None:  # the full-power rate nearest the setpoint, before it
            low, high = setpoint - APPROACH_BAND[0], setpoint - APPROACH_BAND[1]
            latest = max(self._dead_times())
            spell = self._spell(t, SPELL_S, True, latest)
            if spell is not None and low <= samples[-1].pv <= high:
                reach = SPELL_S + latest
                full = all(self._total(s) >= 1.0 - 1e-9 for s in samples if s.t > t - reach)
                if full and spell[1] > 0.0:
                    self.full_rate = spell[1]
        if self.hold_power is None or (self.hold_steady and not self.suspect):
            self._hold_reference(t, setpoint, HOLD_S)
        if self.hold_power is None:
            self._hold_reference(t, setpoint, STEADY_HOLD_S)

    def _hold_reference(self, t: float, setpoint: float, span: float) -> None:
        """The hold's power u0 over the last `span` s, its power's window a dead time before
        it, the PV's drift taken off. Over HOLD_S the PV must stand within HOLD_BAND of the
        setpoint from before that window; until such a hold comes, a STEADY_HOLD_S span that
        is `_steady` serves (`hold_steady`): a landing on understated losses can sit half a
        degree short longer than an element may die unseen (population tun 62: 15
        minutes)."""
        samples = self._samples
        steady = span != HOLD_S
        if t - samples[0].t < span + self.dead_time + (span / 2.0 if steady else 0.0):
            return
        # From before its power's window too: the approach's last power, which a dead time
        # longer than the tun's would count, is not the hold's.
        settled = [s for s in samples if s.t >= t - span - self.dead_time]
        if steady:
            if not self._steady(t, setpoint, settled, span):
                return
        elif any(abs(s.pv - setpoint) > HOLD_BAND for s in settled):
            return
        held = [s for s in samples if s.t >= t - span]
        drift = _mean_pv(held[-PV_MEAN_PERIODS:]) - _mean_pv(held[:PV_MEAN_PERIODS])
        powered = [s for s in samples if t - span - self.dead_time < s.t <= t - self.dead_time]
        seconds = _mean_t(held[-PV_MEAN_PERIODS:]) - _mean_t(held[:PV_MEAN_PERIODS])
        rate = self.full_rate if self.full_rate is not None else self.fit_rate
        most = HOLD_DRIFT if rate is None else HOLD_DRIFT_SHARE * rate * seconds
        if abs(drift) > max(most, HOLD_DRIFT) or not powered:
            return
        mean = sum(self._total(s) for s in powered) / len(powered)
        self.hold_power, self.hold_steady = mean, steady
        self.hold_cycled = any(b.on2 and not a.on2 for a, b in itertools.pairwise(powered))
        if self.full_rate is not None:  # less what the drift took, by G = R/(1 − u0)
            part = drift / seconds / self.full_rate
            self.hold_power = (mean - part) / (1.0 - part)
        elif self.fit_rate is not None:  # … or by the heat-up's G
            self.hold_power = mean - drift / seconds / self.fit_rate

    def _steady(self, t: float, setpoint: float, settled: list[_Sample], span: float) -> bool:
        """Whether a `span` is a hold though short of HOLD_S and of the band: its PV, from
        before its power's window (`settled`), moved by at most HOLD_BAND within
        STEADY_HOLD_BAND of the setpoint, with no full power, and the power over its window
        and the half span before it, in three parts, had means within STEADY_POWER_SPREAD:
        the heat arriving is the power's own, none stored from a swing's top."""
        pvs = [s.pv for s in settled]
        if max(pvs) - min(pvs) > HOLD_BAND or max(abs(pv - setpoint) for pv in pvs) > (
            STEADY_HOLD_BAND
        ):
            return False
        end, part = t - self.dead_time, span / 2.0
        parts = [
            [self._total(s) for s in self._samples if end - (k + 1) * part < s.t <= end - k * part]
            for k in range(3)
        ]
        if any(not powers or max(powers) >= 1.0 - 1e-9 for powers in parts):
            return False
        if any(self._total(s) >= 1.0 - 1e-9 for s in settled):
            return False
        means = [sum(powers) / len(powers) for powers in parts]
        return max(means) - min(means) <= STEADY_POWER_SPREAD

    def _gain(self) -> float | None:
        """G, the rise per unit of both elements' power (°C/s): from the full-power rate and
        the hold's power, else the heat-up fit's; None before either is known."""
        if self.hold_power is None or self.hold_power >= 1.0:
            return None
        if self.full_rate is not None:
            return self.full_rate / (1.0 - self.hold_power)
        return self.fit_rate

    def _spell(
        self, t: float, span: float, steady: bool, dead: float
    ) -> tuple[float, float, dict[int, float]] | None:
        """(mean total power, PV rate, each element's part of the total) of the `span` s
        judged now, its power from `span` + `dead` s ago; none within `SETTLE_S` of water
        added, and with `steady` the second element in one state all through."""
        samples = self._samples
        start = t - span - dead
        if samples[0].t > start - 1e-9:
            return None
        if self._fell_at is not None and self._fell_at > t - span - self.dead_time - SETTLE_S:
            return None
        spell = [s for s in samples if s.t > start]
        if steady and any(s.on2 != spell[-1].on2 for s in spell):
            return None
        powered = [s for s in spell if s.t <= t - dead]
        if not powered:
            return None
        if not steady and any(
            self._total(s) >= 1.0 - 1e-9
            for s in powered
            if min(s.t - powered[0].t, powered[-1].t - s.t) < self.dead_time
        ):
            # Both full within a dead time of an end (a heat-up's or a recovery's): whether its
            # heat shows in the window depends on θ. Pulses of both inside it show within it
            # (a hold the SSR cannot make alone, the SSR's element dead: population tun 95).
            return None
        first = [s for s in spell if s.t >= t - span][:PV_MEAN_PERIODS]
        last = spell[-PV_MEAN_PERIODS:]
        seconds = _mean_t(last) - _mean_t(first)
        if seconds < span / 2:
            return None
        n = len(powered)
        parts = {
            1: self.share1 * sum(s.duty1 for s in powered) / n,
            2: self.share2 * sum(s.on2 for s in powered) / n,
        }
        rate = (_mean_pv(last) - _mean_pv(first)) / seconds
        return parts[1] + parts[2], rate, parts

    def _stall(self, t: float) -> list[ElementReport]:
        """A heat-up's ramp that slowed at once by an element's part (no hold needed): both
        full through three windows a dead time apart and the dead time before them, the
        last's slope below the middle's by more than `STALL_BEND` times the ramp's slowing
        from the first to the middle and the noise allow, that drop as a part of the total by
        the heat-up fit's rate (both elements' before the losses)."""
        gain, theta, samples = self.fit_rate, self.dead_time, self._samples
        reach = 3.0 * STALL_S + 3.0 * theta
        if self.probed is not None or self.suspect or self.doubtful or gain is None:
            return []
        if self._total(samples[-1]) < 1.0 - 1e-9:
            return []  # not at full now: the common case, before the reach is scanned
        if samples[0].t > t - reach + 1e-9 or (
            self._fell_at is not None and self._fell_at > t - reach - SETTLE_S
        ):
            return []
        if any(self._total(s) < 1.0 - 1e-9 for s in samples if s.t > t - reach):
            return []
        ends = (t - 2.0 * (STALL_S + theta), t - STALL_S - theta, t)
        windows = [[s for s in samples if end - STALL_S < s.t <= end] for end in ends]
        first, middle, last = (pv_slope([(s.t, s.pv) for s in window]) for window in windows)
        if first is None or middle is None or last is None:
            return []
        bend = max(first.rate - middle.rate, 0.0)
        noise = STALL_SE * math.sqrt(
            middle.error**2 + last.error**2 + STALL_BEND**2 * (first.error**2 + middle.error**2)
        )
        drop = middle.rate - last.rate
        missing = (drop - STALL_BEND * bend - noise) / gain
        parts = {1: self.share1, 2: self.share2}
        blamed = [e for e, c in parts.items() if MISSING * c <= missing <= c / MISSING]
        element = blamed[0] if len(blamed) == 1 else EITHER if blamed else None
        for each in (1, 2, EITHER):
            if each != element:
                self._since.pop((each, True, STALL_S), None)
        if element is None:
            return []
        if t - self._since.setdefault((element, True, STALL_S), t) < CONFIRM_S:
            return []
        self._since.clear()
        self.suspect.add(element)
        message = (
            f"{no_heat_words(element)} the heat-up's rise slowed at once by "
            f"{100.0 * drop / gain:.0f} % of both elements' power with both full "
            "(against the heat-up fit's rate), or the tun began to lose that much more (a lid "
            "off?)"
        )
        return [ElementReport(element, t, True, message)]

    def _judge(self, t: float) -> list[ElementReport]:
        stalled = self._stall(t)
        gain, hold = self._gain(), self.hold_power
        if stalled or self.probed is not None or gain is None or hold is None:
            return stalled
        for span, steady, least, confirm, bracketed in WINDOWS:
            if steady and self.hold_cycled:
                # A hold that switched the second element on is judged by the long window
                # alone: had it given nothing all day, the hold cycled it for nothing and
                # u0 took its nominal heat for the tun's losses, and a short window with it
                # on throughout would blame the first element for its missing heat.
                continue
            # Judged at each dead time the tun's may be: power that changed near the
            # window's ends shows at the sensor sooner or later than `dead_time` says.
            dead_times = self._dead_times() if bracketed else (self.dead_time,)
            seen = [self._spell(t, span, steady, theta) for theta in dead_times]
            spells = [spell for spell in seen if spell is not None]
            if len(spells) < len(seen):
                continue
            blamed: set[int | None] = set()
            restored: set[int] = set()
            surplus = True
            for power, rate, parts in spells:
                missing = power - (hold + rate / gain)
                surplus = surplus and missing <= -SURPLUS
                judged = {e: c for e, c in parts.items() if c >= least}
                # A dead element's missing heat is its own part: blamed when it fits that,
                # or either of the two when both do.
                fits = [e for e, c in judged.items() if MISSING * c <= missing <= c / MISSING]
                blamed.add(fits[0] if len(fits) == 1 else EITHER if fits else None)
                restored |= {e for e, c in judged.items() if missing <= RESTORED * c}
                if len(restored) == 2:
                    restored.add(EITHER)
            power, rate, parts = spells[dead_times.index(self.dead_time)]
            missing = power - (hold + rate / gain)
            parts[EITHER] = min((c for c in parts.values() if c >= least), default=0.0)
            if self.doubtful:
                continue  # the references are not of both elements: nothing is judged by them
            key = (UNASKED, True, span)
            if not surplus:
                self._since.pop(key, None)
            elif t - self._since.setdefault(key, t) >= confirm:
                self._since.clear()
                self.doubtful = True
                return [self._report(t, UNASKED, True, missing, parts[EITHER])]
            for element, part in parts.items():
                raising = element not in self.suspect
                # One element at a time: both dead is the supervisor's (neither holds the
                # tun: the water falls at full power).
                finding = (
                    blamed == {element} and not self.suspect if raising else element in restored
                )
                key = (element, raising, span)
                if not finding:
                    self._since.pop(key, None)
                elif t - self._since.setdefault(key, t) >= confirm:
                    self._since.clear()
                    return [self._report(t, element, raising, missing, part)]
        return []

    def _report(
        self, t: float, element: int, raising: bool, missing: float, part: float
    ) -> ElementReport:
        share = 100.0 * part
        if element == UNASKED:
            self.suspect.add(element)
            message = (
                f"{no_heat_words(element)} {-100.0 * missing:.0f} % of both elements' power "
                "more than asked, against this day's full-power rise and hold: an element on "
                "unasked (a relay or SSR shorted?), or one gave none when they were measured "
                "(dead since the heat-up?), or the tun loses that much less (a lid put on?)"
            )
        elif raising:
            self.suspect.add(element)
            message = (
                f"{no_heat_words(element)} {100.0 * missing:.0f} % of both elements' "
                f"power missing with it on for {share:.0f} % (against this day's full-power "
                "rise and hold), or the tun loses that much more than in the hold (a lid off?)"
            )
        else:
            self.suspect.discard(element)
            which = "elements 1 and 2 heat" if element == EITHER else f"element {element} heats"
            message = (
                f"{which} again ({100.0 * missing:.0f} % of both elements' "
                f"power missing with it on for {share:.0f} %)"
            )
        return ElementReport(element, t, raising, message)

    def _total(self, sample: _Sample) -> float:
        return self.share1 * sample.duty1 + (self.share2 if sample.on2 else 0.0)


def _mean_pv(samples: list[_Sample]) -> float:
    return sum(s.pv for s in samples) / len(samples)


def _mean_t(samples: list[_Sample]) -> float:
    return sum(s.t for s in samples) / len(samples)
