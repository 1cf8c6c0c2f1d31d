"""The program's pump timer (docs/herms.md, "The pump's timer"): a rest's `pump_off_every`
and `pump_off_for` stop the pump hermsd switches for a while and start it again, each turn
known ahead. The stop is announced to the HLT law a dead time before it (the coil's load
told to end then), so the heat in flight for the coil does not land in water the coil no
longer draws from; the restart is prepared like any start.

The plant is tests/test_pump_start.py's: a 90 L HLT, 9 kW, its heat 60 s late and the sensor
10 s behind (the daemon's dead time 70 s), a coil of 188.6 W/K to 50 L and 12 kg doughed in at
45 °C, so that the outer loop climbs with the HLT at the limit (66 + 10 °C) while the timer
turns: the coil then draws some 188.6 × (76 − 50) ≈ 4.9 kW.
"""

from __future__ import annotations

import copy
import itertools
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from test_pump_start import (
    ALLOWED_DROP,
    DEAD_TIME,
    DOUGH_AT,
    LITRES,
    PERIOD,
    REST,
    WATTS,
    TracedTun,
    config,
    dough,
    held_law,
    hlt,
)

from hermsd.cli import main
from hermsd.config.read import parse
from hermsd.control import predictive
from hermsd.program import model
from hermsd.program.runner import Runner
from hermsd.runtime import notify
from hermsd.runtime.period import PeriodRecord
from hermsd.sim import scenario
from hermsd.sim.hlt import WATER_J_PER_LITRE_K

LIMIT = 10.0  # herms.max_hlt_above_mash's default
EVERY, STOP = 900.0, 120.0  # s: the rest's timer
RUNS = EVERY - STOP
K = 188.6  # W/K: the coil's ε·ṁc (250 W/K at 6 L/min)
DAY_S = DOUGH_AT + EVERY + 600.0


def timer_doc(timer: bool) -> dict[str, Any]:
    """Strike at the limit, "Mash in" at DOUGH_AT, then a rest of 66 °C whose pump the timer
    stops (`timer`), or that the brewer stops and restarts at the same instants with
    `hermsd set pump` (no timer: the stop unannounced)."""
    rest: dict[str, Any] = {"name": "Rest", "setpoint": REST, "hold": "60m"}
    events: list[dict[str, Any]] = [
        {"at": f"{DOUGH_AT:g}s", "dough_in": dough(45.0)},
        {"at": f"{DOUGH_AT:g}s", "confirm": "Mash in"},
    ]
    if timer:
        rest |= {"pump_off_every": f"{EVERY:g}s", "pump_off_for": f"{STOP:g}s"}
    else:
        events += [
            {"at": f"{DOUGH_AT + RUNS:g}s", "pump": "off"},
            {"at": f"{DOUGH_AT + EVERY:g}s", "pump": "on"},
        ]
    strike = {"name": "Strike", "setpoint": REST + LIMIT - 0.2, "hold": "0s", "confirm": "Mash in"}
    return {
        "name": "pump-timer",
        "duration": f"{DAY_S:g}s",
        "setpoint": REST,
        "plant": {"model": "physical", "litres": LITRES, "element_watts": WATTS},
        "events": events,
        "program": {"name": "Timer", "steps": [strike, rest]},
    }


def timer_day(
    timer: bool, attach: Callable[[Any], None] | None = None
) -> tuple[TracedTun, list[PeriodRecord]]:
    """`timer_doc`'s day on tests/test_pump_start.py's plant (`attach`: handed the daemon)."""
    tun = TracedTun(hlt(WATTS, REST + LIMIT - 0.2), coil_w_per_k=250.0, mash_ua_w_per_k=5.0)
    result = scenario.run(
        scenario.parse_scenario(timer_doc(timer)),
        parse(config("sim")),
        outside_plant=tun,
        keep_records=True,
        attach=attach,
    )
    return tun, result.records


def switches(records: list[PeriodRecord]) -> list[tuple[float, bool]]:
    return [(b.t, bool(b.pump)) for a, b in itertools.pairwise(records) if a.pump != b.pump]


def highest(tun: TracedTun, start: float, end: float) -> float:
    return max(c for t, c in tun.trace.items() if start <= t <= end)


def test_the_timer_stops_and_restarts_the_pump_at_its_turns() -> None:
    _, records = timer_day(True)
    turns = switches(records)
    # The rest begins at the "Mash in" period; its first start is prepared (a dead time
    # late), the timer counts from the rest's start: off at 780 s, on again at 900 s, the
    # restart prepared so that the pump runs at its turn (within a period).
    assert [on for _, on in turns[:3]] == [True, False, True]
    (first, _), (stop, _), (restart, _) = turns[:3]
    assert first == DOUGH_AT + DEAD_TIME
    assert abs(stop - (DOUGH_AT + RUNS)) <= PERIOD
    assert abs(restart - (DOUGH_AT + EVERY)) <= PERIOD
    announced = [r for r in records if r.pump_stop_in is not None]
    assert announced and all(0.0 < (r.pump_stop_in or 0.0) <= DEAD_TIME for r in announced)
    assert all(DOUGH_AT + RUNS - DEAD_TIME - PERIOD <= r.t < stop for r in announced)


def test_an_unannounced_stop_lands_the_heat_in_flight_and_the_climbs_room_holds_the_limit() -> None:
    """Unannounced, the element's heat in flight for the coil's draw lands in water nothing
    draws from: the load × the dead time over the HLT's heat capacity (some 4.9 kW × 60 s
    / 377 kJ/K ≈ 0.8 °C, less what the law cuts once it sees the rise). Announced, the heat
    sent from a dead time before the stop is the water's alone. Either way the HLT stays
    under its limit: the climb's setpoint keeps room for the landing (`cascade.stop_room`)."""
    capacity = WATER_J_PER_LITRE_K * LITRES
    load = K * (REST + LIMIT - 50.0)  # the HLT at the limit, the mash near 50 °C
    in_flight = load * (DEAD_TIME - 10.0) / capacity  # the element's 60 s, not the sensor's
    limit = REST + LIMIT
    rises = {}
    for timer in (True, False):
        tun, _ = timer_day(timer)
        stop = DOUGH_AT + RUNS
        at_stop = tun.trace[min(tun.trace, key=lambda t: abs(t - stop))]
        peak = highest(tun, stop, stop + 300.0)
        assert peak <= limit
        rises[timer] = peak - at_stop
    assert rises[False] >= rises[True] + 0.35 * in_flight  # the landing the timer spares


def test_the_restart_after_a_timer_stop_meets_the_hlt_it_left() -> None:
    """The HLT's setpoint kept through the stop, the restart prepared: no fall below the
    lesser of where the HLT stood and its setpoint (bench/herms.py's measure) of more than
    ALLOWED_DROP while the climb goes on. Readied for the mash's shortfall during the stop
    instead, the HLT came down towards that and climbed again as the pump restarted (0.52 °C
    on bench seed 5)."""
    tun, records = timer_day(True)
    restart = DOUGH_AT + EVERY
    stopped = [r for r in records if DOUGH_AT + RUNS + PERIOD <= r.t < restart]
    running = [r for r in records if DOUGH_AT + RUNS - 2 * DEAD_TIME <= r.t < DOUGH_AT + RUNS]
    assert stopped and running
    assert {r.hlt_setpoint for r in stopped} <= {r.hlt_setpoint for r in running}
    held = next(c for t, c in sorted(tun.trace.items()) if t >= restart)
    # Until the climb it restarted in ends (the coast then lets the HLT fall by design).
    after = [r for r in records if r.t >= restart]
    ends = next(r.t for r in after if r.pump and r.cascade != "climb")
    window = [r for r in after if r.t < ends]
    fall = max(min(held, r.hlt_setpoint or math.inf) - tun.trace[r.t] for r in window)
    assert fall <= ALLOWED_DROP


TIMED = """\
name: Timed
steps:
  - {name: Strike, setpoint: 72, hold: 0s, confirm: Mash in}
  - {name: Rest, setpoint: 66, hold: 60m, pump_off_every: 20m, pump_off_for: 2m}
  - {name: Mash out, setpoint: 78, hold: 10m}
"""


def test_a_pump_timer_is_read_kept_as_data_and_said() -> None:
    program = model.parse(TIMED, "timed.yaml")
    assert program.steps[1].pump_timer == (1200.0, 120.0)
    assert program.steps[2].pump_timer is None
    assert model.from_data(model.to_data(program)) == program
    assert model.describe_step(program.steps[1]).endswith("pump off 2 min every 20 min")


@pytest.mark.parametrize(
    ("keys", "says"),
    [
        ("pump_off_every: 20m", "steps[1].pump_off_for: missing (a pump timer needs both"),
        ("pump_off_for: 2m", "steps[1].pump_off_every: missing"),
        ("pump_off_every: 20, pump_off_for: 2m", "steps[1].pump_off_every: 20 has no unit"),
        (
            "pump_off_every: until told, pump_off_for: 2m",
            "steps[1].pump_off_every: a pump timer's times are durations",
        ),
        ("pump_off_every: 2m, pump_off_for: 1m30s", "90 s off every 120 s: stop the pump"),
        ("pump_off_every: 20m, pump_off_for: 5s", "5 s off every 1200 s"),
        ("pump: off, pump_off_every: 20m, pump_off_for: 2m", "a pump timer on a step whose pump"),
    ],
)
def test_a_pump_timer_that_cannot_run_is_refused_with_its_line(keys: str, says: str) -> None:
    text = TIMED.replace("pump_off_every: 20m, pump_off_for: 2m", keys)
    with pytest.raises(model.ProgramError) as raised:
        model.parse(text, "timed.yaml")
    assert str(raised.value).startswith("timed.yaml:4:")
    assert says in str(raised.value)


def test_a_pump_timer_on_the_strike_waiting_for_the_mash_is_refused() -> None:
    text = TIMED.replace(
        "confirm: Mash in}", "confirm: Mash in, pump_off_every: 20m, pump_off_for: 2m}"
    )
    with pytest.raises(model.ProgramError, match=r"timed.yaml:3:.*a pump timer on a step whose"):
        model.parse(text, "timed.yaml")


def test_the_runner_turns_the_pump_by_the_steps_own_clock() -> None:
    """Run 18 min, stop 2 min, counted from the step's start (`program next` at 0 s, the
    periods 5 s apart), on through a pause (the pump's timer is not the rest's)."""
    program = model.parse(TIMED, "timed.yaml")
    runner = Runner.start(program, max_step_s=2 * PERIOD)
    runner.period(0.0, 72.0)  # the strike held, waiting for "Mash in"
    assert runner.pump is False and runner.pump_turn_in() is None
    runner.command("next", 72.0)  # the mash is in: the rest begins now
    seen: dict[float, tuple[bool, int, float | None]] = {}
    for n in range(1, 481):
        t = n * PERIOD
        runner.period(t, 66.0)
        if t == 150.0:
            runner.command("pause", 66.0)
        seen[t] = (runner.pump, runner.pump_turns(), runner.pump_turn_in())
    assert seen[5.0] == (True, 0, 1075.0)
    assert seen[1075.0] == (True, 0, 5.0)
    assert seen[1080.0] == (False, 1, 120.0)
    assert seen[1195.0] == (False, 1, 5.0)
    assert seen[1200.0] == (True, 2, 1080.0)
    assert seen[2280.0] == (False, 3, 120.0)


def test_a_load_announced_to_end_is_no_load_once_it_has() -> None:
    """Ending now, the load told the law is none at all; ending before it starts is refused."""
    plain = held_law()
    ended = copy.deepcopy(plain)
    predictive.known_load(ended, 1000.0, 4000.0, starts_in=0.0, ends_in=0.0)
    assert ended.step(66.0, 66.0, ended.output) == plain.step(66.0, 66.0, plain.output)
    # Ending after the dead time, its whole share is in the holding duty (25 % of 4 kW).
    late = copy.deepcopy(plain)
    running = copy.deepcopy(plain)
    predictive.known_load(late, 1000.0, 4000.0, ends_in=600.0)
    predictive.known_load(running, 1000.0, 4000.0)
    assert late.step(66.0, 66.0, late.output) == running.step(66.0, 66.0, running.output)
    with pytest.raises(ValueError, match=r"ending in 10\.0 s is invalid"):
        predictive.known_load(plain, 1000.0, 4000.0, starts_in=20.0, ends_in=10.0)


def test_program_check_warns_of_a_timer_where_hermsd_switches_no_pump(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A pump outside hermsd (`pump.backend: none`, seen or not) cannot be stopped by it: the
    timer would do nothing, said by `program check --config` and at the program's start."""
    program, outside, fitted = tmp_path / "p.yaml", tmp_path / "out.yaml", tmp_path / "fit.yaml"
    program.write_text(TIMED, encoding="utf-8")
    outside.write_text("pump:\n  backend: none\n  sense: sim\n", encoding="utf-8")
    fitted.write_text("pump:\n  backend: sim\n", encoding="utf-8")
    assert main(["program", "check", str(program), "--config", str(outside)]) == 0
    out = capsys.readouterr().out
    assert (
        f"warning: {program}: steps[1].pump_off_every: pump.backend is none: hermsd switches "
        "no pump, so this timer stops nothing"
    ) in out
    assert out.count("warning") == 1  # the one step with a timer
    assert main(["program", "check", str(program), "--config", str(fitted)]) == 0
    assert "warning" not in capsys.readouterr().out
    said = model.config_warnings(model.parse(TIMED), parse("pump:\n  backend: none\n"))
    assert [line.split(":")[0] for line in said] == ["steps[1].pump_off_every"]


def test_the_status_says_when_the_timer_turns_next() -> None:
    """The status reply's `mash.pump_turn_in`, and the status line's words: 780 s of running
    left as the rest begins (its first start prepared), 120 s stopped once it stops."""
    seen: list[tuple[float, bool | None, object]] = []

    class Watch:
        def __init__(self, daemon: Any) -> None:
            self.daemon = daemon

        def period(self, record: PeriodRecord) -> None:
            mash = self.daemon.role_status()["mash"]
            seen.append((record.t, record.pump, mash["pump_turn_in"]))

        def alarm(self, alarm: object) -> None:
            pass

    def attach(daemon: Any) -> None:
        daemon.listeners.append(Watch(daemon))

    doc = timer_doc(True)
    tun = TracedTun(hlt(WATTS, REST + LIMIT - 0.2), coil_w_per_k=250.0, mash_ua_w_per_k=5.0)
    scenario.run(
        scenario.parse_scenario(doc), parse(config("sim")), outside_plant=tun, attach=attach
    )
    turns = {t: turn for t, _, turn in seen}
    assert turns[DOUGH_AT - PERIOD] is None  # the strike's step: no timer
    assert turns[DOUGH_AT + 100.0] == RUNS - 100.0
    assert turns[DOUGH_AT + RUNS + 20.0] == STOP - 20.0
    assert (
        notify.pump_words(True, {"pump_turn_in": RUNS - 100.0}) == "pump on, off in 11 min (timer)"
    )
    assert notify.pump_words(False, {"pump_turn_in": 100.0}) == "pump off, on in 100 s (timer)"
    assert notify.pump_words(True, {"pump_turn_in": None}) == "pump on"
