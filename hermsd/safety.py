"""The safety supervisor: decides, from readings and outputs alone, whether the heater may be on.

Pure and time-injected: the daemon feeds it every sensor read, every control period and the
loop's lateness, and obeys `heater_allowed`. Two kinds of fault:

- auto-recovering (sensor fault, stale reading, over-temperature, loop stall): the heater is
  off while they last and control resumes by itself, bumplessly, once they clear;
- latched (element not heating, SSR stuck on, dry fire, stuck sensor): the heater stays off
  until someone resets the alarm, because each means the hardware is not what the loop
  believes it is.

Defaults scale with the tun: the fastest rise the element can cause is P / (m·c).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Any

WATER_HEAT_CAPACITY = 4186.0  # J/(kg·K); a litre of water is taken as 1 kg
FULL_POWER = 80.0  # % at or above which the element is expected to heat visibly
SUDDEN_DROP = 0.25  # °C in one period: water was added, not lost to the room

AUTO_KINDS = ("sensor_fault", "stale_reading", "over_temperature", "loop_stall")
LATCHED_KINDS = ("heater_not_heating", "ssr_stuck_on", "dry_fire", "sensor_stuck")


@dataclass(frozen=True, slots=True)
class SafetyLimits:
    """Every threshold the supervisor uses, in SI units (°C, s, %)."""

    max_temp: float = 95.0
    hysteresis: float = 5.0
    plausible_min: float = -10.0
    plausible_max: float = 110.0
    max_step: float = 2.0
    fault_reads: int = 2
    resume_reads: int = 5
    stale_after: float = 3.0
    heater_watch: float = 300.0
    heater_min_rise: float = 0.5
    ssr_watch: float = 300.0
    ssr_max_rise: float = 0.5
    full_rate: float = 0.008
    dry_fire_rate: float = 0.024
    dry_fire_window: float = 60.0
    stuck_time: float = 600.0
    stuck_output_change: float = 40.0
    stall_after: float = 10.0

    @classmethod
    def derive(
        cls,
        *,
        litres: float,
        element_watts: float,
        period: float,
        read_interval: float,
        max_temp: float = 95.0,
        hysteresis: float = 5.0,
        plausible_min: float = -10.0,
        plausible_max: float = 110.0,
        max_step: float | None = None,
        fault_reads: int = 2,
        resume_reads: int = 5,
        stale_after: float | None = None,
        heater_watch: float | None = None,
        heater_min_rise: float | None = None,
        ssr_watch: float | None = None,
        ssr_max_rise: float | None = None,
        dry_fire_factor: float = 3.0,
        stuck_time: float = 600.0,
        stuck_output_change: float = 40.0,
        stall_periods: float = 2.0,
    ) -> SafetyLimits:
        """Limits for a tun of `litres` heated by `element_watts`; None means derive it."""
        full_rate = element_watts / (litres * WATER_HEAT_CAPACITY)  # °C/s at 100 %
        heater_watch = heater_watch if heater_watch is not None else 300.0
        ssr_watch = ssr_watch if ssr_watch is not None else 300.0
        return cls(
            max_temp=max_temp,
            hysteresis=hysteresis,
            plausible_min=plausible_min,
            plausible_max=plausible_max,
            # Only a dump of cold water moves the sensor this far within one read.
            max_step=max_step if max_step is not None else 2.0,
            fault_reads=fault_reads,
            resume_reads=resume_reads,
            stale_after=stale_after if stale_after is not None else 3.0 * read_interval,
            heater_watch=heater_watch,
            # A quarter of what 80 % power would add with no losses: losses at mash
            # temperatures take about a third of the element, dead time the first minutes.
            heater_min_rise=(
                heater_min_rise
                if heater_min_rise is not None
                else 0.25 * FULL_POWER / 100.0 * full_rate * heater_watch
            ),
            ssr_watch=ssr_watch,
            # Margin over what the delivered heat can explain: eight LSBs are not noise.
            ssr_max_rise=ssr_max_rise if ssr_max_rise is not None else 0.5,
            full_rate=full_rate,
            dry_fire_rate=dry_fire_factor * full_rate,
            dry_fire_window=max(60.0, 4 * period),
            stuck_time=stuck_time,
            stuck_output_change=stuck_output_change,
            stall_after=stall_periods * period,
        )


@dataclass(frozen=True, slots=True)
class Alarm:
    """A fault raised or cleared: what, when, and the values that showed it."""

    kind: str
    at: float
    message: str
    latched: bool
    raised: bool = True
    values: dict[str, Any] = field(default_factory=dict)


class _Watch:
    """A rising-edge window: the lowest PV since it began, and when that low was seen."""

    __slots__ = ("base", "base_t", "start")

    def __init__(self) -> None:
        self.start: float | None = None
        self.base = math.inf
        self.base_t = 0.0

    def stop(self) -> None:
        self.start = None

    def restart(self, t: float, pv: float) -> None:
        self.start = t
        self.base, self.base_t = pv, t


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
        self._previous_value: float | None = None
        self._last_raw: int | None = None
        self._heater_watch = _Watch()
        self._energy: deque[tuple[float, float, float]] = deque()  # (t, pv, full-power s)
        self._last_period_t: float | None = None
        self._wrong_chip = False
        self._history: deque[tuple[float, float]] = deque()
        self._raw_since: float | None = None
        self._output_swing = _OutputSwing()

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
        self._energy.clear()
        self._history.clear()
        self._raw_since = None
        self._output_swing.clear(None)
        return cleared

    # -- inputs ---------------------------------------------------------------------------

    def reading(self, t: float, celsius: float, raw: int | None = None, crit: bool = False) -> bool:
        """A value the sensor returned; True when it is accepted as a measurement."""
        lim = self.limits
        if self._wrong_chip:
            return False
        previous, self._previous_value = self._previous_value, celsius
        if not lim.plausible_min <= celsius <= lim.plausible_max:
            self._bad(t, f"implausible reading {celsius:.4f} °C", {"celsius": celsius})
            return False
        last = self._last_accepted
        # A jump is accepted only when the read before it agrees: a lone spike is dropped,
        # a real step (cold water) is believed one read later.
        if (
            last is not None
            and abs(celsius - last) > lim.max_step
            and (previous is None or abs(celsius - previous) > lim.max_step)
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

    def period(self, t: float, pv: float | None, output: float, applied: float) -> None:
        """Once per control period: the checks that need a history of PV and output."""
        if pv is None:
            return
        self._check_dry_fire(t, pv)
        self._check_heater(t, pv, applied)
        self._check_ssr(t, pv, applied)
        if self.heater_allowed:
            self._check_stuck(t, output)
        else:
            self._output_swing.clear(self._raw_since)  # a forced 0 % is not the controller

    # -- the period checks ----------------------------------------------------------------

    def _check_dry_fire(self, t: float, pv: float) -> None:
        lim = self.limits
        history = self._history
        history.append((t, pv))
        while history and t - history[0][0] > lim.dry_fire_window:
            history.popleft()
        t0, pv0 = history[0]
        span = t - t0
        if span >= lim.dry_fire_window * 0.99 and (pv - pv0) / span > lim.dry_fire_rate:
            self._raise(
                "dry_fire",
                t,
                f"rising {(pv - pv0) / span * 60:.2f} °C/min, more than the water allows "
                f"({lim.dry_fire_rate * 60:.2f} °C/min)",
                {"rate_c_per_s": (pv - pv0) / span},
            )

    def _check_heater(self, t: float, pv: float, applied: float) -> None:
        lim, watch = self.limits, self._heater_watch
        if applied < FULL_POWER:
            watch.stop()
            return
        if watch.start is None:
            watch.restart(t, pv)
            return
        if pv < watch.base:
            # A sudden drop (cold water) starts the wait again from the new low; a slow fall
            # (an element that does not heat, losing to the room) does not.
            if watch.base - pv > SUDDEN_DROP:
                watch.base_t = t
            watch.base = pv
            return
        if pv >= watch.base + lim.heater_min_rise:
            watch.restart(t, pv)
            return
        if t - watch.base_t >= lim.heater_watch:
            # A working sensor on a dead element still shows the water cooling, a step every
            # minute or two; a stuck one has shown nothing for most of the watch.
            since = self._raw_since
            frozen = since is not None and t - since >= 0.75 * lim.heater_watch
            kind = "sensor_stuck" if frozen else "heater_not_heating"
            what = (
                "the reading has not changed at all"
                if frozen
                else f"PV rose {pv - watch.base:.2f} °C"
            )
            self._raise(
                kind,
                t,
                f"output at {applied:.0f} % for {t - watch.base_t:.0f} s but {what} "
                f"(expected at least {lim.heater_min_rise:.2f} °C)",
                {"rise_c": pv - watch.base, "applied": applied},
            )

    def _check_ssr(self, t: float, pv: float, applied: float) -> None:
        """Heat the element did not deliver: the rise exceeds all the energy it was given.

        Losses only ever take heat away, so over a watch window the water can rise at most by
        the element's delivered energy over m·c. Energy from the window before is counted too,
        because heat reaches the sensor late. More rise than that means something else is
        heating: an SSR that failed shorted.
        """
        lim, history = self.limits, self._energy
        previous, self._last_period_t = self._last_period_t, t
        dt = 0.0 if previous is None else t - previous
        history.append((t, pv, applied / 100.0 * dt))
        while t - history[0][0] > 2 * lim.ssr_watch:
            history.popleft()
        if t - history[0][0] < 2 * lim.ssr_watch - dt:
            return
        pv_then = next(p for when, p, _ in history if when >= t - lim.ssr_watch)
        full_power_s = sum(e for _, _, e in history)
        allowed = lim.full_rate * full_power_s + lim.ssr_max_rise
        if pv - pv_then > allowed:
            self._raise(
                "ssr_stuck_on",
                t,
                f"PV rose {pv - pv_then:.2f} °C in {lim.ssr_watch:.0f} s, more than the "
                f"{full_power_s:.0f} s of full power delivered can explain ({allowed:.2f} °C)",
                {"rise_c": pv - pv_then, "allowed_c": allowed},
            )

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
