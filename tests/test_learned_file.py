"""A stored learned model the controller cannot take, or that cannot be this tun's, is
ignored with a warning (the config's prior in force), at start and in check-config alike.

The default config: 3000 W into 90 L, a full-power rate of 3000 / (4186 · 90) = 0.00796 °C/s
(0.478 °C/min): a heat-up's fit is taken within ¼–4× of it, 0.00199–0.0319 °C/s, and the
limits hold for a fill of 45–180 L.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hermsd.cli import commands as cli
from hermsd.control.learning import LEARNED_FILE

GOOD = {"rate": 0.008, "loss": 1 / 15000, "dead_time": 115.0, "ambient": 20.0, "litres": 90.0}
RUN = ["run", "--simulate", "--speed", "max", "--duration", "10s", "--state"]

BAD = {
    "a room of 500 °C": ({"ambient": 500.0}, "room 500 °C is not within −100…100 °C"),
    "60 °C/min": (
        {"rate": 1.0},
        "full-power rate 60 °C/min at 90 L is not within ¼–4× of the 0.478 °C/min",
    ),
    "3 °C/min": (
        {"rate": 0.05},
        "full-power rate 3 °C/min at 90 L is not within ¼–4× of the 0.478 °C/min",
    ),
    "a third of the fill": (
        {"rate": 0.02, "litres": 30.0},
        "fill 30 L is not within half to twice the configured 90 L",
    ),
}


@pytest.mark.parametrize(("edit", "why"), BAD.values(), ids=BAD)
def test_a_learned_model_out_of_bounds_is_ignored_by_run_and_check_config_alike(
    tmp_path: Path, edit: dict[str, float], why: str, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / LEARNED_FILE).write_text(json.dumps(GOOD | edit), encoding="utf-8")
    said = f"learned model ignored: {tmp_path / LEARNED_FILE}: {why}"

    assert cli.main([*RUN, str(tmp_path)]) == 0
    _out, err = capsys.readouterr()
    assert "Traceback" not in err
    assert said in err
    assert "tun model in use" not in err  # the prior: nothing measured

    config = tmp_path / "hermsd.yaml"
    config.write_text("tun: {litres: 90, element_watts: 3000}\n", encoding="utf-8")
    assert cli.main(["check-config", str(config), "--simulate", "--state", str(tmp_path)]) == 0
    out, _err = capsys.readouterr()
    assert f"# {said}" in out
    assert "# safety limits in force (nothing measured yet):" in out


def test_a_learned_model_within_bounds_is_used(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / LEARNED_FILE).write_text(json.dumps(GOOD), encoding="utf-8")

    assert cli.main([*RUN, str(tmp_path)]) == 0
    _out, err = capsys.readouterr()
    assert "learned model ignored" not in err
    assert "tun model in use (control and safety limits): learned: full-power rate 0.480" in err
