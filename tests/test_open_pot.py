"""An open pot (tun.lid off): its evaporation fitted with its physical shape, and the model at
the hold that the controller and the supervisor are given."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import pytest

from hermsd.cli import main
from hermsd.commissioning import tune
from hermsd.commissioning.identify import TunModel, identify
from hermsd.config import schema as config
from hermsd.sim import scenario

K, TAU, THETA, AMBIENT, E, PERIOD = 1.0, 10000.0, 60.0, 20.0, 16.0, 5.0
"""The walls' gain and time constant, °C/% and s; E: the evaporation at 66 °C over the
walls' losses, °C (16 °C: the family's open pots)."""


def vapour_ratio(celsius: float) -> float:
    """Water's saturation pressure at `celsius` over that at 66 °C (Magnus, written out)."""
    return math.exp(17.625 * celsius / (celsius + 243.04) - 17.625 * 66.0 / (66.0 + 243.04))


def open_pot_day(evaporation: float | None = None) -> tuple[list[float | None], list[float]]:
    """Off, full power for 6000 s, then 62 % (the duty that holds 66 °C: 46 + 16) to 9000 s,
    integrated from τ·dT/dt = −(T − ambient) + K·u(t − θ) − E·g(T) by RK4 in 0.5 s steps
    (`evaporation`: another E)."""
    e = E if evaporation is None else evaporation
    duties = [0.0] + [100.0 if k * PERIOD <= 6000.0 else 62.0 for k in range(1, 1800)]
    lag = round(THETA / PERIOD)
    temp, pvs = AMBIENT, []
    for k in range(len(duties)):
        u = duties[k - lag] if k >= lag else 0.0

        def slope(t: float, u: float = u) -> float:
            return (-(t - AMBIENT) + K * u - e * vapour_ratio(t)) / TAU

        for _ in range(10):
            h = PERIOD / 10
            k1 = slope(temp)
            k2 = slope(temp + h / 2 * k1)
            k3 = slope(temp + h / 2 * k2)
            k4 = slope(temp + h * k3)
            temp += h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        pvs.append(temp)
    return list(pvs), duties


def test_the_model_at_the_hold_is_the_static_gain_there() -> None:
    model = TunModel(K, TAU, THETA, AMBIENT, AMBIENT, 0.0, 0.0, evaporation=E)
    # At 66 °C g = 1: the duty that holds it is (46 + 16)/K = 62 %, so K_h = 46/62.
    held = model.at_hold(66.0)
    assert held.gain == pytest.approx(46 / 62, rel=1e-12)
    assert held.tau == pytest.approx(TAU * 46 / 62, rel=1e-12)
    assert held.gain / held.tau == pytest.approx(K / TAU)  # the element's rate is kept
    assert (held.dead_time, held.ambient, held.evaporation) == (THETA, AMBIENT, 0.0)
    # At 50 °C: g = e^(17.625·50/293.04 − 17.625·66/309.04) = 0.469162, K_h = 30/(30 + 16·g).
    assert model.at_hold(50.0).gain == pytest.approx(0.799859, rel=1e-5)


def test_a_lidded_model_at_the_hold_is_itself() -> None:
    model = TunModel(K, TAU, THETA, AMBIENT, AMBIENT, 0.0, 0.0)
    assert model.at_hold(66.0) is model


def test_the_fit_finds_the_open_pots_walls_and_evaporation() -> None:
    pvs, duties = open_pot_day()
    model = identify(pvs, duties, PERIOD, evaporation=True)
    assert model.gain == pytest.approx(K, rel=0.01)
    assert model.tau == pytest.approx(TAU, rel=0.01)
    assert model.evaporation == pytest.approx(E, rel=0.02)
    assert model.dead_time == pytest.approx(THETA, abs=PERIOD)
    assert model.ambient == pytest.approx(AMBIENT, abs=0.1)


@pytest.mark.parametrize("ambient", [None, AMBIENT])
def test_an_open_pot_is_tuned_to_its_gain_at_the_hold(ambient: float | None) -> None:
    pvs, duties = open_pot_day()
    tuned = tune.from_series(pvs, duties, PERIOD, ambient, open_pot_hold=66.0)
    assert tuned.model.gain == pytest.approx(46 / 62, rel=0.01)
    assert tuned.model.tau == pytest.approx(TAU * 46 / 62, rel=0.01)
    assert tuned.evaporation == pytest.approx(E, rel=0.02)
    assert (tuned.hold, tuned.confidence) == (66.0, "good")
    # The duty the written model holds 66 °C with is the pot's own, 62 %.
    m = tuned.model
    assert (66.0 - m.ambient) / m.gain == pytest.approx(62.0, rel=0.01)
    assert tuned.recommended["control.model_gain"] == pytest.approx(46 / 62, rel=0.01)


def test_without_the_lid_off_the_same_pot_is_fitted_wrong_and_called_good() -> None:
    # What tune did before tun.lid: a first-order fit that bends the room's temperature to
    # mimic the evaporation (15.9 °C), K 10.7 % above the hold's, and no warning of it.
    pvs, duties = open_pot_day()
    tuned = tune.from_series(pvs, duties, PERIOD)
    assert tuned.evaporation is None
    assert tuned.model.gain / (46 / 62) - 1 > 0.10
    assert tuned.model.ambient < AMBIENT - 3.0


def test_tune_file_reads_the_lid_from_the_logs_config(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # The default scenario's tun is first order (K 1.689, τ 14961 s, θ 115 s) and has no
    # evaporation: told the lid is off, the fit finds little and the same K and τ.
    base = config.DEFAULT
    open_pot = dataclasses.replace(base, tun=dataclasses.replace(base.tun, lid="off"))
    heat_up_and_hold = dataclasses.replace(scenario.DEFAULT, duration=2.5 * 3600.0, events=())
    scenario.run(heat_up_and_hold, open_pot, log_dir=tmp_path)
    files = [str(path) for path in sorted(tmp_path.glob("*.mcap"))]
    assert main(["tune", *files, "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["hold"] == 66.0
    # A little evaporation is traded against the room's temperature (1.1 °C of it, 0.4 °C);
    # the gain at the hold, the duty that holds it, stays within 1.5 %.
    assert abs(result["evaporation"]) < 2.0  # °C, against 46 °C of the walls' drive
    assert result["model"]["gain"] == pytest.approx(1.689, rel=0.015)
    assert result["model"]["tau"] == pytest.approx(14961.0, rel=0.03)
    assert main(["tune", *files]) == 0
    assert "an open pot (tun.lid off): K and τ are those at the hold, 66 °C" in (
        capsys.readouterr().out
    )


def test_an_open_pot_held_near_the_rooms_temperature_is_refused() -> None:
    # At 22 °C in a 20 °C room the hold's loss is 2 + 16·g(22) °C of drive: nothing to
    # measure a gain by, and below the room the "gain" would change sign.
    pvs, duties = open_pot_day()
    with pytest.raises(tune.TuneError, match=r"the setpoint 22 °C is not above the room's"):
        tune.from_series(pvs, duties, PERIOD, AMBIENT, open_pot_hold=22.0)


def test_a_lidded_fit_that_misses_the_shape_says_what_the_lid_key_would_do() -> None:
    pvs, duties = open_pot_day()
    tuned = tune.from_series(pvs, duties, PERIOD, AMBIENT)
    assert tuned.confidence.startswith("poor at 2σ: ")
    assert (
        "RMS 0.061 °C: the model does not describe the tun over this log (an open pot? with "
        "tun.lid: off its evaporation is fitted)"
    ) in tuned.confidence


def test_losses_that_shrink_as_it_warms_are_fitted_without_evaporation() -> None:
    # E < 0 is no evaporation; at the hold it would raise the gain (or divide by zero).
    pvs, duties = open_pot_day(evaporation=-8.0)
    model = identify(pvs, duties, PERIOD, evaporation=True)
    assert model.evaporation == 0.0
    assert model.at_hold(66.0) == model
    assert model == identify(pvs, duties, PERIOD)  # the lidded fit
