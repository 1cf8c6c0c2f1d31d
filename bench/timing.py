"""The daemon in real time on simulated hardware: how late its periods and SSR edges are.

Runs the real loop (monotonic clock, sleeping for real) against the simulated tun, first on
an idle machine, then with every core busy (one CPU-burning process per core), and reports
control-period lateness and SSR-edge error (p50/p99/max), the CPU the daemon used and its
peak RSS. Goals: edge error p99 ≤ 10 ms, period lateness p99 ≤ 5 ms under load, CPU ≤ 1 %
of a core, RSS ≤ 50 MB.

    uv run python bench/timing.py [--seconds 300] [--write]
"""

from __future__ import annotations

import argparse
import dataclasses
import multiprocessing
import os
import resource
import sys
import time
from pathlib import Path

from hermsd import config as config_module
from hermsd.clock import MonotonicClock
from hermsd.daemon import Daemon
from hermsd.scheduler import percentile
from hermsd.sim.world import build_world
from hermsd.ssr import DeadManThread


def burn(stop_at: float) -> None:
    while time.monotonic() < stop_at:
        pass


def measure(seconds: float) -> dict[str, float]:
    config = dataclasses.replace(
        config_module.DEFAULT,
        output=dataclasses.replace(config_module.DEFAULT.output, backend="sim"),
    )
    clock = MonotonicClock()
    # Start at the setpoint, so the SSR time-proportions (at full power it has no edges).
    plant = {"model": "foptd", "start_s": clock.monotonic(), "start_c": 66.0}
    world = build_world(config, clock, plant)
    daemon = Daemon(config, clock, world.sensor, world.outputs)
    periods: list[float] = []
    edges: list[float] = []
    original_edge = daemon._on_edge  # the timers' actual-minus-planned time, per edge

    def on_edge(when: float, now: float) -> None:
        edges.append(now - when)
        original_edge(when, now)

    daemon._on_edge = on_edge  # type: ignore[method-assign]
    deadman = DeadManThread(daemon.outputs.all())
    deadman.start()
    usage0 = resource.getrusage(resource.RUSAGE_SELF)
    wall0 = time.monotonic()
    with daemon:
        daemon.start()
        control = daemon._control_task
        daemon.run(until=clock.monotonic() + seconds)
    wall = time.monotonic() - wall0
    deadman.stop()
    usage = resource.getrusage(resource.RUSAGE_SELF)
    cpu = (usage.ru_utime - usage0.ru_utime) + (usage.ru_stime - usage0.ru_stime)
    periods = sorted(control.lateness._samples)
    edges.sort()
    return {
        "period_p50_ms": percentile(periods, 50) * 1e3,
        "period_p99_ms": percentile(periods, 99) * 1e3,
        "period_max_ms": periods[-1] * 1e3,
        "edge_p50_ms": percentile(edges, 50) * 1e3,
        "edge_p99_ms": percentile(edges, 99) * 1e3,
        "edge_max_ms": edges[-1] * 1e3,
        "periods": len(periods),
        "edges": len(edges),
        "cpu_percent": 100.0 * cpu / wall,
        "rss_mb": usage.ru_maxrss / 1024.0,
        "overruns": control.overruns,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=300.0)
    parser.add_argument("--write", action="store_true", help="update bench/RESULTS.md")
    args = parser.parse_args()
    rows = {"idle": measure(args.seconds)}
    cores = os.cpu_count() or 2
    stop_at = time.monotonic() + args.seconds + 5
    burners = [multiprocessing.Process(target=burn, args=(stop_at,)) for _ in range(cores)]
    for p in burners:
        p.start()
    try:
        rows[f"{cores} cores busy"] = measure(args.seconds)
    finally:
        for p in burners:
            p.terminate()
            p.join()
    lines = [
        "| load | period p50/p99/max ms | edge p50/p99/max ms | periods | edges | CPU % "
        "| peak RSS MB | overruns |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, r in rows.items():
        lines.append(
            f"| {name} | {r['period_p50_ms']:.2f} / {r['period_p99_ms']:.2f} / "
            f"{r['period_max_ms']:.2f} | {r['edge_p50_ms']:.2f} / {r['edge_p99_ms']:.2f} / "
            f"{r['edge_max_ms']:.2f} | {r['periods']:.0f} | {r['edges']:.0f} "
            f"| {r['cpu_percent']:.2f} | {r['rss_mb']:.1f} | {r['overruns']:.0f} |"
        )
    table = "\n".join(lines)
    print(table)
    if args.write:
        from control import _replace_section  # bench/control.py, beside this file

        text = (
            "## Timing: the real loop on simulated hardware\n\n"
            f"`uv run python bench/timing.py --seconds {args.seconds:.0f} --write` "
            f"({args.seconds:.0f} s per row, {cores} cores). Goals: edge p99 ≤ 10 ms, period "
            "p99 ≤ 5 ms under load, CPU ≤ 1 % of a core, RSS ≤ 50 MB. RSS is the whole "
            "Python process (interpreter, mcap, yaml, the simulator).\n\n" + table + "\n"
        )
        _replace_section(Path(__file__).with_name("RESULTS.md"), "## Timing:", text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
