"""The real loop while its state saves stall and its tune fits run: on the loop, and beside it.

On a Pi's SD card an fsync can stall for seconds. This runs bench/timing.py's loop (monotonic
clock, real sleeps, 0.5 s periods, 0.1 s SSR windows at 50 %: one timed edge per window) and,
every `--every` seconds, makes it do what it does rarely on a brew day:

- saves: hands over a save of the latched alarms and one of the learned model, each stalled
  `--stall` seconds before its (real, durable) write, as an fsync on a slow card would;
- fits: `tune step`'s fit of an open pot's whole default step test (the records of
  bench/tuning.py's step test on the family's "open 120 L 3.5 kW" tun).

Rows of the same run: on the loop thread (the saves done at once, `Saver(threaded=False)`,
and the fit at once: how the daemon did them before) and beside it (`Saver()`, and
`FitProcess`: how it does them now); and the fit on a thread beside the loop, which the
interpreter's lock makes the edges wait for. Goals: edge p99 ≤ 10 ms, period p99 ≤ 5 ms.

    uv run python bench/slow_disk.py [--seconds 60] [--every 10] [--stall 2] [--write]

Run as root (or with an RLIMIT_RTPRIO of 10): the loop thread runs at real-time priority, as
`hermsd run` runs it on the Pi.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, ParamSpec, TypeVar

import sections  # bench/sections.py, beside this file
from timing import bench_config, measure, timing_table  # bench/timing.py, beside this file
from tuning import step_test  # bench/tuning.py, beside this file

from hermsd.commissioning import tune
from hermsd.commissioning.step_response import FitProcess, fit_in_thread
from hermsd.config import schema as config_module
from hermsd.control.learning import LearnedModel, ModelStore
from hermsd.runtime.daemon import Daemon
from hermsd.runtime.period import PeriodRecord
from hermsd.runtime.saver import Saver
from hermsd.safety.latches import LatchStore
from hermsd.safety.limits import Alarm
from hermsd.sim.tuns import FAMILY

OPEN_POT = "open 120 L 3.5 kW"
WINDOW_S = bench_config().output.window or 0.0
Store = TypeVar("Store", LatchStore, ModelStore)
Saved = ParamSpec("Saved")
MODEL = LearnedModel(0.5 / 60.0, 1.0 / 12000.0, 90.0, 18.0, 90.0, wall_ns=1)


def stall_saves(store: Store, stall: float) -> Store:
    """`store` with each save stalled `stall` s before it writes, as an fsync on a slow card."""
    store.save = stalled(store.save, stall)  # type: ignore[method-assign]
    return store


def stalled(save: Callable[Saved, None], stall: float) -> Callable[Saved, None]:
    """`save`, each call stalled `stall` s before it runs."""

    def late(*args: Saved.args, **kwargs: Saved.kwargs) -> None:
        time.sleep(stall)
        save(*args, **kwargs)

    return late


class Every:
    """A listener that does `work(t)` every `every` s of the loop's periods."""

    def __init__(self, every: float, work: Callable[[float], object]) -> None:
        self.every, self.work = every, work
        self.next: float | None = None
        self.times = 0

    def period(self, record: PeriodRecord) -> None:
        if self.next is None:
            self.next = record.t + self.every
        elif record.t >= self.next:
            self.next += self.every
            self.times += 1
            self.work(record.t)

    def alarm(self, alarm: Alarm) -> None:
        pass


def hooked(
    beside: Callable[..., contextlib.AbstractContextManager[Every]],
    how: Any,
    done: list[Every],
    gaps: list[float],
) -> Callable[[Daemon], contextlib.AbstractContextManager[None]]:
    """bench/timing.py's hook: `beside(how, daemon)` around the run, and the real time between
    one SSR window's start and the next in `gaps` (a window the loop missed shows as a gap)."""

    @contextlib.contextmanager
    def hook(daemon: Daemon) -> Iterator[None]:
        original = daemon._on_window
        last: list[float] = []

        def on_window(deadline: float, now: float) -> None:
            if last:
                gaps.append(now - last[0])
            last[:] = [now]
            original(deadline, now)

        daemon._on_window = on_window  # type: ignore[method-assign]
        with beside(how, daemon) as every:
            done.append(every)
            yield

    return hook


def open_pot_fit() -> Callable[[], object]:
    """The fit `tune step` makes of an open pot's whole step test (its last and largest)."""
    spec = next(spec for spec in FAMILY if spec.name == OPEN_POT)
    experiment = step_test(spec)
    config = spec.config(config_module.DEFAULT)
    pvs, duties = list(experiment.pvs), list(experiment.duties)

    def fit() -> object:
        return tune.from_series(
            pvs,
            duties,
            config.control.period,
            None,
            config.tun.element_watts,
            config.tun.litres,
            config.control.setpoint,
        )

    return fit


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--every", type=float, default=10.0, help="s between saves, or fits")
    parser.add_argument("--stall", type=float, default=2.0, help="s each save stalls")
    parser.add_argument("--dir", type=Path, default=Path("/var/tmp"), help="disk for the files")
    parser.add_argument("--write", action="store_true", help="update bench/RESULTS.md")
    args = parser.parse_args()
    fit = open_pot_fit()
    began = time.perf_counter()
    fit()
    fit_s = time.perf_counter() - began
    print(f"one open pot's fit: {fit_s:.3f} s", flush=True)
    rows: dict[str, dict[str, float]] = {}
    counts: dict[str, int] = {}
    stalls: dict[str, float] = {}
    with tempfile.TemporaryDirectory(dir=args.dir, prefix="hermsd-slow-disk-") as scratch:
        state = Path(scratch)

        @contextlib.contextmanager
        def saves(threaded: bool, daemon: Daemon) -> Iterator[Every]:
            daemon.saver = Saver(threaded=threaded)
            daemon.latches = stall_saves(LatchStore(state), args.stall)
            models = stall_saves(ModelStore(state), args.stall)

            def save(t: float) -> None:
                daemon._save_latches(t)
                daemon._store_model(models, MODEL, None, t)

            every = Every(args.every, save)
            daemon.listeners.append(every)
            yield every

        @contextlib.contextmanager
        def on_loop(_where: str, daemon: Daemon) -> Iterator[Every]:
            every = Every(args.every, lambda t: fit())
            daemon.listeners.append(every)
            yield every

        @contextlib.contextmanager
        def beside_loop(where: str, daemon: Daemon) -> Iterator[Every]:
            start: Callable[[Callable[[], object]], object]
            if where == "thread":
                start = fit_in_thread
            else:
                start = process = FitProcess()  # started before the loop, as `hermsd tune`
            every = Every(args.every, lambda t: start(fit))
            daemon.listeners.append(every)
            try:
                yield every
            finally:
                if where == "process":
                    process.close()

        runs: list[tuple[str, Callable[..., contextlib.AbstractContextManager[Every]], Any]] = [
            ("saves on the loop (before)", saves, False),
            ("saves beside the loop (after)", saves, True),
            ("fits on the loop (before)", on_loop, ""),
            ("fits on a thread beside the loop", beside_loop, "thread"),
            ("fits in a process beside the loop (after)", beside_loop, "process"),
        ]
        for name, beside, how in runs:
            done: list[Every] = []
            gaps: list[float] = []
            rows[name] = measure(
                args.seconds, state / "logs", True, hooked(beside, how, done, gaps)
            )
            counts[name] = done[0].times
            stalls[name] = (max(gaps) - WINDOW_S) * 1e3
            print(name, counts[name], f"{stalls[name]:.1f} ms", rows[name], flush=True)
    more = ["saves or fits", "longest stall ms", "periods skipped"]
    cells = {
        name: f"{counts[name]} | {stalls[name]:.1f} | {r['overruns']:.0f}"
        for name, r in rows.items()
    }
    table = timing_table("the loop's extra work", more, rows, cells)
    ratios = _ratios(rows, stalls)
    print(table)
    print(ratios)
    if args.write:
        text = (
            f"As root ({args.seconds:.0f} s per row, the loop thread at SCHED_FIFO, files on "
            f"{args.dir}, a virtual machine's disk, not a Pi's SD card). bench/timing.py's "
            "loop (0.5 s periods, 0.1 s SSR windows at 50 %: one timed edge per window); every "
            f"{args.every:g} s it hands over a save of the latched alarms and of the learned "
            f"model, each stalled {args.stall:g} s before its durable write (as an fsync on a "
            "slow SD card), or fits an open pot's whole default step test as `tune step` "
            f"does ({fit_s:.2f} s on this machine). Before: on the loop thread, as the "
            "daemon did them; after: `hermsd.runtime.saver.Saver`, and `FitProcess` (what `hermsd "
            "tune` uses on the tun). The longest stall is the longest time between one SSR "
            "window's start and the next, less the window: p99 alone hides a stall, as the "
            "windows the loop missed have no edges to be late (and the periods it missed are "
            "skipped, not late). The thread row is why the fits run in a process: a fit is "
            "pure Python and holds the interpreter's lock, so an edge due meanwhile waits the "
            "switch interval (5 ms) or more. Goals: edge p99 ≤ 10 ms, period p99 ≤ 5 ms."
            "\n\n" + table + "\n\n" + ratios + "\n"
        )
        sections.write(
            "## Slow disk and tune fits: the loop with its saves and fits beside it", text
        )
    return 0


def _ratios(rows: dict[str, dict[str, float]], stalls: dict[str, float]) -> str:
    """Before against after, same run: the longest stall of the SSR windows, and the edges
    made (p99 alone hides a stall: the windows the loop missed have no edges to be late)."""
    parts = []
    for what, after in (
        ("saves", "saves beside the loop (after)"),
        ("fits", "fits in a process beside the loop (after)"),
    ):
        before = f"{what} on the loop (before)"
        parts.append(
            f"{what}: the longest stall {stalls[before]:.1f} → {stalls[after]:.1f} ms "
            f"({stalls[before] / max(stalls[after], 1e-3):.0f}× shorter), SSR edges made "
            f"{rows[before]['edges']:.0f} → {rows[after]['edges']:.0f}"
        )
    return "Same run: " + "; ".join(parts) + "."


if __name__ == "__main__":
    sys.exit(main())
