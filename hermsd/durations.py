"""Durations as brewers write them: `90s`, `4h`, `1h30m`, `3h17m13s`, or plain seconds."""

from __future__ import annotations

import math
import re

_PART = re.compile(r"(\d+(?:\.\d+)?)([hms])")
_UNIT = {"h": 3600.0, "m": 60.0, "s": 1.0}


def parse_duration(text: str | float | int) -> float:
    """Seconds in `text`; ValueError naming what would be right."""
    if isinstance(text, bool):
        raise ValueError(f"expected a duration like 90s, 4h or 1h30m, got {text!r}")
    if isinstance(text, int | float):
        seconds = float(text)
    else:
        spec = text.strip().lower().replace(" ", "")
        try:
            seconds = float(spec)
        except ValueError:
            parts = _PART.findall(spec)
            units = [u for _, u in parts]
            if (
                not parts
                or "".join(n + u for n, u in parts) != spec
                or len(set(units)) != len(units)
                or units != sorted(units, key="hms".index)
            ):
                raise ValueError(
                    f"expected a duration like 90s, 4h, 1h30m or 3h17m13s, got {text!r}"
                ) from None
            seconds = sum(float(n) * _UNIT[u] for n, u in parts)
    if not math.isfinite(seconds) or seconds < 0:
        raise ValueError(f"a duration must be a finite number of seconds >= 0, got {text!r}")
    return seconds
