"""`hermsd run` and `hermsd simulate`: the control loop on the hardware or on the simulated
tun, and what each needs before it starts (state directory, log, socket, outputs)."""

from __future__ import annotations

import argparse
import contextlib
import errno
import json
import logging
import math
import os
import signal
import stat
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

from hermsd.api.client import default_socket_path, simulated_socket_path
from hermsd.api.server import ControlServer, SocketInUseError
from hermsd.cli.common import (
    DEFAULT_STATE,
    Shutdown,
    UserError,
    _on_signal,
    config_path,
    log,
)
from hermsd.config import read
from hermsd.config import schema as config_module
from hermsd.config.file import ConfigFile
from hermsd.config.schema import (
    ROLE_SENSORS,
    Config,
    ContactorConfig,
    Element2Config,
    OutputConfig,
    PumpConfig,
    RoleSensorConfig,
)
from hermsd.control.learning import ModelStore
from hermsd.durations import parse_duration
from hermsd.hardware.current_sense import CurrentSense, open_current_sense
from hermsd.hardware.pump_sense import PumpSense, open_pump_sense
from hermsd.hardware.realtime import loop_priority
from hermsd.hardware.sensors.kinds import open_role_sensor, open_sensor
from hermsd.hardware.ssr import Switch, describe_output, open_hardware_switch
from hermsd.log.mcap_file import NotRecovered, recover_directory
from hermsd.log.recorder import Recorder
from hermsd.runtime.instance import DirectoryLock, InstanceError
from hermsd.runtime.log_queue import DroppingQueueHandler
from hermsd.runtime.notify import Notifier, NotifyEnvironmentError, check_watchdog
from hermsd.safety.latches import LatchStore, StateError

if TYPE_CHECKING:
    from hermsd.hardware.sensors.base import Sensor
    from hermsd.runtime.clock import Clock
    from hermsd.runtime.daemon import Daemon
    from hermsd.sim.scenario import Scenario


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
    from hermsd.hardware.outputs import guard_outputs
    from hermsd.hardware.ssr import DeadManThread
    from hermsd.runtime.assemble import assemble
    from hermsd.runtime.clock import MonotonicClock

    scenario = _live_scenario(args)
    path = config_path(args.config, simulate=args.simulate)
    config_file = ConfigFile(path, simulated=args.simulate) if path is not None else None
    config = config_file.load() if config_file is not None else config_module.DEFAULT
    if args.simulate:  # the simulated tun's SSR, whatever the file names
        config = read.on_simulated_tun(config)
    if scenario is not None:  # its overrides stand over the file, which is read once
        config, config_file = _scenario_config(config, scenario), None
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
            server = _claim_control_socket(_run_socket_path(args), simulated=args.simulate)
            stack.callback(server.close)
            if args.simulate:
                from hermsd.sim.world import simulated_daemon

                speed = _speed(args.speed)
                if scenario is not None:
                    daemon = _scenario_daemon(
                        scenario,
                        config,
                        speed,
                        on_status=status.update,
                        notifier=notifier,
                        latches=latches,
                        models=models,
                    )
                else:
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
                sensors, (ssr, contactor, element2, pump) = _hardware(config)
                pump_sense = _pump_sense(config)
                if pump_sense is not None:
                    stack.callback(pump_sense.close)
                current_sense = _current_sense(config, clock)
                if current_sense is not None:
                    stack.callback(current_sense.close)
                daemon = assemble(
                    config,
                    clock,
                    sensors["sensor"],
                    guard_outputs(ssr, contactor, clock, config, element2, pump),
                    notifier=notifier,
                    on_status=status.update,
                    config_file=config_file,
                    latches=latches,
                    models=models,
                    mash_sensor=sensors.get("mash_sensor"),
                    coil_sensor=sensors.get("coil_sensor"),
                    pump_sense=pump_sense,
                    current_sense=current_sense,
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


def _live_scenario(args: argparse.Namespace) -> Scenario | None:
    """The scenario `run --simulate --scenario FILE` runs live; UserError for a bad one."""
    if args.scenario is None:
        return None
    if not args.simulate:
        raise UserError("--scenario goes with --simulate")
    from hermsd.sim.scenario import ScenarioError, load_scenario

    try:
        return load_scenario(args.scenario)
    except ScenarioError as error:
        raise UserError(str(error)) from None


def _scenario_config(config: Config, scenario: Scenario) -> Config:
    """`config` with the scenario's overrides and setpoint; UserError naming the bad key."""
    from hermsd.sim.scenario import ScenarioError, effective_config

    try:
        return effective_config(config, scenario)
    except ScenarioError as error:
        raise UserError(str(error)) from None


def _scenario_daemon(scenario: Scenario, config: Config, speed: float, **parts: Any) -> Daemon:
    """`sim.live.scenario_daemon`, a scenario the simulated hardware cannot run a UserError."""
    from hermsd.sim.live import scenario_daemon
    from hermsd.sim.scenario import ScenarioError

    try:
        return scenario_daemon(scenario, config, speed, **parts)
    except ScenarioError as error:
        raise UserError(str(error)) from None


def _run_socket_path(args: argparse.Namespace) -> Path:
    """Where `run` listens: --socket, $RUNTIME_DIRECTORY, /run/hermsd, or for a simulated tun
    one fixed place of the user's own (`simulated_socket_path`), which the commands find
    without --socket, and never the service's."""
    if args.socket is not None or not args.simulate or os.environ.get("RUNTIME_DIRECTORY"):
        return default_socket_path(args.socket)
    path = simulated_socket_path()
    directory = path.parent
    try:
        directory.mkdir(mode=0o700, exist_ok=True)
        held = os.lstat(directory)
        if stat.S_ISDIR(held.st_mode) and held.st_uid == os.getuid():
            os.chmod(directory, 0o700)  # the socket is this user's alone
    except OSError as error:
        raise UserError(
            f"cannot make {directory} for the simulated daemon's control socket: "
            f"{error.strerror or error} (choose a place with --socket PATH)"
        ) from None
    if not stat.S_ISDIR(held.st_mode) or held.st_uid != os.getuid():
        raise UserError(
            f"{directory} is not a directory of this user's (uid {os.getuid()}): it cannot "
            "hold the simulated daemon's control socket (remove it, or choose a place with "
            "--socket PATH)"
        )
    return path


def _claim_control_socket(path: Path, *, simulated: bool) -> ControlServer:
    """The control socket at `path`, bound but not served yet; UserError, saying what to do,
    if another daemon answers there or it cannot be made."""
    server = ControlServer(path)
    try:
        server.bind()
    except OSError as error:
        server.close()
        why = error.strerror or str(error)
        if isinstance(error, SocketInUseError) and error.errno == errno.EADDRINUSE:
            hint = (
                "a simulated hermsd runs: stop it first (Ctrl-C in its terminal), or give this "
                "one --socket PATH"
                if simulated
                else "another hermsd on this tun? else choose a place with --socket PATH"
            )
        elif error.errno == errno.ENOENT and not path.parent.is_dir():
            why = f"its directory {path.parent} does not exist"
            hint = (
                f"the service's RuntimeDirectory= makes it; by hand: `sudo install -d -o "
                f"hermsd -g hermsd -m 0750 {path.parent}`, or choose a place with --socket PATH"
            )
        elif error.errno in (errno.EACCES, errno.EPERM):
            hint = (
                f"run as a user who may write in {path.parent}, or choose a place with "
                "--socket PATH"
            )
        else:
            hint = "choose a place with --socket PATH"
        raise UserError(f"cannot open the control socket {path}: {why} ({hint})") from None
    return server


def _serve_control(daemon: Daemon, server: ControlServer) -> None:
    """Serve the control socket beside the loop (started before it takes real-time priority,
    so its thread stays ordinary); said on the first line of output."""
    from hermsd.api.link import LoopLink

    link = LoopLink(daemon)
    server.answer_with(link.status_line, link.history_line, link.arrived)
    server.start()
    link.attach(server)
    where = f"control socket {server.path}"
    if server.path == simulated_socket_path():
        where += " (hermsd status, set, web and mqtt find it)"
    print(where, flush=True)


def _hardware(
    config: Config,
) -> tuple[dict[str, Sensor], tuple[Switch, Switch | None, Switch | None, Switch | None]]:
    """The sensors by their config section, and the SSR, contactor, second element and pump
    as the config names them (outputs closed on failure)."""
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
        if config.pump.backend == "sim":
            raise UserError("pump.backend is 'sim', the simulated tun's: run with --simulate")
        pump = _open_output(config.pump) if config.pump.backend != "none" else None
        if pump is not None:
            opened.append(pump)
        sensors = {"sensor": open_sensor(config.sensor, time.monotonic)}
        for section in ROLE_SENSORS:
            role: RoleSensorConfig = getattr(config, section)
            if role.fitted:  # one that cannot be opened is a fault, said: the HLT is held
                sensors[section] = open_role_sensor(role, time.monotonic, section)
    except BaseException:
        for switch in opened:
            switch.close()
        raise
    return sensors, (ssr, contactor, element2, pump)


def _pump_sense(config: Config) -> PumpSense | None:
    """The pump's sense as the config fits it on hardware; UserError for the simulator's, or
    a line that cannot be had."""
    if config.pump.sense == "sim":
        raise UserError("pump.sense is 'sim', the simulated pump's: run with --simulate")
    try:
        return open_pump_sense(config.pump)
    except OSError as error:
        raise UserError(
            f"cannot open the pump sense's line {config.pump.sense_line} of "
            f"{config.pump.sense_chip}: {error.strerror or error} (check pump.sense_chip and "
            "sense_line)"
        ) from None


def _current_sense(config: Config, clock: Clock) -> CurrentSense | None:
    """The element's current input as the config fits it on hardware; UserError for the
    simulator's, or a device that cannot be had."""
    current = config.current
    if current.kind == "sim":
        raise UserError("current.kind is 'sim', the simulated circuit's: run with --simulate")
    where, check = (
        (f"line {current.line} of {current.chip}", "current.chip and line")
        if current.kind == "gpio"
        else (
            f"ADS1115 at {current.address:#04x} on /dev/i2c-{current.bus}",
            "current.bus, address and the wiring",
        )
    )
    try:
        return open_current_sense(current, config.output.mains_hz, clock.monotonic, time.sleep)
    except (OSError, ImportError) as error:
        why = error.strerror if isinstance(error, OSError) and error.strerror else error
        raise UserError(f"cannot open the current input's {where}: {why} (check {check})") from None


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


def _open_output(section: OutputConfig | ContactorConfig | Element2Config | PumpConfig) -> Switch:
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


def cmd_simulate(args: argparse.Namespace) -> int:
    from hermsd.sim import scenario as scenario_module
    from hermsd.sim.hlt import PlantFailed, PlantLoadError, load_plant

    config = read.load(args.config) if args.config else config_module.DEFAULT
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
