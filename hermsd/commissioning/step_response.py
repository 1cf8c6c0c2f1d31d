"""`hermsd tune step`: seed 001's two open-loop experiments as one run of the daemon's own loop.

The loop holds the heater off for a baseline (the starting temperature, and the room's when
the water has stood in it), then steps the manual output to P through `Daemon.set_manual`,
so the supervisor watches the run as any other and the recorder logs it (replayable, and
`hermsd tune FILE` fits the same log). From the records it measures:

- §4.1: the 10 % rule's dead time (the step to PV ≥ T1 + 10 %·ΔT, ΔT the rise so far), the
  slope a of the regression line between 10 % and 90 % of the rise, where that line meets T1
  (the document's dead time), and a* = a/P;
- §4.2: K and τ (and the FOPTD's own θ) from hermsd.commissioning.identify's least-squares
  fit, the one every other user of a model shares, instead of the document's 28.3 %/63.2 %
  points, which need the final temperature (hours at a 4 h time constant). An open pot
  (tun.lid off) is fitted with its evaporation, and K and τ are given at the setpoint
  (tune.from_series).

It stops as soon as the fit is good (STOP_RULE), or when PV reaches the limit, or after
MAX_STEP_S; an alarm or an interrupt stops it at once. Whatever stops it, the daemon's
shutdown switches the heater off, and what was measured up to then is kept.

A fit takes up to half a second (an open pot's, on a loaded Pi), which the loop's SSR edges
cannot wait: each fit runs beside the loop on a copy of the records so far (`Stopping.fits`,
`fit_in_thread`), and the loop takes its result at the first period after the one that asked
for it at which it is done, says so in the log (`operator: tune …: the fit of the periods to
t=… s, taken at t=… s`), and acts on it there: what replay reads is where the result took
effect. On a virtual clock, `at_once` fits at once, so the result comes one period later,
every run.
"""

from __future__ import annotations

import dataclasses
import math
import multiprocessing
import os
import signal
import threading
import time
from abc import ABC, abstractmethod
from collections.abc import Callable
from concurrent.futures import BrokenExecutor, Future, ProcessPoolExecutor
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any, Generic, Protocol, TypeVar, cast

from hermsd.commissioning import tune
from hermsd.commissioning.identify import MIN_DUTY_SPAN
from hermsd.config.file import in_thread
from hermsd.runtime.daemon import Daemon
from hermsd.runtime.period import PeriodRecord
from hermsd.safety.limits import Alarm

BASELINE_S = 120.0
"""Heater off at the start: T1, and the sensor's noise, before anything moves."""
EVALUATE_S = 120.0
"""How often (experiment time) the model is fitted again: each fit costs up to ~0.1 s."""
MIN_STEP_S = 600.0
"""No verdict on less of the step than this: the fit needs the response well under way."""
MAX_STEP_S = 3 * 3600.0
MIN_OUTPUT = MIN_DUTY_SPAN
TARGET_STEP_S = 90 * 60.0
"""The default output reaches the limit in about this long at the water's linear rate."""
ABORTED = ("alarm", "interrupted")
"""How `stopped` begins when the run was cut short: nothing is written then."""
SETTLE_S = 600.0
SETTLED_RELATIVE = 0.03
"""K and τ moved less than this over the last SETTLE_S: a tun that is not quite first order
(a sensor in a thermowell lags the water) drifts its fit as the step goes on, faster than
the stated uncertainty shrinks, and would be stopped on a biased τ."""
STOP_RULE = (
    "the fit is good (every 2σ within the goals: K and τ ±10 %, θ ±20 s; RMS ≤ 0.04 °C) and "
    f"settled (K and τ within {100 * SETTLED_RELATIVE:g} % of the fit {SETTLE_S:g} s before) "
    f"at two fits in a row, {EVALUATE_S:g} s apart, at least {MIN_STEP_S:g} s after the step"
)


FIT_GOOD = "the fit is good"  # why a test stops when its fit may be written
FIT_LOST = "the fits' process stopped"  # … and when the fits can no longer run
FIT_FAILED = "a fit failed"  # … and when one raised what no fit should
PARENT_CHECK_S = 1.0  # how often the fits' process looks whether its parent is still there


@dataclass(frozen=True, slots=True)
class OpenLoop:
    """Seed 001's §4.1 numbers, as the document computes them."""

    t1: float  # °C, mean PV of the baseline
    rise: float  # ΔT so far, °C
    dead_time_10: float | None  # s, step to PV ≥ T1 + 10 % of the rise
    dead_time_line: float | None  # s, step to where the 10–90 % regression line meets T1
    slope: float | None  # a, °C/s
    a_star: float | None  # a/P, °C/(%·s)


@dataclass(frozen=True, slots=True)
class Progress:
    elapsed: float  # s since the step
    pv: float | None
    open_loop: OpenLoop
    tuned: tune.Tuned | None
    problem: str | None  # why there is no fit yet
    left_s: float | None  # expected time to a good fit or the limit; None: unknown
    settled: bool = False  # K and τ have stopped moving (SETTLED_RELATIVE)


_Progress = TypeVar("_Progress")
FitStart = Callable[[Callable[[], _Progress]], Future[_Progress]]
"""How a fit runs: `fit_in_thread` beside the loop (the tun), `at_once` on a virtual clock."""


def fit_in_thread(job: Callable[[], _Progress]) -> Future[_Progress]:
    return in_thread(job, name="hermsd-fit")


class FitProcess:
    """Fits in a process of their own (the tun's: `hermsd tune step|relay`). A fit is pure
    Python: on a thread it would hold the interpreter's lock, and every SSR edge due while it
    runs would wait for it, 5 ms (the switch interval) and more. Start it before the loop
    runs (its interpreter takes a moment to start) and `close` it after."""

    def __init__(self) -> None:
        context = multiprocessing.get_context("spawn")  # no fork of a threaded process
        self._pool = ProcessPoolExecutor(
            max_workers=1, mp_context=context, initializer=_fit_worker, initargs=(os.getpid(),)
        )
        self._pool.submit(int).result()  # started now, not at the first fit

    def __call__(self, job: Callable[[], _Progress]) -> Future[_Progress]:
        try:
            return self._pool.submit(job)
        except BrokenExecutor as error:  # said when the loop takes the fit
            future: Future[_Progress] = Future()
            future.set_exception(error)
            return future

    def close(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)


@dataclass(frozen=True, slots=True)
class _Settings:
    """What a copy of a test fitted in another process needs of its daemon: the config."""

    config: Any


def _progress_at(test: Stopping[_Progress], t: float) -> _Progress:
    return test.progress(t)


def _fit_worker(parent: int) -> None:
    """The fits' process: Ctrl-C is its parent's to act on (the test stops and says what it
    measured), and it ends when its parent is gone (killed outright, it would stay forever)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(PARENT_CHECK_S)
        os._exit(0)

    threading.Thread(target=watch, name="hermsd-fit-parent", daemon=True).start()


def settings_of(daemon: Daemon) -> Daemon:
    """A stand-in for `daemon` in a copy of a test that is fitted in another process: its
    config, which is all a fit reads of it."""
    return cast(Daemon, _Settings(daemon.config))


class Stopping(ABC, Generic[_Progress]):
    """How a test stops: an alarm or Ctrl-C cuts it short, keeping what was measured; a stop
    of its own asks the heater off first and makes its last estimate once the loop has
    stopped. Its fits run beside the loop (`_ask_fit`, `_taken_fit`)."""

    NAME = ""  # the command's word for the test, in the log
    RECORDS: tuple[str, ...] = ()  # the lists the loop appends to, copied for a fit
    daemon: Daemon
    stopped: str | None
    last: _Progress | None
    times: list[float]
    pvs: list[float | None]
    duties: list[float]
    fits: FitStart[_Progress]
    _asked: tuple[float, Future[_Progress]] | None  # the fit running: of the periods to t
    _final_at: float | None  # the last estimate is due, at this t, once the loop has stopped

    @abstractmethod
    def progress(self, t: float) -> _Progress:
        """The estimates at `t`, from every period so far."""

    @abstractmethod
    def _evaluate(self, progress: _Progress, t: float) -> None:
        """Act on a fit taken at `t`: go on, or stop."""

    def _recorded(self, record: PeriodRecord) -> bool:
        """Keep a period and act on a fit taken at it; whether the test goes on."""
        if self.stopped is not None:
            return False
        self.times.append(record.t)
        self.pvs.append(record.pv)
        self.duties.append(record.applied)
        fitted = self._taken_fit(record)
        if fitted is not None:
            self._evaluate(fitted, record.t)
        return self.stopped is None

    def _snapshot(self) -> Stopping[_Progress]:
        """A copy of the test to fit beside the loop: its RECORDS as they are now (the loop
        goes on appending to its own), and of its daemon the config alone (the copy may go to
        another process)."""
        copies = {name: list(getattr(self, name)) for name in self.RECORDS}
        copy: Stopping[_Progress] = dataclasses.replace(
            cast(Any, self),
            daemon=settings_of(self.daemon),
            on_progress=None,
            fits=fit_in_thread,
            _asked=None,
            **copies,
        )
        return copy

    def _ask_fit(self, t: float) -> None:
        """Fit the periods to `t` beside the loop, unless a fit is still running."""
        if self._asked is None:
            self._asked = (t, self.fits(partial(_progress_at, self._snapshot(), t)))

    def _taken_fit(self, record: PeriodRecord) -> _Progress | None:
        """The fit asked for at an earlier period, once done: taken at this one and said in
        the log here, where what it decides takes effect."""
        asked = self._asked
        if asked is None or record.t <= asked[0] or not asked[1].done():
            return None
        self._asked = None
        try:
            progress = asked[1].result()
        except BrokenExecutor as error:  # the fit's process died (killed, out of memory)
            self._finish(f"{FIT_LOST}: {error or type(error).__name__}", record.t)
            return None
        except Exception as error:  # a fault of the fit's own: the test ends, heater off
            self._finish(f"{FIT_FAILED}: {type(error).__name__}: {error}", record.t)
            return None
        tuned: tune.Tuned | None = getattr(progress, "tuned", None)
        verdict = tuned.confidence if tuned is not None else getattr(progress, "problem", None)
        self.daemon.operator_action(
            f"tune {self.NAME}: the fit of the periods to t={asked[0]:g} s, taken at "
            f"t={record.t:g} s: {verdict}",
            record.t,
        )
        return progress

    def alarm(self, alarm: Alarm) -> None:
        if alarm.raised and self.stopped is None:
            self._finish(f"{ABORTED[0]} {alarm.kind}: {alarm.message}", alarm.at)

    def interrupted(self, why: str) -> None:
        """The run was stopped from outside (Ctrl-C): keep what was measured."""
        if self.stopped is None:
            self.stopped = f"{ABORTED[1]} ({why})"
            self.last = self.progress(self.times[-1] if self.times else 0.0)

    def conclude(self) -> None:
        """The last estimate of a test that stopped itself, now that the loop has stopped."""
        if self._final_at is not None:
            self.last = self.progress(self._final_at)
            self._final_at = None

    def _finish(self, why: str, t: float, fitted: _Progress | None = None) -> None:
        """Stop at `t`, because of `why`; `fitted`: the fit that decided it, the last estimate."""
        self.stopped = why
        self.daemon.set_manual(0.0)
        self.daemon.stop()  # the caller's shutdown switches every output off
        if fitted is not None:
            self.last = fitted
        else:
            self._final_at = t  # fitted once the heater is off (`conclude`)


@dataclass(slots=True)
class StepExperiment(Stopping[Progress]):
    """Listens to the daemon's periods, steps the output, and stops the loop when done."""

    daemon: Daemon
    output: float | None  # %; None: default_output from the baseline's temperature
    limit: float  # °C
    ambient: float | None = None  # the room's, if measured
    on_progress: Callable[[Progress], None] | None = None
    times: list[float] = field(default_factory=list)
    pvs: list[float | None] = field(default_factory=list)
    duties: list[float] = field(default_factory=list)
    step_at: float | None = None  # when the stepped output first ran
    stopped: str | None = None  # why it stopped
    last: Progress | None = None
    _started_at: float | None = None
    _next_fit: float = math.inf
    _good_fits: int = 0
    _step_asked: bool = False
    _fits: list[tuple[float, float, float]] = field(default_factory=list)  # (elapsed, K, τ)
    _history: list[tuple[float, float]] = field(default_factory=list)  # (elapsed, worst ratio)
    fits: FitStart[Progress] = fit_in_thread
    _asked: tuple[float, Future[Progress]] | None = None
    _final_at: float | None = None
    NAME = "step"
    RECORDS = ("times", "pvs", "duties", "_history")

    def period(self, record: PeriodRecord) -> None:
        if not self._recorded(record):
            return
        if self._started_at is None:
            self._started_at = record.t
        if self.step_at is None:
            stepped = self.output is not None and record.output >= self.output - 1e-9
            if record.mode == "manual" and stepped:
                self.step_at = record.t
                self._next_fit = record.t + MIN_STEP_S
            elif record.t - self._started_at >= BASELINE_S and self.output is None:
                self.output = self._default_output(record.pv)
            if record.t - self._started_at >= BASELINE_S and not self._step_asked:
                self._step_asked = True
                self.daemon.set_manual(self.output)
            return
        if record.pv is not None and record.pv >= self.limit:
            self._finish(f"PV reached the limit {self.limit:g} °C", record.t)
        elif record.t >= self._next_fit:
            self._next_fit = record.t + EVALUATE_S
            self._ask_fit(record.t)
        elif record.t - self.step_at >= MAX_STEP_S:
            self._finish(f"no good fit in {MAX_STEP_S:g} s", record.t)

    def _default_output(self, pv: float | None) -> float:
        config = self.daemon.config
        start = pv if pv is not None else self.limit
        return default_output(
            config.tun.litres,
            config.tun.element_watts,
            start,
            self.limit,
            config.control.max_output,
        )

    def _evaluate(self, progress: Progress, t: float) -> None:
        """Act on a fit taken at `t`."""
        self.last = progress
        tuned = progress.tuned
        if tuned is not None:
            self._history.append((progress.elapsed, _worst_ratio(tuned)))
            self._fits.append((progress.elapsed, tuned.model.gain, tuned.model.tau))
        if tuned is not None and self.settled():
            progress = dataclasses.replace(progress, settled=True)
            self.last = progress
        if tuned is not None and tuned.confidence == "good" and progress.settled:
            self._good_fits += 1
        else:
            self._good_fits = 0
        if self.on_progress is not None:
            self.on_progress(progress)
        if self._good_fits >= 2:
            self._finish(FIT_GOOD, t, progress)

    def settled(self) -> bool:
        """Whether K and τ now are within SETTLED_RELATIVE of the fit SETTLE_S before."""
        if not self._fits:
            return False
        now, gain, tau = self._fits[-1]
        before = [fit for fit in self._fits if fit[0] <= now - SETTLE_S + 1e-6]
        if not before:
            return False
        _, old_gain, old_tau = before[-1]
        return max(abs(gain / old_gain - 1), abs(tau / old_tau - 1)) <= SETTLED_RELATIVE

    def progress(self, t: float) -> Progress:
        """The estimates now, from every period so far."""
        elapsed = t - self.step_at if self.step_at is not None else 0.0
        open_loop = self.open_loop()
        tuned, problem = None, None
        config = self.daemon.config
        try:
            tuned = tune.from_series(
                self.pvs,
                self.duties,
                config.control.period,
                self.ambient,
                config.tun.element_watts,
                config.tun.litres,
                config.control.setpoint if config.tun.lid == "off" else None,
            )
        except tune.TuneError as error:
            problem = str(error)
        left = None
        if tuned is not None:
            left = self._time_left(open_loop, [*self._history, (elapsed, _worst_ratio(tuned))])
        pv = next((pv for pv in reversed(self.pvs) if pv is not None), None)
        return Progress(elapsed, pv, open_loop, tuned, problem, left)

    def _time_left(self, open_loop: OpenLoop, history: list[tuple[float, float]]) -> float | None:
        """To a good fit, if the worst 2σ/goal ratio (`history`: (elapsed, ratio) of each fit)
        falls as a power of time as it has between the last two fits; or to the limit at the
        present slope, if that is sooner."""
        candidates = []
        if len(history) >= 2:
            (t0, r0), (t1, r1) = history[-2:]
            if r1 <= 1.0:
                candidates.append(0.0)
            elif t0 > 0 and r0 > r1 > 0 and t1 > t0:
                power = math.log(r0 / r1) / math.log(t1 / t0)
                candidates.append(t1 * r1 ** (1.0 / power) - t1)
        last_pv = next((pv for pv in reversed(self.pvs) if pv is not None), None)
        if open_loop.slope is not None and open_loop.slope > 0 and last_pv is not None:
            candidates.append(max(self.limit - last_pv, 0.0) / open_loop.slope)
        return min(candidates) if candidates else None

    def open_loop(self) -> OpenLoop:
        """§4.1 on the records so far (None where the rise is too small to tell)."""
        base = [
            pv
            for t, pv in zip(self.times, self.pvs, strict=True)
            if pv is not None and (self.step_at is None or t <= self.step_at)
        ]
        t1 = sum(base) / len(base) if base else math.nan
        after = [
            (t, pv)
            for t, pv in zip(self.times, self.pvs, strict=True)
            if pv is not None and self.step_at is not None and t > self.step_at
        ]
        if not after or not base or self.step_at is None:
            return OpenLoop(t1, 0.0, None, None, None, None)
        rise = after[-1][1] - t1
        if rise <= 0:
            return OpenLoop(t1, rise, None, None, None, None)
        t10 = next(t for t, pv in after if pv >= t1 + 0.1 * rise)
        t90 = next(t for t, pv in after if pv >= t1 + 0.9 * rise)
        points = [(t, pv) for t, pv in after if t10 <= t <= t90]
        if len(points) < 3:
            return OpenLoop(t1, rise, t10 - self.step_at, None, None, None)
        slope, intercept = _line(points)
        if slope <= 0:
            return OpenLoop(t1, rise, t10 - self.step_at, None, None, None)
        meets = (t1 - intercept) / slope
        output = self.output or math.nan
        return OpenLoop(t1, rise, t10 - self.step_at, meets - self.step_at, slope, slope / output)


def _worst_ratio(tuned: tune.Tuned) -> float:
    """The largest 2σ as a fraction of its goal (≤ 1: within every goal)."""
    m, u = tuned.model, tuned.uncertainty
    return max(
        2 * u.gain / (tune.GOAL_RELATIVE * m.gain),
        2 * u.tau / (tune.GOAL_RELATIVE * m.tau),
        2 * u.dead_time / tune.GOAL_DEAD_TIME_S,
    )


def _line(points: list[tuple[float, float]]) -> tuple[float, float]:
    """Least-squares slope and intercept of y on x."""
    n = len(points)
    mx = sum(x for x, _ in points) / n
    my = sum(y for _, y in points) / n
    sxx = sum((x - mx) ** 2 for x, _ in points)
    sxy = sum((x - mx) * (y - my) for x, y in points)
    slope = sxy / sxx
    return slope, my - slope * mx


def default_output(
    litres: float, element_watts: float, start: float, limit: float, max_output: float = 100.0
) -> float:
    """The output that would take the water from `start` to `limit` in TARGET_STEP_S at the
    element's linear rate (no losses), within MIN_OUTPUT..100 %: a strong element at a low
    output bends the curve enough to show τ before the limit (the seed steps to 20 %); never
    above the config's control.max_output."""
    capacity = tune.WATER_J_PER_L_K * litres
    wanted = 100.0 * (limit - start) * capacity / (element_watts * TARGET_STEP_S)
    return float(min(max(math.ceil(wanted), MIN_OUTPUT), max_output))


def write(experiment: StepExperiment, path: Path) -> str:
    """Write the fit's settings into the config file (tune's writer): never after an alarm or
    an interrupt, nor from a fit that is not good."""
    why = experiment.stopped or "not run"
    if why.startswith(ABORTED):
        raise tune.TuneError(f"{path} left as it is: the step test was stopped by {why}")
    last = experiment.last
    if last is None or last.tuned is None:
        raise tune.TuneError(f"{path} left as it is: no model was fitted")
    if why != FIT_GOOD and last.tuned.confidence == "good" and not last.settled:
        raise tune.TuneError(
            f"{path} left as it is: the test stopped ({why}) before K and τ had settled"
        )
    return tune.write_tuned(path, last.tuned)


class Experiment(Protocol):
    """A test that listens to the daemon's periods and can be told it was interrupted."""

    @property
    def daemon(self) -> Daemon: ...

    def period(self, record: PeriodRecord) -> None: ...

    def alarm(self, alarm: Alarm) -> None: ...

    def interrupted(self, why: str) -> None: ...

    def conclude(self) -> None: ...


def run(
    experiment: Experiment,
    interrupts: tuple[type[BaseException], ...],
    *,
    heater_off: bool = True,
) -> None:
    """Run the daemon until the experiment stops it, an interrupt, or a failure; the heater is
    off afterwards whatever happened (the daemon's shutdown on leaving its context).

    `heater_off`: manual 0 % from the first period (the step's baseline); else the daemon
    starts as it was asked to (the relay test's heat-up in auto)."""
    daemon = experiment.daemon
    daemon.listeners.append(experiment)
    if heater_off:
        daemon.set_manual(0.0)  # applied before the first period: the baseline is heater-off
    try:
        with daemon:
            daemon.run()
    except interrupts as why:
        experiment.interrupted(type(why).__name__)
    experiment.conclude()


def clock_text(seconds: float) -> str:
    """h:mm:ss, as the progress lines give times."""
    minutes, secs = divmod(round(seconds), 60)
    return f"{minutes // 60}:{minutes % 60:02d}:{secs:02d}"


def progress_line(progress: Progress) -> str:
    """One line a fit: elapsed, PV, the estimates with one standard deviation, time left."""
    head = f"step +{clock_text(progress.elapsed)}"
    if progress.pv is not None:
        head += f"  PV {progress.pv:.2f} °C"
    tuned = progress.tuned
    if tuned is None:
        return f"{head}  no fit yet: {progress.problem}"
    left = "unknown" if progress.left_s is None else f"~{clock_text(progress.left_s)}"
    verdict = "poor" if tuned.confidence != "good" else "good" if progress.settled else "settling"
    return f"{head}  {estimates(tuned)}  ({verdict})  left {left}"


def estimates(tuned: tune.Tuned) -> str:
    """K, τ and θ with one standard deviation, on one line."""
    m, u = tuned.model, tuned.uncertainty
    return (
        f"K {m.gain:.3f}±{u.gain:.3f} °C/%  τ {m.tau:.0f}±{u.tau:.0f} s  "
        f"θ {m.dead_time:.0f}±{u.dead_time:.0f} s"
    )


def result_json(experiment: StepExperiment) -> dict[str, Any]:
    last = experiment.last
    result: dict[str, Any] = {
        "stopped": experiment.stopped,
        "stop_rule": STOP_RULE,
        "output": experiment.output,
        "limit": experiment.limit,
        "step_s": None if last is None else last.elapsed,
        "open_loop": None if last is None else dataclasses.asdict(last.open_loop),
        "problem": None if last is None else last.problem,
    }
    if last is not None and last.tuned is not None:
        result.update(tune.tuned_json(last.tuned))
    return result


def result_lines(experiment: StepExperiment) -> list[str]:
    last = experiment.last
    lines = [f"step test stopped: {experiment.stopped}; the heater is off"]
    if last is None or experiment.step_at is None:
        return [*lines, "nothing measured: the output was never stepped"]
    ol = last.open_loop
    lines.append(
        f"step to {experiment.output:g} % for {clock_text(last.elapsed)}, T1 {ol.t1:.2f} °C, "
        f"rise {ol.rise:.2f} °C (limit {experiment.limit:g} °C)"
    )
    lines.append("open loop (seed 001 §4.1, on the rise so far):")
    lines.append(f"  dead time, 10 % rule: {_maybe(ol.dead_time_10, '.0f', 's')}")
    lines.append(
        f"  dead time, 10–90 % regression line at T1: {_maybe(ol.dead_time_line, '.0f', 's')}"
    )
    lines.append(
        f"  slope a {_maybe(ol.slope, '.3g', '°C/s')}, a* {_maybe(ol.a_star, '.3g', '°C/(%·s)')}"
    )
    if last.tuned is None:
        return [*lines, f"no model: {last.problem}"]
    lines += ["", *tune.tuned_lines(last.tuned)]
    return lines


def _maybe(value: float | None, spec: str, unit: str) -> str:
    return "not yet measurable" if value is None else f"{value:{spec}} {unit}"
