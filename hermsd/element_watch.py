"""Whether each of two elements gives heat: a warning, not an alarm (docs/two-elements.md).

The supervisor judges the total power of both elements against limits that hold for any fill
from half to twice the configured litres. Where one element can hold the tun alone, the loop
holds on it when the other dies, and no limit of that width can tell. This watch compares
the loop's own spells with two references measured the same day, so the fill cancels out:

- the full-power rate R (°C/s): the PV's rise with both elements fully on (a heat-up or a
  recovery), the first measured at the setpoint in force;
- the hold's power u0 (a fraction of both elements' total): the mean asked while the PV held
  the setpoint for `HOLD_S`: the tun's losses there, in the elements' own units.

With G = R/(1 − u0) the rise rate per unit of total power (the losses at the heat-up's
temperature taken as at the setpoint's: they are less, so G is read low and a working
element looks stronger, not weaker), a spell of `SPELL_S` with the second element's state
steady, judged one dead time `dead_time` after the power it saw, delivered u0 + r/G of the
total where u was asked (r its rate). An element switched on for a part c of the total whose
heat is missing (u − delivered ≥ `MISSING` · c) for `CONFIRM_S` is reported; it is cleared
once a spell shows it giving at least (1 − `RESTORED`) of it again.

Pure, fed once a control period with time as an argument, its state made of what the
period records log, so `hermsd replay` derives the same reports from a log.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

SPELL_S = 120.0
"""s of PV judged at a time: 2 LSB of noise (0.125 °C) over it is 1e-3 °C/s, some 10 % of the
full-power rate of a 5.5 kW tun of 150 L (its slowest in the benches)."""
HOLD_S = 1200.0
"""s the PV must stay within `HOLD_BAND` of the setpoint for the hold's power to be taken."""
HOLD_BAND = 0.3
"""°C: the hold's band for its reference."""
HOLD_DRIFT = 0.1
"""°C: the most the PV may drift over that hold (its mean at either end)."""
APPROACH_BAND = (10.0, 0.5)
"""°C below the setpoint: the full-power rate is taken where the PV lies between these, near
the losses of the setpoint and clear of the approach's cut-back."""
SUDDEN_FALL = 0.25
"""°C within `SUDDEN_SPAN`: faster than any loss, water was added; no spell spans it."""
SUDDEN_SPAN = 30.0
LEAST_SHARE = 0.2
"""An element giving less than this part of the total in a spell is not judged in it."""
CYCLES_S = 900.0
"""s: a longer window judged whatever the second element did in it (a hold that cycles it
at its minimum times never leaves it in one state for a spell)."""
LEAST_PART = 0.05
"""… where an element's part is judged from this (its missing heat is then still 6× the
noise's 1.5e-5 °C/s over the window on the slowest tun)."""
MISSING = 0.6
"""Missing heat, as a part of an element's own, that reports it (a dead one: 1)."""
RESTORED = 0.3
"""Missing heat, as a part of its own, below which a reported element is cleared."""
CONFIRM_S = 60.0
"""s a finding must last before it is reported or cleared."""
PV_MEAN_PERIODS = 3
"""Periods whose PV are averaged at either end of a spell (noise: sd/√3)."""


@dataclass(frozen=True, slots=True)
class ElementReport:
    """A finding on one element (1: the SSR's, 2: the second), raised or cleared."""

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

    def __init__(self, watts1: float, watts2: float, dead_time: float) -> None:
        if not (watts1 > 0.0 and watts2 > 0.0 and dead_time >= 0.0):
            raise ValueError(f"watts must be > 0, dead time ≥ 0: {watts1}, {watts2}, {dead_time}")
        self.share1 = watts1 / (watts1 + watts2)
        self.share2 = watts2 / (watts1 + watts2)
        self.dead_time = dead_time
        self.full_rate: float | None = None  # °C/s with both fully on
        self.hold_power: float | None = None  # the hold's mean total, 0..1
        self.setpoint: float | None = None
        self.suspect: set[int] = set()  # the elements reported and not cleared
        self._samples: deque[_Sample] = deque()
        self._since: dict[tuple[int, bool], float] = {}  # (element, raise?) → first seen

    def period(
        self, t: float, pv: float | None, setpoint: float, duty1: float, duty2: float
    ) -> list[ElementReport]:
        """One control period: the PV, the setpoint, and each element's duty (%) as switched
        in the period before. Returns what was reported or cleared now."""
        if setpoint != self.setpoint:
            self.setpoint, self.hold_power = setpoint, None  # losses differ at another one
        if pv is None or not math.isfinite(pv):
            self._samples.clear()
            return []
        samples = self._samples
        samples.append(_Sample(t, pv, duty1 / 100.0, duty2 >= 100.0))
        keep = max(HOLD_S, CYCLES_S) + self.dead_time + SUDDEN_SPAN
        while t - samples[0].t > keep:
            samples.popleft()
        if duty2 > 0.0 and duty2 < 100.0:
            self._since.clear()
            return []  # the second element switched within the period: no spell spans it
        self._take_references(t, setpoint)
        return self._judge(t)

    def _take_references(self, t: float, setpoint: float) -> None:
        samples = self._samples
        if self.full_rate is None:
            low, high = setpoint - APPROACH_BAND[0], setpoint - APPROACH_BAND[1]
            spell = self._spell(t)
            if spell is not None and low <= samples[-1].pv <= high:
                power, rate, _ = spell
                if power >= 1.0 - 1e-9 and rate > 0.0:
                    self.full_rate = rate
        if self.hold_power is None and t - samples[0].t >= HOLD_S + self.dead_time:
            held = [s for s in samples if s.t >= t - HOLD_S]
            if all(abs(s.pv - setpoint) <= HOLD_BAND for s in held):
                drift = _mean_pv(held[-PV_MEAN_PERIODS:]) - _mean_pv(held[:PV_MEAN_PERIODS])
                powered = [
                    s for s in samples if t - HOLD_S - self.dead_time < s.t <= t - self.dead_time
                ]
                if abs(drift) <= HOLD_DRIFT and powered:
                    self.hold_power = sum(self._total(s) for s in powered) / len(powered)

    def _spell(
        self, t: float, span: float = SPELL_S, steady: bool = True
    ) -> tuple[float, float, dict[int, float]] | None:
        """(mean total power, PV rate, each element's part of the total) of the `span` s
        judged now, its power from `span` + the dead time ago; no water added in it, and
        with `steady` the second element in one state all through."""
        samples = self._samples
        start = t - span - self.dead_time
        if samples[0].t > start - 1e-9:
            return None
        spell = [s for s in samples if s.t > start]
        if steady and any(s.on2 != spell[-1].on2 for s in spell):
            return None
        powered = [s for s in spell if s.t <= t - self.dead_time]
        seen = [s for s in samples if s.t >= start - SUDDEN_SPAN]
        if not powered or _fell_suddenly(seen):
            return None
        if not steady and any(self._total(s) >= 1.0 - 1e-9 for s in powered):
            return None  # a heat-up or recovery's end: where its heat shows depends on θ
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

    def _judge(self, t: float) -> list[ElementReport]:
        if self.full_rate is None or self.hold_power is None or self.hold_power >= 1.0:
            return []
        gain = self.full_rate / (1.0 - self.hold_power)
        findings: dict[int, list[tuple[bool, bool, float, float]]] = {}
        for span, steady, least in ((SPELL_S, True, LEAST_SHARE), (CYCLES_S, False, LEAST_PART)):
            spell = self._spell(t, span, steady)
            if spell is None:
                continue
            power, rate, parts = spell
            missing = power - (self.hold_power + rate / gain)
            judged = {e: c for e, c in parts.items() if c >= least}
            # Heat missing with both on: the element whose own heat is nearest it.
            culprit = min(judged, key=lambda e: abs(judged[e] - missing), default=None)
            for element, part in judged.items():
                blamed = element == culprit and missing >= MISSING * part
                cleared = missing <= RESTORED * part
                findings.setdefault(element, []).append((blamed, cleared, missing, part))
        reports = []
        for element, found in sorted(findings.items()):
            bad = next((f for f in found if f[0]), None)
            good = next((f for f in found if f[1]), None) if bad is None else None
            shown = bad or good or found[0]
            reports += self._confirm(t, element, bad is not None, good is not None, *shown[2:])
        return reports

    def _confirm(
        self, t: float, element: int, bad: bool, good: bool, missing: float, part: float
    ) -> list[ElementReport]:
        raising = element not in self.suspect
        # One element at a time: a window that spans a death blames the other in part, and
        # both dead is the supervisor's (neither holds the tun: the water falls at full power).
        finding = (bad and not self.suspect) if raising else good
        key = (element, raising)
        if not finding:
            self._since.pop(key, None)
            return []
        first = self._since.setdefault(key, t)
        if t - first < CONFIRM_S:
            return []
        del self._since[key]
        share = 100.0 * part
        if raising:
            self.suspect.add(element)
            message = (
                f"element {element} gives no heat? {100.0 * missing:.0f} % of both elements' "
                f"power missing with it on for {share:.0f} % (against this day's full-power "
                "rise and hold), or the tun loses that much more than in the hold (a lid off?)"
            )
        else:
            self.suspect.discard(element)
            message = (
                f"element {element} heats again ({100.0 * missing:.0f} % of both elements' "
                f"power missing with it on for {share:.0f} %)"
            )
        return [ElementReport(element, t, raising, message)]

    def _total(self, sample: _Sample) -> float:
        return self.share1 * sample.duty1 + (self.share2 if sample.on2 else 0.0)


def _mean_pv(samples: list[_Sample]) -> float:
    return sum(s.pv for s in samples) / len(samples)


def _mean_t(samples: list[_Sample]) -> float:
    return sum(s.t for s in samples) / len(samples)


def _fell_suddenly(samples: list[_Sample]) -> bool:
    """Any fall of `SUDDEN_FALL` within `SUDDEN_SPAN` among `samples` (oldest first)."""
    window: deque[_Sample] = deque()
    for sample in samples:
        window.append(sample)
        while sample.t - window[0].t > SUDDEN_SPAN:
            window.popleft()
        if max(s.pv for s in window) - sample.pv >= SUDDEN_FALL:
            return True
    return False
