"""What `check-config` and `run` say about files that are not config files, or not for them."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from hermsd.cli import common, run
from hermsd.config import file as config_file
from hermsd.config.read import MAX_FILE_BYTES, SHIPPED_FILE_MAX_BYTES
from hermsd.config.schema import ConfigError, OutputConfig


def check_config(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "hermsd.cli", "check-config", *args],
        capture_output=True,
        text=True,
        timeout=30,
    )


def test_files_that_are_not_regular_files_are_refused_without_reading(tmp_path: Path) -> None:
    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)  # reading it would wait for a writer forever
    huge = tmp_path / "huge.yaml"
    huge.touch()
    os.truncate(huge, 50_000_000)  # reading it would cost 50 MB and tens of seconds
    cases = {
        "/dev/zero": "/dev/zero: is a character device, not a regular file (name the YAML "
        "file itself)",
        str(fifo): f"{fifo}: is a FIFO (named pipe), not a regular file (name the YAML file "
        "itself)",
        str(tmp_path): f"{tmp_path}: is a directory, not a regular file (name the YAML file "
        "itself)",
        str(huge): f"{huge}: is 50000000 bytes long, more than the 64 KiB a config file may "
        "be (the shipped one is under 16 KiB: is this the right file?)",
    }
    for path, message in cases.items():
        proc = check_config(path)
        assert (proc.returncode, proc.stdout, proc.stderr) == (2, "", message + "\n")


def test_the_shipped_file_is_far_below_the_cap_its_message_compares_with() -> None:
    # The refusal tells a user the shipped file is under a quarter of the cap: it must be.
    shipped = Path(__file__).parent.parent / "config" / "hermsd.yaml"
    assert SHIPPED_FILE_MAX_BYTES == MAX_FILE_BYTES // 4 == 16 * 1024
    assert os.path.getsize(shipped) < SHIPPED_FILE_MAX_BYTES


def test_a_file_of_the_largest_size_is_read(tmp_path: Path) -> None:
    cfg = tmp_path / "hermsd.yaml"
    text = "control:\n  setpoint: 64.0\n"
    cfg.write_text(text + "#" * (MAX_FILE_BYTES - len(text) - 1) + "\n")
    assert os.path.getsize(cfg) == MAX_FILE_BYTES
    proc = check_config(str(cfg))
    assert proc.returncode == 0 and "setpoint: 64.0" in proc.stdout


SIMULATED = "output:\n  backend: sim\nlog:\n  dir: null\n"


def test_check_config_refuses_the_simulated_output_unless_checking_for_simulation(
    tmp_path: Path,
) -> None:
    cfg = tmp_path / "hermsd.yaml"
    cfg.write_text(SIMULATED)
    proc = check_config(str(cfg))
    assert (proc.returncode, proc.stdout) == (2, "")
    assert proc.stderr == (
        f"{cfg}:2:3: output.backend: 'sim' is the simulated tun's output, which `hermsd run` "
        "uses only with --simulate (choose serial-rts, serial-dtr or gpio for the tun, or "
        "check a file for simulation with check-config --simulate)\n"
    )
    simulated = check_config("--simulate", str(cfg))
    assert simulated.returncode == 0 and "backend: sim" in simulated.stdout


def test_run_on_hardware_with_the_simulated_output_says_what_to_do(tmp_path: Path) -> None:
    cfg = tmp_path / "hermsd.yaml"
    cfg.write_text(SIMULATED)
    proc = subprocess.run(
        [sys.executable, "-m", "hermsd.cli", "run", "--config", str(cfg), "--state", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert proc.returncode == 2
    assert proc.stderr == (
        f"hermsd: {cfg}: output.backend is 'sim', the simulated tun's output: run with "
        "--simulate, or choose serial-rts, serial-dtr or gpio for the tun\n"
    )


def test_a_gpio_output_without_gpiod_names_its_line_and_the_extra(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setitem(sys.modules, "gpiod", None)  # as when the extra is not installed
    with pytest.raises(common.UserError) as caught:
        run._open_output(OutputConfig(backend="gpio", line=17))
    assert str(caught.value) == (
        "cannot open gpio line 17 of /dev/gpiochip0: the gpio backend needs the gpiod "
        "package, which is not installed (install the gpio extra: `uv sync --extra gpio`, "
        "or `pip install 'hermsd[gpio]'`)"
    )


def test_a_fault_in_checking_an_edit_refuses_it_and_keeps_the_loop(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "hermsd.yaml"
    path.write_text("control:\n  setpoint: 60\n")
    watched = config_file.ConfigFile(path, start=config_file.at_once)
    watched.load()

    def broken(*args: object) -> list[object]:
        raise RuntimeError("a checker bug")

    monkeypatch.setattr(config_file, "reload_problems", broken)
    path.write_text("control:\n  setpoint: 61\n")
    os.utime(path, ns=(1, 1))  # a new signature even within the file system's clock tick
    result = watched.poll()
    assert isinstance(result, ConfigError)
    assert "could not be checked (RuntimeError: a checker bug)" in str(result)
