"""hermsd tune: Table 2 of seed 001, the model of a logged brew day, the settings it writes."""

from __future__ import annotations

import json

import pytest

from hermsd import tune
from hermsd.cli import main

SEED_MODEL = "K=1.689,tau=14961,theta=115,a_star=6.68e-5"

# Table 2 of the PID calculus document, as printed (decimal commas): Kc, Ti, Td, form.
SEED_TABLE_2 = """\
Ziegler-Nichols Open Loop	156,2	230,0	57,5	PID
	117,2	383,0	--	PI
Ziegler-Nichols Closed Loop	92,4	230,0	57,5	PID
	69,3	383,0	--	PI
Cohen-Coon	102,8	282,2	41,8	PID
	69,4	377,2	--	PI
ITAE-Load	80,8	489,0	44,9	PID
	59,2	810,2	--	PI
"""


def run_cli(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(["tune", *argv])
    out, err = capsys.readouterr()
    return code, out, err


def seed_rows() -> list[list[str]]:
    """The seed's rows as cells: method (blank on a PI row), Kc, Ti, Td, form."""
    return [line.replace(",", ".").split("\t") for line in SEED_TABLE_2.splitlines()]


def test_table_reproduces_table_2_of_the_seed_to_every_printed_digit(
    capsys: pytest.CaptureFixture[str],
) -> None:
    code, out, err = run_cli(capsys, "--table", SEED_MODEL)
    assert (code, err) == (0, "")
    lines = out.splitlines()
    header = next(i for i, line in enumerate(lines) if "Kc [%/°C]" in line)
    printed = lines[header + 1 :]
    assert len(printed) == len(seed_rows())
    for line, (method, kc, ti, td, form) in zip(printed, seed_rows(), strict=True):
        assert line.startswith(method)
        assert line[len(method) :].split()[:4] == [kc, ti, td, form]


def test_table_says_which_numbers_each_rule_uses(capsys: pytest.CaptureFixture[str]) -> None:
    _, out, _ = run_cli(capsys, "--table", SEED_MODEL)
    uses = {
        line.split("  ")[0]: line.rsplit("PID", 1)[1].strip()
        for line in out.splitlines()
        if line.endswith(("a*", "θ"))
    }
    # Table 1: the open-loop Ziegler–Nichols rules take the slope, the others the FOPTD.
    assert uses == {
        "Ziegler-Nichols Open Loop": "θ, a*",
        "Ziegler-Nichols Closed Loop": "K, τ, θ",
        "Cohen-Coon": "K, τ, θ",
        "ITAE-Load": "K, τ, θ",
    }


def test_table_names_the_seeds_inconsistent_slope(capsys: pytest.CaptureFixture[str]) -> None:
    # The seed's a* = 6.68e-5 is 0.59 of its own K/τ = 1.689/14961 = 1.129e-4.
    _, out, _ = run_cli(capsys, "--table", SEED_MODEL)
    assert "a* is 0.59 × K/τ = 0.000113" in out
    _, out, _ = run_cli(capsys, "--table", "K=1.689,tau=14961,theta=115,a_star=1.13e-4")
    assert "note" not in out


def test_383_is_the_decimal_value_rounded_half_up() -> None:
    # Ti of the PI Ziegler–Nichols rows is 3.33·115 = 382.95 exactly; the double is
    # 382.9499…, which '%.1f' prints 382.9; the seed's spreadsheet printed 383.0.
    assert f"{3.33 * 115.0:.1f}" == "382.9"
    assert tune.printed(3.33 * 115.0) == "383.0"
    assert tune.printed(-0.25) == "-0.3"
    assert tune.printed(102.84) == "102.8"


def test_table_without_a_star_uses_k_over_tau(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run_cli(capsys, "--table", "K=2,tau=10000,theta=100", "--json")
    assert code == 0
    result = json.loads(out)
    assert result["model"]["a_star"] == pytest.approx(2e-4)
    assert result["model"]["a_star_given"] is False
    zn_open_pid = result["rules"][0]
    # 1.2 / (θ·a*) = 1.2 / (100 · 2e-4) = 60 %/°C, the same as the closed-loop 1.2·τ/(K·θ).
    assert (zn_open_pid["method"], zn_open_pid["form"]) == ("Ziegler-Nichols Open Loop", "PID")
    assert zn_open_pid["kc"] == pytest.approx(60.0)
    assert result["rules"][2]["kc"] == pytest.approx(60.0)
    assert result["rules"][1]["td"] is None


@pytest.mark.parametrize(
    ("spec", "says"),
    [
        ("K=1.689,tau=14961", "theta missing"),
        ("K=1.689,tau=0,theta=115", "tau='0': tau must be a number > 0 s"),
        ("K=1.689,tau=14961,theta=nan", "theta='nan'"),
        ("K=1.689,tau=14961,theta=115,gain=3", "'gain=3' is not key=value with a key of K"),
        ("K=1,K=2,tau=1,theta=1", "K is given twice"),
        ("K 1.689", "'K 1.689' is not key=value"),
    ],
)
def test_bad_table_input_is_one_line_and_exit_2(
    capsys: pytest.CaptureFixture[str], spec: str, says: str
) -> None:
    code, out, err = run_cli(capsys, "--table", spec)
    assert (code, out) == (2, "")
    assert err.count("\n") == 1
    assert says in err
