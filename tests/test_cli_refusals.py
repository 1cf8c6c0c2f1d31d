"""Input that a library below would have raised on: refused up front with one clear line."""

from __future__ import annotations

from pathlib import Path

import pytest

from hermsd import cli


@pytest.mark.parametrize("name", ["day.xyz", "day.mcap"])
def test_replay_refuses_a_plot_format_matplotlib_cannot_write_before_reading_the_log(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], name: str
) -> None:
    plot = tmp_path / name
    code = cli.main(["replay", str(tmp_path / "missing.mcap"), "--plot", str(plot)])
    _out, err = capsys.readouterr()
    assert code == cli.EXIT_USAGE
    suffix = name.rpartition(".")[2]
    assert err.startswith(f"hermsd: --plot {plot}: cannot draw a .{suffix} file")
    assert ".png" in err and ".svg" in err and ".pdf" in err
    assert not plot.exists()


@pytest.mark.parametrize(
    "table",
    [
        "K=1e308,tau=1e308,theta=1e308",  # overflows the rules to inf
        "K=1,tau=1e30,theta=1",  # finite, but past the 28 digits a setting is rounded in
        "K=1,tau=10,theta=1,a_star=1e-300",  # Kc from a*: 1/(a*·θ)
    ],
)
def test_tune_table_refuses_a_tun_whose_settings_no_tun_needs(
    capsys: pytest.CaptureFixture[str], table: str
) -> None:
    code = cli.main(["tune", "--table", table])
    out, err = capsys.readouterr()
    assert code != 0 and out == ""
    assert err.startswith(f"hermsd: --table: {table}: the rules give settings beyond 1e+12")
