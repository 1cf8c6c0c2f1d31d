"""Losses that step up in the hold: no dead-element verdict on a working element.

The population's one-element tuns (bench/population.py, seeds 1…N), each on its brew day
with the day's water and sensor, and at 2.5 h in the hold the room's temperature dropped so
that the tun loses more: a lid taken off, a door opened onto a cold garage, as a step. Day 1
(shipped config) with the conduction ×1.5 (what the supervisor's measured hold allows: 1.5×
its duty), day 2 (from day 1's state) with it ×3 (beyond that: the level's verdict may
fall outside its assumption there, the climb's may not), day 3 (from day 2's) with it ×2
ramped over 20 minutes in 30-s steps (a wind that rises, a garage door left open as the
evening cools: no step within a window for the climb's halves to see; the climb's bound,
hermsd/safety/heat_balance.py `RAMP_SHARE`) and day 4 ×3 over the same 20 minutes, beyond
that bound. The extra
loss stops where the element could no longer hold the water at 75 % of its power (the
supervisor's 80 % at −10 % mains, less a margin). Every alarm on these days is false; each
is listed with its message.

    uv run --group bench python bench/loss_steps.py [--tuns 100] [--jobs 2] [--write]
"""

from __future__ import annotations

import argparse
import dataclasses
import multiprocessing
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import population as pop  # bench/population.py, beside this file
import sections

from hermsd.sim import scenario
from hermsd.sim.scenario import Event

STEP_AT_S = 2.5 * 3600.0
HOLDS_AT = 0.75
"""The most of the element's power the tun may lose after the step."""
DAYS = (("day 1", 1.5, 0.0), ("day 2", 3.0, 0.0), ("day 3", 2.0, 1200.0), ("day 4", 3.0, 1200.0))
"""Each day, the conduction's factor after its step, and the s it is ramped over (0: a
step)."""
RAMP_STEP_S = 30.0
"""s between the ramp's steps of the room."""
HEADING = "## Losses that step up in the hold: no dead-element verdict"


def one_tun(seed: int) -> dict[str, Any] | None:
    """Tun `seed`'s two days with their steps: per day, the losses' rise (× the tun's own
    losses at 66 °C) and the alarms raised; None for a two-element tun."""
    tun, _ = pop.draw(seed)
    if tun.two_elements:
        return None
    water = tun.water
    conduction = water.ua_w_per_k * (pop.SETPOINT - water.ambient_c)
    before = tun.losses_w()
    found: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="hermsd-state-") as state:
        for label, factor, ramp_s in DAYS:
            extra = min((factor - 1.0) * conduction, HOLDS_AT * water.element_watts - before)
            if extra <= 0.0:
                found[label] = None  # holding already takes that much: no step
                continue
            day = tun.day()
            steps = max(1, round(ramp_s / RAMP_STEP_S))
            colder = [
                Event(
                    STEP_AT_S + k * RAMP_STEP_S,
                    "ambient",
                    water.ambient_c - extra * (k + 1) / steps / water.ua_w_per_k,
                )
                for k in range(steps)
            ]
            events = tuple(sorted((*day.events, *colder), key=_at))
            result = scenario.run(
                dataclasses.replace(day, events=events), tun.config(), state_dir=Path(state)
            )
            alarms = [
                (a["kind"], a["at_s"], a["message"])
                for a in result.summary["alarms"]
                if a["at_s"] > 0.0  # a latch restored from day 1 is counted there
            ]
            found[label] = {"rise": extra / before, "alarms": alarms}
    return found


def _at(event: Event) -> float:
    return event.at


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tuns", type=int, default=100)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--write", action="store_true")
    args = parser.parse_args()
    started = time.perf_counter()
    with multiprocessing.get_context("fork").Pool(args.jobs) as pool:
        seeds = range(1, args.tuns + 1)
        found = dict(zip(seeds, pool.map(one_tun, seeds, 1), strict=True))
    wall = time.perf_counter() - started
    lines = [
        f"One-element tuns of seeds 1–{args.tuns} of the population, a step up of the losses at "
        f"{STEP_AT_S / 3600:g} h in the hold (the room colder: × the conduction, up to "
        f"{HOLDS_AT:.0%} of the element's power lost; days 3 and 4 ramped), {wall:.0f} s on "
        f"{args.jobs} processes. A latch leaves the heater off and the water cools towards "
        "that colder room (below −70 °C for ×3 on some tuns): a reading below the sensor's "
        "range then follows, on that day and on the next if the latch is kept over it.",
        "",
        "| day | conduction after the step | days | losses after ÷ before (median, most) "
        "| days with no alarm | first alarm: the output's watch | the balance's level "
        "| the balance's climb | the balance's stall | another kind |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for label, factor, ramp_s in DAYS:
        days = [f[label] for f in found.values() if f is not None and f[label] is not None]
        rises = sorted(d["rise"] for d in days)
        first = [_verdict(*d["alarms"][0]) for d in days if d["alarms"]]
        counts = [first.count(v) for v in VERDICTS]
        lines.append(
            f"| {label} | ×{factor:g}{f' over {ramp_s / 60:g} min' if ramp_s else ''} "
            f"| {len(days)} | ×{1 + rises[len(rises) // 2]:.2f}, "
            f"×{1 + rises[-1]:.2f} | {len(days) - len(first)} | "
            + " | ".join(str(c) for c in counts)
            + " |"
        )
    listed = [
        f"- tun {seed}, {label}: {kind} at {at_s:.0f} s: {message}"
        for seed, days in found.items()
        if days is not None
        for label, _, _ in DAYS
        if days[label] is not None
        for kind, at_s, message in days[label]["alarms"]
    ]
    if listed:
        lines += ["", "The alarms (all false):", "", *listed]
    text = "\n".join(lines)
    print(text)
    if args.write:
        sections.write(HEADING, text)
    return 0


VERDICTS = ("watch", "level", "climb", "stall", "other")


def _verdict(kind: str, at_s: float, message: str) -> str:
    """Which verdict an alarm is: the output's watch, the balance's level, climb or stall,
    or another kind of alarm."""
    if kind != "heater_not_heating":
        return "other"
    if "climbed" in message:
        return "climb"
    if "at its limit" in message:
        return "stall"
    return "level" if "on average" in message else "watch"


if __name__ == "__main__":
    sys.exit(main())
