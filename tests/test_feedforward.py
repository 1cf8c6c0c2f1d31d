"""The predictive law's feed-forward of a known load (`predictive.known_load`): the holding
duty rises by the load's share of the element at once, and no load is the law unchanged."""

from __future__ import annotations

import random

import pytest

from hermsd.control import laws, predictive
from hermsd.control.pid import Controller, PlantModel

NO_DEAD_TIME = PlantModel(gain=1.689, tau=14961.0, dead_time=0.0, ambient=20.0)


def law(model: PlantModel = NO_DEAD_TIME) -> Controller:
    return laws.create("predictive", kc=20.0, ti=800.0, ts=5.0, model=model)


def test_a_load_moves_the_duty_by_its_share_of_the_element_on_its_first_step() -> None:
    plain, fed = law(), law()
    for _ in range(20):  # the same steady hold on both
        assert plain.step(66.0, 66.0) == fed.step(66.0, 66.0)
    predictive.known_load(fed, 1100.0, 5500.0)  # 1100/5500·100 = 20 %
    assert fed.step(66.0, 66.0) - plain.step(66.0, 66.0) == pytest.approx(20.0, abs=1e-9)


def run_with_load(tell: bool) -> tuple[float, float, float]:
    """A tun exactly as the model says, held at 66 °C, from which 20 % of the element is drawn
    from period 100 on: (the bias before the load, the bias 1000 periods later, six times the
    observer's bias time constant, and the largest drop of the PV below 66)."""
    model, ts = NO_DEAD_TIME, 5.0
    controller = law()
    controller.reset(66.0, 100.0 * (66.0 - model.ambient) / (model.tau * model.rate))
    pv, drop, before = 66.0, 0.0, 0.0
    for k in range(1100):
        load = 20.0 if k >= 100 else 0.0
        if tell:
            predictive.known_load(controller, load * 55.0, 5500.0)
        if k == 100:
            before = controller._bias  # type: ignore[attr-defined]
        u = controller.step(66.0, pv)
        pv += ts * (model.rate * (u - load) / 100.0 - (pv - model.ambient) / model.tau)
        drop = max(drop, 66.0 - pv)
    return before, controller._bias, drop  # type: ignore[attr-defined]


def test_a_load_the_model_knows_is_not_learned_again_as_a_loss() -> None:
    before, after, drop = run_with_load(tell=True)
    assert after == pytest.approx(before, abs=1e-9) and drop < 1e-6
    # Untold, the bias takes the load up as a loss: −rate·20/100 °C/s
    before, after, drop = run_with_load(tell=False)
    assert after - before == pytest.approx(-NO_DEAD_TIME.rate * 0.2, rel=0.05) and drop > 0.05


@pytest.mark.parametrize("dead_time", [0.0, 115.0])
def test_no_load_leaves_every_decision_bit_for_bit_as_it_was(dead_time: float) -> None:
    model = PlantModel(1.689, 14961.0, dead_time, 20.0)
    plain, told = law(model), law(model)
    rng = random.Random(7)
    pv = 20.0
    for k in range(3000):
        sp = 66.0 if k < 2000 else 72.0
        pv += rng.gauss(0.0, 0.05) + (0.02 if pv < sp else -0.01)
        predictive.known_load(told, 0.0, 5500.0)
        a, b = plain.step(sp, pv), told.step(sp, pv)
        assert (a, plain.terms) == (b, told.terms)
        assert repr(a) == repr(b)


def test_a_load_of_an_element_of_no_power_is_refused() -> None:
    with pytest.raises(ValueError, match="element's power > 0"):
        predictive.known_load(law(), 100.0, 0.0)
