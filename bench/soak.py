"""Soak: days of the daemon with logging and rotation, its memory and its loop's CPU by the hour.

The daemon with the default config (period 5 s, a reading a second, a file a day) runs on the
simulated tun (20 → 66 °C, then holding) on the virtual clock, logging through the real
Recorder into a temporary directory (on /dev/shm where there is one: the disk is not what is
measured), as `bench/log_bench.py` does: the simulation waits for the writer every
flush_interval of simulated time, so each chunk holds what it would in real time (a chunk
per 2 s flush, the count that grows the writer's index). Each simulated hour it samples:

- the process's resident memory (VmRSS of /proc/self/status);
- the main thread's CPU per control period over the hour (the loop and the simulated world:
  what a daemon that runs for months must keep flat);
- the writer thread's CPU over the hour;
- the CPU a fixed piece of work takes (the same 200,000 steps of arithmetic), so that what the
  load of a shared machine does to every CPU figure shows beside them; the loop's CPU per
  period is also given in units of it, which stays flat when only the load moved.

Goals: from the first day on, RSS within 2 MB of its value at 24 h and at most 50 MB; the
loop's CPU per period flat.

    uv run python bench/soak.py [--days 7] [--write]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from statistics import median

from log_bench import paced_recorder, run_daemon  # bench/log_bench.py, beside this file
from sections import write  # bench/sections.py, beside this file

from hermsd.config import schema as config_module
from hermsd.sim.clock import VirtualClock

GOAL_RSS_MB = 50.0
GOAL_RSS_SPREAD_MB = 2.0
HOUR_S = 3600.0
REFERENCE_STEPS = 200_000
SHOWN_EVERY_H = 6  # rows of the table in RESULTS.md (every hour is printed)


@dataclass(frozen=True, slots=True)
class Sample:
    hour: int
    rss_mb: float
    loop_us_per_period: float
    writer_cpu_s: float
    reference_ms: float
    files: int

    @property
    def loop_per_reference(self) -> float:
        return self.loop_us_per_period / (1e3 * self.reference_ms)


def rss_mb() -> float:
    """This process's resident memory, MB (VmRSS, in kB in /proc/self/status)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    raise SystemExit("no VmRSS in /proc/self/status")


def reference_ms() -> float:
    """The main thread's CPU for a fixed piece of work, ms (the best of three)."""
    times = []
    for _ in range(3):
        started = time.thread_time()
        sum(k * k % 7 for k in range(REFERENCE_STEPS))
        times.append(time.thread_time() - started)
    return 1e3 * min(times)


def soak(days: float, directory: Path, show: bool) -> list[Sample]:
    """The daemon for `days` on the virtual clock, logging into `directory`; hourly samples."""
    config = config_module.DEFAULT
    clock = VirtualClock()
    recorder, writer_cpu = paced_recorder(directory, clock, config)
    periods_per_hour = HOUR_S / config.control.period
    samples: list[Sample] = []
    last = [time.thread_time(), writer_cpu()]

    def sample() -> None:
        hour = round(clock.monotonic() / HOUR_S)
        loop, writer = time.thread_time(), writer_cpu()
        reference = reference_ms()
        samples.append(
            Sample(
                hour,
                rss_mb(),
                1e6 * (loop - last[0]) / periods_per_hour,
                writer - last[1],
                reference,
                len(list(directory.glob("*.mcap"))),
            )
        )
        last[:] = [time.thread_time(), writer]
        if show:
            print(row(samples[-1]), flush=True)
        clock.call_at(clock.monotonic() + HOUR_S, sample)

    clock.call_at(HOUR_S, sample)
    run_daemon(config, clock, days * 24.0, recorder)
    recorder.close()
    if recorder.dropped or recorder.lost or recorder.errors:
        raise SystemExit(
            f"the recorder dropped {recorder.dropped}, lost {recorder.lost} records "
            f"and failed {recorder.errors} times: {recorder.last_error}"
        )
    return samples


def row(sample: Sample) -> str:
    return (
        f"| {sample.hour} | {sample.rss_mb:.1f} | {sample.loop_us_per_period:.0f} "
        f"| {sample.loop_per_reference:.3f} | {sample.writer_cpu_s:.2f} "
        f"| {sample.reference_ms:.1f} | {sample.files} |"
    )


def verdict(samples: list[Sample]) -> list[str]:
    """The goals, judged from the samples after the first day."""
    at_day = next((s for s in samples if s.hour == 24), None)
    if at_day is None:
        return ["fewer than 24 hours: no goal judged"]
    later = [s for s in samples if s.hour > 24]
    spread = max((abs(s.rss_mb - at_day.rss_mb) for s in later), default=0.0)
    highest = max(s.rss_mb for s in samples)
    first = [s.loop_us_per_period for s in samples if s.hour <= 24]
    last = [s.loop_us_per_period for s in samples[-24:]]
    first_relative = [s.loop_per_reference for s in samples if s.hour <= 24]
    last_relative = [s.loop_per_reference for s in samples[-24:]]
    yes = {True: "yes", False: "no"}
    return [
        f"RSS at 24 h: {at_day.rss_mb:.1f} MB; after it, at most {spread:.1f} MB away from that "
        f"(goal ≤ {GOAL_RSS_SPREAD_MB:g} MB: {yes[spread <= GOAL_RSS_SPREAD_MB]}); highest "
        f"{highest:.1f} MB (goal ≤ {GOAL_RSS_MB:g} MB: {yes[highest <= GOAL_RSS_MB]}).",
        f"The loop's CPU per period, median of the first day {median(first):.0f} µs, of the "
        f"last 24 samples {median(last):.0f} µs; in units of the reference work "
        f"{median(first_relative):.3f} and {median(last_relative):.3f}.",
    ]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--days", type=float, default=7.0, help="simulated days (default 7)")
    parser.add_argument("--write", action="store_true", help="update bench/RESULTS.md")
    args = parser.parse_args()
    days: float = args.days
    header = (
        "| hour | RSS, MB | loop CPU per period, µs | the same, in reference works "
        "| writer CPU in the hour, s | reference work, ms | files |"
    )
    print(header, flush=True)
    started = time.perf_counter()
    shm = Path("/dev/shm")
    with tempfile.TemporaryDirectory(dir=shm if shm.is_dir() else None) as tmp:
        samples = soak(days, Path(tmp), show=True)
    took = time.perf_counter() - started
    judged = verdict(samples)
    print("\n".join(judged))
    print(f"{days:g} simulated days in {took:.0f} s")
    if not args.write:
        return 0
    shown = [s for s in samples if s.hour % SHOWN_EVERY_H == 0 or s.hour == 1]
    machine = f"{os.cpu_count()} cores ({platform.machine()}), Python {platform.python_version()}"
    text = (
        f"On {machine}, {took:.0f} s. {days:g} simulated days of the daemon (default config: "
        "period 5 s, a reading a second, a log file a day) on the simulated tun, on the "
        "virtual clock, logging through "
        "the real Recorder paced as in `bench/log_bench.py` (a chunk per 2 s flush); sampled "
        "each simulated hour, shown every "
        f"{SHOWN_EVERY_H} h. RSS is VmRSS of the process; the loop's CPU is the main thread's "
        "(the daemon and the simulated world) over the hour, per control period, also in units "
        "of a fixed piece of work timed at each sample (the machine's load moves both).\n\n"
        + "\n".join(f"- {line}" for line in judged)
        + "\n\n"
        + "\n".join([header, "|---|---|---|---|---|---|---|", *map(row, shown)])
        + "\n"
    )
    write("## Soak: memory and loop CPU over days of logging", text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
