"""How well each step of a mash program was held, from the period records alone.

Used by `hermsd replay` (from the log) and `hermsd simulate` (from the run): the periods of
one step are those in a row that name it. A step is reached at its first period whose PV is
within ±BAND of the setpoint asked for, once that setpoint is the step's own (after a ramp);
from then on, the time in the band (each period counts until the next one) and the largest
deviation from the setpoint say how well it was held. A program scheduled for later
(`ready_by`, heater off) is in no step until it starts heating.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Sequence
from typing import Any, Protocol

from hermsd.metrics import BAND


class StepRecord(Protocol):
    """What a period record gives (hermsd.runtime.daemon.PeriodRecord)."""

    @property
    def setpoint(self) -> float: ...

    @property
    def pv(self) -> float | None: ...

    @property
    def step(self) -> str | None: ...

    @property
    def step_index(self) -> int | None: ...

    @property
    def state(self) -> str: ...


def step_quality(rows: Iterable[tuple[float, StepRecord]]) -> list[dict[str, Any]]:
    """One entry per step run, in order: index, name, setpoint, start_s, reached_s,
    end_s, in_band_s, max_deviation_c (times in the rows' own seconds)."""
    timed = list(rows)
    steps: list[dict[str, Any]] = []
    position = 0
    current: tuple[int | None, str | None] = (None, None)

    def step_of(row: tuple[float, StepRecord]) -> tuple[int | None, str | None]:
        """A program scheduled for later is in no step yet; a heat-up that waits again
        (heater off: it started early) stays in its step."""
        nonlocal current
        record = row[1]
        step = (record.step_index, record.step)
        if record.state != "scheduled" or step != current:
            current = (None, None) if record.state == "scheduled" else step
        return current

    for key, group in itertools.groupby(timed, key=step_of):
        members = list(group)
        position += len(members)
        if key[0] is None:
            continue
        end = timed[position][0] if position < len(timed) else members[-1][0]
        steps.append(_one_step(key[0], str(key[1]), members, end))
    return steps


def _one_step(
    index: int, name: str, members: Sequence[tuple[float, StepRecord]], end: float
) -> dict[str, Any]:
    target = members[-1][1].setpoint
    reached: float | None = None
    in_band = 0.0
    worst: float | None = None
    ends = [t for t, _ in members[1:]] + [end]
    for (t, record), until in zip(members, ends, strict=True):
        pv = record.pv
        if reached is None:
            if pv is None or record.setpoint != target or abs(pv - target) > BAND:
                continue
            reached = t
        if pv is None:
            continue
        deviation = abs(pv - record.setpoint)
        worst = deviation if worst is None else max(worst, deviation)
        if deviation <= BAND:
            in_band += until - t
    return {
        "index": index,
        "name": name,
        "setpoint": target,
        "start_s": round(members[0][0], 1),
        "reached_s": None if reached is None else round(reached, 1),
        "end_s": round(end, 1),
        "in_band_s": round(in_band, 1),
        "max_deviation_c": None if worst is None else round(worst, 3),
    }


def step_lines(steps: Sequence[dict[str, Any]]) -> list[str]:
    """The steps in words, one line each, for the summaries."""
    lines = []
    for step in steps:
        reached = "never reached" if step["reached_s"] is None else f"reached {step['reached_s']} s"
        held = step["end_s"] - (
            step["reached_s"] if step["reached_s"] is not None else step["end_s"]
        )
        worst = step["max_deviation_c"]
        lines.append(
            f"step {step['index'] + 1} {step['name']!r} ({step['setpoint']:g} °C): from "
            f"{step['start_s']} s, {reached}, to {step['end_s']} s; in ±{BAND:g} °C "
            f"{step['in_band_s']:g} s of {held:g} s, max deviation "
            + ("--" if worst is None else f"{worst:.3f} °C")
        )
    return lines
