"""The mash side of a HERMS in the loop: the mash's and the coil outlet's sensors read beside
the HLT's and recorded each period, a faulty one a warning that leaves the heater alone, and
the pump switched by `hermsd set pump` through the control socket, off at the stop.

The plant here is a small HERMS of this file's own (`LaggingMash`): the HLT is the simulator's
first-order tun, the mash follows the HLT's water with a first-order lag while the pump runs
and stands still while it stops, the wort leaves the coil a fixed share of the way from the
mash to the HLT. Its temperatures are computed here, independently of the loop.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import sys
import types
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from jsonschema import Draft202012Validator
from test_control import serve
from test_log_schemas import invalid

from hermsd.cli import main
from hermsd.cli.run import _open_output
from hermsd.config.read import parse
from hermsd.hardware.outputs import guard_outputs
from hermsd.hardware.pump_sense import PumpSense
from hermsd.hardware.sensors.base import Sensor
from hermsd.hardware.sensors.kinds import open_role_sensor
from hermsd.hardware.ssr import Switch
from hermsd.log.recorder import Recorder
from hermsd.log.topics import PERIOD_TOPIC, TOPICS
from hermsd.runtime.assemble import assemble
from hermsd.runtime.daemon import Daemon
from hermsd.runtime.mash_side import PumpNotFitted
from hermsd.runtime.period import PeriodRecord
from hermsd.sim.clock import VirtualClock
from hermsd.sim.hlt import FoptdPlant
from hermsd.sim.mash import HermsPlant
from hermsd.sim.world import World, build_world

PERIOD = 5.0
MASH_TAU_S = 600.0  # the mash's lag behind the HLT's water while the pump runs
COIL_SHARE = 0.8  # how far from the mash to the HLT the wort is warmed in the coil
LM92_STEP = 0.0625
TIMEOUT = 10.0

HLT_AT_ROOM = "setpoint: 70\n  mode: manual\n  manual_output: 0\n"  # the HLT stays at 20 °C
FITTED = (
    "output:\n  backend: sim\nlog:\n  dir: null\ncontrol:\n  setpoint: 70\n"
    "mash_sensor:\n  kind: lm92\n  address: 0x49\n"
    "coil_sensor:\n  kind: ds18b20\n  id: 28-000000000002\n"
    "pump:\n  backend: sim\n"
)


class LaggingMash:
    """A HERMS plant: the simulator's FOPTD tun as the HLT, and a mash that follows its water
    as dM/dt = (T_hlt − M)/MASH_TAU_S while the pump runs (exact over each step, the HLT
    taken as it is at the step's end: the loop asks every second, the HLT moves mK in one)."""

    def __init__(self, hlt_c: float = 20.0, mash_c: float = 20.0) -> None:
        self.hlt = FoptdPlant(start_c=hlt_c)
        self.mash_c = mash_c
        self.pump = False
        self.flowing = True
        self.since = 0.0
        self.pump_changes: list[tuple[float, bool]] = []

    def _advance(self, t: float) -> None:
        if t > self.since and self.pump and self.flowing:
            hlt = self.hlt.water_temperature(t)
            self.mash_c = hlt + (self.mash_c - hlt) * math.exp(-(t - self.since) / MASH_TAU_S)
        self.since = max(self.since, t)

    # -- the HLT (the `Plant` protocol) --------------------------------------------------------
    def set_heater(self, on: bool, t: float) -> None:
        self.hlt.set_heater(on, t)

    def set_element_ok(self, ok: bool, t: float) -> None:
        self.hlt.set_element_ok(ok, t)

    def set_ambient(self, temp_c: float, t: float) -> None:
        self.hlt.set_ambient(temp_c, t)

    def add_water(self, litres: float, temp_c: float, t: float) -> None:
        self.hlt.add_water(litres, temp_c, t)

    def temperature(self, t: float) -> float:
        return self.hlt.temperature(t)

    def water_temperature(self, t: float) -> float:
        return self.hlt.water_temperature(t)

    # -- the mash side --------------------------------------------------------------------------
    def set_pump(self, on: bool, t: float) -> None:
        self._advance(t)
        self.pump = on
        self.pump_changes.append((t, on))

    def set_recirculation_ok(self, ok: bool, t: float) -> None:
        self._advance(t)
        self.flowing = ok

    def dough_in(
        self, grain_kg: float, grain_c: float, water_litres: float, water_c: float, t: float
    ) -> None:
        raise NotImplementedError("not needed here")

    def mash_temperature(self, t: float) -> float:
        self._advance(t)
        return self.mash_c

    def coil_outlet_temperature(self, t: float) -> float:
        mash = self.mash_temperature(t)
        if not (self.pump and self.flowing):
            return mash
        return mash + COIL_SHARE * (self.hlt.water_temperature(t) - mash)

    def coil_watts(self, t: float) -> float:
        return 0.0


class Periods:
    """The loop's period records and the events it logs."""

    def __init__(self) -> None:
        self.records: list[PeriodRecord] = []
        self.events: list[str] = []

    def period(self, record: PeriodRecord) -> None:
        self.records.append(record)

    def alarm(self, alarm: object) -> None:
        """Not looked at here."""

    def write(self, topic: str, log_time_ns: int, message: dict[str, Any]) -> None:
        if topic == "/hermsd/log":
            self.events.append(message["message"])


def herms_daemon(
    text: str = FITTED,
    plant: LaggingMash | None = None,
    *,
    pump: Switch | None = None,
    coil_sensor: Sensor | None = None,
    pump_sense: PumpSense | None = None,
) -> tuple[Daemon, World]:
    """The daemon on `plant` in a simulated world, with the simulated pump, coil outlet
    sensor and pump sense (as the config fits them), or the given ones in their place."""
    config = parse(text)
    clock = VirtualClock()
    world = build_world(config, clock, tun=plant or LaggingMash())
    assert world.mash is not None
    if pump is not None:
        circuit = world.circuit
        world.outputs = guard_outputs(
            circuit.ssr, circuit.contactor, clock, config, circuit.relay2, pump
        )
    daemon = assemble(
        config,
        clock,
        world.sensor,
        world.outputs,
        mash_sensor=world.mash.mash_sensor,
        coil_sensor=coil_sensor or world.mash.coil_sensor,
        pump_sense=pump_sense or world.mash.pump_sense,
    )
    return daemon, world


def watched(daemon: Daemon) -> Periods:
    periods = Periods()
    daemon.listeners.append(periods)
    daemon.recorder = periods
    return periods


def run_for(daemon: Daemon, seconds: float) -> None:
    daemon.run(until=daemon.clock.monotonic() + seconds)


def lm92(celsius: float) -> float:
    """What the LM92 reads: its 0.0625 °C steps, truncated toward zero."""
    return math.trunc(celsius / LM92_STEP) * LM92_STEP


def test_the_plant_is_a_herms_plant() -> None:
    assert isinstance(LaggingMash(), HermsPlant)
    assert not isinstance(FoptdPlant(), HermsPlant)


def test_each_period_records_the_mash_the_coil_outlet_and_the_pump() -> None:
    plant = LaggingMash(hlt_c=20.0, mash_c=45.0)
    daemon, _world = herms_daemon(FITTED.replace("setpoint: 70\n", HLT_AT_ROOM), plant=plant)
    periods = watched(daemon)
    run_for(daemon, 10 * PERIOD)
    first = periods.records[-1]
    # The pump is off from the start: the mash stands, and the wort in the coil is the mash's.
    assert first.pump is False and plant.pump_changes[:1] == [(0.0, False)]
    assert first.mash == lm92(45.0) == 45.0
    assert first.coil == pytest.approx(45.0, abs=LM92_STEP)  # a DS18B20's 1/16 °C steps
    daemon.set_pump(True, "by the test")
    on_at = daemon.clock.monotonic()
    run_for(daemon, 120 * PERIOD)
    record = periods.records[-1]
    assert record.pump is True
    # The mash falls toward the HLT, held at the room's 20 °C, read at the last read before
    # the period's end (the LM92's steps, and a conversion of up to a second before it).
    read_at = record.t - 0.5  # reads fall half an interval before each period's boundary
    expected = 20.0 + (45.0 - 20.0) * math.exp(-(read_at - on_at) / MASH_TAU_S)
    assert record.mash is not None and abs(record.mash - expected) < LM92_STEP + 25.0 / 600.0
    assert record.mash < 30.0
    assert record.coil is not None and record.coil < record.mash
    assert "pump on: by the test" in periods.events


def test_the_status_line_and_reply_show_the_mash_and_the_pump() -> None:
    daemon, _world = herms_daemon(plant=LaggingMash(mash_c=64.8))
    run_for(daemon, 3 * PERIOD)
    roles = daemon.role_status()
    mash = roles["mash"]
    assert mash is not None and mash["celsius"] == lm92(64.8) and mash["fault"] is None
    # The pump stopped: the outer loop readies the HLT, never past the limit (70 + 10 °C).
    assert mash["phase"] == "ready" and isinstance(mash["hlt_setpoint"], float)
    assert 70.0 < mash["hlt_setpoint"] <= 80.0
    text = daemon.status_text()
    assert f"→ {mash['hlt_setpoint']:.2f} °C, " in text
    assert ", mash 64.8 → 70.0 °C (ready), pump off, " in text
    assert roles["coil"] is not None and roles["coil"]["fault"] is None
    daemon.set_pump(True, "by the test")
    run_for(daemon, PERIOD)
    # Started a dead time on (the HLT law's: control.dead_time, 115 s), the heat sent ahead.
    assert re.search(r", pump starting in 1[01]\d s, ", daemon.status_text())
    run_for(daemon, 120.0)
    assert ", pump on, " in daemon.status_text()


def test_without_the_mash_side_the_status_line_is_as_it_was() -> None:
    daemon, _world = herms_daemon("output:\n  backend: sim\nlog:\n  dir: null\n")
    periods = watched(daemon)
    run_for(daemon, 2 * PERIOD)
    assert "mash" not in daemon.status_text() and "pump" not in daemon.status_text()
    record = periods.records[-1]
    assert (record.mash, record.coil, record.pump) == (None, None, None)
    with pytest.raises(PumpNotFitted, match="no pump is fitted"):
        daemon.set_pump(True, "by the test")


def test_a_faulty_mash_sensor_is_a_warning_and_leaves_the_heater_alone() -> None:
    steady, _ = herms_daemon()
    faulty, world = herms_daemon()
    assert world.mash is not None and world.mash.mash_chip is not None
    chip = world.mash.mash_chip
    said = watched(faulty)
    held = watched(steady)
    faulty.clock.call_at(600.0, lambda: chip.set_fault("nack"))  # type: ignore[attr-defined]
    faulty.clock.call_at(900.0, lambda: chip.set_fault("ok"))  # type: ignore[attr-defined]
    run_for(steady, 800.0)
    run_for(faulty, 800.0)
    mash = faulty.role_status()["mash"]
    assert mash is not None and mash["celsius"] is None and "NACK" in str(mash["fault"]).upper()
    assert "mash sensor fault" in faulty.status_text()
    faults = [e for e in said.events if e.startswith("mash sensor fault: ")]
    assert len(faults) == 1 and faults[0].endswith("(the HLT is held as before)")
    mid = said.records[-1]
    assert mid.mash is None and mid.state == "ok" and mid.heater_allowed
    run_for(steady, 400.0)
    run_for(faulty, 400.0)
    assert any(e.startswith("mash sensor reads again: ") for e in said.events)
    assert said.records[-1].mash is not None
    # The heater saw nothing of it: every period's output and duty as without the fault.
    drive = [(r.k, r.output, r.applied, r.state, r.alarms) for r in held.records]
    assert [(r.k, r.output, r.applied, r.state, r.alarms) for r in said.records] == drive


def test_a_mash_sensor_that_cannot_be_opened_is_a_fault_from_the_start() -> None:
    text = FITTED.replace("id: 28-000000000002", "w1_root: /nonexistent")
    missing = open_role_sensor(parse(text).coil_sensor, lambda: 0.0, "coil_sensor")
    daemon, _world = herms_daemon(text, coil_sensor=missing)
    periods = watched(daemon)
    run_for(daemon, 2 * PERIOD)
    [fault] = [e for e in periods.events if e.startswith("coil outlet sensor fault: ")]
    assert "coil_sensor.id is null and 0 DS18B20 are under /nonexistent" in fault
    assert periods.records[-1].coil is None and periods.records[-1].mash is not None


@pytest.mark.parametrize(
    ("running_for", "said"),
    [
        (120.0, "pump off: stopped"),  # past the prepared start's dead time: the pump ran
        (PERIOD, "pump start cancelled: stopped"),  # still being prepared: it never runs
    ],
)
def test_the_pump_stops_with_the_daemon_and_says_so(running_for: float, said: str) -> None:
    plant = LaggingMash()
    daemon, _world = herms_daemon(plant=plant)
    periods = watched(daemon)
    run_for(daemon, PERIOD)
    daemon.set_pump(True, "by the test")
    run_for(daemon, running_for)
    assert daemon.shutdown("stopped")
    assert plant.pump is False and plant.pump_changes[-1][1] is False
    assert periods.events[-2:] == [said, "heater off: stopped"]
    assert any(on for _, on in plant.pump_changes) == (said == "pump off: stopped")


def test_a_herms_config_around_a_plant_without_a_mash_is_refused() -> None:
    with pytest.raises(ValueError, match="mash_sensor and pump configured, but the simulated"):
        build_world(
            parse(FITTED.replace("coil_sensor:\n  kind: ds18b20", "coil_sensor:\n  kind: none")),
            VirtualClock(),
        )


# -- the period record in the log ---------------------------------------------------------------


def test_the_logged_periods_are_valid_against_their_closed_schema(tmp_path: Path) -> None:
    daemon, _world = herms_daemon()
    recorder = Recorder(tmp_path, now=daemon.clock.monotonic, lossless=True)
    daemon.recorder = recorder
    try:
        run_for(daemon, 4 * PERIOD)
        daemon.set_pump(True, "by the test")
        run_for(daemon, 4 * PERIOD)
        daemon.shutdown()
    finally:
        recorder.close()
    counts, problems = invalid(tmp_path)
    assert counts[PERIOD_TOPIC] >= 8 and problems == []
    schema = TOPICS[PERIOD_TOPIC].schema
    record = {"mash": 64.8, "coil": 70.1, "pump": True}
    wrong = {"mash": "64.8", "coil": None, "pump": "on"}
    validator = Draft202012Validator({**schema, "required": []})
    assert not list(validator.iter_errors(record))
    assert len(list(validator.iter_errors(wrong))) == 2


# -- the pump's GPIO line, through a fake of the gpiod bindings ---------------------------------


class FakeGpiod(types.ModuleType):
    """The `gpiod` 2.x bindings as GpioSwitch and GpioPumpSense use them: one request of one
    line, its settings and every value it was set to kept; an input line reads `level` (a
    Value, as the kernel gives it after active_low), or raises `fails` when set."""

    def __init__(self) -> None:
        super().__init__("gpiod")
        self.requests: list[Any] = []
        line = types.ModuleType("gpiod.line")
        for name, members in {
            "Bias": ("PULL_UP", "PULL_DOWN"),
            "Direction": ("OUTPUT", "INPUT"),
            "Value": ("ACTIVE", "INACTIVE"),
        }.items():
            setattr(line, name, types.SimpleNamespace(**{m: f"{name}.{m}" for m in members}))
        self.line = line
        self.LineSettings = types.SimpleNamespace
        outer = self

        class Request:
            def __init__(self, chip: str, consumer: str, config: dict[int, Any]) -> None:
                self.chip, self.consumer, self.config = chip, consumer, config
                self.values: list[tuple[int, str]] = []
                self.released = False
                self.level = "Value.INACTIVE"
                self.fails: OSError | None = None
                self.reads = 0

            def set_value(self, offset: int, value: str) -> None:
                assert not self.released
                self.values.append((offset, value))

            def get_value(self, offset: int) -> str:
                assert not self.released and offset in self.config
                self.reads += 1
                if self.fails is not None:
                    raise self.fails
                return self.level

            def release(self) -> None:
                self.released = True

        def request_lines(chip: str, consumer: str, config: dict[int, Any]) -> Request:
            request = Request(chip, consumer, config)
            outer.requests.append(request)
            return request

        self.request_lines = request_lines


def fake_gpiod(monkeypatch: pytest.MonkeyPatch) -> FakeGpiod:
    """FakeGpiod in the place of the `gpiod` bindings for the test."""
    fake = FakeGpiod()
    monkeypatch.setitem(sys.modules, "gpiod", fake)
    monkeypatch.setitem(sys.modules, "gpiod.line", fake.line)
    return fake


@pytest.fixture
def gpiod(monkeypatch: pytest.MonkeyPatch) -> FakeGpiod:
    return fake_gpiod(monkeypatch)


def test_the_pump_on_a_gpio_line_starts_off_runs_when_told_and_is_released_off(
    gpiod: FakeGpiod,
) -> None:
    gpio = "pump:\n  backend: gpio\n  line: 22\n  active_low: true\n"
    text = FITTED.replace("pump:\n  backend: sim\n", gpio)
    switch = _open_output(parse(text).pump)
    [request] = gpiod.requests
    settings = request.config[22]
    assert request.chip == "/dev/gpiochip0" and request.consumer == "hermsd"
    assert (settings.direction, settings.output_value) == ("Direction.OUTPUT", "Value.INACTIVE")
    assert settings.active_low is True and settings.bias == "Bias.PULL_UP"
    daemon, world = herms_daemon(text, pump=switch)
    outputs = world.outputs
    run_for(daemon, PERIOD)
    assert request.values and set(request.values) == {(22, "Value.INACTIVE")}
    daemon.set_pump(True, "by the test")
    run_for(daemon, 220.0)  # a pump is no heater: the dead-man never stops it
    assert outputs.pump is not None and outputs.pump.check() is False
    assert request.values[-1] == (22, "Value.ACTIVE")
    daemon.shutdown()
    assert request.values[-1] == (22, "Value.INACTIVE") and request.released


# -- `hermsd set pump` over a real control socket ------------------------------------------------


@contextlib.contextmanager
def served(tmp_path: Path, text: str = FITTED) -> Iterator[tuple[Daemon, Path, Periods]]:
    """The daemon on the virtual clock behind a real control socket, a period at a time."""
    daemon, _world = herms_daemon(text)
    periods = watched(daemon)
    where = tmp_path / "control.sock"
    with serve(daemon, where):
        yield daemon, where, periods


def test_set_pump_through_the_socket_runs_the_pump_and_logs_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # A long dead time: the start still pending however slowly the commands come.
    slow = FITTED.replace("setpoint: 70\n", "setpoint: 70\n  dead_time: 600\n")
    with served(tmp_path, slow) as (_daemon, where, periods):
        sock = ["--socket", os.fspath(where)]
        assert main(["set", "pump", "on", *sock]) == 0
        said = capsys.readouterr().out
        assert main(["status", *sock]) == 0
        status = capsys.readouterr().out
        assert main(["status", "--json", *sock]) == 0
        reply = json.loads(capsys.readouterr().out)
        assert main(["set", "pump", "off", *sock]) == 0
        off = capsys.readouterr().out
    # The start is prepared: the pump runs the HLT law's dead time (600 s) after the command.
    assert said == "now: setpoint 70 °C, auto, pump starting in 600 s\n"
    # The mash far below its 70 °C: the HLT readied to the limit, 70 + 10 less 0.15 °C, but
    # with a start prepared, to the climb's setpoint: the limit less the heat in flight for
    # the coil that a stop lands, 200 W/K·(79.85 − 20) K·600 s / (90 L·4186 J/(L·K)) =
    # 19.06354 °C, and the SSR's ripple on it (r·W/4, r = 3000/(90·4186) °C/s: 0.00995 °C)
    # and one of the LM92's 0.0625 °C steps, beyond the margin: 79.85 − 18.98599 = 60.86401 °C.
    assert "HLT 20.00 °C → 60.86 °C, " in status
    assert re.search(r", mash 20.0 → 70.0 °C \(ready\), pump starting in \d+ s, ", status)
    # Still pending, at most the dead time off (600 s where no period ran between the two
    # commands: the daemon steps on its own thread).
    assert reply["pump"] is False and 0.0 < reply["mash"]["pump_start_in"] <= 600.0
    assert reply["mash"]["hlt_setpoint"] == pytest.approx(60.86401, abs=1e-5)
    assert reply["mash"]["phase"] == "ready"
    assert reply["mash"]["warning"] is None
    assert reply["coil"]["fault"] is None and reply["warnings"] == []
    assert off.endswith("pump off\n")
    assert "operator: set pump on (from the control socket)" in periods.events
    assert (
        "pump starting in 600 s: by the operator (from the control socket) (the coil's load "
        "sent ahead to the element)" in periods.events
    )
    # The operator's off cancels the start before the pump ever ran.
    assert "pump start cancelled: by the operator (from the control socket)" in periods.events
    assert not any(e.startswith("pump on") for e in periods.events)
    assert all(r.pump is False for r in periods.records)


def test_status_shows_the_coil_outlet_on_a_line_of_its_own(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """With the pump off the wort stands: the coil outlet reads the mash's 20 °C (the
    DS18B20's 1/16 °C steps hold 20 exactly)."""
    with served(tmp_path) as (_daemon, where, _periods):
        assert main(["status", "--socket", os.fspath(where)]) == 0
    line, coil, *_ = capsys.readouterr().out.splitlines()
    assert ", mash 20.0 → 70.0 °C (ready), pump off, " in line
    assert coil == "coil outlet 20.0 °C"


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["set", "pump", "fast"], "hermsd: pump: expected on or off, got 'fast'\n"),
        (["set", "pump", "on", "--output", "4"], "hermsd: --output goes with `set mode manual`\n"),
    ],
)
def test_a_bad_pump_command_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], says: str
) -> None:
    with served(tmp_path) as (_daemon, where, _periods):
        assert main([*argv, "--socket", os.fspath(where)]) == 2
    assert capsys.readouterr().err == says


def test_set_pump_without_a_pump_is_refused_and_changes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    text = FITTED.replace("pump:\n  backend: sim\n", "")
    with served(tmp_path, text) as (_daemon, where, periods):
        sock = ["--socket", os.fspath(where)]
        assert main(["set", "pump", "on", *sock]) == 2
        err = capsys.readouterr().err
        assert main(["status", "--json", *sock]) == 0
        reply = json.loads(capsys.readouterr().out)
    assert err == (
        "hermsd: refused, nothing changed: pump: no pump is fitted (set pump.backend in the "
        "config file and restart hermsd)\n"
    )
    assert reply["pump"] is None
    assert not any("pump" in event for event in periods.events)
