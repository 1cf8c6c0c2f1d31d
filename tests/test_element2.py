"""The second element: its modulator, its switch in the loop, its config, its faults."""

from __future__ import annotations

import dataclasses
import itertools
import math
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_daemon import make

from hermsd.config import schema as config_module
from hermsd.config.read import parse
from hermsd.config.schema import Config, ConfigError
from hermsd.control import factory
from hermsd.control.element2 import MidRangeController, OnOffModulator
from hermsd.control.learning import LearnedModel
from hermsd.log.reader import load
from hermsd.log.recorder import Recorder
from hermsd.log.replay import delivered, verify
from hermsd.program.model import Program, Step
from hermsd.runtime.assemble import assemble
from hermsd.runtime.build import model_in_force
from hermsd.runtime.daemon import Daemon
from hermsd.runtime.period import PeriodRecord
from hermsd.sim.clock import VirtualClock
from hermsd.sim.hlt import FoptdPlant, PhysicalPlant
from hermsd.sim.scenario import (
    Event,
    Scenario,
    ScenarioError,
    effective_config,
    run,
    time_to_band,
)
from hermsd.sim.world import World, build_world

H = 5.0  # s, the control period


def phases(states: list[bool]) -> list[tuple[bool, float]]:
    """(state, seconds) of each run of equal states, one state a period."""
    runs: list[tuple[bool, float]] = []
    for on in states:
        if runs and runs[-1][0] == on:
            runs[-1] = (on, runs[-1][1] + H)
        else:
            runs.append((on, H))
    return runs


def test_a_steady_duty_gives_the_shorter_phase_its_minimum_and_the_mean_exactly() -> None:
    # 25 % with 120 s minimums: on 120 s (the minimum), then off until the 90 s of debt
    # it ran ahead (120 · 0.75) are paid back at 0.25 s/s: 360 s. 120/(120 + 360) = 25 %.
    modulator = OnOffModulator(120.0, 120.0)
    states = [modulator.decide(k * H, 25.0) for k in range(2000)]
    cycles = phases(states)[2:-1]  # whole cycles, past the start
    assert set(cycles) == {(True, 120.0), (False, 360.0)}


@settings(max_examples=40, deadline=None)
@given(
    st.lists(st.floats(0.0, 100.0), min_size=1, max_size=30),
    st.sampled_from([(10.0, 10.0), (120.0, 120.0), (30.0, 200.0), (200.0, 30.0)]),
)
def test_minimum_times_hold_the_debt_stays_bounded_and_each_duty_is_delivered(
    duties: list[float], minimums: tuple[float, float]
) -> None:
    min_on, min_off = minimums
    limit = max(min_on, min_off)
    modulator = OnOffModulator(min_on, min_off)
    steps = 200  # periods per duty: 1000 s
    states = []
    for k in range(len(duties) * steps):
        states.append(modulator.decide(k * H, duties[k // steps]))
        assert abs(modulator.owed) <= limit
    for index, duty in enumerate(duties):
        # Within a duty's span the delivered energy differs from the asked by at most the
        # debt carried in and out (the minimum times make that debt, nothing else).
        delivered = sum(H for on in states[index * steps : (index + 1) * steps] if on)
        assert abs(delivered - duty / 100.0 * steps * H) <= 2 * limit + H
    runs = phases(states)
    for on, seconds in runs[1:-1]:  # inner phases: both ends are switches
        assert seconds >= (min_on if on else min_off)
    hours = len(states) * H / 3600.0
    edges = len(runs) - 1
    assert edges <= 7200.0 / (min_on + min_off) * hours + 2


def test_full_and_no_duty_switch_nothing_and_a_forced_off_is_at_once() -> None:
    modulator = OnOffModulator(120.0, 60.0)
    assert not any(modulator.decide(k * H, 0.0) for k in range(100))
    assert all(modulator.decide(500.0 + k * H, 100.0) for k in range(100))
    modulator.force_off(1000.0)  # 500 s on: within no minimum, but an alarm wins anyway
    assert not modulator.on
    on_again = next(k for k in range(100) if modulator.decide(1000.0 + k * H, 100.0))
    assert on_again * H == 60.0  # the minimum off time counts from the forced off


# -- configuration ------------------------------------------------------------------------------

TWO = "control:\n  algorithm: midrange\nelement2:\n  backend: relay-board\n  port: /dev/ttyUSB3\n"


def problems(text: str) -> list[str]:
    with pytest.raises(ConfigError) as caught:
        parse(text, "hlt.yaml")
    return [str(problem) for problem in caught.value.problems]


def test_a_second_element_goes_with_any_controller_and_midrange_needs_one() -> None:
    for algorithm in ("predictive", "type_a", "midrange"):
        text = f"control:\n  algorithm: {algorithm}\nelement2:\n  backend: gpio\n  line: 5\n"
        assert parse(text, "hlt.yaml").element2.line == 5
    assert problems("control:\n  algorithm: midrange\n")[0].startswith(
        "hlt.yaml:2:14: control.algorithm: control.algorithm midrange with element2.backend none"
    )


def test_config_reads_the_second_element() -> None:
    config = parse(TWO + "  watts: 3500\n  min_on: 60\n  min_off: 90\n", "hlt.yaml")
    assert (config.element2.watts, config.element2.min_on, config.element2.min_off) == (
        3500.0,
        60.0,
        90.0,
    )


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("control:\n  algorithm: midrange\n", "hlt.yaml:2:14: control.algorithm: control"),
        (TWO + "  min_on: 3\n", "hlt.yaml:6:11: element2.min_on: 3 s is out of range"),
        (
            TWO.replace("midrange\n", "midrange\n  period: 10\n") + "  min_off: 8\n",
            "hlt.yaml:7:12: element2.min_off: 8 s is shorter than control.period (10 s)",
        ),
        (
            TWO + "contactor:\n  backend: relay-board\n  port: /dev/ttyUSB3\n  channel: 2\n",
            "element2 and contactor would both drive /dev/ttyUSB3",
        ),
        (
            "control:\n  algorithm: midrange\nelement2:\n  backend: serial-rts\n"
            "  port: /dev/ttyUSB0\n",
            "hlt.yaml:4:12: element2.backend: element2 and output would both drive /dev/ttyUSB0",
        ),
        (
            "control:\n  algorithm: midrange\nelement2:\n  backend: gpio\n",
            "hlt.yaml:4:12: element2.backend: the gpio backend needs element2.line",
        ),
        (TWO + "  watts: 50\n", "hlt.yaml:6:10: element2.watts: 50 W is out of range"),
    ],
)
def test_config_errors_name_file_line_and_column(text: str, expected: str) -> None:
    found = problems(text)
    assert any(expected in problem for problem in found), found


def test_a_relay_board_may_share_its_port_on_another_channel() -> None:
    text = TWO + "contactor:\n  backend: relay-board\n  port: /dev/ttyUSB3\n  channel: 1\n"
    assert parse(text).contactor.port == parse(text).element2.port


# -- the loop ---------------------------------------------------------------------------------


def two_element_config(**control: object) -> Config:
    d = config_module.DEFAULT
    return dataclasses.replace(
        d,
        tun=dataclasses.replace(d.tun, element_watts=2000.0),
        output=dataclasses.replace(d.output, backend="sim"),
        element2=dataclasses.replace(d.element2, backend="sim", watts=3500.0),
        control=dataclasses.replace(d.control, **{"algorithm": "midrange", **control}),  # type: ignore[arg-type]
    )


@pytest.mark.parametrize("learn", ["on", "pinned", "off"])
def test_with_a_second_element_the_model_is_the_prior_not_what_one_element_showed(
    learn: str,
) -> None:
    # Learned (3 kW into 90 L: 0.5 °C/min at full power) and measured (`hermsd tune --write`)
    # models are each the answer of the SSR's element alone: with the second fitted, neither.
    learned = LearnedModel(0.5 / 60.0, 1.0 / 12000.0, 90.0, 18.0, 90.0)
    one = dataclasses.replace(
        config_module.DEFAULT,
        control=dataclasses.replace(config_module.DEFAULT.control, learn=learn, model_litres=90.0),
    )
    two = two_element_config(learn=learn, model_litres=90.0)
    assert model_in_force(learned, one).source != "prior"  # either would be used with one
    choice = model_in_force(learned, two)
    assert (choice.source, choice.measured) == ("prior", None)
    assert choice.model == factory.prior_model(two)


PLANT = {"model": "physical", "litres": 90.0, "element_watts": 2000.0, "element2_watts": 3500.0}


def test_any_alarm_cuts_both_elements_at_once_and_shutdown_leaves_both_off() -> None:
    daemon, world, _clock, listener = make(two_element_config(), PLANT)
    circuit = world.circuit
    with daemon:
        daemon.run(until=600.0)  # heating from cold: both on
        assert circuit.powered and circuit.powered2
        world.chip.set_fault("gone")
        daemon.run(until=700.0)
        alarm = listener.alarms[0]
        assert alarm.kind == "sensor_fault"
        off = circuit.off_at_or_after(alarm.at)
        assert off == alarm.at  # both elements without power from the alarm's instant
        assert not circuit.relay2_on
        world.chip.set_fault("ok")
        daemon.run(until=900.0)
        assert circuit.relay2_on  # heating resumed, the second element with it
    assert not (circuit.ssr_on or circuit.relay2_on or circuit.powered2)


class _U2GoesNaN(MidRangeController):
    """The mid-ranging controller, its second element's duty NaN once `broken`."""

    broken = False

    @property
    def u2(self) -> float:
        return math.nan if self.broken else super().u2


def test_a_second_element_duty_that_is_no_duty_latches_an_alarm_with_both_elements_off() -> None:
    daemon, world, _clock, listener = make(two_element_config(), PLANT)
    assert isinstance(daemon.controller, MidRangeController)
    controller = _U2GoesNaN(daemon.controller._inner, daemon.controller.params)
    daemon.controller = controller
    circuit = world.circuit
    with daemon:
        daemon.run(until=600.0)  # heating from cold: both on
        assert circuit.powered and circuit.powered2
        controller.broken = True
        daemon.run(until=700.0)  # no exception: the loop runs on
    [alarm] = listener.alarms
    assert (alarm.kind, alarm.at, alarm.latched) == ("controller_fault", 600.0, True)
    assert alarm.message.startswith("controller output for element2 nan % is not a duty")
    assert circuit.off_at_or_after(alarm.at) == alarm.at  # both without power at once
    assert not (circuit.ssr_on or circuit.relay2_on)
    held = [r for r in listener.records if r.t >= 600.0]
    assert all((r.state, r.output, r.u2) == ("alarm", 0.0, 0.0) for r in held)


def test_a_program_waiting_for_its_ready_by_time_keeps_both_elements_off() -> None:
    """A scheduled start holds the heater off: the second element too, and its duty counts as
    off (the supervisor judges a rise against it: a shorted SSR must still show)."""
    daemon, world, clock, periods = make(two_element_config(), PLANT)
    circuit = world.circuit
    with daemon:
        daemon.run(until=600.0)  # heating from cold: both on
        assert circuit.relay2_on
        late = Program("Late", (Step("Strike", 72.0, 0.0),))
        daemon.start_program(late, "23:00", clock.monotonic())
        daemon.run(until=1800.0)
        assert daemon.program.status(clock.wall_ns())["state"] == "scheduled"
        assert not (circuit.ssr_on or circuit.relay2_on or circuit.powered2)
    waiting = [r for r in periods.records if r.t > 700.0]
    assert waiting and all(r.state == "scheduled" and r.switched2 == 0.0 for r in waiting)


def logged_daemon(
    config: Config, directory: Path, seed: int
) -> tuple[Daemon, World, VirtualClock, Recorder]:
    """A daemon on the simulated two-element tun (noise sd 0.03 °C) logging to `directory`."""
    config = dataclasses.replace(config, log=config_module.DEFAULT.log)
    clock = VirtualClock()
    world = build_world(config, clock, {**PLANT, "noise_c": 0.03, "seed": seed}, history=True)
    recorder = Recorder(directory, now=clock.monotonic, lossless=True)
    daemon = assemble(config, clock, world.sensor, world.outputs, recorder=recorder)
    return daemon, world, clock, recorder


def test_the_loop_hands_applied2_to_the_slow_controller_and_replay_reproduces_it(
    tmp_path: Path,
) -> None:
    daemon, world, clock, recorder = logged_daemon(two_element_config(), tmp_path, 3)
    with daemon:
        daemon.run(until=3 * 3600.0)
    recorder.close()
    log = load(sorted(tmp_path.iterdir()))
    periods = log.periods
    assert {p.algorithm for p in periods} == {"midrange"}
    cycled = [p for p in periods if p.switched2 not in (0.0, 100.0, None)]
    assert not cycled  # the second element switches only at period boundaries
    edges = world.circuit.relay2_edges
    assert len(edges) >= 3
    assert min(b - a for a, b in itertools.pairwise(edges)) >= 120.0  # min on and off
    # The energy replay reports is both elements' up to the last period: the water's books
    # at the end, less what was still on its way (60 s of transport, 5.5 kW at most) and
    # plus what was switched after the last period.
    _, kwh = delivered(log)
    end = clock.monotonic()
    assert isinstance(world.plant, PhysicalPlant)
    reached = world.plant.energy_in(end) / 3.6e6
    after = (end - periods[-1].t) * 5500.0 / 3.6e6
    assert kwh is not None and -after <= kwh - reached <= 60.0 * 5500.0 / 3.6e6
    entries = log.entries
    result = verify(entries)
    assert result.mismatch is None and result.verified > 2000
    # The slow controller's integral depends on applied2: a changed one is caught.
    index = next(i for i, e in enumerate(entries) if isinstance(e, PeriodRecord) and e.k == 900)
    record = entries[index]
    assert isinstance(record, PeriodRecord)
    entries[index] = dataclasses.replace(record, applied2=(record.applied2 or 0.0) + 1.0)
    mismatch = verify(entries).mismatch
    # In the very step that is handed it: C2's integral moves by h/Tt2 per % (Tt2 = ti2).
    assert mismatch is not None and (mismatch.k, mismatch.name) == (900, "d")
    assert mismatch.recomputed - mismatch.logged == pytest.approx(H / 600.0, rel=1e-9)


def test_a_dead_second_element_is_caught_and_a_shorted_relay_too() -> None:
    # A lid-off tun that needs more at 66 °C than the SSR's element gives (2.5 kW of loss):
    # with the second element dead the water falls with both outputs at 100 %.
    lossy = {**PLANT, "ua_w_per_k": 2500.0 / 46.0, "noise_c": 0.03}
    base = Scenario(
        name="two",
        duration=5 * 3600.0,
        plant=lossy,
        config={
            "tun": {"element_watts": 2000},
            "control": {"algorithm": "midrange"},
            "element2": {"backend": "sim", "watts": 3500},
        },
        events=(Event(3 * 3600.0, "heater2", "open"),),
    )
    dead = run(base).summary["alarms"]
    assert [a["kind"] for a in dead] == ["heater_not_heating"]
    assert dead[0]["detected_after_s"] < 1800.0 and dead[0]["heater_off_after_s"] == 0.0
    fitted = {**base.config, "contactor": {"backend": "gpio", "line": 27}}
    shorted = dataclasses.replace(
        base, plant=PLANT, config=fitted, events=(Event(3 * 3600.0, "relay2", "stuck_on"),)
    )
    alarms = run(shorted).summary["alarms"]
    assert alarms and alarms[0]["kind"] in ("ssr_stuck_on", "dry_fire")
    assert alarms[0]["heater_off_after_s"] == 0.0  # the series contactor feeds both


def test_a_scenario_runs_the_second_element_on_the_simulated_tun_whatever_the_file_says() -> None:
    base = parse(TWO + "  watts: 3500\n")  # a relay board on /dev/ttyUSB3
    scenario = Scenario(duration=1200.0, plant=PLANT, events=())
    assert effective_config(base, scenario).element2.backend == "sim"  # as logged
    assert run(scenario, base).summary["algorithm"] == "midrange"


def test_second_element_events_need_a_second_element() -> None:
    scenario = Scenario(duration=600.0, events=(Event(60.0, "relay2", "stuck_on"),))
    with pytest.raises(ScenarioError, match="need a second element"):
        run(scenario)


# A first-order tun, K = 1 °C/% for the first element's 3 kW (UA = 30 W/K), τ = 10000 s,
# θ = 100 s, in a 20 °C room, from 20 °C, with a second element of 3 kW. Full power's water
# (no sensor lag): T(t) = 20 + ΔT·(1 − e^(−(t − θ)/τ)) after θ, ΔT = P/UA: 100 K on the first
# element, 200 K on both. The band's lower edge for 66 °C is 65.5 °C, 45.5 K up.
FOPTD_TWO = {
    "gain_c_per_pct": 1.0,
    "tau_s": 10000.0,
    "dead_time_s": 100.0,
    "ambient_c": 20.0,
    "element_watts": 3000.0,
    "element2_watts": 3000.0,
}
BOTH_TO_BAND_S = 100.0 + 10000.0 * math.log(200.0 / (200.0 - 45.5))  # 2681.2 s
ONE_TO_BAND_S = 100.0 + 10000.0 * math.log(100.0 / (100.0 - 45.5))  # 6169.7 s


def test_the_fastest_to_the_band_is_with_every_element_the_config_fits() -> None:
    both = time_to_band(FoptdPlant(**FOPTD_TWO), 0.0, 66.0, 8 * 3600.0, element2=True)
    assert both == pytest.approx(BOTH_TO_BAND_S, abs=0.01)
    one = time_to_band(FoptdPlant(**FOPTD_TWO), 0.0, 66.0, 8 * 3600.0, element2=False)
    assert one == pytest.approx(ONE_TO_BAND_S, abs=0.01)
    with pytest.raises(ValueError, match="no second element"):
        time_to_band(_NoSecond(), 0.0, 66.0, 3600.0, element2=True)


class _NoSecond:
    """A plant without a second element's switch."""

    def set_heater(self, on: bool, t: float) -> None: ...


def test_a_two_element_runs_settle_ratio_is_against_both_elements_full_power() -> None:
    plant = {"model": "foptd", **FOPTD_TWO}
    day = Scenario(duration=3600.0, plant=plant, setpoint=66.0, events=())
    summary = run(day, parse(TWO)).summary
    assert summary["physical_min_s"] == round(BOTH_TO_BAND_S, 1)
