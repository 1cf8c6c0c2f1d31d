"""What the web server knows of the daemon: its last status and a mirror of its history.

One task asks the daemon for `status` every `poll` seconds (a fifth of the control period,
0.2 to 1 s, so a new period reaches the pages well within one period) and, when a new
period has run, for the history rows since the last it has (`history`, paged), so the
mirror has no gap however a poll was late. Each new period is pushed to every open page as
one server-sent event. The pages' chart loads the mirror once (`history_body`, encoded once
per period however many pages ask); the daemon is asked for no more than one page of
history a period after the first load.

Every event says how old its reading is: `age`, the seconds since the hub first got that
period from the daemon (within a poll of its running), and `stale_after`, the age beyond
which the page must not show it as live (two control periods). A page opened or
reconnected while the daemon does not answer (its socket refuses, or no answer for
`stale_after`) is told so first, never handed the last status the hub kept.
"""

from __future__ import annotations

import asyncio
import contextlib
import gzip
import json
import logging
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

from hermsd.api.client import LONGEST_PERIOD
from hermsd.api.history import KEPT_SECONDS
from hermsd.metrics import BAND
from hermsd.safety.limits import LATCHED_KINDS
from hermsd.web.socket_client import DaemonUnavailable, ask

log = logging.getLogger("hermsd")

PAGE_FIELDS = (
    "tun",
    "t",
    "pv",
    "setpoint",
    "output",
    "output2",
    "applied",
    "mode",
    "manual_output",
    "state",
    "alarms",
    "alarm_reasons",
    "warnings",
    "heater_allowed",
    "program",
    "mash",
    "pump",
    "pump_switched",
    "current",
)
"""What the page shows of a status (not the limits, model and learned texts: 2 kB a period)."""
PAGE_DERIVED = ("latched",)
"""What the hub adds for the page: `latched`, the standing alarms that wait for a reset (the
others clear themselves once over), so the page offers a reset only where one does something."""
STALE_PERIODS = 2.0  # control periods a reading may be old and still be shown as live
QUEUE_EVENTS = 32  # events a page may fall behind by before it is dropped (it reconnects)
MAX_PAGES = 32  # open event streams at once

Asker = Callable[[Path, dict[str, Any]], Awaitable[dict[str, Any]]]
"""How a hub asks the daemon a request and awaits its reply (`socket_client.ask`)."""


class TooManyPages(Exception):
    """MAX_PAGES event streams are open already."""


class Hub:
    """The daemon's state as the pages see it, and the event streams to them."""

    def __init__(
        self,
        socket: Path,
        poll: float | None = None,
        asker: Asker = ask,
        clock: Callable[[], float] = time.monotonic,
        stale_after: float | None = None,
    ) -> None:
        """`asker`: its own way to the daemon, so that no other hub's requests (another
        page's, in one process) pass through one given to this hub. `clock`: s, for the
        readings' ages. `stale_after`: s; None: STALE_PERIODS control periods."""
        self.socket = socket
        self.poll = poll
        self._ask = asker
        self._clock = clock
        self._stale_after = stale_after
        self.status: dict[str, Any] | None = None
        self.error: str | None = "connecting to hermsd"
        self.answered_at: float | None = None  # clock() at the daemon's last status answer
        self.seen_at = 0.0  # clock() when `status` (its period) first came
        self.offset = 0.0  # wall-clock s minus the daemon's t, at the last new period
        self.period: float | None = None
        # t, pv (None: unknown), setpoint, output, mash (None: none fitted, or faulty), the
        # HLT's setpoint the outer loop chose (None: no mash sensor): the chart's columns
        self._columns: tuple[list[Any], ...] = ([], [], [], [], [], [])
        self._body: tuple[float | None, bytes, bytes] | None = None  # last t, JSON, gzipped
        self._pages: set[asyncio.Queue[bytes | None]] = set()
        self._poke = asyncio.Event()

    # -- polling ------------------------------------------------------------------------------

    async def run(self) -> None:
        """Poll the daemon until cancelled."""
        while True:
            try:
                await self.refresh()
            except Exception as error:  # a reply it cannot read must not end the polling
                why = f"hermsd's reply could not be read ({error!r})"
                if self.error != why:  # said once, not at every poll
                    self.error = why
                    log.exception("web: %s; polling on", why)
                    self._push(self._error_event(why))
            self._poke.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._poke.wait(), self._interval())

    def poke(self) -> None:
        """Poll now (a command was just applied)."""
        self._poke.set()

    def _interval(self) -> float:
        if self.poll is not None:
            return self.poll
        return 1.0 if self.period is None else min(1.0, max(0.2, self.period / 5.0))

    async def refresh(self) -> None:
        """Ask for the status; on a new period, catch the mirror up and push the period."""
        try:
            status = await self._ask(self.socket, {"cmd": "status"})
            if not status["ok"]:
                raise DaemonUnavailable(str(status.get("error", "hermsd refused status")))
            self.answered_at = self._clock()
            if self.status is not None and status["t"] == self.status["t"]:
                if self.error is not None:  # answering again, no period run meanwhile
                    self.error = None
                    self._push(self._status_event([]))
                return
            restarted, rows = await self._rows_since_mirror(status["t"])
        except DaemonUnavailable as error:
            if self.error != str(error):
                self.error = str(error)
                log.warning("web: %s", error)
                self._push(self._error_event(self.error))
            return
        self._add(restarted, rows, status["t"])
        self.error = None
        self.status = page_status(status)
        self.seen_at = self._clock()
        self.offset = time.time() - float(status["t"])
        self._push(self._status_event(rows))

    # -- how old the reading is -------------------------------------------------------------

    def stale_after(self) -> float:
        """The age (s) beyond which a reading is not live: STALE_PERIODS control periods."""
        if self._stale_after is not None:
            return self._stale_after
        return STALE_PERIODS * (LONGEST_PERIOD if self.period is None else self.period)

    def reading_age(self) -> float | None:
        """Seconds since the hub got the period its status is of; None: it has none."""
        return None if self.status is None else self._clock() - self.seen_at

    def silence(self) -> str | None:
        """Why the daemon cannot be taken as answering now, or None: it answers."""
        if self.error is not None:
            return self.error
        quiet = self._clock() - (self.answered_at or 0.0)
        if quiet > self.stale_after():
            return f"hermsd has not answered for {quiet:.0f} s"
        return None

    def _status_event(self, rows: list[list[Any]]) -> dict[str, Any]:
        return {
            "status": self.status,
            "rows": rows,
            "offset": self.offset,
            "age": self.reading_age(),
            "stale_after": self.stale_after(),
        }

    def _error_event(self, why: str) -> dict[str, Any]:
        return {"error": why, "age": self.reading_age(), "stale_after": self.stale_after()}

    async def _rows_since_mirror(self, latest: float) -> tuple[bool, list[list[Any]]]:
        """Whether the daemon restarted (its history is new), and the rows the mirror lacks
        (all kept ones after a restart). The mirror itself is not touched here: it changes
        with the status, between two awaits, so a page never sees one without the other."""
        times = self._columns[0]
        restarted = bool(times) and latest < times[-1]
        since = None if restarted or not times else times[-1]
        new: list[list[Any]] = []
        more = True
        while more:
            page = await self._ask(self.socket, {"cmd": "history", "since": since, "limit": 2000})
            if not page["ok"]:
                raise DaemonUnavailable(str(page.get("error", "hermsd refused history")))
            self.period = float(page["period"])
            more = bool(page["more"]) and bool(page["rows"])
            for row in page["rows"]:
                t = row[0]
                if t > latest:  # a period that ran after the status: it comes with its own
                    return restarted, new
                padded = [*row, None, None]  # a daemon from before the mash, or its loop
                new.append([*padded[:4], padded[5], padded[6]])
                since = t
        return restarted, new

    def _add(self, restarted: bool, rows: list[list[Any]], latest: float) -> None:
        if restarted:
            for column in self._columns:
                column.clear()
        for row in rows:
            for column, value in zip(self._columns, row, strict=True):
                column.append(value)
        self._trim(latest)

    def _trim(self, latest: float) -> None:
        times = self._columns[0]
        cut = 0
        while cut < len(times) and times[cut] <= latest - KEPT_SECONDS:
            cut += 1
        if cut:
            for column in self._columns:
                del column[:cut]

    # -- the pages ------------------------------------------------------------------------------

    def history_body(self) -> tuple[bytes, bytes]:
        """The mirror as JSON columns (t, pv, setpoint, output, mash, hlt_setpoint), plain and
        gzipped, made once per period however many pages load it (a day is 514 kB, 11× less
        gzipped)."""
        times = self._columns[0]
        last = times[-1] if times else None
        if self._body is None or self._body[0] != last:
            t, pv, setpoint, output, mash, hlt_setpoint = self._columns
            body = {
                "band": BAND,  # °C either side of the setpoint that counts as holding it
                "period": self.period,
                "offset": self.offset,
                "t": t,
                "pv": pv,
                "setpoint": setpoint,
                "output": output,
                "mash": mash,
                "hlt_setpoint": hlt_setpoint,
            }
            encoded = json.dumps(body, separators=(",", ":")).encode()
            self._body = (last, encoded, gzip.compress(encoded, compresslevel=6))
        return self._body[1], self._body[2]

    def rows_after(self, since: float) -> list[list[Any]]:
        """The mirrored rows after `since` (a page that reconnects)."""
        times = self._columns[0]
        start = next((i for i in range(len(times) - 1, -1, -1) if times[i] <= since), -1) + 1
        return [[column[i] for column in self._columns] for i in range(start, len(times))]

    def open_page(self, since: float | None) -> asyncio.Queue[bytes | None]:
        """A queue of this page's events, starting with the state now: the daemon's silence,
        if it does not answer (never the last status kept), else its status and age."""
        if len(self._pages) >= MAX_PAGES:
            raise TooManyPages(f"{MAX_PAGES} pages are open already")
        queue: asyncio.Queue[bytes | None] = asyncio.Queue(QUEUE_EVENTS)
        silence = self.silence()
        if silence is not None or self.status is None:
            first = self._error_event(silence or "connecting to hermsd")
        else:
            first = self._status_event([] if since is None else self.rows_after(since))
        queue.put_nowait(_event(first))
        self._pages.add(queue)
        return queue

    def close_page(self, queue: asyncio.Queue[bytes | None]) -> None:
        self._pages.discard(queue)

    def _push(self, message: dict[str, Any]) -> None:
        event = _event(message)
        for queue in list(self._pages):
            try:
                queue.put_nowait(event)
            except asyncio.QueueFull:  # a page that stopped reading: end its stream
                self._pages.discard(queue)
                queue.get_nowait()
                queue.put_nowait(None)


def page_status(status: dict[str, Any]) -> dict[str, Any]:
    """The fields of a status reply the page shows (`program` only when the daemon has it), and
    PAGE_DERIVED."""
    shown = {key: status[key] for key in PAGE_FIELDS if key in status}
    shown["latched"] = [kind for kind in status.get("alarms", ()) if kind in LATCHED_KINDS]
    return shown


def _event(message: dict[str, Any]) -> bytes:
    return b"data: " + json.dumps(message, separators=(",", ":")).encode() + b"\n\n"
