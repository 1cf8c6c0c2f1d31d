"""The tune tests' fits run beside the loop: the loop takes each result at a later period,
says there which periods it fitted, and acts on it there; replay reads the same day back."""

from __future__ import annotations

import functools
import itertools
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

import pytest
from test_relay import NOISE, SEED_TUN
from test_step_response import experiment_on

from hermsd.commissioning import relay, step_response
from hermsd.config import schema as config_module
from hermsd.config.file import in_thread
from hermsd.log import reader, replay
from hermsd.log.recorder import Recorder
from hermsd.runtime.assemble import assemble
from hermsd.runtime.period import PeriodRecord
from hermsd.safety.limits import Alarm
from hermsd.sim.clock import VirtualClock
from hermsd.sim.world import build_world

HELD = 3  # periods each fit is held back before it may finish
TAKEN = re.compile(r"tune relay: the fit of the periods to t=(\S+) s, taken at t=(\S+) s: ")


class SlowFits:
    """Fits on a thread of their own that cannot finish before HELD periods have passed (as a
    fit on a loaded Pi may take periods): then each is let go and waited for."""

    def __init__(self) -> None:
        self.running: list[tuple[threading.Event, Future[relay.Progress], list[int]]] = []
        self.periods_while_running = 0

    def __call__(self, job: Callable[[], relay.Progress]) -> Future[relay.Progress]:
        gate = threading.Event()

        def held() -> relay.Progress:
            gate.wait(10.0)
            return job()

        future = in_thread(held)
        self.running.append((gate, future, [0]))
        return future

    def period(self, record: PeriodRecord) -> None:
        for gate, future, seen in self.running:
            seen[0] += 1
            if seen[0] < HELD:
                assert not future.done()  # the loop went on while it ran
                self.periods_while_running += 1
            elif not gate.is_set():
                gate.set()
                future.result(10.0)  # joined: done before the experiment looks at this period

    def alarm(self, alarm: Alarm) -> None:
        pass


def test_a_fit_is_taken_and_acted_on_at_the_period_the_log_says_and_replay_verifies(
    tmp_path: Path,
) -> None:
    clock = VirtualClock()
    cfg = config_module.DEFAULT
    world = build_world(cfg, clock, {**SEED_TUN, **NOISE}, history=True)
    daemon = assemble(cfg, clock, world.sensor, world.outputs)
    recorder = Recorder(tmp_path, now=clock.monotonic, lossless=True)
    daemon.recorder = recorder
    fits = SlowFits()
    daemon.listeners.append(fits)  # before the experiment: it lets a fit go first
    experiment = relay.RelayExperiment(daemon, 66.0, fits=fits)
    relay.start(experiment, (KeyboardInterrupt,))
    recorder.close()
    assert experiment.stopped == relay.CYCLES_GOOD
    assert not world.circuit.powered
    assert fits.periods_while_running >= HELD - 1

    log = reader.load(sorted(tmp_path.glob("*.mcap")))
    taken = [m for e in log.events if (m := TAKEN.search(e.message))]
    assert len(taken) == len(fits.running) >= 2
    period = cfg.control.period
    levels = experiment.switches
    switches_down = [t for (_, before), (t, level) in itertools.pairwise(levels) if level < before]
    for match in taken:
        asked, at = float(match[1]), float(match[2])
        assert asked in switches_down  # a fit of the cycles to a switch down …
        assert at == asked + HELD * period  # … taken where the loop found it done
    # The last fit stopped the test at the period it was taken: no period after it.
    assert log.periods[-1].t == float(taken[-1][2])
    verification = replay.verify(log.entries)
    assert verification.mismatch is None and verification.verified > 100


def test_the_tuns_fits_run_in_a_process_of_their_own_and_give_the_loops_result() -> None:
    """`hermsd tune` on the tun fits in another process (a fit on a thread would hold the
    interpreter's lock while the loop's edges wait): the copy it gets fits as the test would."""
    plant = {"model": "foptd", "gain_c_per_pct": 1.689, "tau_s": 14961.0, "dead_time_s": 115.0}
    experiment, _world, _clock = experiment_on(plant)
    step_response.run(experiment, (KeyboardInterrupt,))
    t = experiment.times[-1]
    fits = step_response.FitProcess()
    try:
        copy = experiment._snapshot()
        fitted = fits(functools.partial(step_response._progress_at, copy, t)).result(60.0)
    finally:
        fits.close()
    assert fitted == experiment.progress(t)
    assert fitted.tuned is not None and fitted.tuned.confidence == "good"


@pytest.mark.parametrize(
    ("error", "stopped"),
    [
        (
            BrokenProcessPool("a child process terminated abruptly"),
            f"{step_response.FIT_LOST}: a child process terminated abruptly",
        ),
        (  # a fault of the fit's own never escapes into the loop
            ValueError("math domain error"),
            f"{step_response.FIT_FAILED}: ValueError: math domain error",
        ),
    ],
)
def test_a_fit_that_cannot_be_had_stops_the_test_with_the_heater_off(
    error: Exception, stopped: str
) -> None:
    def failed(job: Callable[[], step_response.Progress]) -> Future[step_response.Progress]:
        future: Future[step_response.Progress] = Future()
        future.set_exception(error)
        return future

    plant = {"model": "foptd", "gain_c_per_pct": 1.689, "tau_s": 14961.0, "dead_time_s": 115.0}
    experiment, world, _clock = experiment_on(plant)
    experiment.fits = failed
    step_response.run(experiment, (KeyboardInterrupt,))
    assert experiment.stopped == stopped
    assert experiment.step_at is not None  # the first fit's time: the step plus MIN_STEP_S,
    stopped_at = experiment.step_at + step_response.MIN_STEP_S + 5.0  # taken a period later
    assert experiment.times[-1] == stopped_at
    assert not world.circuit.powered
    assert experiment.last is not None and experiment.last.tuned is not None  # what was measured


def _gone(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return True
    return state in ("Z", "X")  # ended, waiting to be reaped by whoever adopted it


def test_ctrl_c_is_the_tests_to_act_on_not_the_fits_process() -> None:
    """Ctrl-C reaches the whole process group; the fits' process leaves it to its parent
    (which stops the test and says what it measured) rather than dying with a traceback."""
    fits = step_response.FitProcess()
    try:
        worker = fits(os.getpid).result(60.0)
        os.kill(worker, signal.SIGINT)
        assert fits(os.getpid).result(60.0) == worker  # alive, and still fitting
    finally:
        fits.close()


def test_the_fits_process_ends_when_its_parent_is_killed_outright() -> None:
    program = (
        "import os\n"
        "from hermsd.commissioning.step_response import FitProcess\n"
        "print(FitProcess()(os.getpid).result(60), flush=True)\n"
        "os._exit(0)  # as SIGKILL: no close, no atexit\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", program], capture_output=True, text=True, timeout=60, check=True
    )
    worker = int(done.stdout)
    deadline = time.monotonic() + 10 * step_response.PARENT_CHECK_S
    while not _gone(worker) and time.monotonic() < deadline:
        time.sleep(0.05)  # a real process's end: nothing to inject
    assert _gone(worker)
