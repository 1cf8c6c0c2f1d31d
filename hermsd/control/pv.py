"""The process value for a control period, from that period's readings.

The LM92 is read about once a second and the controller runs every few seconds, so each
period has several readings. Their mean has finer resolution than one 0.0625 °C step; a
single glitch that slipped past the supervisor's checks is dropped by comparing each
reading with the period's median first.
"""

from __future__ import annotations

import statistics

GLITCH_BAND = 0.25  # °C from the period's median: four LSBs, far above the chip's noise


def period_value(readings: list[float]) -> float | None:
    """Mean of the readings that agree with the median; None for no readings.

    With an even count the median lies between two readings, and when those two are more
    than twice GLITCH_BAND apart no reading agrees with it: then the median itself.
    """
    if not readings:
        return None
    if len(readings) < 3:
        return sum(readings) / len(readings)
    middle = statistics.median(readings)
    kept = [r for r in readings if abs(r - middle) <= GLITCH_BAND]
    return sum(kept) / len(kept) if kept else middle
