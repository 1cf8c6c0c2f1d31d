"""What the daemon learns of its tun: from clean spells only, kept across restarts and crashes,
refused when it cannot be a tun, and replayable bit for bit.

The tun is the seed's FOPTD (K 1.689 °C/%, τ 14961 s, θ 115 s, room 20 °C) run through the
real daemon on the virtual clock; the config's prior (a 90 L, 3 kW physical tun) heats
30 % slower than that, so a heat-up measures something other than the prior.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import random
import shutil
import statistics
from pathlib import Path

import pytest

from hermsd.cli import commands as cli
from hermsd.config import read
from hermsd.config import schema as config_module
from hermsd.control import factory, laws, learning, predictive
from hermsd.control.learning import Estimate, LearnedModel, Learner, ModelStore
from hermsd.control.pid import PlantModel
from hermsd.control.watches import HeatUpFit
from hermsd.log import reader, replay
from hermsd.log.mcap_file import LogFile
from hermsd.log.topics import MODEL_TOPIC
from hermsd.sim import scenario
from hermsd.sim.scenario import Event, Scenario
from hermsd.sim.world import simulated_daemon

K, TAU, THETA = 1.689, 14961.0, 115.0
RATE = 100.0 * K / TAU  # °C/s at full power
# Heat-up (~4800 s) and the 30 min of hold the learner waits for, with room to spare.
DAY = 8000.0


def day(*events: Event) -> Scenario:
    return Scenario(name="learn", duration=DAY, events=events)


def learned(state: Path) -> LearnedModel | None:
    model, problem = ModelStore(state).load()
    assert problem is None
    return model


@pytest.fixture(scope="module")
def learned_day(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """(state directory, log directory) of a clean day that learned."""
    state = tmp_path_factory.mktemp("state")
    logs = tmp_path_factory.mktemp("logs")
    scenario.run(day(), state_dir=state, log_dir=logs)
    return state, logs


def test_a_clean_day_learns_the_tun(learned_day: tuple[Path, Path]) -> None:
    model = learned(learned_day[0])
    assert model is not None
    assert model.rate == pytest.approx(RATE, rel=0.03)
    # A period's PV is its mean, half a period old: the fitted dead time is θ + Ts/2.
    assert model.dead_time == pytest.approx(THETA + 2.5, abs=5.0)
    # The holding duty 46/K % at 66 °C against the room of 20 °C: loss = rate·duty/100/46.
    # Fitted to the heat balance, not the hold's mean duty: the approach's last 0.25 °C of rise
    # in the first half hour is no loss (the mean duty made it 1.6 % too high).
    assert 1.0 / model.loss == pytest.approx(TAU, rel=0.01)
    assert model.litres == config_module.DEFAULT.tun.litres


def test_the_next_start_uses_what_was_learned(
    learned_day: tuple[Path, Path], tmp_path: Path
) -> None:
    state = tmp_path / "state"
    shutil.copytree(learned_day[0], state)  # the learned day stays as it was for the others
    model = learned(state)
    assert model is not None
    restarted = simulated_daemon(config_module.DEFAULT, math.inf, models=ModelStore(state))
    assert restarted.model == model.plant_model(config_module.DEFAULT.tun.litres)
    result = scenario.run(day(), state_dir=state, keep_records=True)
    # The heat-up now starts on the learned rate: no overshoot, full power to the band.
    assert result.summary["overshoot_c"] <= 0.1
    assert result.summary["settle_ratio"] <= 1.01


def test_replay_verifies_and_shows_a_day_that_learned(learned_day: tuple[Path, Path]) -> None:
    log = reader.load(sorted(learned_day[1].glob("*.mcap")))
    verification = replay.verify(log.entries)
    assert verification.mismatch is None and verification.verified > 1000
    messages = [item["message"] for item in replay.summarise(log)["learning"]]
    stored = [
        message["learned"]
        for path in sorted(learned_day[1].glob("*.mcap"))
        for topic, _, message in LogFile(path).messages([MODEL_TOPIC])
        if topic == MODEL_TOPIC
    ]
    assert stored == [dataclasses.asdict(learned(learned_day[0]))]
    assert any(m.startswith("heat-up measured: ") for m in messages)
    assert any(m.startswith("learned the tun: ") for m in messages)


def test_replay_verifies_a_day_on_a_learned_model(
    learned_day: tuple[Path, Path], tmp_path: Path
) -> None:
    state = tmp_path / "state"
    shutil.copytree(learned_day[0], state)
    scenario.run(day(), state_dir=state, log_dir=tmp_path / "logs")
    log = reader.load(sorted((tmp_path / "logs").glob("*.mcap")))
    assert replay.verify(log.entries).mismatch is None
    summary = replay.summarise(log)
    model = learned(learned_day[0])
    assert model is not None
    assert summary["tun_model"]["dead_time"] == model.dead_time


@pytest.mark.parametrize(
    "interruption",
    [
        Event(5400.0, "mode", "manual"),
        Event(5400.0, "sensor", ("nack", None), lasts=10.0),
        Event(5400.0, "config", {"control": {"kc": 100.0}}),
        # During the heat-up's fit (the PV rises 1 → 3 °C from 200 to 380 s), a reload
        # that leaves the controller running: its measurement spans the reload.
        Event(250.0, "config", {"safety": {"stuck_time": 4000.0}}),
    ],
    ids=["manual", "sensor fault", "reload", "reload during the heat-up"],
)
def test_nothing_is_learned_across_a_manual_faulty_or_reloaded_spell(
    interruption: Event, tmp_path: Path
) -> None:
    # In the hold, before its 30 min are up: the heat-up before it no longer counts.
    events = [interruption]
    if interruption.kind == "mode":
        events.append(Event(5500.0, "mode", "auto"))
    scenario.run(day(*events), state_dir=tmp_path)
    assert learned(tmp_path) is None


def test_pinned_or_off_learns_nothing(tmp_path: Path) -> None:
    for setting in ("pinned", "off"):
        scenario.run(
            Scenario(duration=DAY, config={"control": {"learn": setting}}), state_dir=tmp_path
        )
        assert learned(tmp_path) is None


def test_off_ignores_what_was_learned(learned_day: tuple[Path, Path]) -> None:
    off = read.from_dict(read.to_dict(config_module.DEFAULT) | {"control": {"learn": "off"}})
    model = learned(learned_day[0])
    assert model is not None
    prior = factory.prior_model(off)
    assert prior.dead_time == THETA and model.dead_time != THETA


def test_learned_values_survive_a_crash_mid_write(
    learned_day: tuple[Path, Path], tmp_path: Path
) -> None:
    model = learned(learned_day[0])
    assert model is not None
    store = ModelStore(tmp_path)
    store.save(model)
    # A crash between writing the temporary file and renaming it leaves a torn temporary.
    (tmp_path / (learning.LEARNED_FILE + ".tmp")).write_text('{"rate": 0.0', encoding="utf-8")
    assert ModelStore(tmp_path).load() == (model, None)


@pytest.mark.parametrize(
    ("text", "said"),
    [
        ("{not json", "not valid JSON"),
        ("[" * 100_000 + "]" * 100_000, "nested too deeply"),
        ('{"rate": 1e400}', "out of range"),
        ('{"rate": NaN}', "not a number JSON allows"),
        ("[1, 2]", "not a learned model"),
        ('{"rate": "fast"}', "not a learned model"),
    ],
)
def test_a_damaged_store_is_said_and_the_prior_used(tmp_path: Path, text: str, said: str) -> None:
    (tmp_path / learning.LEARNED_FILE).write_text(text, encoding="utf-8")
    model, problem = ModelStore(tmp_path).load()
    assert model is None and problem is not None and said in problem


def test_a_store_that_is_not_a_regular_file_is_said(tmp_path: Path) -> None:
    os.mkfifo(tmp_path / learning.LEARNED_FILE)  # would hang a plain open()
    model, problem = ModelStore(tmp_path).load()
    assert model is None and problem is not None and "not a regular file" in problem


def test_forget_deletes_the_store(learned_day: tuple[Path, Path], tmp_path: Path) -> None:
    model = learned(learned_day[0])
    assert model is not None
    store = ModelStore(tmp_path)
    store.save(model)
    assert store.forget() is True
    assert store.load() == (None, None)
    assert store.forget() is False


def test_an_implausible_hold_is_refused_and_said() -> None:
    # A hold at 66 °C with the element off throughout: no losses at all, not a tun of water.
    learner = Learner(litres=90.0, ambient=20.0, period=5.0)
    learner.heat_up(HeatUpFit(RATE, THETA))
    # The window opens once the duty of a dead time before it is known (θ/Ts periods and the
    # window's first), and closes HOLD_S later.
    periods = round(THETA / 5.0) + 1 + int(learning.HOLD_S / 5.0)
    estimates = [learner.period(66.0, 66.0, 0.0, noise=1.0) for _ in range(periods)]
    assert estimates[-2] is None
    estimate = estimates[-1]
    assert estimate is not None and estimate.model is None
    assert estimate.refused is not None and "time constant" in estimate.refused


def test_the_loss_is_the_heat_balance_not_the_approachs_duty() -> None:
    # The last 0.25 °C of an approach inside the window, on more than the holding duty, each
    # period's PV by the FOPTD's balance (implicit in the loss, the duty a dead time late):
    # the heat the rise took is no loss. The window's mean duty makes the loss 3 % too high.
    ts, lag, loss, ambient = 5.0, round(THETA / 5.0), 1.0 / TAU, 20.0
    hold = 100.0 * loss * (66.0 - ambient) / RATE
    learner = Learner(litres=90.0, ambient=ambient, period=ts)
    learner.heat_up(HeatUpFit(RATE, THETA))
    duties = [hold + 4.0 * 0.99**k for k in range(2000 + lag)]
    pv, estimate = 65.76, None
    for k in range(2000):
        pv = (pv + ts * (RATE * duties[k] / 100.0 + loss * ambient)) / (1.0 + ts * loss)
        estimate = learner.period(66.0, pv, duties[k + lag], noise=1.0)
        if estimate is not None:
            break
    assert estimate is not None and estimate.model is not None
    assert estimate.model.loss == pytest.approx(loss, rel=1e-6)


def test_water_in_the_hold_starts_the_hold_anew() -> None:
    # The FOPTD's balance as above, holding, with 0.2 °C of cold water at period 200: the
    # window that held it would read its heat as loss; the one after it is exact again.
    ts, loss, ambient = 5.0, 1.0 / TAU, 20.0
    hold = 100.0 * loss * (66.0 - ambient) / RATE
    learner = Learner(litres=90.0, ambient=ambient, period=ts)
    learner.heat_up(HeatUpFit(RATE, THETA))
    pv, estimate, k = 65.99, None, 0
    while estimate is None and k < 2000:
        pv = (pv + ts * (RATE * hold / 100.0 + loss * ambient)) / (1.0 + ts * loss)
        pv -= 0.2 if k == 200 else 0.0
        estimate = learner.period(66.0, pv, hold, noise=1.0)
        k += 1
    assert estimate is not None and estimate.model is not None
    assert k > 200 + learning.HOLD_S / ts  # from after the water
    assert estimate.model.loss == pytest.approx(loss, rel=1e-6)


def _noisy_hold(noise: float | None, water_at: int | None) -> tuple[Estimate | None, int]:
    """A hold of the FOPTD's balance with the truth at 66.12 °C, read 5 times a period with
    0.06 °C of noise truncated to the LM92's 0.0625 °C, the period's PV their mean; `water_at`:
    the period 0.3 °C of cold water comes (still in the hold's band). `noise`: the learner's
    noise scale, None for the one a predictive controller measures of the same readings.
    The estimate within three hours, and the periods taken."""
    ts, loss, ambient = 5.0, 1.0 / TAU, 20.0
    hold = 100.0 * loss * (66.12 - ambient) / RATE
    rng = random.Random(2)
    law = laws.create("predictive", kc=120.0, ti=800.0, ts=ts, model=PlantModel())
    learner = Learner(litres=90.0, ambient=ambient, period=ts)
    learner.heat_up(HeatUpFit(RATE, THETA))
    truth, estimate, k = 66.12, None, 0
    while estimate is None and k < 3 * 720:
        truth = (truth + ts * (RATE * hold / 100.0 + loss * ambient)) / (1.0 + ts * loss)
        truth -= 0.3 if k == water_at else 0.0
        lsb = 0.0625
        readings = [math.floor((truth + rng.gauss(0.0, 0.06)) / lsb) * lsb for _ in range(5)]
        predictive.readings_seen(law, readings)
        scale = predictive.noise_scale(law) if noise is None else noise
        estimate = learner.period(66.0, statistics.fmean(readings), hold, noise=scale)
        k += 1
    return estimate, k


def test_a_noisy_sensors_hold_is_learned_and_its_water_still_seen() -> None:
    # A period's mean of 5 readings scatters with sd √((0.06² + 0.0625²/12)/5) = 0.029 °C; the
    # highest of a minute's 12 lies 2 LSB above the latest many times an hour: at the bench's
    # fall these three hours hold no 30 min whole (6 seeds of 8). The scatter measured as the
    # daemon measures it (a reading's sd about its period's mean 0.0687 °C, docs/sensors.md:
    # 1.72× the bench's 0.04) raises the fall to 0.215 °C: the hold is learned exactly, and
    # 0.3 °C of water still starts it anew.
    law = laws.create("predictive", kc=120.0, ti=800.0, ts=5.0, model=PlantModel())
    assert predictive.noise_scale(law) == 1.0  # nothing measured yet: the bench's
    assert _noisy_hold(1.0, None)[0] is None
    estimate, k = _noisy_hold(None, None)
    assert estimate is not None and estimate.model is not None
    assert estimate.model.loss == pytest.approx(1.0 / TAU, rel=0.02)
    assert k < (learning.HOLD_S + THETA) / 5.0 + 10  # the first hold
    estimate, k = _noisy_hold(None, 200)
    assert estimate is not None and estimate.model is not None
    assert k > 200 + learning.HOLD_S / 5.0  # from after the water


def test_an_implausible_store_is_refused(tmp_path: Path) -> None:
    bad = {"rate": 5.0, "loss": 1e-4, "dead_time": 100.0, "ambient": 20.0, "litres": 90.0}
    (tmp_path / learning.LEARNED_FILE).write_text(json.dumps(bad), encoding="utf-8")
    model, problem = ModelStore(tmp_path).load()
    assert model is None and problem is not None and "rate" in problem


def test_the_model_is_rescaled_to_the_configured_litres() -> None:
    # Twice the water: half the rate (same element), the loss rate by (½)^⅓ (surface ∝ V^⅔).
    model = LearnedModel(RATE, 1.0 / TAU, THETA, 20.0, 90.0)
    doubled = model.plant_model(180.0)
    assert doubled.rate == pytest.approx(RATE / 2.0, rel=1e-12)
    assert doubled.tau == pytest.approx(TAU * 2.0 ** (1.0 / 3.0), rel=1e-12)
    assert math.isclose(doubled.dead_time, THETA)


def test_the_forget_model_command(
    learned_day: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    shutil.copy(learned_day[0] / learning.LEARNED_FILE, tmp_path)
    assert cli.main(["forget-model", "--state", str(tmp_path)]) == 0
    assert "forgot" in capsys.readouterr().out
    assert not (tmp_path / learning.LEARNED_FILE).exists()
    assert cli.main(["forget-model", "--state", str(tmp_path)]) == 0
    assert "nothing learned" in capsys.readouterr().out


def test_forget_model_on_a_file_names_the_option_not_the_user(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    a_file = tmp_path / "hermsd.yaml"
    a_file.write_text("", encoding="utf-8")
    assert cli.main(["forget-model", "--state", str(a_file)]) == 2
    err = capsys.readouterr().err
    assert "--state names it" in err and "run as root" not in err
    assert err.count("\n") == 1


def test_the_learned_model_sets_the_supervisors_limits(
    learned_day: tuple[Path, Path], tmp_path: Path
) -> None:
    state = tmp_path / "state"
    shutil.copytree(learned_day[0], state)
    model = learned(state)
    assert model is not None
    restarted = simulated_daemon(config_module.DEFAULT, math.inf, models=ModelStore(state))
    unmeasured = simulated_daemon(config_module.DEFAULT, math.inf).supervisor.limits
    limits = restarted.supervisor.limits
    # Judged after 1.5 θ (θ ≈ 117.5 s measured) instead of the 300 s any tun may need; the
    # weakest rise 0.8·0.81·r/1.5 of the measured rate, not 0.8·0.81·r/2 of the configured.
    assert unmeasured.dead_time == 300.0
    assert limits.dead_time == pytest.approx(1.5 * (THETA + 2.5), abs=8.0)
    assert limits.heater_rise_rate == pytest.approx(0.8 * 0.81 * RATE / 1.5, rel=0.03)
    assert unmeasured.heater_rise_rate == pytest.approx(0.8 * 0.81 * 3000 / (90 * 4186) / 2)
    assert dict(limits.origins)["heater_rise_rate"] == "measured"
    # control.learn off: neither the controller nor the supervisor uses it.
    off = read.from_dict(read.to_dict(config_module.DEFAULT) | {"control": {"learn": "off"}})
    ignored = simulated_daemon(off, math.inf, models=ModelStore(state)).supervisor.limits
    assert ignored.dead_time == 300.0
    # A day on it logs the model its limits came from, and replay says so.
    scenario.run(day(), state_dir=state, log_dir=tmp_path / "logs")
    summary = replay.summarise(reader.load(sorted((tmp_path / "logs").glob("*.mcap"))))
    stored = model.plant_model(config_module.DEFAULT.tun.litres)
    fields = ("gain", "tau", "dead_time", "ambient")  # the FOPTD the limits are of
    assert summary["safety_tun_model"] == {k: getattr(stored, k) for k in fields}


def test_check_config_shows_the_limits_from_what_was_learned(
    learned_day: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "hermsd.yaml"
    path.write_text("tun: {litres: 90}\n", encoding="utf-8")
    assert cli.main(["check-config", str(path), "--state", str(learned_day[0])]) == 0
    out = capsys.readouterr().out
    assert "# safety limits in force (the tun as learned: full-power rate" in out
    assert "[measured]" in out
    path.write_text("control: {learn: 'off'}\n", encoding="utf-8")
    assert cli.main(["check-config", str(path), "--state", str(learned_day[0])]) == 0
    out = capsys.readouterr().out
    assert "# safety limits in force (nothing measured yet):" in out
    assert "[measured]" not in out


@pytest.mark.parametrize(("litres", "said"), [(0.0, "fill"), (-90.0, "fill"), (1e4, "fill")])
def test_a_store_with_an_impossible_fill_is_refused(
    tmp_path: Path, litres: float, said: str
) -> None:
    bad = {"rate": 0.008, "loss": 1 / 15000, "dead_time": 100.0, "ambient": 20.0, "litres": litres}
    (tmp_path / learning.LEARNED_FILE).write_text(json.dumps(bad), encoding="utf-8")
    model, problem = ModelStore(tmp_path).load()
    assert model is None and problem is not None and said in problem


# -- a model measured by `hermsd tune` (the control.model_* keys) ------------------------------


def test_a_foptd_maps_to_the_learned_quantities_and_back() -> None:
    # Seed 001's tun, measured at 90 L: rate 100·1.689/14961 = 0.0112893 °C/s at full power,
    # loss 1/14961 = 6.68404e-5 /s.
    measured = LearnedModel.from_plant(PlantModel(1.689, 14961.0, 115.0, 20.0), 90.0)
    assert measured.rate == pytest.approx(0.0112893, rel=1e-5)
    assert measured.loss == pytest.approx(6.68404e-5, rel=1e-5)
    assert (measured.dead_time, measured.ambient, measured.litres) == (115.0, 20.0, 90.0)
    *back, losses_measured = dataclasses.astuple(measured.plant_model(90.0))
    assert back == pytest.approx([1.689, 14961.0, 115.0, 20.0])
    assert losses_measured  # a measured model's losses are no prior's
    # With 45 L configured: rate ×2, loss ×2^⅓ (the wetted surface), so K = 1.689·2^⅔ =
    # 2.68112 °C/% and τ = 14961/2^⅓ = 11874.5 s; θ and the room unchanged.
    half = measured.plant_model(45.0)
    assert (half.gain, half.tau) == (
        pytest.approx(2.68112, rel=1e-5),
        pytest.approx(11874.5, rel=1e-5),
    )
    assert (half.dead_time, half.ambient) == (115.0, 20.0)


def with_control(**control: object) -> config_module.Config:
    return read.from_dict(
        read.to_dict(config_module.DEFAULT)
        | {"control": read.to_dict(config_module.DEFAULT)["control"] | control}
    )


TUNED = {"model_gain": 2.0, "model_tau": 12000.0, "dead_time": 90.0, "model_ambient": 18.0}


@pytest.mark.parametrize(
    ("learn", "litres", "source"),
    [
        ("on", None, "learned"),  # nothing measured by tune: what was learned
        ("on", 90.0, "learned"),  # on: the daemon's own, later measurement first
        ("pinned", 90.0, "measured"),  # pinned: what tune measured, as written
        ("pinned", None, "learned"),
        ("off", 90.0, "measured"),
        ("off", None, "prior"),
    ],
)
def test_learn_decides_between_the_learned_and_the_tuned_model(
    learned_day: tuple[Path, Path], learn: str, litres: float | None, source: str
) -> None:
    config = with_control(learn=learn, model_litres=litres, **TUNED)
    daemon = simulated_daemon(config, math.inf, models=ModelStore(learned_day[0]))
    assert daemon.model_choice.source == source
    if source == "measured":
        *foptd, _ = dataclasses.astuple(daemon.model)
        assert foptd == pytest.approx([2.0, 12000.0, 90.0, 18.0])
    measured = source != "prior"
    assert daemon.model.measured == measured
    assert (dict(daemon.supervisor.limits.origins)["loss_rate"] == "measured") == measured


def test_a_tuned_model_is_rescaled_to_the_configured_litres() -> None:
    config = with_control(learn="off", model_litres=45.0, **TUNED)  # DEFAULT's tun: 90 L
    daemon = simulated_daemon(config, math.inf)
    # Twice the water: rate ÷2 and loss ÷2^⅓, so K = 2·2^-⅔ = 1.25992 °C/%, τ = 12000·2^⅓.
    assert daemon.model.gain == pytest.approx(1.25992, rel=1e-5)
    assert daemon.model.tau == pytest.approx(15119.1, rel=1e-5)
    assert daemon.supervisor.limits.loss_per_k == pytest.approx(1.5 / 15119.1, rel=1e-5)


def test_check_config_shows_the_limits_from_a_tuned_model(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "hermsd.yaml"
    path.write_text(
        "control: {model_gain: 2, model_tau: 12000, dead_time: 90, model_litres: 90}\n",
        encoding="utf-8",
    )
    assert cli.main(["check-config", str(path)]) == 0
    out = capsys.readouterr().out
    assert "# safety limits in force (the tun as measured by hermsd tune" in out
    rows = {line[4:].split("  ")[0]: line for line in out.splitlines() if line.startswith("#   ")}
    # θ·1.5 = 135 s; 0.8·0.81·(100·2/12000 °C/s)/1.5 = 0.432 °C/min.
    assert rows["heat shows at the sensor within"].endswith(" 135 s  [measured]")
    assert rows["weakest heating at 80 %"].endswith(" 0.432 °C/min  [measured]")


def test_a_tuned_model_that_cannot_be_a_tun_is_a_config_error(tmp_path: Path) -> None:
    path = tmp_path / "hermsd.yaml"
    path.write_text("control:\n  model_tau: 100\n  model_litres: 90\n", encoding="utf-8")
    # 100·1.689/100 = 1.69 °C/s at full power: no element boils water that fast.
    with pytest.raises(config_module.ConfigError, match=r"yaml:3:.*model_litres: .*rate 1.69 °C/s"):
        read.load(path)
