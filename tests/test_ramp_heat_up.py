"""A program step that ramps its setpoint is no step of known size: nothing wrong is learned.

The seed's 90 L, 3 kW tun (lid on, sensor noise sd 0.03 °C) held at 20 °C, then a step to
66 °C ramped at 1 °C/min: the output follows the ramping setpoint up from 0 % over a few
periods and only then saturates, while the sensor, a dead time behind, still shows the water
steady. Taken from the last of those duties (39 %), the step to full power looked 61 % tall
and the heat-up was measured 1/0.61 = 1.6× too fast, learned and used the next day.

The golden rate is the element's on that water, losses added back (the fit's `rate`):
P/(m·c) = 3000 W / (90 L × 4186 J/(L·K)) = 0.0079626 °C/s = 0.47776 °C/min.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from hermsd.control.learning import ModelStore
from hermsd.log import reader, replay
from hermsd.sim import scenario

TRUE_RATE = 3000.0 / (90.0 * 4186.0) * 60.0  # °C/min at full power, losses added back
PLANT = "{model: physical, litres: 90, element_watts: 3000, noise_c: 0.03, seed: 1}"


def day(directory: Path, duration: str, ramp: str) -> list[Path]:
    """The tun at 20 °C for 5 min, then 66 °C (`ramp`: the step's ramp, if any), logged and
    learning into `directory`; the log's files."""
    text = (
        f"name: r\nduration: {duration}\nplant: {PLANT}\n"
        "program: {name: R, steps: [{name: Start, setpoint: 20, hold: 5m}, "
        f'{{name: Strike, setpoint: 66, hold: "until told"{ramp}}}]}}\n'
    )
    directory.mkdir()
    path = directory / "day.yaml"
    path.write_text(text)
    scenario.run(scenario.load_scenario(path), log_dir=directory / "log", state_dir=directory)
    return sorted((directory / "log").glob("*.mcap"))


def measured(log: reader.Log) -> list[float]:
    """The heat-up rates (°C/min) the daemon said it measured."""
    events = replay.learning(log)
    said = (re.match(r"heat-up measured: rate ([0-9.]+)", e["message"]) for e in events)
    return [float(m.group(1)) for m in said if m]


def test_a_ramped_heat_up_learns_no_wrong_rate_and_its_log_verifies(tmp_path: Path) -> None:
    paths = day(tmp_path / "ramp", "2h30m", ", ramp: 1.0")
    log = reader.load(paths)
    rates = measured(log)
    assert all(abs(rate / TRUE_RATE - 1.0) <= 0.1 for rate in rates), rates
    learned, why = ModelStore(tmp_path / "ramp").load()
    assert why is None
    assert learned is None or abs(learned.rate * 60.0 / TRUE_RATE - 1.0) <= 0.1, learned
    assert replay.verify(log.entries).mismatch is None


def test_an_ordinary_heat_up_measures_the_rate_as_before(tmp_path: Path) -> None:
    paths = day(tmp_path / "step", "1h", "")
    log = reader.load(paths)
    [rate] = measured(log)
    assert rate == pytest.approx(TRUE_RATE, rel=0.02)
    assert replay.verify(log.entries).mismatch is None
