"""A mash program on a HERMS: its rests timed on the mash, not on the HLT, and its pump.

The plant is this file's own small HERMS (`CoilMash`, after test_mash_side's): the HLT is
the simulator's FOPTD tun, starting at the rests' 66 °C and steered by the mash's outer
loop (the mash here ignores it); the mash follows a coil held at exactly 66 °C while the pump
runs, dM/dt = (66 − M)/MASH_TAU_S, and stands still while it stops. From 55 °C the mash is
then within 0.5 °C of 66 °C after MASH_TAU_S·ln(11/0.5) = 600·ln 22 = 1854.6 s of pumping.
The LM92 reads in 0.0625 °C steps, and 65.5 °C is one (1048 steps): it reads the band's
edge exactly when the mash is there.
Every time below comes from that equation and the loop's timing (a period of 5 s, a read a
second, a fault declared at the second failed read), worked out by hand, never from a run.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest
from test_mash_side import LaggingMash, Periods, herms_daemon, run_for, watched

from hermsd.log import reader, replay
from hermsd.program import model
from hermsd.program.quality import step_lines
from hermsd.runtime.period import PeriodRecord
from hermsd.sim.clock import VirtualClock
from hermsd.sim.scenario import Result, parse_scenario, run

COIL_C = 66.0
MASH_TAU_S = 600.0
MASH_C = 55.0
PERIOD = 5.0
IN_BAND_AFTER_S = MASH_TAU_S * math.log((COIL_C - MASH_C) / 0.5)  # 1854.6 s of pumping
REST_S = 1200.0  # the rest's 20 minutes
CONFIRM_AT = 600.0

HERMS_CONFIG = {
    "mash_sensor": {"kind": "lm92", "address": 0x49},
    "pump": {"backend": "sim"},
}
MASH_IN_PROGRAM = {
    "name": "Mash",
    "steps": [
        {"name": "Strike", "setpoint": 66, "hold": "0s", "confirm": "Mash in"},
        {"name": "Rest", "setpoint": 66, "hold": "20m"},
        {"name": "Mash out", "setpoint": 66, "hold": "until told"},
    ],
}


class CoilMash(LaggingMash):
    """A HERMS plant: the FOPTD tun as the HLT, and a mash warmed towards COIL_C with the
    time constant MASH_TAU_S while the pump runs (exact: the solution of the equation)."""

    def __init__(self, mash_c: float = MASH_C) -> None:
        super().__init__(hlt_c=COIL_C, mash_c=mash_c)

    def _advance(self, t: float) -> None:
        if t > self.since and self.pump:
            gap = (self.mash_c - COIL_C) * math.exp(-(t - self.since) / MASH_TAU_S)
            self.mash_c = COIL_C + gap
        self.since = max(self.since, t)

    def set_pump(self, on: bool, t: float) -> None:
        """Only the changes are kept (the loop says the pump's state again every read)."""
        self._advance(t)
        if on != self.pump:
            self.pump_changes.append((t, on))
        self.pump = on


def simulate(
    program: dict[str, Any],
    events: list[dict[str, Any]],
    config: dict[str, Any],
    log_dir: Path | None = None,
) -> tuple[Result, CoilMash]:
    scenario = parse_scenario(
        {
            "name": "herms-rest",
            "duration": "1h30m",
            "setpoint": COIL_C,
            "config": config,
            "program": program,
            "events": events,
        }
    )
    plant = CoilMash()
    return run(scenario, outside_plant=plant, keep_records=True, log_dir=log_dir), plant


def first(records: list[PeriodRecord], step_index: int, holding: bool = False) -> float:
    """When the program was first at `step_index` (holding: with its hold counting)."""
    return next(
        r.t
        for r in records
        if r.step_index == step_index and (not holding or r.step_left_s is not None)
    )


@pytest.fixture(scope="module")
def mash_in_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("mash-in")


@pytest.fixture(scope="module")
def mash_in_day(mash_in_log: Path) -> tuple[Result, CoilMash]:
    events = [{"at": "10m", "confirm": "Mash in"}]
    return simulate(MASH_IN_PROGRAM, events, HERMS_CONFIG, mash_in_log)


def test_a_rest_starts_its_clock_when_the_mash_enters_the_band(
    mash_in_day: tuple[Result, CoilMash],
) -> None:
    result, plant = mash_in_day
    records = result.records
    pumped_from = plant.pump_changes[0][0]
    # The rest begins at the period after the confirm (the first from 10 min), the HLT above
    # the rest's setpoint: the outer loop (a mash sensor is fitted) sets it there for the
    # mash, which this plant's coil ignores.
    rest = [r for r in records if r.step_index == 1]
    assert rest[0].t == CONFIRM_AT + PERIOD
    # Its pump start is prepared: the pump runs at the first period within half a period of
    # the HLT law's dead time (the load sent ahead, `pump_in`) after the step began.
    lead = rest[0].pump_in
    assert lead is not None and lead > PERIOD
    due = rest[0].t + lead - PERIOD / 2
    assert due <= pumped_from < due + PERIOD and pumped_from % PERIOD == 0.0
    assert rest[0].hlt_setpoint is not None and rest[0].hlt_setpoint > COIL_C
    assert rest[0].step_left_s is None
    # The mash enters the band 1854.6 s after the pump starts; the first period from there
    # reads it (a reading at most 1 s old): the hold counts from that period on.
    reached = first(records, 1, holding=True)
    assert pumped_from + IN_BAND_AFTER_S <= reached < pumped_from + IN_BAND_AFTER_S + PERIOD + 1
    # The 20 minutes run from there: the next step begins at the period they are full.
    assert first(records, 2) == pytest.approx(reached + REST_S, abs=PERIOD)
    summary = result.summary["steps"][1]
    assert summary["mash"]["reached_s"] == pytest.approx(reached, abs=0.05)


def test_the_pump_stays_off_through_mash_in_until_the_brewer_confirms(
    mash_in_day: tuple[Result, CoilMash],
) -> None:
    result, plant = mash_in_day
    pumped_from = plant.pump_changes[0][0]
    # Never on before the confirm; off again only at the daemon's stop, the day's end.
    assert plant.pump_changes == [(pumped_from, True), (5400.0, False)]
    before = [r for r in result.records if r.t < pumped_from]  # the start's preparation too
    assert before and all(r.pump is False for r in before)
    assert all(r.mash == pytest.approx(MASH_C, abs=0.0625) for r in before)  # nothing pumped
    assert all(r.pump is True for r in result.records if r.t > pumped_from)


def test_the_strike_step_holds_the_hlt_at_its_own_setpoint_not_the_mashs_outer_loops(
    mash_in_day: tuple[Result, CoilMash],
) -> None:
    """Before "Mash in" the mash sensor reads 11 °C under the step's 66 °C: taken for a mash,
    the outer loop would ready the HLT above 66 °C, heat that coasts the mash past its rest."""
    result, plant = mash_in_day
    strike = [r for r in result.records if r.step_index == 0 and r.t < plant.pump_changes[0][0]]
    assert strike and all(r.mash == pytest.approx(MASH_C, abs=0.0625) for r in strike)
    assert {(r.hlt_setpoint, r.coil_load, r.cascade) for r in strike} == {(COIL_C, 0.0, "strike")}


def test_the_report_gives_each_rest_on_the_mash_and_not_the_strike(
    mash_in_day: tuple[Result, CoilMash],
) -> None:
    result, _ = mash_in_day
    strike, rest, _mash_out = result.summary["steps"]
    assert "mash" not in strike  # the strike water's: no mash yet
    on_mash = rest["mash"]
    # After reaching the band the mash only closes on 66 °C: no overshoot. The LM92 reads
    # 65.7 °C or more once the mash is at 65.75 °C (its step: 65.6875 below that), when
    # 66 − 11·e^(−x/600) = 65.75: 600·ln(11/0.25) = 2270.5 s after the pump started, 415.9 s
    # after the band was reached: of the rest judged (from 5 min after) all but 115.9 s.
    assert on_mash["overshoot_c"] == 0.0
    judged = on_mash["judged_s"]
    assert judged == pytest.approx(rest["end_s"] - on_mash["reached_s"] - 300.0, abs=0.05)
    assert on_mash["tight_s"] == pytest.approx(judged - 115.9, abs=PERIOD + 1)
    line = step_lines([rest])[1]
    assert line.startswith(f"  mash: reached {on_mash['reached_s']} s, within ±0.3 °C ")


def test_replay_gives_the_rests_on_the_mash_as_the_simulation_did(
    mash_in_day: tuple[Result, CoilMash], mash_in_log: Path
) -> None:
    """Replay knows the strike water's step from the log alone (it waited for the brewer)."""
    result, _ = mash_in_day
    replayed = replay.summarise(reader.load(sorted(mash_in_log.glob("*.mcap"))))
    assert "mash" not in replayed["steps"][0]
    for logged, simulated in zip(replayed["steps"][1:], result.summary["steps"][1:], strict=True):
        assert logged["mash"] == simulated["mash"]


def test_without_a_mash_sensor_the_rest_is_timed_on_the_hlt() -> None:
    result, plant = simulate(MASH_IN_PROGRAM, [{"at": "10m", "confirm": "Mash in"}], {})
    confirmed = first(result.records, 1)  # the period after the confirm's
    assert CONFIRM_AT + PERIOD <= confirmed < CONFIRM_AT + 2 * PERIOD
    assert first(result.records, 1, holding=True) == confirmed  # the HLT is in the band
    assert first(result.records, 2) == pytest.approx(confirmed + REST_S, abs=PERIOD)
    assert plant.pump_changes == []
    assert "mash" not in result.summary["steps"][1]


REST_FROM_THE_START = model.from_data(
    {
        "name": "Rest",
        "steps": [
            {"name": "Rest", "setpoint": 66, "hold": "20m"},
            {"name": "Mash out", "setpoint": 66, "hold": "until told"},
        ],
    },
    typed=True,
)
FITTED = (
    "output:\n  backend: sim\nlog:\n  dir: null\ncontrol:\n  setpoint: 66\n"
    "mash_sensor:\n  kind: lm92\n  address: 0x49\npump:\n  backend: sim\n"
)


def rest_with(fault: bool) -> tuple[float, list[str]]:
    """When the rest ended, and what the loop said, its mash sensor failing (NACK) from
    10 to 15 min when `fault`; the mash 0.1 °C under 66 °C, in the band from the start."""
    daemon, world = herms_daemon(FITTED, CoilMash(mash_c=COIL_C - 0.1))
    assert world.mash is not None
    chip = world.mash.mash_chip
    assert chip is not None
    periods = Periods()
    daemon.listeners.append(periods)
    daemon.recorder = periods
    clock = daemon.clock
    assert isinstance(clock, VirtualClock)
    clock.call_at(PERIOD / 2, lambda: daemon.start_program(REST_FROM_THE_START, None, 0.0))
    if fault:
        clock.call_at(600.0, lambda: chip.set_fault("nack"))
        clock.call_at(900.0, lambda: chip.set_fault("ok"))
    with daemon:
        run_for(daemon, 2400.0)
    return first(periods.records, 1), periods.events


def test_a_mash_sensor_fault_stops_the_rests_clock_and_says_so() -> None:
    """A rest from the start (no Mash in wait: the mash is in), its mash sensor failing for
    5 minutes: the rest runs that much longer, less the second before the fault is declared."""
    plain, calm = rest_with(fault=False)
    faulty, said = rest_with(fault=True)
    # Reads at 0.5 s past each second: 600.5 and 601.5 fail, the fault declared at 601.5;
    # 900.5 reads again: 299 s without a mash reading, counted to the periods that see it.
    assert faulty - plain == pytest.approx(299.0, abs=PERIOD)
    lost = [e for e in said if e.startswith("step 'Rest': no mash reading")]
    back = [e for e in said if e.startswith("step 'Rest': the mash reads ")]
    assert len(lost) == 1 and len(back) == 1
    assert not any("no mash reading" in e for e in calm)


MASH_IN_FILE = (
    "steps:\n"
    "  - name: Strike\n    setpoint: 72\n    hold: 0s\n    confirm: Mash in\n{strike}"
    "  - name: Rest\n    setpoint: 66\n    hold: 60m\n{rest}"
)


@pytest.mark.parametrize(
    ("rest", "pumps"),
    [
        ("", [False, True]),
        ("    pump: off\n", [False, False]),
        ("    pump: on\n", [False, True]),
        ("    pump: false\n", [False, False]),
    ],
)
def test_a_step_may_say_whether_the_pump_runs(rest: str, pumps: list[bool]) -> None:
    program = model.parse(MASH_IN_FILE.format(strike="", rest=rest), "mash.yaml")
    assert [model.pump_wanted(program, i) for i in range(2)] == pumps
    assert model.from_data(model.to_data(program)) == program  # as the socket carries it


@pytest.mark.parametrize(
    ("strike", "rest", "says"),
    [
        (
            "    pump: on\n",
            "",
            "mash.yaml:6:11: steps[0].pump: the pump stays off until the mash is in (this step "
            "waits for 'Mash in'; write pump: off, or leave it out)",
        ),
        (
            "",
            "    pump: sometimes\n",
            "mash.yaml:9:11: steps[1].pump: 'sometimes' is not one of the choices ('on' or 'off')",
        ),
    ],
)
def test_a_wrong_pump_is_refused_with_its_line(strike: str, rest: str, says: str) -> None:
    with pytest.raises(model.ProgramError) as caught:
        model.parse(MASH_IN_FILE.format(strike=strike, rest=rest), "mash.yaml")
    assert str(caught.value).startswith(says)


def test_without_a_mash_in_wait_the_pump_runs_from_the_first_step() -> None:
    program = model.parse("steps:\n  - {name: Rest, setpoint: 66, hold: 60m}\n", "rest.yaml")
    assert model.mash_in_index(program) == 0
    assert model.pump_wanted(program, 0) is True


def test_a_strike_the_hlts_limit_cannot_honour_is_warned_of_as_the_program_starts() -> None:
    """Strike 72 °C, first rest 60 °C, herms.max_hlt_above_mash 10 °C (the default): 72 > 70."""
    daemon, _world = herms_daemon()
    periods = watched(daemon)
    run_for(daemon, 2 * PERIOD)
    strike = model.Step("Strike", 72.0, 0.0, confirm="Mash in")
    program = model.Program("Hot strike", (strike, model.Step("Rest", 60.0, 1200.0)))
    assert daemon.program_problems(program) == []  # a warning: the program runs
    daemon.start_program(program, None, daemon.clock.monotonic())
    run_for(daemon, PERIOD)
    assert daemon.program.active
    assert (
        "program 'Hot strike': steps[0].setpoint: Strike 72 °C is above the first rest Rest "
        "60 °C + herms.max_hlt_above_mash 10 °C = 70 °C: the HLT will stand above the limit "
        "when the pump starts; lower the strike or raise herms.max_hlt_above_mash"
    ) in periods.events
