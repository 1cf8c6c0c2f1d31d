"""How long until the next rest starts, by the tun's model: heating at full power up to a
warmer step, cooling with the heater off down to a cooler one (72 → 64 °C), in the program's
status (`rest_in_s`) for the page, `hermsd status` and the MQTT bridge. Golden values from the
first-order step response by hand: heater off, the water falls as y = Ta + (y0 − Ta)·e^(−t/τ)."""

from __future__ import annotations

import datetime as dt
import math

import pytest

from hermsd.cli.remote import program_line
from hermsd.control.pid import PlantModel
from hermsd.program.driver import ProgramDriver
from hermsd.program.model import Program, Step
from hermsd.program.readiness import Tun
from hermsd.program.runner import MashReading, reach_s

PERIOD = 5.0
WALL_NS = 1_795_834_800 * 1_000_000_000
MODEL = PlantModel(gain=1.0, tau=1000.0, dead_time=100.0, ambient=20.0)  # 1 °C per %, τ 1000 s
TUN = Tun(MODEL, 100.0, measured=True, fit=None)
STEP_DOWN = Program("Step down", (Step("Alpha", 72.0, 600.0), Step("Beta", 64.0, 1800.0)))
STEP_UP = Program("Step up", (Step("Beta", 64.0, 600.0), Step("Alpha", 72.0, 1800.0)))


def _next_step(program: Program, pv: float) -> ProgramDriver:
    """`program` reached at `pv` (its first step) and told to go on to its second."""
    driver = ProgramDriver(None, dt.UTC, PERIOD)
    driver.start(program, None, setpoint=pv, wall_ns=WALL_NS, pv=pv, tun=TUN)
    driver.period(0.0, pv, WALL_NS, TUN, 30.0, False)
    driver.command("next", pv)
    return driver


def _status(driver: ProgramDriver, pv: float, mash: MashReading | None = None) -> dict[str, object]:
    driver.period(PERIOD, pv, WALL_NS, TUN, 0.0, False, mash)
    status = driver.status(WALL_NS)
    assert status is not None
    return status


def test_stepping_down_the_rest_starts_when_the_water_has_cooled_to_the_band() -> None:
    driver = _next_step(STEP_DOWN, 72.0)
    status = _status(driver, 72.0)
    assert status["state"] == "heating" and status["step"] == {
        "index": 1,
        "name": "Beta",
        "setpoint": 64.0,
    }
    # Heater off from 72 °C in a 20 °C room to the band's top, 64.5 °C: τ·ln(52 / 44.5).
    assert status["rest_in_s"] == pytest.approx(1000.0 * math.log(52.0 / 44.5))


def test_stepping_up_the_rest_starts_after_the_dead_time_and_the_rise() -> None:
    driver = _next_step(STEP_UP, 64.0)
    # Full power settles at 120 °C; from 64 °C to 71.5 °C once θ has passed:
    # τ·ln((K·u·e^(θ/τ) − (64 − 20)) / (20 + 100 − 71.5)).
    expected = 1000.0 * math.log((100.0 * math.exp(0.1) - 44.0) / 48.5)
    assert _status(driver, 64.0)["rest_in_s"] == pytest.approx(expected)


def test_no_estimate_while_holding_paused_on_the_mash_or_short_of_the_band() -> None:
    driver = _next_step(STEP_UP, 64.0)
    assert _status(driver, 71.8)["rest_in_s"] is None  # reached: holding
    paused = _next_step(STEP_UP, 64.0)
    paused.command("pause", 64.0)
    assert _status(paused, 64.0)["rest_in_s"] is None
    weak = PlantModel(gain=0.5, tau=1000.0, dead_time=100.0, ambient=20.0)  # full power: 70 °C
    assert reach_s(weak, 100.0, 64.0, 71.5) is None
    assert reach_s(MODEL, 0.0, 72.0, 19.0) is None  # the room is warmer than that


def test_a_step_timed_on_the_mash_has_no_estimate_from_the_hlts_model() -> None:
    driver = _next_step(STEP_UP, 64.0)  # a mash sensor fitted: the steps are timed on it
    assert _status(driver, 75.0, MashReading(64.0))["rest_in_s"] is None


@pytest.mark.parametrize(
    ("rest_in_s", "words"),
    [
        (720.0, ", rest in about 12 min"),
        (749.0, ", rest in about 12 min"),  # 12.48 min: whole minutes, as the page rounds
        (59.0, ", rest in under a minute"),
        (3900.0, ", rest in about 1 h 5 min"),
    ],
)
def test_the_status_line_says_when_the_rest_starts(rest_in_s: float, words: str) -> None:
    state = _status(_next_step(STEP_UP, 64.0), 64.0)
    assert state["rest_in_s"] is not None  # heating towards the step: the daemon estimates
    line = program_line({**state, "rest_in_s": rest_in_s})
    assert line.startswith("program 'Step up': heating, step 2/2 'Alpha' at 72 °C")
    assert words in line and line.count("rest in") == 1


def test_the_status_line_says_nothing_of_a_rest_without_an_estimate() -> None:
    holding = _status(_next_step(STEP_UP, 64.0), 71.8)
    assert holding["rest_in_s"] is None
    assert "rest in" not in program_line(holding)
    assert "rest in" not in program_line({**holding, "rest_in_s": None})
