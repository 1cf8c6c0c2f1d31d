"""The systemd units: accepted by systemd-analyze, sandboxed to an exposure ≤ 1.0 (the MQTT
bridge's and the web page's ≤ 2.0), and carrying the directives the daemon's safety relies
on."""

from __future__ import annotations

import re
import shutil
import subprocess
from collections import defaultdict
from pathlib import Path

import pytest
from programs import require_program

from hermsd.hardware.realtime import LOOP_PRIORITY

SYSTEMD_DIR = Path(__file__).resolve().parent.parent / "systemd"
INSTALLED_BINARY = "/usr/local/bin/hermsd"
# The template is checked through one instance, so %i resolves as it will on the Pi.
UNITS = {"hermsd.service": "hermsd.service", "hermsd@.service": "hermsd@hlt.service"}
CONFIG = {"hermsd.service": "/etc/hermsd/hermsd.yaml", "hermsd@.service": "/etc/hermsd/%i.yaml"}
# The MQTT bridge's units: no hardware, but the network (the daemon's stay at 1.0 or less).
MQTT_UNITS = {
    "hermsd-mqtt.service": "hermsd-mqtt.service",
    "hermsd-mqtt@.service": "hermsd-mqtt@hlt.service",
}
# The web page's unit: no hardware, TCP from the Pi itself.
WEB_UNITS = {"hermsd-web.service": "hermsd-web.service"}
EXPOSURE_LIMITS = {
    **dict.fromkeys(UNITS, 1.0),
    **dict.fromkeys(MQTT_UNITS, 2.0),
    **dict.fromkeys(WEB_UNITS, 2.0),
}

SYSTEMD_ANALYZE = shutil.which("systemd-analyze")


def _directives(unit_file: str) -> dict[str, list[str]]:
    """'Section.Key' → values in file order (systemd lets most keys repeat)."""
    directives: dict[str, list[str]] = defaultdict(list)
    section = ""
    for raw_line in (SYSTEMD_DIR / unit_file).read_text().splitlines():
        line = raw_line.strip()
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("["):
            section = line.strip("[]")
            continue
        key, _, value = line.partition("=")
        directives[f"{section}.{key}"].append(value)
    return directives


def _staged_unit(unit_file: str, directory: Path) -> Path:
    """A copy whose ExecStart=/ExecStopPost= name an existing binary, because verify
    refuses a unit whose command does not exist; returns the path to analyse."""
    true_binary = shutil.which("true")
    assert true_binary is not None
    text = (SYSTEMD_DIR / unit_file).read_text()
    assert INSTALLED_BINARY in text
    (directory / unit_file).write_text(text.replace(INSTALLED_BINARY, true_binary))
    return directory / {**UNITS, **MQTT_UNITS, **WEB_UNITS}[unit_file]


def _analyze(*arguments: str) -> subprocess.CompletedProcess[str]:
    require_program(
        Path(SYSTEMD_ANALYZE) if SYSTEMD_ANALYZE else None, "systemd", what="the unit checks"
    )
    assert SYSTEMD_ANALYZE is not None
    return subprocess.run(
        [SYSTEMD_ANALYZE, *arguments], capture_output=True, text=True, timeout=60, check=False
    )


@pytest.mark.parametrize("unit_file", EXPOSURE_LIMITS)
def test_systemd_analyze_verify_reports_nothing(unit_file: str, tmp_path: Path) -> None:
    unit = _staged_unit(unit_file, tmp_path)

    result = _analyze("verify", "--man=no", str(unit))

    assert (result.returncode, result.stderr, result.stdout) == (0, "", "")


@pytest.mark.parametrize("unit_file", EXPOSURE_LIMITS)
def test_sandbox_exposure_is_within_its_limit(unit_file: str, tmp_path: Path) -> None:
    unit = _staged_unit(unit_file, tmp_path)
    limit = EXPOSURE_LIMITS[unit_file]

    # --threshold is on systemd's internal 0..100 scale: 10 is the displayed 1.0.
    result = _analyze("security", "--offline=yes", f"--threshold={round(10 * limit)}", str(unit))

    match = re.search(r"Overall exposure level for \S+: (\d+\.\d)", result.stdout)
    assert match is not None, result.stdout + result.stderr
    assert float(match.group(1)) <= limit
    assert result.returncode == 0, result.stderr


@pytest.mark.parametrize("unit_file", UNITS)
def test_the_unit_has_what_the_daemon_relies_on(unit_file: str) -> None:
    directives = _directives(unit_file)
    config = CONFIG[unit_file]

    expected = {
        "Service.Type": ["notify"],
        "Service.NotifyAccess": ["main"],
        "Service.ExecStart": [f"{INSTALLED_BINARY} run --config {config}"],
        # The same config for safe-off, so it switches off the output the daemon drove.
        "Service.ExecStopPost": [f"{INSTALLED_BINARY} safe-off --config {config}"],
        "Service.ExecReload": ["/bin/kill -HUP $MAINPID"],
        # Three control periods of 5 s (Ts of the identified HLT).
        "Service.WatchdogSec": ["15s"],
        "Service.Restart": ["always"],
        "Service.RestartSec": ["2"],
        "Service.User": ["hermsd"],
        "Service.Group": ["hermsd"],
        "Service.SupplementaryGroups": ["i2c dialout gpio"],
        "Service.ConfigurationDirectory": ["hermsd"],
        "Service.DevicePolicy": ["closed"],
        "Service.DeviceAllow": [
            # Names as in /proc/devices: i2c-dev, usb-serial, cdc-acm, the GPIO character device.
            "char-i2c rw",
            "char-ttyUSB rw",
            "char-ttyACM rw",
            "char-gpiochip rw",
        ],
        "Service.PrivateNetwork": ["yes"],
        "Service.RestrictAddressFamilies": ["AF_UNIX"],
        "Service.ProtectSystem": ["strict"],
        "Service.CapabilityBoundingSet": [""],
        "Service.NoNewPrivileges": ["yes"],
    }
    assert {key: directives.get(key) for key in expected} == expected
    assert directives["Service.TimeoutStopSec"]
    # The loop thread may raise itself to real-time priority (and nothing higher).
    assert directives["Service.LimitRTPRIO"] == [str(LOOP_PRIORITY)]
    assert "sched_setscheduler" in directives["Service.SystemCallFilter"]
    assert directives.get("Service.RestrictRealtime", ["no"]) == ["no"]
    assert directives["Service.StateDirectory"][0].startswith("hermsd")
    assert directives["Service.LogsDirectory"][0].startswith("hermsd")
    # The control socket's directory: the service's group may enter it, no one else.
    assert directives["Service.RuntimeDirectory"][0].startswith("hermsd")
    assert directives["Service.RuntimeDirectoryMode"] == ["0750"]


def test_the_template_differs_from_the_plain_unit_only_per_vessel() -> None:
    plain = _directives("hermsd.service")
    template = _directives("hermsd@.service")
    per_vessel = {
        "Unit.Description",
        "Service.ExecStart",
        "Service.ExecStopPost",
        "Service.StateDirectory",
        "Service.LogsDirectory",
        "Service.RuntimeDirectory",
    }

    assert {key for key in plain.keys() | template.keys() if plain[key] != template[key]} == (
        per_vessel
    )
    assert template["Service.StateDirectory"] == ["hermsd/%i"]
    assert template["Service.LogsDirectory"] == ["hermsd/%i"]
    assert template["Service.RuntimeDirectory"] == ["hermsd/%i"]


# -- the MQTT bridge's unit -----------------------------------------------------------------

MQTT_PLACES = {  # the config and the socket of the vessel each bridges
    "hermsd-mqtt.service": ("/etc/hermsd/hermsd.yaml", "/run/hermsd/control.sock"),
    "hermsd-mqtt@.service": ("/etc/hermsd/%i.yaml", "/run/hermsd/%i/control.sock"),
}


@pytest.mark.parametrize("unit_file", MQTT_UNITS)
def test_the_mqtt_bridge_runs_as_its_own_user_without_hardware(unit_file: str) -> None:
    directives = _directives(unit_file)
    config, control_socket = MQTT_PLACES[unit_file]
    expected = {
        "Service.ExecStart": [
            f"{INSTALLED_BINARY} mqtt --config {config} --socket {control_socket}"
        ],
        "Service.Restart": ["always"],
        "Service.User": ["hermsd-mqtt"],
        "Service.Group": ["hermsd-mqtt"],
        # the control socket and the config file are the hermsd group's
        "Service.SupplementaryGroups": ["hermsd"],
        "Service.PrivateDevices": ["yes"],
        "Service.DevicePolicy": ["closed"],
        "Service.RestrictAddressFamilies": ["AF_UNIX AF_INET AF_INET6"],
        "Service.ProtectSystem": ["strict"],
        "Service.CapabilityBoundingSet": [""],
        "Service.NoNewPrivileges": ["yes"],
    }
    assert {key: directives.get(key) for key in expected} == expected
    assert "Service.DeviceAllow" not in directives
    assert "Service.PrivateNetwork" not in directives


def test_the_mqtt_template_differs_from_the_plain_unit_only_per_vessel() -> None:
    plain = _directives("hermsd-mqtt.service")
    template = _directives("hermsd-mqtt@.service")
    per_vessel = {"Unit.Description", "Unit.After", "Service.ExecStart"}
    assert {k: v for k, v in plain.items() if k not in per_vessel} == {
        k: v for k, v in template.items() if k not in per_vessel
    }
    assert template["Unit.After"] == ["network-online.target hermsd@%i.service mosquitto.service"]


# -- the web page's unit --------------------------------------------------------------------


def test_the_web_unit_runs_as_its_own_user_without_the_hardware() -> None:
    directives = _directives("hermsd-web.service")
    expected = {
        "Service.ExecStart": [
            f"{INSTALLED_BINARY} web --config /etc/hermsd/hermsd.yaml "
            "--socket /run/hermsd/control.sock"
        ],
        "Service.User": ["hermsd-web"],
        # The daemon's group reaches the control socket and reads the config; no i2c,
        # dialout or gpio group, and no device node at all.
        "Service.SupplementaryGroups": ["hermsd"],
        "Service.PrivateDevices": ["yes"],
        "Service.DevicePolicy": ["closed"],
        "Service.DeviceAllow": None,
        "Service.ProtectSystem": ["strict"],
        "Service.CapabilityBoundingSet": [""],
        "Service.NoNewPrivileges": ["yes"],
        "Service.IPAddressDeny": ["any"],
        "Service.IPAddressAllow": ["localhost"],
    }
    assert {key: directives.get(key) for key in expected} == expected
    assert "hermsd" not in directives.get("Service.StateDirectory", [])
