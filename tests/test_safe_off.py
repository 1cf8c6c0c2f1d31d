"""`hermsd safe-off` against damaged config files, on pseudo-terminals.

The SSR is on the DTR line of one pty (a pty has no modem lines, so its failure line proves
that safe-off went for the right port); the contactor is a serial relay board on another,
whose bytes the test reads back. Whatever is wrong with the file, the relay board must get
its off command, and the exit code must be 0 only when every output found is off.
"""

from __future__ import annotations

import dataclasses
import os
import select
import subprocess
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_config import mutated_config

from hermsd.cli import main
from hermsd.config import read
from hermsd.config import schema as config_module
from hermsd.hardware.safe_off import switch_off

# The common serial relay board's "channel 1 off": A0, channel, state 0, and the checksum
# A0 + 01 + 00 = A1 (the board's documented frames are A0 01 01 A2 on, A0 01 00 A1 off).
OFF_CHANNEL_1 = bytes.fromhex("a00100a1")
SUMMARY = "hermsd safe-off: not every output is known to be off"


@dataclass
class Bench:
    """Two pseudo-terminals: `ssr` for the SSR's DTR line, `relay` for the relay board."""

    ssr: str
    relay: str
    relay_controller: int

    def relay_bytes(self) -> bytes:
        """Everything written to the relay board's port so far."""
        data = b""
        while select.select([self.relay_controller], [], [], 0)[0]:
            data += os.read(self.relay_controller, 4096)
        return data


@pytest.fixture
def bench() -> Iterator[Bench]:
    ssr_controller, ssr_terminal = os.openpty()
    relay_controller, relay_terminal = os.openpty()
    try:
        yield Bench(os.ttyname(ssr_terminal), os.ttyname(relay_terminal), relay_controller)
    finally:
        for fd in (ssr_controller, ssr_terminal, relay_controller, relay_terminal):
            os.close(fd)


def outputs(bench: Bench, contactor: str = "") -> bytes:
    """Output sections naming the bench's ptys (the contactor's as given, or the plain one)."""
    contactor = contactor or f"contactor:\n  backend: relay-board\n  port: {bench.relay}\n"
    return f"output:\n  backend: serial-dtr\n  port: {bench.ssr}\n{contactor}".encode()


@dataclass
class Outcome:
    code: int
    out: list[str]
    err: list[str]


def safe_off(tmp_path: Path, capsys: pytest.CaptureFixture[str], data: bytes) -> Outcome:
    cfg = tmp_path / "hermsd.yaml"
    cfg.write_bytes(data)
    code = main(["safe-off", "--config", str(cfg)])
    captured = capsys.readouterr()
    return Outcome(code, captured.out.splitlines(), captured.err.splitlines())


def assert_only_the_pty_failed(bench: Bench, outcome: Outcome, notes: int = 0) -> None:
    """The SSR was gone for (a pty cannot drop DTR: then exit 1), and nothing else failed."""
    ssr_off = f"output: serial-dtr on {bench.ssr}: off"
    if ssr_off in outcome.out:
        assert outcome.code == 0 and len(outcome.err) == notes
        return
    assert outcome.code == 1
    assert len(outcome.err) == notes + 2, outcome.err
    failure, summary = outcome.err[notes:]
    assert failure.startswith(f"hermsd safe-off: output: serial-dtr on {bench.ssr}: not switched")
    assert summary == SUMMARY


def before(damage: bytes) -> Callable[[bytes], bytes]:
    """Damage in a section ahead of the output sections."""
    return lambda sections: damage + sections


@pytest.mark.parametrize(
    ("damage", "note"),
    [
        (before(b"control:\n  setpoint: 66\n bad indent\n"), ":3:2: invalid YAML"),
        (before(b"tun:\n  name: Caf\xe9\n"), ":2:12: byte 0xe9 is not UTF-8"),
        (before(b"tun:\n  name: a\x07b\n"), ":2:10: the control character #x7"),
        (before(b'tun:\n  name: "HLT\ncontrol:\n  kc: 5\n'), "invalid YAML"),
        (lambda sections: sections.replace(b"\n  ", b"\n\t"), "indent with spaces, not tabs"),
    ],
    ids=["syntax-error", "not-utf8", "control-character", "unclosed-quote", "tabs-in-outputs"],
)
def test_damage_is_read_around(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    bench: Bench,
    damage: Callable[[bytes], bytes],
    note: str,
) -> None:
    outcome = safe_off(tmp_path, capsys, damage(outputs(bench)))
    assert bench.relay_bytes() == OFF_CHANNEL_1
    assert f"contactor: relay-board channel 1 on {bench.relay} at 9600 baud: off" in outcome.out
    assert note in outcome.err[0] and outcome.err[0].endswith("; read around it")
    assert_only_the_pty_failed(bench, outcome, notes=1)


def test_a_bad_baud_rate_sends_off_at_every_valid_one(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], bench: Bench
) -> None:
    contactor = f"contactor: {{backend: relay-board, port: {bench.relay}, baud: 1234}}\n"
    outcome = safe_off(tmp_path, capsys, outputs(bench, contactor))
    bauds = (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200)  # the board's rates
    assert bench.relay_bytes() == OFF_CHANNEL_1 * len(bauds)  # a pty takes any rate
    assert (
        f"contactor: relay-board channel 1 on {bench.relay}: off (sent with each valid value "
        "of contactor.baud, which could not be used)" in outcome.out
    )
    assert_only_the_pty_failed(bench, outcome)


def test_a_bad_channel_switches_every_relay_of_the_board_off(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], bench: Bench
) -> None:
    contactor = f"contactor:\n  backend: relay-board\n  port: {bench.relay}\n  channel: 9\n"
    safe_off(tmp_path, capsys, outputs(bench, contactor))
    frames = bench.relay_bytes()
    expected = {bytes((0xA0, channel, 0, 0xA0 + channel)) for channel in range(1, 9)}
    assert {frames[i : i + 4] for i in range(0, len(frames), 4)} == expected
    assert len(frames) == 4 * 8


def test_a_line_that_cannot_be_read_in_an_output_section_is_a_doubt(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], bench: Bench
) -> None:
    damaged = outputs(bench).replace(b"contactor:", b"  window: [5\ncontactor:")
    outcome = safe_off(tmp_path, capsys, damaged)
    assert bench.relay_bytes() == OFF_CHANNEL_1
    assert any(f"output: serial-dtr on {bench.ssr}" in line for line in outcome.err)
    assert outcome.code == 1
    assert any(
        ":4:1: output: this line cannot be read; so the output may be another device" in line
        for line in outcome.err
    )


def test_exit_0_when_every_output_found_is_off(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], bench: Bench
) -> None:
    damaged = b"control:\n  setpoint: 66\n bad indent\noutput:\n  backend: sim\n"
    contactor = f"contactor:\n  backend: relay-board\n  port: {bench.relay}\n".encode()
    outcome = safe_off(tmp_path, capsys, damaged + contactor)
    assert bench.relay_bytes() == OFF_CHANNEL_1
    assert outcome.code == 0
    assert len(outcome.err) == 1 and "invalid YAML" in outcome.err[0]


@pytest.mark.parametrize(
    ("section", "off"),
    # The board's "channel 2 off": A0 02 00, checksum A0 + 02 + 00 = A2; channel 3's: A3.
    # The pump too: nothing hermsd switches runs while it does not (docs/herms.md).
    [("element2", "a00200a2"), ("pump", "a00300a3")],
)
def test_the_second_element_and_the_pump_are_switched_off_too_even_in_a_damaged_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], bench: Bench, section: str, off: str
) -> None:
    damaged = b"control:\n  algorithm: midrange\n bad indent\noutput:\n  backend: sim\n"
    output = f"{section}:\n  backend: relay-board\n  port: {bench.relay}\n".encode()
    outcome = safe_off(tmp_path, capsys, damaged + output)
    assert bench.relay_bytes() == bytes.fromhex(off)
    channel = int(off[2:4])
    where = f"{section}: relay-board channel {channel} on {bench.relay} at 9600 baud: off"
    assert where in outcome.out
    assert outcome.code == 0


@pytest.mark.parametrize(
    ("data", "why"),
    [
        (None, "no such file"),
        (b"", "names no section (an emptied file?)"),
        (b"# all commented out\n", "names no section (an emptied file?)"),
        (b"{}\n", "names no section (an emptied file?)"),
        (b"outptu:\n  backend: serial-dtr\n", "outptu: unknown key (did you mean 'output'?)"),
        (b"output\n  backend: serial-dtr\n", "cannot tell which section this line is"),
    ],
    ids=["missing", "empty", "comments", "empty-mapping", "misspelt-section", "no-colon"],
)
def test_without_the_outputs_the_defaults_are_tried_and_the_exit_code_says_so(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], data: bytes | None, why: str
) -> None:
    cfg = tmp_path / "hermsd.yaml"
    if data is not None:
        cfg.write_bytes(data)
    code = main(["safe-off", "--config", str(cfg)])
    err = capsys.readouterr().err.splitlines()
    assert code == 1
    assert any(why in line for line in err) and err[-1] == SUMMARY
    default = "output (the built-in default): serial-rts on /dev/ttyUSB0"
    assert any(default in line for line in err) or os.path.exists("/dev/ttyUSB0")


def test_a_fifo_in_place_of_the_file_does_not_hang_it(tmp_path: Path) -> None:
    fifo = tmp_path / "hermsd.yaml"
    os.mkfifo(fifo)
    proc = subprocess.run(
        [sys.executable, "-m", "hermsd.cli", "safe-off", "--config", str(fifo)],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert proc.returncode == 1
    assert f"{fifo}: is a FIFO (named pipe), not a regular file" in proc.stderr
    assert "Traceback" not in proc.stderr


class Recorded:
    """A switch that records what it was told."""

    def __init__(self, log: list[tuple[str, object]], arguments: dict[str, object]) -> None:
        self._log = log
        self._log.append(("open", arguments))

    def set(self, on: bool) -> None:
        self._log.append(("set", on))

    def close(self) -> None:
        self._log.append(("close", None))


@pytest.mark.parametrize(
    ("section", "refused"),
    [
        ("output:\n  backend: serial-rts\n  port: 5\n", "output.port"),
        ("output:\n  backend: serial-rst\n  port: /dev/ttyUSB3\n", "output.backend"),
        ("output:\n  backend: gpio\n  line: 17\n  active_low: maybe\n", "output.active_low"),
        ("output:\n  backend: gpio\n  line: seventeen\n", "output.line"),
    ],
    ids=["port", "backend", "gpio-polarity", "gpio-line"],
)
def test_an_unusable_key_that_names_the_device_switches_nothing_in_doubt(
    tmp_path: Path, section: str, refused: str
) -> None:
    cfg = tmp_path / "hermsd.yaml"
    cfg.write_text(section)
    log: list[tuple[str, object]] = []
    report = switch_off(read.load_outputs(cfg), lambda **arguments: Recorded(log, arguments))
    assert log == [], "another port, line or polarity may be someone else's device"
    assert report.switched == []
    assert len(report.failures) == 1 and f"{refused}:" in report.failures[0]


def test_an_unusable_setting_that_does_not_name_the_device_is_ignored(tmp_path: Path) -> None:
    cfg = tmp_path / "hermsd.yaml"
    cfg.write_text("output:\n  backend: serial-dtr\n  port: /dev/ttyUSB3\n  window: 0.1\n")
    log: list[tuple[str, object]] = []
    report = switch_off(read.load_outputs(cfg), lambda **arguments: Recorded(log, arguments))
    assert [entry[0] for entry in log] == ["open", "set", "close"]
    assert log[1] == ("set", False)
    assert report.switched == ["output: serial-dtr on /dev/ttyUSB3: off"]
    assert report.failures == []


@settings(
    max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(data=mutated_config() | st.binary(max_size=300))
def test_fuzz_whatever_the_file_holds_the_ssr_output_is_tried_unless_it_is_unknown(
    tmp_path: Path, data: bytes
) -> None:
    cfg = tmp_path / "hermsd.yaml"
    cfg.write_bytes(data)
    found = read.load_outputs(cfg)
    log: list[tuple[str, object]] = []
    switch_off(found, lambda **arguments: Recorded(log, arguments))
    output = found.output
    assert set(output.values) | set(output.refused) <= {
        f.name for f in dataclasses.fields(config_module.OutputConfig)
    }
    backend = output.values.get("backend", "serial-rts")
    names_the_device = {"backend", "port", "chip", "line", "active_low"}
    if backend != "sim" and not names_the_device & set(output.refused):
        action, arguments = log[0]
        assert action == "open"
        assert isinstance(arguments, dict) and arguments["backend"] == backend
    # Every switch opened was told off, then closed.
    opened = [entry for entry in log if entry[0] == "open"]
    assert log == [e for o in opened for e in (o, ("set", False), ("close", None))]


def test_a_relay_board_out_of_reach_is_said_once_for_all_the_rates_tried(tmp_path: Path) -> None:
    cfg = tmp_path / "hermsd.yaml"
    cfg.write_text(
        "output: {backend: sim}\n"
        "contactor: {backend: relay-board, port: /dev/ttyUSB7, baud: 1234}\n"
    )
    tried: list[object] = []

    def unplugged(**arguments: object) -> Recorded:
        tried.append(arguments["baud"])
        raise OSError(2, "No such file or directory")

    report = switch_off(read.load_outputs(cfg), unplugged)
    assert tried == [9600, 1200, 2400, 4800, 19200, 38400, 57600, 115200]  # the default first
    assert report.failures == [
        "contactor: relay-board channel 1 on /dev/ttyUSB7: not switched off with each valid "
        "value of contactor.baud, which could not be used: [Errno 2] No such file or directory"
    ]
