"""`hermsd tune`: the tun's model from a day's logs, from a step test or from a relay test
run through the loop."""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import signal
from collections.abc import Callable, Iterator
from concurrent.futures import BrokenExecutor
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from hermsd.cli.common import (
    Shutdown,
    UserError,
    _on_signal,
    config_path,
    log,
)
from hermsd.cli.run import (
    _hardware,
    _latch_file_refused,
    _latch_store,
    _lock_directories,
    _open_recorder,
)
from hermsd.config import read
from hermsd.config import schema as config_module
from hermsd.config.file import ConfigFile, at_once
from hermsd.log.recorder import Recorder
from hermsd.safety.latches import StateError

if TYPE_CHECKING:
    from hermsd.commissioning import step_response
    from hermsd.runtime.daemon import Daemon


_Experiment = TypeVar("_Experiment", bound="step_response.Experiment")


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
    return read.on_simulated_tun(config) if args.simulate else config


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
    from hermsd.hardware.outputs import guard_outputs
    from hermsd.runtime.assemble import assemble
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
                daemon = assemble(config, clock, world.sensor, world.outputs)
                recorder = (
                    Recorder(log_dir, now=clock.monotonic, lossless=True) if log_dir else None
                )
            else:
                from hermsd.hardware.ssr import DeadManThread
                from hermsd.runtime.clock import MonotonicClock

                hardware_clock = MonotonicClock()
                sensors, (ssr, contactor, element2, pump) = _hardware(config)
                daemon = assemble(
                    config,
                    hardware_clock,
                    sensors["sensor"],
                    guard_outputs(ssr, contactor, hardware_clock, config, element2, pump),
                    latches=latches,
                    mash_sensor=sensors.get("mash_sensor"),
                    coil_sensor=sensors.get("coil_sensor"),
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
