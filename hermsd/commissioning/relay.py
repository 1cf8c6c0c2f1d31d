"""`hermsd tune relay`: an Åström–Hägglund relay test around the setpoint, through the daemon.

The loop first brings the water to the setpoint under the configured controller (auto) and
holds it there for SETTLE_S, whose mean applied duty is the relay's bias. Then the manual
output switches between two levels, `low` = max(0, bias − P) and `high` = low + 2·P (the
bias ± P, shifted up when the bias is below P), whenever the period's PV leaves the
hysteresis band SP ± ε: to `low` above SP + ε, to `high` below SP − ε. The supervisor
watches the run as any other and the recorder logs it.

From the settled cycles (from the first switch down after the start or the last change of
P: `cycles`), each
taken as the exact limit cycle of a lag-dominant tun (τ ≫ the period: an integrator with
dead time) under a relay with hysteresis (`ultimate`): the dead time θ from the times at
high and low and the amplitude a, the ultimate period Pu = 4θ and the ultimate gain
Ku = πd/(2(a − ε)), with the loop's own delay (one control period: the PV is a period's
mean, a new output acts over the next period) taken off θ. The describing function's
Ku = 4d/(π·√(a² − ε²)) (the real part of the hysteretic relay's −1/N(a)) is given beside
it: for a triangular PV it is low by up to 8/π² (19 %), and the relay's own period, which
includes the hysteresis's 4ε/s, is not Pu.

The model is the least-squares FOPTD of hermsd.commissioning.identify over the hold and the
relay (the one fitting code every user shares), with the room's temperature known: over a test much
shorter than τ the cycles show θ and K/τ, and only the hold's duty against the water's rise
above the room (K = (T − T_amb)/u) separates K from τ. Beside it: the fitted model's own Ku
and Pu (phase −π), and the FOPTD with the fit's K whose ultimate point is the measured one
(magnitude and phase conditions at ωu, `foptd_from_ultimate`).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import statistics
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hermsd.commissioning import tune
from hermsd.commissioning.identify import MIN_DUTY_SPAN
from hermsd.commissioning.step_response import (
    ABORTED,
    FitStart,
    Stopping,
    clock_text,
    estimates,
    fit_in_thread,
    run,
)
from hermsd.runtime.daemon import Daemon
from hermsd.runtime.period import PeriodRecord

LSB_C = 0.0625
HYSTERESIS_C = LSB_C
"""ε: one LM92 step. The family's sensor (0.03 °C sd before the 0.0625 °C truncation, which
adds 0.018 °C sd) averaged over a period's ~5 readings leaves ~0.016 °C sd on the period's
PV; the band 2ε is 8 of those, so noise alone does not switch the relay back."""
REACHED_C = 0.25  # the heat-up is over when PV is this close below the setpoint
SETTLE_S = 300.0
"""In auto at the setpoint before the relay: its mean duty is the relay's bias."""
MAX_AT_SETPOINT_S = 45 * 60.0
ROOM_BELOW_C = 10.0
"""Without --ambient the first PV is the room's (the water stood in it): not when it starts
this close to the setpoint (hot water from the tap, a tun still warm)."""
RUNAWAY_C = 1.0
"""PV this far above the setpoint during the relay stops the test: the swing aims at 0.3 °C."""
MIN_AMPLITUDE = MIN_DUTY_SPAN / 2.0
"""%: the relay's span 2·P is at least the duty span the fit needs for K and τ to show."""
MAX_AMPLITUDE = 50.0  # %: bias ± 50 spans the whole output
TARGET_SWING_C = 0.3
"""The aimed peak distance of PV from the setpoint: well inside ±0.5 °C, and 5× ε."""
RESCALE_ABOVE_C = 0.45
"""A first cycle that swings further than this (or less than half the target) rescales P."""
MIN_CYCLES = 2
CONSISTENT = 0.15
"""Relative spread (sd/mean) of Pu and of Ku over the settled cycles: a ~0.2 °C amplitude read
in 0.0625 °C steps moves Ku by ~10 % from one cycle to the next."""
GOAL_RELATIVE = 0.15  # the relay's accuracy goal for K, τ and θ (2σ)
STOP_RULE = (
    f"at least {MIN_CYCLES} settled cycles whose Pu and Ku vary by at most "
    f"{100 * CONSISTENT:g} % (sd/mean), and the fit's 2σ within ±{100 * GOAL_RELATIVE:g} % "
    f"for K, τ and θ (θ: or one period); at most {MAX_AT_SETPOINT_S / 60:g} min at the setpoint"
)
CYCLES_GOOD = "the cycles are consistent and the fit is good"
ULTIMATE_METHOD = (
    "each settled cycle as a lag-dominant tun's (an integrator with dead time) under a relay "
    "with hysteresis ε: θ = (T_H·T_L/(T_H + T_L))·(1 − ε/a) less one control period (the "
    "PV's averaging and the output's next period), Pu = 4θ, Ku = ωu/a* with "
    "a* = (a − ε)/(d·(θ + period)); "
    "ku_df the describing function's 4d/(π·√(a² − ε²)); a half the peak-to-peak PV"
)


class RelayError(ValueError):
    """Settings a relay test cannot run with; the message says what would be right."""


@dataclass(frozen=True, slots=True)
class Cycle:
    """One full relay cycle: from a switch to the low output to the next one."""

    period: float  # s
    high_s: float  # s at the high output
    amplitude: float  # a, half the peak-to-peak PV, °C


@dataclass(frozen=True, slots=True)
class Ultimate:
    """Ku and Pu from the settled cycles (means, and sample standard deviations)."""

    cycles: int
    period: float  # s, the relay's own oscillation
    amplitude: float  # a, °C
    d: float  # %, half the relay's span
    dead_time: float  # θ, s, of the lag-dominant cycle
    pu: float  # s, 4θ
    pu_sd: float
    ku: float  # %/°C, πd/(2(a − ε))
    ku_sd: float
    ku_df: float  # %/°C, the describing function's 4d/(π·√(a² − ε²))


@dataclass(frozen=True, slots=True)
class Progress:
    at_setpoint: float  # s since the heat-up ended
    pv: float | None
    phase: str  # "heat-up", "settle", "relay"
    ultimate: Ultimate | None
    tuned: tune.Tuned | None
    problem: str | None


def amplitude_for(element_watts: float, litres: float, dead_time: float) -> float:
    """P (%) for a swing of TARGET_SWING_C: past a switch, PV runs on for θ at the water's
    rate a*·P (a* = watts/(100·C)), so the peak is ε + a*·P·θ; MIN_ to MAX_AMPLITUDE."""
    a_star = element_watts / (100.0 * tune.WATER_J_PER_L_K * litres)
    wanted = (TARGET_SWING_C - HYSTERESIS_C) / (a_star * max(dead_time, 1.0))
    return min(max(MIN_AMPLITUDE, float(round(wanted))), MAX_AMPLITUDE)


def levels(bias: float, amplitude: float, max_output: float) -> tuple[float, float]:
    """The relay's two outputs: bias ± P, shifted up to stay ≥ 0, the top at most max_output."""
    low = max(0.0, bias - amplitude)
    high = min(max_output, low + 2.0 * amplitude)
    return low, high


def ultimate_point(gain: float, tau: float, dead_time: float) -> tuple[float, float]:
    """Ku (%/°C) and Pu (s) of K·e^(−θs)/(τs + 1): the frequency where θω + atan(τω) = π
    (by bisection: the phase falls monotonically), and 1/|G| there."""
    if dead_time <= 0:
        raise RelayError("a FOPTD without dead time never reaches −180°: no ultimate point")
    low, high = 0.0, math.pi / dead_time
    for _ in range(200):
        mid = 0.5 * (low + high)
        if dead_time * mid + math.atan(tau * mid) < math.pi:
            low = mid
        else:
            high = mid
    omega = 0.5 * (low + high)
    return math.hypot(1.0, tau * omega) / gain, 2.0 * math.pi / omega


def foptd_from_ultimate(gain: float, ku: float, pu: float) -> tuple[float, float]:
    """τ and θ of the FOPTD with gain K whose ultimate point is (Ku, Pu): |G(iωu)| = 1/Ku
    gives τ = √((K·Ku)² − 1)/ωu, the phase −π gives θ = (π − atan(τ·ωu))/ωu."""
    if gain * ku <= 1.0:
        raise RelayError(f"K·Ku = {gain * ku:.3g} ≤ 1: no FOPTD with this gain has that Ku")
    omega = 2.0 * math.pi / pu
    tau = math.sqrt((gain * ku) ** 2 - 1.0) / omega
    return tau, (math.pi - math.atan(tau * omega)) / omega


def cycles(
    switches: list[tuple[float, float]],
    times: list[float],
    pvs: list[float | None],
    high: float,
    since: float,
) -> list[Cycle]:
    """Each full cycle from a switch down after `since` to the next one. At a switch down PV
    is at SP + ε and the high output has acted for longer than θ (it is switched only once
    its heat has shown), which is all an integrator with dead time remembers: so the first
    such cycle after the relay's start or a change of P is already the limit cycle."""
    after = [(t, level) for t, level in switches if t > since]
    downs = [t for t, level in after if level != high]
    out = []
    for start, end in itertools.pairwise(downs):
        up = next((t for t, level in after if start < t < end and level == high), None)
        span = [pv for t, pv in zip(times, pvs, strict=True) if start <= t < end and pv is not None]
        if span and up is not None:
            out.append(Cycle(end - start, end - up, 0.5 * (max(span) - min(span))))
    return out


def ultimate(
    measured: list[Cycle], d: float, hysteresis: float, loop_delay: float = 0.0
) -> Ultimate | None:
    """Ku and Pu from the cycles (None: fewer than two, or an amplitude within the hysteresis).

    Over a cycle a lag-dominant tun (τ ≫ the period) is an integrator with dead time: PV
    moves at s₁ = a*·(high − hold) while the high output acts, at s₂ = a*·(hold − low) while
    the low one does, each for θ past a switch at SP ± ε. So the peak-to-peak is
    2a = 2ε + (s₁ + s₂)·θ, the times at high and low are T_H = θ + (2ε + s₂θ)/s₁ and
    T_L = θ + (2ε + s₁θ)/s₂, and s₁·T_H = s₂·T_L (PV ends where it began). Solved:
    θ = (T_H·T_L/(T_H + T_L))·(1 − ε/a) and a*·θ = (a − ε)/d, whose ultimate point
    (ωu = π/(2θ), Ku = ωu/a*) is Pu = 4θ and Ku = π·d/(2(a − ε)): exact for the integrator,
    where the describing function's 4d/(π·√(a² − ε²)) is low by up to 8/π² (19 %) from the
    triangular PV alone, and its period includes the hysteresis's 4ε/s.

    `loop_delay`: what the loop adds to the tun's own θ in the cycle (the daemon's: one
    control period, `RelayExperiment`), taken off θ; a*·θ comes from the cycle as measured.
    """
    if len(measured) < 2 or any(c.amplitude <= hysteresis for c in measured):
        return None
    loop_dead_times = [
        c.high_s * (c.period - c.high_s) / c.period * (1.0 - hysteresis / c.amplitude)
        for c in measured
    ]
    if any(theta <= loop_delay for theta in loop_dead_times):
        return None
    dead_times = [theta - loop_delay for theta in loop_dead_times]
    gains = [
        math.pi * d * loop / (2.0 * (c.amplitude - hysteresis) * theta)
        for c, loop, theta in zip(measured, loop_dead_times, dead_times, strict=True)
    ]
    amplitude = statistics.fmean(c.amplitude for c in measured)
    return Ultimate(
        cycles=len(measured),
        period=statistics.fmean(c.period for c in measured),
        amplitude=amplitude,
        d=d,
        dead_time=statistics.fmean(dead_times),
        pu=4.0 * statistics.fmean(dead_times),
        pu_sd=4.0 * statistics.stdev(dead_times),
        ku=statistics.fmean(gains),
        ku_sd=statistics.stdev(gains),
        ku_df=4.0 * d / (math.pi * math.sqrt(amplitude**2 - hysteresis**2)),
    )


def consistent(found: Ultimate) -> bool:
    return (
        found.cycles >= MIN_CYCLES
        and found.pu_sd <= CONSISTENT * found.pu
        and found.ku_sd <= CONSISTENT * found.ku
    )


def implied_foptd(gain: float, found: Ultimate | None) -> tuple[float, float] | None:
    """τ and θ of the FOPTD with gain K at the measured ultimate point (None: none such)."""
    if found is None or gain * found.ku <= 1.0:
        return None
    return foptd_from_ultimate(gain, found.ku, found.pu)


def fit_good(tuned: tune.Tuned, period_s: float) -> bool:
    """Every 2σ within GOAL_RELATIVE (θ's: or one period, the fit's step) and the RMS low."""
    m, u = tuned.model, tuned.uncertainty
    return (
        2 * u.gain <= GOAL_RELATIVE * m.gain
        and 2 * u.tau <= GOAL_RELATIVE * m.tau
        and 2 * u.dead_time <= max(GOAL_RELATIVE * m.dead_time, period_s)
        and m.rms <= tune.MAX_RMS_C
    )


@dataclass(slots=True)
class RelayExperiment(Stopping[Progress]):
    """Listens to the daemon's periods: heat-up, hold, relay; stops the loop when done."""

    daemon: Daemon
    setpoint: float  # °C
    hysteresis: float = HYSTERESIS_C
    amplitude: float | None = None  # P, %; None: amplitude_for the config's tun
    ambient: float | None = None  # the room's; None: the first PV (ROOM_BELOW_C)
    on_progress: Callable[[Progress], None] | None = None
    times: list[float] = field(default_factory=list)
    pvs: list[float | None] = field(default_factory=list)
    duties: list[float] = field(default_factory=list)
    switches: list[tuple[float, float]] = field(default_factory=list)  # (t, new output)
    phase: str = "heat-up"
    reached_at: float | None = None  # when the heat-up ended
    relay_at: float | None = None
    settled_since: float = math.inf  # cycles count from the first switch down after this
    bias: float | None = None
    low: float = 0.0
    high: float = 0.0
    stopped: str | None = None
    last: Progress | None = None
    _settle_from: int = 0  # index of the first period of the hold
    _rescaled: bool = False
    _level: float = 0.0
    fits: FitStart[Progress] = fit_in_thread
    _asked: tuple[float, Future[Progress]] | None = None
    _final_at: float | None = None
    NAME = "relay"
    RECORDS = ("times", "pvs", "duties", "switches")

    def period(self, record: PeriodRecord) -> None:
        if not self._recorded(record):
            return
        pv = record.pv
        if self.ambient is None and pv is not None:
            if pv > self.setpoint - ROOM_BELOW_C:
                self._finish(
                    f"the water starts at {pv:.1f} °C, within {ROOM_BELOW_C:g} °C of the "
                    "setpoint: it cannot stand for the room's temperature, which K needs; "
                    "give --ambient",
                    record.t,
                )
                return
            self.ambient = pv
        if pv is None:
            return
        if self.phase == "heat-up":
            if pv >= self.setpoint - REACHED_C:
                self.phase, self.reached_at = "settle", record.t
                self._settle_from = len(self.times)
            return
        assert self.reached_at is not None
        if record.t - self.reached_at >= MAX_AT_SETPOINT_S:
            self._finish(f"{MAX_AT_SETPOINT_S / 60:g} min at the setpoint", record.t)
        elif self.phase == "relay" and pv > self.setpoint + RUNAWAY_C:
            self._finish(
                f"PV {pv:.2f} °C, {RUNAWAY_C:g} °C above the setpoint: the relay's low output "
                f"({self.low:g} %) still heats the tun (the hold's duty was not its bias)",
                record.t,
            )
        elif self.phase == "settle":
            if record.t - self.reached_at >= SETTLE_S:
                self._start_relay(record.t, pv)
        elif self._level == self.high and pv >= self.setpoint + self.hysteresis:
            self._switch(self.low, record.t)
            self._ask_fit(record.t)
        elif self._level == self.low and pv <= self.setpoint - self.hysteresis:
            self._switch(self.high, record.t)
            self._rescale_once(record.t)

    def _start_relay(self, t: float, pv: float) -> None:
        self.bias = statistics.fmean(self.duties[self._settle_from :])
        if self.amplitude is None:
            tun = self.daemon.config.tun
            self.amplitude = amplitude_for(
                tun.element_watts, tun.litres, self.daemon.config.control.dead_time
            )
        self.low, self.high = levels(self.bias, self.amplitude, self._max_output())
        self.phase, self.relay_at, self.settled_since = "relay", t, t
        self._switch(self.high if pv < self.setpoint else self.low, t)

    def _max_output(self) -> float:
        return self.daemon.config.control.max_output

    def _switch(self, level: float, t: float) -> None:
        self._level = level
        self.switches.append((t, level))
        self.daemon.set_manual(level)

    def _rescale_once(self, t: float) -> None:
        """At the first switch up after a full cycle: a swing too far from the target
        (past RESCALE_ABOVE_C, or under half the target) rescales P, once."""
        ups = [s for s, level in self.switches if level == self.high]
        if self._rescaled or len(ups) < 2 or self.amplitude is None or self.bias is None:
            return
        self._rescaled = True
        swing = max(
            abs(pv - self.setpoint)
            for s, pv in zip(self.times, self.pvs, strict=True)
            if s >= ups[-2] and pv is not None
        )
        if swing > RESCALE_ABOVE_C or swing < TARGET_SWING_C / 2:
            scale = (TARGET_SWING_C - self.hysteresis) / max(swing - self.hysteresis, 1e-3)
            self.amplitude = min(max(MIN_AMPLITUDE, round(self.amplitude * scale)), MAX_AMPLITUDE)
            self.low, self.high = levels(self.bias, self.amplitude, self._max_output())
            self.settled_since = t
            self._switch(self.high, t)

    def _evaluate(self, progress: Progress, t: float) -> None:
        """At a fit of the cycles to a switch down (a cycle's end), taken at `t`: say it,
        and stop when the cycles and the fit say so."""
        self.last = progress
        if self.on_progress is not None:
            self.on_progress(progress)
        found, tuned = progress.ultimate, progress.tuned
        period_s = self.daemon.config.control.period
        if found and consistent(found) and tuned is not None and fit_good(tuned, period_s):
            self._finish(CYCLES_GOOD, t, progress)

    def progress(self, t: float) -> Progress:
        """The cycles and the fit now, from every period since the heat-up ended."""
        at = 0.0 if self.reached_at is None else t - self.reached_at
        pv = next((pv for pv in reversed(self.pvs) if pv is not None), None)
        if self.relay_at is None or self.amplitude is None:
            return Progress(at, pv, self.phase, None, None, "the relay has not started")
        found = ultimate(
            cycles(self.switches, self.times, self.pvs, self.high, self.settled_since),
            0.5 * (self.high - self.low),
            self.hysteresis,
            self.daemon.config.control.period,
        )
        tuned, problem = None, None
        config = self.daemon.config
        try:
            tuned = tune.from_series(
                self.pvs[self._settle_from :],
                self.duties[self._settle_from :],
                config.control.period,
                self.ambient,
                config.tun.element_watts,
                config.tun.litres,
            )
        except tune.TuneError as error:
            problem = str(error)
        return Progress(at, pv, self.phase, found, tuned, problem)


def start(experiment: RelayExperiment, interrupts: tuple[type[BaseException], ...]) -> None:
    """Run the test: the heat-up in auto towards the setpoint, then the hold and the relay."""
    daemon = experiment.daemon
    daemon.set_setpoint(experiment.setpoint)
    daemon.set_auto()
    run(experiment, interrupts, heater_off=False)


def write(experiment: RelayExperiment, path: Path) -> str:
    """Write the fit's settings into the config file: never after an alarm or an interrupt,
    nor from a fit short of the goals (`fit_good`). The settings are the fit's alone, so a
    test that ran out of time before two cycles settled (θ of minutes) may still write."""
    why = experiment.stopped or "not run"
    if why.startswith(ABORTED):
        raise tune.TuneError(f"{path} left as it is: the relay test was stopped by {why}")
    last = experiment.last
    period_s = experiment.daemon.config.control.period
    if last is None or last.tuned is None or not fit_good(last.tuned, period_s):
        raise tune.TuneError(
            f"{path} left as it is: the relay test stopped ({why}) without a fit within "
            f"±{100 * GOAL_RELATIVE:g} % at 2σ"
        )
    return tune.write_config(path, last.tuned.recommended)


def progress_line(progress: Progress) -> str:
    """One line a cycle: time at the setpoint, PV, Ku and Pu, the model with one σ."""
    head = f"relay +{clock_text(progress.at_setpoint)}"
    if progress.pv is not None:
        head += f"  PV {progress.pv:.2f} °C"
    found = progress.ultimate
    if found is None:
        head += "  too few settled cycles"
    else:
        head += (
            f"  {found.cycles} cycles: Pu {found.pu:.0f}±{found.pu_sd:.0f} s  "
            f"Ku {found.ku:.3g}±{found.ku_sd:.2g} %/°C"
        )
    tuned = progress.tuned
    if tuned is None:
        return f"{head}  no fit yet: {progress.problem}"
    return f"{head}  {estimates(tuned)}"


def result_json(experiment: RelayExperiment) -> dict[str, Any]:
    last = experiment.last
    result: dict[str, Any] = {
        "stopped": experiment.stopped,
        "stop_rule": STOP_RULE,
        "setpoint": experiment.setpoint,
        "hysteresis": experiment.hysteresis,
        "amplitude": experiment.amplitude,
        "bias": experiment.bias,
        "levels": [experiment.low, experiment.high],
        "ambient": experiment.ambient,
        "at_setpoint_s": None if last is None else last.at_setpoint,
        "problem": None if last is None else last.problem,
        "ultimate": None,
    }
    if last is not None and last.ultimate is not None:
        result["ultimate"] = {**dataclasses.asdict(last.ultimate), "method": ULTIMATE_METHOD}
    if last is not None and last.tuned is not None:
        result.update(tune.tuned_json(last.tuned))
        m = last.tuned.model
        ku, pu = ultimate_point(m.gain, m.tau, m.dead_time)
        result["model_ultimate"] = {"ku": ku, "pu": pu}
        implied = implied_foptd(m.gain, last.ultimate)
        if implied is not None:
            result["from_ultimate"] = {"K": m.gain, "tau": implied[0], "theta": implied[1]}
    return result


def result_lines(experiment: RelayExperiment) -> list[str]:
    last = experiment.last
    lines = [f"relay test stopped: {experiment.stopped}; the heater is off"]
    if last is None or experiment.relay_at is None:
        return [*lines, "nothing measured: the relay never started"]
    lines.append(
        f"relay {experiment.low:.1f} ↔ {experiment.high:.1f} % (bias {experiment.bias:.1f} %), "
        f"hysteresis ±{experiment.hysteresis:g} °C around {experiment.setpoint:g} °C, "
        f"{clock_text(last.at_setpoint)} at the setpoint; room {experiment.ambient:.1f} °C"
    )
    found = last.ultimate
    if found is None:
        lines.append("too few settled cycles for Ku and Pu")
    else:
        lines += [
            f"{found.cycles} settled cycles: period {found.period:.0f} s, amplitude a "
            f"{found.amplitude:.3f} °C, d {found.d:g} %",
            f"  Pu {found.pu:.0f} ± {found.pu_sd:.0f} s (4θ, θ {found.dead_time:.0f} s)",
            f"  Ku {found.ku:.4g} ± {found.ku_sd:.2g} %/°C (πd/(2(a − ε)); the describing "
            f"function's 4d/(π·√(a² − ε²)): {found.ku_df:.4g})",
        ]
    if last.tuned is None:
        return [*lines, f"no model: {last.problem}"]
    m = last.tuned.model
    ku, pu = ultimate_point(m.gain, m.tau, m.dead_time)
    lines.append(f"  the fitted model's own: Ku {ku:.4g} %/°C, Pu {pu:.0f} s (phase −180°)")
    implied = implied_foptd(m.gain, found)
    if implied is not None:
        lines.append(
            f"  the FOPTD with the fit's K and the measured Ku, Pu: τ {implied[0]:.0f} s, "
            f"θ {implied[1]:.0f} s"
        )
    lines += ["", *tune.tuned_lines(last.tuned)]
    return lines
