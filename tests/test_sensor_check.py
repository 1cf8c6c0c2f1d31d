"""`hermsd sensor --kind ds18b20|max31865`: readings, traps as one line each, --decode."""

from __future__ import annotations

from pathlib import Path

import pytest

from hermsd.cli import commands as cli
from hermsd.cli import hardware as cli_hardware
from hermsd.sim.w1 import FakeW1Tree


@pytest.fixture(autouse=True)
def no_sleep(monkeypatch: pytest.MonkeyPatch) -> list[float]:
    slept: list[float] = []
    monkeypatch.setattr(cli_hardware.time, "sleep", slept.append)
    return slept


@pytest.mark.parametrize("kind", ["ds18b20", "max31865"])
def test_the_simulated_sensor_of_each_kind(kind: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["sensor", "--kind", kind, "--simulate", "--count", "3"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 1 + 3
    assert all("°C" in line for line in lines[1:])


def test_every_ds18b20_found_is_read_and_a_trap_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    tree = FakeW1Tree(tmp_path)
    good = tree.add("28-000000000001", lambda: 21.5)
    bad = tree.add("28-000000000002", lambda: 21.5)
    good.convert()
    bad.set_fault("zeros")
    bad.convert()
    assert (
        cli.main(["sensor", "--kind", "ds18b20", "--w1-root", str(tmp_path), "--count", "1"]) == 1
    )
    out = capsys.readouterr().out.splitlines()
    assert out == [
        f"2 DS18B20 under {tmp_path}",
        "28-000000000001   21.5000 °C  raw 0x0158",
        "28-000000000002  bad reading: DS18B20 28-000000000002: all-zero scratchpad (its CRC "
        "passes and reads 0 °C): the data line is shorted to ground, check DQ against GND",
    ]


def test_no_ds18b20_is_one_line_on_how_to_enable_1_wire(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert cli.main(["sensor", "--kind", "ds18b20", "--w1-root", str(tmp_path)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and "dtoverlay=w1-gpio" in err[0]


def test_decode_an_rtd_register(capsys: pytest.CaptureFixture[str]) -> None:
    # 0x3b88: code 7620 → 7620/32768 × 430 = 99.9939 Ω → −0.0156 °C (worked in test_max31865)
    assert cli.main(["sensor", "--kind", "max31865", "--decode", "0x3b88"]) == 0
    assert capsys.readouterr().out == (
        "0x3b88: code 7620, 99.9939 Ω, -0.0156 °C (PT100, reference 430 Ω)\n"
    )
    assert cli.main(["sensor", "--kind", "max31865", "--decode", "0x3b89"]) == 1
    assert "fault bit (D0) is set" in capsys.readouterr().out


def test_the_lm92_check_is_unchanged(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["sensor", "--simulate", "--count", "1"]) == 0
    assert capsys.readouterr().out.startswith("LM92 found at 0x48 on simulated bus")
