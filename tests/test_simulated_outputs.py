"""A simulated run drives the simulated tun's SSR whatever hardware the config file names,
and says so: in its log, on a reload of the file, in `check-config --simulate`, and in a
simulated tune test's log."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from hermsd.cli import commands as cli
from hermsd.config.file import ConfigFile, at_once
from hermsd.log.mcap_file import LogFile
from hermsd.log.topics import CONFIG_TOPIC, LOG_TOPIC
from hermsd.sim.world import simulated_daemon

SHIPPED = Path(__file__).parent.parent / "config" / "hermsd.yaml"


def a_file_for_the_tun(directory: Path, setpoint: float = 66.0) -> Path:
    """The shipped file, as a brewer's tun's: its SSR on a serial line's RTS, a second
    element on a GPIO line."""
    text = SHIPPED.read_text(encoding="utf-8")
    assert "\n  backend: serial-rts\n" in text
    text = text.replace("  setpoint: 66", f"  setpoint: {setpoint:g}", 1)
    text += "\nelement2:\n  backend: gpio\n  line: 27\n  watts: 2000\n"
    path = directory / "hermsd.yaml"
    path.write_text(text, encoding="utf-8")
    return path


def logged_configs(directory: Path) -> list[dict[str, Any]]:
    return [
        message
        for path in sorted(directory.glob("*.mcap"))
        for topic, _, message in LogFile(path).messages([CONFIG_TOPIC])
    ]


class Written:
    """The records the daemon hands its recorder."""

    def __init__(self) -> None:
        self.records: list[tuple[str, dict[str, Any]]] = []

    def write(self, topic: str, log_time_ns: int, message: dict[str, Any]) -> None:
        self.records.append((topic, message))


def backends(config: dict[str, Any]) -> tuple[str, str]:
    return config["output"]["backend"], config["element2"]["backend"]


def test_a_simulated_run_logs_the_simulated_ssr_not_the_file_s_hardware(tmp_path: Path) -> None:
    config = a_file_for_the_tun(tmp_path)
    logs = tmp_path / "logs"
    argv = ["run", "--simulate", "--speed", "max", "--duration", "1m", "--config", str(config)]
    assert cli.main([*argv, "--log", str(logs), "--state", str(tmp_path / "state")]) == 0
    [start] = logged_configs(logs)
    assert backends(start["config"]) == ("sim", "sim")


def test_a_reload_in_a_simulated_run_asks_for_no_restart(tmp_path: Path) -> None:
    path = a_file_for_the_tun(tmp_path)
    source = ConfigFile(path, at_once, simulated=True)
    config = source.load()
    assert (config.output.backend, config.element2.backend) == ("sim", "sim")
    daemon = simulated_daemon(config, float("inf"), config_file=source)
    written = Written()
    daemon.recorder = written
    with daemon:
        daemon.start()
        daemon.run(until=60.0)
        a_file_for_the_tun(tmp_path, setpoint=70.0)
        daemon.request_reload()
        daemon.run(until=120.0)
    assert daemon.config.control.setpoint == 70.0
    said = [m["message"] for topic, m in written.records if topic == LOG_TOPIC]
    assert "config reloaded: control.setpoint changed" in said
    assert not [line for line in said if "restart" in line]
    reloaded = [m for topic, m in written.records if topic == CONFIG_TOPIC][-1]
    assert reloaded["reason"] == "reload" and backends(reloaded["config"]) == ("sim", "sim")


def test_check_config_for_a_simulated_run_prints_the_simulated_ssr(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = a_file_for_the_tun(tmp_path)
    assert cli.main(["check-config", str(path)]) == 0
    assert "output:\n  backend: serial-rts\n" in capsys.readouterr().out
    assert cli.main(["check-config", str(path), "--simulate"]) == 0
    out = capsys.readouterr().out
    assert "output:\n  backend: sim\n" in out and "element2:\n  backend: sim\n" in out


def test_a_simulated_tune_test_logs_the_simulated_ssr(tmp_path: Path) -> None:
    config = a_file_for_the_tun(tmp_path)
    logs = tmp_path / "logs"
    argv = ["tune", "step", "--simulate", "--config", str(config), "--log", str(logs), "--json"]
    cli.main(argv)
    assert [backends(m["config"]) for m in logged_configs(logs)][:1] == [("sim", "sim")]
