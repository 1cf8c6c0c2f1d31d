"""The heat-up's probe of two elements: its share by hand on a tun made of straight lines,
then the simulator's heat-ups (virtual clock) at half and twice the fill and with each kind
of element dead from the start, and replay re-running a probed day."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
from test_element2 import logged_daemon, two_element_config

from hermsd.control import laws, pid, predictive
from hermsd.control.element2 import PowerSplit, SplitController
from hermsd.log.reader import load
from hermsd.log.replay import verify
from hermsd.runtime.period import PeriodRecord
from hermsd.safety.element_probe import BELOW, FIT_S, PROBE_S, SETTLE_S, ElementProbe, ProbeResult
from hermsd.sim import tun_faults as tf
from hermsd.sim.scenario import Event, Scenario, run
from hermsd.sim.tuns import TunSpec

H = 1.0
W1, W2 = 2000.0, 3500.0
THETA = 115.0  # the config's dead time: the tun below shows heat exactly this late
C = 90.0 * 4186.0  # J/K: 90 L of water
LOSS = 500.0  # W at any temperature


def _heat_up(
    gives1: float,
    gives2: float,
    bend: float = 0.0,
    until: float = 3000.0,
    water: tuple[float, float] | None = None,
) -> tuple[list[ProbeResult], list[float]]:
    """The probe fed a heat-up from 20 °C whose PV is the heat, less LOSS, over C, THETA
    late, plus ½·`bend`·t² (°C/s²), less `water` (when, °C) from then on: straight lines but
    where the probe switched the SSR's element off, unless bent. The findings, and the
    periods the SSR's element was off."""
    probe = ElementProbe(W1, W2, H, THETA)
    off: list[float] = []
    found: list[ProbeResult] = []
    t = 0.0
    while t < until:
        t += H
        seen = t - THETA  # the heat that reached the sensor by now was switched by then
        heat = max(0.0, seen) * (W1 * gives1 + W2 * gives2 - LOSS)
        heat -= W1 * gives1 * H * sum(1 for s in off if s + H <= seen)
        pv = 20.0 + heat / C + 0.5 * bend * max(0.0, seen) ** 2
        if water is not None and t >= water[0]:
            pv -= water[1]  # cold water landed: the PV a step lower from then on
        if probe.step(66.0, pv, True):
            off.append(t)  # off for the period that starts now
        if (result := probe.take()) is not None:
            found.append(result)
    assert len(off) in (0, PROBE_S / H)
    return found, off


def test_both_heating_take_their_share_of_the_rise() -> None:
    # The offset at the probe's middle is P1·t/C = 2000·60/376740 = 0.3185 °C, and the rise
    # over the same 60 s (5500 − 500)·60/C = 0.7963 °C: a share of 2000/5000 = 0.4.
    (found,), _ = _heat_up(1.0, 1.0)
    assert found.element is None and found.share == pytest.approx(0.4, abs=1e-6)
    assert "both elements heat: 40 ± 0 %" in found.message


@pytest.mark.parametrize("at", [900.0, 1400.0, 2000.0])
def test_water_landing_in_the_judged_heat_up_names_no_element(at: float) -> None:
    # A step of 0.8 °C down (3 L of 15 °C water into 90 L at 40 °C) in the side before the
    # probe (it starts at 1131 s), between it and the side after, or in that side: a level
    # moved by as much as the probe's 0.32 °C twice over, which no missing heat explains.
    (found,), _ = _heat_up(1.0, 1.0, water=(at, 0.8))
    assert found.element is None
    assert found.message == "elements not checked: the water fell in the heat-up (added?)"


def test_a_heat_up_bent_by_its_losses_is_judged_by_its_rise_midway() -> None:
    # Losses growing with the temperature bend the rise: −1e-6 °C/s² takes 0.0005 °C/s off
    # the straight rise's 0.01327 in 500 s. Both sides span 600 s (the heat-up leaves time
    # for it: 1131 + 1190 s from 20 °C at under 0.0133 °C/s stays below 56 °C); their middles
    # are 300 s before the probe's start and 60 + 530 + 300 s after it (+ half a period each,
    # the points being the periods' ends), so midway is 295.5 s after the start. The levels'
    # difference is the missing heat exactly, 0.3185 °C, and the rise is the slope there:
    # 5000 W/C + bend·(t − THETA).
    bend = -1e-6
    (found,), off = _heat_up(1.0, 1.0, bend)
    midway = off[0] + (PROBE_S + 2.0 * THETA + SETTLE_S) / 2.0 + H / 2.0
    rise = (5000.0 / C + bend * (midway - THETA)) * PROBE_S
    assert found.share == pytest.approx(W1 * PROBE_S / C / rise, abs=1e-6)
    assert found.element is None


def test_a_dead_ssr_element_is_named() -> None:
    # Nothing missing when it is off: a share of 0.
    (found,), _ = _heat_up(0.0, 1.0)
    assert found.element == 1 and found.share == pytest.approx(0.0, abs=1e-6)


def test_a_dead_second_element_is_named() -> None:
    # The probe stops all heating: 2000/(2000 − 500) = 4/3 of the rise missing.
    (found,), _ = _heat_up(1.0, 0.0)
    assert found.element == 2 and found.share == pytest.approx(4.0 / 3.0, abs=1e-6)


def test_too_little_time_before_the_setpoint_says_the_elements_were_not_checked() -> None:
    probe = ElementProbe(W1, W2, H, THETA)
    # 0.03 °C/s from 20 °C: 650 s of full power (its fit, twice the dead time and the
    # settling) reach 39.5 °C, and the probe and its second fit take 60 + 530 + 120 = 710 s
    # more: 21.3 °C, past 66 − 10 °C.
    lead = FIT_S[0] + 2.0 * THETA + SETTLE_S
    for k in range(1, int(lead) + 2):
        assert not probe.step(66.0, 20.0 + 0.03 * k, True)
    found = probe.take()
    assert found is not None and found.element is None
    assert "not checked: too little time" in found.message
    assert not probe.step(66.0, 41.0, True)  # once: it never probes after


def test_an_interrupted_probe_is_given_up_and_not_tried_again() -> None:
    probe = ElementProbe(W1, W2, H, THETA)
    t = 0.0
    while not probe.step(66.0, 20.0 + 0.01 * t, True):
        t += H
    probe.abandon()  # the controller held: an alarm, manual, a program waiting
    found = probe.take()
    assert found is not None and "interrupted" in found.message
    assert not any(probe.step(66.0, 30.0 + 0.01 * k, True) for k in range(2000))


def test_a_spell_that_ends_within_its_band_says_so() -> None:
    probe = ElementProbe(W1, W2, H, THETA)
    assert not probe.step(66.0, 66.0 - BELOW + 1.0, False)  # a hold: nothing said
    assert probe.take() is None
    assert not probe.step(66.0, 63.0, True)  # a recovery: full power too near the setpoint
    found = probe.take()
    assert found is not None and "no full-power spell" in found.message


TUN = TunSpec("60 L lidded", 60, W1 + W2, 1.0, 45, 10, 20)
HEAT_UP = 2700.0  # s: the probe is judged by (530 + 600) + 60 + (530 + 600) s


def _heat_up_day(day: Scenario, *events: Event, check: bool = True) -> Scenario:
    plant = {**day.plant, "element_watts": W1, "element2_watts": W2}
    config = {
        "tun": {"element_watts": W1, "litres": TUN.litres},
        "element2": {"backend": "sim", "watts": W2, "check": check},
    }
    return dataclasses.replace(day, plant=plant, config=config, events=events, duration=HEAT_UP)


def _named(day: Scenario) -> list[int]:
    result = run(day, keep_records=True)
    assert result.summary["alarms"] == []
    return sorted({e for r in result.records for e in (r.no_heat or [])})


@pytest.mark.parametrize("fill", [0.5, 2.0])
def test_no_warning_at_half_and_twice_the_fill(fill: float) -> None:
    assert _named(_heat_up_day(tf.normal_day(TUN, fill))) == []


@pytest.mark.parametrize(("fault", "element"), [("heater", 1), ("heater2", 2)])
def test_an_element_dead_from_the_start_is_named(fault: str, element: int) -> None:
    dead = Event(1.0, fault, "open")
    assert _named(_heat_up_day(TUN.brew_day(), dead)) == [element]
    assert _named(_heat_up_day(TUN.brew_day(), dead, check=False)) == []


def test_replay_re_runs_the_probe_and_its_warning(tmp_path: Path) -> None:
    config = two_element_config(algorithm="predictive")
    daemon, world, clock, recorder = logged_daemon(config, tmp_path, 5)
    world.plant.set_element_ok(False, clock.monotonic())  # the SSR's element dead from 0 s
    with daemon:
        daemon.run(until=HEAT_UP)
    recorder.close()
    entries = load(sorted(tmp_path.iterdir())).entries
    periods = [e for e in entries if isinstance(e, PeriodRecord)]
    # The SSR off with the contactor on, before its element was said dead (after, it is not
    # asked at all: the contactor holds the tun alone).
    probed = [
        p for p in periods if p.on2 and p.output == 0.0 and p.pv is not None and not p.no_heat
    ]
    assert len(probed) == PROBE_S / config.control.period
    assert periods[-1].no_heat == [1]
    assert verify(entries).mismatch is None
    # A log whose SSR was not off in the probe is caught at its first period.
    index = next(i for i, e in enumerate(entries) if e is probed[0])
    entries[index] = dataclasses.replace(probed[0], output=100.0)
    mismatch = verify(entries).mismatch
    assert mismatch is not None and mismatch.k == probed[0].k and mismatch.name == "output"


def test_replay_of_a_log_missing_periods_before_the_probe_leaves_it_unknown(
    tmp_path: Path,
) -> None:
    """Periods missing from the log (a disk that failed) before the probe ran: what the
    daemon's probe did in them is not known, so no period after them is held against it."""
    config = two_element_config(algorithm="predictive")
    daemon, _world, _clock, recorder = logged_daemon(config, tmp_path, 5)
    with daemon:
        daemon.run(until=HEAT_UP)
    recorder.close()
    entries = load(sorted(tmp_path.iterdir())).entries
    periods = [e for e in entries if isinstance(e, PeriodRecord)]
    first_off = next(p for p in periods if p.on2 and p.output == 0.0 and p.pv is not None)
    # lose a stretch of ten minutes that ends a minute before the probe began
    lost = {p.k for p in periods if first_off.t - 660.0 <= p.t < first_off.t - 60.0}
    gapped = [e for e in entries if not (isinstance(e, PeriodRecord) and e.k in lost)]
    result = verify(gapped)
    assert result.mismatch is None
    assert result.unknown_state > 0


def test_the_power_back_after_the_probe_is_no_step_that_measures_the_tun() -> None:
    """Full power again after the probe held the SSR's element off is the loop's own doing:
    a heat-up or recovery watch armed on it would fit a 36 % step to a rise made by 100 %
    (a model rate 2.65× the tun's on a slow heat-up). The watch is armed on a step to full
    power from below it, unless told that step is the loop's."""
    for told in (False, True):
        controller = laws.create(
            "predictive", kc=120.0, ti=800.0, ts=5.0, out_max=100.0, model=pid.SEED_HLT
        )
        assert isinstance(controller, predictive._Predictive)
        controller.reset(30.0, 63.6)
        pv = 30.0
        for _ in range(20):  # a slow heat-up at 63.6 %, as in the probe: the PV steady
            pv += 0.001
            controller.step(66.0, pv, 63.6)
        if told:
            predictive.loops_own_step(controller)
        controller.step(66.0, pv, 100.0)  # the SSR's element back on
        assert (controller._watch.active or controller._recovery.active) is not told


def test_the_split_tells_its_controller_the_power_back_after_the_probe_is_its_own(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The step whose power before last was the probe's is the one told (`loops_own_step`)."""

    class Held(ElementProbe):
        def __init__(self) -> None:
            super().__init__(W1, W2, H, 115.0)
            self.n = 0

        def step(self, setpoint: float, pv: float, full: bool) -> bool:
            self.n += 1
            return self.n in (3, 4)  # the SSR's element held off in steps 3 and 4

    steps: list[float] = []
    told: list[int] = []
    monkeypatch.setattr(predictive, "loops_own_step", lambda _c: told.append(len(steps) + 1))
    inner = laws.create("predictive", kc=120.0, ti=800.0, ts=H, out_max=100.0, model=pid.SEED_HLT)
    split = SplitController(inner, PowerSplit(W1, W2, H, 120.0, 120.0), Held())
    for _ in range(8):
        steps.append(split.step(66.0, 30.0, 100.0))
    assert (steps[2], steps[3]) == (0.0, 0.0)  # held off in steps 3 and 4
    assert told == [5, 6]  # their power is what steps 5 and 6 see as the one before last


RELOAD_AT = 2500.0
"""s: after the probe found the SSR's element dead (judged by 2320 s, HEAT_UP above)."""


@pytest.mark.parametrize(
    ("change", "kept"),
    [
        ({"control": {"dead_time": 120.0}}, True),  # the element watch starts afresh
        ({"control": {"kc": 100.0}}, True),  # a retune: a new controller
        ({"tun": {"litres": 61.0}}, False),  # another tun: probed afresh
    ],
)
def test_a_reload_keeps_the_probes_finding_unless_it_changed_the_tun(
    change: dict[str, dict[str, float]], kept: bool, tmp_path: Path
) -> None:
    dead = Event(1.0, "heater", "open")
    reload = Event(RELOAD_AT, "config", change)
    day = dataclasses.replace(_heat_up_day(TUN.brew_day(), dead, reload), duration=3600.0)
    result = run(day, keep_records=True, log_dir=tmp_path)
    named = {r.t: r.no_heat for r in result.records}
    assert named[RELOAD_AT - 5.0] == [1]
    assert all(n == ([1] if kept else []) for t, n in named.items() if t > RELOAD_AT + 5.0)
    # Not probed again: the SSR's element is off in the probe's 60 s only, while not said
    # dead (then it is not asked at all).
    probed = [
        r
        for r in result.records
        if r.switched2 == 100.0
        and r.output == 0.0
        and r.pv is not None
        and r.pv < 66.0 - BELOW
        and not r.no_heat
    ]
    assert len(probed) == PROBE_S / 5.0
    assert verify(load(sorted(tmp_path.glob("*.mcap"))).entries).mismatch is None


def test_a_contactor_dead_from_the_start_leaves_the_ssr_to_hold_without_an_alarm() -> None:
    """Named in the heat-up, the contactor is no longer asked and the SSR's 2 kW holds the
    60 L tun alone. The heat-up's fit measured the SSR's heat as both elements' full power,
    so limits tightened by it read the SSR alone at full (36 % of both) as heat beyond what
    was switched on: a shorted SSR latched, both off, an hour into the hold. Said dead, the
    fit is taken back and the limits are the config's."""
    day = tf.normal_day(TUN, 1.0)
    events = tuple(e for e in day.events if e.at < 3.0 * 3600.0)
    dead = Event(1.0, "heater2", "open")
    whole = dataclasses.replace(_heat_up_day(day, dead, *events), duration=3.0 * 3600.0)
    result = run(whole, keep_records=True)
    assert result.summary["alarms"] == []
    assert result.records[-1].no_heat == [2]
    # The SSR alone brings it to the setpoint, and not past it.
    held = [r.pv for r in result.records if r.pv is not None]
    assert max(held) < 66.2 and abs(held[-1] - 66.0) < 0.2
