"""A simulated daemon behind a real control socket, and the web page in front of it, for the
web tests: the daemon runs on the virtual clock, one period per `pace` s of wall time on a
thread (or held, for a test to step it), and the page is served by uvicorn on a loopback
port of its own. Also bench/web.py's Chromium settings."""

from __future__ import annotations

import asyncio
import contextlib
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from starlette.applications import Starlette
from test_reload import BASE, PERIOD, Events, run_for, start

from hermsd.api.link import LoopLink
from hermsd.api.server import ControlServer
from hermsd.runtime.daemon import Daemon
from hermsd.sim.hlt import Plant
from hermsd.web.app import WebSettings, create_app
from hermsd.web.hub import Hub
from hermsd.web.main import listening_socket, make_server
from hermsd.web.passwords import hash_password, parse_hash

if TYPE_CHECKING:  # the browser's types only: test_web.py runs no browser
    from playwright.sync_api import ViewportSize

CHROMIUM = Path("/usr/bin/chromium")  # Debian's, never a downloaded build
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
PHONE: ViewportSize = {"width": 390, "height": 844}
PASSWORD = "mash-in-at-72"
STORED = parse_hash(hash_password(PASSWORD))
TIMEOUT = 10.0


@dataclass
class Site:
    daemon: Daemon
    events: Events
    server: ControlServer
    url: str
    running: threading.Event  # cleared: the daemon is held between periods
    lock: threading.Lock  # held while a period runs
    hub: Hub  # the page's view of the daemon
    answering: bool = True  # False: the daemon's control socket is closed

    def stop_answering(self) -> None:
        """Close the daemon's control socket, as a daemon that stops does, and wait until the
        page's hub has seen it gone (a subscription cut as the socket closed says so first,
        "connection reset", under load; the hub's next try finds nothing answering)."""
        self.answering = False
        self.server.close()
        deadline = time.monotonic() + TIMEOUT
        while not (self.hub.error or "").startswith("no hermsd is running"):
            assert time.monotonic() < deadline, "the hub did not see the daemon go"
            time.sleep(0.01)

    @contextlib.contextmanager
    def held(self) -> Iterator[float]:
        """The loop held between periods (no new status can reach a page); yields the t of
        the last period run."""
        self.running.clear()
        try:
            with self.lock:
                last = self.events.periods[-1].t
            yield last
        finally:
            self.running.set()

    def step(self, periods: int = 1) -> None:
        """Run `periods` periods now (with `running` cleared, nothing else steps)."""
        with self.lock:
            run_for(self.daemon, periods * PERIOD)

    def wait_for_command(self) -> None:
        """Until a command from a client waits for the next period boundary."""
        deadline = time.monotonic() + TIMEOUT
        while not self.server._commands:
            assert time.monotonic() < deadline, "no command reached the daemon"
            time.sleep(0.005)


@contextlib.contextmanager
def site(
    tmp_path: Path,
    *,
    read_only_view: bool = True,
    pace: float = 0.05,
    stale_after: float = 60.0,
    text: str = BASE,
    tun: Plant | None = None,
) -> Iterator[Site]:
    """`stale_after`: s a reading is shown as live; long by default, as a test may hold the
    loop longer than two periods (10 s of wall time here, as the hub counts them). `text`
    and `tun`: the daemon's config and plant (`test_reload.HERMS` and `doughed_in()`: a
    HERMS)."""
    daemon, _world, _path, events = start(tmp_path, text, tun=tun)
    link = LoopLink(daemon)
    control = ControlServer(tmp_path / "control.sock")
    control.answer_with(link.status_line, link.history_line, link.arrived)
    control.start()
    link.attach(control)
    running, stop, lock = threading.Event(), threading.Event(), threading.Lock()
    running.set()

    def stepping() -> None:
        while not stop.is_set():
            with lock:
                if running.is_set():
                    run_for(daemon, PERIOD)
            stop.wait(pace)  # paces virtual time; nothing is measured on this clock

    settings = WebSettings(
        tmp_path / "control.sock",
        STORED,
        3600.0,
        read_only_view,
        poll=min(0.05, pace),
        stale_after=stale_after,
    )
    app = create_app(settings)
    stepper = threading.Thread(target=stepping)
    stepper.start()
    answering = [True]
    try:
        with served(app) as url:
            opened = Site(daemon, events, control, url, running, lock, app.state.hub)
            try:
                yield opened
            finally:
                answering[0] = opened.answering
    finally:
        stop.set()
        stepper.join(TIMEOUT)
        if answering[0]:
            control.close()


@contextlib.contextmanager
def served(app: Starlette, **bounds: Any) -> Iterator[str]:
    """`app` served by `hermsd web`'s uvicorn setup (`make_server`, given `bounds`) on a
    loopback port of its own, on a thread; yields its URL."""
    http = make_server(app, **bounds)
    listener = listening_socket("127.0.0.1", 0)
    port = listener.getsockname()[1]
    serving = threading.Thread(target=lambda: asyncio.run(http.serve(sockets=[listener])))
    serving.start()
    deadline = time.monotonic() + TIMEOUT
    try:
        while not http.started:
            assert time.monotonic() < deadline, "the web server did not start"
            time.sleep(0.01)
        yield f"http://127.0.0.1:{port}"
    finally:
        http.should_exit = True
        serving.join(TIMEOUT)
        listener.close()
