"""What keeping a mash program's progress costs the control loop, and the disk.

An hour of 5 s periods of a rest in the largest program (50 steps, each with a 100-character
message), run through `ProgramDriver.period` with a real store in a temporary directory
beside this file (the disk the state directory would be on). The loop thread's time per
period (median, 99th percentile, largest) against a peer in the same run: the whole program
document written durably on the loop thread each period (`write_atomically`, as the store
once did; it fsynced once a minute and at step changes, so this peer is its worst period).
The writer thread is waited for between periods, untimed, as a real 5 s period would.
Then the bytes the hour wrote, both ways.

    uv run python bench/program_store.py
"""

from __future__ import annotations

import datetime as dt
import json
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from hermsd.control.pid import PlantModel
from hermsd.files import write_atomically
from hermsd.program.driver import ProgramDriver
from hermsd.program.model import MAX_STEPS, Program, Step, to_data
from hermsd.program.readiness import Tun
from hermsd.program.runner import Progress
from hermsd.program.store import ProgressStore

PERIOD_S = 5.0
PERIODS = 720  # an hour
PROGRAM = Program(
    "Largest", tuple(Step(f"Step {i:02d}", 66.0, 7200.0, None, "m" * 100) for i in range(MAX_STEPS))
)


def summary(times: list[float]) -> str:
    times = sorted(times)
    p99 = times[int(0.99 * len(times))]
    return (
        f"median {statistics.median(times) * 1e3:.3f} ms, p99 {p99 * 1e3:.3f} ms, "
        f"max {times[-1] * 1e3:.3f} ms"
    )


def timed(
    step: Callable[[int], object], between: Callable[[], object] = lambda: None
) -> list[float]:
    """Each period's time; `between` runs after each, untimed (the rest of a real period)."""
    times = []
    for k in range(PERIODS):
        start = time.perf_counter()
        step(k)
        times.append(time.perf_counter() - start)
        between()
    return times


class CountingStore(ProgressStore):
    """A real store that notes the size of each progress record it writes."""

    def __init__(self, directory: str) -> None:
        super().__init__(directory)
        self.written: list[int] = []

    def save_progress(self, progress: Progress, started_at_ns: int, wall_ns: int) -> None:
        super().save_progress(progress, started_at_ns, wall_ns)
        self.written.append(self.progress_path.stat().st_size)


def main() -> None:
    here = Path(__file__).resolve().parent
    tun = Tun(PlantModel(), 100.0, measured=False, fit=None)
    with tempfile.TemporaryDirectory(dir=here) as directory:
        store = CountingStore(directory)
        driver = ProgramDriver(store, dt.UTC, PERIOD_S)
        driver.start(PROGRAM, None, setpoint=66.0, wall_ns=0, pv=66.0, tun=tun)
        ours = timed(
            lambda k: driver.period(PERIOD_S * k, 66.0, int(PERIOD_S * 1e9) * k, tun, 100.0, True),
            driver.flush,  # a real period is 5 s: the writer is done long before the next
        )
        driver.close(10.0)
        program_bytes = store.path.stat().st_size
        document = json.dumps({"program": to_data(PROGRAM), "progress": {}}, indent=1)
        peer_path = Path(directory) / "peer.json"
        peer = timed(lambda _k: write_atomically(peer_path, document))
    print(f"loop thread per period, progress handed to the writer: {summary(ours)}")
    print(f"loop thread per period, whole document written durably (peer): {summary(peer)}")
    print(f"median ratio peer/ours: {statistics.median(peer) / statistics.median(ours):.0f}")
    written = store.written
    ours_bytes = program_bytes + sum(written)
    print(
        f"bytes written in the hour: {ours_bytes} ({len(written)} progress records) "
        f"against {len(document.encode()) * PERIODS} (peer)"
    )


if __name__ == "__main__":
    main()
