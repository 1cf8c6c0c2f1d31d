"""The element's current input (`current`, docs/current.md): the ADS1115 reader on the fake
I2C bus against a CT's sine worked out by hand from the datasheet; the optocoupler through a
fake of the gpiod bindings; the config's rules; simulated days where a shorted SSR and an
element gone open are latched within one control period, a normal day without an alarm, a
CT unplugged from the start only said, a reader that fails said and recovered; the day's log
re-run exactly by `replay --verify`.
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import math
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
from test_control import Inbox, status_of
from test_mash_side import fake_gpiod

from hermsd.api.link import LoopLink
from hermsd.config import schema as config_module
from hermsd.config.read import parse
from hermsd.config.schema import ConfigError, CurrentConfig
from hermsd.control import factory
from hermsd.hardware.current_sense import (
    ADS1115Current,
    GpioCurrentSense,
    open_current_sense,
)
from hermsd.log import reader, replay
from hermsd.runtime import build, current_side
from hermsd.runtime.assemble import assemble
from hermsd.runtime.notify import current_words
from hermsd.runtime.saver import Saver
from hermsd.sim import scenario
from hermsd.sim import tun_faults as tf
from hermsd.sim.bus import ADS1115_POWER_UP_CONFIG, FakeADS1115, FakeSMBus
from hermsd.sim.clock import VirtualClock
from hermsd.sim.scenario import Event, Scenario, effective_config
from hermsd.sim.tuns import FAMILY, TunSpec
from hermsd.sim.world import build_world

ADDRESS = 0x49
CT_AMPS_PER_VOLT = 30.0  # an SCT-013-030: 30 A for 1 V rms


def ct_volts(amps_rms: float, hz: float = 50.0, bias: float = 0.0) -> Callable[[float], float]:
    """A CT's output at `amps_rms` through it: a sine of amps/30 V rms, on `bias` volts."""
    peak = amps_rms / CT_AMPS_PER_VOLT * math.sqrt(2.0)
    return lambda t: bias + peak * math.sin(2.0 * math.pi * hz * t + 0.3)


def ads1115(
    amps_rms: float, current: CurrentConfig, *, hz: int = 50, bias: float = 0.0
) -> tuple[ADS1115Current, FakeADS1115, VirtualClock]:
    clock = VirtualClock(100.0)
    chip = FakeADS1115(ct_volts(amps_rms, hz, bias), clock.monotonic)
    bus = FakeSMBus()
    bus.attach(ADDRESS, chip)
    sense = ADS1115Current(bus, ADDRESS, current, hz, clock.monotonic, clock.advance)
    return sense, chip, clock


# -- the ADS1115 on the fake bus ---------------------------------------------------------------


def test_the_config_register_is_the_datasheets_word_for_continuous_860_sps() -> None:
    # a0-a1 (MUX 000), ±1.024 V (PGA 011), MODE 0, DR 111, COMP_QUE 11: 0000 0110 1110 0011.
    _, chip, _ = ads1115(0.0, CurrentConfig(kind="ads1115", range=1.024))
    assert chip.config == 0b0000_0110_1110_0011
    # a0 single-ended (MUX 100), ±4.096 V (PGA 001): 0100 0010 1110 0011.
    _, chip, _ = ads1115(0.0, CurrentConfig(kind="ads1115", input="a0", range=4.096))
    assert chip.config == 0x42E3


@pytest.mark.parametrize("hz", [50, 60])
def test_ten_amps_through_a_30_a_per_volt_ct_read_as_ten_amps_rms(hz: int) -> None:
    # 10 A → 0.3333 V rms, 0.4714 V peak: 15085 counts of 31.25 µV at ±1.024 V. The RMS of
    # two cycles' samples at 860 SPS is within 1 % of it (17 or 14 samples a cycle, rounded
    # to whole counts).
    current = CurrentConfig(kind="ads1115", range=1.024, amps_per_volt=30.0, threshold=1.0)
    sense, chip, clock = ads1115(10.0, current, hz=hz)
    started, before = clock.monotonic(), chip.transfers
    read = sense.read()
    assert read.drawing
    assert read.amps == pytest.approx(10.0, rel=0.01)
    # The time it holds its caller: two cycles and at most one poll more; a transfer a poll.
    took = clock.monotonic() - started
    assert 2.0 / hz <= took <= 2.0 / hz + 1.0 / 860 + 1e-9
    polls = chip.transfers - before - 1  # the config register checked first
    assert math.floor(2.0 / hz * 860) <= polls <= math.ceil(2.0 / hz * 860) + 1


def test_a_single_ended_ct_biased_to_mid_supply_reads_its_ac_part() -> None:
    current = CurrentConfig(kind="ads1115", input="a0", range=4.096)
    sense, _, _ = ads1115(10.0, current, bias=1.65)  # 1.65 V is 13200 counts of 125 µV
    assert sense.read().amps == pytest.approx(10.0, rel=0.01)


def test_no_current_reads_below_the_threshold() -> None:
    sense, _, _ = ads1115(0.0, CurrentConfig(kind="ads1115", threshold=0.5))
    read = sense.read()
    assert not read.drawing
    assert read.amps == 0.0


def test_a_chip_that_lost_its_config_is_set_again_before_it_is_read() -> None:
    sense, chip, _ = ads1115(10.0, CurrentConfig(kind="ads1115"))
    chip.config = ADS1115_POWER_UP_CONFIG  # a dip in its supply: single-shot, stale register
    assert sense.read().amps == pytest.approx(10.0, rel=0.01)
    assert chip.config == 0x06E3


def test_a_bus_error_is_an_os_error() -> None:
    sense, chip, _ = ads1115(10.0, CurrentConfig(kind="ads1115"))
    chip.failing = True
    with pytest.raises(OSError, match="Remote I/O"):
        sense.read()


# -- the optocoupler on a GPIO line ------------------------------------------------------------


def test_the_optocoupler_is_an_input_line_read_through_gpiod(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    gpiod = fake_gpiod(monkeypatch)
    current = CurrentConfig(kind="gpio", line=23, active_low=True)
    sense = open_current_sense(current, 50, lambda: 0.0, lambda _: None)
    assert isinstance(sense, GpioCurrentSense)
    [request] = gpiod.requests
    settings = request.config[23]
    assert (request.chip, request.consumer) == ("/dev/gpiochip0", "hermsd")
    assert settings.direction == "Direction.INPUT" and settings.active_low is True
    assert settings.bias == "Bias.PULL_UP"  # a module unplugged reads no mains
    assert sense.read().drawing is False
    request.level = "Value.ACTIVE"
    read = sense.read()
    assert read.drawing is True and read.amps is None
    sense.close()
    assert request.released


def test_without_gpiod_the_error_names_the_input_and_the_extra(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setitem(sys.modules, "gpiod", None)
    with pytest.raises(ImportError, match="the gpio current input needs the gpiod package"):
        GpioCurrentSense("/dev/gpiochip0", 23)


# -- the config ---------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "said"),
    [
        (
            "current:\n  kind: gpio\n",
            "<string>:2:9: current.kind: the gpio current input needs current.line",
        ),
        (
            "current:\n  kind: ads1115\n  address: 0x4C\n",
            "<string>:3:12: current.address: 0x4C is out of range (a whole number from 0x48 "
            "to 0x4B)",
        ),
        (
            "current:\n  kind: ads1115\n  address: 0x48\n",
            "<string>:3:12: current.address: address 0x48 on I2C bus 1 is sensor's LM92",
        ),
        (
            "current:\n  kind: ads1115\n  threshold: 0\n",
            "<string>:3:14: current.threshold: 0 A is out of range (a number above 0 and at "
            "most 100 A)",
        ),
        (
            "output:\n  backend: gpio\n  line: 17\ncurrent:\n  kind: gpio\n  line: 17\n",
            "<string>:6:9: current.line: line 17 of /dev/gpiochip0 is output's output",
        ),
        (
            "current:\n  kind: ads1115\n  range: 0.5\n",
            "<string>:3:10: current.range: 0.5 is not one of the choices",
        ),
    ],
)
def test_a_current_input_the_config_cannot_have_is_one_line_that_says_why(
    text: str, said: str
) -> None:
    with pytest.raises(ConfigError) as caught:
        parse(text)
    [problem] = [str(p) for p in caught.value.problems]
    assert problem.startswith(said), problem


def test_the_current_input_is_off_by_default_and_each_kind_is_taken() -> None:
    assert not parse("").current.fitted
    assert parse("current:\n  kind: ads1115\n").current.address == 0x49
    assert parse("current:\n  kind: gpio\n  line: 23\n").current.line == 23


def test_with_a_current_input_no_pulse_or_gap_is_shorter_than_two_reads() -> None:
    """Two reads of two mains cycles, each a half-cycle and 10 ms from its part's edges, and a
    half-cycle for the grid: 3 × (40 + 20) + 10 = 190 ms at 50 Hz, 3 × (33.3 + 18.3) + 8.3 =
    163.3 ms at 60 Hz; the duty is kept on average all the same."""
    for hz, least in ((50, 0.190), (60, 0.1633)):
        config = parse(f"output:\n  mains_hz: {hz}\ncurrent:\n  kind: sim\n")
        for duty in (1.0, 99.0):  # a window's pulse, and its gap, shorter than two reads
            planner = build.planner(config, factory.prior_model(config))
            plans = [planner.plan(5.0 * k, duty) for k in range(400)]
            assert min(p.on_time for p in plans if p.on_time > 0) >= least - 1e-9
            assert min(p.length - p.on_time for p in plans if p.on_time < p.length) >= least - 1e-9
            mean = sum(p.applied for p in plans) / len(plans)
            assert mean == pytest.approx(duty, abs=0.05)
    plain = parse("")
    least = build.planner(plain, factory.prior_model(plain)).min_on_slots
    assert least == 2  # without the input, the config's 20 ms: two half-cycles at 50 Hz


# -- simulated days -----------------------------------------------------------------------------

SPEC = FAMILY[0]
PERIOD = 5.0  # the control period of the family's days


def with_current(day: Scenario, *events: Event) -> Scenario:
    config = {**day.config, "current": {"kind": "sim"}}
    return dataclasses.replace(day, config=config, events=(*day.events, *events))


def test_a_normal_day_with_the_current_input_raises_no_alarm() -> None:
    result = scenario.run(with_current(tf.normal_day(SPEC)), keep_records=True)
    assert result.summary["alarms"] == []
    samples = [s for r in result.records for s in r.current or []]
    assert len(samples) > 1000
    assert any(s[1] for s in samples) and any(not s[1] for s in samples)  # on and off


def test_a_shorted_ssr_is_latched_by_the_current_within_one_period() -> None:
    result = scenario.run(with_current(tf.ssr_shorts(SPEC)))
    [alarm] = result.summary["alarms"]
    assert alarm["kind"] == "ssr_stuck_on"
    assert alarm["detected_after_s"] <= PERIOD
    assert alarm["message"].startswith("the current input reads current")
    assert alarm["heater_off_after_s"] == 0.0  # the contactor opened at once


EVERY = current_side.PROOF_EVERY_S


@pytest.mark.parametrize(("min_off", "gap", "every"), [(None, 0.19, EVERY), (1.9, 1.9, 10 * EVERY)])
def test_a_short_behind_an_ssr_held_fully_on_is_found_by_a_gap(
    min_off: float | None, gap: float, every: float
) -> None:
    """The thermowell 120 L tun on two elements (1091 W on the SSR, 1909 W on a contactor):
    the SSR carries the hold at 100 % with the contactor's element off, so it takes no
    off-sample and a short in the hold went untold for the half hour after it. With the input
    fitted a window is left off for its least gap (two reads with their margins, 190 ms at
    50 Hz; or `output.min_off`) once the last off-sample is `every` old (PROOF_EVERY_S, ten
    times that for a gap ten times as long): the short told within that and two windows
    (the gap's own, the one it waits for); the gaps no closer together than `every`."""
    spec = FAMILY[7]
    ssr_w = round(spec.element_watts * 2.0 / 5.5)
    day = tf.ssr_shorts(spec)
    plant = {**day.plant, "element_watts": ssr_w, "element2_watts": spec.element_watts - ssr_w}
    element2 = {"backend": "sim", "watts": spec.element_watts - ssr_w}
    config = {**day.config, "tun": {"element_watts": ssr_w}, "element2": element2}
    if min_off is not None:
        config["output"] = {"min_off": min_off}
    day = dataclasses.replace(day, plant=plant, config=config, duration=tf.FAULT_AT + 1800.0)
    result = scenario.run(with_current(day), spec.config(config_module.DEFAULT), keep_records=True)
    before = [r for r in result.records if tf.FAULT_AT - 600.0 <= r.t < tf.FAULT_AT]
    assert min(r.output for r in before) > 99.0  # the SSR asked (all but) fully on
    assert not any(r.switched2 for r in before)  # and the contactor's element off
    hour = [r for r in result.records if tf.FAULT_AT - 3600.0 <= r.t < tf.FAULT_AT]
    held = [r for r in hour if r.output > 99.0 and not r.switched2]  # the SSR's alone
    gaps = [r.t for r in held if r.applied < 100.0]
    assert {round(100.0 - r.applied, 6) for r in held if r.t in gaps} == {round(gap / 0.05, 6)}
    assert min(b - a for a, b in itertools.pairwise(gaps)) >= every
    [alarm] = result.summary["alarms"]
    assert alarm["kind"] == "ssr_stuck_on"
    assert alarm["message"].startswith("the current input reads current")
    assert alarm["detected_after_s"] <= every + 2 * PERIOD


def test_an_element_gone_open_is_latched_by_the_current_within_one_period() -> None:
    result = scenario.run(with_current(tf.element_dies(SPEC)))
    [alarm] = result.summary["alarms"]
    assert alarm["kind"] == "heater_not_heating"
    assert alarm["detected_after_s"] <= PERIOD
    assert "the element, its wiring or the current sensor" in alarm["message"]


def test_an_element_gone_open_in_a_hold_of_pulses_too_short_to_read_is_told_at_the_next_pulse() -> (
    None
):
    """12 kW on 16 L in a 35 °C room holds 66 °C at under 1 %: some 35 ms a window, under the
    80 ms a read needs, so without a rule no on-sample is taken until the water, cooling, asks
    for longer pulses (minutes). With the input fitted the planner joins the duty into pulses
    two reads long, and the first after the element goes open tells it: within the pulses'
    spacing (the least pulse ÷ the duty) and a window."""
    spec = TunSpec("small, big element, warm room", 16, 12000, 0.5, 60, 20, 35)
    at = 2 * 3600.0 + 1.7
    day = with_current(dataclasses.replace(spec.brew_day(), duration=at + 1800.0))
    day = dataclasses.replace(day, events=(*day.events, Event(at, "heater", "open")))
    result = scenario.run(day, spec.config(config_module.DEFAULT), keep_records=True)
    [alarm] = result.summary["alarms"]
    assert alarm["kind"] == "heater_not_heating"
    assert alarm["message"].startswith("the current input reads no current")
    hold = [r.applied for r in result.records if at - 600.0 <= r.t < at]
    duty = sum(hold) / len(hold) / 100.0
    assert 0.0 < duty * PERIOD < 0.08  # a window's share of the duty: no read fits it
    assert alarm["detected_after_s"] <= 0.19 / duty + PERIOD


def test_a_ct_unplugged_from_the_start_is_said_never_latched(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.WARNING, logger="hermsd")
    day = with_current(tf.normal_day(SPEC), Event(0.0, "current", "unplugged"))
    result = scenario.run(day)
    assert result.summary["alarms"] == []
    said = [r.message for r in caplog.records if "no current seen" in r.message]
    assert said == [
        "no current seen with the element on: check the current sensor (the current "
        "verdicts are off until it shows some)"
    ]


def test_a_ct_unplugged_after_it_showed_current_latches_heater_not_heating() -> None:
    day = with_current(tf.normal_day(SPEC), Event(tf.FAULT_AT, "current", "unplugged"))
    [alarm] = scenario.run(day).summary["alarms"]
    assert alarm["kind"] == "heater_not_heating"  # the heater off: the safe side
    assert alarm["at_s"] - tf.FAULT_AT <= PERIOD


def test_a_reader_that_fails_is_a_warning_and_its_recovery_said(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.INFO, logger="hermsd")
    day = with_current(
        tf.normal_day(SPEC),
        Event(tf.FAULT_AT, "current", "failing"),
        Event(tf.FAULT_AT + 600.0, "current", "ok"),
    )
    result = scenario.run(day)
    assert result.summary["alarms"] == []
    said = [r.message for r in caplog.records if r.message.startswith("current sensor")]
    assert said == [
        "current sensor fault: [Errno 121] the current input cannot be read (simulated) (the "
        "current verdicts are off; the temperature's stand)",
        "current sensor reads again: the current verdicts are on",
    ]


def test_the_status_shows_the_current_and_while_its_verdicts_are_off_says_why() -> None:
    """Through the daemon's status (what `hermsd status`, the web page and MQTT show): the
    latest sample's amps, the element's watts over the simulated mains' 230 V when the SSR
    was on, none when off; a failing input is a warning that stands until it reads again."""
    day = with_current(tf.normal_day(SPEC))
    config = effective_config(SPEC.config(config_module.DEFAULT), day)
    clock = VirtualClock()
    world = build_world(config, clock, day.plant)
    assert world.current is not None
    daemon = assemble(
        config,
        clock,
        world.sensor,
        world.outputs,
        current_sense=world.current,
        saver=Saver(threaded=False),
    )
    LoopLink(daemon).attach(Inbox())
    seen: set[tuple[bool, float]] = set()
    for t in range(600, 7200, 5):  # the heat-up's full power, then the hold's duty
        daemon.run(until=float(t))
        current = status_of(daemon)["current"]
        seen.add((current["on"], current["amps"]))
        assert current["judging"] and current["warning"] is None
        assert 0.0 <= current["age_s"] <= PERIOD
    assert seen == {(True, SPEC.element_watts / 230.0), (False, 0.0)}
    assert status_of(daemon)["warnings"] == []
    world.current.set_fault("failing")
    daemon.run(until=7800.0)
    status = status_of(daemon)
    assert status["current"]["judging"] is False
    warning = (
        "current sensor fault (the current verdicts are off): [Errno 121] the current input "
        "cannot be read (simulated)"
    )
    assert status["current"]["warning"] == warning and status["warnings"] == [warning]
    world.current.set_fault("ok")
    daemon.run(until=8100.0)
    assert status_of(daemon)["warnings"] == [] and status_of(daemon)["current"]["judging"]
    assert status_of(daemon)["alarms"] == []
    daemon.shutdown()


@pytest.mark.parametrize(
    ("on", "drawing", "amps", "warning", "words"),
    [
        (True, True, 13.04, None, "element current 13.0 A (SSR on)"),
        (False, False, 0.0, None, "element current 0.0 A (SSR off)"),
        (True, True, None, None, "element current powered (SSR on)"),
        (None, None, None, None, "element current --"),
        (True, None, None, "current sensor fault (…)", "element current: not judging"),
    ],
)
def test_hermsd_status_says_the_current_in_a_line(
    on: bool | None, drawing: bool | None, amps: float | None, warning: str | None, words: str
) -> None:
    # `hermsd status`'s line under the status line; the warning's words are its own line.
    current = {"on": on, "drawing": drawing, "amps": amps, "warning": warning}
    assert current_words(current) == words


# -- replay --------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def short_day_log(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    directory = tmp_path_factory.mktemp("current-short")
    scenario.run(with_current(tf.ssr_shorts(SPEC)), log_dir=directory)
    return sorted(directory.glob("*.mcap"))


def test_a_day_with_a_current_caught_fault_replays_exact(short_day_log: list[Path]) -> None:
    log = reader.load(short_day_log)
    said = [line for p in log.periods for line in p.current_said or []]
    assert [line for line in said if line.startswith("ssr_stuck_on: ")]
    assert any("ssr_stuck_on" in p.alarms for p in log.periods)
    result = replay.verify(log.entries)
    assert result.mismatch is None
    assert result.verified > 1000


def test_replay_names_a_period_whose_current_samples_were_altered(
    short_day_log: list[Path],
) -> None:
    log = reader.load(short_day_log)
    target = next(p for p in log.periods if any("ssr_stuck_on" in s for s in p.current_said or []))
    assert target.current is not None
    cleared = [[*s[:2], False, 0.0, None] for s in target.current]  # no current ever flowed

    altered = [dataclasses.replace(e, current=cleared) if e is target else e for e in log.entries]
    result = replay.verify(altered)
    assert result.mismatch is not None
    assert result.mismatch.k == target.k
    assert result.mismatch.name.startswith("current_said")


def test_replay_refuses_a_malformed_current_sample_in_one_line(
    short_day_log: list[Path],
) -> None:
    log = reader.load(short_day_log)
    target = next(p for p in log.periods if p.current)
    broken = dataclasses.replace(target, current=[[target.t, True]])
    entries = [broken if e is target else e for e in log.entries]
    with pytest.raises(reader.ReplayError, match=f"period k={target.k}: a current sample is"):
        replay.verify(entries)
