"""hermsd tune relay: the relay analysis by hand, and the test through the daemon on simulated
tuns (heater off and config unchanged after an alarm or Ctrl-C)."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from test_step_response import powered_after

from hermsd.cli import main
from hermsd.commissioning import relay, tune
from hermsd.config import read
from hermsd.config import schema as config_module
from hermsd.config.file import at_once
from hermsd.runtime.assemble import assemble
from hermsd.runtime.period import PeriodRecord
from hermsd.safety.limits import Alarm
from hermsd.sim.clock import VirtualClock
from hermsd.sim.world import World, build_world

SHIPPED = Path(__file__).parent.parent / "config" / "hermsd.yaml"
NOISE = {"noise_c": 0.03, "seed": 3}
SEED_TUN = {"model": "foptd", "gain_c_per_pct": 1.689, "tau_s": 14961.0, "dead_time_s": 115.0}


def test_the_ultimate_point_of_a_foptd_by_hand() -> None:
    # τ = 100 s, ω = 0.01 rad/s: atan(τω) = π/4, so θ = (π − π/4)/ω = 235.619 s puts the phase
    # at −π there; |G| = K/√2, so Ku = √2/K; Pu = 2π/ω = 628.319 s.
    theta = 0.75 * math.pi / 0.01
    ku, pu = relay.ultimate_point(2.0, 100.0, theta)
    assert ku == pytest.approx(math.sqrt(2) / 2.0, rel=1e-9)
    assert pu == pytest.approx(628.3185307, rel=1e-9)


def test_the_inversion_gives_the_foptd_back() -> None:
    # The hand example above, inverted: K = 2, Ku = √2/2, Pu = 200π → τ = 100 s, θ = 75π s.
    tau, theta = relay.foptd_from_ultimate(2.0, math.sqrt(2) / 2.0, 200 * math.pi)
    assert tau == pytest.approx(100.0, rel=1e-9)
    assert theta == pytest.approx(75 * math.pi, rel=1e-9)
    # Round trip on the seed's tun: a lag-dominant FOPTD, whose ultimate point is nearly that
    # of an integrator with delay (ωu ≈ π/(2θ), Ku ≈ τ·ωu/K): 4θ = 460 s and 140.
    ku, pu = relay.ultimate_point(1.689, 14961.0, 115.0)
    assert pu == pytest.approx(4 * 115.0, rel=0.02)
    assert ku == pytest.approx(14961.0 * math.pi / (2 * 115.0) / 1.689, rel=0.02)
    assert relay.foptd_from_ultimate(1.689, ku, pu) == pytest.approx((14961.0, 115.0), rel=1e-6)


def test_a_gain_too_small_for_the_ultimate_point_is_refused() -> None:
    with pytest.raises(relay.RelayError, match=r"K·Ku = 0\.5 ≤ 1"):
        relay.foptd_from_ultimate(1.0, 0.5, 300.0)


def test_the_cycles_of_an_integrator_with_dead_time_under_the_relay() -> None:
    """The exact limit cycle of PV' = a*·(u(t − θ) − hold), written out by hand: θ = 60 s,
    a*·d = s = 0.002 °C/s either way, ε = 0.0625 °C. Past a switch PV runs on for θ, so
    a = ε + s·θ = 0.1825 °C and each half lasts θ + (2ε + s·θ)/s = 182.5 s. Its true
    ultimate point (a*·e^(−θs)/s at −180°: ωu = π/(2θ)) is Pu = 240 s, Ku = ωu/a* = 130.9
    %/°C with d = 10 % (a* = 2e-4); the describing function says 4d/(π·√(a² − ε²)) = 74.2."""
    theta, slope, band, d, setpoint = 60.0, 0.002, 0.0625, 10.0, 66.0
    half = theta + (2 * band + slope * theta) / slope
    period = 2 * half

    def pv_at(t: float) -> float:
        phase = t % period  # 0: the switch up, at SP − ε while falling
        if phase < theta:
            return setpoint - band - slope * phase
        if phase < half + theta:
            return setpoint - band - slope * theta + slope * (phase - theta)
        return setpoint + band + slope * theta - slope * (phase - half - theta)

    times = [float(t) for t in range(int(6 * period))]
    pvs: list[float | None] = [pv_at(t) for t in times]
    switches = sorted(
        [(k * period, 20.0) for k in range(6)] + [(k * period + half, 0.0) for k in range(6)]
    )
    found = relay.cycles(switches, times, pvs, 20.0, 0.0)
    assert len(found) == 5  # from each switch down, at 182.5 … 2007.5 s, to the next
    for cycle in found:
        assert cycle.period == pytest.approx(365.0)
        assert cycle.high_s == pytest.approx(182.5)
        assert cycle.amplitude == pytest.approx(0.1825, abs=0.001)  # 1 s samples
    result = relay.ultimate(found, d, band)
    assert result is not None
    assert result.dead_time == pytest.approx(60.0, rel=0.01)
    assert result.pu == pytest.approx(240.0, rel=0.01)
    assert result.ku == pytest.approx(130.9, rel=0.01)
    assert result.ku_df == pytest.approx(74.2, rel=0.01)
    assert result.period == pytest.approx(365.0)
    assert relay.consistent(result)
    # 5 s of the cycle's 60 s dead time the loop's own: the tun's θ is 55 s, Pu 220 s, and
    # with the same a* = 2e-4, Ku = (π/110)/2e-4 = 142.8 %/°C.
    tun = relay.ultimate(found, d, band, loop_delay=5.0)
    assert tun is not None
    assert tun.pu == pytest.approx(220.0, rel=0.01)
    assert tun.ku == pytest.approx(142.8, rel=0.01)


def test_the_default_amplitude_and_the_levels() -> None:
    # 90 L, 3 kW: a* = 3000/(100·4186·90) = 7.963e-5 °C/(%·s); θ 115 s:
    # (0.3 − 0.0625)/(7.963e-5·115) = 25.9 → 26 %.
    assert relay.amplitude_for(3000, 90, 115) == 26.0
    # 30 L, 1.5 kW, θ 30 s: a* = 1.194e-4; 0.2375/(1.194e-4·30) = 66.3 → at most 50 %.
    assert relay.amplitude_for(1500, 30, 30) == 50.0
    assert relay.amplitude_for(11000, 150, 600) == relay.MIN_AMPLITUDE  # 2.3 % → 10 %
    assert relay.levels(30.0, 10.0, 100.0) == (20.0, 40.0)
    assert relay.levels(7.0, 10.0, 100.0) == (0.0, 20.0)  # shifted up: the span stays 2·P
    assert relay.levels(95.0, 10.0, 100.0) == (85.0, 100.0)


def experiment_on(plant: dict[str, Any]) -> tuple[relay.RelayExperiment, World, VirtualClock]:
    clock = VirtualClock()
    cfg = config_module.DEFAULT
    world = build_world(cfg, clock, {**plant, **NOISE}, history=True)
    daemon = assemble(cfg, clock, world.sensor, world.outputs)
    return relay.RelayExperiment(daemon, 66.0, fits=at_once), world, clock


def test_the_relay_finds_the_seed_tun_within_the_goals() -> None:
    experiment, world, _ = experiment_on(SEED_TUN)
    relay.start(experiment, (KeyboardInterrupt,))
    last = experiment.last
    assert last is not None and last.tuned is not None and last.ultimate is not None
    assert experiment.stopped == relay.CYCLES_GOOD
    m = last.tuned.model
    assert abs(m.gain / 1.689 - 1) <= 0.15
    assert abs(m.tau / 14961 - 1) <= 0.15
    assert abs(m.dead_time / 115 - 1) <= 0.15
    assert last.at_setpoint <= 45 * 60
    assert not world.circuit.powered
    # θ/τ = 0.008: the ultimate point is an integrator's with delay within 1 %,
    # Pu = 4θ = 460 s, Ku = τ·π/(2θ·K) = 121.0 %/°C.
    assert last.ultimate.pu == pytest.approx(460.0, rel=0.15)
    assert last.ultimate.ku == pytest.approx(121.0, rel=0.15)
    swing = max(
        abs(pv - 66.0)
        for t, pv in zip(experiment.times, experiment.pvs, strict=True)
        if pv is not None and experiment.relay_at is not None and t >= experiment.relay_at
    )
    assert swing < 0.5


class _MidRelay:
    """Calls `action` in the loop 10 min into the relay (a sensor lost, or Ctrl-C's
    KeyboardInterrupt as SIGINT's handler would raise it)."""

    def __init__(self, experiment: relay.RelayExperiment, action: Callable[[], None]) -> None:
        self.experiment, self.action = experiment, action
        self.at: float | None = None

    def period(self, record: PeriodRecord) -> None:
        started = self.experiment.relay_at
        if self.at is None and started is not None and record.t >= started + 600.0:
            self.at = record.t
            self.action()

    def alarm(self, alarm: Alarm) -> None:
        pass


def test_an_alarm_mid_relay_leaves_the_heater_off_and_the_config_unchanged(
    tmp_path: Path,
) -> None:
    experiment, world, _ = experiment_on(SEED_TUN)
    mid = _MidRelay(experiment, lambda: world.chip.set_fault("gone"))
    experiment.daemon.listeners.append(mid)
    relay.start(experiment, (KeyboardInterrupt,))
    assert mid.at is not None
    assert experiment.stopped is not None and experiment.stopped.startswith("alarm sensor")
    assert not powered_after(world, mid.at + 2 * config_module.DEFAULT.sensor.read_interval)
    assert not world.circuit.powered
    assert experiment.last is not None and experiment.last.tuned is not None  # kept
    path = tmp_path / "hermsd.yaml"
    path.write_bytes(SHIPPED.read_bytes())
    with pytest.raises(tune.TuneError, match="left as it is: the relay test was stopped by alarm"):
        relay.write(experiment, path)
    assert path.read_bytes() == SHIPPED.read_bytes()


def _interrupt() -> None:
    raise KeyboardInterrupt


def test_ctrl_c_mid_relay_leaves_the_heater_off_and_the_config_unchanged(tmp_path: Path) -> None:
    experiment, world, _ = experiment_on(SEED_TUN)
    mid = _MidRelay(experiment, _interrupt)
    experiment.daemon.listeners.append(mid)
    relay.start(experiment, (KeyboardInterrupt,))
    assert mid.at is not None
    assert experiment.stopped == "interrupted (KeyboardInterrupt)"
    assert world.circuit.power_changes[-1][1] is False
    assert not world.circuit.powered
    lines = relay.result_lines(experiment)
    assert lines[0] == "relay test stopped: interrupted (KeyboardInterrupt); the heater is off"
    path = tmp_path / "hermsd.yaml"
    path.write_bytes(SHIPPED.read_bytes())
    with pytest.raises(tune.TuneError, match="stopped by interrupted"):
        relay.write(experiment, path)
    assert path.read_bytes() == SHIPPED.read_bytes()


def test_tune_relay_simulated_writes_the_model(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    path = tmp_path / "hermsd.yaml"
    path.write_bytes(SHIPPED.read_bytes())
    code = main(
        ["tune", "relay", "--simulate", "--config", str(path), "--write", str(path), "--json"]
    )
    out, err = capsys.readouterr()
    assert code == 0
    result = json.loads(out)
    assert result["stopped"] == relay.CYCLES_GOOD
    assert abs(result["model"]["gain"] / 1.689 - 1) <= 0.15
    assert result["ultimate"]["cycles"] >= relay.MIN_CYCLES
    assert "+  model_gain:" in result["written"]["diff"]
    assert "relay +0:" in err  # progress lines
    assert read.load(path).control.model_gain == result["recommended"]["control.model_gain"]


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--hysteresis", "0.01"], "--hysteresis 0.01: the band must be 0.0625"),
        (["--amplitude", "5"], "--amplitude 5: the relay's ± output must be 10 to 50 %"),
        (["--setpoint", "200"], "--setpoint 200: the relay holds above 0 °C"),
        (["--limit", "50"], "--limit: for `hermsd tune step` only"),
    ],
)
def test_bad_relay_options_are_one_line(
    capsys: pytest.CaptureFixture[str], argv: list[str], message: str
) -> None:
    assert main(["tune", "relay", "--simulate", *argv]) == 2
    assert message in capsys.readouterr().err


def test_relay_options_are_refused_without_relay(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["tune", "step", "--simulate", "--hysteresis", "0.1"]) == 2
    assert "--hysteresis: for `hermsd tune relay` only" in capsys.readouterr().err


def test_a_relay_stopped_before_a_good_fit_writes_nothing(tmp_path: Path) -> None:
    """Stopped (here: by the time limit) with no fit: the file stays as it is."""
    path = tmp_path / "hermsd.yaml"
    path.write_bytes(SHIPPED.read_bytes())
    experiment, _, _ = experiment_on(SEED_TUN)
    experiment.stopped = "45 min at the setpoint"
    with pytest.raises(tune.TuneError, match="without a fit within ±15 % at 2σ"):
        relay.write(experiment, path)
    assert path.read_bytes() == SHIPPED.read_bytes()


def test_a_low_output_that_still_heats_stops_the_relay() -> None:
    """Both relay outputs above the hold's duty (a bias taken from a hold that was still
    climbing): PV runs away upwards; the test stops 1 °C above the setpoint, heater off."""
    experiment, world, _ = experiment_on(SEED_TUN)

    def both_high() -> None:
        experiment.low = experiment.high

    experiment.daemon.listeners.insert(0, _MidRelay(experiment, both_high))
    relay.start(experiment, (KeyboardInterrupt,))
    assert experiment.stopped is not None
    assert experiment.stopped.startswith("PV 67.0")
    assert "above the setpoint: the relay's low output" in experiment.stopped
    assert not world.circuit.powered


def test_warm_water_without_the_rooms_temperature_is_refused() -> None:
    """K rests on the room's temperature; water 60 °C at the start cannot stand for it."""
    experiment, world, _ = experiment_on({**SEED_TUN, "start_c": 60.0})
    relay.start(experiment, (KeyboardInterrupt,))
    assert experiment.stopped is not None
    assert experiment.stopped.startswith("the water starts at 60.0 °C, within 10 °C of the")
    assert experiment.stopped.endswith("give --ambient")
    assert not world.circuit.powered
    assert experiment.relay_at is None
