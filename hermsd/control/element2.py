"""The second element: a slow, wide-range heater on a relay or contactor, and the two ways the
load is shared between it and the SSR's element: the one-element controller on the total
power with the SSR making up what the second element's state leaves (`PowerSplit`,
`SplitController`: the default), or the mid-ranging controller (`control.algorithm:
midrange`, the rest of this docstring).

A contactor wears out by the operation (about 100k) and must not switch more than a few times
a minute, so the second element cannot be time-proportioned inside a window as the SSR is.
Its duty u2 (from the slow controller C2 of hermsd/control/midrange.py) is turned into whole control
periods on or off by a first-order sigma-delta modulator with minimum on and off times
(`OnOffModulator`): the energy owed (u2 requested minus delivered, in seconds of full power)
is accumulated, and each period the element is on when that brings the debt nearer zero,
unless it has not yet been on (or off) for its minimum. Why this rather than a fixed slow
PWM window or a hysteresis on u2:

- the mean delivered duty equals u2 (the debt stays within ±max(min_on, min_off) s), so C2
  sees a linear actuator on average and the fast loop only has the ripple to absorb;
- the shorter phase of each cycle lasts exactly its minimum, so the element switches as
  fast as allowed and no faster: every cycle is at least min_on + min_off long, which bounds
  the operations to 7200/(min_on + min_off) an hour whatever u2 does (30 at 2 min each);
- at u2 = 0 or 100 % it stays off or on with no edges at all (nothing is carried, as the
  SSR's planner does), where a fixed-period PWM would still have to decide per window.

C2 tracks what the element delivered on account (`applied2`): the u2 it asked for, less the
debt the modulator forgave (at 0 or 100 %, beyond its bound, at a forced off). The fraction
of each period the element was really on (`switched2`) would not do: it is 0 or 100 % by
design, and tracking it swings C2's integral by up to max(min_on, min_off)/Tt2 within every
cycle, which drives a limit cycle (seen on the simulated tun: ±1 °C every hour). The debt
still carried is bounded, so the two agree on average. The supervisor counts the heat
switched on (`switched2`), which is what warms the water.

Pure code with time as an argument, except `SlowElement`, which drives a `Switch`.
"""

from __future__ import annotations

import math

from hermsd.control import pid, predictive
from hermsd.control.midrange import MidRange
from hermsd.control.reach import FullPower
from hermsd.hardware.ssr import GuardedSwitch, SwitchedDuty
from hermsd.safety.element_probe import ElementProbe, ProbeResult

_EPS = 1e-9  # s: times that differ by rounding are equal


class OnOffModulator:
    """u2 (0–100 %) into on/off decisions, one per control period, within min on/off times.

    Each period first `account`s for the one before (the debt it left, and what was on
    account delivered; `decide` does it when the caller has not), then `decide`s the next
    from the new u2.
    """

    def __init__(self, min_on: float, min_off: float) -> None:
        if not (min_on > 0 and min_off > 0 and math.isfinite(min_on + min_off)):
            raise ValueError(f"min_on and min_off must be finite and > 0, got {min_on}, {min_off}")
        self.min_on = min_on
        self.min_off = min_off
        self.on = False
        self._since = -math.inf  # when the element last switched (or was forced off)
        self._owed = 0.0  # s of full power requested and not yet delivered
        self._dropped = 0.0  # s of full power owed and forgiven since the last account
        self._duty = 0.0  # the fraction requested for the period in progress
        self._last_t: float | None = None

    @property
    def owed(self) -> float:
        """Seconds of full power requested and not (yet) delivered; negative: delivered ahead."""
        return self._owed

    def account(self, t: float) -> float:
        """The duty (%) delivered on account since the last call: what was asked, less the
        debt forgiven (at 0 or 100 %, beyond the bound, at a forced off). The debt still
        carried is delivered later, so the mean of this is the mean delivered."""
        last, self._last_t = self._last_t, t
        if last is None or t <= last:
            self._dropped = 0.0
            return 0.0
        span = t - last
        self._owed += (self._duty - (1.0 if self.on else 0.0)) * span
        limit = max(self.min_on, self.min_off)
        self._forgive(self._owed - max(-limit, min(limit, self._owed)))
        dropped, self._dropped = self._dropped, 0.0
        return min(100.0, max(0.0, 100.0 * (self._duty - dropped / span)))

    def decide(self, t: float, duty: float) -> bool:
        """Whether the element is on for the period that starts at `t` with `duty` % asked."""
        if not 0.0 <= duty <= 100.0:
            raise ValueError(f"duty must be within 0..100 %, got {duty}")
        if self._last_t != t:
            self.account(t)  # the period before, if the caller has not accounted for it
        self._duty = duty / 100.0
        if duty <= 0.0 or duty >= 100.0:
            self._forgive(self._owed)  # fully off or on: nothing is carried
            want = duty >= 100.0
        else:
            want = self._owed > 0.0  # on if that brings the debt nearer zero than off would
        if want != self.on and self.may_switch(t):
            self.on = want
            self._since = t
        return self.on

    def may_switch(self, t: float) -> bool:
        """Whether the element has been on (or off) for its minimum by `t`."""
        return t - self._since + _EPS >= (self.min_on if self.on else self.min_off)

    def force_off(self, t: float) -> None:
        """Off now, whatever the minimum on time (an alarm): the debt is forgiven, nothing is
        asked until the next `decide`, and the minimum off time counts from now."""
        self.account(t)
        if self.on:
            self.on = False
            self._since = t
        self._forgive(self._owed)
        self._duty = 0.0

    def _forgive(self, seconds: float) -> None:
        self._owed -= seconds
        self._dropped += seconds


class SlowElement:
    """The second element's switch, driven once a control period by the modulator, with the
    duty it was switched on since the period before (as switched, forced offs included) and
    the duty it delivered on account (the modulator's)."""

    def __init__(self, switch: GuardedSwitch, min_on: float, min_off: float) -> None:
        self.switch = switch
        self.modulator = OnOffModulator(min_on, min_off)
        self._duty = SwitchedDuty()

    def applied(self, now: float) -> tuple[float, float]:
        """(% switched on, % on account) since the last call; after a forced off, on account
        since then (the loop holds the controller through any period with one)."""
        return self._duty.read(now), self.modulator.account(now)

    def drive(self, now: float, duty: float) -> None:
        """The period starting now: on or off as the modulator decides for `duty` %."""
        self._set(self.modulator.decide(now, duty), now)

    def force_off(self, now: float) -> None:
        self.modulator.force_off(now)
        self._set(False, now)

    def state(self, now: float) -> tuple[bool, bool]:
        """(on, free): whether it is on now, and whether its minimum time lets it switch."""
        return self.modulator.on, self.modulator.may_switch(now)

    def _set(self, on: bool, now: float) -> None:
        self.switch.set(on)
        self._duty.switched(on, now)


class MidRangeController:
    """The mid-ranging controller seen as the loop's controller of the SSR (`pid.Controller`):
    `step` returns u1; u2 is read after it. The duty the second element delivered in the
    period before is handed in first (`applied2`): C2 tracks it, and a reset resumes u2 from
    it, so the loop and `hermsd replay --verify` both restart from what the element did."""

    def __init__(self, inner: MidRange, params: pid.Params) -> None:
        self._inner = inner
        self._params = params
        self.applied2 = 0.0

    @property
    def params(self) -> pid.Params:
        return self._params

    @property
    def output(self) -> float:
        return self._inner.outputs[0]

    @property
    def u2(self) -> float:
        """The second element's duty of the last step, %."""
        return self._inner.outputs[1]

    @property
    def asked(self) -> tuple[float, float | None]:
        """What the last step asked, as the supervisor judges it: u1 and u2."""
        return self.output, self.u2

    @property
    def terms(self) -> tuple[float, float, float]:
        """(P1, I1, I2): C1's terms, and the slow controller's integral."""
        p1, i1, _, i2 = self._inner.terms
        return p1, i1, i2

    def step(self, sp: float, pv: float, applied: float | None = None) -> float:
        tracked = None if applied is None else (applied, self.applied2)
        return self._inner.step(sp, pv, tracked)[0]

    def reset(self, pv: float, output: float) -> None:
        self._inner.reset(pv, output, self.applied2)


def total_share(watts1: float, watts2: float, duty1: float, duty2: float) -> float:
    """Two elements' duties as one % of their total power (what the supervisor watches)."""
    return (watts1 * duty1 + watts2 * duty2) / (watts1 + watts2)


class PowerSplit:
    """One total power u (% of both elements) shared between the second element (whole
    periods on or off, within its minimum times) and the SSR's element (any duty), decided
    once a period, the second element first; the SSR makes up the difference.

    Each state of the second element allows a range of totals: [0, w1] off, [w2, w1 + w2] on
    (as % of the total). When the present state gives u exactly, it stays and nothing is
    carried: the controller is told the power it got and answers for any heat that came
    before. Otherwise the shortfall (u − given) is carried, and the element switches only
    when that brings the carried total nearer zero, counting that a switch holds the new
    state for its whole minimum time: switch when |owed + (u − given_new)·min_time| <
    |owed + (u − given_now)·h|. So for a u between the two ranges the mean given equals the
    mean asked (the controller's P needs no offset to hold), the debt swings about zero, the
    shorter phase is the minimum time (the least ripple the element allows), and a u that
    passes through the gap (the end of a heat-up's approach) does not switch the element at
    its first period there, to be held in the wrong state for a minimum time. A second
    element whose share alone exceeds `max_total` (control.max_output: a power limit) is
    never switched on, nor one whose heat over its minimum on-time would carry the water
    past the setpoint (`decide`'s `room`: `fits_under`); what it would have given is then
    not owed. An element the watch says gives no heat (`dead`: docs/two-elements.md) is not
    asked and its heat not counted: the other holds the tun alone, and a total beyond what
    that one gives is asked of it whole.
    """

    def __init__(
        self,
        watts1: float,
        watts2: float,
        period: float,
        min_on: float,
        min_off: float,
        max_total: float = 100.0,
    ) -> None:
        if not (watts1 > 0.0 and watts2 > 0.0 and period > 0.0 and min(min_on, min_off) > 0.0):
            raise ValueError(
                f"watts, period and minimum times must be > 0, got {watts1}, {watts2}, "
                f"{period}, {min_on}, {min_off}"
            )
        total = watts1 + watts2
        self.watts1, self.watts2, self.period = watts1, watts2, period
        self.min_on, self.min_off = min_on, min_off
        self.share2 = 100.0 * watts2 / total  # % of the total the second element gives
        self.share1 = 100.0 * watts1 / total
        self.owed = 0.0  # %·s of the total asked and not given (negative: given ahead)
        self.max_total = max_total
        self.may_close = self.share2 <= max_total
        self.dead: frozenset[int] = frozenset()  # the elements said to give no heat (1, 2)

    def total(self, duty1: float, duty2: float) -> float:
        """Two duties as one % of the total, the heat of an element said dead not counted;
        both full is exactly 100 (full-power checks)."""
        duty1 = 0.0 if 1 in self.dead else duty1
        duty2 = 0.0 if 2 in self.dead else duty2
        if duty1 >= 100.0 and duty2 >= 100.0:
            return 100.0
        return total_share(self.watts1, self.watts2, duty1, duty2)

    def decide(self, u: float, on: bool, free: bool, room: bool = True) -> tuple[bool, float]:
        """(second element on, SSR duty %) for total `u` %, the element `on` now and `free`
        to switch (its minimum time passed); `room` False: its heat over a minimum on-time
        would carry the water past the setpoint, so it is not switched on."""

        if self.dead:  # no more than the element left can give: the dead one's part is no one's
            u = min(u, self._range(self._closes)[1])

        def carried(state: bool) -> float:
            span = self.period if state == on else (self.min_on if state else self.min_off)
            return self.owed + (u - self._given(u, state)) * span

        state = on
        allowed = free and (on or (self._closes and room))
        if on and free and 2 in self.dead:
            state = False  # said to give no heat since it closed
        elif self._given(u, on) != u and allowed and abs(carried(not on)) < abs(carried(on)):
            state = not on
        given = self._given(u, state)
        held_off = not state and not room  # not owed: paid back later, it is the overshoot
        self.owed = 0.0 if given == u or held_off else self.owed + (u - given) * self.period
        return state, self._duty1(given, state)

    def full_power(self) -> FullPower:
        """The duties at the most the controller may ask (`max_total`): the second element on
        (off, if it may never close) and the SSR making up the rest: 100 % under no limit."""
        on = self._closes
        return FullPower(self._duty1(self._given(self.max_total, on), on), on)

    @property
    def _closes(self) -> bool:
        """Whether the second element may be switched on at all."""
        return self.may_close and 2 not in self.dead

    def _range(self, on: bool) -> tuple[float, float]:
        """The totals the SSR can make with the second element on or off, %: none of its
        own once it is said to give no heat."""
        ssr = 1 not in self.dead
        if on and 2 not in self.dead:
            return (self.share2, 100.0 if ssr else self.share2)
        return (0.0, self.share1 if ssr else 0.0)

    def _given(self, u: float, on: bool) -> float:
        low, high = self._range(on)
        return min(max(u, low), high)

    def _duty1(self, given: float, on: bool) -> float:
        low, high = self._range(on)
        if 1 in self.dead:
            return 0.0
        if given >= high:
            return 100.0
        return min(100.0, max(0.0, (given - low) * 100.0 / self.share1))


class SplitController:
    """A controller of the total power of both elements (any `pid.Controller`, its % of
    w1 + w2), seen by the loop as the controller of the SSR: `step` returns the SSR's duty,
    and the second element's state (`u2`, 0 or 100 %) is read after it. Before each step (and
    reset) the loop hands in the second element's duty as switched in the period before
    (`applied2`) and its state now (`on2`, `free2`): the controller is told the total power
    that really reached the water, so its model's prediction stays exact, and replay hands
    in the same from the period's record. With a `probe`, the SSR's element is switched off
    once in the first heat-up to check that both heat (hermsd/safety/element_probe.py)."""

    def __init__(
        self, inner: pid.Controller, split: PowerSplit, probe: ElementProbe | None = None
    ) -> None:
        self.inner = inner
        predictive.on_two_elements(inner)
        self.split = split
        self.probe = probe
        # Whether the probe held the SSR's element off in the step before last, and the last.
        self._held = (False, False)
        self.applied2 = 0.0
        self.on2 = False
        self.free2 = True
        self.u2 = 0.0
        self.total = 0.0  # the inner controller's last output: the total asked, % of w1 + w2
        self._output = 0.0

    @property
    def params(self) -> pid.Params:
        return self.inner.params

    @property
    def output(self) -> float:
        return self._output

    @property
    def terms(self) -> tuple[float, float, float]:
        return self.inner.terms

    @property
    def asked(self) -> tuple[float, float | None]:
        """What the last step asked, as the supervisor judges it: the total, before the
        share-out (which turns NaN into an SSR at 0 % and leaves the contactor as it was)."""
        return self.total, None

    def step(self, sp: float, pv: float, applied: float | None = None) -> float:
        total = None if applied is None else self.split.total(applied, self.applied2)
        if self._held[0]:  # the power two periods ago was the probe's, this one's full again
            predictive.loops_own_step(self.inner)
        u = self.total = self.inner.step(sp, pv, total)
        split = self.split
        room = fits_under(self.inner, sp, split)
        on, self._output = split.decide(u, self.on2, self.free2, room)
        self.u2 = 100.0 if on else 0.0
        full = on and self.on2 and self._output >= 100.0
        held = self.probe is not None and self.probe.step(sp, pv, full)
        if held:
            self._output = 0.0
        self._held = (self._held[1], held)
        return self._output

    def probe_result(self) -> ProbeResult | None:
        """What the heat-up's probe found in a step before, once (None: nothing new)."""
        return None if self.probe is None else self.probe.take()

    def reset(self, pv: float, output: float) -> None:
        """Continue from the SSR at `output` % with the second element as it is now."""
        self.split.owed = 0.0
        if self.probe is not None:
            self.probe.abandon()
        self.inner.reset(pv, self.split.total(output, 100.0 if self.on2 else 0.0))


def fits_under(law: pid.Controller, sp: float, split: PowerSplit) -> bool:
    """Whether the second element may close for its minimum time, which it then stays on
    whatever the law asks next: a period's ask near the setpoint (a time-optimal step of
    89 % at 0.5 °C below it) held 7.7 kW on a 17 L tun for 2 min, 10 °C over
    (bench/population.py tun 54). By the law's model, net of the losses (the least it
    gives, the SSR off), it must end at or under `sp`; where the SSR alone cannot hold the
    water (it falls at full power), half its rise above, at most LINEAR_BAND, so that the
    hold cycles about the setpoint by the least pulse the contactor allows rather than under
    it, out of the band (tun 200: 0.5 °C a pulse). No model: it may."""
    ssr_most = 0.0 if 1 in split.dead else split.share1  # % the SSR's element gives alone
    predicted = predictive.predicted_after(law, split.min_on, split.share2, ssr_most)
    if predicted is None:
        return True
    ahead, (after, alone) = predicted
    over = min(max(0.0, after - ahead) / 2.0, pid.LINEAR_BAND) if alone < ahead else 0.0
    return after <= sp + over


TwoElementController = MidRangeController | SplitController
"""A controller of both elements: its `u2` drives the second, its `applied2` is handed in."""
