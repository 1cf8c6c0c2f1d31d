"""The control loop on the simulated tun, on a virtual clock; and the real process's signals."""

from __future__ import annotations

import dataclasses
import itertools
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from hermsd.config import schema as config_module
from hermsd.config.schema import Config
from hermsd.control import pid
from hermsd.hardware.outputs import guard_outputs
from hermsd.runtime.assemble import assemble
from hermsd.runtime.daemon import Daemon
from hermsd.runtime.period import PeriodRecord
from hermsd.safety.latches import LatchStore
from hermsd.safety.limits import Alarm
from hermsd.sim.clock import VirtualClock
from hermsd.sim.world import World, build_world


class Periods:
    def __init__(self) -> None:
        self.records: list[PeriodRecord] = []
        self.alarms: list[Alarm] = []

    def period(self, record: PeriodRecord) -> None:
        self.records.append(record)

    def alarm(self, alarm: Alarm) -> None:
        self.alarms.append(alarm)


def make(
    config: Config | None = None, plant: dict[str, object] | None = None, *, history: bool = True
) -> tuple[Daemon, World, VirtualClock, Periods]:
    config = config or dataclasses.replace(
        config_module.DEFAULT,
        output=dataclasses.replace(config_module.DEFAULT.output, backend="sim"),
    )
    clock = VirtualClock()
    world = build_world(config, clock, plant, history=history)
    daemon = assemble(config, clock, world.sensor, world.outputs)
    periods = Periods()
    daemon.listeners.append(periods)
    return daemon, world, clock, periods


def test_edges_fall_exactly_where_the_planner_put_them() -> None:
    daemon, world, _clock, periods = make()
    with daemon:
        daemon.run(until=6000.0)
    edges = world.circuit.ssr_edges
    assert edges, "the heater never switched"
    # Every edge lies on the 10 ms half-cycle grid measured from the window start.
    for t in edges:
        offset = t % 5.0
        assert offset / 0.01 == pytest.approx(round(offset / 0.01), abs=1e-6)
    # The applied duty each period is the on-time the element really got, recomputed here
    # from the circuit's own record of its power.
    changes = world.circuit.power_changes
    for previous, record in zip(periods.records, periods.records[1:], strict=False):
        on = 0.0
        state, since = False, previous.t
        for when, powered in changes:
            if when <= previous.t:
                state = powered
                continue
            if when >= record.t:
                break
            if state:
                on += when - since
            state, since = powered, when
        if state:
            on += record.t - since
        assert record.applied == pytest.approx(100.0 * on / (record.t - previous.t), abs=1e-6)


def test_a_swing_switches_less_and_the_controller_is_told_what_it_asked() -> None:
    """The seed's 90 L, 3 kW tun with `output.swing` 1/16 °C: r = 3000 / (4186 × 90) =
    0.00796 °C/s, a band B = 0.0625 / 2r − W/4 = 2.67 s. Over an hour of its hold: the edges
    at most what the band's cycle makes (3600·d·(1 − d)/B, a quarter more for duty changes)
    where a pulse a window makes 720; the water swings at most r·(2B + W) (the debt's span:
    the band either way and a window's asking); each period's `applied` is the duty asked
    for its window, and the heat so counted is the heat switched to within a band and a
    window."""
    rate = 3000.0 / (4186.0 * 90.0)
    band = 0.0625 / (2.0 * rate) - 5.0 / 4.0
    config = dataclasses.replace(
        config_module.DEFAULT,
        output=dataclasses.replace(config_module.DEFAULT.output, backend="sim", swing=0.0625),
    )
    daemon, world, _clock, periods = make(config)
    start, temps = 8400.0, []
    with daemon:
        daemon.run(until=start)
        for k in range(1, 3601):
            daemon.run(until=start + k)
            temps.append(world.plant.temperature(start + k))
    records = periods.records
    hold = [(p, r) for p, r in itertools.pairwise(records) if p.t >= start]
    duty = sum(p.output for p, _ in hold) / len(hold) / 100.0
    edges = [t for t in world.circuit.ssr_edges if t >= start]
    assert len(edges) <= 1.25 * 3600.0 * duty * (1.0 - duty) / band
    assert max(temps) - min(temps) <= rate * (2.0 * band + 5.0)
    assert not periods.alarms
    for asked, record in hold:
        assert record.applied == pytest.approx(asked.output, abs=1e-6)
    switched = _on_seconds(world.circuit.power_changes, hold[0][0].t, hold[-1][1].t)
    counted = sum(r.applied / 100.0 * (r.t - p.t) for p, r in hold)
    assert abs(counted - switched) <= band + 5.0


def _on_seconds(changes: list[tuple[float, bool]], start: float, end: float) -> float:
    """How long the element was powered between `start` and `end`."""
    on, state, since = 0.0, False, start
    for when, powered in changes:
        if when >= end:
            break
        if when > start and state:
            on += when - since
        state, since = powered, max(when, start)
    return on + (end - since if state else 0.0)


def test_an_exception_in_the_loop_leaves_the_heater_off() -> None:
    daemon, world, clock, _ = make()

    class Boom(Exception):
        pass

    def explode() -> None:
        raise Boom

    clock.call_at(1234.5, explode)
    with pytest.raises(Boom), daemon:
        daemon.run(until=5000.0)
    assert world.circuit.ssr_on is False and world.circuit.powered is False


def test_manual_to_auto_is_bumpless() -> None:
    daemon, _world, _clock, periods = make()
    with daemon:
        daemon.run(until=6000.0)  # holding at the setpoint
        daemon.set_manual(35.0)
        daemon.run(until=6300.0)
        assert periods.records[-1].output == 35.0
        daemon.set_auto()
        daemon.run(until=6310.0)
    last_manual = next(r for r in reversed(periods.records) if r.mode == "manual")
    first_auto = next(r for r in periods.records if r.t >= 6300.0 and r.mode == "auto")
    c = daemon.config.control
    assert last_manual.pv is not None and first_auto.pv is not None
    error = first_auto.p / c.kc  # the error it acts on: predictive's is on the predicted PV
    # One P-step: what the error's change and one period of integral can move the output.
    p_step = c.kc * abs(first_auto.pv - last_manual.pv) + c.kc * c.period / c.ti * abs(error)
    assert abs(first_auto.output - 35.0) <= p_step + 1e-9
    assert abs(first_auto.output - 35.0) < 3.0


def test_a_sensor_fault_holds_the_controller_and_resumes_from_its_output() -> None:
    daemon, world, clock, periods = make()
    clock.call_at(7000.0, lambda: world.chip.set_fault("nack"))
    clock.call_at(7030.0, lambda: world.chip.set_fault("ok"))
    with daemon:
        daemon.run(until=7200.0)
    before = [r for r in periods.records if r.t <= 7000.0][-1]  # the last output before the hold
    held = [r for r in periods.records if 7002.0 <= r.t < 7030.0]
    assert held and all(r.output == 0.0 and not r.heater_allowed for r in held)
    resumed = next(r for r in periods.records if r.t > 7030.0 and r.heater_allowed)
    c = daemon.config.control
    assert resumed.pv is not None and before.pv is not None
    # Within one P-step of it: what the water's change over the hold and one period of
    # integral can move the output.
    error = resumed.p / c.kc  # the error it acts on: predictive's is on the predicted PV
    p_step = c.kc * abs(resumed.pv - before.pv) + c.kc * c.period / c.ti * abs(error)
    assert abs(resumed.output - before.output) <= p_step + 1e-9
    assert {a.kind for a in periods.alarms if a.raised} == {"sensor_fault", "stale_reading"}


def test_status_line_names_the_tun_the_temperatures_and_the_output() -> None:
    daemon, _world, _clock, _periods = make()
    with daemon:
        daemon.run(until=100.0)
    text = daemon.status_text()
    assert text.startswith("HLT ") and "°C → 66.00 °C" in text and text.endswith(", ok")


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "hermsd.cli", *args]


def test_sigterm_turns_the_heater_off_and_exits_0(tmp_path: Path) -> None:
    proc = subprocess.Popen(
        _cli("run", "--simulate", "--speed", "60"),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=tmp_path,
    )
    assert proc.stderr is not None
    line = proc.stderr.readline()  # blocks until the loop has started (or the process died)
    assert "started" in line, line
    time.sleep(0.3)  # a few simulated periods, so the heater is really on
    proc.send_signal(signal.SIGTERM)
    _out, err = proc.communicate(timeout=10)
    assert proc.returncode == 0, err
    assert "SIGTERM received" in err and "heater off" in err


def test_safe_off_exits_1_and_says_what_it_could_not_reach(tmp_path: Path) -> None:
    cfg = tmp_path / "hermsd.yaml"
    cfg.write_text("output:\n  backend: serial-rts\n  port: /dev/does-not-exist\n")
    proc = subprocess.run(
        _cli("safe-off", "--config", str(cfg)), capture_output=True, text=True, timeout=30
    )
    assert proc.returncode == 1
    assert "serial-rts" in proc.stderr and "does-not-exist" in proc.stderr


def _safe_off_on_a_pty(tmp_path: Path, before_output: str = "") -> subprocess.CompletedProcess[str]:
    """`hermsd safe-off` with the SSR on the DTR line of a pseudo-terminal."""
    controller, terminal = os.openpty()
    try:
        cfg = tmp_path / "hermsd.yaml"
        cfg.write_text(
            f"{before_output}output:\n  backend: serial-dtr\n  port: {os.ttyname(terminal)}\n"
        )
        return subprocess.run(
            _cli("safe-off", "--config", str(cfg)), capture_output=True, text=True, timeout=30
        )
    finally:
        os.close(controller)
        os.close(terminal)


def test_safe_off_on_a_pseudo_terminal_drops_the_line(tmp_path: Path) -> None:
    proc = _safe_off_on_a_pty(tmp_path)
    # A pty has no modem lines: either it was switched off or the reason is said in one line.
    if proc.returncode == 0:
        assert proc.stdout.startswith("output: serial-dtr on /dev/") and proc.stderr == ""
    else:
        assert proc.returncode == 1
        failure, summary = proc.stderr.splitlines()
        assert failure.startswith("hermsd safe-off: output: serial-dtr on /dev/")
        assert summary == "hermsd safe-off: not every output is known to be off"


def test_a_chip_that_comes_back_gets_its_critical_limit_again() -> None:
    daemon, world, clock, _ = make()
    clock.call_at(1000.0, lambda: world.chip.set_fault("gone"))
    clock.call_at(1060.0, lambda: world.chip.set_fault("ok"))  # powers up with T_CRIT 80 °C
    with daemon:
        daemon.run(until=1200.0)
        assert world.sensor.limit("crit") == daemon.config.safety.max_temp


def test_a_chip_reset_between_two_reads_gets_its_limits_again() -> None:
    daemon, world, clock, _ = make()
    clock.call_at(1000.0, world.chip.power_dip)  # T_CRIT 80 °C, T_HYST 2 °C, no failed read
    with daemon:
        daemon.run(until=1000.0 + 2 * daemon.config.control.period)
        assert world.sensor.limit("crit") == daemon.config.safety.max_temp
        assert world.sensor.limit("hyst") == daemon.config.safety.hysteresis


def test_sighup_reloads_the_edited_file_in_the_running_process(tmp_path: Path) -> None:
    cfg = tmp_path / "hermsd.yaml"
    cfg.write_text("output:\n  backend: sim\nlog:\n  dir: null\n")
    proc = subprocess.Popen(
        _cli("run", "--simulate", "--speed", "20", "--config", str(cfg)),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stderr is not None
    assert "started" in proc.stderr.readline()
    cfg.write_text("output:\n  backend: sim\nlog:\n  dir: null\ncontrol:\n  setpoint: 70\n")
    proc.send_signal(signal.SIGHUP)
    reloaded = proc.stderr.readline()  # the next period reads it (or polling would, anyway)
    proc.send_signal(signal.SIGTERM)
    _out, err = proc.communicate(timeout=10)
    assert "config reloaded: control.setpoint changed" in reloaded, reloaded + err
    assert proc.returncode == 0, err


def test_safe_off_finds_the_outputs_in_a_file_broken_elsewhere(tmp_path: Path) -> None:
    proc = _safe_off_on_a_pty(tmp_path, before_output="control:\n  kc: -5\n  setpont: 70\n")
    assert proc.returncode in (0, 1)  # 1: a pty has no modem lines to drop
    assert "serial-dtr" in proc.stdout + proc.stderr  # it went for the line, not the errors
    assert "kc" not in proc.stderr and "setpont" not in proc.stderr


def test_safe_off_names_a_problem_in_the_output_section(tmp_path: Path) -> None:
    cfg = tmp_path / "hermsd.yaml"
    cfg.write_text("control:\n  kc: -5\noutput:\n  backend: serial-rst\n")
    proc = subprocess.run(
        _cli("safe-off", "--config", str(cfg)), capture_output=True, text=True, timeout=30
    )
    assert proc.returncode == 1
    assert f"{cfg}:4:12: output.backend" in proc.stderr and "kc" not in proc.stderr


def test_a_watchdog_shorter_than_three_periods_is_refused(tmp_path: Path) -> None:
    env = dict(os.environ, WATCHDOG_USEC="10000000")  # WatchdogSec=10s
    env.pop("WATCHDOG_PID", None)  # no pid: the watchdog is this process's
    proc = subprocess.run(
        _cli("run", "--simulate", "--speed", "max", "--duration", "10s"),
        capture_output=True,
        text=True,
        timeout=30,
        env=env,
        cwd=tmp_path,
    )
    assert proc.returncode == 2
    assert proc.stderr.strip() == (
        "hermsd: WatchdogSec=10s is shorter than three control periods (3 × 5 s): "
        "set WatchdogSec=15s or more in the unit, or shorten control.period"
    )


class _Line:
    """An output that records what was done to it; `on_close` runs inside its close()."""

    def __init__(self, on_close: Callable[[], None] | None = None) -> None:
        self.on_close = on_close
        self.state = False
        self.closed = False

    def set(self, on: bool) -> None:
        self.state = on

    def close(self) -> None:
        self.closed = True
        if self.on_close is not None:
            self.on_close()


def _raise_shutdown() -> None:
    from hermsd.cli.common import Shutdown

    raise Shutdown("SIGTERM")  # a handler that was already due when shutdown began


@pytest.mark.parametrize(
    "stop",
    [lambda: os.kill(os.getpid(), signal.SIGTERM), _raise_shutdown],
    ids=["signal-during-close", "handler-already-due"],
)
def test_a_second_stop_signal_during_shutdown_still_switches_every_output_off(
    stop: Callable[[], None],
) -> None:
    from hermsd.cli.common import Shutdown, _on_signal

    config = dataclasses.replace(
        config_module.DEFAULT,
        output=dataclasses.replace(config_module.DEFAULT.output, backend="sim"),
    )
    clock = VirtualClock()
    world = build_world(config, clock)
    ssr = _Line(on_close=stop)  # systemd's stop, while the SSR is being switched off
    contactor = _Line()
    daemon = assemble(config, clock, world.sensor, guard_outputs(ssr, contactor, clock, config))
    previous = signal.signal(signal.SIGTERM, _on_signal)  # as `hermsd run` installs it
    try:
        with pytest.raises(Shutdown):
            daemon.shutdown("SIGINT")
    finally:
        signal.signal(signal.SIGTERM, previous)

    assert (ssr.closed, contactor.closed) == (True, True)
    assert (ssr.state, contactor.state) == (False, False)


def test_the_long_running_simulator_keeps_no_history_of_its_edges() -> None:
    daemon, world, _clock, _periods = make(history=False)  # as `hermsd run --simulate` builds it
    with daemon:
        daemon.run(until=6 * 3600.0)

    assert world.outputs.ssr.edges > 1000  # it did time-proportion
    assert (world.circuit.ssr_edges, world.circuit.power_changes) == ([], [])


class _RealTime:
    """The real clock under a paced simulation: sleeps pass at once, and every tenth wakes
    30 ms late, as a busy machine wakes a process."""

    def __init__(self) -> None:
        self.now = 1000.0
        self.sleeps = 0

    def monotonic(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.sleeps += 1
        self.now += seconds + (0.030 if self.sleeps % 10 == 0 else 0.0)


def test_a_machine_that_wakes_late_is_no_fault_of_a_fast_simulation(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from hermsd.sim import clock as sim_clock
    from hermsd.sim.world import simulated_daemon

    real = _RealTime()
    monkeypatch.setattr(sim_clock, "time", real)
    daemon = simulated_daemon(config_module.DEFAULT, 500.0)
    periods = Periods()
    daemon.listeners.append(periods)
    with daemon:
        daemon.run(until=3600.0)

    assert [alarm.kind for alarm in periods.alarms] == []
    assert daemon.overruns == 0 and len(periods.records) == 720
    assert real.now - 1000.0 >= 3600.0 / 500.0  # paced: never faster than asked


class _GoesNaN:
    """A controller that answers NaN while `broken` (a model or settings it cannot work with),
    else as the real one."""

    def __init__(self, inner: pid.Controller, output: float) -> None:
        self.inner = inner
        self.bad_output = output
        self.broken = False

    @property
    def params(self) -> pid.Params:
        return self.inner.params

    @property
    def output(self) -> float:
        return self.inner.output

    @property
    def terms(self) -> tuple[float, float, float]:
        return self.inner.terms

    def step(self, sp: float, pv: float, applied: float | None = None) -> float:
        good = self.inner.step(sp, pv, applied)
        return self.bad_output if self.broken else good

    def reset(self, pv: float, output: float) -> None:
        self.inner.reset(pv, output)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_a_controller_output_that_is_no_duty_latches_an_alarm_and_the_loop_runs_on(
    tmp_path: Path, bad: float
) -> None:
    daemon, world, clock, periods = make()
    daemon.latches = LatchStore(tmp_path)
    controller = _GoesNaN(daemon.controller, bad)
    daemon.controller = controller
    clock.call_at(1002.5, lambda: setattr(controller, "broken", True))
    clock.call_at(1502.5, lambda: setattr(controller, "broken", False))  # the cause is gone
    with daemon:
        daemon.run(until=2000.0)  # no exception: the loop runs on
        assert world.circuit.powered is False
        status = daemon.status_text()
        assert daemon.saver.flush(5.0)  # saved beside the loop
        stored = LatchStore(tmp_path).load()  # what a restart raises again
        daemon.reset_alarms()  # the brewer, having read why
        daemon.run(until=2100.0)

    raised = [a for a in periods.alarms if a.raised]
    assert [(a.kind, a.at, a.latched) for a in raised] == [("controller_fault", 1005.0, True)]
    assert f"controller output {bad} %" in raised[0].message
    assert "controller_fault" in status
    heating = [on for t, on in world.circuit.power_changes if t < 1005.0]
    assert heating[-1] is True  # it was heating up when the controller failed …
    assert [on for t, on in world.circuit.power_changes if 1005.0 <= t < 2000.0] == [False]
    held = [r for r in periods.records if 1005.0 <= r.t < 2000.0]
    assert held[-1].t == 1995.0  # … and went on period by period, logging
    assert all((r.state, r.output, r.heater_allowed) == ("alarm", 0.0, False) for r in held)
    assert [(a.kind, a.values) for a in stored.alarms] == [
        ("controller_fault", {"output": str(bad)})
    ]
    resumed = [r for r in periods.records if r.t >= 2000.0]
    assert all(r.state == "ok" and 0.0 < r.output <= 100.0 for r in resumed)
    assert any(on for t, on in world.circuit.power_changes if t >= 2000.0)  # heating again
