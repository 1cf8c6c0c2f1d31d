"""The element's current input: how long one ADS1115 read holds the control loop.

The real reader (`hardware/current_sense.py`) on the fake I2C bus (`sim/bus.py`'s
FakeADS1115, a CT's sine at 10 A), on the real clock: `time.monotonic` paces the polls and
`time.sleep` waits between them, as on a Pi. The fake answers at once, so a Pi's I2C
transfers are not in these figures (one register read, 5 bytes on the wire: about 0.1 ms at
400 kHz, 0.5 ms at 100 kHz, times 28–36 polls a read); the sampling window, the sleeps'
overshoot and the Python each poll runs are. The daemon takes a read only where no SSR edge
falls within it and a margin (`runtime/current_side.py`), so this is what a read delays the
loop's other work by (a read of the HLT's sensor, a control period's start), never an edge.

    uv run python bench/current_read.py [--reads 200] [--write]
"""

from __future__ import annotations

import argparse
import math
import time

import sections  # bench/sections.py, beside this file

from hermsd.config.schema import CurrentConfig
from hermsd.hardware.current_sense import ADS1115Current
from hermsd.runtime.scheduler import percentile
from hermsd.sim.bus import FakeADS1115, FakeSMBus

ADDRESS = 0x49
AMPS = 10.0


def reads(hz: int, count: int) -> tuple[list[float], list[int], list[float]]:
    """`count` reads at `hz`: each one's wall time (ms), its polls, and the amps it gave."""
    peak = AMPS / 30.0 * math.sqrt(2.0)
    chip = FakeADS1115(lambda t: peak * math.sin(2.0 * math.pi * hz * t), time.monotonic)
    bus = FakeSMBus()
    bus.attach(ADDRESS, chip)
    current = CurrentConfig(kind="ads1115", address=ADDRESS)
    sense = ADS1115Current(bus, ADDRESS, current, hz, time.monotonic, time.sleep)
    took, polls, amps = [], [], []
    for _ in range(count):
        before = chip.transfers
        started = time.perf_counter()
        read = sense.read()
        took.append((time.perf_counter() - started) * 1000.0)
        polls.append(chip.transfers - before - 1)  # the config register's check is not a poll
        amps.append(read.amps or 0.0)
        time.sleep(0.01)
    return took, polls, amps


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reads", type=int, default=200, help="reads at each mains frequency")
    parser.add_argument("--write", action="store_true", help="update bench/RESULTS.md")
    args = parser.parse_args()
    rows = [
        "| mains | window ms | read ms: median | p99 | max | polls a read | amps read (10 A) |",
        "|---|---|---|---|---|---|---|",
    ]
    for hz in (50, 60):
        took, polls, amps = reads(hz, args.reads)
        ordered = sorted(took)
        rows.append(
            f"| {hz} Hz | {2000.0 / hz:.1f} | {percentile(ordered, 50):.1f} "
            f"| {percentile(ordered, 99):.1f} | {ordered[-1]:.1f} | {min(polls)}–{max(polls)} "
            f"| {min(amps):.3f}–{max(amps):.3f} |"
        )
    text = "\n\n".join(
        [
            " ".join(
                [
                    f"{args.reads} reads at each mains frequency of the ADS1115 reader on the",
                    "fake I2C bus, on the real clock (bench/current_read.py's docstring: the",
                    "bus's own transfer time is not in them; add 0.1 ms a poll at 400 kHz, 0.5",
                    "ms at 100 kHz). A read holds the loop's thread for its window of two mains",
                    "cycles and at most a poll more; the daemon takes one only clear of any SSR",
                    "edge.",
                ]
            ),
            "\n".join(rows),
        ]
    )
    print(text)
    if args.write:
        sections.write("## Element-current input: what an ADS1115 read holds the loop", text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
