"""The daemon in real time on simulated hardware: how late its periods and SSR edges are.

Runs the real loop (monotonic clock, sleeping for real, the MCAP recorder writing beside it)
against the simulated tun, under four loads: an idle machine; one CPU-burning process per
core; four CPU-burning processes plus a writer that fsyncs 256 KiB blocks without pause
(to the disk the log is on); and that same load with the loop thread at real-time priority
(`hermsd.hardware.realtime.loop_priority`, as `hermsd run` does on hardware). It reports
control-period lateness and SSR-edge error (p50/p99/max), the CPU the daemon used and its
peak RSS. Goals: edge error p99 ≤ 10 ms, period lateness p99 ≤ 5 ms under load, CPU ≤ 1 %
of a core, RSS ≤ 50 MB.

So that a p99 is not simply the worst sample, the loop runs its periods ten times faster
than the default config (0.5 s, a reading each) and its SSR windows fifty times faster
(0.1 s), in manual mode at 50 %: one timed SSR edge per window, ten a second.

    uv run python bench/timing.py [--seconds 250] [--dir /var/tmp] [--write]

Run as root (or with an RLIMIT_RTPRIO of 10) for the real-time row.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import multiprocessing
import os
import resource
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path

from hermsd.config import schema as config_module
from hermsd.hardware.realtime import LOOP_PRIORITY, loop_priority
from hermsd.hardware.ssr import DeadManThread
from hermsd.log.recorder import Recorder
from hermsd.runtime.assemble import assemble
from hermsd.runtime.clock import MonotonicClock
from hermsd.runtime.daemon import Daemon
from hermsd.runtime.scheduler import percentile
from hermsd.sim.world import build_world

BUSY_LOOPS_WITH_DISK = 4
FSYNC_BLOCK = 256 * 1024
FSYNC_FILE_BLOCKS = 256  # the load's file is rewritten from the start every 64 MiB


def burn(stop_at: float) -> None:
    while time.monotonic() < stop_at:
        pass


def fsync_writer(path: str, stop_at: float) -> None:
    block = os.urandom(FSYNC_BLOCK)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    written = 0
    while time.monotonic() < stop_at:
        os.write(fd, block)
        os.fsync(fd)
        written += 1
        if written % FSYNC_FILE_BLOCKS == 0:
            os.lseek(fd, 0, os.SEEK_SET)
    os.close(fd)


def bench_config() -> config_module.Config:
    """The default config with the loop's rates raised (see the module docstring)."""
    base = config_module.DEFAULT
    return dataclasses.replace(
        base,
        control=dataclasses.replace(base.control, period=0.5, mode="manual", manual_output=50.0),
        sensor=dataclasses.replace(base.sensor, read_interval=0.5),
        output=dataclasses.replace(base.output, backend="sim", window=0.1, min_on=0, min_off=0),
    )


def measure(
    seconds: float,
    log_dir: Path,
    realtime: bool,
    beside: Callable[[Daemon], contextlib.AbstractContextManager[object]] | None = None,
) -> dict[str, float]:
    """The loop's timing over `seconds`; `beside(daemon)` is entered before the loop takes
    its priority and left after it stops (bench/socket_load.py serves the socket in it)."""
    config = bench_config()
    clock = MonotonicClock()
    plant = {"model": "foptd", "start_s": clock.monotonic(), "start_c": 66.0}
    world = build_world(config, clock, plant)
    log_dir.mkdir(parents=True, exist_ok=True)  # the recorder writes into it, never makes it
    recorder = Recorder(log_dir)
    daemon = assemble(config, clock, world.sensor, world.outputs, recorder=recorder)
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
    # As in `hermsd run`: the recorder and dead-man threads started first stay ordinary.
    with (
        beside(daemon) if beside is not None else contextlib.nullcontext(),
        loop_priority() if realtime else contextlib.nullcontext(False) as raised,
        daemon,
    ):
        if realtime and not raised:
            raise SystemExit("the real-time row needs root or an RLIMIT_RTPRIO of 10")
        daemon.start()
        control = daemon._control_task
        daemon.run(until=clock.monotonic() + seconds)
    wall = time.monotonic() - wall0
    deadman.stop()
    recorder.close()
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
        "dropped": recorder.dropped,
    }


@contextlib.contextmanager
def load(busy: int, fsync_path: Path | None, seconds: float) -> Iterator[None]:
    """`busy` CPU-burning processes and, with a path, an fsync-heavy writer, while inside."""
    stop_at = time.monotonic() + seconds + 30
    workers = [multiprocessing.Process(target=burn, args=(stop_at,)) for _ in range(busy)]
    if fsync_path is not None:
        workers.append(
            multiprocessing.Process(target=fsync_writer, args=(str(fsync_path), stop_at))
        )
    for worker in workers:
        worker.start()
    try:
        yield
    finally:
        for worker in workers:
            worker.terminate()
            worker.join()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=250.0)
    parser.add_argument(
        "--dir", type=Path, default=Path("/var/tmp"), help="disk for the logs and the fsync load"
    )
    parser.add_argument("--write", action="store_true", help="update bench/RESULTS.md")
    args = parser.parse_args()
    cores = os.cpu_count() or 2
    disk_load = f"{BUSY_LOOPS_WITH_DISK} busy + fsync writer"
    runs: list[tuple[str, int, bool, bool]] = [
        ("idle", 0, False, False),
        (f"{cores} busy", cores, False, False),
        (disk_load, BUSY_LOOPS_WITH_DISK, True, False),
        (f"{disk_load}, real-time loop", BUSY_LOOPS_WITH_DISK, True, True),
    ]
    rows: dict[str, dict[str, float]] = {}
    with tempfile.TemporaryDirectory(dir=args.dir, prefix="hermsd-timing-") as scratch:
        for index, (name, busy, fsync, realtime) in enumerate(runs):
            logs = Path(scratch, f"log{index}")
            fsync_path = Path(scratch, "fsync-load") if fsync else None
            with load(busy, fsync_path, args.seconds):
                rows[name] = measure(args.seconds, logs, realtime)
            print(name, rows[name], flush=True)
    table = _table(rows)
    ordinary, realtime_row = rows[disk_load], rows[f"{disk_load}, real-time loop"]
    ratios = _ratios(ordinary, realtime_row)
    print(table)
    print(ratios)
    if args.write:
        import sections  # bench/sections.py, beside this file

        text = (
            f"As root ({args.seconds:.0f} s per row, {cores} cores, logs and fsync load on "
            f"{args.dir}; other processes ran meanwhile, so idle means without the bench's "
            "load). Periods of 0.5 s and SSR windows of 0.1 s (manual 50 %: one timed "
            "edge per window), so that p99 is not the worst sample; the MCAP recorder writes "
            "beside the loop. The real-time row is the loop thread at SCHED_FIFO "
            f"{LOOP_PRIORITY} (`hermsd.hardware.realtime.loop_priority`, what `hermsd run` does "
            "when the unit's `LimitRTPRIO=` allows it); the recorder and dead-man threads stay "
            "ordinary. Goals: edge p99 ≤ 10 ms, period p99 ≤ 5 ms under load, CPU ≤ 1 % of "
            "a core, RSS ≤ 50 MB. RSS is the whole Python process (interpreter, mcap, yaml, "
            "the simulator).\n\n" + table + "\n\n" + ratios + "\n"
        )
        sections.write("## Timing: the real loop on simulated hardware", text)
    return 0


def _table(rows: dict[str, dict[str, float]]) -> str:
    more = ["CPU %", "peak RSS MB", "overruns", "log records dropped"]
    cells = {
        name: f"{r['cpu_percent']:.2f} | {r['rss_mb']:.1f} | {r['overruns']:.0f} "
        f"| {r['dropped']:.0f}"
        for name, r in rows.items()
    }
    return timing_table("load", more, rows, cells)


def timing_table(
    first: str, more: list[str], rows: dict[str, dict[str, float]], cells: dict[str, str]
) -> str:
    """A Markdown table: `first` (the row names), the timing columns, then `more` (`cells`)."""
    header = [first, "period p50/p99/max ms", "edge p50/p99/max ms", "periods", "edges", *more]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += [f"| {name} | {timing_cells(r)} | {cells[name]} |" for name, r in rows.items()]
    return "\n".join(lines)


def timing_cells(r: dict[str, float]) -> str:
    """Period and edge p50/p99/max, and their counts, as table cells."""
    return (
        f"{r['period_p50_ms']:.2f} / {r['period_p99_ms']:.2f} / {r['period_max_ms']:.2f} | "
        f"{r['edge_p50_ms']:.2f} / {r['edge_p99_ms']:.2f} / {r['edge_max_ms']:.2f} | "
        f"{r['periods']:.0f} | {r['edges']:.0f}"
    )


def _ratios(ordinary: dict[str, float], realtime: dict[str, float]) -> str:
    def ratio(key: str) -> float:
        return ordinary[key] / max(realtime[key], 1e-9)

    return (
        f"Under CPU and fsync load the real-time loop's edge p99 is {ratio('edge_p99_ms'):.0f}× "
        f"smaller than the ordinary loop's, its period p99 {ratio('period_p99_ms'):.0f}× smaller."
    )


if __name__ == "__main__":
    sys.exit(main())
