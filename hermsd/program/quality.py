"""How well each step of a mash program was held, from the period records alone.

Used by `hermsd replay` (from the log) and `hermsd simulate` (from the run): the periods of
one step are those in a row that name it. A step is reached at its first period whose PV is
within ±BAND of the setpoint asked for, once that setpoint is the step's own (after a ramp);
from then on, the time in the band (each period counts until the next one) and the largest
deviation from the setpoint say how well it was held. A program scheduled for later
(`ready_by`, heater off) is in no step until it starts heating.

A rest on the mash (a step from `mash_from` on, in records that hold the mash's reading) is
judged on the mash too, as the brewer's rest is: when the mash reached the band, how long it
was within ±MASH_TIGHT of the setpoint from MASH_SETTLE_S after that (the time before is the
mash still levelling out, which the HLT's swing and the coil decide), and its overshoot: how
far past the setpoint it went after reaching the band, in the way it came from.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Sequence
from typing import Any, Protocol

from hermsd.metrics import BAND

MASH_TIGHT = 0.3  # °C: a rest held this close is held as the recipe means it
MASH_SETTLE_S = 300.0  # s after the mash reached the band before it is judged that closely


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

    @property
    def mash(self) -> float | None: ...


def step_quality(
    rows: Iterable[tuple[float, StepRecord]], mash_from: int = 0
) -> list[dict[str, Any]]:
    """One entry per step run, in order: index, name, setpoint, start_s, reached_s,
    end_s, in_band_s, max_deviation_c (times in the rows' own seconds); and `mash` for a
    rest on the mash (step `mash_from` on, with mash readings: `_on_mash`)."""
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
        step = _one_step(key[0], str(key[1]), members, end)
        mash = _on_mash(members, end) if key[0] >= mash_from else None
        if mash is not None:
            step["mash"] = mash
        steps.append(step)
    return steps


def mash_from_events(events: Iterable[tuple[str, int | None]]) -> int:
    """The first step on the mash, from a log's program events (event, step): the second
    when the first waited for the brewer (its "Mash in"), else the first."""
    return 1 if any(e in ("waiting", "confirmed") and i == 0 for e, i in events) else 0


def _on_mash(members: Sequence[tuple[float, StepRecord]], end: float) -> dict[str, Any] | None:
    """The rest as the mash had it (None: no mash reading in it): reached_s, tight_s of
    judged_s (the time within ±MASH_TIGHT, from MASH_SETTLE_S after reached to the end),
    overshoot_c (None: never reached)."""
    readings = [r.mash for _, r in members if r.mash is not None]
    if not readings:
        return None
    target = members[-1][1].setpoint
    rising = readings[0] <= target
    ends = [t for t, _ in members[1:]] + [end]
    reached: float | None = None
    tight = overshoot = 0.0
    for (t, record), until in zip(members, ends, strict=True):
        mash = record.mash
        if mash is None:
            continue
        if reached is None:
            if record.setpoint != target or abs(mash - target) > BAND:
                continue
            reached = t
        overshoot = max(overshoot, (mash - target) if rising else (target - mash))
        judged_from = max(t, reached + MASH_SETTLE_S)
        if until > judged_from and abs(mash - target) <= MASH_TIGHT:
            tight += until - judged_from
    judged = 0.0 if reached is None else max(0.0, end - reached - MASH_SETTLE_S)
    return {
        "reached_s": None if reached is None else round(reached, 1),
        "tight_s": round(tight, 1),
        "judged_s": round(judged, 1),
        "overshoot_c": None if reached is None else round(overshoot, 3),
    }


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
        mash = step.get("mash")
        if mash is not None:
            lines.append(f"  mash: {_mash_words(mash)}")
    return lines


def _mash_words(mash: dict[str, Any]) -> str:
    """'reached 1234.5 s, within ±0.3 °C 900 s of 900 s from 5 min after, overshoot 0.12 °C'."""
    if mash["reached_s"] is None:
        return f"never within ±{BAND:g} °C"
    return (
        f"reached {mash['reached_s']} s, within ±{MASH_TIGHT:g} °C {mash['tight_s']:g} s of "
        f"{mash['judged_s']:g} s from {MASH_SETTLE_S / 60:g} min after, overshoot "
        f"{mash['overshoot_c']:.3f} °C"
    )
