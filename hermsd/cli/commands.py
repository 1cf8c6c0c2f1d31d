"""The `hermsd` command: run the loop, simulate, check wiring and config, replay logs.

Every failure a user can cause (no I2C bus, wrong address, a bad config, a bad scenario)
ends in one line on stderr and exit code 2, never a traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import signal
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from hermsd import __version__
from hermsd.cli.common import (
    DEFAULT_CONFIG,
    DEFAULT_STATE,
    EXIT_USAGE,
    Shutdown,
    Unreachable,
    UserError,
)
from hermsd.cli.files import cmd_check_config, cmd_forget_model
from hermsd.cli.hardware import cmd_safe_off, cmd_sensor
from hermsd.cli.logs import cmd_recover, cmd_replay
from hermsd.cli.remote import (
    _step_number,
    cmd_confirm,
    cmd_program,
    cmd_reset_alarm,
    cmd_set,
    cmd_status,
)
from hermsd.cli.run import (
    cmd_run,
    cmd_simulate,
)
from hermsd.cli.services import cmd_mqtt, cmd_web
from hermsd.cli.tune import cmd_tune
from hermsd.config import schema as config_module
from hermsd.config.schema import ConfigError
from hermsd.hardware.lm92 import SensorError
from hermsd.runtime.log_queue import DroppingQueueHandler

if TYPE_CHECKING:
    pass


def main(argv: Sequence[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    try:
        with _logging_to_stderr(getattr(args, "verbose", False)):
            result: int = args.func(args)
        sys.stdout.flush()  # here, so that a closed pipe is met inside the handler below
        return result
    except BrokenPipeError:
        return _reader_gone()
    except UserError as error:
        print(f"hermsd: {error}", file=sys.stderr)
        return EXIT_USAGE
    except Unreachable as error:
        print(f"hermsd: {error}", file=sys.stderr)
        return 1
    except ConfigError as error:
        print(str(error), file=sys.stderr)
        return EXIT_USAGE
    except SensorError as error:
        print(f"hermsd: {error}", file=sys.stderr)
        return EXIT_USAGE
    except Shutdown:
        return 0
    except KeyboardInterrupt:
        return 0


def _reader_gone() -> int:
    """The reader of stdout went away (`hermsd replay ... | head`): stop quietly, with the
    status of a command that SIGPIPE ended, as `cat` would."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())  # the interpreter's last flush must not fail again
    os.close(devnull)
    return 128 + signal.SIGPIPE


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="hermsd", description="Holds a HERMS Hot Liquor Tank at its setpoint."
    )
    parser.add_argument("--version", action="version", version=f"hermsd {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    sensor = sub.add_parser("sensor", help="identify a sensor and print readings (wiring check)")
    sensor.add_argument(
        "--kind", choices=("lm92", "ds18b20", "max31865"), default="lm92", help="default lm92"
    )
    sensor.add_argument(
        "--bus", type=int, help="I2C bus number (lm92, default 1) or SPI bus (max31865, default 0)"
    )
    sensor.add_argument(
        "--address", type=_address, default=0x48, help="LM92 address 0x48..0x4b (default 0x48)"
    )
    sensor.add_argument("--id", help="ds18b20: the device id 28-…; default every one found")
    sensor.add_argument(
        "--w1-root", default="/sys/bus/w1/devices", help="ds18b20: where the w1 devices are"
    )
    sensor.add_argument("--device", type=int, default=0, help="max31865: chip select (default 0)")
    sensor.add_argument("--r0", type=float, default=100.0, help="max31865: 100 or 1000 (PT100)")
    sensor.add_argument("--rref", type=float, default=430.0, help="max31865: reference, Ω (430)")
    sensor.add_argument("--wires", type=int, choices=(2, 3, 4), default=3, help="max31865 (3)")
    sensor.add_argument("--filter", type=int, choices=(50, 60), default=50, help="mains Hz (50)")
    sensor.add_argument(
        "--decode", type=_rtd_word, help="max31865: print what an RTD register value 0xNNNN means"
    )
    sensor.add_argument("--count", type=_positive_int, help="stop after N readings")
    sensor.add_argument("--simulate", action="store_true", help="read the simulated tun")
    sensor.set_defaults(func=cmd_sensor)

    run = sub.add_parser("run", help="run the control loop")
    run.add_argument("--config", type=Path, help=f"config file (default {DEFAULT_CONFIG})")
    run.add_argument("--simulate", action="store_true", help="simulated tun and heater")
    run.add_argument(
        "--speed", default="1", help="with --simulate: times real time, or 'max' (default 1)"
    )
    run.add_argument(
        "--scenario",
        type=Path,
        help="with --simulate: this scenario's tun (a HERMS's mash too), config and events, live",
    )
    run.add_argument("--duration", help="stop after this long, e.g. 90s, 4h, 1h30m")
    run.add_argument("--log", type=Path, help="MCAP log directory (default: the config's log.dir)")
    run.add_argument(
        "--state",
        type=Path,
        help="directory that keeps latched alarms across restarts (default: systemd's "
        f"$STATE_DIRECTORY, else {DEFAULT_STATE} unless simulating)",
    )
    run.add_argument(
        "--socket",
        type=Path,
        help="control socket (default: $RUNTIME_DIRECTORY/control.sock, else "
        "/run/hermsd/control.sock; simulating: $XDG_RUNTIME_DIR/hermsd-sim/control.sock, "
        "else /tmp/hermsd-sim-UID/control.sock)",
    )
    run.set_defaults(func=cmd_run)

    status = sub.add_parser("status", help="what the running daemon is doing")
    status.add_argument("--json", action="store_true", help="print the daemon's reply as JSON")
    _socket_argument(status)
    status.set_defaults(func=cmd_status)

    set_ = sub.add_parser(
        "set",
        help="change the running daemon's setpoint or mode (until the file's key is edited), "
        "or run or stop the pump",
    )
    set_.add_argument("what", metavar="setpoint|mode|pump", help="what to set")
    set_.add_argument("value", help="°C for setpoint; auto or manual for mode; on or off for pump")
    set_.add_argument("--output", help="with `mode manual`: the output in %% (default: hold it)")
    _socket_argument(set_)
    set_.set_defaults(func=cmd_set)

    program = sub.add_parser(
        "program",
        help="the mash program: check a file, start it, move it on, pause, stop; import one "
        "from a BeerXML recipe",
    )
    program.add_argument(
        "action",
        choices=("check", "start", "next", "pause", "resume", "stop", "import"),
        help="what to do",
    )
    program.add_argument(
        "file",
        nargs="?",
        type=Path,
        help="the program file (check, start), or a BeerXML 1.0 file of recipes or mash "
        "profiles (import)",
    )
    program.add_argument(
        "-o",
        "--output",
        type=Path,
        metavar="OUT.yaml",
        help="with import: write the program here (default: stdout)",
    )
    program.add_argument(
        "--recipe", metavar="NAME", help="with import: the recipe, when the file holds several"
    )
    program.add_argument(
        "--ready-by",
        metavar="HH:MM",
        help="with start: have the first step's setpoint reached at this local time",
    )
    program.add_argument(
        "--config",
        type=Path,
        help="with check: also warn of what this config's HERMS cannot honour (a strike above "
        "the first rest + herms.max_hlt_above_mash)",
    )
    _step_argument(program, "with next: end step N only (refused if another is current)")
    _socket_argument(program)
    program.set_defaults(func=cmd_program)

    confirm = sub.add_parser("confirm", help="answer the program's step that waits for you")
    _step_argument(confirm, "confirm step N only (refused if another is current)")
    _socket_argument(confirm)
    confirm.set_defaults(func=cmd_confirm)

    reset = sub.add_parser(
        "reset-alarm", help="clear the latched alarms, once their cause is found"
    )
    _state_argument(reset)
    _socket_argument(reset)
    reset.set_defaults(func=cmd_reset_alarm)

    forget = sub.add_parser(
        "forget-model", help="delete what hermsd learned of the tun (it starts from the config)"
    )
    _state_argument(forget)
    forget.set_defaults(func=cmd_forget_model)

    recover = sub.add_parser("recover", help="turn .mcap.part files left by a crash into logs")
    recover.add_argument("files", nargs="+", type=Path)
    recover.set_defaults(func=cmd_recover)

    simulate = sub.add_parser("simulate", help="run a scenario at full speed and measure it")
    simulate.add_argument("--config", type=Path, help="config file (default: built-in)")
    simulate.add_argument("--scenario", type=Path, help="scenario file (default: 20 → 66 °C)")
    simulate.add_argument("--json", action="store_true", help="print one JSON object")
    simulate.add_argument("--log", type=Path, help="write the MCAP log into this directory")
    simulate.add_argument(
        "--plant",
        metavar="MODULE:FACTORY",
        help="simulate the tun that FACTORY() makes (path/to/tun.py:make_tun or "
        "package.module:make_tun; the protocol is hermsd.sim.hlt.Plant)",
    )
    simulate.add_argument(
        "--state",
        type=Path,
        help="state directory kept from one simulated day to the next (default: none)",
    )
    simulate.set_defaults(func=cmd_simulate)

    replay = sub.add_parser(
        "replay", help="summarise a brew day's logs, re-run its controller, try other settings"
    )
    replay.add_argument(
        "files", nargs="*", type=Path, help=".mcap or .mcap.part files of one day, in any order"
    )
    replay.add_argument("--json", action="store_true", help="print one JSON object")
    replay.add_argument(
        "--verify",
        action="store_true",
        help="re-run the logged controller on the logged inputs; exit 1 at the first difference "
        "(a log of another control law than this hermsd's is named so, not re-run)",
    )
    replay.add_argument(
        "--what-if",
        metavar="KEY=VALUE,...",
        help="run the day again on a model of the tun fitted to the log, with these control "
        f"settings ({', '.join(config_module.TUNING_KEYS)}; 'logged': the logged ones)",
    )
    replay.add_argument("--csv", type=Path, metavar="FILE", help="write the period records as CSV")
    replay.add_argument(
        "--plot",
        type=Path,
        metavar="FILE.png",
        help="draw the day: temperature, error against the ±0.5 °C band, output and applied "
        "duty, alarms and labelled events (needs matplotlib)",
    )
    replay.set_defaults(func=cmd_replay)

    tune = sub.add_parser(
        "tune", help="the tun's model and the settings that follow from it (seed 001's Table 1)"
    )
    tune.add_argument(
        "files",
        nargs="*",
        type=Path,
        help="the .mcap or .mcap.part files of an ordinary brew day (a heat-up and a hold), "
        "or `step` for the step test",
    )
    tune.add_argument(
        "--table",
        metavar="K=..,tau=..,theta=..[,a_star=..]",
        help="print Table 1's settings for this model (K °C/%%, tau s, theta s, "
        "a_star °C/(%%·s); a_star = K/tau when left out)",
    )
    tune.add_argument("--json", action="store_true", help="print one JSON object")
    tune.add_argument(
        "--ambient",
        metavar="°C",
        type=float,
        help="the room's temperature during the day, if measured: it pins K and τ when the "
        "heat-up is short compared with τ",
    )
    tune.add_argument(
        "--write",
        metavar="FILE",
        nargs="?",
        type=Path,
        const=DEFAULT_CONFIG,
        help=f"write the recommended settings into the config file (default {DEFAULT_CONFIG}), "
        "keeping everything else in it, and show the diff",
    )
    step = tune.add_argument_group(
        "tune step", "`hermsd tune step`: a manual output step through the loop (seed 001 §4.1-4.2)"
    )
    step.add_argument(
        "--output", type=float, metavar="%", help="the step (default: reaches the limit in ~90 min)"
    )
    step.add_argument(
        "--limit", type=float, metavar="°C", help="stop at this PV (default and most: the setpoint)"
    )
    step.add_argument("--config", type=Path, help=f"config file (default {DEFAULT_CONFIG})")
    step.add_argument("--simulate", action="store_true", help="on the simulated tun, at full speed")
    step.add_argument("--plant", metavar="MODULE:FACTORY", help="with --simulate: this tun")
    step.add_argument("--log", type=Path, help="MCAP log directory (default: the config's log.dir)")
    relay = tune.add_argument_group(
        "tune relay",
        "`hermsd tune relay`: a relay test around the setpoint after the heat-up (with "
        "--config, --simulate, --plant, --log, --ambient as above)",
    )
    relay.add_argument("--setpoint", type=float, metavar="°C", help="default: the config's")
    relay.add_argument(
        "--hysteresis",
        type=float,
        metavar="°C",
        help="the relay's band ± around the setpoint (default one LM92 step, 0.0625)",
    )
    relay.add_argument(
        "--amplitude",
        type=float,
        metavar="%",
        help="the relay's ± output around the hold's duty (default: a ~0.3 °C swing)",
    )
    tune.set_defaults(func=cmd_tune)

    safe_off = sub.add_parser(
        "safe-off",
        help="drive every output the config names off, whatever else is wrong with it; "
        "exit 1 unless every one is known to be off",
    )
    safe_off.add_argument("--config", type=Path, help=f"config file (default {DEFAULT_CONFIG})")
    safe_off.set_defaults(func=cmd_safe_off)

    web = sub.add_parser("web", help="serve the brewer's web page (talks to the daemon's socket)")
    web.add_argument("--config", type=Path, help=f"config file (default: {DEFAULT_CONFIG})")
    web.add_argument("--listen", help="HOST:PORT to listen on (default: the config's web.listen)")
    web.add_argument(
        "--hash-password",
        action="store_true",
        help="print the hash of a new password for web.password_hash, and exit",
    )
    _socket_argument(web)
    web.set_defaults(func=cmd_web)

    check = sub.add_parser("check-config", help="validate a config file and print it")
    check.add_argument("file", nargs="?", type=Path, default=DEFAULT_CONFIG)
    check.add_argument(
        "--simulate", action="store_true", help="check a file for `run --simulate` (backend sim)"
    )
    check.add_argument(
        "--state",
        type=Path,
        help="the daemon's state directory: its latch file checked as `run` reads it, and the "
        "limits from what it learned of the tun",
    )
    check.set_defaults(func=cmd_check_config)

    mqtt = sub.add_parser(
        "mqtt", help="bridge the daemon to an MQTT broker and Home Assistant (docs/mqtt.md)"
    )
    mqtt.add_argument("--config", type=Path, help=f"config file (default {DEFAULT_CONFIG})")
    mqtt.add_argument(
        "--programs",
        type=Path,
        metavar="DIR",
        help="the program files Home Assistant may start (default: programs/ beside the config)",
    )
    _socket_argument(mqtt)
    mqtt.set_defaults(func=cmd_mqtt)
    return parser


def _socket_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--socket",
        type=Path,
        help="the daemon's control socket (default: $RUNTIME_DIRECTORY/control.sock, else "
        "/run/hermsd/control.sock if it exists, else the simulated daemon's if its socket exists)",
    )


def _address(text: str) -> int:
    try:
        value = int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an address like 0x48, got {text!r}") from None
    if not 0x48 <= value <= 0x4B:
        raise argparse.ArgumentTypeError(f"the LM92 answers at 0x48..0x4b, not {value:#x}")
    return value


def _rtd_word(text: str) -> int:
    try:
        value = int(text, 16)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected a register value like 0x3b88, got {text!r}"
        ) from None
    if not 0 <= value <= 0xFFFF:
        raise argparse.ArgumentTypeError(f"the RTD register is 16 bits, not {text}")
    return value


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected at least 1, got {value}")
    return value


_SYSLOG_PRIORITIES = (
    (2, logging.CRITICAL),
    (3, logging.ERROR),
    (4, logging.WARNING),
    (6, logging.INFO),
)


class JournalFormatter(logging.Formatter):
    """Each line prefixed with its syslog priority, `<4>` for a warning: the journal files a
    line written to stderr under that priority (systemd.exec(5), SyslogLevelPrefix=)."""

    def format(self, record: logging.LogRecord) -> str:
        priority = next((p for p, level in _SYSLOG_PRIORITIES if record.levelno >= level), 7)
        return f"<{priority}>" + super().format(record)


def stderr_is_journal() -> bool:
    """Whether stderr is systemd's journal stream: JOURNAL_STREAM names its device and inode."""
    try:
        status = os.fstat(sys.stderr.fileno())
    except (OSError, ValueError, AttributeError):
        return False
    return os.environ.get("JOURNAL_STREAM") == f"{status.st_dev}:{status.st_ino}"


@contextlib.contextmanager
def _logging_to_stderr(verbose: bool) -> Iterator[None]:
    """The "hermsd" logger's lines on stderr, written by a thread of their own: a stalled
    stderr never holds up the thread that logs (hermsd/runtime/log_queue.py). At the end, however it
    comes, every queued line is written before the command's own last words."""
    handler = logging.StreamHandler(sys.stderr)
    formatter = JournalFormatter if stderr_is_journal() else logging.Formatter
    handler.setFormatter(formatter("%(levelname)s %(message)s"))
    queued = DroppingQueueHandler(handler)
    root = logging.getLogger("hermsd")
    root.handlers[:] = [queued]
    root.setLevel(logging.DEBUG if verbose else logging.INFO)
    root.propagate = False
    queued.start()
    try:
        yield
    finally:
        root.handlers[:] = [handler]  # a line from a thread still running goes straight out
        queued.stop()


def _step_argument(parser: argparse.ArgumentParser, text: str) -> None:
    """--step N: the step (numbered from 1, as `hermsd status` shows it) a confirm or next is
    for; without it, the step current a second before the daemon receives the request."""
    parser.add_argument(
        "--step", type=_step_number, metavar="N", help=text + "; default: the current step"
    )


def _state_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--state",
        type=Path,
        help=f"the daemon's state directory (default: $STATE_DIRECTORY, else {DEFAULT_STATE})",
    )


if __name__ == "__main__":
    sys.exit(main())
