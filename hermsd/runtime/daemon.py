"""The control loop: sensor → supervisor → controller → planner → outputs, on one scheduler.

The same code runs on the Pi (real clock, LM92 on /dev/i2c-N, SSR on a serial line or GPIO),
in real time against the simulated tun, and at full speed in `hermsd simulate`. Everything
outside — hardware, clock, recorder, systemd notifier — is handed in, with the parts built
from the config (`runtime/assemble.py`, the composition root).

Per control period the controller sees one PV and the duty the SSR was driven at in the
period before (`applied`: the time its input was on, as switched, edge lateness and forced
offs included), so it tracks the actuator. It is not a measurement of the element's power:
a shorted SSR, an open contactor or a dead element show only in the temperature, which is
what the supervisor's watches are for. When the supervisor forbids
heating, the SSR is cut at once (mid-window), the contactor opens, and the controller is
held, not fed zeros; when heating is allowed again it resumes from the output it had.
Inside a period the loop acts on one thing only: cold water that the controller answers
with full power runs the element at full power from that reading on (`_act_on_drop`).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any, Protocol

from hermsd.config.schema import Config
from hermsd.control import predictive
from hermsd.control.element2 import SplitController, TwoElementController, total_share
from hermsd.control.factory import full_power
from hermsd.control.learning import LearnedModel, ModelStore
from hermsd.control.pv import period_value
from hermsd.control.reach import Said
from hermsd.control.watches import HeatUpFit
from hermsd.hardware.lm92 import (
    LimitName,
    Reading,
    SensorError,
    WrongChipError,
    decode_temperature,
    encode_temperature,
)
from hermsd.hardware.outputs import window_length
from hermsd.hardware.sensors.kinds import describe as describe_sensor
from hermsd.hardware.ssr import (
    CarriedHeat,
    SwitchedDuty,
    WindowPlan,
    cut,
)
from hermsd.log.topics import MODEL_TOPIC, LogLevel, log_message
from hermsd.runtime.alerts import SHUTDOWN_WAIT, Alerts, Event
from hermsd.runtime.build import (
    element2_watts,
    elements,
    left_out,
    measured_tun,
    reach_period,
    safety_limits,
    said_dead,
    take_heat_up,
)
from hermsd.runtime.current_side import CurrentSide
from hermsd.runtime.latch_keeping import LatchKeeping
from hermsd.runtime.mash_side import MashSide, SeenPump, role_sensors
from hermsd.runtime.notify import WatchdogGate
from hermsd.runtime.parts import Parts
from hermsd.runtime.period import PeriodRecord
from hermsd.runtime.reloading import Reloading
from hermsd.runtime.reporting import Reporting
from hermsd.runtime.running_program import RunningProgram
from hermsd.runtime.scheduler import LatenessStats, Scheduler, Timer
from hermsd.safety.element_probe import ProbeResult
from hermsd.safety.element_watch import named_dead, report_kind
from hermsd.safety.latches import Latches
from hermsd.safety.limits import Alarm, MeasuredTun, raised_alarm_text

log = logging.getLogger("hermsd")

TIMING_INTERVAL = 60.0  # s between timing records
STOP_SIGNALS = {signal.SIGINT, signal.SIGTERM}
LATCH_SAVE_SLOW_S = 10.0  # a latch save not done after this long is said as not saved (yet)
STOP_WAIT_S = 8.0
"""s of real time at most that the stop waits, once the outputs are off, for the saves (the
latched alarms first: what a restart must find), then the program's progress, then queued
alerts, in that order: inside systemd's stop timeout of 10 s (systemd/hermsd.service), so
that what was not saved is said before a SIGKILL could cut the stop short."""


class ControlHook(Protocol):
    """Operator commands from outside the loop (the control socket, `hermsd.control`)."""

    def at_boundary(self, t: float) -> None:
        """Check and queue the commands that arrived (at a period boundary, before the queue
        of operator actions is applied)."""
        ...


class Listener(Protocol):
    """Observers of the loop (the simulator's metrics, tests)."""

    def period(self, record: PeriodRecord) -> None: ...

    def alarm(self, alarm: Alarm) -> None: ...


def _hold_stop_signals(held: list[int]) -> tuple[dict[int, Any], BaseException | None]:
    """Make SIGINT and SIGTERM append to `held` instead of running their handlers.

    Returns the handlers to put back, and a stop that was already due and ran meanwhile.
    Handlers can only be changed on the main thread; elsewhere nothing is held.
    """
    if threading.current_thread() is not threading.main_thread():
        return {}, None

    def hold(signum: int, frame: object) -> None:
        held.append(signum)

    previous: dict[int, Any] = {}
    interrupted: BaseException | None = None
    for sig in STOP_SIGNALS:
        while True:
            try:
                current = signal.getsignal(sig)
                if current is not hold:
                    previous.setdefault(sig, current)
                signal.signal(sig, hold)
                break
            except BaseException as error:  # a handler already due ran here: try again
                interrupted = interrupted or error
    return previous, interrupted


@dataclass(slots=True)
class _Window:
    """The window in progress and its pending edges."""

    plan: WindowPlan | None = None
    timers: list[Timer] = field(default_factory=list)
    cut: bool = False  # the heater was forced off in it: nothing heats again before the next

    def cancel(self) -> None:
        for timer in self.timers:
            timer.cancel()
        self.timers.clear()


class Daemon(Reloading, RunningProgram, LatchKeeping, MashSide, CurrentSide, Reporting):
    """One tun's control loop (its reload, mash program, latched alarms on disk, the mash's
    sensors and pump, and the element's current input in their own modules)."""

    def __init__(self, parts: Parts) -> None:
        """The loop on `parts` (`runtime/assemble.py` builds them from a config)."""
        config, clock, outputs, notifier = parts.config, parts.clock, parts.outputs, parts.notifier
        self.config = config
        self.tun_model = parts.tun_model
        self.config_file = parts.config_file
        self.latches = parts.latches
        self.clock = clock
        self.sensor = parts.sensor
        self.outputs = outputs
        self.recorder = parts.recorder
        self.notifier = notifier
        interval = notifier.watchdog_interval() if notifier is not None else None
        # Every healthy period may ping: one missed period must not use up the timeout.
        period = config.control.period
        self._watchdog = WatchdogGate(min(interval, period / 2)) if interval else None
        self._ready = False
        self.on_status = parts.on_status
        self.listeners: list[Listener] = []
        self.scheduler = Scheduler(clock)
        self.models = parts.models
        self.saver = parts.saver  # latches and model, off the loop
        self._stored_model = parts.stored_model
        self._learned_since: LearnedModel | None = None  # stored since the start, not in force
        self._model_problem = parts.model_problem  # said in the log at start
        self.model_choice = parts.model_choice
        self.model = self.model_choice.model
        self.supervisor = parts.supervisor
        self.controller = parts.controller
        self._learner = parts.learner
        self._heat_up_seen = predictive.heat_up_fit(self.controller)
        self._limits_fit: HeatUpFit | None = None  # the heat-up the limits were tightened by
        self._limits_dead: frozenset[int] = frozenset()  # … and the elements they leave out
        self._pulsing = False  # whether a measured pulse holds the heat (said when it moves)
        self._reloaded_at = -math.inf  # when a reload last changed the config
        self.planner = parts.planner
        self.element2 = parts.element2
        self.element_watch = parts.element_watch
        self.reach = parts.reach
        self.setpoint = config.control.setpoint
        self.mode = config.control.mode
        self.manual_output = config.control.manual_output
        self.output = 0.0
        self.k = 0
        self.edge_lateness = LatenessStats()
        self._pv: float | None = None
        self._last_celsius: float | None = None
        self._readings: list[float] = []
        self._stepped = False  # the controller stepped at the last boundary (its state is fresh)
        self._full_from: int | None = None  # see PeriodRecord.full_from
        # The element went to full power within this period (acted on `_full_from`): what the
        # supervisor and the status are told was asked. The controller's output stays its own,
        # so a manual switch or a bumpless restart never takes the 100 % for the brewer's.
        self._full_power = False
        self._outputs_off = False  # shut down: every output switched off, for good
        self._held = True  # nothing to continue from until the first good period
        self._resume_output = 0.0
        self._window = _Window()
        self._ssr_duty = SwitchedDuty()  # the SSR as switched since the last period
        self._carried = CarriedHeat()  # … and the heat its band carried (docs/ssr-band.md)
        self._reads = 0
        self._pending: list[Callable[[float], None]] = []
        self.control: ControlHook | None = None
        self._started = False
        self._reload_requested = False
        self._config_problem: str | None = None  # why the file's last edit was rejected
        self._output2: float | None = None  # the second element's duty, when one is fitted
        self._saved_latches: list[str] = []  # the kinds on disk, as last saved
        self._tried_latches: list[str] = []  # the kinds of the last save handed over
        self._latch_failing: str | None = None  # why the last latch save done failed
        self._latch_retry_at = 0.0  # a failed save is tried again from then, or at a change
        self._latches_handed_at = 0.0  # when the last latch save was handed to the saver
        self._latch_slow = False  # whether _latch_failing says a save that has not finished
        self._latched_wall_ns: dict[str, int] = {}  # when each latched alarm was raised
        self._latched_messages: dict[str, str] = {}  # restored ones' messages, as first raised
        self._log_failing: str | None = None  # why the recorder cannot write, as last said
        self._log_failing_since = 0.0
        self._log_failing_said = 0.0
        self.alerts = Alerts(
            config.alerts, lambda message: self._event(logging.WARNING, message, clock.monotonic())
        )
        self.program = parts.program
        self._roles, self._pump_on, self._program_pump_step = role_sensors(parts), False, None
        self._seen_pump = SeenPump(parts.pump_sense) if parts.pump_sense is not None else None
        self._mash_control = parts.mash_control
        self._init_current(parts.current_sense)

    # -- life cycle -----------------------------------------------------------------------

    def start(self) -> None:
        """Outputs off, check and program the sensor, and lay out the schedule.

        A latch file that cannot be read raises StateError: the daemon must not guess.
        """
        for output in self.outputs.all():
            output.set(False)
        stored = self.latches.load() if self.latches is not None else Latches()
        self.sensor.identify()
        self._program_sensor()
        now = self.clock.monotonic()
        self._ssr_duty.begin(now)
        read_interval = self.config.sensor.read_interval
        self._read_now(now)
        self._start_mash_side()
        sched = self.scheduler
        sched.every("read", read_interval, self._on_read, origin=now + read_interval / 2)
        self._control_task = sched.every(
            "control", self.config.control.period, self._on_control, origin=now, priority=1
        )
        sched.every("window", window_length(self.config), self._on_window, origin=now, priority=2)
        sched.every("timing", TIMING_INTERVAL, self._on_timing, origin=now + TIMING_INTERVAL)
        self._started = True
        self._record_config("start", now)
        self._event(logging.INFO, "started", now)
        if self.config.sensor.kind != "lm92":  # the LM92's log as it was
            simulated = " (simulated)" if self.config.output.backend == "sim" else ""
            said = f"sensor: {describe_sensor(self.config.sensor)}{simulated}"
            self._event(logging.INFO, said, now)
        self.alerts.start()
        self._alert("started", "hermsd started", now)
        self._check_log(now)
        if self._model_problem is not None:
            self._event(logging.WARNING, f"learned model ignored: {self._model_problem}", now)
        if self._stored_model is not None and self.model_choice.source != "learned":
            learn, litres = self.config.control.learn, self.config.tun.litres
            why = f"out of the controller's range at {litres:g} L"
            if element2_watts(self.config) and self.config.control.algorithm == "midrange":
                why = "mid-ranging's two controllers: it models one law"
            elif learn == "off":
                why = "control.learn off"
            elif learn == "pinned" and self.model_choice.source == "measured":
                why = "control.learn pinned: the model from hermsd tune comes first"
            self._event(
                logging.INFO,
                f"learned model not used ({why}): {self._stored_model.describe()}",
                now,
            )
        if self.model_choice.measured is not None:  # else the prior, as status says
            what = self.model_choice.describe()
            self._event(logging.INFO, f"tun model in use (control and safety limits): {what}", now)
        self._restore_latches(stored, now)
        resumed = self.program.restore(self.setpoint, self.clock.wall_ns())
        if resumed is not None:
            self._event(logging.WARNING if "not resumed" in resumed else logging.INFO, resumed, now)

    def _program_sensor(self) -> None:
        """Wake the chip and set its limits; its T_CRIT_A pin can then gate the SSR in hardware."""
        safety = self.config.safety
        self.sensor.wake()
        self.sensor.set_limit("hyst", safety.hysteresis)
        self.sensor.set_limit("crit", safety.max_temp)

    def run(self, until: float = math.inf) -> None:
        """Run the loop until `until` (monotonic s) or `stop()`; start() first if needed."""
        if not self._started:
            self.start()
        self.scheduler.run(until)

    def stop(self) -> None:
        self.scheduler.stop()

    def __enter__(self) -> Daemon:
        return self

    def __exit__(self, *exc: object) -> None:
        error = exc[1]
        self.shutdown("stopped" if error is None else f"stopped ({error or type(error).__name__})")

    @property
    def overruns(self) -> int:
        """Control periods skipped because the loop was late."""
        return self._control_task.overruns if self._started else 0

    def shutdown(self, reason: str = "stopped") -> bool:
        """Heater off and contactor open, whatever else fails; False if an output refused.

        A stop signal that arrives meanwhile (a second Ctrl-C, systemd's stop during a SIGINT)
        is held until every output has been tried, then delivered: masking it would not do,
        as any other thread may take it and Python runs its handler on this one all the same.
        A stop that was already due when holding began is caught and raised at the end.
        """
        held: list[int] = []
        previous, interrupted = _hold_stop_signals(held)
        try:
            ok, failed_by = self._all_off(reason)
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
        interrupted = interrupted or failed_by
        if interrupted is not None:
            raise interrupted
        for signum in held[:1]:
            signal.raise_signal(signum)  # to the handler that was held back
        return ok

    def _all_off(self, reason: str) -> tuple[bool, BaseException | None]:
        ok = True
        interrupted: BaseException | None = None
        steps = [("the window's edges", self._window.cancel)]
        steps += [(output.name, output.close) for output in self.outputs.all()]
        for name, step in steps:
            try:
                step()
            except Exception as error:  # every output must be tried, and the failure told
                ok = False
                log.critical("could not switch %s off: %s", name, error)
            except BaseException as error:  # a stop that was already due: the rest first
                interrupted = interrupted or error
        now = self.clock.monotonic()
        self._ssr_duty.switched(False, now)
        self._outputs_off = True
        self._stop_mash_side(reason, now)
        self._event(logging.INFO, f"heater off: {reason}", now)
        self._alert("stopped", f"heater off: {reason}", now)
        deadline = time.monotonic() + STOP_WAIT_S  # outputs are off: what is left may wait
        self._close_saves(now, STOP_WAIT_S)
        self.program.close(max(0.0, deadline - time.monotonic()))  # for the next start
        left = max(0.0, deadline - time.monotonic())
        self.alerts.close(min(self.config.alerts.timeout, SHUTDOWN_WAIT, left))
        if self.notifier is not None:
            self.notifier.stopping()
        return ok, interrupted

    # -- operator actions (applied at the next period boundary) ---------------------------

    def set_setpoint(self, celsius: float) -> None:
        if not (math.isfinite(celsius) and 0.0 <= celsius <= 100.0):
            raise ValueError(f"setpoint must be within 0..100 °C, got {celsius}")
        self._pending.append(lambda t: self._apply_setpoint(celsius, t))

    def set_manual(self, output: float | None = None) -> None:
        """Manual mode at `output` % (the current output when None)."""
        if output is not None and not (math.isfinite(output) and 0.0 <= output <= 100.0):
            raise ValueError(f"manual output must be within 0..100 %, got {output}")
        self._pending.append(lambda t: self._apply_manual(output, t))

    def set_auto(self) -> None:
        self._pending.append(self._apply_auto)

    def reset_alarms(self, kinds: list[str] | None = None) -> None:
        """Clear latched alarms (`kinds`, or all) at the next period boundary."""
        self._pending.append(lambda t: self._apply_reset(t, kinds))

    def operator_action(self, what: str, t: float) -> None:
        """Log an operator's action (`what` names it and where it came from)."""
        self._event(logging.INFO, f"operator: {what}", t)

    def _apply_setpoint(self, celsius: float, t: float) -> None:
        if self.program.active:  # the program owns the setpoint until it stops
            self.program.after = celsius
            self._event(logging.INFO, f"setpoint {celsius:.2f} °C when the program stops", t)
            return
        self.setpoint = celsius
        self._event(logging.INFO, f"setpoint {celsius:.2f} °C", t)

    def _apply_manual(self, output: float | None, t: float) -> None:
        self.mode = "manual"
        wanted = self.output if output is None else output
        self.manual_output = min(wanted, self.config.control.max_output)  # the power limit holds
        self._event(logging.INFO, f"manual mode at {self.manual_output:.1f} %", t)

    def _apply_auto(self, t: float) -> None:
        if self.mode != "auto":
            self.mode = "auto"
            self._held = True  # resume bumplessly from the manual output
            self._resume_output = self.manual_output
            self._event(logging.INFO, "auto mode", t)

    def _apply_reset(self, t: float, kinds: list[str] | None = None) -> None:
        cleared = self.supervisor.reset_latched(t, kinds)
        self._drain_alarms(t)
        if cleared:
            self._event(logging.WARNING, f"alarms reset: {', '.join(cleared)}", t)

    # -- the tun's model: prior, learned, learning ----------------------------------------

    @property
    def learned_model(self) -> LearnedModel | None:
        """What was learned of the tun and stored: the last saved since the start, else as
        read at start (None: nothing usable). The model in force (`model_choice`) takes a
        new one at the next start only."""
        return self._learned_since or self._stored_model

    def _measured_tun(self, config: Config) -> MeasuredTun | None:
        """The tun as measured for the supervisor's limits (`build.measured_tun`)."""
        return measured_tun(config, self._stored_model, self.tun_model)

    def _learn(self, record: PeriodRecord) -> None:
        """Feed the learner one period; store and log what it learned (or why not)."""
        models = self.models
        if self.config.control.learn != "on" or models is None:
            return
        if self.element2 is not None and self.config.control.algorithm == "midrange":
            return  # two controllers, one an element each: the learner models one law
        learner = self._learner
        fit = predictive.heat_up_fit(self.controller)
        pumping = record.pump or record.coil_load  # the coil draws heat the model has not
        if record.state != "ok" or record.mode != "auto" or record.pv is None or pumping:
            learner.interrupt()
        elif record.reset_from is not None and record.k > 1:
            learner.interrupt()  # resumed after a hold: the spell before it does not count
        elif fit is not self._heat_up_seen and fit is not None:
            if record.t - fit.span <= self._reloaded_at:
                learner.interrupt()  # the heat-up it measured had a reload in it
                self._heat_up_seen = fit
                return
            learner.heat_up(fit)
            what = f"rate {fit.rate * 60.0:.3f} °C/min, dead time {fit.dead_time:.0f} s"
            if fit.lag > 0.0:
                what += f" (of it the sensor's lag {fit.lag:.0f} s)"
            if fit.refused is None:
                self._event(logging.INFO, f"heat-up measured: {what}", record.t)
            else:
                self._event(logging.WARNING, f"heat-up measure refused: {fit.refused}", record.t)
        else:
            applied = self._of_both(record.applied, record.applied2)
            noise = predictive.noise_scale(self.controller)
            estimate = learner.period(record.hlt_target, record.pv, applied, noise=noise)
            if estimate is not None:
                self._store_model(models, estimate.model, estimate.refused, record.t)
        self._heat_up_seen = fit

    def _store_model(
        self, models: ModelStore, model: LearnedModel | None, refused: str | None, t: float
    ) -> None:
        if model is None:
            self._event(logging.WARNING, f"learned model refused: {refused}", t)
            return
        model = dataclasses.replace(
            self.with_coil(model), wall_ns=self.clock.wall_ns(), elements=elements(self.config)
        )
        if self.recorder is not None:
            self.recorder.write(
                MODEL_TOPIC, self.clock.wall_ns(), {"t": t, "learned": asdict(model)}
            )
        self.saver.save("model", lambda: models.save(model), model)
        self._take_saves(t)

    # -- the periodic work ----------------------------------------------------------------

    def _on_read(self, deadline: float, now: float) -> None:
        self._read_now(now)
        self._read_mash_side()
        sup = self.supervisor
        sup.tick(now)
        if not sup.heater_allowed:
            self._force_off(now)
        self._drain_alarms(now)
        self._act_on_drop(now)

    def _asked(self) -> float:
        """The output the element is driven at now: the controller's, or full power since a
        reading in this period showed cold water."""
        return 100.0 if self._full_power else self.output

    def _act_on_drop(self, now: float) -> None:
        """Full power from this reading on, not from the next period, when the readings so
        far show cold water that the controller answers with it (`pid.full_power_now`).

        The decision depends only on what the period record logs (its readings, and the
        controller as the last step left it), so replay checks it; it is made whether or not
        heating is allowed, and acted on only when it is (every edge is gated all the same).
        """
        if self._full_from is not None or not self._stepped or self._pv is None:
            return
        if not predictive.full_power_now(
            self.controller, self.hlt_target(), self._pv, self._readings
        ):
            return
        self._full_from = len(self._readings)
        window = self._window
        # A window cut by a forced off left the contactor open: nothing heats before the next.
        if not self.supervisor.heater_allowed or window.plan is None or window.cut:
            return
        self._full_power = True  # in force until the next step
        drop = self._pv - self._readings[-1]
        self._event(logging.INFO, f"PV fell {drop:.2f} °C within the period: full power", now)
        window.cancel()
        self._arm(self.planner.full_from(window.plan, now), now)

    def _read_now(self, now: float) -> None:
        sup = self.supervisor
        self._reads += 1
        reading: Reading | None = None
        error: SensorError | None = None
        lost: str | None = None
        try:
            if self._reads % self._reads_per_period() == 0:
                self.sensor.identify()
                sup.chip_check(self.clock.monotonic(), True)
                lost = self._sensor_limits_lost()
            reading = self.sensor.read()
        except WrongChipError as exc:
            error = exc
        except SensorError as exc:
            error = exc
        t = self.clock.monotonic()  # a slow bus moves time; judge the value when it arrived
        if lost is not None:
            self._event(logging.WARNING, f"the sensor lost its limits ({lost}): set again", t)
            self._reprogram_sensor(t)
        accepted = False
        if isinstance(error, WrongChipError):
            sup.chip_check(t, False, f"wrong chip: {error}")
        elif error is not None:
            sup.read_error(t, f"read failed: {error}", error.errno)
        elif reading is not None:
            accepted = sup.reading(t, reading.celsius, reading.raw, reading.crit)
            if accepted:
                self._readings.append(reading.celsius)
                self._last_celsius = reading.celsius
        if self.recorder is not None:
            self.recorder.write(
                "/hermsd/reading",
                self.clock.wall_ns(),
                {
                    "t": t,
                    "celsius": reading.celsius if reading else None,
                    "raw": reading.raw if reading else None,
                    "crit": reading.crit if reading else None,
                    "high": reading.high if reading else None,
                    "low": reading.low if reading else None,
                    "error": str(error) if error else None,
                    "errno": error.errno if error else None,
                    "accepted": accepted,
                },
            )

    def _reads_per_period(self) -> int:
        return max(1, round(self.config.control.period / self.config.sensor.read_interval))

    def _on_control(self, deadline: float, now: float) -> None:
        sup = self.supervisor
        sup.loop_lateness(now, now - deadline)
        sup.tick(now)
        self.alerts.flush(now)
        self._poll_config(now)
        self._poll_reset_request(now)
        if self.control is not None:
            self.control.at_boundary(now)
        for action in self._pending:
            action(now)
        self._pending.clear()
        readings, self._readings = self._readings, []
        full_from, self._full_from = self._full_from, None
        asked, self._full_power = self._asked(), False
        self._stepped = False
        pv = period_value(readings)
        if pv is None:
            pv = self._last_celsius  # a slow read interval: the latest accepted value
        self._pv = pv
        # The band's carried heat counts as given when asked (a controller would chase bursts).
        applied = self._ssr_duty.read(now, self._carried.take(self._window.plan, now))
        switched2 = applied2 = None
        on2 = free2 = None
        if self.element2 is not None:
            switched2, applied2 = self.element2.applied(now)
            on2, free2 = self.element2.state(now)
        if isinstance(self.controller, SplitController) and on2 is not None:
            applied2 = switched2  # the heat, as switched: the total's model stays exact
            self.controller.on2, self.controller.free2 = on2, bool(free2)
        if isinstance(self.controller, TwoElementController):
            self.controller.applied2 = applied2 or 0.0
        probed = (
            self.controller.probe_result() if isinstance(self.controller, SplitController) else None
        )
        if self.element_watch is not None:  # the heat-up as fitted by the step before (replay)
            take_heat_up(self.element_watch, self.controller)
            said_dead(self.controller, self.element_watch.suspect)  # as the last period said
        total_asked, total_applied = self._total_power(asked, applied, switched2)
        at_full = full_power(self.config).reached(applied, switched2)
        sup.period(now, pv, total_asked, total_applied, self.coil_load(pv))
        self._drain_alarms(now)
        # The schedule's tun is both elements (its rates are of their sum): so is its duty.
        standby = self._program_period(now, pv, total_applied, at_full) and self.mode == "auto"
        target = self._steer(pv, applied, now)  # the HLT's setpoint (the mash's outer loop's)
        state = "ok"
        reset_from: float | None = None
        if standby and sup.heater_allowed and pv is not None:
            if not self._held:  # heating starts from nothing when the program's time comes
                self._held, self._resume_output = True, 0.0
            self.output = 0.0
            state = "scheduled"
        elif sup.heater_allowed and pv is not None:
            if self.mode == "manual":
                self.output = self.manual_output
            else:
                if self._held:
                    reset_from = self._resume_output
                    self.controller.reset(pv, reset_from)
                    self._held = False
                if full_from is not None:
                    predictive.cold_water_seen(self.controller)
                predictive.readings_seen(self.controller, readings)
                self.output = self.controller.step(target, pv, applied)
                self._stepped = True
                controller = self.controller
                asked_outputs = (
                    controller.asked
                    if isinstance(controller, TwoElementController)
                    else (self.output, None)
                )
                if not sup.controller_output(now, *asked_outputs):
                    self._drain_alarms(now)  # the heater off at once, said, latched
                    self._held, self._resume_output = True, 0.0
                    self.output, self._stepped, state = 0.0, False, "alarm"
        else:
            if not self._held:
                self._held = True
                self._resume_output = self.output
            self.output = 0.0
            self._force_off(now)
            state = "alarm" if sup.active else "waiting"
        if self.mode == "manual" and state == "ok":
            state = "manual"
        if readings and self._watchdog is not None:
            # A fresh reading made a fresh decision, heating or held off (an alarm, a program
            # waiting for its time): the loop is alive. Only a loop without readings stops
            # earning pings; a kill in a healthy hold would restart, and re-alert, for hours.
            self._watchdog.note_healthy_cycle()
        u2 = self._output2 = self._drive_element2(now, state)
        if self.element_watch is not None and switched2 is not None:
            self._watch_elements(now, pv, applied, switched2, state, probed)  # replay too
        self.k += 1
        terms = self.controller.terms
        record = PeriodRecord(
            t=now,
            k=self.k,
            setpoint=self.setpoint,
            pv=pv,
            readings=readings,
            output=self.output,
            applied=applied,
            p=terms[0],
            i=terms[1],
            d=terms[2],
            mode=self.mode,
            algorithm=self.config.control.algorithm,
            state=state,
            alarms=sup.active,
            heater_allowed=sup.heater_allowed,
            reset_from=reset_from,
            u2=u2,
            applied2=applied2,
            switched2=switched2,
            on2=on2,
            free2=free2,
            no_heat=None if self.element_watch is None else sorted(self.element_watch.suspect),
            full_from=full_from,
            **self.program.record_fields(),
            **self.mash_side_fields(),
            **self.current_fields(),
        )
        said = reach_period(self.reach, record, self.model, self.config, self.controller)
        self._say_reach(said, now)
        record = dataclasses.replace(record, ceiling=self.reach.ceiling)
        for listener in self.listeners:
            listener.period(record)
        if self.recorder is not None:
            self.recorder.write("/hermsd/period", self.clock.wall_ns(), asdict(record))
        self._learn(record)
        self._limits_from_heat_up(record.t)
        self._say_pulse(record.t)
        self._report(now)

    def _limits_from_heat_up(self, t: float) -> None:
        """Tighten the supervisor's limits by the day's heat-up once the control law has
        measured it (its rate and dead time): a fault is then judged on this tun as it is
        filled today, not on any tun the config may describe (`SafetyLimits.with_heat_up`).
        An element said dead takes the fit back (it may have measured the other's heat as
        both's: docs/two-elements.md) and leaves full power the other's (`safety_limits`)."""
        fit = predictive.heat_up_fit(self.controller)
        if fit is None or fit.refused is not None:
            fit = self._limits_fit
        watch = self.element_watch
        dead = frozenset() if watch is None else named_dead(watch.suspect)
        if dead:
            fit = None
        if fit is self._limits_fit and dead == self._limits_dead:
            return
        self._limits_fit, self._limits_dead = fit, dead
        limits = safety_limits(self.config, self._measured_tun(self.config), fit, dead)
        if limits == self.supervisor.limits:
            return  # a measured model's limits stand
        self.supervisor.limits = limits
        said = (
            f"safety limits from the heat-up: its heat shows within {limits.dead_time:.0f} s, "
            f"full power heats at most {limits.heat_rate * 60.0:.3f} °C/min"
            if fit is not None
            else "safety limits: an element is said to give no heat, so full power is the "
            "other's alone, judged by the config's limits rather than the heat-up's"
        )
        self._event(logging.INFO, said, t)

    def _say_pulse(self, t: float) -> None:
        """Say when a measured pulse begins and ends: the heat off below the setpoint on
        purpose, for minutes, is nothing a brewer should have to guess at."""
        pulsing = predictive.pulse_running(self.controller)
        if pulsing == self._pulsing:
            return
        self._pulsing = pulsing
        said = (
            "heat-up: full power ends here to measure the tun (the heat stays off until what "
            "was sent has reached the sensor, then most of the rest is sent by the rate it "
            "shows, and the losses met while it arrives)"
            if pulsing
            else "heat-up: the measured pulse is over; the law brings the water the rest of "
            "the way and holds it"
        )
        self._event(logging.INFO, said, t)

    def _on_window(self, deadline: float, now: float) -> None:
        window = self._window
        self._carried.count(window.plan, now)  # the window before has ended
        window.cancel()
        window.cut = False
        allowed = self.supervisor.heater_allowed
        if self.outputs.contactor is not None:
            self.outputs.contactor.set(allowed)
        at_once = self._draw_began_unannounced()
        duty, gap = (self.output if allowed else 0.0), self._current_gap_due(deadline, now)
        self._arm(self.planner.plan(deadline, duty, at_once, gap), now)

    def _arm(self, plan: WindowPlan, now: float) -> None:
        """Make `plan` the window in progress (logged; a later one for the same start replaces
        it): the SSR as it says now, and its edges to come."""
        window = self._window
        window.plan = plan
        self._switch(plan.is_on(now), now)
        end = plan.start + plan.length
        for edge in (plan.on_at, plan.off_at):
            if now < edge < end:
                window.timers.append(self.scheduler.at(edge, self._on_edge))
        for at in self._current_times(plan, now):
            window.timers.append(self.scheduler.at(at, self._on_current_sample))
        if self.recorder is not None:
            self.recorder.write(
                "/hermsd/window",
                self.clock.wall_ns(),
                {
                    "t": plan.start,
                    "window": plan.length,
                    "requested": plan.requested,
                    "on_time": plan.on_time,
                    "applied": plan.applied,
                },
            )

    def _on_edge(self, when: float, now: float) -> None:
        plan = self._window.plan
        if plan is None:
            return
        self.edge_lateness.add(now - when)
        self._switch(plan.is_on(when), now)

    def _on_current_sample(self, when: float, now: float) -> None:
        """A sample of the element's current, while the heater may be on (else the window's
        timers are gone: a forced off cancels them)."""
        plan = self._window.plan
        if plan is not None and not self._window.cut and self.supervisor.heater_allowed:
            self._sample_current(plan.is_on(when))

    def _on_timing(self, deadline: float, now: float) -> None:
        if self.recorder is None:
            return
        p50, p99, worst = self._control_task.lateness.summary()
        e50, e99, eworst = self.edge_lateness.summary()
        self.recorder.write(
            "/hermsd/timing",
            self.clock.wall_ns(),
            {
                "t": now,
                "period_lateness_p50": p50,
                "period_lateness_p99": p99,
                "period_lateness_max": worst,
                "edge_error_p50": e50,
                "edge_error_p99": e99,
                "edge_error_max": eworst,
                "overruns": self._control_task.overruns,
                "dropped": getattr(self.recorder, "dropped", 0),
            },
        )

    # -- outputs --------------------------------------------------------------------------

    def _switch(self, on: bool, now: float) -> None:
        on = on and self.supervisor.heater_allowed
        self.outputs.ssr.set(on)
        self._ssr_duty.switched(on, now)

    def _force_off(self, now: float) -> None:
        """Heater off at once: the window in progress is cut, the contactor opened."""
        window = self._window
        if window.plan is not None:
            window.plan = cut(window.plan, now)
        window.cancel()
        window.cut = True
        self.planner.reset()
        self.outputs.ssr.set(False)
        self._ssr_duty.switched(False, now)
        if self.outputs.contactor is not None:
            self.outputs.contactor.set(False)
        if self.element2 is not None:
            self.element2.force_off(now)

    def _drive_element2(self, now: float, state: str) -> float | None:
        """The second element for the period: the controller's u2 in auto. Any other state
        (manual, which drives the SSR alone; an alarm; a program waiting for its ready_by
        time) forces it off every period, its minimum on time aside, so its switch and its
        duty say off: manual 0 % must not leave 3.5 kW on for minutes."""
        if self.element2 is None:
            return None
        if state != "ok":
            self.element2.force_off(now)
            return 0.0
        controller = self.controller
        u2 = controller.u2 if isinstance(controller, TwoElementController) else 0.0
        self.element2.drive(now, u2)
        return u2

    def _watch_elements(
        self,
        now: float,
        pv: float | None,
        duty1: float,
        duty2: float,
        state: str,
        probed: ProbeResult | None,
    ) -> None:
        """Said, not latched: the other element holds the tun (docs/two-elements.md). The
        heat-up's probe's finding of the step before comes first, as replay takes it."""
        assert self.element_watch is not None
        watch = self.element_watch
        reports = []
        if probed is not None and probed.element is None:
            self._event(logging.INFO, probed.message, now)
        elif probed is not None and probed.element is not None:
            reports.append(watch.blame(now, probed.element, probed.message))
        reports += watch.period(
            now, pv, self.hlt_target(), duty1, duty2, state == "ok", self.pump_state
        )
        for report in reports:
            said = report.message + left_out(report, self.controller)
            self._event(logging.WARNING if report.raised else logging.INFO, said, now)
            self._alert("element_warning", said, now, report_kind(report.element))

    def _say_reach(self, said: Said | None, t: float) -> None:
        """Log and alert what the reach watch said (a warning; nothing is switched off)."""
        if said is None:
            return
        self._event(logging.WARNING if said.raised else logging.INFO, said.message, t)
        kind = "short" if said.raised else "cleared"
        self._alert("setpoint_unreachable", said.message, t, kind)

    def _total_power(
        self, output: float, applied: float, applied2: float | None
    ) -> tuple[float, float]:
        """(output, applied) as % of all the elements' power, for the supervisor."""
        if applied2 is None or not isinstance(self.controller, TwoElementController):
            return output, applied
        return self._of_both(output, self.controller.u2), self._of_both(applied, applied2)

    def _of_both(self, duty: float, duty2: float | None) -> float:
        """The SSR's element's `duty` and the second's `duty2` (%) as one % of both elements'
        power (the split's law drives their total); `duty` itself without a second."""
        if duty2 is None or self.element2 is None:
            return duty
        watts, watts2 = self.config.tun.element_watts, element2_watts(self.config)
        return total_share(watts, watts2, duty, duty2)

    def _drain_alarms(self, t: float) -> None:
        for alarm in self.supervisor.drain_events():
            if alarm.raised:
                if alarm.latched:
                    self._latched_wall_ns.setdefault(alarm.kind, self.clock.wall_ns())
                self._force_off(t)
                level = logging.ERROR if alarm.latched else logging.WARNING
                self._event(level, raised_alarm_text(alarm), t)
                self._alert("alarm_raised", raised_alarm_text(alarm), t, alarm.kind)
            else:
                self._latched_wall_ns.pop(alarm.kind, None)
                self._latched_messages.pop(alarm.kind, None)
                self._event(logging.INFO, f"{alarm.kind} {alarm.message}", t)
                self._alert("alarm_cleared", f"{alarm.kind} {alarm.message}", t, alarm.kind)
                if alarm.kind == "sensor_fault":
                    self._reprogram_sensor(t)
            for listener in self.listeners:
                listener.alarm(alarm)
        self._take_saves(t)
        slow = t - self._latches_handed_at
        if self._latch_failing is None and slow >= LATCH_SAVE_SLOW_S and self._saving_latches():
            # A disk that hangs fails nothing: said all the same, as a restart now loses them.
            self._latch_failing = f"the save has not finished in {slow:.0f} s"
            self._latch_slow = True
            self._event(logging.ERROR, f"saving latched alarms: {self._latch_failing}", t)
        latched = self.supervisor.latched
        if latched != self._tried_latches or (
            self._latch_failing is not None
            and t >= self._latch_retry_at
            and not self._saving_latches()
        ):
            self._save_latches(t)

    def _alert(self, event: str, message: str, t: float, kind: str = "") -> None:
        """Hand an event to the alerts worker, with what the loop knows now."""
        name, wall_ns = self.config.tun.name, self.clock.wall_ns()
        heating = self.supervisor.heater_allowed and not self._outputs_off
        output = self._asked() if heating else 0.0  # the output in force
        self.alerts.send(
            Event(event, message, name, wall_ns, kind, self._pv, self.setpoint, output), t
        )

    def _sensor_limits_lost(self) -> str | None:
        """What of the chip's limits differs from what was set, or None. A chip reset by a
        dip in its supply reads on without a failed read, but with T_CRIT back at 80 °C."""
        safety = self.config.safety
        limits: tuple[tuple[LimitName, float], ...] = (
            ("crit", safety.max_temp),
            ("hyst", safety.hysteresis),
        )
        for name, celsius in limits:
            meant = decode_temperature(encode_temperature(celsius))
            found = self.sensor.limit(name)
            if found != meant:
                return f"{name} reads {found:g} °C, not {meant:g} °C: was the chip reset?"
        return None

    def _reprogram_sensor(self, t: float) -> None:
        """A chip that was gone may have powered up again with T_CRIT at 80 °C: set it again."""
        try:
            self._program_sensor()
        except SensorError as error:
            self.supervisor.read_error(t, f"programming the limits failed: {error}", error.errno)

    def _event(self, level: int, message: str, t: float) -> None:
        log.log(level, message)
        if self.recorder is not None:
            severity = {logging.WARNING: LogLevel.WARNING, logging.ERROR: LogLevel.ERROR}
            self.recorder.write(
                "/hermsd/log",
                self.clock.wall_ns(),
                log_message(severity.get(level, LogLevel.INFO), message, self.clock.wall_ns()),
            )
