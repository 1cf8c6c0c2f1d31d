"""What a `reset-alarm` did, said exactly: which alarms it cleared, which stand and why.

A reset clears latched alarms only. An alarm that does not latch (over-temperature, a faulty
or stale sensor, a stalled loop) clears by itself when its cause is gone and holds the
heater off until then, whatever the brewer presses; a latched alarm raised after the brewer
looked is left for them to read first; one whose cause is still there latches again at once.
A reply that said "done" over any of these would be the lie that sends the brewer away from
a tun that is still off. One place for the words: the control socket's reply carries them to
the command line, the web page and MQTT alike.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from hermsd.safety.limits import LATCHED_KINDS, SafetyLimits


@dataclass(frozen=True, slots=True)
class ResetOutcome:
    cleared: tuple[str, ...]  # latched alarms this reset cleared
    standing: dict[str, str]  # each alarm still standing: why it stands, in words

    def text(self) -> str:
        """One line: what was cleared, what stands and why."""
        if not self.cleared and not self.standing:
            return "reset: no alarm to reset, none stands"
        said = (
            "reset: cleared " + ", ".join(self.cleared) if self.cleared else "reset: cleared none"
        )
        if not self.standing:
            return f"{said}; no alarm stands, the heater may heat again"
        why = "; ".join(f"{kind}: {reason}" for kind, reason in self.standing.items())
        return f"{said}; still standing, the heater stays off: {why}"

    def as_reply(self) -> dict[str, Any]:
        """The `reset` field of the reply to `reset-alarm`."""
        return {"cleared": list(self.cleared), "standing": self.standing, "text": self.text()}


def reset_outcome(
    asked: tuple[str, ...] | None,
    latched_before: list[str],
    standing: dict[str, str],
    limits: SafetyLimits,
) -> ResetOutcome:
    """The outcome of a reset of `asked` (None: every latched alarm), from the alarms latched
    just before it and those standing after it (`standing`: each one's message)."""
    cleared = tuple(
        kind for kind in latched_before if (asked is None or kind in asked) and kind not in standing
    )
    why = {
        kind: f"{_why_it_stands(kind, asked, latched_before, limits)} ({message})"
        for kind, message in standing.items()
    }
    return ResetOutcome(cleared, why)


def _why_it_stands(
    kind: str, asked: tuple[str, ...] | None, latched_before: list[str], limits: SafetyLimits
) -> str:
    if kind not in LATCHED_KINDS:
        return f"does not latch, so no reset clears it: it clears by itself {_clears(kind, limits)}"
    if kind in latched_before and asked is not None and kind not in asked:
        return "raised after the alarms you saw: read it, then reset again"
    return "latched again at once: its cause is still there"


def _clears(kind: str, limits: SafetyLimits) -> str:
    if kind == "over_temperature":
        return f"once the water is below {limits.max_temp - limits.hysteresis:g} °C"
    if kind == "sensor_fault":
        return f"after {limits.resume_reads} good readings in a row"
    if kind == "stale_reading":
        return "once readings come again"
    if kind == "loop_stall":
        return "once the control loop is on time again"
    return "when its cause is gone"
