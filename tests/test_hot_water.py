"""Hot water poured into the tun is no fault: the dry-fire and SSR watches tell its rise,
a lagged step that stops, from heat that goes on (a dry fire, a shorted SSR).

Rises expected from a pour are worked by the mixing equation, T = (V·T₀ + v·Tᵥ)/(V + v), and
the sensor's first-order lag, not read off the code.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import pytest

from hermsd.config import schema as config_module
from hermsd.safety.limits import SafetyLimits
from hermsd.safety.supervisor import Supervisor
from hermsd.sim import scenario
from hermsd.sim.scenario import Event, Scenario
from hermsd.sim.tuns import FAMILY, TunSpec

WATER_J_PER_K_L = 4186.0
WINDOW = 60.0  # s: the dry-fire window at a 5 s period


def mixed(litres: float, celsius: float, added: float, added_celsius: float) -> float:
    return (litres * celsius + added * added_celsius) / (litres + added)


def old_limit_per_window(spec: TunSpec) -> float:
    """°C in one window the single-window rule allowed: 3× the rated full-power rate."""
    return 3.0 * spec.element_watts / (spec.litres * WATER_J_PER_K_L) * WINDOW


def alarms(sc: Scenario, spec: TunSpec | None = None) -> list[str]:
    base = spec.config(config_module.DEFAULT) if spec else config_module.DEFAULT
    found: list[dict[str, Any]] = scenario.run(sc, base).summary["alarms"]
    return [a["kind"] for a in found]


def seed_day(duration: float, litres: float, pour_at: float, added: float, temp: float) -> Scenario:
    plant = {"model": "physical", "litres": litres, "element_watts": 3000, "noise_c": 0.03}
    event = Event(pour_at, "add_water", {"litres": added, "temp": temp})
    return Scenario(name="pour", duration=duration, plant=plant, setpoint=66.0, events=(event,))


# -- the supervisor alone, on the shapes the physics gives ----------------------------------


def lagged_step(t: float, pour: float, step: float, lag: float) -> float:
    return step * (1.0 - math.exp(-(t - pour) / lag)) if t > pour else 0.0


def period_mean(f: Any, t: float, period: float = 5.0, reads: int = 5) -> float:
    """The PV as the daemon makes it: the mean of the period's reads."""
    return sum(f(t - period + (i + 1) * period / reads) for i in range(reads)) / reads


def seed_limits() -> SafetyLimits:
    return SafetyLimits.derive(litres=90.0, element_watts=3000.0, period=5.0, read_interval=1.0)


@pytest.mark.parametrize("lag", [5.0, 10.0, 40.0, 120.0, 150.0])
@pytest.mark.parametrize("step", [1.5, 5.0, 30.0])
@pytest.mark.parametrize("heating", [0.0, 1.0])
def test_a_lagged_step_of_any_size_on_any_heating_is_no_dry_fire(
    lag: float, step: float, heating: float
) -> None:
    """A pour at every offset within a period, on the element's fastest heating or none."""
    lim = seed_limits()
    for offset in (0.0, 1.3, 2.5, 4.9):
        pour = 600.0 + offset
        sup = Supervisor(lim)

        def pv(t: float, pour: float = pour) -> float:
            return 40.0 + heating * lim.heat_rate * t + lagged_step(t, pour, step, lag)

        for k in range(1, 400):
            t = 5.0 * k
            sup.period(t, period_mean(pv, t), 100.0 * heating, 100.0 * heating)
        assert "dry_fire" not in sup.active, (lag, step, heating, offset)


def test_a_sustained_rise_just_over_the_limit_is_a_dry_fire_three_windows_on() -> None:
    lim = seed_limits()
    sup = Supervisor(lim)
    rate = 1.2 * lim.dry_fire_rate
    raised = None
    for k in range(1, 200):
        t = 5.0 * k
        sup.period(t, 20.0 + rate * t, 100.0, 100.0)
        if "dry_fire" in sup.active:
            raised = t
            break
    # The first PV at 5 s; three 60 s windows of history from it, and the same a period on.
    assert raised == 5.0 + 3 * WINDOW + 5.0


def test_a_limit_set_below_the_elements_fastest_heat_still_alarms_at_its_own_rate() -> None:
    """dry_fire_factor 1.5: a steady rise at 1.6× the rated rate is over it, though under
    the fastest an element heats half the water (2.42×, heat_rate)."""
    lim = SafetyLimits.derive(
        litres=90.0, element_watts=3000.0, period=5.0, read_interval=1.0, dry_fire_factor=1.5
    )
    rated = 3000.0 / (90.0 * WATER_J_PER_K_L)
    rate = 1.6 * rated
    assert lim.dry_fire_rate < rate < lim.heat_rate
    sup = Supervisor(lim)
    for k in range(1, 200):
        sup.period(5.0 * k, 20.0 + rate * 5.0 * k, 100.0, 100.0)
    assert "dry_fire" in sup.active


# -- whole days on the simulator -------------------------------------------------------------


def test_the_reviews_pours_raise_nothing() -> None:
    """5 L of 95 °C into 90 L holding 66 °C: +1.53 °C in a step, more than the 1.43 °C a
    window the single-window rule allowed; 30 L of 55 °C topping up 60 L heating; 10 L of
    70 °C in the heat-up; 10 L of 90 °C in the hold."""
    assert mixed(90, 66, 5, 95) - 66 == pytest.approx(1.526, abs=1e-3)
    days = [
        seed_day(2.5 * 3600 + 1200, 90, 2.5 * 3600, 5, 95),
        seed_day(40 * 60 + 1200, 60, 40 * 60, 30, 55),
        seed_day(30 * 60 + 1200, 90, 30 * 60, 10, 70),
        seed_day(2.5 * 3600 + 1200, 90, 2.5 * 3600, 10, 90),
    ]
    for day in days:
        assert alarms(day) == [], day.events


def test_a_dry_fire_is_still_caught() -> None:
    """8 L in a tun configured for 90 L: 3 kW heats it 11× the rated rate."""
    day = Scenario(
        name="dry",
        duration=1200.0,
        plant={"model": "physical", "litres": 8, "noise_c": 0.03},
        setpoint=66.0,
    )
    assert alarms(day)[:1] == ["dry_fire"]


HEAT_UP_POUR_AT = 300.0  # s after the start, the heat-up under way


def heat_up_start(spec: TunSpec) -> float:
    """A third of the way from the room to 60 °C: where the day starts before the pour."""
    return spec.ambient_c + (60.0 - spec.ambient_c) / 3.0


def least_heat_up_step(spec: TunSpec) -> float:
    """The least step a tenth of the volume of 60 °C water makes: into water warmed at most
    at the element's full rate +10 % mains since the start (losses leave it colder)."""
    rate = 1.21 * spec.element_watts / (spec.litres * WATER_J_PER_K_L)
    warmest = heat_up_start(spec) + rate * HEAT_UP_POUR_AT
    return mixed(spec.litres, warmest, spec.litres / 10.0, 60.0) - warmest


def window_rise(step: float, lag: float) -> float:
    """The most of a lagged step seen within one window (the first after the pour)."""
    return step * (1.0 - math.exp(-WINDOW / lag))


def pour_day(spec: TunSpec, start_c: float, at: float, litres: float, temp: float) -> Scenario:
    return Scenario(
        name=spec.name,
        duration=at + 900.0,
        plant={**spec.plant(), "start_c": start_c},
        setpoint=66.0,
        events=(Event(at, "add_water", {"litres": litres, "temp": temp}),),
    )


def test_pours_on_every_tun_of_the_family_raise_nothing() -> None:
    """A 5 L kettle of 95 °C in the hold (from 66 °C, poured once the loop has settled),
    and a tenth of the volume of 60 °C water in the heat-up, on each of the 12 tuns."""
    hard = 0
    for spec in FAMILY:
        kettle = mixed(spec.litres, 66.0, 5.0, 95.0) - 66.0
        limit = old_limit_per_window(spec)
        hard += window_rise(kettle, spec.sensor_lag_s) > limit
        hard += window_rise(least_heat_up_step(spec), spec.sensor_lag_s) > limit
        hold = pour_day(spec, 66.0, 1800.0, 5.0, 95.0)
        warm = pour_day(spec, heat_up_start(spec), HEAT_UP_POUR_AT, spec.litres / 10.0, 60.0)
        assert alarms(hold, spec) == [], (spec.name, "kettle in the hold")
        assert alarms(warm, spec) == [], (spec.name, "warm water in the heat-up")
    # The pours rise faster than the single-window rule allowed (by the lagged step alone,
    # the element's heat not counted) on 8 of the 24 days: the seed's both, the garage's
    # both, the far sensor's, big lid-off's and open 120 L's heat-up, small 1.5 kW's kettle.
    assert hard == 8


@pytest.mark.parametrize("manual", [None, 5.0, 10.0, 20.0])
def test_a_kettle_into_a_keggle_behind_the_slowest_thermowell_raises_nothing(
    manual: float | None,
) -> None:
    """The 50 L keggle with its sensor in a well of 150 s lag (the slowest the limits allow
    for): 5 L of 95 °C into it at 66 °C is +2.6 °C, a step the sensor shows over minutes;
    held by the law, or by hand at a steady duty (which goes on heating through the pour:
    at 10 %, with the lag taken as 120 s at most, this latched ssr_stuck_on). The day runs
    an hour and a half past it, for the 900 s and hour-long watches."""
    keggle = next(s for s in FAMILY if s.name.startswith("keggle"))
    spec = dataclasses.replace(keggle, name="keggle, 150 s well", sensor_lag_s=150.0)
    assert mixed(spec.litres, 66.0, 5.0, 95.0) - 66.0 == pytest.approx(2.636, abs=1e-3)
    by_hand = {} if manual is None else {"control": {"mode": "manual", "manual_output": manual}}
    day = dataclasses.replace(
        pour_day(spec, 66.0, 3600.0, 5.0, 95.0), duration=3600.0 + 5400.0, config=by_hand
    )
    assert alarms(day, spec) == []


# -- the SSR watch ---------------------------------------------------------------------------


def test_warm_water_into_a_tun_nothing_heats_is_no_shorted_ssr() -> None:
    """216 L at 15 °C in a 120 L thermowell tun (lag 120 s), nothing heating; 10.8 L of
    62 °C poured in: a step of 2.2 °C, 0.5 °C of it within 33 s, with no energy delivered
    (the single-window rule said a shorted SSR)."""
    spec = next(s for s in FAMILY if s.name.startswith("thermowell 120"))
    step = mixed(216.0, 15.0, 10.8, 62.0) - 15.0
    assert step == pytest.approx(2.238, abs=1e-3)
    plant = {**spec.plant(), "litres": 216.0, "ambient_c": 15.0}
    day = Scenario(
        name="idle pour",
        duration=3600.0,
        plant=plant,
        setpoint=66.0,
        events=(
            Event(1.0, "output", 0.0),  # by hand, off
            Event(1800.0, "add_water", {"litres": 10.8, "temp": 62.0}),
        ),
    )
    assert alarms(day, spec) == []


@pytest.mark.parametrize("lag", [10.0, 60.0, 120.0, 150.0])
@pytest.mark.parametrize("step", [1.0, 2.5, 10.0])
def test_a_hot_pour_into_a_hold_behind_any_sensor_lag_is_no_shorted_ssr(
    lag: float, step: float
) -> None:
    """A hold on 10 % (the seed tun's losses at 66 °C), and hot water poured in: 5 L of 95 °C
    into 50 L at 66 °C is +2.6 °C. The water's step shows through the sensor's lag, up to the
    150 s a thermowell may have; the output held as it was (a controller would cut it, which
    only leaves less heat to explain the rise)."""
    lim = seed_limits()
    for offset in (0.0, 2.5):
        pour = 3600.0 + offset
        sup = Supervisor(lim)

        def pv(t: float, pour: float = pour) -> float:
            return 66.0 + lagged_step(t, pour, step, lag)

        for k in range(1, 1200):
            t = 5.0 * k
            sup.period(t, period_mean(pv, t), 10.0, 10.0)
        assert sup.latched == [], (lag, step, offset)


def test_a_heater_nothing_switched_on_is_still_a_shorted_ssr() -> None:
    """The element's full rated rise with 0 % asked: caught once the watch and the heat's
    memory are past, and the watch's thirds show the rise going on."""
    lim = seed_limits()
    sup = Supervisor(lim)
    raised = None
    for k in range(1, 400):
        t = 5.0 * k
        sup.period(t, 20.0 + lim.full_rate * t, 0.0, 0.0)
        if "ssr_stuck_on" in sup.active:
            raised = t
            break
    # Judged once the history from the first period (5 s) spans the watch and the memory,
    # 300 + 450 s, less a period (at 750 s); confirmed a period later.
    assert raised == 750.0 + 5.0


# -- a shorted SSR with no pour: judged by the energy balance, as fast as it allows ----------


def test_a_shorted_ssr_in_a_hold_with_no_pour_is_caught_when_the_energy_balance_says() -> None:
    """The small 30 L, 5.5 kW tun (unmeasured) holding on 8 %; its SSR shorts at t_f and the
    PV climbs at the element's rated rate while the controller asks 0 %.

    By hand: rated r = 5500/(30·4186) = 0.043797 °C/s; the fastest heat the supervisor
    allows per full-power second is half the water at +10 % mains, h = 2·1.21·r = 0.105990.
    x s after t_f the 120 s watch has risen r·x; the most heat any 120 s window (and the
    period it may straddle: 26 periods) delivered within the 450 s the heat takes to show is
    the hold's, 0.08·5·26 = 10.4 full-power s. The energy balance says so when r·x >
    h·10.4 + 0.2 (the 0.5 °C of 300 s, scaled), x > 29.7 s (over 300 s: 71.4 s). The rise must
    also go on as a heater's (`_heat_goes_on`): three windows since its onset, whole periods
    each, each beating e^(−w/150 s) of the one before by 0.1 °C, r·w·(1 − e^(−w/150)) > 0.1:
    w = 20 s (0.109 °C; 15 s gives 0.063 °C), at x = 60 s; confirmed a period later.
    """
    lim = SafetyLimits.derive(litres=30.0, element_watts=5500.0, period=5.0, read_interval=1.0)
    rate = 5500.0 / (30.0 * WATER_J_PER_K_L)
    sup = Supervisor(lim)
    fault = 3000.0
    raised = None
    for k in range(1, 1000):
        t = 5.0 * k
        x = max(0.0, t - fault)
        output = 8.0 if t <= fault else 0.0
        sup.period(t, 66.0 + rate * x, output, output)
        if "ssr_stuck_on" in sup.active:
            raised = t - fault
            break
    assert raised == 65.0


def test_a_shorted_ssr_right_after_a_kettle_is_still_caught() -> None:
    """5 L of 95 °C into the 50 L keggle holding 66 °C (+2.6 °C, through a 10 s lag: the
    pour the energy balance alone took for a shorted SSR), and the SSR shorts 30 s later:
    the rise from its heat goes on past the pour's settling, and is caught."""
    spec = next(s for s in FAMILY if s.name.startswith("keggle"))
    pour, short = 1800.0, 1830.0
    day = Scenario(
        name=spec.name,
        duration=pour + 1500.0,
        plant={**spec.plant(), "start_c": 66.0},
        setpoint=66.0,
        config={"contactor": {"backend": "gpio", "line": 27}},
        events=(
            Event(pour, "add_water", {"litres": 5.0, "temp": 95.0}),
            Event(short, "ssr", "stuck_on"),
        ),
    )
    assert alarms(day, spec)[:1] == ["ssr_stuck_on"]
