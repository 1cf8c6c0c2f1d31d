"""The default controller on tuns that are not the one its model describes.

The tun here is written from its equation, not from hermsd: a first-order plus dead time
water temperature, τ·dx/dt = −x + K·u(t − θ) with x the rise above the room, discretised
exactly for a duty held over each period (x ← a·x + K·(1 − a)·u, a = e^(−Ts/τ)), the dead
time in whole periods, and optionally the LM92's view of it: Gaussian noise, then truncation
to 0.0625 °C.
"""

from __future__ import annotations

import copy
import dataclasses
import itertools
import math
import random
from collections import deque

import pytest

from hermsd.control import laws, pid, watches
from hermsd.control import predictive as control_predictive

TS = 5.0
SP = 66.0
ROOM = 20.0
SEED = pid.SEED_HLT  # K 1.689 °C/%, τ 14961 s, θ 115 s
LSB = 0.0625


class Tun:
    """FOPTD water, a whole number of periods of dead time, an optional noisy LM92."""

    def __init__(
        self, gain: float, tau: float, dead_time: float, start: float, noise: float = 0.0
    ) -> None:
        self.gain, self.tau, self.a = gain, tau, math.exp(-TS / tau)
        self.rise = start - ROOM
        lag = round(dead_time / TS)
        self.pipe: deque[float] = deque([self.holding(start)] * lag)
        self.noise = noise
        self.rng = random.Random(7)

    def holding(self, temp: float) -> float:
        return (temp - ROOM) / self.gain

    def pv(self) -> float:
        temp = ROOM + self.rise
        if self.noise:
            temp = math.floor((temp + self.rng.gauss(0.0, self.noise)) / LSB) * LSB
        return temp

    def heat(self, duty: float) -> None:
        self.pipe.append(duty)
        arriving = self.pipe.popleft() if len(self.pipe) > 1 else duty
        self.rise = self.a * self.rise + self.gain * (1.0 - self.a) * arriving

    def add_water(self, fraction: float, temp: float) -> None:
        """Mix in `fraction` of the volume at `temp`: the rise drops at once, and the larger
        heat capacity C makes τ = C/UA longer (K = P/(100·UA) stays)."""
        self.rise = (self.rise + fraction * (temp - ROOM)) / (1.0 + fraction)
        self.tau *= 1.0 + fraction
        self.a = math.exp(-TS / self.tau)


def run(
    controller: pid.Controller,
    tun: Tun,
    seconds: float,
    water_at: float | None = None,
) -> list[tuple[float, float, float]]:
    """(t, pv, output) of every period; the duty the tun receives is the output."""
    trace = []
    applied: float | None = None
    for k in range(round(seconds / TS)):
        t = k * TS
        if water_at is not None and t == water_at:
            tun.add_water(0.1, 15.0)
        pv = tun.pv()
        output = controller.step(SP, pv, applied)
        tun.heat(output)
        applied = output
        trace.append((t, pv, output))
    return trace


def predictive(model: pid.PlantModel = SEED) -> pid.Controller:
    return laws.create("predictive", kc=120.0, ti=800.0, ts=TS, model=model)


def test_resume_near_the_setpoint_is_bumpless() -> None:
    controller = predictive()
    controller.reset(65.98, 27.0)
    # The model's bias takes what makes the first step continue from 27 %; the PV has not
    # moved, so the output does not either (to the rounding of the model's first period).
    assert controller.step(SP, 65.98) == pytest.approx(27.0, abs=1e-4)


def test_a_cold_start_is_full_power() -> None:
    controller = predictive()
    controller.reset(20.0, 0.0)
    assert controller.step(SP, 20.0) == 100.0


def test_a_cold_start_is_full_power_behind_a_long_dead_time_too() -> None:
    # 10.6 kW into 20 L behind 320 s (a learned model): a bias of 94 % of the element's rate
    # "explains" the 40 °C below the setpoint as heat in flight, and a start that took it to
    # be bumpless at 0 % never heated at all.
    rate, dead_time = 0.132, 320.0
    tau = 12000.0
    fast = pid.PlantModel(rate * tau / 100.0, tau, dead_time, 20.0)
    controller = predictive(fast)
    controller.reset(26.0, 0.0)
    assert controller.step(SP, 26.0) == 100.0


def test_heat_up_on_the_true_model_is_time_optimal_without_overshoot() -> None:
    tun = Tun(SEED.gain, SEED.tau, SEED.dead_time, ROOM)
    trace = run(predictive(), tun, 3 * 3600.0)
    # Full power from the start reaches SP − 0.5 after the dead time plus
    # τ·ln(K·100 / (K·100 − 45.5)) s, and can never be beaten.
    full = SEED.dead_time + SEED.tau * math.log(168.9 / (168.9 - 45.5))
    reached = next(t for t, pv, _ in trace if pv >= SP - 0.5)
    assert reached <= 1.01 * full
    assert max(pv for _, pv, _ in trace) <= SP + 0.05


MISMATCHES = {
    "dead time ×0.5": (SEED.gain, SEED.tau, 0.5 * SEED.dead_time),
    "dead time ×2": (SEED.gain, SEED.tau, 2.0 * SEED.dead_time),
    "gain ×0.5": (0.5 * SEED.gain, SEED.tau, SEED.dead_time),
    "gain ×2": (2.0 * SEED.gain, SEED.tau, SEED.dead_time),
    "time constant ×0.5": (SEED.gain, 0.5 * SEED.tau, SEED.dead_time),
    "time constant ×2": (SEED.gain, 2.0 * SEED.tau, SEED.dead_time),
}


def swings(values: list[float]) -> list[float]:
    """The size of each excursion from the setpoint, one per crossing of it, in order."""
    sizes: list[float] = []
    side = 0
    for value in values:
        error = value - SP
        now = (error > 0.01) - (error < -0.01)
        if now and now != side:
            sizes.append(0.0)
            side = now
        if now and sizes:
            sizes[-1] = max(sizes[-1], abs(error))
    return sizes


@pytest.mark.parametrize("truth", MISMATCHES.values(), ids=list(MISMATCHES))
def test_a_mismatched_model_settles_after_cold_water_without_bias(
    truth: tuple[float, float, float],
) -> None:
    # From a steady hold (no heat-up to re-measure the tun on), 10 % of 15 °C water at 1 h.
    # Off by 2×, the recovery at full power may overshoot (the heat in flight is misjudged by
    # up to half), but each swing is at most half the one a cycle before it: damped.
    gain, tau, dead_time = truth
    tun = Tun(gain, tau, dead_time, SP)
    controller = predictive()
    controller.reset(SP, tun.holding(SP))
    trace = run(controller, tun, 5 * 3600.0, water_at=3600.0)
    after = [pv for t, pv, _ in trace if t > 3600.0]
    sizes = swings(after)[1:]  # the first is the drop itself
    assert all(b <= a / 2.0 for a, b in zip(sizes, sizes[2:], strict=False)), sizes
    last_hour = [pv for t, pv, _ in trace if t >= 4 * 3600.0]
    assert max(last_hour) - min(last_hour) <= 0.1  # no sustained oscillation
    assert sum(last_hour) / len(last_hour) == pytest.approx(SP, abs=0.05)  # no lasting bias


def test_cold_water_on_the_true_model_leaves_no_bias_and_no_overshoot() -> None:
    tun = Tun(SEED.gain, SEED.tau, SEED.dead_time, SP)
    controller = predictive()
    controller.reset(SP, tun.holding(SP))
    trace = run(controller, tun, 4 * 3600.0, water_at=3600.0)
    assert max(pv for t, pv, _ in trace if t > 3600.0) <= SP + 0.1
    last_hour = [pv for t, pv, _ in trace if t >= 3 * 3600.0]
    assert sum(last_hour) / len(last_hour) == pytest.approx(SP, abs=0.01)


def test_sensor_noise_moves_the_held_output_by_under_ten_percent_a_period() -> None:
    tun = Tun(SEED.gain, SEED.tau, SEED.dead_time, SP, noise=0.03)
    controller = predictive()
    controller.reset(SP, tun.holding(SP))
    outputs = [u for _, _, u in run(controller, tun, 2 * 3600.0)]
    assert max(abs(b - a) for a, b in itertools.pairwise(outputs)) <= 10.0


class ShortedTun(Tun):
    """The FOPTD water whose element runs at full power whatever the duty once shorted."""

    shorted = False

    def heat(self, duty: float) -> None:
        super().heat(100.0 if self.shorted else duty)


def test_water_out_of_the_band_above_and_rising_gets_no_heat_until_back_in_it() -> None:
    # A shorted SSR in a steady hold, on the true model of a lossy tun behind a long dead
    # time (the hold's duty 50 %): the water climbs at K·(100 − 50)/τ = 0.55 °C/min once the
    # dead time has passed. The gentle gain near the setpoint, 100/(rate·2θ) %/°C, would cut
    # the hold's 50 % only with the water 0.5·rate·2θ ≈ 5.5 °C over. Heat sent is in the
    # water a dead time later and cannot be taken back, so once the water reads out of the
    # band above (a degree: the band's 0.5 °C and the observer's trail behind a PV running
    # away from its model) and still rises, any duty only adds to a rise nothing asked for.
    gain, tau, dead_time = 46.0 / 50.0, 5000.0, 300.0
    tun = ShortedTun(gain, tau, dead_time, SP)
    controller = predictive(pid.PlantModel(gain, tau, dead_time, ROOM))
    controller.reset(SP, tun.holding(SP))
    before = run(controller, tun, 3600.0)
    assert max(abs(pv - SP) for _, pv, _ in before) <= 0.01  # held: the short is all that moves
    tun.shorted = True
    trace = run(controller, tun, 1800.0)
    rising = [(pv, u) for (_, a, _), (_, pv, u) in itertools.pairwise(trace) if pv > a]
    out_above = [u for pv, u in rising if pv >= SP + 1.0]
    assert out_above and max(out_above) == 0.0
    # The SSR heals: the water, degrees over, falls back at its losses' rate, and gets no
    # heat until it is back in the band (a duty sent on the way down would only slow that).
    tun.shorted = False
    after = run(controller, tun, 3 * 3600.0)
    back = next(k for k, (_, pv, _) in enumerate(after) if pv <= SP + 0.5)
    assert back > 0 and max(u for _, _, u in after[:back]) == 0.0


class DeadTun(Tun):
    """The FOPTD water whose element gives no heat once dead, whatever the duty."""

    dead = False

    def heat(self, duty: float) -> None:
        super().heat(0.0 if self.dead else duty)


def dead_element_climb(two_elements: bool) -> tuple[float, float]:
    """(s from the death until the water reads LINEAR_BAND low, s from then to full power) on
    a tun that loses little (its holding duty 8 %, full power 0.02 °C/s) behind 300 s of
    dead time, held on its true model until its element dies."""
    gain, dead_time = 46.0 / 8.0, 300.0
    tau = 100.0 * gain / 0.02
    tun = DeadTun(gain, tau, dead_time, SP)
    controller = predictive(pid.PlantModel(gain, tau, dead_time, ROOM))
    if two_elements:
        control_predictive.on_two_elements(controller)
    controller.reset(SP, tun.holding(SP))
    before = run(controller, tun, 3600.0)
    assert max(abs(pv - SP) for _, pv, _ in before) <= 0.01
    tun.dead = True
    trace = run(controller, tun, 3600.0)
    low = next(t for t, pv, _ in trace if pv < SP - pid.LINEAR_BAND)
    full = next(t for t, _, u in trace if u >= 100.0)
    return low, full - low


def test_an_element_that_dies_in_the_hold_has_full_power_asked_within_minutes() -> None:
    # The water falls at its losses' rate, 46/τ = 0.096 °C/min, and reads LINEAR_BAND
    # (0.25 °C) low 300 + 160 s after the death. The heat the model counts on never
    # arrives, and the bias chases a missing heat that grows with the duty it adds: the duty
    # climbs at u0/τ_b a second, from 8 % to 100 % in (100 − 8)/8·τ_b, 1150 s at the 100 s
    # the bias learns at while heat is missing (the P term on the falling water hastens it).
    low, climb = dead_element_climb(two_elements=False)
    assert 400.0 <= low <= 520.0
    assert climb <= (100.0 - 8.0) / 8.0 * pid.MISSING_HEAT_BIAS_S
    # On two elements' total the missing heat may be one element's, which the other holds:
    # the bias keeps ti's 800 s (the P term still climbs, in some 1900 s).
    low_two, climb_two = dead_element_climb(two_elements=True)
    assert low_two == low
    assert climb_two > (100.0 - 8.0) / 8.0 * pid.MISSING_HEAT_BIAS_S


def _losses_triple(
    dead_time: float, noise: float, poured: bool
) -> list[tuple[float, float, float]]:
    """A small fast tun (full power 0.044 °C/s) held at 17 % on its true model for 600 s,
    then, with `poured`, a tenth of its water at 15 °C and 600 s more, then its losses
    tripled (a lid off, a door to a cold garage: K and τ to a third): the 2 hours after."""
    gain = 46.0 / 17.0
    tun = Tun(gain, 100.0 * gain / 0.044, dead_time, SP, noise=noise)
    controller = predictive(pid.PlantModel(gain, tun.tau, dead_time, ROOM))
    controller.reset(SP, tun.holding(SP))
    run(controller, tun, 600.0)
    if poured:
        tun.add_water(0.1, 15.0)
        run(controller, tun, 600.0)
    tun.gain, tun.tau = gain / 3.0, tun.tau / 3.0
    tun.a = math.exp(-TS / tun.tau)
    return run(controller, tun, 7200.0)


def _back_for_good(trace: list[tuple[float, float, float]], within: float) -> None:
    """The water within LINEAR_BAND for good before `within` s, its last hour at the duty
    that holds 66 °C on the tripled losses: (66 − 20)/(K/3) = 51.1 % (cold water leaves K
    as it was)."""
    out = [t for t, pv, _ in trace if abs(pv - SP) > pid.LINEAR_BAND]
    assert out[-1] < within
    last_hour = [u for t, _, u in trace if t >= 3600.0]
    assert sum(last_hour) / len(last_hour) == pytest.approx(46.0 / (46.0 / 17.0 / 3.0), abs=0.5)


@pytest.mark.parametrize(
    ("dead_time", "noise", "within"),
    [(150.0, 0.0, 3600.0), (150.0, 0.03, 6000.0), (250.0, 0.03, 6000.0)],
)
def test_losses_that_triple_in_the_hold_are_learned_not_taken_for_cold_water(
    dead_time: float, noise: float, within: float
) -> None:
    # At 17 % the water falls a degree a minute, the estimate trailing it and catching up in
    # jumps; taken for cold water each time, they shrank the model's rate by a quarter,
    # forgot the held setpoint, and the water sat 2 °C low for hours. A jump the PV itself
    # did not fall beyond the clip for is no water: the rate is kept, the missing heat
    # learned, and the water back in the band within the hour. Behind a noisy LM92 a reading
    # falls beyond the clip now and then on the fall and its noise, and the jump is taken
    # for water: the setpoint held is kept through it, and the stalled recovery learns the
    # missing heat, back in the band for good within 100 minutes (where forgotten, not in
    # two hours: the duty 2 % short of the hold's at the end).
    _back_for_good(_losses_triple(dead_time, noise, poured=False), within)


def test_heat_missing_after_cold_water_is_learned_in_its_recovery() -> None:
    # Behind a noisy LM92 and 250 s of dead time, the losses triple while the water recovers
    # from a pour (the lid left off after it). The pour's fall is the water's; a recovery
    # that then stops rising short of the band has heat missing, learned at
    # MISSING_HEAT_BIAS_S, and the water is back in the band for good within 100 minutes.
    # With the setpoint held forgotten at the pour it was learned at ti: the water 3.3 °C
    # low an hour on, not back in two hours.
    _back_for_good(_losses_triple(250.0, 0.03, poured=True), 6000.0)


@pytest.mark.parametrize("seed", range(4))
def test_a_recovery_creeping_up_behind_noise_is_no_heat_missing(seed: int) -> None:
    # A 40 L tun on 2.1 kW (0.0127 °C/s at full power) holding at 21 %, behind 335 s of dead
    # time and an LM92 with 0.058 °C of noise, a tenth of its water at 15 °C poured in. Its
    # recovery lands short and creeps up as the heat in flight arrives: a minute's reading
    # behind the noise often stands no higher than the one before, and taken for heat
    # missing, the bias learned the creep and the water came over by 0.4–0.6 °C. Judged over
    # the heat's way to the sensor the creep rises: the minute means of the readings stay
    # within 0.25 °C of the setpoint.
    gain, dead_time = 46.0 / 21.0, 335.0
    tun = Tun(gain, 100.0 * gain / 0.0127, dead_time, SP, noise=0.058)
    tun.rng.seed(seed)
    controller = predictive(pid.PlantModel(gain, tun.tau, dead_time, ROOM))
    controller.reset(SP, tun.holding(SP))
    run(controller, tun, 1800.0)
    tun.add_water(0.1, 15.0)
    pvs = [pv for _, pv, _ in run(controller, tun, 7200.0)]
    minute = round(60.0 / TS)
    means = [sum(pvs[k : k + minute]) / minute for k in range(len(pvs) - minute)]
    assert max(means) <= SP + 0.25


def test_held_at_no_heat_above_the_band_the_bias_learns_the_losses() -> None:
    # A tun that loses little (its true holding duty (66 − 20)/4.6 = 10 %) on a model that
    # holds at 30 % with the true rate: the water runs away over the band and gets no heat
    # until back in it. Held there, the model errs only by its losses, which the bias learns:
    # back in the band the duty is the tun's. Frozen, it came back at 30 % and the water ran
    # away again, the duty cycling 0–98 % at the band's edge.
    gain, tau, dead_time = 4.6, 20000.0, 200.0
    tun = Tun(gain, tau, dead_time, SP)
    model_gain = 46.0 / 30.0  # the same rate, K/τ: three times the losses
    controller = predictive(pid.PlantModel(model_gain, tau * model_gain / gain, dead_time, ROOM))
    controller.reset(SP, 30.0)
    trace = run(controller, tun, 2700.0)
    assert max(pv for _, pv, _ in trace) > SP + 0.5  # it ran away
    settled = [u for t, _, u in trace if t >= 2100.0]
    assert all(abs(u - 10.0) <= 2.0 for u in settled)


def test_a_heat_up_measures_the_dead_time_and_rate_and_uses_them() -> None:
    # The sensor is twice as far as the model says: measured on the heat-up's ramp.
    tun = Tun(SEED.gain, SEED.tau, 240.0, ROOM)
    controller = predictive()
    trace = run(controller, tun, 3 * 3600.0)
    fit = control_predictive.heat_up_fit(controller)
    assert fit is not None and fit.refused is None
    # The fit takes a period's PV as its mean, half a period old; here it is a sample at the
    # step, so it reads the dead time half a period short.
    assert fit.dead_time == pytest.approx(240.0 - TS / 2, abs=2.0)
    assert fit.rate == pytest.approx(100.0 * SEED.gain / SEED.tau, rel=0.02)
    assert max(pv for _, pv, _ in trace) <= SP + 0.1


@pytest.mark.parametrize("delay", [120.0, 260.0])
def test_a_heat_up_lands_on_losses_its_ramp_learned_not_the_priors(delay: float) -> None:
    # The config's prior (the seed's losses) is three times this tun's, at the same rate.
    # On the prior the landing's heat in flight and the holding duty it sends are each too
    # much by a dead time of the losses it has wrong: the PV passed 66 °C by 0.50 °C (120 s)
    # and 0.81 °C (260 s). Learned on the ramp after its fit: within the day-1 goal.
    tun = Tun(3.0 * SEED.gain, 3.0 * SEED.tau, delay, ROOM, noise=0.02)
    controller = predictive(dataclasses.replace(SEED, dead_time=delay))
    trace = run(controller, tun, 3 * 3600.0)
    fit = control_predictive.heat_up_fit(controller)
    assert fit is not None and fit.refused is None
    assert max(pv for _, pv, _ in trace) <= SP + 0.3
    # The hold then asks the tun's own duty, a third of the prior's.
    held = [u for t, _, u in trace if t >= 2 * 3600.0]
    assert sum(held) / len(held) == pytest.approx(tun.holding(SP), rel=0.1)


class LaggedTun(Tun):
    """The same water read through a thermowell: a first-order sensor lag on it, exact for
    the water held over each period."""

    def __init__(self, gain: float, tau: float, delay: float, lag: float, start: float) -> None:
        super().__init__(gain, tau, delay, start)
        self.fade = math.exp(-TS / lag)
        self.sensor = start

    def pv(self) -> float:
        return self.sensor

    def heat(self, duty: float) -> None:
        super().heat(duty)
        self.sensor = ROOM + self.rise + (self.sensor - ROOM - self.rise) * self.fade


@pytest.mark.parametrize(("delay", "lag"), [(60.0, 80.0), (60.0, 100.0), (120.0, 60.0)])
def test_behind_a_sensor_lag_the_heat_up_lands_without_overshoot(delay: float, lag: float) -> None:
    # 8 kW into 40 L (0.048 °C/s) behind a thermowell: the lag's tail still climbs when a
    # pure delay of delay + lag says the heat has all arrived; a law that took the tail for
    # a shortfall added heat, and the PV passed 66 °C by 0.55–0.85 °C on these. The model
    # is told the whole dead time; the heat-up's fit tells it the lag.
    tau = 11900.0
    gain = 0.048 * tau / 100.0
    tun = LaggedTun(gain, tau, delay, lag, ROOM)
    model = pid.PlantModel(gain, tau, delay + lag, ROOM)
    controller = predictive(model)
    trace = run(controller, tun, 2 * 3600.0)
    fit = control_predictive.heat_up_fit(controller)
    assert fit is not None and fit.refused is None
    assert fit.lag == pytest.approx(lag, rel=0.15)
    assert max(pv for _, pv, _ in trace) <= SP + 0.1


def test_an_implausible_heat_up_is_refused_and_says_why() -> None:
    # Heating ten times faster than the model allows for: a wrong config, not a tun.
    tun = Tun(10.0 * SEED.gain, SEED.tau, SEED.dead_time, ROOM)
    controller = predictive()
    run(controller, tun, 600.0)
    fit = control_predictive.heat_up_fit(controller)
    assert fit is not None and fit.refused is not None
    assert "rate" in fit.refused and "¼–4×" in fit.refused


def test_cold_water_is_acted_on_in_the_period_the_sensor_shows_it() -> None:
    tun = Tun(SEED.gain, SEED.tau, SEED.dead_time, SP)
    controller = predictive()
    controller.reset(SP, tun.holding(SP))
    trace = run(controller, tun, 3600.0 + TS, water_at=3600.0)
    # 10 % of 15 °C water takes the tun from 66 to 61.4 °C at once: the very step that reads
    # it acts on the whole drop (P at least kc on it), not on a filtered fraction of it.
    t, pv, output = trace[-1]
    assert t == 3600.0 and pv < 62.0 and output == 100.0
    assert controller.terms[0] >= 120.0 * (SP - pv)


def recover(model: pid.PlantModel) -> tuple[float, float, float]:
    """(s back in the band, the least s full power from that period on takes, peak °C
    after) of the predictive controller on `model`'s own tun after a tenth of cold water."""
    tun = Tun(model.gain, model.tau, model.dead_time, SP)
    controller = predictive(model)
    controller.reset(SP, tun.holding(SP))
    trace = run(controller, tun, 2 * 3600.0, water_at=3600.0)
    back = next(t for t, pv, _ in trace if t > 3600.0 and pv >= SP - 0.5) - 3600.0
    # The least it can take: the same tun, the same water, full power from that period on
    # (the duty already in the dead time still arrives first).
    fastest = Tun(model.gain, model.tau, model.dead_time, SP)
    fastest.add_water(0.1, 15.0)
    steps = 0
    while fastest.pv() < SP - 0.5:
        fastest.heat(100.0)
        steps += 1
    return back, steps * TS, max(pv for t, pv, _ in trace if t > 3600.0)


def test_recovery_from_cold_water_is_within_two_percent_of_full_power() -> None:
    back, fastest, peak = recover(SEED)
    assert back <= 1.02 * fastest
    assert peak <= SP + 0.1


def least_recovery(tun: LaggedTun) -> int:
    """Periods the least recovery takes: a copy of the tun, full power from the water on,
    until the sensor, having fallen out of the band, is back in it."""
    fastest, steps, fallen = copy.deepcopy(tun), 0, False
    while not (fallen and fastest.pv() >= SP - 0.5):
        fastest.heat(100.0)
        steps += 1
        fallen = fallen or fastest.pv() < SP - 0.5
    return steps


def lagged_day(model: pid.PlantModel, delay: float, lag: float) -> tuple[float, float, float]:
    """(s back in the band, the least s full power from the water on takes, peak °C after)
    of a day on `model`'s water behind a thermowell: a heat-up from the room (its fit
    measures the lag), a hold, and a tenth of 15 °C water at 2 h."""
    water_at = 7200.0
    tun = LaggedTun(model.gain, model.tau, delay, lag, ROOM)
    controller = predictive(model)
    trace = run(controller, tun, water_at)
    tun.add_water(0.1, 15.0)
    steps = least_recovery(tun)
    after = run(controller, tun, 3600.0)
    low = next(i for i, (_, pv, _) in enumerate(after) if pv < SP - 0.5)
    back = next(t for t, pv, _ in after[low:] if pv >= SP - 0.5)
    assert trace and min(pv for _, pv, _ in trace[-100:]) >= SP - 0.1  # it held before
    return back, steps * TS, max(pv for _, pv, _ in after)


def test_a_recovery_on_a_measured_model_lands_within_two_percent_of_full_power() -> None:
    # 0.01 °C/s behind 30 s and a 100 s thermowell: the sensor crosses back into the band on
    # the lag's tail, so the nearer the heat in flight lands the water to the setpoint, the
    # sooner it does. A measured model lands 3 % of the heat in flight short (here under
    # 0.05 °C); the config's prior, whose losses may be half the truth, a quarter degree.
    tau = 11900.0
    gain = 0.01 * tau / 100.0
    measured = pid.PlantModel(gain, tau, 130.0, ROOM, measured=True)
    back, fastest, peak = lagged_day(measured, 30.0, 100.0)
    assert back <= 1.02 * fastest
    assert peak <= SP + 0.1
    prior_back, prior_fastest, _ = lagged_day(
        dataclasses.replace(measured, measured=False), 30.0, 100.0
    )
    assert prior_fastest == fastest
    assert prior_back > back


def test_cold_water_behind_a_slow_sensor_is_heated_for_its_whole_drop() -> None:
    # 4 kW into 48 L (0.02 °C/s) behind a 50 s delay and a 150 s thermowell, a tenth of
    # 15 °C water into the 66 °C hold: the water drops to (66 + 0.1·15)/1.1 = 61.364 °C at
    # once, the sensor shows it as 4.6·(1 − e^(−t/150)), still 1.5 °C above the water when
    # the heat turns it. A law that took the PV's turn as the whole drop cut full power
    # with the water 1.7 °C short and crept up the rest (back in the band ×1.6 of the
    # least). The water itself is back at the setpoint before full power could have
    # brought the sensor into the band, and the rate is scaled by the whole drop:
    # (66 − 5)/(61.364 − 5) = 1.0823 × the capacity.
    tau = 11900.0
    gain = 0.02 * tau / 100.0
    delay, lag = 50.0, 150.0
    model = pid.PlantModel(gain, tau, delay + lag, ROOM, measured=True)
    tun = LaggedTun(model.gain, model.tau, delay, lag, ROOM)
    controller = predictive(model)
    held = run(controller, tun, 7200.0)
    assert min(pv for _, pv, _ in held[-100:]) >= SP - 0.1
    tun.add_water(0.1, 15.0)
    steps = least_recovery(tun)
    law = control_predictive._law(controller)
    assert law is not None
    water, applied = [], None
    for _ in range(round(3600.0 / TS)):
        output = controller.step(SP, tun.pv(), applied)
        tun.heat(output)
        applied = output
        water.append(ROOM + tun.rise)
    assert max(water[: steps + 1]) >= SP - 0.1
    assert max(water) <= SP + 0.1
    dropped = (SP + 0.1 * 15.0) / 1.1
    assert law._rate == pytest.approx(model.rate * (dropped - 5.0) / (SP - 5.0), rel=0.01)


@pytest.mark.parametrize(("tau", "dead_time"), [(SEED.tau, 150.0), (SEED.tau / 2.0, 100.0)])
def test_recovery_re_measures_the_rate_the_water_lowered(tau: float, dead_time: float) -> None:
    # The model is exact until the water: a tenth more water heats 9 % slower. Heard only at
    # the next heat-up, the heat in flight is misjudged and the recovery ends 0.03 °C off
    # the setpoint; measured on the recovery's own ramp, full power ends where the heat in
    # flight lands the PV on it.
    back, fastest, peak = recover(pid.PlantModel(SEED.gain, tau, dead_time, ROOM))
    assert back <= 1.02 * fastest
    assert peak <= SP + 0.01


@pytest.mark.parametrize(("tau", "dead_time"), [(SEED.tau / 4.0, 260.0), (SEED.tau / 2.0, 250.0)])
def test_cold_water_behind_a_long_dead_time_is_known_as_heat_capacity_by_its_drop(
    tau: float, dead_time: float
) -> None:
    # Full power ends before any of its heat shows, so the recovery's ramp measures nothing;
    # the drop itself says how much water came: from 66 °C to p, at least (66 − p)/(p − 5)
    # of the heat capacity (as much water at 5 °C; this is at 15 °C, a tenth). Keeping the
    # old rate, full power ended 9 % early, the PV crept up the rest and went on 0.1 °C
    # over (×1.2 on the second tun).
    back, fastest, peak = recover(pid.PlantModel(SEED.gain, tau, dead_time, ROOM))
    assert back <= 1.02 * fastest
    assert peak <= SP + 0.1


def test_the_drop_scales_the_rate_by_the_heat_capacity_it_says() -> None:
    # A tenth of 15 °C water into 66 °C: (66 + 0.1·15)/1.1 = 61.364 °C, at once (no lag).
    # The law takes it as water at 5 °C: (66 − 5)/(61.364 − 5) = 1.0823 × the capacity.
    model = pid.PlantModel(SEED.gain, SEED.tau, 200.0, ROOM)
    tun = Tun(model.gain, model.tau, model.dead_time, SP)
    controller = predictive(model)
    controller.reset(SP, tun.holding(SP))
    run(controller, tun, 600.0 + TS, water_at=600.0)
    law = control_predictive._law(controller)
    assert law is not None
    dropped = (SP + 0.1 * 15.0) / 1.1
    assert law._rate == pytest.approx(model.rate * (dropped - 5.0) / (SP - 5.0), rel=1e-9)


class PartPeriodTun:
    """FOPTD water whose dead time ends `share` of the way into a period: over each period
    the duty sent n + 1 periods before still arrives for `share` of it, then the one sent n
    periods before (each sub-span discretised exactly)."""

    def __init__(self, gain: float, tau: float, dead_time: float, start: float) -> None:
        self.gain, self.tau = gain, tau
        self.rise = start - ROOM
        whole, self.share = divmod(dead_time / TS, 1.0)
        self.n = int(whole)
        self.sent = [self.rise / gain] * (self.n + 2)

    def pv(self) -> float:
        return ROOM + self.rise

    def heat(self, duty: float) -> None:
        self.sent.append(duty)
        older, newer = self.sent[-2 - self.n], self.sent[-1 - self.n]
        for arriving, span in ((older, self.share * TS), (newer, (1.0 - self.share) * TS)):
            a = math.exp(-span / self.tau)
            self.rise = a * self.rise + self.gain * (1.0 - a) * arriving


@pytest.mark.parametrize("dead_time", [32.4, 27.6])
def test_heat_in_flight_counts_once_whatever_part_of_a_period_the_dead_time_ends_in(
    dead_time: float,
) -> None:
    # A fast tun (30 L at 5.5 kW heats 0.044 °C/s) held at the setpoint on its own model,
    # then one period of full power: the PV one dead time ahead is the hold plus that
    # period's heat, 0.045 °C/s × 5 s × (100 − 27) % ≈ 0.16 °C, before the heat arrives,
    # while it arrives and after. A dead time of 6.48 or 5.52 periods rounded to 6 lets
    # half a period of it slip: the pulse is counted part twice or part never as it lands.
    tau = SEED.tau / 4.0
    model = pid.PlantModel(SEED.gain, tau, dead_time, ROOM)
    tun = PartPeriodTun(SEED.gain, tau, dead_time, SP)
    holding = (SP - ROOM) / SEED.gain
    controller = predictive(model)
    controller.reset(SP, holding)
    duties = [holding] * 4 + [100.0] + [holding] * 12
    proportional = []
    applied = holding
    for duty in duties:
        controller.step(SP, tun.pv(), applied)
        proportional.append(controller.terms[0])
        tun.heat(duty)
        applied = duty
    after = proportional[5:]  # from the step that knows of the pulse on
    assert min(after) < -1.0  # the pulse is predicted: above the setpoint, P cuts
    assert max(after) - min(after) <= 0.02 * -min(after), after


def test_a_pour_followed_for_many_of_its_lags_ends_with_nothing_unseen() -> None:
    # A short lag followed for minutes (water that keeps the PV falling: an element too weak
    # to turn it): e^(−t/L) underflows to 0, and the rest taken as the drop's is none, not
    # a division by zero inside the control step.
    gap = watches._PourGap(66.0)
    fade = math.exp(-TS / 1.0)
    for _ in range(2000):
        gap.advance(0.0, fade)
    gap.seen(60.0, fade, 66.0)
    gap.settle(fade)
    assert gap.unseen(fade) == 0.0
    assert gap.advance(0.0, fade) == 0.0
