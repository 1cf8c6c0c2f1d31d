"""bench/population.py's physical bounds, against their equations worked by hand."""

from __future__ import annotations

import math

from bench_scripts import load

POPULATION = load("population")


def test_a_sensor_with_no_lag_shows_the_waters_whole_ripple() -> None:
    assert POPULATION._lagged_peak_to_peak(0.4, 120.0, 900.0, 0.0) == 0.4


def test_a_lagging_sensor_shows_a_triangle_smoothed_as_a_first_order_lag_does() -> None:
    # Water rising and falling 0.4 °C over 600 s each (m = 0.4/600 °C/s), a lag τ = 100 s.
    # The lag's error e = x − y settles, each way, to e1 = m·τ·tanh(T/4τ) at the turn (T the
    # 1200 s cycle); the sensor turns where e crosses 0, m·τ·ln(1 + tanh(T/4τ)) s after the
    # water, which it lags by that much at each end: p-p = 0.4 − 2·m·τ·ln(1 + tanh 3).
    m, lag = 0.4 / 600.0, 100.0
    shown = 0.4 - 2.0 * m * lag * math.log(1.0 + math.tanh(1200.0 / (4.0 * lag)))
    assert abs(POPULATION._lagged_peak_to_peak(0.4, 600.0, 600.0, lag) - shown) < 1e-3
