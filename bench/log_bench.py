"""The flight recorder's cost: log bytes per hour, CPU per hour, and how fast a day's log reads.

Runs the daemon with the default config (period 5 s, a reading a second, windows of one
period, a timing record a minute) on the simulated tun (20 → 66 °C, then holding) on the
virtual clock, through the real Recorder into a temporary directory. The simulation waits
for the writer thread every flush_interval of simulated time (`Recorder.sync`), so every
record is kept and each chunk holds what it would in real time; left alone, the simulation
outruns the writer, the queue overflows and chunks grow. Measures:

- log bytes per hour (goal ≤ 2 MB/h);
- the recorder's CPU per simulated hour: the writer thread's own CPU time, and the whole
  process with the recorder against the same run without it; and the caller's CPU per
  `Recorder.write` (what the control loop pays);
- reading the whole log back with `hermsd.log.recorder.read_messages`, and the replay summary,
  as multiples of real time (goal for replay ≥ 100,000×; `bench/replay.py` times the
  `hermsd replay` command and its stages on such a log).

    uv run python bench/log_bench.py [--hours 24] [--write]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import sections  # bench/sections.py, beside this file
from mcap.reader import make_reader

from hermsd.config import schema as config_module
from hermsd.config.schema import Config
from hermsd.log import reader, replay
from hermsd.log.mcap_file import read_messages
from hermsd.log.recorder import Recorder
from hermsd.log.topics import PERIOD_TOPIC
from hermsd.runtime.assemble import assemble
from hermsd.sim.clock import DEFAULT_EPOCH_NS, VirtualClock
from hermsd.sim.world import build_world

GOAL_BYTES_PER_HOUR = 2e6
GOAL_REPLAY_SPEED = 100_000.0
WRITE_CALLS = 100_000
READ_REPEATS = 3


@dataclass(frozen=True, slots=True)
class Run:
    process_cpu_s: float
    writer_cpu_s: float | None  # None: run without a recorder


def simulate(hours: float, directory: Path | None) -> Run:
    """The daemon for `hours` of simulated time, logging into `directory` (None: no log)."""
    config = config_module.DEFAULT
    started = time.process_time()
    clock = VirtualClock()
    if directory is None:
        run_daemon(config, clock, hours, None)
        return Run(time.process_time() - started, None)
    recorder, writer_cpu = paced_recorder(directory, clock, config)
    run_daemon(config, clock, hours, recorder)
    recorder.sync()  # the thread's CPU clock is gone once it has stopped
    writer_cpu_s = writer_cpu()
    recorder.close()
    if recorder.dropped or recorder.lost or recorder.errors:
        raise SystemExit(
            f"the recorder dropped {recorder.dropped}, lost {recorder.lost} records "
            f"and failed {recorder.errors} times: {recorder.last_error}"
        )
    return Run(time.process_time() - started, writer_cpu_s)


def paced_recorder(
    directory: Path, clock: VirtualClock, config: Config
) -> tuple[Recorder, Callable[[], float]]:
    """The daemon's Recorder as `config.log` sets it, and its writer thread's CPU clock.

    The simulation waits for the writer every flush_interval of simulated time
    (`Recorder.sync`), so every record is kept and each chunk holds what it would in real time.
    """
    log = config.log
    before = set(threading.enumerate())
    recorder = Recorder(
        directory,
        now=clock.monotonic,
        rotate_s=log.rotate_hours * 3600.0,
        flush_interval=log.flush_interval,
        sync_interval=log.sync_interval,
        queue_size=log.queue_size,
        metadata={"tun": config.tun.name},
    )
    [writer] = set(threading.enumerate()) - before
    writer_clock = time.pthread_getcpuclockid(writer.ident or 0)  # started by the constructor

    def keep_pace() -> None:
        recorder.sync()
        clock.call_at(clock.monotonic() + log.flush_interval, keep_pace)

    clock.call_at(log.flush_interval, keep_pace)
    return recorder, lambda: time.clock_gettime(writer_clock)


def run_daemon(
    config: Config, clock: VirtualClock, hours: float, recorder: Recorder | None
) -> None:
    world = build_world(config, clock)
    with assemble(config, clock, world.sensor, world.outputs, recorder=recorder) as daemon:
        daemon.run(until=hours * 3600.0)


def write_cost(message: dict[str, Any], calls: int) -> float:
    """The caller's CPU seconds per `Recorder.write` of `message` (the writer runs alongside)."""
    with tempfile.TemporaryDirectory() as directory:
        recorder = Recorder(directory, queue_size=calls + 1)
        started = time.thread_time()
        for k in range(calls):
            recorder.write(PERIOD_TOPIC, DEFAULT_EPOCH_NS + k * 5_000_000_000, message)
        cpu = time.thread_time() - started
        recorder.close()
    if recorder.dropped:
        raise SystemExit(f"write bench: {recorder.dropped} records dropped")
    return cpu / calls


def chunk_count(paths: list[Path]) -> int:
    """Chunks in finished files, from their summaries (one per flush: the size overhead)."""
    total = 0
    for path in paths:
        with path.open("rb") as f:
            summary = make_reader(f).get_summary()
        if summary is None or summary.statistics is None:
            raise SystemExit(f"{path}: no summary")
        total += summary.statistics.chunk_count
    return total


def _yes(met: bool) -> str:
    return "yes" if met else "no"


def best_time(read: Callable[[list[Path]], object], paths: list[Path]) -> float:
    times = []
    for _ in range(READ_REPEATS):
        started = time.perf_counter()
        read(paths)
        times.append(time.perf_counter() - started)
    return min(times)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=24.0, help="simulated hours (default 24)")
    parser.add_argument("--write", action="store_true", help="update bench/RESULTS.md")
    args = parser.parse_args()
    hours: float = args.hours
    seconds = hours * 3600.0
    lines: list[str] = []

    def row(measure: str, value: str, goal: str = "") -> None:
        lines.append(f"| {measure} | {value} | {goal} |")
        print(lines[-1], flush=True)

    bare = simulate(hours, None)
    with tempfile.TemporaryDirectory() as tmp:
        logged = simulate(hours, Path(tmp))
        paths = sorted(Path(tmp).glob("*.mcap"))
        size = sum(p.stat().st_size for p in paths)
        messages = list(read_messages(paths))
        last_period = next(m.message for m in reversed(messages) if m.topic == PERIOD_TOPIC)
        per_hour = size / hours
        row(
            "log size",
            f"{size / 1e6:.2f} MB in {len(paths)} file(s): {len(messages)} messages "
            f"in {chunk_count(paths)} chunks",
        )
        row(
            "log bytes per hour",
            f"{per_hour / 1e6:.3f} MB/h ({len(messages) / hours:.0f} messages/h)",
            f"≤ {GOAL_BYTES_PER_HOUR / 1e6:.0f} MB/h: {_yes(per_hour <= GOAL_BYTES_PER_HOUR)}",
        )
        assert logged.writer_cpu_s is not None
        row(
            "writer thread CPU per simulated hour",
            f"{logged.writer_cpu_s / hours:.3f} s/h = {100 * logged.writer_cpu_s / seconds:.4f} "
            f"% of a core ({1e6 * logged.writer_cpu_s / len(messages):.0f} µs per record)",
        )
        extra = logged.process_cpu_s - bare.process_cpu_s
        row(
            "process CPU, with recorder / without",
            f"{logged.process_cpu_s:.2f} s / {bare.process_cpu_s:.2f} s = "
            f"×{logged.process_cpu_s / bare.process_cpu_s:.2f}; the recorder's share "
            f"{extra / hours:.3f} s/h = {100 * extra / seconds:.4f} % of a core",
        )
        periods = seconds / config_module.DEFAULT.control.period
        row(
            "process CPU per control period, without the recorder (the loop and the simulated tun)",
            f"{1e3 * bare.process_cpu_s / periods:.3f} ms ({periods:.0f} periods)",
        )
        per_write = write_cost(last_period, WRITE_CALLS)
        row("caller CPU per Recorder.write (a period record)", f"{per_write * 1e6:.2f} µs")
        took = best_time(lambda paths: sum(1 for _ in read_messages(paths)), paths)
        row(
            f"read_messages, every message of the {hours:g} h log",
            f"{took:.3f} s = {seconds / took:,.0f}× real time "
            f"({len(messages) / took:,.0f} messages/s)",
        )
        took = best_time(lambda paths: replay.summarise(reader.load(paths)), paths)
        row(
            f"replay summary of the {hours:g} h log, in process",
            f"{took:.3f} s = {seconds / took:,.0f}× real time",
            f"≥ {GOAL_REPLAY_SPEED:,.0f}×: {_yes(seconds / took >= GOAL_REPLAY_SPEED)}",
        )

    table = "\n".join(["| measure | figure | goal |", "|---|---|---|", *lines])
    machine = f"{os.cpu_count()} cores ({platform.machine()}), Python {platform.python_version()}"
    text = (
        f"On {machine}: {hours:g} h of the default config (period 5 s, a reading a second, "
        f"windows of one "
        "period, a timing record a minute) on the simulated tun (20 → 66 °C, then holding), "
        "on the virtual clock, through the real Recorder; the simulation waits for the writer "
        "every flush_interval (2 s), so every record is kept in chunks of real-time size. "
        "CPU is `pthread_getcpuclockid` of the writer thread (an upper bound: keeping pace "
        "costs an fdatasync every 2 s, the daemon does one every sync_interval, 10 s), and "
        "`process_time` of the same run with and without the recorder; the write cost is the "
        f"calling thread's CPU over {WRITE_CALLS:,} calls. Reads are the best of "
        f"{READ_REPEATS} over the same log (`bench/replay.py` times `hermsd replay` on "
        "one).\n\n" + table + "\n"
    )
    if args.write:
        sections.write("## Log: size, recorder CPU, read speed", text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
