"""hermsd tune: Table 2 of seed 001, the model of a logged brew day, the settings it writes."""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import stat
from pathlib import Path
from typing import Any

import pytest

from hermsd.cli import main
from hermsd.commissioning import tune
from hermsd.config import read
from hermsd.config import schema as config_module
from hermsd.config.file import ConfigFile, at_once
from hermsd.log import reader
from hermsd.sim import scenario
from hermsd.sim.scenario import Scenario
from hermsd.sim.world import simulated_daemon

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


# -- tune FILE ----------------------------------------------------------------------------------

# The default scenario's tun (hermsd.sim.hlt.FoptdPlant's defaults): seed 001's numbers.
TRUE_GAIN, TRUE_TAU, TRUE_DEAD_TIME = 1.689, 14961.0, 115.0
PERIOD = 5.0


def logged_day(directory: Path, scene: Scenario) -> list[str]:
    scenario.run(scene, log_dir=directory)
    return [str(path) for path in sorted(directory.glob("*.mcap"))]


@pytest.fixture(scope="module")
def brew_day(tmp_path_factory: pytest.TempPathFactory) -> list[str]:
    return logged_day(tmp_path_factory.mktemp("day"), scenario.DEFAULT)


def tune_json(capsys: pytest.CaptureFixture[str], files: list[str]) -> dict[str, Any]:
    code, out, err = run_cli(capsys, *files, "--json")
    assert (code, err) == (0, "")
    result: dict[str, Any] = json.loads(out)
    return result


def test_tune_finds_the_simulated_tun_in_an_ordinary_brew_day(
    capsys: pytest.CaptureFixture[str], brew_day: list[str]
) -> None:
    result = tune_json(capsys, brew_day)
    model = result["model"]
    assert model["gain"] == pytest.approx(TRUE_GAIN, rel=0.02)
    assert model["tau"] == pytest.approx(TRUE_TAU, rel=0.03)
    # PV is the mean of a period's readings, half a period behind its end.
    assert abs(model["dead_time"] - TRUE_DEAD_TIME) <= PERIOD
    assert model["ambient"] == pytest.approx(20.0, abs=0.5)
    assert result["a_star"] == pytest.approx(model["gain"] / model["tau"])
    assert result["confidence"] == "good"
    assert result["recommended"] == {
        "control.model_gain": pytest.approx(model["gain"], rel=1e-3),
        "control.model_tau": round(model["tau"]),
        "control.dead_time": model["dead_time"],
        "control.model_ambient": pytest.approx(model["ambient"], abs=0.05),
        "control.model_litres": result["logged_litres"],  # with what water it was measured
    }
    assert result["logged_litres"] == 90.0
    # Table 1 for the fitted model: ZN open loop from a* = K/τ equals ZN closed loop.
    rules = result["rules"]
    assert rules[0]["kc"] == pytest.approx(rules[2]["kc"])
    assert rules[6]["kc"] == pytest.approx(
        1.357 / model["gain"] * (model["dead_time"] / model["tau"]) ** -0.947
    )
    # 3 kW into the seed's K and τ is C = τ·P/(100·K) = 265.7 kJ/K, 63.5 L of water.
    assert result["implied_litres"] == pytest.approx(63.5, rel=0.03)


def test_tune_prints_the_model_table_and_settings(
    capsys: pytest.CaptureFixture[str], brew_day: list[str]
) -> None:
    code, out, err = run_cli(capsys, *brew_day)
    assert (code, err) == (0, "")
    assert out.startswith("tun model (fitted to the first 14")
    for line in ("Table 1 for this model:", "recommended settings:", "  control.model_gain: 1.6"):
        assert any(printed.startswith(line) for printed in out.splitlines()), line


def test_a_measured_room_temperature_is_held(
    capsys: pytest.CaptureFixture[str], brew_day: list[str]
) -> None:
    code, out, err = run_cli(capsys, *brew_day, "--ambient", "20", "--json")
    assert (code, err) == (0, "")
    model = json.loads(out)["model"]
    assert model["ambient"] == 20.0
    assert model["gain"] == pytest.approx(TRUE_GAIN, rel=0.02)


def test_noise_widens_the_stated_uncertainty(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, brew_day: list[str]
) -> None:
    quiet = tune_json(capsys, brew_day)["uncertainty"]
    noisy_plant = {"model": "foptd", "noise_c": 0.2, "seed": 3}
    noisy_day = logged_day(tmp_path, Scenario(plant=noisy_plant))
    capsys.readouterr()  # the simulated daemon's own log lines
    noisy = tune_json(capsys, noisy_day)["uncertainty"]
    # The ambient's spread is the noise part alone (the model part moves only K and τ).
    assert noisy["ambient"] > 3 * quiet["ambient"]
    assert noisy["gain"] > quiet["gain"]
    assert noisy["tau"] > quiet["tau"]


@pytest.mark.parametrize(
    ("scene", "says"),
    [
        (
            Scenario(duration=200.0, events=()),
            "40 periods with a PV before the first disturbance, at least 60 needed",
        ),
        (
            Scenario(duration=1800.0, events=(), config={"control": {"mode": "manual"}}),
            "the log is a manual-only day (360 periods at 0 to 0 %)",
        ),
        (
            Scenario(duration=1800.0, events=(), setpoint=15.0),
            "no heat-up in the log: the duty stayed between 0 and 0 %",
        ),
    ],
)
def test_a_day_that_cannot_be_tuned_says_what_is_missing(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, scene: Scenario, says: str
) -> None:
    code, out, err = run_cli(capsys, *logged_day(tmp_path, scene))
    assert (code, out) == (2, "")
    assert err.count("\n") == 1
    assert says in err


@pytest.mark.parametrize("value", ["nan", "inf", "51", "-21"])
def test_a_room_temperature_out_of_range_is_refused(
    capsys: pytest.CaptureFixture[str], brew_day: list[str], value: str
) -> None:
    code, out, err = run_cli(capsys, *brew_day, "--ambient", value)
    assert (code, out) == (2, "")
    assert "the room's temperature in °C, -20 to 50" in err


def test_tune_wants_files_or_a_table(capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run_cli(capsys)
    assert code == 2
    assert "give either the log files of a brew day or --table" in err


# -- --write ------------------------------------------------------------------------------------

SHIPPED = Path(__file__).parent.parent / "config" / "hermsd.yaml"
MODEL_KEYS = ("model_gain", "model_tau", "dead_time", "model_ambient", "model_litres")


@pytest.fixture
def config_copy(tmp_path: Path) -> Path:
    path = tmp_path / "hermsd.yaml"
    path.write_bytes(SHIPPED.read_bytes())
    path.chmod(0o640)
    if os.geteuid() == 0:  # as installed: root's file, readable by the daemon's group
        os.chown(path, 0, 65534)
    return path


def test_write_changes_only_the_recommended_values(
    capsys: pytest.CaptureFixture[str], brew_day: list[str], config_copy: Path
) -> None:
    running = ConfigFile(config_copy, start=at_once)
    running.load()
    code, out, err = run_cli(capsys, *brew_day, "--write", str(config_copy), "--json")
    assert (code, err) == (0, "")
    result = json.loads(out)
    before = SHIPPED.read_bytes().splitlines(keepends=True)
    after = config_copy.read_bytes().splitlines(keepends=True)
    assert len(after) == len(before)
    changed = [(old, new) for old, new in zip(before, after, strict=True) if old != new]
    # Every other line (comments, blank lines, 0x48, null, the section order) byte for byte.
    assert sorted(old.split(b":")[0].strip().decode() for old, _ in changed) == sorted(MODEL_KEYS)
    for old, new in changed:
        assert new.split(b":")[0] == old.split(b":")[0]  # same key, same indentation
    config = read.load(config_copy)  # passes the config check
    for key in MODEL_KEYS:
        assert getattr(config.control, key) == result["recommended"][f"control.{key}"]
    assert stat.S_IMODE(config_copy.stat().st_mode) == 0o640
    if os.geteuid() == 0:  # the group that reads it is kept, not root's own
        assert (config_copy.stat().st_uid, config_copy.stat().st_gid) == (0, 65534)
    assert result["written"]["diff"].count("\n-  ") == 5
    # A running daemon sees the new file as it sees any edit.
    reloaded = running.poll()
    assert isinstance(reloaded, config_module.Config)
    assert reloaded.control.model_tau == result["recommended"]["control.model_tau"]


def test_write_shows_the_diff_and_says_when_nothing_changes(
    capsys: pytest.CaptureFixture[str], brew_day: list[str], config_copy: Path
) -> None:
    code, out, _ = run_cli(capsys, *brew_day, "--write", str(config_copy))
    assert code == 0
    assert f"--- {config_copy}" in out and "+  model_tau: " in out
    code, out, _ = run_cli(capsys, *brew_day, "--write", str(config_copy))
    assert code == 0
    assert out.rstrip().endswith(f"{config_copy}: already so")


def test_a_tune_that_fails_leaves_the_file_unchanged(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, config_copy: Path
) -> None:
    manual = Scenario(duration=1800.0, events=(), config={"control": {"mode": "manual"}})
    files = logged_day(tmp_path / "logs", manual)
    capsys.readouterr()
    before = config_copy.stat()
    code, out, err = run_cli(capsys, *files, "--write", str(config_copy))
    assert (code, out) == (2, "")
    assert "manual-only day" in err
    after = config_copy.stat()
    assert (after.st_ino, after.st_mtime_ns) == (before.st_ino, before.st_mtime_ns)
    assert config_copy.read_bytes() == SHIPPED.read_bytes()
    assert sorted(os.listdir(config_copy.parent)) == ["hermsd.yaml", "logs"]  # no .tmp left


def test_a_poor_fit_is_not_written(brew_day: list[str], config_copy: Path) -> None:
    tuned = tune.from_log(reader.load(brew_day))
    assert tuned.confidence == "good"
    poor = dataclasses.replace(tuned, confidence="poor at 2σ: K ±30 %")
    with pytest.raises(tune.TuneError, match=r"left as it is: the fit is poor at 2σ: K ±30 %"):
        tune.write_tuned(config_copy, poor)
    assert config_copy.read_bytes() == SHIPPED.read_bytes()


def test_values_the_config_refuses_are_not_written(config_copy: Path) -> None:
    # An ambient of 80 °C is outside control.model_ambient's -20 to 50.
    with pytest.raises(tune.TuneError, match=r"would not be a valid config.*model_ambient"):
        tune.write_config(config_copy, {"control.model_ambient": 80.0})
    assert config_copy.read_bytes() == SHIPPED.read_bytes()


def test_a_planted_temporary_symlink_is_not_written_through(config_copy: Path) -> None:
    # Where the temporary file was once always made: a link there to another file.
    victim = config_copy.parent / "victim"
    victim.write_text("the victim's own text\n", encoding="utf-8")
    victim.chmod(0o600)
    planted = config_copy.with_name(config_copy.name + ".tmp")
    planted.symlink_to(victim)
    tune.write_config(config_copy, {"control.model_gain": 1.0})
    assert victim.read_text(encoding="utf-8") == "the victim's own text\n"
    assert stat.S_IMODE(victim.stat().st_mode) == 0o600
    assert planted.is_symlink() and os.readlink(planted) == str(victim)
    assert "model_gain: 1.0" in config_copy.read_text(encoding="utf-8")
    assert stat.S_IMODE(config_copy.stat().st_mode) == 0o640  # the original's, kept
    assert sorted(os.listdir(config_copy.parent)) == ["hermsd.yaml", "hermsd.yaml.tmp", "victim"]


def test_a_read_only_config_is_refused_and_left_as_it_is(
    capsys: pytest.CaptureFixture[str], brew_day: list[str], config_copy: Path
) -> None:
    config_copy.chmod(0o444)  # root may write it; the mode says nobody should
    before = config_copy.stat()
    code, out, err = run_cli(capsys, *brew_day, "--write", str(config_copy))
    assert (code, out) == (2, "")
    assert err == (
        f"hermsd: {config_copy}: the config file is read-only (mode 0444): nothing written; "
        "make it writable (chmod u+w) to let tune write it, or leave out --write\n"
    )
    after = config_copy.stat()
    assert (after.st_ino, after.st_mtime_ns, after.st_mode) == (
        before.st_ino,
        before.st_mtime_ns,
        before.st_mode,
    )
    assert config_copy.read_bytes() == SHIPPED.read_bytes()
    assert os.listdir(config_copy.parent) == ["hermsd.yaml"]


def test_a_broken_config_is_not_edited(config_copy: Path) -> None:
    config_copy.write_text("control:\n  kc: fast\n", encoding="utf-8")
    with pytest.raises(tune.TuneError, match=r"is not a valid config now; fix it first"):
        tune.write_config(config_copy, {"control.model_gain": 1.0})
    assert config_copy.read_text(encoding="utf-8") == "control:\n  kc: fast\n"


def test_after_write_the_next_start_uses_the_written_model(
    capsys: pytest.CaptureFixture[str],
    caplog: pytest.LogCaptureFixture,
    brew_day: list[str],
    config_copy: Path,
) -> None:
    before = simulated_daemon(read.load(config_copy), math.inf)
    assert before.model_choice.source == "prior" and before.supervisor.limits.dead_time == 300.0
    code, out, _ = run_cli(capsys, *brew_day, "--write", str(config_copy), "--json")
    assert code == 0
    written = json.loads(out)["recommended"]
    caplog.set_level(logging.INFO, logger="hermsd")
    hermsd_log = logging.getLogger("hermsd")  # the CLI run above may have stopped propagation
    hermsd_log.addHandler(caplog.handler)
    try:
        daemon = simulated_daemon(read.load(config_copy), math.inf)
        daemon.start()
    finally:
        hermsd_log.removeHandler(caplog.handler)
    gain, tau, theta = (
        written[f"control.{key}"] for key in ("model_gain", "model_tau", "dead_time")
    )
    # Measured at the configured 90 L: the controller's model is the written one as it stands.
    assert daemon.model_choice.source == "measured"
    assert (daemon.model.gain, daemon.model.tau) == (pytest.approx(gain), pytest.approx(tau))
    assert (daemon.model.dead_time, daemon.model.ambient) == (
        theta,
        written["control.model_ambient"],
    )
    said = [r.getMessage() for r in caplog.records]
    assert any(
        m.startswith("tun model in use (control and safety limits): measured by hermsd tune")
        for m in said
    ), said
    # The supervisor's limits from it, as from a learned model: judged after 1.5·θ (not the
    # 300 s any tun may need), losses bounded by 1.5/τ, the weakest rise 0.8·0.81·(100·K/τ)/1.5.
    limits = daemon.supervisor.limits
    assert limits.dead_time == pytest.approx(max(60.0, 1.5 * theta))
    assert limits.loss_per_k == pytest.approx(1.5 / tau)
    assert limits.heater_rise_rate == pytest.approx(0.8 * 0.81 * 100.0 * gain / tau / 1.5)
    assert dict(limits.origins)["heater_rise_rate"] == "measured"


def test_a_log_without_the_litres_is_written_with_the_files(
    brew_day: list[str], config_copy: Path
) -> None:
    tuned = tune.from_log(reader.load(brew_day))
    unknown = {k: v for k, v in tuned.recommended.items() if k != "control.model_litres"}
    config_copy.write_text("tun:\n  litres: 45\n", encoding="utf-8")
    tune.write_tuned(config_copy, dataclasses.replace(tuned, recommended=unknown))
    assert read.load(config_copy).control.model_litres == 45.0


def _changed_lines(before: str, after: str) -> list[tuple[str, str]]:
    old, new = before.splitlines(keepends=True), after.splitlines(keepends=True)
    assert len(new) == len(old)
    return [(a, b) for a, b in zip(old, new, strict=True) if a != b]


def test_write_keeps_the_brewers_own_layout_byte_for_byte() -> None:
    events = "\n".join(f"  - {e}" for e in config_module.ALERT_EVENTS)
    long_command = (
        '  command: ["/usr/local/bin/notify-brewer-with-a-long-name", "--channel", '
        '"brewery-alerts", "--verbose"]'
    )
    text = (
        SHIPPED.read_text(encoding="utf-8")
        .replace(events, events.replace("  - ", "    - "))  # a list indented further
        .replace("  command: null", long_command)  # a line longer than 80 characters
        .replace("  dead_time: 115.0", "  dead_time: 115.0   # measured in October")
        .replace("\ntun:\n", "\ntun:   \n")  # trailing spaces
    )
    assert text.count("    - ") == len(config_module.ALERT_EVENTS)
    written = tune.updated_config(text, "hermsd.yaml", {"control.dead_time": 42.5})
    assert _changed_lines(text, written) == [
        (
            "  dead_time: 115.0   # measured in October\n",
            "  dead_time: 42.5   # measured in October\n",
        )
    ]


def test_write_keeps_windows_line_ends() -> None:
    text = SHIPPED.read_text(encoding="utf-8").replace("\n", "\r\n")
    written = tune.updated_config(text, "hermsd.yaml", {"control.model_litres": 45.0})
    assert _changed_lines(text, written) == [
        ("  model_litres: null\r\n", "  model_litres: 45.0\r\n")
    ]


def test_a_key_the_file_lacks_gets_a_line_at_the_end_of_its_section() -> None:
    text = (
        "tun:\n    litres: 90\n    # the element\n    element_watts: 3000\n"
        "\n# sensor\nsensor:\n  address: 0x48\n"
    )
    written = tune.updated_config(
        text, "hermsd.yaml", {"tun.name": "HLT", "control.model_litres": 90.0}
    )
    assert written == (
        "tun:\n    litres: 90\n    # the element\n    element_watts: 3000\n"
        '    name: "HLT"\n'
        "\n# sensor\nsensor:\n  address: 0x48\n"
        "control:\n  model_litres: 90.0\n"
    )
