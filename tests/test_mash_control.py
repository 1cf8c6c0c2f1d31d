"""The HERMS's outer loop in the daemon (`runtime/mash_control.py`): with a mash sensor fitted
the setpoint is the mash's, and the HLT law holds the HLT where the outer loop sets it.

The plant is `scenarios/herms-day.yaml`'s (a 90 L 3 kW HLT, 50 L and 12 kg mashed in at
38 °C, a 250 W/K coil at 6 L/min), on the virtual clock, without the stuck bed. The
supervisor does not count the coil's load yet: its heater watch, which takes the pump's first
pull on the HLT at full power for a dead element, is lengthened here (safety.heater_watch).
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import pytest
import yaml
from test_control import Inbox, status_of
from test_log_schemas import invalid
from test_mash_side import Periods

from hermsd.api.link import LoopLink, role_faults
from hermsd.cli import main
from hermsd.config.read import parse
from hermsd.control import laws
from hermsd.control.cascade import Decision
from hermsd.control.learning import LearnedModel, ModelStore
from hermsd.control.pid import Controller, PlantModel
from hermsd.log.reader import load
from hermsd.runtime.assemble import assemble
from hermsd.runtime.daemon import Daemon
from hermsd.runtime.mash_control import MashControl, coil_prior, mash_control
from hermsd.runtime.period import PeriodRecord
from hermsd.sim import scenario
from hermsd.sim.clock import VirtualClock
from hermsd.sim.mash import make_herms_plant
from hermsd.sim.world import World, build_world

ROOT = Path(__file__).resolve().parents[1]
HERMS_DAY = yaml.safe_load((ROOT / "scenarios" / "herms-day.yaml").read_text())
MASH_SP = 66.0
LIMIT = 10.0  # herms.max_hlt_above_mash's default
PUMP_AT = 3900.0  # 1 h 5 min
BAND = 0.3
CONFIG = (
    "output:\n  backend: sim\nlog:\n  dir: null\ncontrol:\n  setpoint: 66\n"
    "mash_sensor:\n  kind: lm92\n  address: 0x49\npump:\n  backend: sim\n"
    # The mash as mashed in; its tun's losses guessed low (the plant's are 10 W/K).
    "herms:\n  mash_litres: 50\n  grain_kg: 12\n  mash_loss_w_per_k: 5\n"
    "safety:\n  heater_watch: 7200\n"
)
EVENTS: list[dict[str, Any]] = [
    {"at": "1h", "dough_in": {"grain_kg": 12, "grain_c": 20, "water_litres": 50, "water_c": 39.75}},
    {"at": "1h5m", "pump": "on"},
    {"at": "3h55m", "pump": "off"},
]


def herms_scenario() -> scenario.Scenario:
    doc = {"name": "herms-hold", "duration": "4h", "setpoint": MASH_SP, "events": EVENTS}
    return scenario.parse_scenario({**doc, "plant": HERMS_DAY["plant"]})


@pytest.fixture(scope="module")
def day(tmp_path_factory: pytest.TempPathFactory) -> tuple[scenario.Result, Path]:
    state = tmp_path_factory.mktemp("state")
    return scenario.run(herms_scenario(), parse(CONFIG), keep_records=True, state_dir=state), state


def pumped(records: list[PeriodRecord]) -> list[PeriodRecord]:
    return [r for r in records if r.t >= PUMP_AT and r.pump]


def test_the_mash_reaches_its_setpoint_and_holds_it(day: tuple[scenario.Result, Path]) -> None:
    """On the mash sensor's readings (LM92 steps, 10 s behind the mash)."""
    result, _state = day
    assert result.summary["alarms"] == []
    records = pumped(result.records)
    mash = [(r.t, r.mash) for r in records if r.mash is not None]
    reached = next(t for t, m in mash if m >= MASH_SP - BAND)
    assert max(m for _, m in mash) - MASH_SP <= 0.2
    assert all(abs(m - MASH_SP) <= BAND for t, m in mash if t >= reached + 300.0)
    assert records[-1].cascade == "hold"
    # The setpoint logged is the mash's throughout; the HLT's is the outer loop's.
    assert {r.setpoint for r in result.records} == {MASH_SP}
    assert all(r.hlt_setpoint is not None for r in result.records)


def test_the_hlt_never_passes_the_mash_setpoint_plus_the_limit(
    day: tuple[scenario.Result, Path],
) -> None:
    result, _state = day
    top = MASH_SP + LIMIT
    assert max(r.hlt_setpoint or 0.0 for r in result.records) <= top
    assert max(c for r in result.records for c in r.readings) <= top
    # The climb stood under the limit by the HLT law's margin (0.15 °C), or by more where an
    # unannounced pump stop would land more of the coil's heat in flight (`stop_room`: with
    # the mash far below, the coil's load is large).
    climb = [r.hlt_setpoint or 0.0 for r in result.records if r.cascade == "climb"]
    assert climb and max(climb) <= top - 0.15
    assert min(climb) < top - 0.15 - 0.1


def test_the_coils_load_is_fed_forward_while_the_pump_runs(
    day: tuple[scenario.Result, Path],
) -> None:
    result, _state = day
    stopped = [r for r in result.records if r.pump is False and r.pump_in is None]
    assert stopped and all(r.coil_load == 0.0 and r.cascade == "ready" for r in stopped)
    # The start hermsd commanded: the load fed a dead time ahead of the pump, which then ran.
    starting = [r for r in result.records if r.pump_in is not None]
    assert starting and all(r.pump is False and (r.coil_load or 0.0) > 0.0 for r in starting)
    held = [r for r in pumped(result.records) if r.cascade == "hold"]
    assert held and all(r.coil_load is not None and r.coil_load > 0.0 for r in held[-100:])


def test_the_learned_coil_is_stored_and_is_the_next_days_prior(
    day: tuple[scenario.Result, Path],
) -> None:
    """The plant's coil: UA 250 W/K at ṁc = 6 L/min · 4186 J/(L·K) = 418.6 W/K passes
    K = ṁc·(1 − e^(−UA/ṁc)) = 188.2 W/K (the effectiveness of a coil in a stirred tank)."""
    _result, state = day
    stored = LearnedModel(**yaml.safe_load((state / "learned-model.json").read_text()))
    flow = 6.0 / 60.0 * 4186.0
    assert stored.coil == pytest.approx(flow * (1.0 - math.exp(-250.0 / flow)), rel=0.05)
    assert 0.0 < stored.coil_sd < 0.2 * stored.coil
    prior = coil_prior(parse(CONFIG), stored)
    assert (prior.conductance, prior.sd, prior.source) == (stored.coil, stored.coil_sd, "stored")
    assert coil_prior(parse(CONFIG), None).conductance == 200.0  # herms.coil_w_per_k


def test_the_coil_learned_is_kept_when_the_day_ends_with_the_pump_running(
    tmp_path: Path,
) -> None:
    """The daemon stopped with the pump running (no pump stop before it): the day's K is kept
    as at any pump stop, within 5 % of the coil's K = ṁc·(1 − e^(−UA/ṁc)) = 188.2 W/K."""
    doc = {"name": "ends-pumping", "duration": "2h", "setpoint": MASH_SP, "events": EVENTS[:2]}
    run = scenario.parse_scenario({**doc, "plant": HERMS_DAY["plant"]})
    result = scenario.run(run, parse(CONFIG), keep_records=True, state_dir=tmp_path)
    assert result.records[-1].pump is True
    stored = LearnedModel(**yaml.safe_load((tmp_path / "learned-model.json").read_text()))
    flow = 6.0 / 60.0 * 4186.0
    assert stored.coil == pytest.approx(flow * (1.0 - math.exp(-250.0 / flow)), rel=0.05)


def herms_daemon(config_text: str = CONFIG, mash_ua: float | None = None) -> tuple[Daemon, World]:
    """herms-day's plant under the daemon (`mash_ua`: the mash tun's losses, W/K, in place
    of the plant's 10)."""
    config = parse(config_text)
    clock = VirtualClock()
    plant = HERMS_DAY["plant"]
    hlt = {k: v for k, v in plant.items() if k not in ("model", "mash")}
    mash = plant["mash"] if mash_ua is None else {**plant["mash"], "mash_ua_w_per_k": mash_ua}
    tun = make_herms_plant(plant["model"], mash, **hlt)
    world = build_world(config, clock, tun=tun)
    assert world.mash is not None
    daemon = assemble(
        config, clock, world.sensor, world.outputs, mash_sensor=world.mash.mash_sensor
    )
    return daemon, world


def watched_day(
    config_text: str = CONFIG, mash_ua: float | None = None
) -> tuple[Daemon, World, Periods]:
    """`herms_daemon`, its periods and events watched: doughed in at 1 h, the pump started at
    PUMP_AT by the test."""
    daemon, world = herms_daemon(config_text, mash_ua)
    periods = Periods()
    daemon.listeners.append(periods)
    daemon.recorder = periods
    tun: Any = world.plant
    daemon.clock.call_at(3600.0, lambda: tun.dough_in(12.0, 20.0, 50.0, 39.75, 3600.0))
    daemon.clock.call_at(PUMP_AT, lambda: daemon.set_pump(True, "by the test"))
    return daemon, world, periods


def test_a_mash_sensor_fault_holds_the_hlt_at_its_last_setpoint() -> None:
    daemon, world, periods = watched_day()
    assert world.mash is not None and world.mash.mash_chip is not None
    chip = world.mash.mash_chip
    fault_at, back_at = 4500.0, 5400.0  # in the climb: the HLT set at the limit
    daemon.clock.call_at(fault_at, lambda: chip.set_fault("nack"))
    daemon.clock.call_at(back_at, lambda: chip.set_fault("ok"))
    daemon.run(until=fault_at + 300.0)
    held = [r for r in periods.records if r.cascade == "held"]
    before = [r for r in periods.records if r.t < held[0].t][-1] if held else None
    assert before is not None and before.cascade == "climb"
    assert held and held[0].t - fault_at <= 2 * 5.0  # declared after two failed reads
    assert {r.hlt_setpoint for r in held} == {before.hlt_setpoint}
    assert all(r.mash is None and r.state == "ok" for r in held)
    assert "mash sensor fault" in daemon.status_text()
    assert f"no mash reading: the HLT is held at {before.hlt_setpoint:.2f} °C" in periods.events
    daemon.run(until=back_at + 60.0)
    assert periods.records[-1].cascade != "held" and periods.records[-1].mash is not None
    assert "mash reading again: the HLT steered by the mash" in periods.events
    # The day's K (learned since the pump started), three uncertainties high, bounds the
    # coil's load the supervisor counts: narrower than the whole flow's 12 L/min, 837 W/K.
    assert daemon._mash_control is not None
    coil = daemon._mash_control.coil.estimate()
    hlt, mash = 70.0, daemon.mash_side_fields()["mash"]  # the mash as last read
    assert coil.source == "learned" and mash is not None
    high = coil.conductance + 3.0 * coil.sd
    assert high < 12.0 / 60.0 * 4186.0
    assert daemon.coil_load(hlt).high == pytest.approx(high * (hlt - mash + 1.0))


def test_a_herms_log_verifies(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config, day_file = tmp_path / "hermsd.yaml", tmp_path / "herms.yaml"
    config.write_text(CONFIG)
    doc = {"name": "herms-hold", "duration": "2h", "setpoint": MASH_SP, "events": EVENTS[:2]}
    day_file.write_text(yaml.safe_dump({**doc, "plant": HERMS_DAY["plant"]}))
    logs = tmp_path / "log"
    argv = ["simulate", "--config", str(config), "--scenario", str(day_file), "--log", str(logs)]
    assert main(argv) == 0
    (log_file,) = logs.glob("*.mcap")
    counts, problems = invalid(logs)  # every record as the log's closed schemas declare it
    assert problems == [] and counts["/hermsd/period"] > 0
    periods = load([log_file]).periods
    assert {"climb", "coast"} <= {p.cascade for p in periods}
    capsys.readouterr()
    assert main(["replay", "--verify", str(log_file)]) == 0
    assert capsys.readouterr().out.strip() == f"{len(periods)} periods verified"


def test_the_coil_learned_before_any_tun_model_is_kept_alone_and_is_the_next_days_prior(
    tmp_path: Path,
) -> None:
    """Doughed in at 2 min and pumped from 5 min, the HLT never holds without the coil, so
    nothing is learned of the tun; the coil's K (188.2 W/K, as above) is kept alone as the
    pump stops, with no tun's fields made up, and is the next start's prior."""
    events: list[dict[str, Any]] = [
        {"at": "2m", "dough_in": EVENTS[0]["dough_in"]},
        {"at": "5m", "pump": "on"},
        {"at": "2h50m", "pump": "off"},
    ]
    doc = {"name": "herms-early", "duration": "3h", "setpoint": MASH_SP, "events": events}
    early = scenario.parse_scenario({**doc, "plant": HERMS_DAY["plant"]})
    result = scenario.run(early, parse(CONFIG), state_dir=tmp_path)
    assert result.summary["alarms"] == []
    kept_file = yaml.safe_load((tmp_path / "learned-model.json").read_text())
    assert set(kept_file) == {"coil", "coil_sd", "wall_ns"}
    store = ModelStore(tmp_path)
    assert store.load() == (None, None)  # nothing of the tun: no model in force from it
    kept = store.load_coil()
    assert kept is not None
    flow = 6.0 / 60.0 * 4186.0
    assert kept[0] == pytest.approx(flow * (1.0 - math.exp(-250.0 / flow)), rel=0.05)
    assert 0.0 < kept[1] < 0.2 * kept[0]
    # the next start: the coil's prior is the kept K, the tun's model the config's prior
    config = parse(CONFIG)
    clock = VirtualClock()
    world = build_world(config, clock, tun=make_herms_plant("physical", {}, start_c=20.0))
    assert world.mash is not None
    daemon = assemble(
        config,
        clock,
        world.sensor,
        world.outputs,
        mash_sensor=world.mash.mash_sensor,
        models=store,
    )
    assert daemon.model_choice.source == "prior"
    assert daemon._mash_control is not None
    prior = daemon._mash_control.coil.estimate()
    assert (prior.conductance, prior.sd, prior.source) == (*kept, "stored")


STUCK_AT, FREED_AT, STIR_AT = 7200.0, 7800.0, 10200.0  # as herms-day; stirring at 2 h 50 min
Seen = tuple[str, tuple[str, ...]]
"""The status line and the status reply's warnings of the mash side (`link.role_faults`)."""


def stuck_bed() -> tuple[Daemon, Periods, Any]:
    """herms-day's daemon, its periods and events watched: doughed in at 1 h, the pump
    started at PUMP_AT, the bed stuck from STUCK_AT (the pump runs, nothing flows)."""
    daemon, world, periods = watched_day()
    tun: Any = world.plant
    daemon.clock.call_at(STUCK_AT, lambda: tun.set_recirculation_ok(False, STUCK_AT))
    return daemon, periods, tun


@pytest.fixture(scope="module")
def stuck_day() -> tuple[Daemon, Periods, Seen, Seen]:
    """herms-day: the bed stuck 2 h to 2 h 10 min (the pump runs, nothing flows), then the
    pump stopped 5 min for stirring; the status line and the status reply's warnings looked
    at while the sign stands (at 2 h 9 min) and after the stirring (at 3 h)."""
    daemon, periods, tun = stuck_bed()
    clock = daemon.clock
    clock.call_at(FREED_AT, lambda: tun.set_recirculation_ok(True, FREED_AT))
    clock.call_at(STIR_AT, lambda: daemon.set_pump(False, "by the test"))
    clock.call_at(STIR_AT + 300.0, lambda: daemon.set_pump(True, "by the test"))
    daemon.run(until=FREED_AT - 60.0)
    stuck = daemon.status_text(), role_faults(daemon.role_status())
    daemon.run(until=3 * 3600.0)
    return daemon, periods, stuck, (daemon.status_text(), role_faults(daemon.role_status()))


def test_a_stuck_bed_is_signed_while_it_lasts_and_the_heater_stays_on(
    stuck_day: tuple[Daemon, Periods, Seen, Seen],
) -> None:
    _daemon, periods, stuck, after = stuck_day
    signed = [r.t for r in periods.records if r.cascade == "no flow"]
    assert signed and STUCK_AT < signed[0] < FREED_AT  # raised while the bed is stuck …
    assert FREED_AT < signed[-1] < FIRST_REST_BY  # … and ended once it flows again, only then
    assert signed == [r.t for r in periods.records if signed[0] <= r.t <= signed[-1]]
    raised = [e for e in periods.events if e.startswith("no flow through the coil:")]
    ended = [e for e in periods.events if e.startswith("no flow through the coil ended")]
    assert len(raised) == 1 and ended == ["no flow through the coil ended: the wort flows again"]
    assert "a stuck bed, a pump running dry, a closed valve?" in raised[0]
    assert stuck[1] == (raised[0].split(": the HLT readied")[0],)  # `warning:` in status
    assert re.search(r", mash 6\d\.\d → 66\.0 °C \(no flow\), pump on, ", stuck[0])
    assert after[1] == () and "(no flow)" not in after[0]
    # A warning, never an alarm: the heater is not turned off for it.
    assert all(r.alarms == [] and r.heater_allowed for r in periods.records)
    # Nor taken for a rest the limit cannot reach: the HLT is readied, not held at its most.
    assert not [e for e in periods.events if e.startswith("the mash levels out")]


FIRST_REST_BY = FREED_AT + 600.0
"""s: the sign ends within 10 min of the bed freeing (when the mash rises again)."""


def test_the_mash_does_not_overshoot_after_a_stuck_bed(
    stuck_day: tuple[Daemon, Periods, Seen, Seen],
) -> None:
    """The HLT does not wind up while nothing flows: once the bed frees, the mash reaches its
    rest without passing it by more than 0.2 °C (0.56 °C before the sign existed)."""
    _daemon, periods, _stuck, _after = stuck_day
    mash = [r.mash for r in periods.records if r.t >= FREED_AT and r.mash is not None]
    assert max(mash) >= MASH_SP - BAND  # the rest is reached …
    assert max(mash) - MASH_SP <= 0.2  # … without an overshoot heat cannot take back


def test_no_flow_is_never_signed_on_a_normal_herms_day(day: tuple[scenario.Result, Path]) -> None:
    """The pump's first minutes after the dough-in, the climb, the coast and the hold: the
    coil passes its heat all along, no sign."""
    result, _state = day
    assert [r.t for r in result.records if r.cascade == "no flow"] == []


def test_a_reload_while_no_flow_is_signed_says_the_sign_ended() -> None:
    """A reload that makes the outer loop again drops its flow watch: the sign standing is
    said to end (why), not left without its end; the new watch judges the flow afresh."""
    daemon, periods, _tun = stuck_bed()
    daemon.run(until=FREED_AT - 60.0)
    assert any(e.startswith("no flow through the coil:") for e in periods.events)
    daemon.reload(parse(CONFIG.replace("mash_loss_w_per_k: 5", "mash_loss_w_per_k: 6")))
    daemon.run(until=FREED_AT - 30.0)
    ended = [e for e in periods.events if e.startswith("no flow through the coil ended")]
    assert ended == [
        "no flow through the coil ended: the outer loop made again for the reloaded config, "
        "the flow judged afresh"
    ]


LOSSY_UA, TIGHT_LIMIT = 40.0, 3.0
"""A bare steel mash tun (40 W/K) under a 3 °C limit: the HLT held at its most (66 + 3 °C, less
the HLT law's margin) cannot bring the mash to 66 °C."""
LOSSY_CONFIG = CONFIG.replace(
    "mash_loss_w_per_k: 5\n", f"mash_loss_w_per_k: 28\n  max_hlt_above_mash: {TIGHT_LIMIT:g}\n"
)


def lossy_level(hlt: float) -> float:
    """Where an HLT held at `hlt` brings the lossy mash: (K·H + UA·room)/(K + UA), K the coil's
    250 W/K at 6 L/min, 1 − e^(−250/418.6) of the flow's 418.6 W/K (188.2 W/K)."""
    flow = 6.0 / 60.0 * 4186.0
    k = flow * (1.0 - math.exp(-250.0 / flow))
    return (k * hlt + LOSSY_UA * 20.0) / (k + LOSSY_UA)


@pytest.mark.parametrize("clear", ["rest", "reload"])
def test_a_rest_the_limit_cannot_bring_the_mash_to_is_said_with_its_level_and_cleared(
    clear: str,
) -> None:
    """At a steady HLT H, the coil's K·(H − m) meets the mash's losses UA·(m − room) at
    m = (K·H + UA·room)/(K + UA) (K = 188.2 W/K, as above): the warning names that level,
    measured from the mash's own rise, within half a degree, while the mash is short of the
    rest; a warning, never an alarm; a rest changed, or a reload, clears it."""
    daemon, _, periods = watched_day(LOSSY_CONFIG, LOSSY_UA)
    LoopLink(daemon).attach(Inbox())
    daemon.run(until=5 * 3600.0)
    said = [e for e in periods.events if e.startswith("the mash levels out")]
    assert len(said) == 1, said
    last_hour = [r.pv for r in periods.records if r.t >= 4 * 3600.0 and r.pv is not None]
    level = lossy_level(sum(last_hour) / len(last_hour))
    assert MASH_SP - level > 5.0  # far short: a rest nobody should wait for
    control = daemon._mash_control
    assert control is not None and control.reach.ceiling is not None
    assert abs(control.reach.ceiling - level) < 0.5
    # Named as measured when said; the estimate goes on refining after (within a tenth).
    named = re.search(r"near (\d+\.\d) °C with the HLT at its most", said[0])
    assert named is not None and abs(float(named[1]) - control.reach.ceiling) <= 0.1
    assert "raise herms.max_hlt_above_mash (3 °C)" in said[0]
    status = status_of(daemon)
    assert status["warnings"] == [said[0]]
    assert status["mash"]["levels_at"] == control.reach.ceiling
    assert f"levels out near {control.reach.ceiling:.1f} °C" in daemon.status_text()
    assert all(r.alarms == [] and r.heater_allowed for r in periods.records)
    if clear == "rest":
        daemon.set_setpoint(58.0)
        why = "the rest changed"
    else:  # the HLT's most may move with the outer loop made again: measured afresh
        daemon.reload(parse(LOSSY_CONFIG.replace("above_mash: 3", "above_mash: 12")))
        why = "the outer loop made again for the reloaded config"
    daemon.run(until=5 * 3600.0 + 10.0)
    assert periods.events[-1] == f"the mash levels out elsewhere now: {why}, measured afresh"
    assert status_of(daemon)["warnings"] == []
    daemon.shutdown()


def test_a_rest_out_of_reach_is_said_though_the_pump_stops_every_twenty_minutes() -> None:
    """A recirculation timer outside the program (the operator's pump off 2 min every 20 min)
    pauses the watch's run, as the program's own timer does: ended at each stop, its 18 min of
    wort flowing would hold one 10 min block, never the three in a row it says on. The level
    named is the one the HLT held while the wort flowed brings the mash to (as above)."""
    daemon, _, periods = watched_day(LOSSY_CONFIG, LOSSY_UA)
    for stop in range(int(PUMP_AT) + 1200, 5 * 3600, 1200):
        daemon.clock.call_at(float(stop), lambda: daemon.set_pump(False, "by the operator"))
        daemon.clock.call_at(stop + 120.0, lambda: daemon.set_pump(True, "by the operator"))
    daemon.run(until=5 * 3600.0)
    said = [e for e in periods.events if e.startswith("the mash levels out")]
    assert len(said) == 1, said
    last_hour = [r.pv for r in periods.records if r.t >= 4 * 3600.0 and r.pump and r.pv]
    level = lossy_level(sum(last_hour) / len(last_hour))
    control = daemon._mash_control
    assert control is not None and control.reach.ceiling is not None
    assert abs(control.reach.ceiling - level) < 0.5
    daemon.shutdown()


def test_the_reach_warning_names_the_key_that_sets_the_hlts_most() -> None:
    """With a 10 °C limit and safety.max_temp 85 °C the HLT may stand at 84 °C at most
    (CUT_OUT_MARGIN below the cut-out): a 63 °C rest's most is 63 + 10 − 0.15 = 72.85 °C, set
    by the limit; a 78 °C rest's would be 87.85, so safety.max_temp sets it at 84 °C."""
    config = parse(CONFIG + "  max_temp: 85\n")  # CONFIG ends in its safety section
    model = PlantModel(1.0, 20000.0, 60.0, 20.0)
    control = mash_control(config, model, coil_prior(config, None))
    words = control.reach._words
    assert "raise herms.max_hlt_above_mash (10 °C)," in words(60.0, 63.0, 72.85)
    assert "raise safety.max_temp (85 °C)," in words(76.0, 78.0, 84.0)


def at_63(
    control: MashControl,
    law: Controller,
    *,
    t: float,
    mash_pv: float,
    pump: bool,
    pump_in: float | None = None,
    hlt: float = 70.0,
) -> Decision:
    """A control period of the mash control for a 63 °C rest, its pump known, nothing applied."""
    return control.period(
        law,
        mash_sp=63.0,
        mash_pv=mash_pv,
        mash_age=0.0,
        hlt_pv=hlt,
        pump=pump,
        pump_known=True,
        applied=0.0,
        t=t,
        pump_in=pump_in,
    )


def rest_63(control: MashControl, *, mash_pv: float, pump: bool) -> Decision:
    """The outer loop's step for a 63 °C rest, the HLT at 70 °C, on the coil's estimate."""
    return control.cascade.step(
        mash_sp=63.0,
        mash_pv=mash_pv,
        mash_age=0.0,
        hlt_pv=70.0,
        pump=pump,
        coil=control.coil.estimate(),
    )


@pytest.mark.parametrize(("swing", "climb"), [(0.0, 72.27425), (0.0625, 72.24925)])
def test_a_climb_keeps_the_water_s_ripple_on_a_stop_s_landing_under_the_limit(
    swing: float, climb: float
) -> None:
    """A model heating 3 kW at 100·1/20 000 = 0.005 °C/s (C_h = 600 kJ/K), 60 s behind,
    windows of 5 s: without a band the water swings r·W/2 = 0.0125 °C at worst, half of it
    above its mean. A mash at 40 °C climbing to its 63 °C rest through the prior's 200 W/K:
    an unannounced stop lands 200·(72.85 − 40)·60/600 000 = 0.657 °C, the ripple and the
    reading's 0.0625 °C step on top, beyond HLT_MARGIN: 72.85 − (0.657 + 0.00625 + 0.0625 −
    0.15) = 72.27425 °C. With `output.swing` 1/16 the band is 0.0625/(2r) − W/4 = 5 s, the
    swing 2·r·5 + 0.0125 = 0.0625 °C: 72.85 − (0.657 + 0.03125 + 0.0625 − 0.15) = 72.24925 °C."""
    config = parse(CONFIG.replace("backend: sim\n", f"backend: sim\n  swing: {swing}\n", 1))
    model = PlantModel(1.0, 20000.0, 60.0, 20.0)
    control = mash_control(config, model, coil_prior(config, None))
    decision = rest_63(control, mash_pv=40.0, pump=True)
    assert decision.phase == "climb"
    assert decision.hlt_setpoint == pytest.approx(climb, abs=1e-9)


def test_a_load_begun_unannounced_is_told_once_and_a_prepared_start_is_not() -> None:
    """The coil's load fed forward where the period before fed none and no start was
    prepared for it (a pump seen running, wort flowing again) is `unannounced`, for that
    period only; a start prepared a period ahead (`pump_in`) is not, nor one prepared with
    no load told ahead (the HLT at its limit: no room for heat sent ahead)."""
    config = parse(CONFIG)
    model = PlantModel(1.0, 20000.0, 60.0, 20.0)
    control = mash_control(config, model, coil_prior(config, None))
    law = laws.create("predictive", kc=120.0, ti=800.0, ts=5.0, model=model)
    law.reset(70.0, 20.0)

    def period(t: float, pump: bool, pump_in: float | None = None, hlt: float = 70.0) -> bool:
        at_63(control, law, t=t, mash_pv=50.0, pump=pump, pump_in=pump_in, hlt=hlt)
        return control.unannounced

    assert [period(0.0, False), period(5.0, True), period(10.0, True)] == [False, True, False]
    assert [period(15.0, False), period(20.0, False, pump_in=5.0)] == [False, False]
    assert period(25.0, True) is False
    assert [period(30.0, False), period(35.0, False, pump_in=5.0, hlt=73.0)] == [False, False]
    assert control.decision is not None and control.decision.load_watts == 0.0
    assert period(40.0, True) is False


def test_a_reload_of_the_ssrs_swing_moves_the_room_a_climb_keeps() -> None:
    """The outer loop is made again when `output.swing` is reloaded: the room a climb keeps
    under the limit counts the pulses' new swing. A mash at 40 °C far below its 66 °C rest
    (the landing alone above HLT_MARGIN): without a band the water stands r·W/4 above its
    mean, with `swing` 1/16 (a band within a window) 0.0625/2; the climb's setpoint moves by
    the difference."""
    daemon, _world, _periods = watched_day()
    daemon.run(until=10.0)
    control = daemon._mash_control
    assert control is not None
    before = control.cascade.most(MASH_SP, 40.0, 200.0)
    daemon.reload(parse(CONFIG.replace("backend: sim\n", "backend: sim\n  swing: 0.0625\n", 1)))
    daemon.run(until=20.0)
    remade = daemon._mash_control
    assert remade is not None and remade is not control
    ripple = daemon.model.rate * 5.0 / 4.0
    after = remade.cascade.most(MASH_SP, 40.0, 200.0)
    # The band is whole mains half-cycles: r·2·0.005 s of swing at most, half of it above.
    assert after == pytest.approx(before - (0.0625 / 2.0 - ripple), abs=daemon.model.rate * 0.005)
    daemon.shutdown()


@pytest.mark.parametrize(("stopped", "offset"), [(True, -300.0), (False, 0.0)])
def test_the_strike_water_s_hold_measures_what_the_hlt_loses_beyond_its_model(
    stopped: bool, offset: float
) -> None:
    """The model's HLT (C_h = 3000 W / 0.005 °C/s = 600 kJ/K, UA_h = C_h/τ = 30 W/K, room
    20 °C) held at 70 °C in a brewery at 10 °C: it loses 30 × 60 = 1800 W, 60 % of the
    element, where the model says 1500 W. Twenty minutes of that hold with the pump known to
    stand show the 300 W (`CoilEstimator.offset`), what the coil's balance and the coast then
    count; with the pump not known to stand (one run by hand unseen may draw), nothing."""
    config = parse(CONFIG)
    model = PlantModel(1.0, 20000.0, 60.0, 20.0)
    control = mash_control(config, model, coil_prior(config, None))
    law = laws.create("predictive", kc=120.0, ti=800.0, ts=5.0, model=model)
    law.reset(70.0, 60.0)
    for _ in range(240):
        control.strike(law, 70.0, hlt_pv=70.0, applied=60.0, stopped=stopped)
    assert control.coil.offset == pytest.approx(offset, abs=1e-6)


def test_the_empty_tun_s_lowest_reading_is_the_room_the_outer_loop_reckons_to() -> None:
    """Before the mash is in, the mash sensor reads the empty tun: its lowest reading within
    ROOM_SEEN over the strike step (the grain doughed in reads warmer, 36 °C, and a preheated
    tun above 40 °C is none) is the room. A stopped pump's HLT for a mash at its 63 °C rest
    is the hold's, 63 + 5 W/K·(63 − room)/200 W/K (CONFIG's losses, the prior K): 64.0 °C
    for a room of 23 °C, where the model's room (20 °C) gives 64.075."""
    config = parse(CONFIG)
    model = PlantModel(1.0, 20000.0, 60.0, 20.0)
    law = laws.create("predictive", kc=120.0, ti=800.0, ts=5.0, model=model)
    law.reset(70.0, 20.0)

    def ready(readings: list[float]) -> tuple[float, float]:
        control = mash_control(config, model, coil_prior(config, None))
        for reading in readings:
            control.strike(law, 70.0, hlt_pv=70.0, applied=20.0, stopped=True, mash_pv=reading)
        decision = rest_63(control, mash_pv=63.0, pump=False)
        assert decision.phase == "ready"
        return decision.hlt_setpoint, control.cascade.room

    # The room the outer loop reckons to, and hands the flow watch with the losses.
    assert ready([25.0, 24.0, 23.0, 45.0, 36.0]) == (pytest.approx(64.0, abs=1e-12), 23.0)
    assert ready([]) == (pytest.approx(64.075, abs=1e-12), 20.0)
    assert ready([55.0]) == (pytest.approx(64.075, abs=1e-12), 20.0)  # a tun preheated
    # The next day's strike step (the mash was in between) reads its own room, 26 °C:
    # 63 + 5·37/200 = 63.925 °C, not the lower of the two days'.
    control = mash_control(config, model, coil_prior(config, None))
    control.strike(law, 70.0, hlt_pv=70.0, applied=20.0, stopped=True, mash_pv=23.0)
    at_63(control, law, t=0.0, mash_pv=63.0, pump=False)
    control.strike(law, 70.0, hlt_pv=70.0, applied=20.0, stopped=True, mash_pv=26.0)
    assert rest_63(control, mash_pv=63.0, pump=False).hlt_setpoint == pytest.approx(63.925)


def test_a_reload_keeps_what_the_day_measured_where_the_config_still_means_it() -> None:
    """A reload that makes the outer loop again (the limit raised, as the reach warning asks)
    keeps the room the empty tun read (12 °C), the mash's losses the holds learned and the
    HLT model's error its stopped pump showed (the strike's hold as above: −300 W); a new
    guess of the losses is the brewer's, and a model of another HLT says nothing of the old
    one's error."""
    config = parse(CONFIG)
    model = PlantModel(1.0, 20000.0, 60.0, 20.0)
    law = laws.create("predictive", kc=120.0, ti=800.0, ts=5.0, model=model)
    law.reset(70.0, 60.0)
    control = mash_control(config, model, coil_prior(config, None))
    for _ in range(240):
        control.strike(law, 70.0, hlt_pv=70.0, applied=60.0, stopped=True, mash_pv=12.0)
    control.cascade.mash_loss = 9.0  # as the holds showed them

    def remade(text: str, hlt: PlantModel = model) -> MashControl:
        again = mash_control(parse(text), hlt, coil_prior(parse(text), None))
        again.carry(control)
        return again

    raised = remade(CONFIG.replace("grain_kg: 12\n", "grain_kg: 12\n  max_hlt_above_mash: 12\n"))
    assert raised.cascade.ceiling(63.0) == 63.0 + 12.0 - 0.15  # the reload took
    assert (raised.cascade.room, raised.cascade.mash_loss) == (12.0, 9.0)
    assert raised.coil.offset == pytest.approx(-300.0, abs=1e-6)
    guessed = remade(CONFIG.replace("mash_loss_w_per_k: 5", "mash_loss_w_per_k: 7"))
    assert (guessed.cascade.room, guessed.cascade.mash_loss) == (12.0, 7.0)
    other = remade(CONFIG, PlantModel(1.0, 15000.0, 60.0, 20.0))
    assert (other.cascade.room, other.coil.offset) == (12.0, 0.0)


def test_a_reload_mid_mash_keeps_the_losses_the_hold_learned() -> None:
    """Through the daemon: herms-day in its hold (the plant's losses 10 W/K, guessed 5), the
    limit raised by a reload; the outer loop made again goes on from the losses learned."""
    daemon, _world, _periods = watched_day()
    daemon.run(until=3 * 3600.0)
    before = daemon._mash_control
    assert before is not None and before.cascade.mash_loss > 6.0
    daemon.reload(
        parse(CONFIG.replace("grain_kg: 12\n", "grain_kg: 12\n  max_hlt_above_mash: 12\n"))
    )
    daemon.run(until=3 * 3600.0 + 5.0)
    after = daemon._mash_control
    assert after is not None and after is not before
    assert after.cascade.mash_loss == pytest.approx(before.cascade.mash_loss, abs=0.01)
    daemon.shutdown()
