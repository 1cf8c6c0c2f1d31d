"""The element's current against the SSR's command (docs/current.md): a shorted SSR or a dead
element told within a control period, where the water's temperature takes minutes.

Pure and time-injected: the daemon hands in each sample of the current input it took far
from an SSR edge, with whether the SSR was commanded on then; replay hands in the logged ones
and must find the same. The input's own faults are warnings, never alarms: the supervisor's
thermal verdicts stand beside it and hold the tun meanwhile.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from hermsd.config.schema import Config

CONFIRM_SAMPLES = 2
"""Samples in a row that must agree before a verdict: one glitch is not a fault."""
NO_SIGNAL_ON_SAMPLES = 6
"""On-samples without current, none ever seen, before the input is said to show nothing."""


@dataclass(frozen=True, slots=True)
class Sample:
    """One read of the current input: when, whether the SSR was commanded on, and what it
    said (drawing, the amps a CT measured) or why it failed (`error`)."""

    t: float
    on: bool
    drawing: bool | None
    amps: float | None = None
    error: str | None = None

    def logged(self) -> list[Any]:
        """As the period record keeps it."""
        return [self.t, self.on, self.drawing, self.amps, self.error]

    @classmethod
    def from_logged(cls, item: list[Any]) -> Sample:
        t, on, drawing, amps, error = item
        return cls(t, on, drawing, amps, error)


@dataclass(frozen=True, slots=True)
class Verdict:
    """A latched alarm the current input told."""

    kind: str
    message: str
    values: dict[str, Any]


@dataclass(frozen=True, slots=True)
class Said:
    """A line for the journal: `warning`, or news that a warning is over."""

    warning: bool
    message: str


class CurrentWatch:
    """Counts samples that contradict the SSR's command; `optocoupler` for an input that sees
    voltage across the element, not current (its words then say so)."""

    def __init__(self, fault_reads: int, threshold: float, optocoupler: bool = False) -> None:
        self._fault_reads = fault_reads
        self._threshold = threshold
        self._what = "mains across the element" if optocoupler else "current"
        self._failures = 0
        self.fault: str | None = None
        self.seen = False  # the input has shown current since the start
        self._unseen_on = 0
        self._no_signal_said = False
        self._off_drawing = 0  # off-samples in a row with current (on-samples between)
        self._on_idle = 0  # on-samples in a row without (off-samples between)

    @property
    def warning(self) -> str | None:
        """What stands against the input now, in words (its fault, or no current ever seen
        with the element on), for the status's warnings; None: it is judging, or not yet
        due to be said."""
        if self.fault is not None:
            return f"current sensor fault (the current verdicts are off): {self.fault}"
        if self._no_signal_said and not self.seen:
            return f"no {self._what} seen with the element on (the current verdicts are off)"
        return None

    @property
    def judging(self) -> bool:
        """Whether a sample can bring a verdict: the input reads and has shown current."""
        return self.fault is None and self.seen

    def sample(self, sample: Sample) -> tuple[list[Said], Verdict | None]:
        """What `sample` tells: lines to say, and a verdict after CONFIRM_SAMPLES in a row."""
        if sample.drawing is None:
            return self._failed(sample.error or "the read failed"), None
        said: list[Said] = []
        self._failures = 0
        if self.fault is not None:
            said.append(Said(False, "current sensor reads again: the current verdicts are on"))
            self.fault = None
        if sample.drawing and not self.seen:
            self.seen = True
            if self._no_signal_said:
                said.append(Said(False, "current seen: the current verdicts are on"))
        # An on-sample says nothing of a short (current flows either way), an off-sample
        # nothing of an open element: each counts only the samples of its own command.
        if sample.on:
            self._on_idle = 0 if sample.drawing else self._on_idle + 1
            if not self.seen:
                self._unseen_on += 1
                if self._unseen_on >= NO_SIGNAL_ON_SAMPLES and not self._no_signal_said:
                    self._no_signal_said = True
                    said.append(
                        Said(
                            True,
                            f"no {self._what} seen with the element on: check the current "
                            "sensor (the current verdicts are off until it shows some)",
                        )
                    )
        else:
            self._off_drawing = self._off_drawing + 1 if sample.drawing else 0
        return said, self._verdict(sample)

    def _failed(self, error: str) -> list[Said]:
        self._failures += 1
        self._off_drawing = self._on_idle = 0
        if self.fault is not None or self._failures < self._fault_reads:
            return []
        self.fault = error
        return [
            Said(
                True,
                f"current sensor fault: {error} (the current verdicts are off; the "
                "temperature's stand)",
            )
        ]

    def _verdict(self, sample: Sample) -> Verdict | None:
        if not self.judging:
            return None
        amps = "" if sample.amps is None else f" ({sample.amps:.2f} A, threshold "
        amps += "" if sample.amps is None else f"{self._threshold:g} A)"
        if self._off_drawing >= CONFIRM_SAMPLES:
            self._off_drawing = 0
            return Verdict(
                "ssr_stuck_on",
                f"the current input reads {self._what}{amps} with the SSR off, "
                f"{CONFIRM_SAMPLES} samples in a row: the SSR conducts (shorted?)",
                {"amps": sample.amps, "source": "current"},
            )
        if self._on_idle >= CONFIRM_SAMPLES:
            self._on_idle = 0
            return Verdict(
                "heater_not_heating",
                f"the current input reads no {self._what}{amps} with the SSR on, "
                f"{CONFIRM_SAMPLES} samples in a row: the element, its wiring or the current "
                "sensor",
                {"amps": sample.amps, "source": "current"},
            )
        return None


def words(said: list[Said], verdict: Verdict | None) -> list[str]:
    """What a sample told, as its period's record keeps it (`current_said`): what replay
    derives again."""
    told = [line.message for line in said]
    return told if verdict is None else [*told, f"{verdict.kind}: {verdict.message}"]


def current_watch(config: Config) -> CurrentWatch | None:
    """The watch a daemon starts with on `config` (None: no current input fitted)."""
    current = config.current
    if not current.fitted:
        return None
    return CurrentWatch(config.safety.fault_reads, current.threshold, current.kind == "gpio")
