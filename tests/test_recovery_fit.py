"""A recovery's rate is fitted over at least `RECOVERY_FIT_PERIODS`.

On the small 30 L, 5.5 kW tun the PV climbs some 0.2 °C a period after cold water, so the
first 1 °C span holds five periods; the line over those alone missed the rate by a few %
from one noise seed to the next, and the cut from full power landed the water too low or
too high. Now each further full-power period adds its PV and refits, up to 12 or the cut.
The goldens below come from the line's least squares on the truncated ramp, by hand, not
from the code under test. A day of cold water on that tun, its recovery refitted so, is
re-run bit for bit by `replay --verify` in test_cold_water.
"""

from __future__ import annotations

import math

import pytest

from hermsd.control import pid, watches

TS = 5.0
SP = 66.0
HOLD = 20.0  # % that held the setpoint before the water
SLOPE = 0.04  # °C/s the PV climbs at full power (no losses: loss = 0)
TRUE_RATE = SLOPE * 100.0 / (100.0 - HOLD)  # the rate the hold's duty left to climb with
LOW = 61.5  # °C: the dip's bottom


def lsb(x: float) -> float:
    """The LM92's reading: truncated to its 0.0625 °C step."""
    return math.floor(x / pid.SENSOR_LSB) * pid.SENSOR_LSB


def ramp(periods: int) -> list[float]:
    """The PV of each full-power period: the dip's bottom for two periods, then the ramp
    (the mean over a period of a line is its middle), truncated to the LSB."""
    return [lsb(LOW + max(0.0, (k - 1.5) * TS * SLOPE)) for k in range(periods)]


def worst_slope_error(times: list[float]) -> float:
    """°C/s: the most that readings each truncated by up to one LSB can tilt a least-squares
    line through `times`: all low on one side of the mean time, all exact on the other."""
    mean = sum(times) / len(times)
    spread = sum((t - mean) ** 2 for t in times)
    return pid.SENSOR_LSB * sum(abs(t - mean) for t in times) / 2.0 / spread


def fed(periods: int) -> list[tuple[float, float] | None]:
    """The watch's answers to `periods` of full power."""
    watch = watches._RecoveryWatch()
    pvs = ramp(periods)
    watch.arm(pvs[0], HOLD)
    # The controller feeds the watch while it is active and full power runs.
    return [watch.add(pv, TS, SP, 0.0) if watch.active else None for pv in pvs]


def test_the_rate_is_refitted_every_period_up_to_the_fewest_periods() -> None:
    pvs = ramp(30)
    fits = fed(30)
    # The fit's points: from the first period 1 °C above the dip on (period 7: 61.5 + 1.1);
    # the first fit comes the period the PV is more than 2 °C above it (period 12, the 6th
    # point), and one more every period after, up to the 12th point (period 18).
    first_in = next(k for k, pv in enumerate(pvs) if pv >= LOW + pid.FIT_FROM)
    first_fit = next(k for k, pv in enumerate(pvs) if pv > LOW + 2.0)
    assert (first_in, first_fit, pid.RECOVERY_FIT_PERIODS) == (7, 12, 12)
    assert [f is not None for f in fits] == [12 <= k <= 18 for k in range(30)]
    periods = 19
    last = fits[periods - 1]
    assert last is not None
    times = [(k + 0.5) * TS for k in range(first_in, periods)]
    bound = worst_slope_error(times) * 100.0 / (100.0 - HOLD)
    # The LSB's worst tilt over all the periods to the cut is under half that over the first
    # span's alone (1/n² for n periods).
    first_span = worst_slope_error(times[: first_fit - first_in]) * 100.0 / (100.0 - HOLD)
    assert bound < first_span / 2.0
    assert last[0] == pytest.approx(TRUE_RATE, abs=bound)
    # Where the estimate stands before the last step: the ramp's PV a period before, within
    # the LSB (the line's mean) and the tilt from the mean time.
    before = times[-2]
    truth = LOW + (periods - 3.5) * TS * SLOPE
    tilt = worst_slope_error(times) * (before - sum(times) / len(times))
    assert last[1] == pytest.approx(truth, abs=pid.SENSOR_LSB + tilt)
