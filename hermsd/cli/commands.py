"""The `hermsd` command: run the loop, simulate, check wiring and config, replay logs.

Every failure a user can cause (no I2C bus, wrong address, a bad config, a bad scenario)
ends in one line on stderr and exit code 2, never a traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import logging
import math
import os
import signal
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import BrokenExecutor
from functools import partial
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Any, TextIO, TypeVar

from hermsd import __version__
from hermsd.api.client import SOCKET_NAME, NoDaemonError, ReplyError, ask, default_socket_path
from hermsd.api.protocol import (
    ProgramAction,
    ProgramStart,
    Request,
    ResetAlarms,
    SetMode,
    SetSetpoint,
    Status,
)
from hermsd.api.server import ControlServer
from hermsd.config import schema as config_module
from hermsd.config.file import ConfigFile, at_once
from hermsd.config.schema import Config, ConfigError, ContactorConfig, Element2Config, OutputConfig
from hermsd.control.learning import ModelStore
from hermsd.durations import parse_duration
from hermsd.files import write_new
from hermsd.hardware.lm92 import LM92, SensorError, open_bus
from hermsd.hardware.realtime import loop_priority
from hermsd.hardware.ssr import Switch, describe_output, open_hardware_switch
from hermsd.log.recorder import NotRecovered, Recorder, recover, recover_directory
from hermsd.runtime.instance import DirectoryLock, InstanceError
from hermsd.runtime.log_queue import DroppingQueueHandler
from hermsd.runtime.notify import Notifier, NotifyEnvironmentError, check_watchdog, status_line
from hermsd.safety.latches import Latches, LatchStore, StateError

if TYPE_CHECKING:
    from hermsd.commissioning import step_response
    from hermsd.runtime.daemon import Daemon

DEFAULT_CONFIG = Path("/etc/hermsd/hermsd.yaml")
DEFAULT_STATE = Path("/var/lib/hermsd")
EXIT_USAGE = 2

log = logging.getLogger("hermsd")


class UserError(Exception):
    """A problem the user can fix; printed as one line, exit code 2."""


class Unreachable(Exception):
    """No daemon answers on the control socket; printed as one line, exit code 1."""


class Shutdown(BaseException):
    """SIGTERM or SIGINT: unwinds the loop from wherever it is, so the heater goes off now."""


def _on_signal(signum: int, frame: FrameType | None) -> None:
    raise Shutdown(signal.Signals(signum).name)


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
        prog="hermsd", description="Holds a HERMS Hot Liquid Tun at its setpoint."
    )
    parser.add_argument("--version", action="version", version=f"hermsd {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    sensor = sub.add_parser("sensor", help="identify the LM92 and print readings (wiring check)")
    sensor.add_argument("--bus", type=int, default=1, help="I2C bus number (default 1)")
    sensor.add_argument(
        "--address", type=_address, default=0x48, help="LM92 address 0x48..0x4b (default 0x48)"
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
        "/run/hermsd/control.sock; simulating: in --state or a temporary directory)",
    )
    run.set_defaults(func=cmd_run)

    status = sub.add_parser("status", help="what the running daemon is doing")
    status.add_argument("--json", action="store_true", help="print the daemon's reply as JSON")
    _socket_argument(status)
    status.set_defaults(func=cmd_status)

    set_ = sub.add_parser(
        "set", help="change the running daemon's setpoint or mode (until the file's key is edited)"
    )
    set_.add_argument("what", metavar="setpoint|mode", help="what to set")
    set_.add_argument("value", help="°C for setpoint; auto or manual for mode")
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
        help="re-run the logged controller on the logged inputs; exit 1 at the first difference",
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
    _socket_argument(mqtt)
    mqtt.set_defaults(func=cmd_mqtt)
    return parser


def _socket_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--socket",
        type=Path,
        help="the daemon's control socket (default: $RUNTIME_DIRECTORY/control.sock, else "
        "/run/hermsd/control.sock)",
    )


def _address(text: str) -> int:
    try:
        value = int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an address like 0x48, got {text!r}") from None
    if not 0x48 <= value <= 0x4B:
        raise argparse.ArgumentTypeError(f"the LM92 answers at 0x48..0x4b, not {value:#x}")
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


def config_path(path: Path | None, *, simulate: bool) -> Path | None:
    """The config file to use; None means the built-in defaults (simulating without one)."""
    if path is None:
        if simulate and not DEFAULT_CONFIG.exists():
            return None
        path = DEFAULT_CONFIG
    if not path.exists():
        raise UserError(f"no config file at {path} (copy config/hermsd.yaml there, or --config)")
    return path


# -- sensor ---------------------------------------------------------------------------------


def cmd_sensor(args: argparse.Namespace) -> int:
    wait: Callable[[float], None] = time.sleep
    if args.simulate:
        from hermsd.sim.world import simulated_sensor

        sensor, advance = simulated_sensor(args.address)

        def paced(seconds: float) -> None:
            """The simulated tun's time moves on, at the wall clock's pace: a reading a
            second, as from the real sensor (a brewer reads them; a test need not wait)."""
            advance(seconds)
            time.sleep(seconds)

        wait = paced
    else:
        sensor = LM92(open_bus(args.bus), args.address, bus_name=f"/dev/i2c-{args.bus}")
    sensor.identify()
    where = "simulated bus" if args.simulate else f"/dev/i2c-{args.bus}"
    print(f"LM92 found at {args.address:#04x} on {where}")
    count = 0
    while args.count is None or count < args.count:
        if count:
            wait(1.0)
        reading = sensor.read()
        flags = [
            name
            for name, on in (("CRIT", reading.crit), ("HIGH", reading.high), ("LOW", reading.low))
            if on
        ]
        print(f"{reading.celsius:8.4f} °C  raw 0x{reading.raw:04x}  {' '.join(flags)}".rstrip())
        sys.stdout.flush()
        count += 1
    return 0


# -- run ------------------------------------------------------------------------------------


class StatusLine:
    """A live one-line status on a terminal; plain lines every minute otherwise.

    Written by a thread of its own: `update`, which the loop calls every period, only hands
    the text over (the newest wins), so a stalled stdout (a terminal paused with Ctrl-S, a
    busy journal) never holds up the loop. On a terminal, `writing` is held while the line
    is drawn, so that a log line that clears it first is not cut by the next one.
    """

    def __init__(self, stream: TextIO, interval: float = 60.0) -> None:
        self._stream = stream
        self._tty = stream.isatty()
        self._interval = interval
        self._last = -math.inf
        self.text = ""
        self.writing = threading.Lock()
        self._handed = threading.Condition()  # never held while the stream is written
        self._newest: str | None = None
        self._closed = False
        self._writer = threading.Thread(
            target=self._write_updates, name="hermsd-status", daemon=True
        )
        self._writer.start()

    def update(self, text: str) -> None:
        with self._handed:
            self._newest = text
            self._handed.notify()

    def close(self) -> None:
        """Show the newest text, end the thread (once the stream takes it) and clear the line."""
        with self._handed:
            self._closed = True
            self._handed.notify()
        self._writer.join()
        if self._tty:
            with self.writing:
                self.clear()

    def _write_updates(self) -> None:
        while True:
            with self._handed:
                self._handed.wait_for(lambda: self._newest is not None or self._closed)
                text, self._newest, closed = self._newest, None, self._closed
            if text is not None:
                self._show(text)
            if closed:
                return

    def _show(self, text: str) -> None:
        self.text = text
        if self._tty:
            with self.writing:
                self._stream.write("\r\033[K" + text)
                self._stream.flush()
            return
        now = time.monotonic()
        if now - self._last >= self._interval:
            self._last = now
            self._stream.write(text + "\n")
            self._stream.flush()

    def clear(self) -> None:
        if self._tty and self.text:
            self._stream.write("\r\033[K")


def cmd_run(args: argparse.Namespace) -> int:
    from hermsd.hardware.ssr import DeadManThread
    from hermsd.runtime.clock import MonotonicClock
    from hermsd.runtime.daemon import Daemon, guard_outputs

    path = config_path(args.config, simulate=args.simulate)
    config_file = ConfigFile(path, simulated=args.simulate) if path is not None else None
    config = config_file.load() if config_file is not None else config_module.DEFAULT
    if args.simulate:  # the simulated tun's SSR, whatever the file names
        config = config_module.on_simulated_tun(config)
    duration = _duration(args.duration)
    try:
        notifier = Notifier.from_environment()
        check_watchdog(notifier, config.control.period)
    except NotifyEnvironmentError as error:
        raise UserError(str(error)) from None
    latches = _latch_store(args.state, simulate=args.simulate)
    models = ModelStore(latches.directory) if latches is not None else None
    log_dir = args.log
    if log_dir is None and not args.simulate:  # a simulated day never goes into log.dir
        log_dir = Path(config.log.dir) if config.log.dir else None
    locks = _lock_directories(log_dir, latches.directory if latches is not None else None)
    status = StatusLine(sys.stdout)
    _route_log_around(status)
    previous = {sig: signal.signal(sig, _on_signal) for sig in (signal.SIGTERM, signal.SIGINT)}
    previous[signal.SIGHUP] = signal.signal(signal.SIGHUP, signal.SIG_IGN)  # until the loop runs
    try:
        if not args.simulate and args.speed != "1":
            raise UserError("--speed goes with --simulate")
        if not args.simulate and config.output.backend == "sim":
            raise UserError(
                f"{path}: output.backend is 'sim', the simulated tun's output: run with "
                "--simulate, or choose serial-rts, serial-dtr or gpio for the tun"
            )
        # Unwinds in reverse: heater off first, then the dead-man, then the log is finished,
        # then the socket is given up.
        with contextlib.ExitStack() as stack:
            # The tun's socket is taken before any output is opened: a second daemon on the
            # tun is refused here, before it can touch the heater's lines.
            server = _claim_control_socket(_run_socket_path(args, stack))
            stack.callback(server.close)
            if args.simulate:
                from hermsd.sim.world import simulated_daemon

                speed = _speed(args.speed)
                daemon = simulated_daemon(
                    config,
                    speed,
                    on_status=status.update,
                    notifier=notifier,
                    config_file=config_file,
                    latches=latches,
                    models=models,
                )
            else:
                clock = MonotonicClock()
                sensor, (ssr, contactor, element2) = _hardware(config)
                daemon = Daemon(
                    config,
                    clock,
                    sensor,
                    guard_outputs(ssr, contactor, clock, config, element2),
                    notifier=notifier,
                    on_status=status.update,
                    config_file=config_file,
                    latches=latches,
                    models=models,
                )
            recorder = _open_recorder(log_dir, config) if log_dir else None
            if recorder is not None:
                stack.callback(recorder.close)
            daemon.recorder = recorder
            deadman = DeadManThread(daemon.outputs.all())
            deadman.start()
            stack.callback(deadman.stop)
            _serve_control(daemon, server)
            if not args.simulate:  # after the recorder and dead-man threads: they stay ordinary
                stack.enter_context(loop_priority())
            stack.enter_context(daemon)
            signal.signal(signal.SIGHUP, lambda signum, frame: daemon.request_reload())
            daemon.start()
            daemon.run(until=daemon.clock.monotonic() + duration)
    except Shutdown as why:
        log.info("%s received", why)
    except StateError as error:
        raise _latch_file_refused(error) from None
    finally:
        status.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        for lock in locks:
            lock.release()
    return 0


def _run_socket_path(args: argparse.Namespace, stack: contextlib.ExitStack) -> Path:
    """Where `run` listens: --socket, $RUNTIME_DIRECTORY, or for a simulated tun a place of
    its own (the state directory, else a temporary one), so it never takes the service's."""
    if args.socket is not None or not args.simulate or os.environ.get("RUNTIME_DIRECTORY"):
        return default_socket_path(args.socket)
    if args.state is not None:
        return Path(args.state, SOCKET_NAME)
    return Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="hermsd-")), SOCKET_NAME)


def _claim_control_socket(path: Path) -> ControlServer:
    """The control socket at `path`, bound but not served yet; UserError if another daemon
    answers there (or it cannot be made)."""
    server = ControlServer(path)
    try:
        server.bind()
    except OSError as error:
        server.close()
        raise UserError(
            f"cannot open the control socket {path}: {error.strerror or error} "
            "(another hermsd on this tun? else choose a place with --socket PATH)"
        ) from None
    return server


def _serve_control(daemon: Daemon, server: ControlServer) -> None:
    """Serve the control socket beside the loop (started before it takes real-time priority,
    so its thread stays ordinary); said on the first line of output."""
    from hermsd.api.link import LoopLink

    link = LoopLink(daemon)
    server.answer_with(link.status_line, link.history_line, link.arrived)
    server.start()
    link.attach(server)
    print(f"control socket {server.path}", flush=True)


def _hardware(config: Config) -> tuple[LM92, tuple[Switch, Switch | None, Switch | None]]:
    """The tun's sensor, SSR, contactor and second element as the config names them (outputs
    closed on failure)."""
    opened: list[Switch] = []
    try:
        ssr = _open_output(config.output)
        opened.append(ssr)
        contactor = _open_output(config.contactor) if config.contactor.backend != "none" else None
        if contactor is not None:
            opened.append(contactor)
        if config.element2.backend == "sim":
            raise UserError("element2.backend is 'sim', the simulated tun's: run with --simulate")
        element2 = _open_output(config.element2) if config.element2.backend != "none" else None
        if element2 is not None:
            opened.append(element2)
        bus = open_bus(config.sensor.bus)
    except BaseException:
        for switch in opened:
            switch.close()
        raise
    sensor = LM92(bus, config.sensor.address, bus_name=f"/dev/i2c-{config.sensor.bus}")
    return sensor, (ssr, contactor, element2)


def _lock_directories(log_dir: Path | None, state_dir: Path | None) -> list[DirectoryLock]:
    """Lock the log and state directories, before any output is touched.

    UserError (naming the other daemon's pid) when one is held: the outputs, the log and the
    latches belong to that daemon. A log directory that cannot be made is said by the
    recorder; one that cannot hold a lock file is said here, and run without it. A state
    directory that cannot be made, locked, or hold a latch file written as a save writes it
    (`LatchStore.probe`) is a UserError: a latched alarm there would not survive a restart,
    and the restart would heat over the fault.
    """
    locks: list[DirectoryLock] = []
    wanted = [(log_dir, "log directory"), (state_dir, "state directory")]
    seen: set[Path] = set()
    try:
        for directory, role in wanted:
            if directory is None or directory.resolve() in seen:
                continue
            seen.add(directory.resolve())
            if role == "state directory":
                locks.append(_claim_state_directory(directory))
                continue
            try:
                directory.mkdir(parents=True, exist_ok=True)
            except OSError:
                continue
            lock = DirectoryLock(directory)
            try:
                lock.acquire(role)
            except OSError as error:
                log.warning("cannot lock the %s %s: %s", role, directory, error.strerror or error)
                continue
            locks.append(lock)
    except (InstanceError, UserError) as error:
        for held in locks:
            held.release()
        raise UserError(str(error)) from None
    return locks


def _claim_state_directory(directory: Path) -> DirectoryLock:
    """The state directory made, locked and shown to keep a latch file; UserError if not."""
    lock = DirectoryLock(directory)
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise _state_refused(f"cannot make the state directory {directory}", error) from None
    try:
        lock.acquire("state directory")
    except OSError as error:
        raise _state_refused(f"cannot lock the state directory {directory}", error) from None
    try:
        LatchStore(directory).probe()
    except OSError as error:
        lock.release()
        raise _state_refused(f"cannot keep latched alarms in {directory}", error) from None
    return lock


def _state_refused(what: str, error: OSError) -> UserError:
    return UserError(
        f"{what}: {error.strerror or error}: a latched alarm would not survive a restart; "
        "not started, heater off (free space or make it writable, or give another with --state)"
    )


def _latch_store(directory: Path | None, *, simulate: bool) -> LatchStore | None:
    """Where latched alarms are kept (None: a simulated tun's, kept nowhere); UserError when
    the directory cannot be made."""
    if directory is None:
        if simulate and not os.environ.get("STATE_DIRECTORY"):
            return None  # a simulated tun's alarms need not outlive it
        directory = _default_state_directory()
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise _state_refused(f"cannot make the state directory {directory}", error) from None
    return LatchStore(directory)


def _latch_file_refused(error: StateError) -> UserError:
    """A latch file the daemon cannot read: it does not start (nor passes check-config)."""
    return UserError(f"{error} (inspect it; `hermsd reset-alarm` replaces it)")


def _default_state_directory() -> Path:
    """systemd's StateDirectory= (the first of them), else /var/lib/hermsd."""
    from_systemd = os.environ.get("STATE_DIRECTORY", "").split(":")[0]
    return Path(from_systemd) if from_systemd else DEFAULT_STATE


def _open_recorder(directory: Path, config: Config) -> Recorder:
    """The flight recorder, after recovering whatever a crash left in `directory`.

    A directory that cannot be made is said here; the recorder says the rest (the daemon
    repeats it while it lasts). A file size limit (`ulimit -f`) must fail a write with
    EFBIG, which the recorder reports, not kill the daemon with SIGXFSZ.
    """
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        log.warning("log failing: cannot create %s: %s", directory, error.strerror or error)
    else:
        try:
            for outcome in recover_directory(directory):
                if isinstance(outcome, NotRecovered):
                    log.warning("log %s not recovered: %s", outcome.part, outcome)
                else:
                    log.warning("recovered %s", outcome.describe())
        except OSError as error:
            log.warning("log recovery in %s failed: %s", directory, error)
    log_cfg = config.log
    return Recorder(
        directory,
        rotate_s=log_cfg.rotate_hours * 3600.0,
        flush_interval=log_cfg.flush_interval,
        sync_interval=log_cfg.sync_interval,
        queue_size=log_cfg.queue_size,
        metadata={"tun": config.tun.name},
    )


def _open_output(section: OutputConfig | ContactorConfig | Element2Config) -> Switch:
    """The hardware a config section names, or a UserError that says why not."""
    channel = getattr(section, "channel", None)
    try:
        return open_hardware_switch(
            section.backend,
            port=section.port,
            chip=section.chip,
            line=section.line,
            active_low=section.active_low,
            channel=channel or 1,
            baud=getattr(section, "baud", 9600),
        )
    except (OSError, ValueError, ImportError) as error:
        where = describe_output(
            section.backend,
            port=section.port,
            chip=section.chip,
            line=section.line,
            channel=channel,
        )
        raise UserError(f"cannot open {where}: {error}") from None


def _route_log_around(status: StatusLine) -> None:
    """Log lines on a terminal first clear the live status line (where they are written)."""
    handler = logging.getLogger("hermsd").handlers[0]
    if isinstance(handler, DroppingQueueHandler):
        handler = handler.target
    original = handler.emit

    def emit(record: logging.LogRecord) -> None:
        with status.writing:
            status.clear()
            original(record)

    handler.emit = emit  # type: ignore[method-assign]


def _duration(text: str | None) -> float:
    if text is None:
        return math.inf
    try:
        return parse_duration(text)
    except ValueError as error:
        raise UserError(f"--duration: {error}") from None


def _speed(text: str) -> float:
    if text == "max":
        return math.inf
    try:
        speed = float(text)
    except ValueError:
        raise UserError(f"--speed: expected a number or 'max', got {text!r}") from None
    if not (speed > 0 and math.isfinite(speed)):
        raise UserError(f"--speed: expected a positive number or 'max', got {text!r}")
    return speed


# -- simulate -------------------------------------------------------------------------------


def cmd_simulate(args: argparse.Namespace) -> int:
    from hermsd.sim import scenario as scenario_module
    from hermsd.sim.hlt import PlantFailed, PlantLoadError, load_plant

    config = config_module.load(args.config) if args.config else config_module.DEFAULT
    if args.log is not None:
        _check_log_directory(args.log)
    locks = _lock_directories(args.log, args.state)
    try:
        scenario = (
            scenario_module.load_scenario(args.scenario)
            if args.scenario
            else scenario_module.DEFAULT
        )
        outside_plant = load_plant(args.plant) if args.plant else None
        if args.state is not None:
            args.state.mkdir(parents=True, exist_ok=True)
        result = scenario_module.run(
            scenario, config, log_dir=args.log, outside_plant=outside_plant, state_dir=args.state
        )
    except (scenario_module.ScenarioError, PlantLoadError, PlantFailed) as error:
        raise UserError(str(error)) from None
    except OSError as error:
        raise UserError(f"cannot use the state directory {args.state}: {error}") from None
    except StateError as error:
        raise UserError(
            f"{error} (inspect it; `hermsd reset-alarm --state DIR` replaces it)"
        ) from None
    finally:
        for lock in locks:
            lock.release()
    summary = result.summary
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        _print_summary(summary)
    return 0


def _check_log_directory(directory: Path) -> None:
    """UserError unless a log can be written in `directory` (made when missing).

    A brewer who asked for a log must get one or be told so before the run, not find a
    run's worth of warnings and no log after it.
    """
    try:
        directory.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=directory):
            pass
    except OSError as error:
        why = "it is not a directory" if isinstance(error, FileExistsError) else error.strerror
        raise UserError(f"--log {directory}: cannot write a log there: {why or error}") from None


def _print_summary(summary: dict[str, Any]) -> None:
    """Key and value a line (a table's keys prefixed with its name); files and alarms in words."""
    lines: list[tuple[str, Any]] = []
    for key, value in summary.items():
        if isinstance(value, dict):
            lines.extend((f"{key}.{name}", item) for name, item in value.items())
        elif key not in ("files", "alarms", "runs", "learning", "reach", "steps"):
            lines.append((key, value))
    width = max((len(key) for key, _ in lines), default=0)
    for report in summary.get("files", []):
        print(_file_line(report))
    runs = summary.get("runs", [])
    for number, run in enumerate(runs if len(runs) > 1 else [], start=1):
        print(
            f"run {number} of {len(runs)} (id {run['run'] or 'not logged'}), from "
            f"{run['start_utc']}: {', '.join(run['files'])}"
        )
    for key, value in lines:
        print(f"{key:{width}} {value}")
    for alarm in summary.get("alarms", []):
        print(_alarm_line(alarm))
    for item in (*summary.get("learning", []), *summary.get("reach", [])):
        print(f"at {item['at_s']} s: {item['message']}")
    for item in summary.get("schedule", []):
        words = f": {item['message']}" if item["message"] else ""  # older logs have none
        print(f"at {item['at_s']} s: ready_by {item['event']}{words}")
    from hermsd.program.quality import step_lines

    for line in step_lines(summary.get("steps", [])):
        print(line)


def _file_line(report: dict[str, Any]) -> str:
    if report["finished"]:
        state = "finished"
    else:
        state = f"not finished, complete up to byte {report['cut_at']} of {report['size']}"
        if report["cut_reason"]:
            state += f" ({report['cut_reason']})"
    damaged = "".join(f"; {damage}" for damage in report.get("damaged", []))
    return (
        f"file {report['path']}: {state}; {report['messages']} messages recovered, "
        f"{report['periods']} control periods{damaged}"
    )


def _alarm_line(alarm: dict[str, Any]) -> str:
    line = f"alarm {alarm['kind']} at {alarm['at_s']} s"
    if "heater_off_after_s" in alarm:
        line += f", heater off after {alarm['heater_off_after_s']} s"
    message = alarm["message"]
    return line + (f": {message}" if message is not None else " (its event was not recovered)")


# -- program --------------------------------------------------------------------------------


def cmd_program_import(args: argparse.Namespace) -> int:
    """Write the program of a BeerXML recipe's mash; an existing file is never replaced."""
    from hermsd.program import beerxml

    try:
        text = beerxml.to_yaml(beerxml.read(args.file, args.recipe))
    except beerxml.BeerXMLError as error:
        raise UserError(str(error)) from None
    if args.output is None:
        sys.stdout.write(text)
        return 0
    _write_new(args.output, lambda temporary: temporary.write_text(text, encoding="utf-8"))
    return 0


def _write_new(path: Path, write: Callable[[Path], object]) -> None:
    """`write_new`, its failures said: an existing file is refused, never replaced."""
    try:
        write_new(path, write)
    except FileExistsError:
        raise UserError(f"{path}: exists; name another file or remove it first") from None
    except OSError as error:
        raise UserError(f"{path}: cannot write: {error.strerror or error}") from None


# -- replay ---------------------------------------------------------------------------------


def cmd_replay(args: argparse.Namespace) -> int:
    from hermsd.log import reader, replay

    status = 0
    try:
        overrides = None if args.what_if is None else replay.parse_what_if(args.what_if)
        if args.plot is not None:
            from hermsd.log import dayplot

            dayplot.check_format(args.plot)
        if not args.files:
            raise UserError("replay: name the .mcap (or .mcap.part) files of one day")
        log = reader.load(args.files)
        result: dict[str, Any] = {}
        if args.verify:
            verification = replay.verify(log.entries)
            if verification.verified == 0 and verification.mismatch is None:
                raise reader.ReplayError(
                    "nothing to verify: the controller never stepped from a known state "
                    "(no auto period with a PV, or the records of its start are missing)"
                )
            status = 0 if verification.mismatch is None else 1
            result["verify"] = dataclasses.asdict(verification)
        if overrides is not None:
            logging.getLogger("hermsd").setLevel(logging.WARNING)  # not the simulated daemon's
            result["what_if"] = dataclasses.asdict(replay.what_if(log, overrides))
        if not result:
            result = replay.summarise(log)
        if args.csv is not None:
            _write_new(args.csv, partial(replay.write_csv, log))
        if args.plot is not None:
            _write_new(args.plot, partial(replay.plot, log))
    except reader.ReplayError as error:
        raise UserError(str(error)) from None
    if args.json:
        print(json.dumps(result, indent=2))
    elif "verify" in result or "what_if" in result:
        if "verify" in result:
            _print_verification(result["verify"])
        if "what_if" in result:
            _print_what_if(result["what_if"])
    else:
        _print_summary(result)
    return status


def _print_verification(verification: dict[str, Any]) -> None:
    verified, unknown = verification["verified"], verification["unknown_state"]
    skipped = f" ({unknown} steps after missing records not re-run)" if unknown else ""
    mismatch = verification["mismatch"]
    if mismatch is None:
        print(f"{verified} periods verified{skipped}")
        return
    print(
        f"period k={mismatch['k']} (t {mismatch['t']!r} s) differs: {mismatch['name']} logged "
        f"{mismatch['logged']!r}, recomputed {mismatch['recomputed']!r}"
    )
    print(f"{verified} periods verified before it{skipped}")


def _print_what_if(what_if: dict[str, Any]) -> None:
    m = what_if["model"]
    print(
        f"tun model: K {m['gain']:.4g} °C/%, τ {m['tau']:.0f} s, θ {m['dead_time']:g} s, "
        f"ambient {m['ambient']:.2f} °C, start {m['start']:.2f} °C; fit RMS {m['rms']:.4f} °C "
        f"over the first {m['fit_s']:g} s"
    )
    rows = [("", "logged", "what-if")]
    settings = what_if["settings"]
    rows += [(k, settings["logged"][k], settings["what_if"][k]) for k in settings["logged"]]
    rows += [(k, what_if["logged"][k], what_if["what_if"][k]) for k in what_if["logged"]]
    width = max(len(str(row[0])) for row in rows)
    column = max(len(str(row[1])) for row in rows)
    for key, logged, new in rows:
        print(f"{key:{width}} {logged!s:{column}} {new}")


def cmd_tune(args: argparse.Namespace) -> int:
    from hermsd.commissioning import tune
    from hermsd.log import reader

    relay_only = ("setpoint", "hysteresis", "amplitude")
    given_relay = [f"--{name}" for name in relay_only if getattr(args, name) is not None]
    if args.files[:1] == [Path("relay")]:
        return _tune_relay(args)
    if given_relay:
        raise UserError(f"{', '.join(given_relay)}: for `hermsd tune relay` only")
    if args.files[:1] == [Path("step")]:
        return _tune_step(args)
    step_only = ("output", "limit", "config", "simulate", "plant", "log")
    given = [f"--{name}" for name in step_only if getattr(args, name) not in (None, False)]
    if given:
        experiments = "" if set(given) <= {"--output", "--limit"} else " or `tune relay`"
        raise UserError(f"{', '.join(given)}: for `hermsd tune step`{experiments} only")
    try:
        if (args.table is None) == (not args.files):
            raise tune.TuneError(
                "give either the log files of a brew day or --table K=..,tau=..,theta=.."
            )
        if args.table is not None:
            if args.write is not None:
                raise tune.TuneError("--write takes its settings from log files, not --table")
            model = tune.parse_table(args.table)
            result, lines = tune.table_json(model), tune.table_lines(model)
        else:
            tuned = tune.from_log(reader.load(args.files), args.ambient)
            result, lines = tune.tuned_json(tuned), tune.tuned_lines(tuned)
            if args.write is not None:
                diff = tune.write_tuned(args.write, tuned)
                result["written"] = {"file": os.fspath(args.write), "diff": diff}
                lines += ["", diff.rstrip("\n") if diff else f"{args.write}: already so"]
    except (tune.TuneError, reader.ReplayError) as error:
        raise UserError(str(error)) from None
    print(json.dumps(result, indent=2) if args.json else "\n".join(lines))
    return 0


def _tune_step(args: argparse.Namespace) -> int:
    """`hermsd tune step`: the experiment on the tun (or the simulated one), then the fit."""
    from hermsd.commissioning import step_response

    if len(args.files) > 1:
        raise UserError(f"tune step takes no files (got {', '.join(map(str, args.files[1:]))})")
    config = _tune_config(args)
    control = config.control
    limit = control.setpoint if args.limit is None else args.limit
    if not (math.isfinite(limit) and limit <= control.setpoint < config.safety.max_temp):
        raise UserError(
            f"--limit {limit:g}: the step stops at most at the setpoint, {control.setpoint:g} °C "
            f"(below safety.max_temp, {config.safety.max_temp:g} °C)"
        )
    if args.output is not None and not (
        step_response.MIN_OUTPUT <= args.output <= control.max_output
    ):
        raise UserError(
            f"--output {args.output:g}: the step must be {step_response.MIN_OUTPUT:g} to "
            f"{control.max_output:g} % (control.max_output) for K and τ to show"
        )

    def build(daemon: Daemon) -> step_response.StepExperiment:
        return step_response.StepExperiment(
            daemon,
            args.output,
            limit,
            args.ambient,
            lambda progress: _say_progress(step_response.progress_line(progress)),
            fits=fits,
        )

    with _tune_fits(args.simulate) as fits:
        experiment = _run_tune(args, config, build, step_response.run)
    result, lines = step_response.result_json(experiment), step_response.result_lines(experiment)
    return _tune_written(args, result, lines, experiment.stopped, step_response.write, experiment)


def _tune_relay(args: argparse.Namespace) -> int:
    """`hermsd tune relay`: heat-up, hold, relay cycles on the tun (or the simulated one)."""
    from hermsd.commissioning import relay

    if len(args.files) > 1:
        raise UserError(f"tune relay takes no files (got {', '.join(map(str, args.files[1:]))})")
    given = [f"--{name}" for name in ("output", "limit") if getattr(args, name) is not None]
    if given:
        raise UserError(f"{', '.join(given)}: for `hermsd tune step` only")
    config = _tune_config(args)
    setpoint = config.control.setpoint if args.setpoint is None else args.setpoint
    if not (math.isfinite(setpoint) and 0.0 < setpoint < config.safety.max_temp - 1.0):
        raise UserError(
            f"--setpoint {setpoint:g}: the relay holds above 0 °C and at least 1 °C below "
            f"safety.max_temp ({config.safety.max_temp:g} °C)"
        )
    hysteresis = relay.HYSTERESIS_C if args.hysteresis is None else args.hysteresis
    if not (math.isfinite(hysteresis) and relay.LSB_C <= hysteresis <= 0.25):
        raise UserError(
            f"--hysteresis {hysteresis:g}: the band must be {relay.LSB_C:g} (one LM92 step) to "
            "0.25 °C: narrower, the sensor's noise switches the relay; wider, the swing leaves "
            "±0.5 °C"
        )
    max_output = config.control.max_output
    if args.amplitude is not None and not (relay.MIN_AMPLITUDE <= args.amplitude <= max_output / 2):
        raise UserError(
            f"--amplitude {args.amplitude:g}: the relay's ± output must be "
            f"{relay.MIN_AMPLITUDE:g} to {max_output / 2:g} % (half control.max_output) for "
            "K and τ to show"
        )

    def build(daemon: Daemon) -> relay.RelayExperiment:
        return relay.RelayExperiment(
            daemon,
            setpoint,
            hysteresis,
            args.amplitude,
            args.ambient,
            lambda progress: _say_progress(relay.progress_line(progress)),
            fits=fits,
        )

    with _tune_fits(args.simulate) as fits:
        experiment = _run_tune(args, config, build, relay.start)
    result, lines = relay.result_json(experiment), relay.result_lines(experiment)
    return _tune_written(args, result, lines, experiment.stopped, relay.write, experiment)


def _say_progress(line: str) -> None:
    """A tune test's progress line, called on the loop: through the log's queue, so that a
    stalled stderr never holds the experiment up (hermsd/runtime/log_queue.py), in order with the
    daemon's own lines."""
    log.info("%s", line)


def _tune_config(args: argparse.Namespace) -> config_module.Config:
    if args.plant and not args.simulate:
        raise UserError("--plant goes with --simulate")
    path = config_path(args.config, simulate=args.simulate)
    config = ConfigFile(path).load() if path is not None else config_module.DEFAULT
    return config_module.on_simulated_tun(config) if args.simulate else config


_Experiment = TypeVar("_Experiment", bound="step_response.Experiment")


@contextlib.contextmanager
def _tune_fits(simulate: bool) -> Iterator[Any]:
    """Where a tune test's fits run: a simulated one's at once (the same run every time, on
    its virtual clock), the tun's in a process of its own, beside the loop."""
    from hermsd.commissioning import step_response

    if simulate:
        yield at_once
        return
    try:
        process = step_response.FitProcess()
    except (OSError, NotImplementedError, BrokenExecutor) as error:
        # no process here (no /dev/shm, no semaphores, a limit), or it died as it started
        why = str(error) or type(error).__name__
        log.warning("fits run on a thread beside the loop (no process for them: %s)", why)
        yield step_response.fit_in_thread
        return
    try:
        yield process
    finally:
        process.close()


def _run_tune(
    args: argparse.Namespace,
    config: config_module.Config,
    build: Callable[[Daemon], _Experiment],
    start: Callable[[_Experiment, tuple[type[BaseException], ...]], None],
) -> _Experiment:
    """A tune experiment through the daemon on the tun (or the simulated one), with the
    service's directories locked; the heater is off when this returns, whatever happened."""
    from hermsd.runtime.daemon import Daemon, guard_outputs
    from hermsd.sim.hlt import PlantFailed

    log_dir = args.log
    if log_dir is None and not args.simulate:
        log_dir = Path(config.log.dir) if config.log.dir else None
    # The service's state directory too: the test must not run beside it, and its latched
    # alarms (an over-temperature, a stuck SSR) keep the heater off during the test as well.
    latches = None if args.simulate else _latch_store(None, simulate=False)
    locks = _lock_directories(log_dir, latches.directory if latches is not None else None)
    previous = {sig: signal.signal(sig, _on_signal) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        with contextlib.ExitStack() as stack:
            if args.simulate:
                from hermsd.sim.clock import VirtualClock
                from hermsd.sim.hlt import PlantLoadError, load_plant
                from hermsd.sim.world import build_world

                clock = VirtualClock()
                try:
                    tun = load_plant(args.plant) if args.plant else None
                    world = build_world(config, clock, SIMULATED_STEP_TUN, tun=tun)
                except (PlantLoadError, TypeError, ValueError) as error:
                    raise UserError(str(error)) from None
                daemon = Daemon(config, clock, world.sensor, world.outputs)
                recorder = (
                    Recorder(log_dir, now=clock.monotonic, lossless=True) if log_dir else None
                )
            else:
                from hermsd.hardware.ssr import DeadManThread
                from hermsd.runtime.clock import MonotonicClock

                hardware_clock = MonotonicClock()
                sensor, outputs = _hardware(config)
                daemon = Daemon(
                    config,
                    hardware_clock,
                    sensor,
                    guard_outputs(outputs[0], outputs[1], hardware_clock, config, outputs[2]),
                    latches=latches,
                )
                recorder = _open_recorder(log_dir, config) if log_dir else None
            if recorder is not None:
                stack.callback(recorder.close)
            daemon.recorder = recorder
            if not args.simulate:
                deadman = DeadManThread(daemon.outputs.all())
                deadman.start()
                stack.callback(deadman.stop)
            experiment = build(daemon)
            start(experiment, (Shutdown, KeyboardInterrupt))
    except StateError as error:
        raise _latch_file_refused(error) from None
    except PlantFailed as error:  # the heater is off: the daemon stopped on it
        raise UserError(str(error)) from None
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        for lock in locks:
            lock.release()
    return experiment


def _tune_written(
    args: argparse.Namespace,
    result: dict[str, Any],
    lines: list[str],
    stopped: str | None,
    write: Callable[[Any, Path], str],
    experiment: object,
) -> int:
    """Write the settings if asked, print the result; exit 1 after an alarm or a refusal."""
    from hermsd.commissioning import step_response, tune

    failed = (stopped or "").startswith(step_response.ABORTED[0])
    try:
        if args.write is not None:
            diff = write(experiment, args.write)
            result["written"] = {"file": os.fspath(args.write), "diff": diff}
            lines += ["", diff.rstrip("\n") if diff else f"{args.write}: already so"]
    except tune.TuneError as error:
        result["written"] = {"file": os.fspath(args.write), "refused": str(error)}
        lines += ["", str(error)]
        failed = True
    print(json.dumps(result, indent=2) if args.json else "\n".join(lines))
    return 1 if failed else 0  # an alarm, or settings asked for and not written


SIMULATED_STEP_TUN = {"model": "foptd", "noise_c": 0.03, "seed": 1}
"""`tune step --simulate`: the seed's identified tun, read with the family's sensor noise."""


# -- safe-off and check-config --------------------------------------------------------------


def cmd_safe_off(args: argparse.Namespace) -> int:
    """Every output the config file names, off; exit 1 unless all of them are known to be off.

    The file is read as far as it can be (`config.load_outputs`), so a bad edit, the likely
    reason the daemon just stopped, cannot keep the element on.
    """
    from hermsd.hardware.safe_off import switch_off

    found = config_module.load_outputs(args.config or DEFAULT_CONFIG)
    report = switch_off(found, open_hardware_switch)
    for line in report.switched:
        print(line)
    for line in report.notes + report.failures:
        print(f"hermsd safe-off: {line}", file=sys.stderr)
    if report.failures:
        print("hermsd safe-off: not every output is known to be off", file=sys.stderr)
        return 1
    return 0


def cmd_reset_alarm(args: argparse.Namespace) -> int:
    """Clear the latched alarms: through the socket when a daemon runs, else by a request
    in the state directory that the daemon takes when it starts."""
    try:
        seen = _ask(args.socket, Status())["alarms"]
    except NoDaemonError:
        return _request_reset_in_state(args)
    if not seen:
        print("no alarm to reset")
        return 0
    # Only what was seen here: an alarm raised in between stays, to be read first.
    reply = _ask(args.socket, ResetAlarms(tuple(seen)))
    print(f"reset: {', '.join(seen)}; now: {', '.join(reply['alarms']) or 'no alarm'}")
    return 0


def _request_reset_in_state(args: argparse.Namespace) -> int:
    """Ask the daemon to clear the latched alarms it keeps in its state directory."""
    directory: Path = args.state or _default_state_directory()
    store = LatchStore(directory)
    try:
        try:
            latches = store.load()
        except StateError as error:
            store.save(Latches())
            print(f"{error}: replaced by an empty one; no alarm stays latched")
            return 0
        if not latches.alarms:
            print(f"no latched alarm in {directory}")
            return 0
        store.request_reset([alarm.kind for alarm in latches.alarms])
    except OSError as error:
        raise UserError(
            f"{directory}: {error.strerror or error} (run as root or as the user hermsd runs as)"
        ) from None
    for alarm in latches.alarms:
        when = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime(alarm.wall_ns / 1e9))
        print(f"{alarm.kind}, latched {when}: {alarm.message}")
    print(
        "reset asked: a running hermsd clears these within one control period, "
        "a stopped one when it starts"
    )
    return 0


# -- status and set, through the control socket ---------------------------------------------


def _step_argument(parser: argparse.ArgumentParser, text: str) -> None:
    """--step N: the step (numbered from 1, as `hermsd status` shows it) a confirm or next is
    for; without it, the step current a second before the daemon receives the request."""
    parser.add_argument(
        "--step", type=_step_number, metavar="N", help=text + "; default: the current step"
    )


def _step_number(text: str) -> int:
    """A step as numbered from 1, to the protocol's index from 0."""
    if not text.isdigit() or int(text) < 1:
        raise argparse.ArgumentTypeError(f"expected a step number from 1, got {text!r}")
    return int(text) - 1


def _ask(socket_path: Path | None, request: Request) -> dict[str, Any]:
    """The daemon's reply; a refusal is a UserError (exit 2) with the daemon's one line."""
    try:
        reply = ask(default_socket_path(socket_path), request)
    except ReplyError as error:
        raise Unreachable(str(error)) from None
    if not reply["ok"]:
        raise UserError(str(reply.get("error", "refused")))
    return reply


def cmd_status(args: argparse.Namespace) -> int:
    try:
        reply = _ask(args.socket, Status())
    except NoDaemonError as error:
        raise Unreachable(str(error)) from None
    if args.json:
        print(json.dumps(reply, indent=2, ensure_ascii=False))
        return 0
    line = status_line(
        reply["tun"],
        reply["pv"],
        reply["setpoint"],
        reply["output"],
        reply["state"],
        reply.get("output2"),
    )
    print(f"{line} (applied {reply['applied']:.0f} %), {_mode_text(reply)}")
    print(f"alarms: {', '.join(reply['alarms']) or 'none'}")
    for kind, reason in reply.get("alarm_reasons", {}).items():
        print(f"  {kind}: {reason}")
    for warning in reply.get("warnings") or []:
        print(f"warning: {warning}")
    for key, values in reply["runtime"].items():
        print(f"{key} {values['running']} set at runtime (config file: {values['file']})")
    model = reply["model"]
    print(
        f"tun model ({model['from']}): K {model['gain']:.4g} °C/%, "
        f"τ {model['tau']:.0f} s, θ {model['dead_time']:.0f} s, room {model['ambient']:.1f} °C"
    )
    learned = reply["learned"]
    print(f"learned: {learned['text'] if learned is not None else 'nothing yet'}")
    if reply.get("program") is not None:
        print(program_line(reply["program"]))
    print("safety limits in force:")
    for row in reply["limits"]:
        print(f"  {row}")
    return 0


def cmd_set(args: argparse.Namespace) -> int:
    request: Request
    if args.what == "setpoint":
        if args.output is not None:
            raise UserError("--output goes with `set mode manual`")
        request = SetSetpoint(_finite(args.value, "setpoint", "°C"))
    elif args.what == "mode":
        if args.value not in ("auto", "manual"):
            raise UserError(f"mode: expected auto or manual, got {args.value!r}")
        if args.output is not None and args.value != "manual":
            raise UserError("--output goes with `set mode manual`")
        output = None if args.output is None else _finite(args.output, "--output", "%")
        request = SetMode(args.value, output)
    else:
        raise UserError(f"set: expected setpoint or mode, got {args.what!r}")
    try:
        reply = _ask(args.socket, request)
    except NoDaemonError as error:
        raise Unreachable(str(error)) from None
    print(f"now: setpoint {reply['setpoint']:g} °C, {_mode_text(reply)}")
    return 0


def cmd_program(args: argparse.Namespace) -> int:
    from hermsd.program import model

    needs_file = args.action in ("check", "start", "import")
    if needs_file != (args.file is not None):
        raise UserError(
            f"program {args.action}: "
            + ("name the program file" if needs_file else "takes no file")
        )
    if args.action != "import" and (args.output is not None or args.recipe is not None):
        raise UserError("-o/--output and --recipe go with `program import`")
    if args.action == "import":
        return cmd_program_import(args)
    if args.ready_by is not None and args.action != "start":
        raise UserError("--ready-by goes with `program start`")
    if args.step is not None and args.action != "next":
        raise UserError("--step goes with `program next` (and `hermsd confirm`)")
    if args.ready_by is not None and model.READY_BY.fullmatch(args.ready_by) is None:
        raise UserError(f"--ready-by: {args.ready_by!r} is not a local time (HH:MM, e.g. 06:30)")
    request: Request
    if needs_file:
        program = model.load(args.file)  # a ConfigError: every problem, exit 2
        if args.action == "check":
            print(f"{args.file}: program {program.name!r}, {len(program.steps)} steps, valid")
            for number, step in enumerate(program.steps, 1):
                print(f"  {number}. {model.describe_step(step)}")
            return 0
        request = ProgramStart(program, args.ready_by)
    else:
        request = ProgramAction(args.action, args.step)
    try:
        reply = _ask(args.socket, request)
    except NoDaemonError as error:
        raise Unreachable(str(error)) from None
    state = reply.get("program")
    if args.action == "stop":
        print(f"program stopped; setpoint {reply['setpoint']:g} °C")
    else:
        print(program_line(state) if state is not None else "no program runs")
    return 0


def cmd_confirm(args: argparse.Namespace) -> int:
    try:
        reply = _ask(args.socket, ProgramAction("confirm", args.step))
    except NoDaemonError as error:
        raise Unreachable(str(error)) from None
    state = reply.get("program")
    print(program_line(state) if state is not None else "no program runs")
    return 0


def program_line(state: dict[str, Any]) -> str:
    """The status reply's `program` in one line."""
    step = state["step"]
    line = (
        f"program {state['name']!r}: {state['state']}, step {step['index'] + 1}/{state['steps']} "
        f"{step['name']!r} at {step['setpoint']:g} °C"
    )
    if state["time_left_s"] is not None:
        line += f", {state['time_left_s'] / 60.0:.1f} min of its hold left"
    if state["message"] is not None:
        line += f", waits for: {state['message']} (`hermsd confirm`)"
    if state["starts_at"] is not None:
        line += f", heating starts at {state['starts_at']}"
    if state.get("late") is not None:
        line += f", LATE: {state['late']}"
    if state["next"] is not None:
        line += f"; next {state['next']!r}"
    return line


def _mode_text(reply: dict[str, Any]) -> str:
    mode = str(reply["mode"])
    return mode + (f" at {reply['manual_output']:g} %" if mode == "manual" else "")


def _finite(text: str, name: str, unit: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise UserError(f"{name}: expected a number in {unit}, got {text!r}") from None
    if not math.isfinite(value):
        raise UserError(f"{name}: expected a number in {unit}, got {text!r}")
    return value


def _state_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--state",
        type=Path,
        help=f"the daemon's state directory (default: $STATE_DIRECTORY, else {DEFAULT_STATE})",
    )


def cmd_web(args: argparse.Namespace) -> int:
    try:
        from hermsd.web import main as web
    except ImportError as error:
        raise UserError(
            f"hermsd web needs the web extra ({error.name} is not installed): "
            "install hermsd with `--extra web` (uv) or as `hermsd[web]` (pip)"
        ) from None
    try:
        if args.hash_password:
            return web.print_hash()
        path = config_path(args.config, simulate=False)
        assert path is not None
        return web.run(config_module.load(path), default_socket_path(args.socket), args.listen)
    except web.WebSetupError as error:
        raise UserError(str(error)) from None


def cmd_forget_model(args: argparse.Namespace) -> int:
    """Delete the learned model; the daemon uses the config's prior from its next start."""
    directory: Path = args.state or _default_state_directory()
    store = ModelStore(directory)
    try:
        forgotten = store.forget()
    except OSError as error:
        # Only a refused permission is the user's to fix by who runs it; a state path that is
        # not a directory is the option's (or the config's) to fix.
        fix = (
            "run as root or as the user hermsd runs as"
            if isinstance(error, PermissionError)
            else f"is {directory} the state directory? --state names it"
        )
        raise UserError(f"{store.path}: {error.strerror or error} ({fix})") from None
    if forgotten:
        print(f"forgot {store.path}: hermsd starts from the config's model at its next start")
    else:
        print(f"nothing learned in {directory}")
    return 0


def cmd_recover(args: argparse.Namespace) -> int:
    failed = 0
    for path in args.files:
        try:
            lock = _hold_for_recovery(path.parent)
        except InstanceError as error:
            daemon = "a running hermsd" + (f" (pid {error.holder})" if error.holder else "")
            print(
                f"hermsd recover: {path}: refused, nothing touched: {path.parent} is the log "
                f"directory of {daemon}: its .part is the log being written (recover is for "
                "what a crash left); stop that daemon first",
                file=sys.stderr,
            )
            failed += 1
            continue
        try:
            print(recover(path).describe())
        except (OSError, ValueError) as error:
            print(f"hermsd recover: {path}: {error}", file=sys.stderr)
            failed += 1
        finally:
            if lock is not None:
                lock.release()
    return EXIT_USAGE if failed else 0


def _hold_for_recovery(directory: Path) -> DirectoryLock | None:
    """The log directory's lock, held while its `.part` files are recovered.

    A `.part` in the directory of a living daemon is the log it is writing: recovering it
    would leave that daemon writing on into a deleted file. Holding the lock also keeps a
    daemon from starting there mid-recovery. None when no lock file can be made there (the
    recovery, which writes beside it, says why if it cannot either).
    """
    lock = DirectoryLock(directory)
    try:
        lock.acquire("log directory")  # InstanceError when a daemon holds it
    except OSError:
        return None
    return lock


def cmd_check_config(args: argparse.Namespace) -> int:
    """The file as hermsd will use it, and the safety limits it puts in force; for `run` on
    hardware unless --simulate is given.

    `output.backend: sim` is valid only in a simulated run, so it is refused here by
    default: a file checked for the service must not fail when the service starts.
    """
    from hermsd.runtime.daemon import model_in_force, safety_limits, stored_model
    from hermsd.safety.supervisor import format_limits

    document = config_module.load_document(args.file)
    if document.config.output.backend == "sim" and not args.simulate:
        line, column = document.written["output.backend"]
        raise ConfigError(
            [
                config_module.Problem(
                    os.fspath(args.file),
                    line,
                    column,
                    "output.backend",
                    "'sim' is the simulated tun's output, which `hermsd run` uses only with "
                    "--simulate (choose serial-rts, serial-dtr or gpio for the tun, or check "
                    "a file for simulation with check-config --simulate)",
                )
            ]
        )
    if args.state:
        try:
            LatchStore(args.state).load()  # as `run` reads it at its start
        except StateError as error:
            raise _latch_file_refused(error) from None
    shown = config_module.on_simulated_tun(document.config) if args.simulate else document.config
    print(config_module.dump_yaml(shown), end="")
    # As YAML comments, so that the output still reads back as the config it is.
    stored, problem = (
        stored_model(ModelStore(args.state), document.config) if args.state else (None, None)
    )
    if problem is not None:
        print(f"\n# learned model ignored: {problem}")
    choice = model_in_force(stored, document.config)
    source = (
        "nothing measured yet" if choice.measured is None else f"the tun as {choice.describe()}"
    )
    print(f"\n# safety limits in force ({source}):")
    limits = safety_limits(document.config, choice.measured)
    for row in format_limits(limits, document.config.control.setpoint):
        print(f"#   {row}")
    return 0


# -- the MQTT bridge ------------------------------------------------------------------------


def cmd_mqtt(args: argparse.Namespace) -> int:
    """Serve the bridge until SIGTERM or Ctrl-C; it leaves "offline" on the broker."""
    try:
        from hermsd.mqtt.bridge import Bridge, BridgeError
    except ModuleNotFoundError as error:
        if not (error.name or "").startswith("paho"):
            raise
        raise UserError(
            "the MQTT bridge needs paho-mqtt: install hermsd with its mqtt extra "
            "(uv sync --extra mqtt; uv tool install --with paho-mqtt)"
        ) from None
    path = config_path(args.config, simulate=False)
    assert path is not None
    config = config_module.load(path)
    try:
        bridge = Bridge(config, default_socket_path(args.socket))
    except BridgeError as error:
        raise UserError(str(error)) from None
    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, lambda _signum, _frame: bridge.stop())
    bridge.run()
    return 0


if __name__ == "__main__":
    sys.exit(main())
