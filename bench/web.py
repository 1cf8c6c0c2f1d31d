"""The web page with a full day of history: time to first paint and bytes sent.

A daemon on the simulated tun (default config: 5 s periods) runs on the virtual clock for
`--hours` (24: 17,280 periods, the ring full) behind a real control socket, then goes on at
one period a second; `hermsd web` serves it on loopback; Debian's Chromium opens the page
`--runs` times, each in a fresh profile (nothing cached) at phone size (390×844), and reads
its performance API: first contentful paint, the chart drawn (the page's `hermsd-chart`
mark, after the history has arrived and been plotted) and the bytes transferred (page,
scripts, styles and history, compressed as sent). The same is measured with 1 hour of
history as the peer, in the same run. Also: the history reply's size with and without
gzip, and the server's time to answer it over 20 requests (the body is made once per
period, so the slowest includes a rebuild: the daemon runs on at one period a second).

`--herms`: the daemon is a HERMS's (a mash sensor and a pump): its mash doughed in at 70 °C
while the HLT starts at 20 °C, the pump running from the start, so every row carries the
mash's reading and the page draws its second line.

And the daemon's part: what the loop pays per period for the ring (`encode_row` and
`append`), and what the socket's server thread holds the interpreter lock for to make one
page of 2,000 rows, each beside encoding the status reply, which that thread does once a
period already.

    uv run python bench/web.py [--hours 24] [--runs 5] [--herms]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import statistics
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
from playwright.sync_api import Browser, sync_playwright

from hermsd.api.history import HistoryRing, capacity_for, encode_row, page_line
from hermsd.api.link import LoopLink
from hermsd.api.protocol import MAX_PAGE, encode
from hermsd.api.server import ControlServer
from hermsd.config import read
from hermsd.config import schema as config_module
from hermsd.config.schema import Config
from hermsd.runtime.assemble import assemble
from hermsd.runtime.daemon import Daemon
from hermsd.runtime.period import PeriodRecord
from hermsd.sim.clock import VirtualClock
from hermsd.sim.hlt import FoptdPlant
from hermsd.sim.mash import HermsTun
from hermsd.sim.world import build_world
from hermsd.web.app import WebSettings, create_app
from hermsd.web.main import listening_socket, make_server

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from webpage import CHROMIUM, CHROMIUM_ARGS, PHONE

MEASURE = """() => {
  const paint = performance.getEntriesByName('first-contentful-paint')[0];
  const chart = performance.getEntriesByName('hermsd-chart')[0];
  const navigation = performance.getEntriesByType('navigation')[0];
  const resources = performance.getEntriesByType('resource')
    .filter((entry) => !entry.name.includes('/api/events'));
  return {
    fcp: paint ? paint.startTime : null,
    chart: chart ? chart.startTime : null,
    bytes: navigation.transferSize + resources.reduce((sum, e) => sum + e.transferSize, 0),
    points: window.hermsd.points(),
  };
}"""


HERMS = "mash_sensor:\n  kind: lm92\n  address: 0x49\npump:\n  backend: sim\n"


@contextlib.contextmanager
def simulated(herms: bool) -> Iterator[tuple[Daemon, Config, VirtualClock]]:
    """The started daemon on the simulated tun (the default config), or on a HERMS whose
    mash was doughed in at 70 °C (50 L at 75 °C, 12 kg of grain at 20 °C), its pump on."""
    config = read.parse(HERMS) if herms else config_module.DEFAULT
    clock = VirtualClock()
    plant = None
    if herms:
        plant = HermsTun(FoptdPlant())
        plant.dough_in(grain_kg=12.0, grain_c=20.0, water_litres=50.0, water_c=75.0, t=0.0)
    world = build_world(config, clock, tun=plant)
    mash = world.mash
    daemon = assemble(
        config,
        clock,
        world.sensor,
        world.outputs,
        mash_sensor=None if mash is None else mash.mash_sensor,
    )
    with daemon:
        if herms:
            daemon.set_pump(True, "by the bench")
        yield daemon, config, clock


@contextlib.contextmanager
def page_server(hours: float, directory: Path, herms: bool) -> Iterator[tuple[str, int]]:
    """A daemon with `hours` of history behind its socket, and the page in front of it."""
    with simulated(herms) as (daemon, config, clock):
        link = LoopLink(daemon)
        control = ControlServer(directory / "control.sock", link.status_line, link.history_line)
        control.start()
        link.attach(control)
        stop = threading.Event()
        daemon.run(until=hours * 3600.0)
        periods = len(link.history.page(None, 1_000_000)[0])

        def live() -> None:
            while not stop.wait(1.0):
                daemon.run(until=clock.monotonic() + config.control.period)

        stepper = threading.Thread(target=live)
        stepper.start()
        settings = WebSettings(directory / "control.sock", None, 3600.0, read_only_view=True)
        http = make_server(create_app(settings))
        listener = listening_socket("127.0.0.1", 0)
        serving = threading.Thread(target=lambda: asyncio.run(http.serve(sockets=[listener])))
        serving.start()
        url = f"http://127.0.0.1:{listener.getsockname()[1]}"
        try:
            with httpx.Client(base_url=url, timeout=30.0) as client:
                while len(_history(client)[0]) < periods:  # the server's mirror is loaded
                    time.sleep(0.1)
            yield url, periods
        finally:
            http.should_exit = True
            stop.set()
            serving.join()
            stepper.join()
            listener.close()
            control.close()


def _history(client: httpx.Client, encoding: str = "gzip") -> tuple[list[Any], int, float]:
    started = time.perf_counter()
    reply = client.get("/api/history", headers={"accept-encoding": encoding})
    elapsed = time.perf_counter() - started
    wire = int(reply.headers.get("content-length", len(reply.content)))
    return reply.json()["t"], wire, elapsed


def measure(browser: Browser, url: str, runs: int) -> dict[str, float]:
    figures: list[dict[str, Any]] = []
    for _ in range(runs):
        context = browser.new_context(viewport=PHONE)
        page = context.new_page()
        page.goto(url)
        for _ in range(600):
            if page.evaluate("performance.getEntriesByName('hermsd-chart').length > 0"):
                break
            page.wait_for_timeout(10)
        page.wait_for_timeout(200)  # FCP is reported a frame after it happens
        figures.append(page.evaluate(MEASURE))
        context.close()
    return {
        key: statistics.median(float(f[key]) for f in figures)
        for key in ("fcp", "chart", "bytes", "points")
    }


class _Keep:
    """Keeps the loop's period records."""

    def __init__(self) -> None:
        self.records: list[PeriodRecord] = []

    def period(self, record: PeriodRecord) -> None:
        self.records.append(record)

    def alarm(self, alarm: object) -> None:
        pass


def _per_call(call: Callable[[], object], repeat: int) -> float:
    """The median of `repeat` timings of `call`, in seconds."""
    times = []
    for _ in range(repeat):
        started = time.perf_counter()
        call()
        times.append(time.perf_counter() - started)
    return statistics.median(times)


def daemon_costs(herms: bool) -> None:
    """Per-call µs of the ring on the loop and of a page on the server thread."""
    with simulated(herms) as (daemon, config, _clock):
        kept = _Keep()
        daemon.listeners.append(kept)
        link = LoopLink(daemon)
        daemon.run(until=24 * 3600.0)
        link.period(kept.records[-1])  # a snapshot to encode, as at a boundary
    ring = HistoryRing(capacity_for(config.control.period))
    started = time.perf_counter()
    for record in kept.records:
        ring.append(*encode_row(record))
    per_row = (time.perf_counter() - started) / len(kept.records)
    page = _per_call(lambda: page_line(*ring.page(None, MAX_PAGE), config.control.period), 200)
    snapshot = link._snapshot
    assert snapshot is not None
    status = _per_call(lambda: encode(LoopLink._status_message(snapshot)), 200)
    print(
        f"\nloop, per period: encode_row + append {per_row * 1e6:.1f} µs "
        f"({len(kept.records)} periods); server thread: a page of {MAX_PAGE} rows "
        f"{page * 1e6:.0f} µs, the status reply encoded {status * 1e6:.0f} µs "
        f"(page ×{page / status:.2f})"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--hours", type=float, default=24.0)
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--herms", action="store_true", help="a HERMS: the mash's line too")
    args = parser.parse_args()
    rows = []
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        for hours in (1.0, args.hours):
            with (
                tempfile.TemporaryDirectory() as directory,
                page_server(hours, Path(directory), args.herms) as (url, periods),
            ):
                with httpx.Client(base_url=url, timeout=30.0) as client:
                    _t, plain, _ = _history(client, "identity")
                    answers = [_history(client) for _ in range(20)]
                gzipped = answers[-1][1]
                times = sorted(answer[2] for answer in answers)
                figures = measure(browser, url, args.runs)
                rows.append((hours, periods, gzipped, plain, times[10], times[-1], figures))
        browser.close()
    print(
        "| history | periods | first paint ms | chart drawn ms | bytes sent | history gzip / "
        "plain bytes | history answer ms (median / max of 20) |"
    )
    print("|---|---|---|---|---|---|---|")
    for hours, periods, gzipped, plain, median, slowest, figures in rows:
        print(
            f"| {hours:g} h | {periods} | {figures['fcp']:.0f} | {figures['chart']:.0f} | "
            f"{figures['bytes']:.0f} | {gzipped} / {plain} | {median * 1e3:.1f} / "
            f"{slowest * 1e3:.1f} |"
        )
    daemon_costs(args.herms)
    day, hour = rows[-1][6], rows[0][6]
    print(
        f"\n{args.hours:g} h against 1 h: first paint ×{day['fcp'] / hour['fcp']:.2f}, chart "
        f"drawn ×{day['chart'] / hour['chart']:.2f}, bytes ×{day['bytes'] / hour['bytes']:.2f}"
    )


if __name__ == "__main__":
    main()
