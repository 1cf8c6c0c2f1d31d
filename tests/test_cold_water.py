"""Cold water answered within the control period: at the sensor's read rate, never on noise."""

from __future__ import annotations

import dataclasses
import math
import random
from pathlib import Path

import pytest

from hermsd.config import schema as config_module
from hermsd.control import laws, pid, predictive
from hermsd.hardware.ssr import TimeProportionalPlanner, WindowPlan
from hermsd.log import reader, replay
from hermsd.log.mcap_file import LogFile
from hermsd.log.topics import WINDOW_TOPIC
from hermsd.runtime.assemble import assemble
from hermsd.runtime.daemon import Daemon
from hermsd.runtime.period import PeriodRecord
from hermsd.sim import scenario
from hermsd.sim.clock import VirtualClock
from hermsd.sim.scenario import Event
from hermsd.sim.tuns import FAMILY, TunSpec
from hermsd.sim.world import World, build_world

SMALL = next(spec for spec in FAMILY if spec.name == "small 30 L 5.5 kW")
WATER_AT = 3000.0  # s: held since about 1500 s; on a period boundary, as the bench's water is
SP = 66.0


# -- the planner: the rest of the window at full power ---------------------------------------


def test_full_power_starts_on_the_next_half_cycle_and_counts_what_was_on() -> None:
    planner = TimeProportionalPlanner(5.0, 50, 0.02, 0.02)
    # A pulse at the window's end (0.5 s from 104.5 s): on from 101.51 s, the next half-cycle
    # after 101.503 s, to the end: 3.49 s of 5, 69.8 %.
    at_end = WindowPlan(100.0, 5.0, 104.5, 105.0, 10.0, 10.0)
    plan = planner.full_from(at_end, 101.503)
    assert (plan.on_at, plan.off_at) == (pytest.approx(101.51), 105.0)
    assert plan.applied == pytest.approx(69.8)
    assert plan.requested == 100.0
    # A pulse at the start that ended at 101 s: on again from 102 s; 1 + 3 s of 5 is 80 %.
    at_start = WindowPlan(100.0, 5.0, 100.0, 101.0, 20.0, 20.0)
    plan = planner.full_from(at_start, 102.0)
    assert (plan.on_at, plan.off_at, plan.applied) == (102.0, 105.0, pytest.approx(80.0))
    # On already: it stays on to the end, without an edge.
    plan = planner.full_from(WindowPlan(100.0, 5.0, 100.0, 102.0, 40.0, 40.0), 101.0)
    assert (plan.on_at, plan.off_at, plan.applied) == (100.0, 105.0, 100.0)


def test_full_power_keeps_the_minimum_off_and_on_times() -> None:
    planner = TimeProportionalPlanner(5.0, 50, 0.5, 0.1)
    # Off since 101.5 s: not on again before 101.6 s.
    plan = planner.full_from(WindowPlan(100.0, 5.0, 100.0, 101.5, 30.0, 30.0), 101.505)
    assert plan.on_at == pytest.approx(101.6)
    assert plan.applied == pytest.approx(100.0 * (1.5 + 3.4) / 5.0)
    # 0.3 s left, less than min_on: the window stays as planned.
    short = WindowPlan(100.0, 5.0, 105.0, 105.0, 0.0, 0.0)
    assert planner.full_from(short, 104.7) is short


def test_full_power_forgets_what_was_carried() -> None:
    # 0.1 % of 500 half-cycles is half of one: rounded to none and carried, so the next
    # window at 0.1 % gets one. A window at full power in between pays any debt and more.
    carried, forgot = TimeProportionalPlanner(5.0), TimeProportionalPlanner(5.0)
    first = carried.plan(0.0, 0.1)
    forgot.plan(0.0, 0.1)
    assert first.on_time == 0.0
    forgot.full_from(first, 2.0)
    assert carried.plan(5.0, 0.1).on_time == pytest.approx(0.01)
    assert forgot.plan(5.0, 0.1).on_time == 0.0


# -- the controller's answer: two readings, and full power by its own law --------------------

# The small tun's first two readings after its water, by hand: 3 L of 15 °C water into 30 L
# at 66 °C mix to (30·66 + 3·15)/33 = 61.3636 °C, a step of 4.6364 °C that the sensor follows
# with its 10 s lag; the readings come 0.5 s and 1.5 s after the water, truncated to the
# LM92's 0.0625 °C: 66 − 4.6364·(1 − e^(−0.05)) = 65.7739 → 65.75 (0.25 below: within the
# quarter degree) and 66 − 4.6364·(1 − e^(−0.15)) = 65.3538 → 65.3125.
LAGGED_DROP = [65.75, 65.3125]


def holding_controller(
    algorithm: str = "predictive", out_max: float = 100.0, model: pid.PlantModel = pid.SEED_HLT
) -> pid.Controller:
    """A controller that has held 66 °C for an hour on `model`'s tun (by default seed 001's:
    1.689 °C/%, τ 14961 s, dead time 115 s, a 20 °C room), started at the holding duty
    46/1.689 = 27.2 %."""
    controller = laws.create(algorithm, kc=120.0, ti=800.0, ts=5.0, out_max=out_max, model=model)
    holding = (SP - model.ambient) / model.gain
    controller.reset(SP, holding)
    in_flight = [holding] * round(model.dead_time / 5.0)
    pv = SP
    for _ in range(720):
        u = in_flight.pop(0)
        pv += 5.0 * (model.rate * u / 100.0 - (pv - model.ambient) / model.tau)
        in_flight.append(controller.step(SP, pv, in_flight[-1]))
    assert 20.0 < controller.output < 35.0  # holding
    return controller


# Full power for a whole period on seed 001's tun adds 5 s · 100·1.689/14961 °C/s · (100 − u) %
# = 0.0564 °C · (1 − u/100): less than 0.045 °C from a holding duty above 20 %.


@pytest.mark.parametrize(
    "readings",
    [
        [66.0, 65.0],  # one reading below: a glitch as far as anyone knows
        [66.0, 60.0],  # however deep
        [65.9375, 65.0],  # after a reading one LSB low: noise does that every few readings
        [65.0, 66.0],
        [66.0, 65.0, 66.0, 65.0, 66.0],  # glitches that do not agree with each other
        [65.875, 65.875],  # the latest only 2 LSB below, not 3
        [65.9375, 65.8125],  # the one before only 1 LSB below
    ],
)
def test_no_full_power_without_two_readings_that_show_the_fall(readings: list[float]) -> None:
    assert not predictive.full_power_now(holding_controller(), SP, SP, readings)


@pytest.mark.parametrize(
    "readings",
    [
        [65.875, 65.8125],  # 2 and 3 LSB below: the least the rule acts on
        [65.8125, 65.8125],
        [65.0, 65.75],
        [65.6875, 65.6875],  # 0.3125 °C below: the law's answer is a few %, not full
    ],
)
def test_a_fall_full_power_cannot_undo_in_a_period_is_answered_whatever_the_law_says(
    readings: list[float],
) -> None:
    # Both readings at least 0.125 °C below, more than the 0.045 °C a period of full power
    # adds: the rule acts without waiting for the law to ask for it.
    assert predictive.full_power_now(holding_controller(), SP, SP, readings)


def test_a_fall_above_a_lowered_setpoint_is_left_to_the_law() -> None:
    """The brewer lowered the setpoint to 60 °C and cools with cold water: readings 2 and 3 LSB
    below 66 °C are a fall, and still 5.8 °C above the setpoint; the law asks for 0 %, and
    so does the rule (the deficit branch acts below the setpoint only)."""
    controller = holding_controller()
    for _ in range(30):
        controller.step(60.0, SP, controller.output)
    assert controller.output == 0.0
    assert not predictive.full_power_now(controller, 60.0, SP, [65.875, 65.8125])
    # below the setpoint, the same fall is acted on (as at 66 °C above)
    assert predictive.full_power_now(controller, 66.5, SP, [65.875, 65.8125])


def test_a_step_from_a_steady_minute_to_a_fallen_pv_is_a_recovery() -> None:
    """The step's own PV counts in judging it steady, not the minute before it alone."""
    controller = holding_controller()
    assert isinstance(controller, predictive._Predictive)
    controller.step(SP, SP, controller.output)
    controller.step(SP, SP - 0.4, 100.0)  # full power from this period on, the PV fallen
    assert (controller._watch.active, controller._recovery.active) == (False, True)


def test_a_thermowell_drop_is_answered_at_its_third_reading() -> None:
    # 4 L of 15 °C water into 40 L at 66 °C mix to (40·66 + 4·15)/44 = 61.3636 °C, a step of
    # 4.6364 °C behind a 60 s sensor lag; readings 0.5, 1.5, 2.5, 3.5 s after it, truncated to
    # 0.0625 °C: 66 − 4.6364·(1 − e^(−t/60)) = 65.9615, 65.8855, 65.8108, 65.7373 →
    # 65.9375, 65.875, 65.75, 65.6875. The third is the first at least 3 LSB below with one
    # at least 2 LSB below before it.
    readings = [65.9375, 65.875, 65.75, 65.6875]
    decided = [
        predictive.full_power_now(holding_controller(), SP, SP, readings[:n]) for n in (1, 2, 3)
    ]
    assert decided == [False, False, True]


def test_where_a_period_of_full_power_could_undo_more_than_the_fall_the_law_decides() -> None:
    # A tun ten times as fast (τ 1689 s: 0.1 °C/s at full power), holding at 27.2 %: a period
    # of full power adds 5 · 0.1 · (1 − u/100) = 0.33 to 0.4 °C from a duty of 20 to 35 %.
    fast = pid.PlantModel(gain=1.689, tau=1689.0, dead_time=115.0)
    # 0.25 °C is less: the law decides, and 0.25 °C below is its gentle zone.
    assert not predictive.full_power_now(holding_controller(model=fast), SP, SP, [65.75, 65.75])
    # 0.4375 °C is more: full power, though the law, 0.44 °C into its kc zone, asks for
    # 27 % + 4.3·0.25 + 120·0.19 = 51 %.
    fallen = [65.5625, 65.5625]
    assert predictive.full_power_now(holding_controller(model=fast), SP, SP, fallen)


def test_a_drop_the_lag_keeps_within_a_quarter_degree_at_first_is_answered_at_its_second() -> None:
    # The first reading is 2 LSB + 0.0625 down, the second 0.6875 °C: full power now, not
    # a reading (a second of full power) later, when both lie beyond 0.25 °C.
    assert predictive.full_power_now(holding_controller(), SP, SP, LAGGED_DROP)
    # The latest reading alone, after a steady one, is a glitch as far as anyone knows.
    assert not predictive.full_power_now(holding_controller(), SP, SP, [66.0, LAGGED_DROP[1]])


def test_full_power_the_readings_asked_for_is_a_recovery_not_a_heat_up_from_steady() -> None:
    # An hour at 66 °C, then a period whose readings showed cold water and got full power
    # within it: its PV is 0.6 °C down, though the minute before it was steady. The step is
    # measured as a recovery (the rate the added water left), not as a heat-up from a steady
    # 66 °C, whose fit would wait for a rise to 67 °C that never comes.
    controller = holding_controller()
    assert isinstance(controller, predictive._Predictive)
    controller.step(SP, SP - 0.6, 100.0)
    assert (controller._recovery.active, controller._watch.active) == (True, False)
    # A step to full power with this period's PV still within the steady band is a heat-up's.
    controller = holding_controller()
    assert isinstance(controller, predictive._Predictive)
    controller.step(SP, SP - 0.0625, 100.0)
    assert (controller._recovery.active, controller._watch.active) == (False, True)


def test_two_readings_a_degree_down_ask_for_full_power_and_change_nothing() -> None:
    controller, twin = holding_controller(), holding_controller()
    assert predictive.full_power_now(controller, SP, SP, [66.0, 65.0, 64.875])
    # The question was asked of a copy: the next step is bit for bit the untouched twin's.
    assert controller.step(SP, 65.0, controller.output) == twin.step(SP, 65.0, twin.output)
    assert controller.terms == twin.terms


def test_cold_water_carries_full_power_across_the_period_end_while_the_pv_falls() -> None:
    # A period of full power adds at most 5 s · 100·1.689/14961 °C/s = 0.0564 °C on seed
    # 001's tun. Behind a slow sensor the period's PV, a mean, fell 0.1875 °C: more than
    # that, yet the law answers it with a few % (its gentle zone).
    told, twin = holding_controller(), holding_controller()
    assert twin.step(SP, SP - 0.1875, 60.0) < 50.0
    predictive.cold_water_seen(told)
    assert told.step(SP, SP - 0.1875, 60.0) == 100.0
    # On without a new word while each period's PV falls by more than 0.0564 °C …
    assert told.step(SP, SP - 0.25, 100.0) == 100.0
    # … and the law's own output once it falls by less (0.05 °C), full power in flight.
    assert told.step(SP, SP - 0.3, 100.0) < 100.0
    # Ended, it takes new readings that show cold water to carry again, however far it falls.
    assert told.step(SP, SP - 0.4, 60.0) < 100.0
    # A fall of less than a period of full power adds is the law's from the start.
    gentle = holding_controller()
    predictive.cold_water_seen(gentle)
    assert gentle.step(SP, SP - 0.05, 30.0) < 50.0


def test_no_carry_above_the_setpoint_nor_after_a_reset() -> None:
    # Cold water into a tun the brewer cools to 60 °C: the law's 0 %.
    cooling = holding_controller()
    for _ in range(30):
        cooling.step(60.0, SP, cooling.output)
    predictive.cold_water_seen(cooling)
    assert cooling.step(60.0, SP - 0.25, 0.0) == 0.0
    # A reset (a hold, a return to auto) forgets a carry in progress.
    carried = holding_controller()
    predictive.cold_water_seen(carried)
    assert carried.step(SP, SP - 0.1875, 60.0) == 100.0
    carried.reset(SP - 0.375, 30.0)
    assert carried.step(SP, SP - 0.5, 30.0) < 100.0


SLOW_SENSOR = TunSpec("slow sensor 30 L 1.5 kW", 30, 1500, 1.0, 30, 120, 20)


def test_a_slow_sensor_keeps_full_power_from_the_period_that_saw_the_water() -> None:
    """A tenth of the volume of 15 °C water behind a 120 s sensor lag: each period's PV falls
    0.15 to 0.2 °C, three times what a period of full power adds (5 · 1500/(30·4186) =
    0.06 °C), yet the law's answer was 27 %, 40 %, 42 % at the three period ends after the
    readings showed the water: each time full power waited for that period's readings."""
    water = 7200.0
    day = dataclasses.replace(
        SLOW_SENSOR.brew_day(),
        duration=water + 120.0,
        events=(Event(water, "add_water", {"litres": 3.0, "temp": 15.0}),),
    )
    records = scenario.run(day, SLOW_SENSOR.config(config_module.DEFAULT), keep_records=True)
    after = [r for r in records.records if r.t > water]
    acted = next(i for i, r in enumerate(after) if r.full_from is not None)
    assert after[acted].t <= water + 10.0
    assert all(r.output == 100.0 for r in after[acted : acted + 12])
    assert all(r.applied == 100.0 for r in after[acted + 1 : acted + 13])


def test_only_predictive_acts_inside_the_period_and_not_when_already_full() -> None:
    assert not predictive.full_power_now(holding_controller("type_a"), SP, SP, [65.0, 64.875])
    heating = laws.create("predictive", kc=120.0, ti=800.0, ts=5.0)
    assert heating.step(SP, 20.0) == 100.0
    assert not predictive.full_power_now(heating, SP, 20.0, [19.0, 18.875])


def test_a_power_limit_below_full_is_kept_inside_the_period() -> None:
    # control.max_output 80 %: the window must not run at 100 % for any part of it.
    readings = [66.0, 65.0, 64.875]
    assert predictive.full_power_now(holding_controller(), SP, SP, readings)  # at 100 % it would
    assert not predictive.full_power_now(holding_controller(out_max=80.0), SP, SP, readings)


@pytest.mark.parametrize("within_lsb", [0.0, 0.25, 0.5, 0.75])
def test_sensor_noise_never_asks_for_full_power(within_lsb: float) -> None:
    # Three hours of hold readings with the bench's noise (sd 0.03 °C before the LM92's
    # 0.0625 °C truncation), the true temperature `within_lsb` of an LSB above the setpoint,
    # each prefix of each period asked as the daemon asks it.
    rng = random.Random(12)
    controller = holding_controller()
    pv = SP
    truth = SP + within_lsb * 0.0625
    for _ in range(3 * 720):
        readings: list[float] = []
        for _ in range(5):
            readings.append(math.floor((truth + rng.gauss(0.0, 0.03)) / 0.0625) * 0.0625)
            assert not predictive.full_power_now(controller, SP, pv, readings)
        pv = sum(readings) / len(readings)
        controller.step(SP, pv, controller.output)


def _noisy_hold(controller: pid.Controller, sd: float, within_lsb: float, told: bool) -> int:
    """Three hours of hold readings of noise `sd` truncated to the LM92's 0.0625 °C, the
    truth `within_lsb` of an LSB above the setpoint; each period's readings told to the law
    (`readings_seen`) or not. The periods whose readings asked for full power."""
    rng = random.Random(12)
    pv, asked = SP, 0
    truth = SP + within_lsb * 0.0625
    for _ in range(3 * 720):
        readings: list[float] = []
        for _ in range(5):
            readings.append(math.floor((truth + rng.gauss(0.0, sd)) / 0.0625) * 0.0625)
            if predictive.full_power_now(controller, SP, pv, readings):
                asked += 1
                break
        pv = sum(readings) / len(readings)
        if told:
            predictive.readings_seen(controller, readings)
        controller.step(SP, pv, controller.output)
    return asked


@pytest.mark.parametrize("within_lsb", [0.0, 0.25, 0.5, 0.75])
def test_a_noisier_sensors_noise_never_asks_for_full_power_once_its_scatter_is_seen(
    within_lsb: float,
) -> None:
    # Noise of 0.06 °C (the population's noisiest sensors): a reading lies about the last
    # period's mean with sd √((0.06² + 0.0625²/12)·(1 + 1/5)) = 0.0687 °C, and 2 and 3 LSB
    # are 1.8 and 2.7 of it. Untold, the same readings ask for full power in the hold; told,
    # the thresholds grow by 0.0687/0.04 and they never do.
    assert _noisy_hold(holding_controller(), 0.06, within_lsb, told=False) > 0
    controller = holding_controller()
    assert _noisy_hold(controller, 0.06, within_lsb, told=True) == 0
    assert predictive.full_power_now(controller, SP, SP, [65.5, 65.0])  # cold water still is


def test_readings_on_a_ramp_are_no_noise() -> None:
    # A heat-up's readings climb 0.5 °C each: their line explains them, the thresholds stay
    # 2 and 3 LSB. Readings as far apart that no line explains (±0.25 °C) raise them.
    ramp, scattered = holding_controller(), holding_controller()
    for k in range(120):
        predictive.readings_seen(ramp, [60.0 + 0.5 * (5 * k + j) for j in range(5)])
        predictive.readings_seen(scattered, [SP + 0.25 * (-1) ** j for j in range(5)])
    assert predictive.full_power_now(ramp, SP, SP, [65.875, 65.8125])
    assert not predictive.full_power_now(scattered, SP, SP, [65.875, 65.8125])


def test_readings_that_are_no_number_leave_the_scatter_as_it_was() -> None:
    # A NaN would make every threshold comparison false, and the least drop ask for full
    # power however noisy the sensor: such a period is not counted.
    noisy = holding_controller()
    for _ in range(120):
        predictive.readings_seen(noisy, [SP + 0.25 * (-1) ** k for k in range(5)])
    predictive.readings_seen(noisy, [SP, math.nan, SP, SP, SP])
    assert not predictive.full_power_now(noisy, SP, SP, [65.875, 65.8125])
    assert predictive.full_power_now(noisy, SP, SP, [65.0, 64.5])


def _fast_recovery(late_s: float) -> tuple[float, list[float]]:
    """A fast tun (K 14 °C/%, τ 10000 s, dead time 150 s: 0.14 °C/s at full power, 25 L on
    11 kW) held at 66 °C by a law with its model, then 4 °C of cold water at once, the
    element's heat reaching the sensor `late_s` later than the model has it. The highest the
    water rises over 66 °C from the water on, and the outputs from the water on."""
    model = pid.PlantModel(14.0, 10000.0, 150.0, 20.0, measured=True)
    controller = laws.create("predictive", kc=120.0, ti=800.0, ts=5.0, model=model)
    holding = (SP - model.ambient) / model.gain
    controller.reset(SP, holding)
    in_flight = [holding] * round((model.dead_time + late_s) / 5.0)
    pv, outputs, highest = SP, [], -math.inf
    for k in range(720 + 300):
        pv -= 4.0 if k == 720 else 0.0
        u = in_flight.pop(0)
        pv += 5.0 * (model.rate * u / 100.0 - (pv - model.ambient) / model.tau)
        in_flight.append(controller.step(SP, pv, in_flight[-1]))
        if k >= 720:
            outputs.append(in_flight[-1])
            highest = max(highest, pv - SP)
    return highest, outputs


def test_heat_that_arrives_late_on_a_fast_tun_is_no_more_cold_water() -> None:
    # 4 °C of water: 30 s of full power. Heat 10 s later than modelled leaves the PV short
    # of the model's rise of 0.7 °C a period (at full power) by more than a step, the PV
    # still rising: taken for more cold water, that sent a second burst (64 %) and overshot
    # 0.67 °C. The water's answer is the burst's alone, within 0.2 °C of on time.
    on_time, outputs = _fast_recovery(0.0)
    assert outputs[:6] == [100.0] * 6  # the water itself: full power at once
    late, outputs = _fast_recovery(10.0)
    assert outputs[:6] == [100.0] * 6
    assert max(outputs[6:]) < 20.0
    assert late < on_time + 0.2


# -- the daemon: on the simulated small tun with a large element -----------------------------


def small_tun_daemon() -> tuple[Daemon, World, VirtualClock, list[PeriodRecord]]:
    config = SMALL.config(
        dataclasses.replace(
            config_module.DEFAULT,
            output=dataclasses.replace(config_module.DEFAULT.output, backend="sim"),
        )
    )
    clock = VirtualClock()
    world = build_world(config, clock, SMALL.plant(noise_c=0.0), history=True)
    daemon = assemble(config, clock, world.sensor, world.outputs)
    records: list[PeriodRecord] = []

    class Keep:
        def period(self, record: PeriodRecord) -> None:
            records.append(record)

        def alarm(self, alarm: object) -> None:
            pass

    daemon.listeners.append(Keep())
    return daemon, world, clock, records


def powered(world: World, t: float) -> bool:
    state = False
    for when, on in world.circuit.power_changes:
        if when > t:
            break
        state = on
    return state


def test_cold_water_gets_full_power_at_the_second_reading_that_shows_it() -> None:
    daemon, world, clock, records = small_tun_daemon()
    clock.call_at(WATER_AT, lambda: world.plant.add_water(3.0, 15.0, WATER_AT))
    with daemon:
        daemon.run(until=WATER_AT + 5.1)
    before, after = records[-2], records[-1]
    assert before.t == WATER_AT and before.output < 20.0  # holding at a low duty
    assert before.pv == SP
    # Readings at 0.5, 1.5, … s after the water: the first two as computed by hand.
    assert after.readings[:2] == LAGGED_DROP
    assert after.full_from == 2
    # The element is on from that reading (within a half-cycle) to the period's end.
    seen = WATER_AT + after.full_from - 0.5
    edges = [t for t, _ in world.circuit.power_changes if seen <= t < WATER_AT + 5.0]
    assert len(edges) <= 1 and all(t <= seen + 0.01 + 1e-9 for t in edges)
    assert all(powered(world, seen + 0.01 + dt) for dt in (0.0, 1.0, 2.0, 2.4))
    assert after.applied > 100.0 * (WATER_AT + 5.0 - seen - 0.01) / 5.0 - 1e-6


def test_cold_water_into_a_tun_cooling_to_a_lower_setpoint_never_heats_it() -> None:
    daemon, world, clock, records = small_tun_daemon()
    water_at = WATER_AT + 300.0
    clock.call_at(WATER_AT, lambda: daemon.set_setpoint(55.0))
    clock.call_at(water_at, lambda: world.plant.add_water(3.0, 15.0, water_at))
    with daemon:
        daemon.run(until=water_at + 60.0)
    assert all(r.output == 0.0 for r in records if WATER_AT + 10.0 < r.t <= water_at)
    after = [r for r in records if r.t > water_at]
    # 3 L of 15 °C into 30 L at ~65 °C mix to ~60.5 °C: a fall, still far above 55 °C
    assert min(r.pv for r in after) > 58.0
    assert all(r.full_from is None for r in after)
    assert not [t for t, on in world.circuit.power_changes if t > water_at and on]


def test_manual_without_an_output_holds_the_controllers_not_the_full_power_of_cold_water() -> None:
    """Switching to manual while the element runs at full power for cold water keeps the
    output the controller asked for: the in-period 100 % is the loop's, never the brewer's."""
    daemon, world, clock, records = small_tun_daemon()
    clock.call_at(WATER_AT, lambda: world.plant.add_water(3.0, 15.0, WATER_AT))
    with daemon:
        daemon.run(until=WATER_AT + 4.0)  # full power since the second reading of the water
        assert "out 100 %" in daemon.status_text()
        stepped = records[-1].output
        assert stepped < 20.0
        daemon.set_manual()
        daemon.run(until=WATER_AT + 5.1)
    assert daemon.mode == "manual" and daemon.manual_output == stepped


def test_a_window_cut_by_a_forced_off_is_not_planned_again_at_full_power() -> None:
    """After a forced off the contactor stays open to the window's end: the cold water is
    logged as seen, and the element stays off until the next window closes the contactor."""
    daemon, world, clock, records = small_tun_daemon()
    clock.call_at(WATER_AT, lambda: world.plant.add_water(3.0, 15.0, WATER_AT))
    clock.call_at(WATER_AT + 0.2, lambda: daemon._force_off(clock.monotonic()))
    with daemon:
        daemon.run(until=WATER_AT + 4.9)
        assert "out 100 %" not in daemon.status_text()
        daemon.run(until=WATER_AT + 5.1)
    assert records[-1].full_from is not None  # the decision is made, and logged
    assert not any(powered(world, WATER_AT + 0.3 + 0.5 * k) for k in range(9))


def test_a_one_reading_spike_changes_nothing_in_the_window() -> None:
    spiked, spiked_world, spiked_clock, spiked_records = small_tun_daemon()
    calm, calm_world, _, calm_records = small_tun_daemon()
    for at in (WATER_AT + 0.2, WATER_AT + 2.2):  # two glitches, a good reading between them
        spiked_clock.call_at(at, lambda: spiked_world.chip.set_fault("spike", SP - 1.0))
    for daemon in (spiked, calm):
        with daemon:
            daemon.run(until=WATER_AT + 5.1)
    assert spiked_records[-1].readings[0] == SP - 1.0  # accepted: within safety.max_step
    assert spiked_records[-1].readings[2] == SP - 1.0
    assert [r.full_from for r in spiked_records] == [None] * len(spiked_records)
    window = [(t, on) for t, on in spiked_world.circuit.power_changes if t >= WATER_AT]
    assert window == [(t, on) for t, on in calm_world.circuit.power_changes if t >= WATER_AT]
    assert spiked_records[-1].applied == calm_records[-1].applied


def test_a_glitch_after_a_low_reading_costs_at_most_the_rest_of_one_window() -> None:
    """A bad reading after one 3 LSB low (noise does that about once in 30 000 readings) is
    taken for cold water: full power from it to the window's end, every edge gated by the
    supervisor, and from the next period on the law's own output again. At most 3.5 s of the
    5.5 kW element: 19.25 kJ into 30 L at 4186 J/(L·K), 0.153 °C."""
    glitched, glitched_world, glitched_clock, glitched_records = small_tun_daemon()
    calm, calm_world, _, _ = small_tun_daemon()
    low, bad = SP - 0.1875, SP - 2.0
    glitched_clock.call_at(WATER_AT + 0.2, lambda: glitched_world.chip.set_fault("spike", low))
    glitched_clock.call_at(WATER_AT + 1.2, lambda: glitched_world.chip.set_fault("spike", bad))
    for daemon in (glitched, calm):
        with daemon:
            daemon.run(until=WATER_AT + 120.1)
    acted = next(r for r in glitched_records if r.t == WATER_AT + 5.0)
    assert acted.readings[:3] == [low, bad, SP] and acted.full_from == 2
    # On at the bad reading; off once the next window's own pulse (its on-time first) is over.
    (on_at, on), (off_at, off) = [
        change for change in glitched_world.circuit.power_changes if change[0] > WATER_AT + 1.0
    ][:2]
    assert (on_at, on, off) == (pytest.approx(WATER_AT + 1.5), True, False)
    assert WATER_AT + 5.0 <= off_at <= WATER_AT + 5.0 + 5.0 * acted.output / 100.0 + 0.01
    assert acted.output < 20.0  # the law's own output at the next step, not full power
    assert max(r.output for r in glitched_records if r.t > acted.t) < 20.0
    later = WATER_AT + 120.1
    extra = glitched_world.plant.water_temperature(later) - calm_world.plant.water_temperature(
        later
    )
    assert 0.0 < extra <= 3.5 * 5500.0 / (30.0 * 4186.0)


# -- replay: the decision is derived from the log, bit for bit -------------------------------


def _cold_water_day(directory: Path) -> list[Path]:
    day = dataclasses.replace(
        SMALL.brew_day(),
        duration=WATER_AT + 600.0,
        events=(Event(WATER_AT, "add_water", {"litres": 3.0, "temp": 15.0}),),
    )
    config = SMALL.config(config_module.DEFAULT)
    scenario.run(day, config, log_dir=directory)
    return sorted(directory.glob("*.mcap"))


@pytest.fixture(scope="module")
def cold_water_log(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    return _cold_water_day(tmp_path_factory.mktemp("cold-water"))


def test_replay_verifies_a_day_with_full_power_inside_a_period(
    cold_water_log: list[Path],
) -> None:
    log = reader.load(cold_water_log)
    acted = [p for p in log.periods if p.full_from is not None]
    assert len(acted) == 1 and acted[0].t == WATER_AT + 5.0
    result = replay.verify(log.entries)
    assert result.mismatch is None and result.verified > 600


def test_the_window_planned_again_is_logged(cold_water_log: list[Path]) -> None:
    windows = [
        message
        for path in cold_water_log
        for topic, _, message in LogFile(path).messages()
        if topic == WINDOW_TOPIC and message["t"] == WATER_AT
    ]
    assert [w["requested"] for w in windows][1:] == [100.0]
    first, again = windows
    assert again["applied"] > first["applied"]
    # On from the reading that decided it (within a half-cycle) to the window's end.
    acted = next(p for p in reader.load(cold_water_log).periods if p.full_from is not None)
    assert acted.full_from is not None
    left = WATER_AT + 5.0 - (WATER_AT + acted.full_from - 0.5)
    assert left - 0.01 - 1e-9 <= again["on_time"] <= left


@pytest.mark.parametrize("shift", [None, 1, 4])
def test_verify_finds_a_full_power_decision_the_readings_do_not_give(
    cold_water_log: list[Path], shift: int | None
) -> None:
    log = reader.load(cold_water_log)
    acted = next(p for p in log.periods if p.full_from is not None)
    assert acted.full_from is not None
    wrong = None if shift is None else acted.full_from + shift
    calm = next(p for p in log.periods if p.t == WATER_AT - 100.0)
    for target, value in ((acted, wrong), (calm, 2)):
        tampered = [
            dataclasses.replace(e, full_from=value) if e is target else e for e in log.entries
        ]
        mismatch = replay.verify(tampered).mismatch
        assert mismatch is not None
        assert (mismatch.k, mismatch.name, mismatch.logged) == (target.k, "full_from", value)
