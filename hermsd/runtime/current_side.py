"""The element's current input in the loop (`current.kind`, docs/current.md): samples taken
far from any SSR edge, each judged against the SSR's command by `safety/current_watch.py`;
a verdict latches through the supervisor, the heater off at once."""

from __future__ import annotations

import logging
import math
from typing import TYPE_CHECKING, Any

from hermsd.control.factory import full_power
from hermsd.hardware.current_sense import read_and_margin, two_reads_part
from hermsd.hardware.lm92 import SensorError
from hermsd.safety.current_watch import CurrentWatch, Sample, current_watch, words

PROOF_EVERY_S = 60.0
"""s the SSR may stay commanded on without an off-sample before a window leaves it off for
one (docs/current.md, "A short behind full duty"): such a short is found within a minute, at
0.3 % of the SSR's element and 120 edges an hour while it stays fully on."""

if TYPE_CHECKING:
    from hermsd.hardware.current_sense import CurrentSense
    from hermsd.hardware.ssr import WindowPlan
    from hermsd.runtime.loop_state import LoopState
else:
    LoopState = object


def _reads_in(start: float, span: float, mains_hz: int) -> list[float]:
    """When to read in a part of a window (on, or off) from `start`, `span` s long, each read
    kept a half-cycle and EDGE_SLACK_S from its edges: at its thirds where two reads fit with
    room, else one in its middle where one fits, else none."""
    read, margin = read_and_margin(mains_hz)
    if span >= 3 * (read + margin):
        return [start + span / 3, start + 2 * span / 3]
    if span >= read + 2 * margin:
        return [start + (span - read) / 2]
    return []


class CurrentSide(LoopState):
    """The Daemon's current input: its sense, its watch and the period's samples."""

    _current_sense: CurrentSense | None
    _current_watch: CurrentWatch | None
    _current_samples: list[list[object]]
    _current_said: list[str]
    _current_last: Sample | None
    _current_off_t: float

    def _init_current(self, sense: CurrentSense | None) -> None:
        self._current_sense = sense
        self._current_watch = None if sense is None else current_watch(self.config)
        self._current_samples, self._current_said = [], []
        self._current_last = None
        self._current_off_t = -math.inf  # the last off-sample read: none yet

    def _current_times(self, plan: WindowPlan, now: float) -> list[float]:
        """When to sample in `plan` after `now`: in each of its parts, on and off, as
        `_reads_in` places a read (two mains cycles)."""
        if self._current_sense is None:
            return []
        hz = self.config.output.mains_hz
        end = plan.start + plan.length
        parts = [(plan.start, plan.on_at), (plan.on_at, plan.off_at), (plan.off_at, end)]
        times = [t for start, stop in parts for t in _reads_in(start, stop - start, hz)]
        return [t for t in times if t > now]

    def _current_gap_due(self, start: float, now: float) -> bool:
        """Whether the window from `start` must leave the SSR off for two off-samples: the
        input judges and has read none for PROOF_EVERY_S, so a short is not hidden for long
        behind an SSR held fully on while the output is not at full power (a second element
        off, the SSR's carrying the hold). Never at full power: a period short of it is no
        ramp for the heat balance, the reach watch or a ready-by heat-up, and a short there
        harms nothing until the output falls, when the first gap shows it. Not where the
        planner's least gap is too short for two reads (the config's minimums left no room);
        one longer than two reads (`output.min_off`) as much rarer, for the same share."""
        watch, planner, element2 = self._current_watch, self.planner, self.element2
        if watch is None or not watch.judging:
            return False
        hz = self.config.output.mains_hz
        gap = planner.min_off_slots * planner.half_cycle
        every = PROOF_EVERY_S * max(1.0, gap / two_reads_part(hz))
        switched2 = None if element2 is None else 100.0 * element2.state(now)[0]
        return (
            start - self._current_off_t >= every
            and len(_reads_in(0.0, gap, hz)) == 2
            and not full_power(self.config).reached(self.output, switched2)
        )

    def _sample_current(self, on: bool) -> None:
        """One sample, the SSR commanded `on`: read, judged, recorded; a verdict latched."""
        assert self._current_sense is not None
        assert self._current_watch is not None
        t = self.clock.monotonic()
        try:
            read = self._current_sense.read()
            sample = Sample(t, on, read.drawing, read.amps)
        except (SensorError, OSError) as error:
            sample = Sample(t, on, None, None, str(error) or type(error).__name__)
        said, verdict = self._current_watch.sample(sample)
        self._current_last = sample
        if not on and sample.drawing is not None:
            self._current_off_t = t
        self._current_samples.append(sample.logged())
        self._current_said += words(said, verdict)
        for line in said:
            self._event(logging.WARNING if line.warning else logging.INFO, line.message, t)
        if verdict is not None:
            self.supervisor.current_fault(t, verdict.kind, verdict.message, verdict.values)
            self._drain_alarms(t)  # the heater off at once, said, latched

    def current_status(self) -> dict[str, Any] | None:
        """The status reply's `current` (None: no input fitted): the latest sample (`on`,
        the SSR's command then; `drawing`; `amps`, None from an input that measures none;
        `age_s`), whether the input's verdicts are on (`judging`) and its `warning`."""
        watch, last = self._current_watch, self._current_last
        if watch is None:
            return None
        return {
            "on": None if last is None else last.on,
            "drawing": None if last is None else last.drawing,
            "amps": None if last is None else last.amps,
            "age_s": None if last is None else self.clock.monotonic() - last.t,
            "judging": watch.judging,
            "warning": watch.warning,
        }

    def current_fields(self) -> dict[str, Any]:
        """The period record's samples and what was said of them (None: no input fitted)."""
        if self._current_watch is None:
            return {}
        samples, said = self._current_samples, self._current_said
        self._current_samples, self._current_said = [], []
        return {"current": samples, "current_said": said}
