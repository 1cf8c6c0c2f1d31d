"""`hermsd tune FILE` on the tun family: the model from a brew day against each tun's physics.

Each tun of hermsd.sim.tuns.FAMILY runs its brew day through the daemon with the default
config (its litres and watts set, as a brewer would), logged to MCAP; the identification
(hermsd.commissioning.tune.from_log, as `hermsd tune FILE` runs it) gets the log of the
heat-up plus a 30 min hold: the periods up to 30 min after PV first reaches setpoint − 0.5 °C.

The true model of a physical tun, independent of the fitting code:
- K = P/(100·UA) °C/%, τ = C/UA with C = 4186·litres J/K (the linear losses only);
- Θ: the physical tun is a transport delay L, the water's lag τ and the sensor's own lag
  T_s in series. Its step response after the delay is K·(1 − (τ·e^(−t/τ) − T_s·e^(−t/T_s))
  /(τ − T_s)); once e^(−t/T_s) has died out it is exactly the FOPTD response with the same
  K and τ and the dead time Θ = L + τ·ln(τ/(τ − T_s)) (≈ L + T_s). That FOPTD is the one the
  heat-up's long tail pins down, so it is the truth the fit is held to. PV is the mean of a
  control period's readings, which adds about half a period (2.5 s) to what a log shows.
- With the lid off, evaporation adds a loss that grows steeply with the temperature (0.28 kW
  from a 40 cm pot at 66 °C): no single K and τ describe the tun over a heat-up. What the
  controller (its feed-forward: the duty that holds the setpoint) and the supervisor (the
  loss it expects at the hold) need is the static gain at the hold, so that is the truth:
  K = P/(100·(UA + evap(66 °C)/(66 − ambient))) and τ = C over the same loss per kelvin
  (K/τ = P/(100·C), the element's rate, whatever the loss). The linear K of the walls alone,
  P/(100·UA), is given beside it. (The incremental gain, P/(100·(UA + d evap/dT)), is another
  22 % lower on the open 120 L pot; the predictive controller's observer takes that
  small-signal rest as a bias.)

Goals (issue 13): K and τ within ±10 %, Θ within ±20 s.

`hermsd tune step` on the same family, from a cold start (the water at the room's
temperature), with its defaults (step output from tun.litres and tun.element_watts, limit
the setpoint): the experiment's duration (baseline included) and its errors against the same
truth, beside the brew-day log the FILE method needed for the same tun.

The brew day after `--write`: each tun's step test, and separately its ordinary day 1's
whole log read by `hermsd tune FILE`, written (`--write`) into a copy of the shipped config
(the tun's litres and watts set, as a brewer would), then the robustness bench's brew day on
that file with `control.learn: off` and an empty state directory, so that the written model
is what runs; judged by the robustness bench's day-2 goals (bench/robustness.py).

    uv run --group bench python bench/tuning.py [--write] [--jobs 2]

`hermsd tune relay` on the same family, from a cold start, with its defaults, beside
CraftBeerPi 4's PIDAutotune (bench/peers.py) through the same daemon: durations, K, τ, θ
errors, and Ku, Pu against the tun's own ultimate point (`--relay`: this table only).

    uv run --group bench python bench/tuning.py --relay [--write]
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import math
import multiprocessing
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import sections  # bench/sections.py, beside this file
from peers import CraftBeerPiAutotune  # bench/peers.py, beside this file
from robustness import DAY_2, SHIPPED, _cell, missed  # bench/robustness.py, beside this file

from hermsd.commissioning import relay, step_response, tune
from hermsd.commissioning.simulated import simulated_step_test
from hermsd.config import read
from hermsd.config import schema as config
from hermsd.config.file import at_once
from hermsd.log import reader
from hermsd.runtime.assemble import assemble
from hermsd.runtime.daemon import Daemon
from hermsd.runtime.period import PeriodRecord
from hermsd.safety.limits import Alarm
from hermsd.sim import scenario
from hermsd.sim.clock import VirtualClock
from hermsd.sim.hlt import evaporation_w, pot_surface_m2
from hermsd.sim.tuns import FAMILY, TunSpec
from hermsd.sim.world import build_world

HOLD_S = 1800.0
BAND_C = 0.5
SETPOINT_C = 66.0


@dataclasses.dataclass(frozen=True, slots=True)
class Truth:
    gain: float  # °C/%, static at the hold: (66 − room)/(the duty that holds 66 °C)
    tau: float  # s, C over the loss per kelvin at the hold (so K/τ = P/(100·C))
    dead_time: float  # s
    linear_gain: float  # °C/%, the walls' losses alone, P/(100·UA) (= gain with the lid on)


def truth(spec: TunSpec) -> Truth:
    """The tun's FOPTD at the hold (see the module's docstring): with the lid off, the loss
    per kelvin is UA + evaporation(66 °C)/(66 − room), its static (secant) value."""
    evaporation = (
        evaporation_w(SETPOINT_C, spec.ambient_c, pot_surface_m2(spec.litres))
        if spec.lid_off
        else 0.0
    )
    ua = spec.ua_w_per_k
    ua_at_hold = ua + evaporation / (SETPOINT_C - spec.ambient_c)
    tau = tune.WATER_J_PER_L_K * spec.litres / ua_at_hold
    lag = spec.sensor_lag_s
    return Truth(
        gain=spec.element_watts / (100.0 * ua_at_hold),
        tau=tau,
        dead_time=spec.transport_delay_s + tau * math.log(tau / (tau - lag)),
        linear_gain=spec.element_watts / (100.0 * ua),
    )


def heat_up_and_hold(log: reader.Log) -> reader.Log | None:
    """The log up to HOLD_S after PV first reached the band below the setpoint (None: never)."""
    reached = next(
        (
            t
            for p, t in zip(log.periods, log.elapsed, strict=True)
            if p.pv is not None and p.pv >= p.setpoint - BAND_C
        ),
        None,
    )
    if reached is None:
        return None
    n = sum(1 for t in log.elapsed if t <= reached + HOLD_S)
    return dataclasses.replace(log, periods=log.periods[:n], elapsed=log.elapsed[:n])


def brew_day_log(spec: TunSpec, directory: Path) -> reader.Log:
    """The whole log of the tun's brew day with the default config (an ordinary day 1)."""
    scenario.run(spec.brew_day(), spec.config(config.DEFAULT), log_dir=directory)
    return reader.load(sorted(directory.glob("*.mcap")))


def trimmed(spec: TunSpec, log: reader.Log) -> reader.Log:
    """The heat-up and hold of the day's log."""
    cut = heat_up_and_hold(log)
    if cut is None:
        raise SystemExit(f"{spec.name}: the brew day never reached the band (an alarm?)")
    return cut


HEADER = (
    "| tun | log used (s) | K true (linear) | K fit ±2σ | K err | τ true (s) | τ fit ±2σ | τ err "
    "| Θ true (s) | Θ fit ±2σ | Θ err (s) | RMS (°C) | stated | goals |",
    "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
)


def row(spec: TunSpec, tuned: tune.Tuned) -> tuple[str, bool]:
    """The table row of one tun, and whether it met the goals."""
    true, m, u = truth(spec), tuned.model, tuned.uncertainty
    k_err, tau_err = m.gain / true.gain - 1.0, m.tau / true.tau - 1.0
    theta_err = m.dead_time - true.dead_time
    ok = abs(k_err) <= 0.10 and abs(tau_err) <= 0.10 and abs(theta_err) <= 20.0
    hold = f" ({true.linear_gain:.3f})" if spec.lid_off else ""
    return (
        f"| {spec.name} | {m.fit_s:.0f} | {true.gain:.3f}{hold} "
        f"| {m.gain:.3f} ±{2 * u.gain:.3f} | {100 * k_err:+.1f} % "
        f"| {true.tau:.0f} | {m.tau:.0f} ±{2 * u.tau:.0f} | {100 * tau_err:+.1f} % "
        f"| {true.dead_time:.1f} | {m.dead_time:.0f} ±{2 * u.dead_time:.0f} "
        f"| {theta_err:+.1f} | {m.rms:.3f} | {tuned.confidence.split(':')[0]} "
        f"| {'met' if ok else 'missed'} |",
        ok,
    )


def step_test(spec: TunSpec) -> step_response.StepExperiment:
    """`hermsd tune step --simulate` with its defaults on the tun, from the room's temperature."""
    experiment, _, _ = simulated_step_test(spec.config(config.DEFAULT), spec.plant())
    step_response.run(experiment, (KeyboardInterrupt,))
    return experiment


STEP_HEADER = (
    "| tun | output (%) | stopped | experiment (min) | brew-day log (min) | ratio | K err "
    "| K err (linear) | τ err | Θ err (s) | Θ 10 % rule (s) | Θ line (s) | goals |",
    "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
)
GOAL_MINUTES = 90.0


def step_row(
    spec: TunSpec, experiment: step_response.StepExperiment, log_s: float
) -> tuple[str, bool]:
    """The row of one tun's step test, and whether it met the goals (errors and ≤ 90 min)."""
    true, last = truth(spec), experiment.last
    if last is None or last.tuned is None or experiment.stopped is None:
        return f"| {spec.name} | {experiment.output} | {experiment.stopped} | no fit |", False
    m = last.tuned.model
    minutes = (last.elapsed + step_response.BASELINE_S) / 60.0
    k_err, tau_err = m.gain / true.gain - 1.0, m.tau / true.tau - 1.0
    theta_err = m.dead_time - true.dead_time
    ok = (
        abs(k_err) <= 0.10
        and abs(tau_err) <= 0.10
        and abs(theta_err) <= 20.0
        and minutes <= GOAL_MINUTES
    )
    linear = f"{100 * (m.gain / true.linear_gain - 1):+.1f} %" if spec.lid_off else "="
    ol = last.open_loop

    def seconds(value: float | None) -> str:
        return "–" if value is None else f"{value - true.dead_time:+.0f}"

    return (
        f"| {spec.name} | {experiment.output:g} | {experiment.stopped} | {minutes:.0f} "
        f"| {log_s / 60:.0f} | {minutes * 60 / log_s:.2f} | {100 * k_err:+.1f} % | {linear} "
        f"| {100 * tau_err:+.1f} % | {theta_err:+.1f} | {seconds(ol.dead_time_10)} "
        f"| {seconds(ol.dead_time_line)} | {'met' if ok else 'missed'} |",
        ok,
    )


def true_ultimate(spec: TunSpec) -> tuple[float, float]:
    """Ku (%/°C) and Pu (s) of the tun's own transfer function, K·e^(−Ls)/((τs + 1)(T_s·s + 1))
    (lid off: K and τ of the hold, the evaporation linearised as its mean loss): the
    frequency where L·ω + atan(τω) + atan(T_s·ω) = π, found by halving an interval on ω
    (not the code under test), and 1/|G| there."""
    true = truth(spec)
    gain, tau = true.gain, true.tau
    delay, lag = spec.transport_delay_s, spec.sensor_lag_s

    def phase(w: float) -> float:
        return delay * w + math.atan(tau * w) + math.atan(lag * w)

    low, high = 1e-9, math.pi / delay
    while high - low > 1e-12 * high:
        low, high = (
            (low, 0.5 * (low + high))
            if phase(0.5 * (low + high)) > math.pi
            else (0.5 * (low + high), high)
        )
    w = 0.5 * (low + high)
    return math.sqrt((1 + (tau * w) ** 2) * (1 + (lag * w) ** 2)) / gain, 2 * math.pi / w


def relay_test(spec: TunSpec) -> relay.RelayExperiment:
    """`hermsd tune relay --simulate` with its defaults, from the room's temperature."""
    cfg = spec.config(config.DEFAULT)
    clock = VirtualClock()
    world = build_world(cfg, clock, spec.plant())
    daemon = assemble(cfg, clock, world.sensor, world.outputs)
    experiment = relay.RelayExperiment(daemon, SETPOINT_C, fits=at_once)
    relay.start(experiment, (KeyboardInterrupt,))
    return experiment


@dataclasses.dataclass
class CraftBeerPiRun:
    """CraftBeerPi's autotune (bench/peers.py) driving the daemon's manual output each period
    on the reading it would have read last (its 5 s sample = the daemon's period)."""

    daemon: Daemon
    tuner: CraftBeerPiAutotune
    limit_s: float
    finished_at: float | None = None

    def period(self, record: PeriodRecord) -> None:
        if self.finished_at is not None or not record.readings:
            return
        if self.tuner.sample(record.readings[-1], record.t) or record.t >= self.limit_s:
            self.finished_at = record.t
            self.daemon.set_manual(0.0)
            self.daemon.stop()
        else:
            self.daemon.set_manual(self.tuner.output)

    def alarm(self, alarm: Alarm) -> None:
        if alarm.raised and self.finished_at is None:
            self.finished_at = alarm.at
            self.tuner.state = f"alarm {alarm.kind}"
            self.daemon.stop()


CBPI_LIMIT_S = 8 * 3600.0


def craftbeerpi_test(spec: TunSpec) -> CraftBeerPiRun:
    """CraftBeerPi's PIDAutotune with its defaults (output step 100 %, lookback 60 s) from the
    room's temperature to 66 °C, through the same daemon, sensor and heater."""
    cfg = spec.config(config.DEFAULT)
    clock = VirtualClock()
    world = build_world(cfg, clock, spec.plant())
    daemon = assemble(cfg, clock, world.sensor, world.outputs)
    tuner = CraftBeerPiAutotune(SETPOINT_C)
    tuner.start(0.0)
    peer = CraftBeerPiRun(daemon, tuner, CBPI_LIMIT_S)
    daemon.listeners.append(peer)
    daemon.set_manual(tuner.output)
    with daemon:
        daemon.run()
    return peer


RELAY_HEADING = "## Tuning by a relay test (`hermsd tune relay`) and CraftBeerPi's autotune"
RELAY_HEADER = (
    "| tun | P (%) | stopped | heat-up (min) | at SP (min) | swing (°C) | K err | K err (linear) "
    "| τ err | θ true (s) | θ err | goals | Ku true | Pu true (s) | Ku relay (err) "
    "| Ku DF (err) | Pu relay (err) | τ, θ from Ku, Pu (err) | Ku model (err) "
    "| CBPi Ku (err) | CBPi Pu (err) | CBPi (h) |",
    "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
)
RELAY_GOAL_RELATIVE = 0.15
RELAY_GOAL_MINUTES = 45.0


def relay_row(
    spec: TunSpec, experiment: relay.RelayExperiment, peer: CraftBeerPiRun
) -> tuple[str, dict[str, float], bool]:
    """The row of one tun's relay test and CraftBeerPi's, the errors, whether goals were met."""
    true, last = truth(spec), experiment.last
    ku_true, pu_true = true_ultimate(spec)
    if last is None or last.tuned is None or experiment.reached_at is None:
        return f"| {spec.name} | no fit: {experiment.stopped} |", {}, False
    m = last.tuned.model
    heat_up = (experiment.reached_at - experiment.times[0]) / 60.0
    at_sp = last.at_setpoint / 60.0
    swing = max(
        abs(pv - SETPOINT_C)
        for t, pv in zip(experiment.times, experiment.pvs, strict=True)
        if pv is not None and experiment.relay_at is not None and t >= experiment.relay_at
    )
    gain, tau = true.gain, true.tau
    errors = {
        "K": m.gain / gain - 1.0,
        "tau": m.tau / tau - 1.0,
        "theta": m.dead_time / true.dead_time - 1.0,
    }
    ok = all(abs(e) <= RELAY_GOAL_RELATIVE for e in errors.values()) and at_sp <= RELAY_GOAL_MINUTES
    ku_model, _ = relay.ultimate_point(m.gain, m.tau, m.dead_time)
    errors["Ku model"] = ku_model / ku_true - 1.0
    found = last.ultimate
    ku_relay = ku_df = pu_relay = implied = "–"
    if found is not None:
        errors["Ku relay"] = found.ku / ku_true - 1.0
        errors["Ku DF"] = found.ku_df / ku_true - 1.0
        errors["Pu relay"] = found.pu / pu_true - 1.0
        ku_relay = f"{found.ku:.0f} ({100 * errors['Ku relay']:+.0f} %)"
        ku_df = f"{found.ku_df:.0f} ({100 * errors['Ku DF']:+.0f} %)"
        pu_relay = f"{found.pu:.0f} ({100 * errors['Pu relay']:+.0f} %)"
        foptd = relay.implied_foptd(m.gain, found)
        if foptd is not None:
            errors["τ from Ku, Pu"] = foptd[0] / tau - 1.0
            errors["θ from Ku, Pu"] = foptd[1] / true.dead_time - 1.0
            implied = (
                f"{foptd[0]:.0f} ({100 * errors['τ from Ku, Pu']:+.0f} %), "
                f"{foptd[1]:.0f} ({100 * errors['θ from Ku, Pu']:+.0f} %)"
            )
    tuner = peer.tuner
    cbpi_hours = (peer.finished_at or math.nan) / 3600.0
    if tuner.state == "succeeded":
        errors["CBPi Ku"] = tuner.ku / ku_true - 1.0
        errors["CBPi Pu"] = tuner.pu / pu_true - 1.0
        cbpi_ku = f"{tuner.ku:.0f} ({100 * errors['CBPi Ku']:+.0f} %)"
        cbpi_pu = f"{tuner.pu:.0f} ({100 * errors['CBPi Pu']:+.0f} %)"
    else:
        cbpi_ku = cbpi_pu = tuner.state
    lin = f"{100 * (m.gain / true.linear_gain - 1):+.1f} %" if spec.lid_off else "="
    return (
        f"| {spec.name} | {experiment.amplitude:g} | {experiment.stopped} | {heat_up:.0f} "
        f"| {at_sp:.0f} | {swing:.2f} | {100 * errors['K']:+.1f} % | {lin} "
        f"| {100 * errors['tau']:+.1f} % "
        f"| {true.dead_time:.0f} | {100 * errors['theta']:+.1f} % | {'met' if ok else 'missed'} "
        f"| {ku_true:.0f} | {pu_true:.0f} | {ku_relay} | {ku_df} | {pu_relay} | {implied} "
        f"| {ku_model:.0f} ({100 * errors['Ku model']:+.0f} %) | {cbpi_ku} | {cbpi_pu} "
        f"| {cbpi_hours:.1f} |",
        errors,
        ok,
    )


def relay_section() -> str:
    started = time.perf_counter()
    table, met = [*RELAY_HEADER], 0
    worst: dict[str, float] = {}
    for spec in FAMILY:
        print(f"{spec.name} (relay)…", file=sys.stderr, flush=True)
        line, errors, ok = relay_row(spec, relay_test(spec), craftbeerpi_test(spec))
        table.append(line)
        met += ok
        for key, value in errors.items():
            worst[key] = max(worst.get(key, 0.0), abs(value))
    summary = ", ".join(f"{key} {100 * value:.0f} %" for key, value in worst.items())
    return "\n".join(
        [
            "Each tun of the family, from the room's temperature, runs `hermsd tune relay` with "
            "its defaults "
            "through the daemon "
            "on the simulator: heat-up in auto, 5 min hold (its mean duty is the bias), then "
            f"the relay ±P around the bias with hysteresis ±{relay.HYSTERESIS_C:g} °C (P for a "
            f"~{relay.TARGET_SWING_C:g} °C swing from the config's litres, watts and dead time, "
            "rescaled once after the first cycle; stop: "
            f"{relay.STOP_RULE}). The room's temperature is the first PV (the water stood in "
            "it). K, τ, θ errors against the truth of the tables above (K, τ: with the lid "
            "off the hold's, evaporation included; K err the linear one beside it); at SP: "
            "from PV first within 0.25 °C of the setpoint to the stop; swing: the largest "
            "|PV − SP| during the relay. Ku true, Pu true: the tun's own transfer function "
            "K·e^(−Ls)/((τs+1)(T_s·s+1)) at phase −180°, solved in this script. Ku relay: "
            "the describing function 4d/(π·√(a² − ε²)) on the settled cycles; Ku model: the "
            "fitted FOPTD's own ultimate point. CBPi: CraftBeerPi 4's PIDAutotune "
            "(bench/peers.py) with its defaults (output step 100 %, lookback 60 s, noise "
            "band 0.5 °C), from the same cold start through the same daemon; (h) its whole run. "
            f"Goals: K, τ, θ within ±{100 * RELAY_GOAL_RELATIVE:g} % in ≤ "
            f"{RELAY_GOAL_MINUTES:g} min at the setpoint.",
            "",
            f"Goals met on {met} of {len(FAMILY)}. Worst |error|: {summary}.",
            "",
            *table,
            "",
            "Every tun meets the goals through the fit (K, τ, θ from the hold and the cycles "
            "with the room's temperature): the hold pins K, the cycles θ and K/τ. The "
            "thermowells' τ comes out 12–13 % long (a sensor lag is not a dead time; the step "
            "test sees the same). The lid-off tuns' K is the hold's (evaporation included), "
            "20–25 % below the linear losses': the gain that matters at the setpoint. Ku and "
            "Pu from the cycles (exact for a lag-dominant tun) land within −10..+9 % and "
            "−12..+7 % of the tun's own; the describing function on the same cycles says "
            "36–55 % too little, for the PV is a triangle and the hysteresis's 4ε/s stretches "
            "the period. With θ ≥ 240 s (far sensor, thermowell 120 L) a cycle lasts ~20 min "
            "(4θ plus the hysteresis's 4ε/s): 40 min of relay after the 5 min hold give fewer "
            "than the two cycles Ku and Pu need, and the first one, from the config's "
            "dead-time guess (115 s), swings past ±0.5 °C (0.55 °C) before P is rescaled; "
            "the fit is within the goals there all the same.",
            "",
            "CraftBeerPi's autotune switches 0 ↔ 100 % (its output step 100 % around an "
            "initial 0), yet divides by the output step in Ku = 4·100/(π·a): twice the "
            "relay's real half-span of 50 %. Its ±0.5 °C band, uncorrected, and the triangular "
            "PV pull the describing function's Ku down by about as much, so its Ku lands "
            "between −39 % and +18 % of the truth by two errors cancelling, not by a sound "
            "measurement. Its Pu is the relay's own, asymmetric period (full power up, the "
            "hold's loss down, the 1 °C band in between): 1.8 to 12 times the ultimate "
            "period, so every rule that uses Pu (Ti, Td) is off by as much. It stops at the "
            "fifth peak, 0.8 to 4.3 h after a cold start.",
            "",
            f"Run time {time.perf_counter() - started:.0f} s.",
            "",
        ]
    )


# -- the brew day after `--write` ----------------------------------------------------------------

AFTER_HEADER = (
    "| tun | day 1 | written (K °C/%, τ s, θ s, room °C) | K err (hold) | overshoot °C "
    "| after water °C | settle ×min | recovery ×min (floor) | jump % | in band % | edges/h "
    "| alarms | day-2 goals |",
    "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
)
STEP, FILE, FILE_ROOM = "tune step", "tune FILE (day 1's log)", "tune FILE --ambient"
METHODS = (STEP, FILE, FILE_ROOM)


def brewers_copy(spec: TunSpec, directory: Path) -> Path:
    """The shipped config file with the tun's litres and watts, as a brewer edits it."""
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / "hermsd.yaml"
    path.write_bytes(SHIPPED.read_bytes())
    tune.write_config(
        path,
        {
            "tun.litres": spec.litres,
            "tun.element_watts": spec.element_watts,
            "tun.lid": "off" if spec.lid_off else "on",
        },
    )
    return path


@dataclasses.dataclass(frozen=True, slots=True)
class DayAfter:
    """One tun's brew day after one method's `--write`: its table row and verdict."""

    row: str
    verdict: str  # "not written", "met", "floor" (missed only the recovery, at its floor), "missed"


def day_after(
    spec: TunSpec, method: str, write: Callable[[Path], str], directory: Path
) -> DayAfter:
    """`write` the tune's result into a copy of the config, run the brew day on it with
    nothing learned, and give its row and verdict on the day-2 goals."""
    path = brewers_copy(spec, directory)
    try:
        write(path)
    except tune.TuneError as error:
        why = str(error).split(": ", 1)[1]
        return DayAfter(
            f"| {spec.name} | {method} | not written ({why}) |" + " – |" * 10, "not written"
        )
    written = read.load(path)
    c = written.control
    off = dataclasses.replace(written, control=dataclasses.replace(c, learn="off"))
    with tempfile.TemporaryDirectory(prefix="hermsd-state-") as state:
        s = scenario.run(spec.brew_day(), off, state_dir=Path(state)).summary
    misses = missed(s, DAY_2)
    verdict = "met" if not misses else "missed"
    if misses == ["recovery"] and s["recovery_ratio"] <= s["recovery_floor_ratio"]:
        verdict = "floor"
    alarms = ", ".join(f"{a['kind']} at {a['at_s']:.0f} s" for a in s["alarms"]) or "0"
    hold = truth(spec).gain
    return DayAfter(
        f"| {spec.name} | {method} | {c.model_gain:g}, {c.model_tau:g}, {c.dead_time:g}, "
        f"{c.model_ambient:g} | {100 * (c.model_gain / hold - 1):+.1f} % "
        f"| {_cell(s['heatup_overshoot_c'], 3)} | {_cell(s['upset_overshoot_c'], 3)} "
        f"| {_cell(s['settle_ratio'], 3)} "
        f"| {_cell(s['recovery_ratio'], 3)} ({_cell(s['recovery_floor_ratio'], 3)}) "
        f"| {_cell(s['max_output_jump'], 1)} | {_cell(s['held_in_band_pct'], 2)} "
        f"| {_cell(s['ssr_edges_per_hour'], 0)} | {alarms} "
        f"| {'met' if not misses else 'missed: ' + ', '.join(misses)} |",
        verdict,
    )


def write_from_log(day: reader.Log, room: float | None, path: Path) -> str:
    """`hermsd tune FILE... [--ambient room] --write path` on the day's log."""
    return tune.write_tuned(path, tune.from_log(day, room))


@dataclasses.dataclass(frozen=True, slots=True)
class TunRows:
    """One tun's rows of every table, and what they count towards."""

    from_log: dict[bool, tuple[str, bool]]  # by whether the room's temperature was given
    step: tuple[str, bool]
    step_minutes: float | None
    after: list[DayAfter]


def measure(index: int) -> TunRows:
    """Every method on tun `index`, and the brew day after each one's `--write`."""
    spec = FAMILY[index]
    print(f"{spec.name}…", file=sys.stderr, flush=True)
    with tempfile.TemporaryDirectory() as name:
        directory = Path(name)
        day = brew_day_log(spec, directory / "day 1")
        log = trimmed(spec, day)
        experiment = step_test(spec)
        minutes = None
        if experiment.last is not None:
            minutes = (experiment.last.elapsed + step_response.BASELINE_S) / 60
        from_log = {
            given: row(spec, tune.from_log(log, spec.ambient_c if given else None))
            for given in (False, True)
        }
        after = [
            day_after(
                spec, STEP, lambda path: step_response.write(experiment, path), directory / "s"
            ),
            *(
                day_after(
                    spec,
                    method,
                    functools.partial(write_from_log, day, room),
                    directory / method,
                )
                for method, room in ((FILE, None), (FILE_ROOM, spec.ambient_c))
            ),
        ]
        return TunRows(
            from_log,
            step_row(spec, experiment, log.elapsed[-1] - log.elapsed[0]),
            minutes,
            after,
        )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="update bench/RESULTS.md")
    parser.add_argument("--jobs", type=int, default=2, help="processes (default 2)")
    parser.add_argument("--relay", action="store_true", help="the relay test's table only")
    parser.add_argument(
        "--only", metavar="TEXT", help="the tuns whose name contains TEXT (no --write)"
    )
    args = parser.parse_args()
    if args.only is not None and args.write:
        parser.error("--only measures part of the family: the tables are not written from it")
    chosen = [i for i, spec in enumerate(FAMILY) if args.only is None or args.only in spec.name]
    if args.relay:
        relay_text = relay_section()
        print(relay_text)
        if args.write:
            sections.write(RELAY_HEADING, relay_text)
        return 0
    started = time.perf_counter()
    tables: dict[bool, list[str]] = {False: [*HEADER], True: [*HEADER]}
    met = {False: 0, True: 0}
    step_table, step_met, step_minutes = [*STEP_HEADER], 0, []
    after_table = [*AFTER_HEADER]
    verdicts: dict[str, list[str]] = {method: [] for method in METHODS}
    with multiprocessing.get_context("fork").Pool(args.jobs) as pool:
        for rows in pool.imap(measure, chosen):
            step_table.append(rows.step[0])
            step_met += rows.step[1]
            if rows.step_minutes is not None:
                step_minutes.append(rows.step_minutes)
            for given, (line, ok) in rows.from_log.items():
                tables[given].append(line)
                met[given] += ok
            for method, after in zip(METHODS, rows.after, strict=True):
                after_table.append(after.row)
                verdicts[method].append(after.verdict)
                print(after.row, flush=True)
    out = [
        "Each tun of the family logs its brew day (default config, its litres and watts) and "
        "`hermsd tune` identifies it from the "
        "heat-up plus a 30 min hold (up to 30 min after PV first reached 65.5 °C). True K "
        "and τ are the tun's first-order model at the hold, what the controller's "
        "feed-forward and the supervisor's loss watch use: K the static gain, (66 − room)/"
        "(the duty that holds 66 °C), = P/(100·UA) with the lid on, and τ = 4186·litres over "
        "the same loss per kelvin (so K/τ = P/(100·C) whatever the loss); with the lid off "
        "the evaporation at 66 °C counts in it, and 'K true (linear)' beside it is the walls' "
        "alone (the incremental gain there, P/(100·(UA + d evap/dT)), is another 22 % "
        "lower on the open 120 L pot: the predictive controller's observer takes that "
        "small-signal rest as a bias, and K/τ, the rate it acts on, is exact either way). "
        "Θ = L + τ·ln(τ/(τ − T_s)) (the FOPTD that matches "
        "the lagged step response's tail; see the script); a log shows about half a period "
        "(2.5 s) more, from the PV's averaging, and the fit gives θ in whole periods. Goals: "
        "K and τ ±10 %, Θ ±20 s. '±' is the fit's stated 2σ, 'stated' its verdict (good: "
        "every 2σ within the goals and the RMS ≤ 0.04 °C). The open pots' config says "
        "`tun.lid: off`: their fit has an evaporation term E·g(PV), g the vapour pressure "
        "of water over that at 66 °C (Magnus: the shape is physics, only E is fitted), and "
        "gives the model at the hold (hermsd.commissioning.identify.TunModel.at_hold).",
        "",
        f"### The room's temperature fitted (`hermsd tune FILE`): goals met on {met[False]} of "
        f"{len(FAMILY)}",
        "",
        *tables[False],
        "",
        "### The room's temperature given (`hermsd tune FILE --ambient C`): goals met on "
        f"{met[True]} of {len(FAMILY)}",
        "",
        *tables[True],
        "",
        "A heat-up much shorter than τ (the strong elements: 2920 s against τ = 14707 s on "
        "the 30 L 5.5 kW tun) hardly bends; with the room's temperature free the fit then "
        "trades it against K and τ together (K/τ stays within a few %), and the stated 2σ, "
        "whose model part comes from moving θ by a period, says so ('poor'). Given the room's "
        "temperature, the hold pins K. The open pots, fitted with their evaporation, come "
        "within 1.5 % of K and τ at the hold and 5 s of Θ, RMS 0.015–0.016 °C, like a lidded "
        "tun; fitted as first order (before `tun.lid`) they were 'poor': RMS 0.055–0.135 °C, "
        "τ 20–25 % short against the linear truth, θ down to 0 (the garage).",
        "",
        f"Run time {time.perf_counter() - started:.0f} s on {args.jobs} processes (the three "
        "tuning sections).",
    ]
    text = "\n".join(out) + "\n"
    step_text = "\n".join(
        [
            "Each tun of the family, from the room's temperature, runs `hermsd tune step` with "
            "its defaults through the daemon on the "
            "simulator (2 min baseline, then the output that reaches 66 °C in about 90 min at "
            "the water's linear rate, at least 20 %; stop: "
            f"{step_response.STOP_RULE}). Errors against the same truth as the table above "
            "(the model at the hold: lid off, the gain at 66 °C with "
            "the evaporation; K err (linear) against the walls' alone). Experiment: baseline "
            "plus step; brew-day log: what the FILE "
            "method above needed for the same tun (heat-up plus a 30 min hold); ratio = "
            "experiment / log. Θ 10 % rule and Θ line: seed 001 §4.1's two dead times on the "
            "rise so far, as errors against the truth. Goals: K and τ ±10 %, Θ ±20 s, ≤ 90 min.",
            "",
            f"Goals met on {step_met} of {len(FAMILY)}; experiment "
            f"{min(step_minutes):.0f} to {max(step_minutes):.0f} min.",
            "",
            *step_table,
            "",
            "The stated 2σ says 'good' on every tun, and the settling rule keeps the lagging "
            "sensors running until τ stops drifting (the thermowells: 88 and 58 min). The open "
            "tuns (`tun.lid: off`) are fitted with their evaporation, its shape known and its "
            "scale fitted, and the K and τ given are those at the setpoint: within 1.8 to "
            "5.5 % and 1.4 to 4.1 %, in 62 to 72 min (the step ends at 32 to 45 °C). A first-"
            "order fit of the same kind of step was 7 to 14 % off the linear K and 15 to 17 % "
            "above the hold's (the two misses before), for where a step ends the evaporation "
            "is a fifth to a third of what it is at 66 °C; the extra parameter widens the "
            "stated 2σ, so these steps run 14 to 20 min longer before they are called good. "
            "Only the config's word lets the term in: on a lidded tun's step it finds up to "
            "95 °C of evaporation that is not there (the section 'an evaporation term in the "
            "step's fit'). Seed 001's own "
            "dead times bracket the truth: the 10 % rule (of the rise so far) comes late by "
            "minutes, the 10–90 % regression line, on a rise that already bends, meets T1 "
            "early; the fit's θ is what is reported and written.",
            "",
        ]
    )
    after_text = "\n".join(
        [
            "Each tun's step test above (tune step), and separately its ordinary day 1 (the "
            "default config, learning on, an empty "
            "state directory: the robustness bench's day 1) whose whole log `hermsd tune FILE` "
            "reads (the fit stops at the cold water; without and with `--ambient`, the room's "
            "temperature), written with `--write` into a copy of "
            "config/hermsd.yaml with the tun's litres and watts; then the robustness bench's "
            "brew day (bench/robustness.py: ambient → 66 °C, a tenth of the volume of 15 °C "
            "water at 4 h) on that file with `control.learn: off` and an empty state "
            "directory, so that the written model (control.model_*, model_litres) is the one "
            "the controller and the supervisor start from; the controller still measures the "
            "heat-up's rate and dead time within the day, as it always does. Day-2 goals (the "
            "robustness bench's): overshoot ≤ 0.1 °C on the heat-up and after the water, "
            "settle ≤ ×1.01, recovery ≤ ×1.02, jump ≤ 10 %, 100 % in band, ≤ 720 edges/h, no "
            "alarm. K err (hold): the written K against the tun's gain at 66 °C (evaporation "
            "included; the linear gain with the lid on). Recovery (floor): the least recovery "
            "a controller acting once a 5 s period can show (see the robustness section).",
            "",
            " ".join(
                f"After `{name} --write`: written on {len(v) - v.count('not written')} of "
                f"{len(v)} tuns, every day-2 goal met on {v.count('met')}, all but the recovery "
                f"on {v.count('floor')} (at its floor), missed otherwise on {v.count('missed')}."
                for name, v in (
                    ("tune step", verdicts[STEP]),
                    ("tune FILE", verdicts[FILE]),
                    ("tune FILE --ambient C", verdicts[FILE_ROOM]),
                )
            ),
            "",
            "Edges an hour are counted in the whole control periods of the hold (a count to "
            "its ends, mid-period, read up to two edges too many: 720.4/h on the garage tun at "
            "one edge a window). `tune FILE` writes nothing from a fit it calls poor: with the "
            "room's temperature left free, the heat-ups too short against τ to pin K (`--ambient` "
            "pins it). The open tuns' written K is now within 5.5 % of the gain at the hold "
            "(+15 to +17 % before).",
            "",
            f"Run time {time.perf_counter() - started:.0f} s on {args.jobs} processes (the "
            "three tuning sections).",
            "",
            *after_table,
            "",
        ]
    )
    print(text)
    print(step_text)
    print(after_text)
    if args.write:
        sections.write("## Tuning from a brew day's log (`hermsd tune FILE`)", text)
        sections.write("## Tuning by a step test (`hermsd tune step`)", step_text)
        sections.write("## Tuning: the brew day after `tune --write`", after_text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
