"""The FOPTD fit (commissioning.identify) on a response computed from the model's own equation."""

from __future__ import annotations

import math

import pytest

from hermsd.commissioning.identify import identify, uncertainty

K, TAU, THETA, AMBIENT, PERIOD = 1.689, 21210.0, 65.0, 20.0, 5.0


def foptd_day() -> tuple[list[float | None], list[float]]:
    """Off, full power for 8000 s, then 30 %: the exact response at each period's end.

    `duties[k]` is the duty of the span ending at sample k; it reaches the water θ later.
    Between samples the delayed duty is constant, so each step is the exact first-order
    solution: T ← T_end + (T − T_end)·e^(−Δt/τ), T_end = ambient + K·u.
    """
    duties = [0.0] + [100.0 if k * PERIOD < 8000.0 else 30.0 for k in range(1, 2000)]
    lag = round(THETA / PERIOD)
    decay = math.exp(-PERIOD / TAU)
    temp, pvs = AMBIENT, []
    for k in range(len(duties)):
        delayed = duties[k - lag] if k >= lag else 0.0
        end = AMBIENT + K * delayed
        temp = end + (temp - end) * decay
        pvs.append(temp)
    return list(pvs), duties


@pytest.mark.parametrize("ambient", [None, AMBIENT])
def test_the_fit_finds_the_model_that_made_the_response(ambient: float | None) -> None:
    # With the ambient given, the search used to stop in a side valley (θ 110 s, K −6 %).
    pvs, duties = foptd_day()
    model = identify(pvs, duties, PERIOD, ambient)
    assert model.gain == pytest.approx(K, rel=1e-4)
    assert model.tau == pytest.approx(TAU, rel=1e-3)
    assert model.dead_time == THETA
    assert model.ambient == pytest.approx(AMBIENT, abs=1e-3)
    assert model.rms < 1e-4


def test_a_noiseless_response_leaves_only_the_model_part_of_the_uncertainty() -> None:
    # A noiseless response: what is left is the model part, from moving θ by a period.
    pvs, duties = foptd_day()
    model = identify(pvs, duties, PERIOD)
    spread = uncertainty(pvs, duties, PERIOD, model)
    assert 0.0 < spread.gain < 0.01 * K
    assert spread.dead_time == PERIOD / 2  # at least half a period: θ is whole periods
