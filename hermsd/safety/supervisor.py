"""The safety supervisor: decides, from readings and outputs alone, whether the heater may be on.

Pure and time-injected: the daemon feeds it every sensor read, every control period and the
loop's lateness, and obeys `heater_allowed`. Two kinds of fault:

- auto-recovering (sensor fault, stale reading, over-temperature, loop stall): the heater is
  off while they last and control resumes by itself, bumplessly, once they clear;
- latched (element not heating, SSR stuck on, dry fire, stuck sensor, controller fault): the
  heater stays off until someone resets the alarm, because each means the hardware (or the
  controller's model of it) is not what the loop believes it is.

Limits come from the tun as measured, or, before it is, hold for any tun the config could
be describing: half to twice its litres, a dead time up to 300 s, an open pot in a cold
room (`SafetyLimits.derive` states each derivation).
"""

from __future__ import annotations

import bisect
import itertools
import math
from collections import deque
from collections.abc import Iterator, Sequence
from typing import Any

from hermsd.safety.coil_load import NO_LOAD, CoilLoad
from hermsd.safety.heat_balance import CONFIRM_S, LOSS_GROWTH, Bounds, HeatBalance
from hermsd.safety.limits import (
    COLDEST_ROOM,
    DRY_FIRE_WINDOWS,
    HOLD_BAND,
    HOLD_DUTY_SPREAD,
    HOLD_ENDS_S,
    HOLD_SPAN_S,
    LATCHED_KINDS,
    MAINS_LOW,
    MODEL_MARGIN,
    NOISE_FLOOR,
    SENSOR_LAG_MAX,
    SUDDEN_DROP,
    WARMEST_ROOM,
    Alarm,
    SafetyLimits,
)


class _HeaterWatch:
    """A stretch at 80 % or more: when it began, the PV once its heat could show, and the PV
    over the last two half-watches (to tell a steady fall from a step)."""

    __slots__ = ("full", "recent", "ref", "ref_t", "start")

    def __init__(self) -> None:
        self.start: float | None = None
        self.full = True  # the output has stayed at 80 % or more all along
        self.ref_t = 0.0
        self.ref: float | None = None
        self.recent: deque[tuple[float, float]] = deque()

    def stop(self) -> None:
        self.start = None

    def restart(self, t: float, full: bool) -> None:
        self.start, self.ref, self.full = t, None, full
        self.recent.clear()


class _OutputSwing:
    """How far the minute means of the output have moved since the reading last changed.

    Kept incrementally, one output per period, so that a reading that rightly stays put
    for days costs the same each period as one that changes every read.
    """

    __slots__ = ("count", "high", "low", "minute", "since", "total", "young")

    def __init__(self) -> None:
        self.clear(None)

    def clear(self, since: float | None) -> None:
        """Forget every output; minutes are counted from `since`."""
        self.since = since
        self.young: deque[tuple[float, float]] = deque()  # outputs not yet old enough
        self.minute: int | None = None
        self.total, self.count = 0.0, 0
        self.low, self.high = math.inf, -math.inf

    def add(self, t: float, output: float) -> None:
        self.young.append((t, output))

    def swing(self, old_before: float) -> float | None:
        """Max − min of the minute means of outputs given at or before `old_before`."""
        since = self.since if self.since is not None else 0.0
        while self.young and self.young[0][0] <= old_before:
            when, output = self.young.popleft()
            minute = int((when - since) // 60.0)
            if minute != self.minute:
                self._close_minute()
                self.minute = minute
            self.total += output
            self.count += 1
        low, high = self.low, self.high
        if self.count:
            mean = self.total / self.count
            low, high = min(low, mean), max(high, mean)
        return high - low if high >= low else None

    def _close_minute(self) -> None:
        if self.count:
            mean = self.total / self.count
            self.low, self.high = min(self.low, mean), max(self.high, mean)
        self.total, self.count = 0.0, 0


class Supervisor:
    """Tracks faults; the heater may be on only while none is active or latched."""

    def __init__(self, limits: SafetyLimits) -> None:
        self.limits = limits
        self._active: dict[str, Alarm] = {}
        self._events: list[Alarm] = []
        self._bad_reads = 0
        self._good_reads = 0
        self._last_good_t: float | None = None
        self._last_accepted: float | None = None
        self._recent_reads: deque[float] = deque(maxlen=3)  # the last values read, good or not
        self._last_raw: int | None = None
        self._heater_watch = _HeaterWatch()
        self._balance = HeatBalance()
        # The last HOLD_SPAN_S of periods (t, PV, applied), and the hold they last showed:
        # (mean duty %, mean PV °C) of a span the water stood steady through.
        self._steady: deque[tuple[float, float, float]] = deque()
        self._hold: tuple[float, float] | None = None
        self._energy: deque[tuple[float, float, float]] = deque()  # (t, pv, full-power s)
        self._energy_before: deque[float] = deque()  # full-power s before each, since start
        self._energy_total = 0.0
        self._last_period_t: float | None = None
        self._wrong_chip = False
        self._history: deque[tuple[float, float]] = deque()
        self._sustained_before: dict[str, bool] = {}  # a rise sustained at the last period
        self._raw_since: float | None = None
        self._output_swing = _OutputSwing()
        # (t, °C/s the coil may cool, and warm, the water at over the period to t)
        self._coil: deque[tuple[float, float, float]] = deque()
        self._coil_warmed: deque[float] = deque()  # °C the coil may have warmed, to each t
        self._coil_total = 0.0

    # -- what the daemon asks -------------------------------------------------------------

    @property
    def heater_allowed(self) -> bool:
        return not self._active

    @property
    def active(self) -> list[str]:
        return sorted(self._active)

    @property
    def latched(self) -> list[str]:
        return sorted(k for k, a in self._active.items() if a.latched)

    def reasons(self) -> dict[str, str]:
        """Each active alarm's message: why the heater is off, in words."""
        return {kind: alarm.message for kind, alarm in sorted(self._active.items())}

    def drain_events(self) -> list[Alarm]:
        """Alarms raised or cleared since the last call, oldest first."""
        events, self._events = self._events, []
        return events

    def latched_alarms(self) -> list[Alarm]:
        """The latched alarms as they were raised (what a restart must not forget)."""
        return [self._active[kind] for kind in self.latched]

    def restore_latched(self, t: float, kind: str, message: str, values: dict[str, Any]) -> None:
        """Raise again a latched alarm that was in force before a restart."""
        if kind not in LATCHED_KINDS:
            raise ValueError(f"{kind} is not a latched alarm")
        self._raise(kind, t, message, values)

    def reset_latched(self, t: float, kinds: list[str] | None = None) -> list[str]:
        """Clear latched alarms (an explicit act of the brewer): those of `kinds`, or all.

        Returns what was cleared.
        """
        cleared = [kind for kind in self.latched if kinds is None or kind in kinds]
        if not cleared:
            return []
        for kind in cleared:
            self._clear(kind, t, "reset by the operator")
        self._heater_watch.stop()
        self._balance.clear()
        self._steady.clear()
        self._energy.clear()
        self._energy_before.clear()
        self._history.clear()
        self._coil.clear()
        self._coil_warmed.clear()
        self._sustained_before.clear()
        self._raw_since = None
        self._output_swing.clear(None)
        return cleared

    # -- inputs ---------------------------------------------------------------------------

    def reading(self, t: float, celsius: float, raw: int | None = None, crit: bool = False) -> bool:
        """A value the sensor returned; True when it is accepted as a measurement."""
        lim = self.limits
        if self._wrong_chip:
            return False
        recent = tuple(self._recent_reads)
        self._recent_reads.append(celsius)
        if not lim.plausible_min <= celsius <= lim.plausible_max:
            self._bad(t, f"implausible reading {celsius:.4f} °C", {"celsius": celsius})
            return False
        last = self._last_accepted
        if (
            last is not None
            and abs(celsius - last) > lim.max_step
            and not _jump_believed(celsius, recent, lim.max_step)
        ):
            self._bad(t, f"jump {celsius - last:+.4f} °C in one read", {"celsius": celsius})
            return False
        self._last_accepted = celsius
        self._last_good_t = t
        self._bad_reads = 0
        self._good_reads += 1
        if raw != self._last_raw or self._raw_since is None:
            self._last_raw, self._raw_since = raw, t
        if "sensor_fault" in self._active and self._good_reads >= lim.resume_reads:
            self._clear("sensor_fault", t, f"{self._good_reads} good reads")
        if "stale_reading" in self._active and self._good_reads >= lim.resume_reads:
            self._clear("stale_reading", t, "readings are fresh again")
        # The T_CRIT flag travels in the same word as the value: trusted when the value is.
        if crit or celsius >= lim.max_temp:
            self._raise(
                "over_temperature",
                t,
                f"{celsius:.2f} °C at or above the limit {lim.max_temp:.1f} °C"
                + (" (LM92 T_CRIT flag)" if crit else ""),
                {"celsius": celsius, "crit": crit},
            )
        elif (
            "over_temperature" in self._active
            and not crit
            and celsius < lim.max_temp - lim.hysteresis
        ):
            self._clear("over_temperature", t, f"{celsius:.2f} °C")
        return True

    def chip_check(self, t: float, ok: bool, message: str = "") -> None:
        """The chip's identity, checked once a period: another chip's values mean nothing."""
        if ok:
            self._wrong_chip = False
            return
        self._wrong_chip = True
        self._good_reads = 0
        self._raw_since = None
        self._raise("sensor_fault", t, message, {})

    def read_error(self, t: float, message: str, errno: int | None = None) -> None:
        """A read that failed (bus error, wrong chip)."""
        self._bad(t, message, {"errno": errno})

    def tick(self, t: float) -> None:
        """Time passes: a reading that is too old is no reading."""
        last = self._last_good_t
        if last is not None and t - last > self.limits.stale_after:
            self._good_reads = 0
            self._raise(
                "stale_reading",
                t,
                f"no good reading for {t - last:.1f} s (limit {self.limits.stale_after:.1f} s)",
                {"age_s": t - last},
            )

    def current_fault(self, t: float, kind: str, message: str, values: dict[str, Any]) -> None:
        """A latched fault the element's current input told (`safety/current_watch.py`): the
        kind the thermal verdict would latch, raised now."""
        if kind not in ("ssr_stuck_on", "heater_not_heating"):
            raise ValueError(f"{kind} is not a fault the current input tells")
        self._raise(kind, t, message, values)

    def loop_lateness(self, t: float, lateness: float) -> None:
        """How late the control period started: a stalled loop cannot be trusted."""
        if lateness > self.limits.stall_after:
            self._raise(
                "loop_stall",
                t,
                f"control period {lateness:.2f} s late (limit {self.limits.stall_after:.1f} s)",
                {"lateness_s": lateness},
            )
        elif "loop_stall" in self._active:
            self._clear("loop_stall", t, "the loop is on time again")

    def controller_output(self, t: float, output: float, output2: float | None = None) -> bool:
        """The controller's outputs for the period (the second element's too, when fitted):
        True when each is a duty (0..100 %).

        NaN or infinity (a learned model or control settings the controller cannot work
        with) is no duty: the heater must not be driven from it, and the next step of the
        same controller is no more to be trusted, so the alarm latches.
        """
        for key, what, duty in (("output", "", output), ("output2", " for element2", output2)):
            if duty is None or (math.isfinite(duty) and 0.0 <= duty <= 100.0):
                continue
            self._raise(
                "controller_fault",
                t,
                f"controller output{what} {duty} % is not a duty within 0..100 % (check the "
                "control settings, or `hermsd forget-model` for a learned model it cannot "
                "work with)",
                {key: str(duty)},  # as text: the latch file holds JSON, which has no NaN
            )
            return False
        return True

    def period(
        self,
        t: float,
        pv: float | None,
        output: float,
        applied: float,
        coil: CoilLoad = NO_LOAD,
    ) -> None:
        """Once per control period: the checks that need a history of PV and output.

        `coil`: the HERMS coil's load on the water over the period (`safety.coil_load`): its
        most taken explains a fall, its most given back a rise.
        """
        if pv is None:
            return
        self._count_coil(t, coil)
        self._check_dry_fire(t, pv)
        self._measure_hold(t, pv, applied)
        self._check_heater(t, pv, applied)
        self._check_balance(t, pv, applied)
        self._check_ssr(t, pv, applied)
        if self.heater_allowed:
            self._check_stuck(t, output)
        else:
            self._output_swing.clear(self._raw_since)  # a forced 0 % is not the controller

    # -- the period checks ----------------------------------------------------------------

    def _count_coil(self, t: float, coil: CoilLoad) -> None:
        """The fastest the coil may have moved the water's temperature over the period to
        `t`, each way (°C/s in the least water the tun may hold), for the heat balances."""
        lim, coils = self.limits, self._coil
        per_joule = lim.rise_per_joule
        given = coil.most_given * per_joule
        if coils:  # its fastest over the period, for the period before the one it is given at
            self._coil_total += given * (t - coils[-1][0])
        coils.append((t, coil.most_taken * per_joule, given))
        self._coil_warmed.append(self._coil_total)
        keep = max(lim.ssr_watch, *lim.creep_watches) + lim.heat_memory + SENSOR_LAG_MAX
        while t - coils[0][0] > keep:
            coils.popleft()
            self._coil_warmed.popleft()

    def _coil_fall(self, start: float, end: float) -> float:
        """°C the coil may have cooled the water by, as the sensor shows it from `start` to
        `end`: the fastest it may have cooled it since a sensor's lag (`SENSOR_LAG_MAX`)
        before `start`, for the whole span (a lagged reading falls no faster than that)."""
        since = start - SENSOR_LAG_MAX
        fastest = max((c for when, c, _ in self._coil if since < when <= end), default=0.0)
        return fastest * (end - start)

    def _coil_rise(self, since: float, end: float) -> float:
        """°C the coil may have warmed the water by from `since` to `end` (its fastest over
        each period, for the period before the one it was given at): a difference of running
        sums, as the checks ask it several times a period over windows of up to an hour."""
        coils, warmed = self._coil, self._coil_warmed
        last = bisect.bisect_right(coils, end, key=_when) - 1
        first = max(bisect.bisect_right(coils, since, key=_when) - 1, 0)
        return warmed[last] - warmed[first] if last > first else 0.0

    def _check_dry_fire(self, t: float, pv: float) -> None:
        """Heat into too little water: a rise faster than the water allows, and sustained.

        Each of the last `DRY_FIRE_WINDOWS` windows must rise faster than `dry_fire_rate`,
        and what each rises above the fastest any element heats the configured water
        (`heat_rate`, over the window; less where the limit is lower, see below) must not
        shrink, window to window, to e^(−window/`SENSOR_LAG_MAX`) of it (0.67 for 60 s) or
        less, plus the noise (0.1 °C), in two consecutive periods.

        Why: hot water poured in is a step of the bulk water, seen through the sensor's
        first-order lag L ≤ 150 s: its rise over a window that starts after the pour is
        e^(−window/L) times that over the window before, at most 0.67 of it; the element adds
        at most `heat_rate` a second (less, and less still as losses grow), so the excess
        over `heat_rate`·window decays at least as fast. The oldest window rising too fast
        shows the pour came before the last two windows; the two periods in a row ensure the
        later two begin after it, not within the mean that makes the PV. A dry fire is an
        element's steady heat into a few litres: its rise does not decay (it slows only as
        losses grow) and it is caught two windows (and a period) later than by one window.
        """
        lim = self.limits
        history = self._history
        history.append((t, pv))
        window = lim.dry_fire_window
        while history and t - history[0][0] > DRY_FIRE_WINDOWS * window + window:
            history.popleft()
        rises = _window_rises(history, t, window, DRY_FIRE_WINDOWS)
        decay = math.exp(-window / SENSOR_LAG_MAX)
        # What the element may explain, and no more than leaves a steady rise at the limit an
        # excess e that beats decay·e + NOISE_FLOOR: a dry_fire_factor set below heat_rate's
        # (2.42× the rated rate) still alarms at its own rate. At the default 3× the element's
        # fastest heat is the lower of the two.
        explained = min(
            lim.heat_rate * window, lim.dry_fire_rate * window - NOISE_FLOOR / (1.0 - decay)
        )
        # The coil's heat back (a warmer mash) explains as much of each window's rise.
        ends = [t - i * window for i in range(DRY_FIRE_WINDOWS - 1, -1, -1)]
        coil = [self._coil_rise(end - window - SENSOR_LAG_MAX, end) for end in ends]
        sustained = rises is not None and _sustained(
            rises,
            [rise - explained - back for rise, back in zip(rises, coil, strict=True)],
            decay,
            least=lim.dry_fire_rate * window,
        )
        if self._confirmed("dry_fire", sustained) and rises is not None:
            rate = rises[-1] / window
            self._raise(
                "dry_fire",
                t,
                f"rising {rate * 60:.2f} °C/min for {DRY_FIRE_WINDOWS * window:.0f} s, more "
                f"than the water allows ({lim.dry_fire_rate * 60:.2f} °C/min)",
                {"rate_c_per_s": rate},
            )

    def _check_heater(self, t: float, pv: float, applied: float) -> None:
        """An element that does not heat: judged only once its heat could show at the sensor.

        From `dead_time` after the output reached 80 % of full power (`heating_output`: less
        on a measured tun; or after the last fall too fast for losses: water was added), a
        working element makes the PV rise by `least_rise` (the cool side, where losses are
        small), and it cannot let the PV fall steadily (the hot side: a dead element in the
        hold shows as a fall at the tun's loss rate while the output climbs to its limit;
        `applied` is the duty as switched, within that limit). Steadily: over each of
        the last two half-watches (the later one past the dead time) by at least half of
        `heater_max_fall`, the later by at least half the earlier. Water poured in shows
        through the sensor's lag (≤ 150 s) as a decaying fall, e^(−150/150) = 0.37 of it in
        the second half-watch, and the element's heat adds to that: not steady. A HERMS coil
        may take more than the element gives: the most it may take (`_coil_fall`) is taken
        off each half's fall and off the least rise, so a fall it can explain is no verdict;
        so is what the day's losses may take beyond the heat due at the sensor (`_fall_due`:
        an output climbing to h, its heat on the way; a colder room).
        """
        lim, watch = self.limits, self._heater_watch
        if applied < self._heating_output(pv):
            watch.stop()
            return
        full = applied >= lim.full_output
        if watch.start is None or self._water_added(pv):
            watch.restart(t, full)
            return
        watch.full = watch.full and full
        half = lim.heater_watch / 2.0
        recent = watch.recent
        recent.append((t, pv))
        while t - recent[0][0] > 2.0 * half:
            recent.popleft()
        if t - watch.start < lim.dead_time:
            return
        if watch.ref is None:
            watch.ref, watch.ref_t = pv, t
        held = t - watch.ref_t
        fall = 0.0
        peak = max(p for _, p in recent)
        # Only the later half need lie past the dead time: the element's heat shows in it,
        # whatever the water did before.
        if held >= half and t - recent[0][0] >= 1.9 * half:
            pv_mid = next(p for when, p in recent if when >= t - half)
            first, second = recent[0][1] - pv_mid, pv_mid - pv
            step = lim.heater_max_fall / 2.0
            # The coil's most taken, and losses beyond the heat due, explain as much of each
            # half's fall.
            begin, middle = recent[0][0], t - half
            losses = self._losses_may_be(peak)
            first -= self._coil_fall(begin, middle) + self._fall_due(begin, middle, losses, t)
            second -= self._coil_fall(middle, t) + self._fall_due(middle, t, losses, t)
            if first >= step and second >= max(step, first / 2.0):
                fall = first + second
        judged = watch.full and held >= lim.heater_watch
        least = lim.least_rise(held, max(peak, watch.ref)) if judged else None
        if least is not None:
            least -= self._coil_fall(watch.ref_t, t)
            least = least if least >= NOISE_FLOOR else None  # the coil may take all of it
        # Heat on, or its lack, moves the water a step or more every few minutes, and noise
        # flips the last bit: a reading that has not changed at all for the watch is stuck,
        # at an output that beats the losses a normal day may grow to (LOSS_GROWTH: at less,
        # a colder room may take all of it and hold the water still), unless the coil, with
        # the losses, may have taken all the element gave (a HERMS hold's steady water, or
        # the bottom of the HLT's dip while the coil's load falls past the element's: there
        # the element's heat is the coil's and the losses').
        since = self._raw_since
        frozen = (
            since is not None
            and t - max(since, watch.ref_t) >= lim.heater_watch
            and applied >= min(lim.full_output, self._held_losses(pv, LOSS_GROWTH) or 0.0)
        )
        if frozen and since is not None:
            still = max(since, watch.ref_t)
            taken = self._coil_fall(still, t)
            if taken > 0.0:
                taken += lim.loss_rate(pv) * (t - still)
            frozen = taken < lim.least_heating(applied) * (t - still)
        if not frozen and not fall and (least is None or pv - watch.ref >= least):
            return
        what = (
            "the reading has not changed at all"
            if frozen
            else f"PV fell steadily, {fall:.2f} °C in {2 * half:.0f} s"
            if fall
            else f"PV rose {pv - watch.ref:.2f} °C in {held:.0f} s (expected at least {least:.2f})"
        )
        self._raise(
            "sensor_stuck" if frozen else "heater_not_heating",
            t,
            f"output at {applied:.0f} % for {t - watch.start:.0f} s, {lim.dead_time:.0f} s of "
            f"it the heat's way to the sensor, but {what}",
            {"rise_c": pv - watch.ref, "fall_c": fall, "applied": applied},
        )

    def _check_balance(self, t: float, pv: float, applied: float) -> None:
        """An element that does not heat, by the heat balance over the last windows of
        whatever the output did (hermsd/safety/heat_balance.py). One element (of two, the
        other may hold: the element watch's), and no HERMS coil that may have drawn within
        the heat's memory: the balance starts again after it (a pump stopped for good), its
        windows then free of the coil, where the watches look back an hour."""
        lim, balance = self.limits, self._balance
        if lim.two_elements or not self.heater_allowed or self._coil_may_draw(lim.heat_memory):
            balance.clear()
            return
        if self._water_added(pv):
            balance.poured(t)
        bounds = Bounds(
            dead_time=lim.dead_time,
            per_duty=lim.heater_rise_rate / lim.full_output,
            loss_duty=self._heating_output(pv),
            least_fall=lim.heater_max_fall / lim.heater_watch,
            any_fall_duty=self._held_losses(pv, LOSS_GROWTH),
            fastest_loss=lim.loss_rate(pv),
            full_duty=lim.max_output,
            # The fastest heat sagging with the mains to −10 %, and an open pot's evaporation
            # starting (a lid taken off); the losses' growth per °C at the PV's top (they
            # grow ever faster with it).
            stall_drop=(1.0 - MAINS_LOW) * lim.heat_rate + lim.evaporation(pv),
            heat_memory=lim.heat_memory,
            loss_per_k=lim.loss_rate(pv + 1.0) - lim.loss_rate(pv),
            hold_duty=None if self._hold is None else self._hold[0],
        )
        verdict = balance.period(t, pv, applied, bounds)
        # A reading frozen bit for bit looks like a ramp that stopped: told only once the
        # reading has moved within the confirmation, so a stuck sensor is named as one
        # (`_check_heater`), and a dead element on a coarse sensor at its next step.
        since = self._raw_since
        if verdict is not None and since is not None and t - since < CONFIRM_S:
            self._raise("heater_not_heating", t, verdict.message, verdict.values)

    def forget_hold(self) -> None:
        """Another tun is configured: the hold measured on the last one (a duty in % of its
        element) says nothing of this one's losses, so the hold is measured anew."""
        self._steady.clear()
        self._hold = None

    def _measure_hold(self, t: float, pv: float, applied: float) -> None:
        """The day's own hold: over the last HOLD_SPAN_S the PV stood within HOLD_BAND, its
        first and last HOLD_ENDS_S' means within NOISE_FLOOR of each other (no heat gained
        or lost to speak of) and the duty's alike, so the mean duty balanced the losses. Water
        poured in starts the span again (the losses per °C changed)."""
        steady = self._steady
        if steady and self._water_added(pv):
            steady.clear()
        steady.append((t, pv, applied))
        while t - steady[0][0] > HOLD_SPAN_S:
            steady.popleft()
        dt = t - steady[-2][0] if len(steady) > 1 else 0.0
        if t - steady[0][0] < HOLD_SPAN_S - dt:
            return
        pvs = [p for _, p, _ in steady]
        if max(pvs) - min(pvs) > HOLD_BAND:
            return
        first = [(p, a) for when, p, a in steady if when <= steady[0][0] + HOLD_ENDS_S]
        last = [(p, a) for when, p, a in steady if when >= t - HOLD_ENDS_S]
        (pv_first, duty_first), (pv_last, duty_last) = _means(first), _means(last)
        if abs(pv_first - pv_last) > NOISE_FLOOR:
            return
        # A duty that climbs while the water sinks is a controller answering a loss of heat
        # (a dead element), not a hold: its ends agree within 2 % or a fifth.
        if abs(duty_first - duty_last) > max(HOLD_DUTY_SPREAD, 0.2 * max(duty_first, duty_last)):
            return
        self._hold = (sum(a for _, _, a in steady) / len(steady), sum(pvs) / len(pvs))

    def _heating_output(self, pv: float) -> float:
        """% of output at or above which a working element cannot let the water at `pv`
        fall: the limits' (`SafetyLimits.heating_output`), or less once the day's hold has
        measured its losses (`_held_losses` with ×1.5 of them: a lid taken off)."""
        most = self.limits.heating_output(pv)
        held = self._held_losses(pv, MODEL_MARGIN)
        return most if held is None else min(most, held)

    def _losses_may_be(self, pv: float) -> float:
        """% of output a normal day's losses may take at `pv`: those h beats
        (`_heating_output`), or `LOSS_GROWTH` times the day's hold's (a colder room: at a
        duty between the two the water may fall and the law still be working), never more
        than the element gives at 80 % of its limit (a tun that loses more is not held on a
        normal day: there a steady fall is the verdict it was)."""
        losses = MAINS_LOW * self._heating_output(pv)
        grown = self._grown_losses(pv, LOSS_GROWTH)
        if grown is None:
            return losses
        return max(losses, min(grown, MAINS_LOW * self.limits.full_output))

    def _fall_due(self, start: float, end: float, losses: float, t: float) -> float:
        """°C the water may fall from `start` to `end` with a working element against
        `losses` % of output: beyond the least heat due at the sensor (any window as long,
        ending within a dead time before `end`, each period's whole), at −10 % mains, every
        % moving the water at most `heat_rate` per 100 s."""
        lim = self.limits
        span = end - start
        last = self._last_period_t
        # Whole periods only: after a stalled loop the last one may be longer than the span.
        whole = span - (0.0 if last is None else t - last)
        least = min(self._window_energies(end, max(whole, 0.0), lim.dead_time), default=0.0)
        short = losses - MAINS_LOW * 100.0 * least / span
        return max(0.0, short) / 100.0 * lim.heat_rate * span

    def _held_losses(self, pv: float, growth: float) -> float | None:
        """% of output that beats the day's hold's losses grown `growth` times
        (`_grown_losses`) at −10 % mains; never below 20 % (a slow fall is lost in the
        noise). None where those are not known."""
        losses = self._grown_losses(pv, growth)
        return None if losses is None else max(20.0, losses / MAINS_LOW)

    def _grown_losses(self, pv: float, growth: float) -> float | None:
        """% of output the day's hold's losses (`_measure_hold`) take grown `growth` times,
        grown with the water's rise above the room over the hold's, and an open surface's
        evaporation on top. None with no hold measured, two elements or a coil that may draw.
        The room is not known: (T − room) over (hold − room) is largest, for water below
        the hold, in the coldest room and, above it, in the warmest; a hold no warmer than
        the warmest room (a scheduled heat-up's water standing cold, the heater off) bounds
        nothing above it."""
        lim = self.limits
        if self._hold is None or lim.two_elements or self._coil_may_draw():
            # Two elements: below 80 % the SSR's may be carrying all that is asked; when it
            # dies the contactor's takes over as the output climbs, where a latch would stop
            # both (the element watch warns of it: safety/element_watch.py). A HERMS coil
            # that may draw: the coil's bound leaves the mash tun's losses to the 80 %
            # (docs/herms.md, "The mash's balance").
            return None
        duty, held_at = self._hold
        if pv <= held_at:
            grows = max(pv - COLDEST_ROOM, 0.0) / max(held_at - COLDEST_ROOM, 1.0)
        elif held_at > WARMEST_ROOM:
            grows = (pv - WARMEST_ROOM) / (held_at - WARMEST_ROOM)
        else:
            return None
        return growth * duty * grows + lim.evaporation_share(pv)

    def _coil_may_draw(self, within: float | None = None) -> bool:
        """Whether a HERMS coil may have taken heat within the coil's bookkeeping (the
        watches and the heat's memory), or in the last `within` s."""
        coils = self._coil
        if within is None or not coils:
            return any(taken > 0.0 for _, taken, _ in coils)
        since = coils[-1][0] - within
        return any(taken > 0.0 for when, taken, _ in coils if when > since)

    def _water_added(self, pv: float) -> bool:
        """The PV fell over the last window faster than any loss can make it: water came in."""
        history = self._history
        t = history[-1][0]
        t0, pv0 = next((when, p) for when, p in history if when >= t - self.limits.dry_fire_window)
        span = t - t0
        fall = pv0 - pv - self._coil_fall(t0, t)
        return fall > max(SUDDEN_DROP, self.limits.loss_rate(pv0) * span)

    def _check_ssr(self, t: float, pv: float, applied: float) -> None:
        """Heat the element was not given: the rise exceeds all the energy it was given.

        Losses only ever take heat away, so over a watch window the water can rise at most by
        the delivered energy times the fastest rate per full-power second (`heat_rate`: half
        the water, +10 % mains). Heat reaches the sensor only after the dead time and the
        well's lag (300 + 150 s before anything is measured: a lag's tail beyond that is e^−2
        of it), so the energy is the most any window as long delivered within `heat_memory`
        before (`_most_delivered`). More rise than that means something else is heating: an
        SSR that failed shorted. The longer
        watches (`CREEP_WATCHES`) see a heater that outpaces the losses only slowly; the
        quick one (`QUICK_WATCH`) a fast short on a small duty sooner.

        Hot water poured in is heat nothing delivered too, but it stops: a step of the water,
        seen through the sensor's lag L ≤ 150 s, whose rise over each window that begins past
        the pour is e^(−window/L) of the window's before or less. A heater keeps going: over
        three equal windows, the thirds of the watch or the thirds of the time since the rise
        began (`_heat_goes_on`), each must rise by more than the noise (`NOISE_FLOOR`), the
        later two beating e^(−window/`SENSOR_LAG_MAX`) times the window's before by more than
        it, in two consecutive periods (see `_check_dry_fire`): a period (5 s) later than the
        energy balance alone. Windows from the onset are judged as soon as the rise has shown
        its shape (60 s after it on the fastest-heating tun), not only once it fills the
        watch's first third: with no pour in the watch, the energy balance is what times the
        alarm. A steady heater passes the thirds when its rise per third, times
        1 − e^(−third/150 s), beats 0.1 °C: from 7.4, 1.4 and 0.3 °C/h for the 300, 900 and
        3600 s watches, whose energy balances need 6, 2 and 0.5 °C/h (a heater between 6 and
        7.4 °C/h is the 900 s watch's); the quick watch's from 38 °C/h, a fast short's, which
        is what it is for. A
        mash warmer than the water gives heat back through a HERMS coil: the most it may give
        over the window and the heat's memory is allowed on top (`_coil_rise`).
        """
        lim, history = self.limits, self._energy
        previous, self._last_period_t = self._last_period_t, t
        dt = 0.0 if previous is None else t - previous
        energy = applied / 100.0 * dt
        history.append((t, pv, energy))
        self._energy_before.append(self._energy_total)
        self._energy_total += energy
        longest = max(lim.ssr_watch, *lim.creep_watches)
        while t - history[0][0] > longest + lim.heat_memory:
            history.popleft()
            self._energy_before.popleft()
        watches = [(w, 0.0) for w in lim.short_watches] + [(lim.ssr_watch, 0.0)]
        watches += [(w, lim.loss_per_k * w) for w in lim.creep_watches]
        for watch, room_per_k in watches:
            span = watch + lim.heat_memory
            if t - history[0][0] < span - dt:
                continue
            pv_then = history[bisect.bisect_left(history, t - watch, key=_when)][1]
            full_power_s = self._most_delivered(t, watch, dt)
            from_room = room_per_k * max(0.0, WARMEST_ROOM - min(pv, pv_then))
            from_coil = self._coil_rise(t - span, t)
            beside = lim.tolerated_rise(watch) + from_room + from_coil
            allowed = lim.heat_rate * full_power_s + beside
            # More than the element at full power through a whole window can make is no SSR's
            # doing: hot water poured into a full-power heat-up (the dry fire's own watch
            # judges a rise too fast for the water).
            ceiling = lim.heat_rate * (watch + 2.0 * dt) + beside
            sustained = allowed < pv - pv_then <= ceiling and _heat_goes_on(
                history, t, watch, pv_then, dt
            )
            if self._confirmed(f"ssr_stuck_on {watch:g}", sustained):
                self._raise(
                    "ssr_stuck_on",
                    t,
                    f"PV rose {pv - pv_then:.2f} °C in {watch:.0f} s, more than the "
                    f"{full_power_s:.0f} s of full power delivered"
                    + (f" and the coil's heat back ({from_coil:.2f} °C)" if from_coil else "")
                    + f" can explain ({allowed:.2f} °C)",
                    {"rise_c": pv - pv_then, "allowed_c": allowed},
                )
                return

    def _most_delivered(self, t: float, watch: float, dt: float) -> float:
        """Full-power s: the most delivered in any `watch` s (and two periods more, the most a
        window between two period marks can straddle) ending within `heat_memory` of `t`.

        Heat delivered at s shows at the sensor through the dead time and the lag, each
        second's heat spread over a delay of 0 to `heat_memory` s by some weights that sum to
        one. The rise over the watch is then a weighted mean, over those delays, of the heat
        delivered in a watch-long window that many seconds earlier: no more than the most any
        such window held. Never more than all the heat of the watch and the memory (the
        bound before it), and far less in a hold: a duty d gives d·watch, not
        d·(watch + memory)."""
        return max(self._window_energies(t, watch + dt, self.limits.heat_memory), default=0.0)

    def _window_energies(self, end: float, span: float, back: float) -> Iterator[float]:
        """Full-power s delivered in each window of `span` s (and the period its first mark
        closes) that ends at a period mark within `back` s before `end`."""
        history, before = self._energy, self._energy_before
        total = self._energy_total
        last = bisect.bisect_right(history, end, key=_when)
        start = bisect.bisect_left(history, end - back - span, key=_when)
        for stop in range(bisect.bisect_left(history, end - back, key=_when), last):
            after_stop = before[stop + 1] if stop + 1 < len(history) else total
            while history[start][0] < history[stop][0] - span:
                start += 1
            yield after_stop - before[start]

    def _confirmed(self, what: str, sustained: bool) -> bool:
        """`sustained` now and at the last period: windows that begin past a pour, not within
        the period whose mean of reads is the PV."""
        before, self._sustained_before[what] = self._sustained_before.get(what, False), sustained
        return sustained and before

    def _check_stuck(self, t: float, output: float) -> None:
        """A reading that stays bit-identical although the output moved long enough ago.

        Only outputs at least half the stuck time old count: a change of power needs the
        tun's dead time and more before a working sensor shows it.
        """
        lim, watch = self.limits, self._output_swing
        since = self._raw_since
        if since != watch.since:
            watch.clear(since)
        if since is None:
            return
        watch.add(t, output)
        # Minute means of the outputs old enough to have shown: an output that chatters
        # around a steady mean does not move the water.
        swing = watch.swing(t - lim.stuck_time / 2)
        if t - since < lim.stuck_time or swing is None:
            return
        if swing >= lim.stuck_output_change:
            self._raise(
                "sensor_stuck",
                t,
                f"the reading has not changed for {t - since:.0f} s while the output "
                f"moved {swing:.0f} %",
                {"swing": swing, "raw": self._last_raw},
            )

    # -- bookkeeping ----------------------------------------------------------------------

    def _bad(self, t: float, message: str, values: dict[str, Any]) -> None:
        self._good_reads = 0
        self._raw_since = None  # a failed read says nothing about a stuck one
        self._bad_reads += 1
        if self._bad_reads >= self.limits.fault_reads:
            self._raise(
                "sensor_fault", t, f"{self._bad_reads} bad reads in a row: {message}", values
            )

    def _raise(self, kind: str, t: float, message: str, values: dict[str, Any]) -> None:
        if kind in self._active:
            return
        alarm = Alarm(kind, t, message, kind in LATCHED_KINDS, True, values)
        self._active[kind] = alarm
        self._events.append(alarm)

    def _clear(self, kind: str, t: float, why: str) -> None:
        alarm = self._active.pop(kind, None)
        if alarm is not None:
            self._events.append(Alarm(kind, t, f"cleared: {why}", alarm.latched, False))


def _means(pairs: Sequence[tuple[float, float]]) -> tuple[float, float]:
    """The means of each member of `pairs`."""
    return sum(p for p, _ in pairs) / len(pairs), sum(a for _, a in pairs) / len(pairs)


def _jump_believed(celsius: float, recent: Sequence[float], max_step: float) -> bool:
    """A read more than `max_step` from the last accepted one is believed when the read
    before it agrees (a real step, cold water, is believed one read later), or when it
    goes on a run of such jumps the same way, as a step of the water (a cold dump of any
    size) shows through the sensor's first-order lag: the reads (`recent`, oldest first,
    refused ones too) were steady or already going that way, the last step was a jump and
    this one is a jump the same way; within the run each full read's step is e^(−interval/lag)
    of the one before, so once two jumps have shown this one must be no larger. The first
    jump may cover only part of its interval (the water stepped between two reads), so the
    second may be larger than it, not the third.

    What a failing sensor or bus gives is refused still. A lone spike, up or down, is one
    jump (an LSB of noise before it is no jump) with a read after it that goes back, and a
    jump back from a spike is against the way the reads went before it; an erratic sensor's
    jumps alternate; the LM92's own faults (a spiked conversion, a frozen register, NACKs
    and timeouts, another chip, a slow bus) give a lone spike, no change or no reading. A
    sensor stuck at a wrong value after a jump is believed from its second read, as before,
    and a reading that then never changes latches `sensor_stuck`. Random words off the bus
    (13 bits, 23 % within the plausible range) make two jumps the same way once in ~78 pairs
    of reads (two that agree: once in ~580): the garbage around them is refused, so the
    fault is raised all the same; a burst of two believed is one period's mean pulled by a
    fifth of its error.
    """
    if recent and abs(celsius - recent[-1]) <= max_step:
        return True
    if len(recent) < 2:
        return False
    step, last = celsius - recent[-1], recent[-1] - recent[-2]
    if abs(last) <= max_step or step * last <= 0.0:
        return False
    before = recent[-2] - recent[-3] if len(recent) == 3 else 0.0
    if before * step < 0.0 and abs(before) > max_step:
        return False  # the jump back from a spike
    return abs(before) <= max_step or abs(step) <= abs(last)


def _when(sample: tuple[float, ...]) -> float:
    return sample[0]


def _window_rises(
    history: Sequence[tuple[float, ...]], t: float, window: float, count: int
) -> list[float] | None:
    """The PV's rise over each of the last `count` windows to `t`, oldest first (None while
    the history is shorter)."""
    slack = 0.01 * window  # periods need not divide the window exactly
    if t - history[0][0] < count * window - slack:
        return None
    edges = [
        next(sample[1] for sample in history if sample[0] >= t - i * window - slack)
        for i in range(count, -1, -1)
    ]
    return [later - earlier for earlier, later in itertools.pairwise(edges)]


def _heat_goes_on(
    history: Sequence[tuple[float, float, float]],
    t: float,
    watch: float,
    pv_then: float,
    period: float,
) -> bool:
    """The rise in the watch to `t` goes on as heat does, not settling as a pour's step does:
    `_sustained` over the watch's three thirds, or over three equal windows from the rise's
    onset (the last PV within the noise of the watch's first, `pv_then`), at least two
    periods each.

    A step from hot water poured in at p shows through the sensor's lag: every period mean
    from p + one period on is the same exponential tail, so the rises of windows that begin
    past it shrink by e^(−window/L) at least, L ≤ `SENSOR_LAG_MAX`, and fail `_sustained` by
    the noise margin. The onset lies at most a period before the pour (the PV was within the
    noise of where it began until the pour lifted it), so with windows of two periods or more
    the later two begin past it and their pair fails; the two consecutive periods
    (`Supervisor._confirmed`) guard the window edges as in the watch's thirds. A pour after
    the onset of a steady rise has a first window that rose by more than the noise: as in
    the thirds, the delivered energy then judges it. A heater's heat arrives through the
    dead time and the lag as a rise that grows or holds (it slows only as losses grow): it
    passes once its rise per window, times 1 − e^(−window/150 s), beats the noise, 60 s
    after its onset for a shorted 5.5 kW element in 30 L (0.044 °C/s), 150 s for the
    rated 3 kW into 90 L (0.008 °C/s), not a third of the watch after the watch began past
    it (the thirds alone: 200 s and more after it).
    """
    third = watch / 3.0
    onset = next(when for when, p, _ in reversed(history) if p <= pv_then + NOISE_FLOOR)
    # Whole periods: windows off the period grid rise by alternately one period more or less
    # on a steady ramp, which the comparison takes for a rise that slows.
    periods = math.floor((t - onset) / (3.0 * period) + 1e-9) if period > 0.0 else 0
    since_onset = periods * period
    windows = [third] + ([since_onset] if periods >= 2 else [])
    for window in windows:
        rises = _window_rises(history, t, window, 3)
        decay = math.exp(-window / SENSOR_LAG_MAX)
        if rises is not None and _sustained(rises, rises, decay, least=NOISE_FLOOR):
            return True
    return False


def _sustained(rises: list[float], excess: list[float], decay: float, least: float) -> bool:
    """Each window rose by more than `least` and by an excess (its rise less what is
    explained) that is positive and beats `decay` times the window before's by more than
    the noise (`NOISE_FLOOR`): a heat still arriving, not a lagged step settling (whose
    excess shrinks by `decay` or more)."""
    if min(rises) <= least or min(excess) <= 0.0:
        return False
    pairs = itertools.pairwise(excess)
    return all(later > decay * earlier + NOISE_FLOOR for earlier, later in pairs)
