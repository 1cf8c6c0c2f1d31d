"""The pump sense (`pump.sense`, docs/herms.md "A pump hermsd only sees"): a contact that
tells hermsd whether a pump it does not switch runs. Its config's rules; its GPIO input line
read through a fake of the gpiod bindings; a simulated day where the pump started by hand is
seen in the period it starts, its load fed forward at once and the HLT not readied to the
limit while it stands; a sense that cannot be read, a warning and the pump taken as unseen;
the day's log re-run exactly by `replay --verify`.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from test_mash_side import PERIOD, LaggingMash, fake_gpiod, herms_daemon, run_for, watched
from test_pump_start import LITRES, UA_HLT, dough, hlt

from hermsd.config.read import parse
from hermsd.config.schema import ConfigError
from hermsd.hardware.pump_sense import GpioPumpSense, open_pump_sense
from hermsd.log import reader, replay
from hermsd.mqtt.messages import Refused, Topics, discovery_messages, parse_command
from hermsd.runtime.mash_side import PumpNotFitted
from hermsd.runtime.period import PeriodRecord
from hermsd.sim import scenario
from hermsd.sim.mash import HermsTun
from hermsd.sim.world import PumpContact

SENSED = (
    "output:\n  backend: sim\nlog:\n  dir: null\ncontrol:\n  setpoint: 70\n"
    "mash_sensor:\n  kind: lm92\n  address: 0x49\n"
    "pump:\n  backend: none\n  sense: sim\n"
)
UNSEEN = "(the pump taken as running unseen, as without a sense)"


def problems(text: str) -> list[str]:
    with pytest.raises(ConfigError) as caught:
        parse(text)
    return [str(p) for p in caught.value.problems]


# -- the config ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "said"),
    [
        (
            "pump:\n  sense: gpio\n",
            "<string>:2:10: pump.sense: the gpio sense needs pump.sense_line, the input line's "
            "offset on /dev/gpiochip0 (add 'sense_line: 27' under pump: for GPIO27",
        ),
        (
            "pump:\n  backend: sim\n  sense: sim\n",
            "<string>:3:10: pump.sense: a pump sense with pump.backend sim: hermsd knows the "
            "pump it switches, the sense is for a pump it does not (set sense: none, or "
            "backend: none",
        ),
        (
            "output:\n  backend: gpio\n  line: 17\npump:\n  sense: gpio\n  sense_line: 17\n",
            "<string>:6:15: pump.sense_line: line 17 of /dev/gpiochip0 is output's output: the "
            "pump sense needs an input line of its own",
        ),
        ("pump:\n  sense: yes\n", "pump.sense: "),
    ],
    ids=["gpio-without-line", "with-a-switched-pump", "on-the-ssr-s-line", "not-a-choice"],
)
def test_a_pump_sense_that_cannot_be_is_refused_in_one_line(text: str, said: str) -> None:
    [problem] = problems(text)
    assert problem.startswith(said) if said.startswith("<") else said in problem


def test_a_gpio_sense_on_a_line_of_its_own_is_taken_and_none_is_the_default() -> None:
    pump = parse("pump:\n  sense: gpio\n  sense_line: 27\n  sense_active_low: true\n").pump
    assert (pump.backend, pump.sense, pump.sense_chip) == ("none", "gpio", "/dev/gpiochip0")
    assert (pump.sense_line, pump.sense_active_low) == (27, True)
    assert parse("").pump.sense == "none"


def test_check_config_accepts_a_sense(tmp_path: Path) -> None:
    from hermsd.cli import main

    path = tmp_path / "hermsd.yaml"
    text = "mash_sensor:\n  kind: lm92\n  address: 0x49\npump:\n  sense: gpio\n  sense_line: 27\n"
    path.write_text(text, "utf-8")
    assert main(["check-config", str(path)]) == 0


# -- the GPIO input line ---------------------------------------------------------------------


class SensedMash(LaggingMash):
    """test_mash_side's HERMS plant, saying whether its pump runs (the simulated contact)."""

    def pump_running(self) -> bool:
        return self.pump


def test_a_gpio_sense_is_an_input_line_read_at_each_read_and_its_changes_said(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    gpiod = fake_gpiod(monkeypatch)
    text = SENSED.replace("sense: sim", "sense: gpio\n  sense_line: 27\n  sense_active_low: true")
    sense = open_pump_sense(parse(text).pump)
    assert isinstance(sense, GpioPumpSense)
    [request] = gpiod.requests
    settings = request.config[27]
    assert (request.chip, request.consumer) == ("/dev/gpiochip0", "hermsd")
    assert settings.direction == "Direction.INPUT" and settings.active_low is True
    assert settings.bias == "Bias.PULL_UP"  # an unplugged module reads a stopped pump
    daemon, _world = herms_daemon(text, SensedMash(), pump_sense=sense)
    periods = watched(daemon)
    run_for(daemon, 2 * PERIOD)
    assert request.reads >= 10  # once a read interval (1 s)
    assert [r.pump for r in periods.records] == [False] * len(periods.records)
    request.level = "Value.ACTIVE"
    run_for(daemon, 2 * PERIOD)  # read within the period, recorded at its end
    assert periods.records[-1].pump is True
    assert [e for e in periods.events if e.startswith("pump seen")] == [
        "pump seen off",
        "pump seen on",
    ]
    daemon.shutdown()
    sense.close()
    assert request.released


# -- a sense that cannot be read -------------------------------------------------------------


def test_a_sense_that_fails_is_one_warning_and_the_pump_unseen_till_it_reads_again() -> None:
    daemon, world = herms_daemon(SENSED, SensedMash())
    assert world.mash is not None and isinstance(world.mash.pump_sense, PumpContact)
    contact = world.mash.pump_sense
    periods = watched(daemon)
    run_for(daemon, 6 * PERIOD)
    seen = periods.records[-1]
    # Seen stopped, the mash 50 °C short: the HLT readied for the shortfall, not the limit.
    assert (seen.pump, seen.cascade) == (False, "ready")
    contact.failing = True
    run_for(daemon, 6 * PERIOD)
    faults = [e for e in periods.events if e.startswith("pump sense fault")]
    assert faults == [
        f"pump sense fault: [Errno 5] the pump sense's line cannot be read (simulated) {UNSEEN}"
    ]
    unseen = periods.records[-1]
    # As without a sense: taken as running, the HLT to the limit; no load fed on a guess.
    assert (unseen.pump, unseen.cascade, unseen.coil_load) == (None, "climb", 0.0)
    contact.failing = False
    run_for(daemon, 2 * PERIOD)
    again = periods.records[-1]
    assert (again.pump, again.cascade) == (False, "ready")
    assert "pump sense reads again: pump off" in periods.events
    every = periods.records
    assert all(r.alarms == [] and r.heater_allowed for r in every)  # never an alarm


# -- a simulated day: the pump started by hand, seen ------------------------------------------

WATTS = 3000.0  # test_pump_start's 90 L HLT with a smaller element
REST, LIMIT = 66.0, 10.0
DOUGH_AT, PUMP_AT, AFTER = 600.0, 1500.0, 900.0


def day_config() -> str:
    capacity = 4186.0 * LITRES
    return (
        "output:\n  backend: sim\n"
        f"tun:\n  litres: {LITRES:g}\n  element_watts: {WATTS:g}\n"
        f"control:\n  setpoint: {REST:g}\n  model_gain: {WATTS / (100 * UA_HLT):.4f}\n"
        f"  model_tau: {capacity / UA_HLT:.0f}\n  dead_time: 70\n"
        "mash_sensor:\n  kind: lm92\n  address: 0x49\n"
        "pump:\n  backend: none\n  sense: sim\n"
        f"herms:\n  mash_litres: 50\n  grain_kg: 12\n  max_hlt_above_mash: {LIMIT:g}\n"
    )


@pytest.fixture(scope="module")
def day(tmp_path_factory: pytest.TempPathFactory) -> tuple[list[PeriodRecord], Path]:
    """50 L and 12 kg at 20 °C doughed in at 63 °C, 3 °C short of the rest; the pump, outside
    hermsd and no coil outlet sensor, started by hand at PUMP_AT; the day logged."""
    doc = {
        "name": "pump-seen",
        "duration": f"{PUMP_AT + AFTER:g}s",
        "setpoint": REST,
        "plant": {"model": "physical", "litres": LITRES, "element_watts": WATTS},
        "events": [
            {"at": f"{DOUGH_AT:g}s", "dough_in": dough(63.0)},
            {"at": f"{PUMP_AT:g}s", "pump": "on"},
        ],
    }
    tun = HermsTun(hlt(WATTS, REST), coil_w_per_k=250.0, mash_ua_w_per_k=5.0)
    log_dir = tmp_path_factory.mktemp("pump-seen")
    result = scenario.run(
        scenario.parse_scenario(doc),
        parse(day_config()),
        outside_plant=tun,
        keep_records=True,
        log_dir=log_dir,
    )
    return result.records, log_dir


def test_a_pump_started_by_hand_is_seen_in_the_period_it_starts_its_load_fed_at_once(
    day: tuple[list[PeriodRecord], Path],
) -> None:
    records, _ = day
    before = [r for r in records if r.t <= PUMP_AT]
    first = next(r for r in records if r.t > PUMP_AT)
    assert before[-1].pump is False and before[-1].coil_load == 0.0
    assert first.t <= PUMP_AT + PERIOD  # the period it starts in
    assert first.pump is True and first.coil_load is not None and first.coil_load > 0.0
    assert all(r.pump is True for r in records if r.t > PUMP_AT)


def test_the_hlt_is_readied_for_the_mashs_shortfall_not_heated_to_the_limit_while_it_stands(
    day: tuple[list[PeriodRecord], Path],
) -> None:
    records, _ = day
    standing = [r for r in records if DOUGH_AT + 300.0 <= r.t <= PUMP_AT]
    assert standing and all(r.cascade == "ready" for r in standing)
    # The HLT's heat above its hold covers the mash's shortfall: 229.7 kJ/K × 3.5 K over the
    # HLT's 376.7 kJ/K is 2.1 °C, about 69 °C with the hold; the limit stands 10 °C over the
    # mash, 72.5 °C (a pump taken as running readies the HLT there, less 0.15 °C).
    for r in standing:
        assert r.mash is not None and r.hlt_setpoint is not None
        assert r.hlt_setpoint < r.mash + LIMIT - 2.0
    highest = max(r.pv for r in standing if r.pv is not None)
    assert highest < min(r.mash for r in standing if r.mash is not None) + LIMIT - 2.0


def test_a_day_with_the_sense_re_runs_exactly(day: tuple[list[PeriodRecord], Path]) -> None:
    _, log_dir = day
    log = reader.load(sorted(log_dir.glob("*.mcap*")))
    logged = {record.pump for record in log.periods}
    assert logged == {False, True}
    result = replay.verify(log.entries)
    assert result.other_law is None and result.mismatch is None
    assert result.verified > 0.9 * (PUMP_AT + AFTER) / PERIOD
    events = [e.message for e in log.events if e.message.startswith("pump seen")]
    assert events == ["pump seen off", "pump seen on"]
    assert not math.isnan(result.verified)


# -- what the brewer is shown ----------------------------------------------------------------


def test_a_seen_pump_is_announced_to_home_assistant_read_only() -> None:
    topics = Topics.of("hermsd", "homeassistant")
    seen = dict(discovery_messages(topics, parse("pump:\n  sense: sim\n")))
    switched = dict(discovery_messages(topics, parse("pump:\n  backend: sim\n")))
    sensor = "homeassistant/binary_sensor/hermsd/pump_seen/config"
    switch = "homeassistant/switch/hermsd/pump/config"
    assert seen[switch] is None and switched[sensor] is None  # each removes the other
    entity = seen[sensor]
    assert entity is not None and "command_topic" not in entity
    assert entity["value_template"] == "{{ 'ON' if value_json.pump else 'OFF' }}"
    assert entity["device_class"] == "running"


def test_a_pump_only_seen_is_refused_a_set_pump_that_says_so() -> None:
    """`hermsd set pump` on a pump hermsd only sees: not "no pump is fitted" (the brewer has
    one, and the page shows it running), but that hermsd does not switch it."""
    daemon, _world = herms_daemon(SENSED, SensedMash())
    with pytest.raises(PumpNotFitted) as refused:
        daemon.set_pump(True, "by the test")
    assert str(refused.value) == (
        "pump: hermsd only sees this pump (pump.sense), it does not switch it (switch it where "
        "it is switched, or set pump.backend in the config file and restart hermsd)"
    )
    topics = Topics.of("hermsd", "homeassistant")
    with pytest.raises(Refused) as mqtt:  # Home Assistant's pump switch: the same words
        parse_command(topics, topics.set_pump, b"ON", parse(SENSED))
    assert str(mqtt.value) == str(refused.value)
