"""An outside plant (`--plant`) that fails during a run: the heater off, then one line that
names the plant and what it did, and a non-zero exit; never a traceback, never an Infinity."""

from __future__ import annotations

from pathlib import Path

import pytest

from hermsd.cli import commands as cli

PLANT = """
import math
import sys
from hermsd.sim.hlt import PhysicalPlant

FAIL_AFTER = 600.0

class Reads(PhysicalPlant):
    def __init__(self, value):
        super().__init__()
        self.value = value
    def temperature(self, t):
        return self.value if t > FAIL_AFTER else super().temperature(t)

class Raises(PhysicalPlant):
    def temperature(self, t):
        if t > FAIL_AFTER:
            raise RuntimeError("probe fell off")
        return super().temperature(t)

class HeaterRaises(PhysicalPlant):
    def set_heater(self, on, t):
        if t > FAIL_AFTER:
            raise OSError("relay gone")
        super().set_heater(on, t)

def nan(): return Reads(math.nan)
def inf(): return Reads(math.inf)
def text(): return Reads("hot")
def none(): return Reads(None)
def raises(): return Raises()
def heater(): return HeaterRaises()
def leaves(): sys.exit(0)
"""

FAILURES = [
    ("nan", "temperature(", "returned nan"),
    ("inf", "temperature(", "returned inf"),
    ("text", "temperature(", "returned 'hot'"),
    ("none", "temperature(", "returned None"),
    ("raises", "temperature(", "raised RuntimeError: probe fell off"),
    ("heater", "set_heater(", "raised OSError: relay gone"),
]


@pytest.fixture
def plant_file(tmp_path: Path) -> Path:
    path = tmp_path / "tun.py"
    path.write_text(PLANT, encoding="utf-8")
    return path


@pytest.fixture
def short_scenario(tmp_path: Path) -> Path:
    path = tmp_path / "short.yaml"
    path.write_text("duration: 1h\nsetpoint: 30\n", encoding="utf-8")  # cycling by then
    return path


def _said_once(err: str, plant: str, call: str, what: str) -> None:
    assert "Traceback" not in err
    assert f"INFO heater off: stopped (plant '{plant}': {call}" in err
    line = err.strip().splitlines()[-1]  # after the log's lines
    assert line.startswith(f"hermsd: plant '{plant}': {call}") and what in line


@pytest.mark.parametrize(("factory", "call", "what"), FAILURES, ids=[f[0] for f in FAILURES])
def test_simulate_stops_with_the_heater_off_and_names_the_plant(
    plant_file: Path,
    short_scenario: Path,
    capsys: pytest.CaptureFixture[str],
    factory: str,
    call: str,
    what: str,
) -> None:
    plant = f"{plant_file}:{factory}"
    code = cli.main(["simulate", "--json", "--scenario", str(short_scenario), "--plant", plant])
    out, err = capsys.readouterr()
    assert code != 0 and out == ""  # no summary, so no Infinity in it either
    _said_once(err, plant, call, what)


@pytest.mark.parametrize(("kind", "factory"), [("step", "nan"), ("relay", "heater")])
def test_tune_stops_with_the_heater_off_and_names_the_plant(
    plant_file: Path,
    capsys: pytest.CaptureFixture[str],
    kind: str,
    factory: str,
) -> None:
    plant = f"{plant_file}:{factory}"
    code = cli.main(["tune", kind, "--simulate", "--plant", plant])
    _out, err = capsys.readouterr()
    assert code != 0
    _said_once(err, plant, *dict((f[0], f[1:]) for f in FAILURES)[factory])


def test_a_factory_that_exits_is_an_error(
    plant_file: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = cli.main(["simulate", "--plant", f"{plant_file}:leaves"])
    _out, err = capsys.readouterr()
    assert code != 0
    assert err.strip() == f"hermsd: plant '{plant_file}:leaves': leaves() failed: SystemExit: 0"
