"""The period's process value from its readings."""

from __future__ import annotations

import pytest

from hermsd.control.pv import period_value


def test_a_glitch_is_dropped() -> None:
    assert period_value([60.0, 60.0625, 75.0, 60.0]) == pytest.approx(60.0625 / 3 + 40.0)


def test_an_even_count_with_no_reading_near_the_median_gives_the_median() -> None:
    # Median 60.5 lies 0.5 from both middle readings: none within 0.25 of it. This used to
    # divide by zero in the control loop (a noisy sensor stopped the daemon).
    assert period_value([60.0, 60.0, 61.0, 61.0]) == 60.5


def test_no_readings_no_value() -> None:
    assert period_value([]) is None
