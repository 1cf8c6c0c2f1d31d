"""Durations as brewers write them: `90s`, `4h`, `1h30m`, `3h17m13s`, or plain seconds.

Where a brewer counts in minutes (a mash program's rests), a bare number is refused with
both of its readings: `60` could be the hour-long rest meant or one minute.
"""

from __future__ import annotations

import math
import re

_PART = re.compile(r"(\d+(?:\.\d+)?)([hms])")
_UNIT = {"h": 3600.0, "m": 60.0, "s": 1.0}
_BARE = re.compile(r"\d+(?:\.\d+)?")


class NoUnit(ValueError):
    """A bare number where the duration must say its unit."""


def no_unit(number: str) -> str:
    """What to write instead of the bare `number`: both of its readings."""
    return (
        f"{number} has no unit (write {number}m for {number} minutes, "
        f"or {number}s for {number} seconds)"
    )


def parse_duration(text: str | float | int, *, unit_required: bool = False) -> float:
    """Seconds in `text`; ValueError naming what would be right.

    A bare number is seconds, unless `unit_required`: then NoUnit, which shows both readings.
    """
    if isinstance(text, bool):
        raise ValueError(f"expected a duration like 90s, 4h or 1h30m, got {text!r}")
    if isinstance(text, int | float):
        if unit_required:
            raise NoUnit(no_unit(f"{text:g}"))
        seconds = float(text)
    else:
        spec = text.strip().lower().replace(" ", "")
        if unit_required and _BARE.fullmatch(spec):
            raise NoUnit(no_unit(spec))
        try:
            seconds = float(spec)
        except ValueError:
            seconds = math.nan
        if unit_required or math.isnan(seconds):  # with units: 1e3 or inf is no duration
            seconds = _seconds_of_parts(spec, text)
    if not math.isfinite(seconds) or seconds < 0:
        raise ValueError(f"a duration must be a finite number of seconds >= 0, got {text!r}")
    return seconds


def _seconds_of_parts(spec: str, text: object) -> float:
    """Seconds in `spec`, hours, minutes and seconds in that order, each at most once."""
    parts = _PART.findall(spec)
    units = [u for _, u in parts]
    if (
        not parts
        or "".join(n + u for n, u in parts) != spec
        or len(set(units)) != len(units)
        or units != sorted(units, key="hms".index)
    ):
        raise ValueError(f"expected a duration like 90s, 4h, 1h30m or 3h17m13s, got {text!r}")
    return sum(float(n) * _UNIT[u] for n, u in parts)
