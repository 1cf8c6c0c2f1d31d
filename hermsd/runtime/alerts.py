"""Alerts: the brewer's own command, run for the events a brewer must hear of.

The control loop only hands an event over (`Alerts.send`: a rate check and a put on a bounded
queue, never a wait). A worker thread of ordinary priority runs `alerts.command` for it,
without a shell, with the event as JSON on stdin and as HERMSD_* environment variables, and
kills the child after `alerts.timeout`. A command that fails, hangs or is not there is a
warning in the journal and the log: an alert is worth less than a control period, but a lost
one must not pass unnoticed. See docs/alerts.md for the variables and examples.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import queue
import signal
import subprocess
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from hermsd.config.schema import AlertsConfig

QUEUE_SIZE = 32
"""Events waiting for the worker; more than a burst of alarms, few enough that a command
that always times out cannot hold a backlog hours old."""
SHUTDOWN_WAIT = 5.0
"""s at most that shutdown waits for queued alerts (less if alerts.timeout is shorter), after
the outputs are off: well inside systemd's stop timeout of 10 s (systemd/hermsd.service)."""

REAP_WAIT = 1.0
"""s the worker gets after a kill at shutdown to reap the command and say so."""


@dataclass(frozen=True, slots=True)
class Event:
    """One thing the brewer should hear of, as the child receives it."""

    event: str  # one of config.ALERT_EVENTS
    message: str
    tun: str
    wall_ns: int
    kind: str = ""  # the alarm's kind (overtemp, sensor_fault, …); empty for other events
    pv: float | None = None
    setpoint: float | None = None
    output: float | None = None
    suppressed: int = 0  # events of this event and kind held back by min_interval before it

    def as_json(self) -> str:
        return json.dumps({**dataclasses.asdict(self), "time": self.time()}) + "\n"

    def time(self) -> str:
        """UTC, ISO 8601 to the second."""
        return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(self.wall_ns // 1_000_000_000))

    def environment(self) -> dict[str, str]:
        """The HERMSD_* variables; an unknown number is the empty string."""

        def number(value: float | None) -> str:
            return "" if value is None else f"{value:.2f}"

        return {
            "HERMSD_EVENT": self.event,
            "HERMSD_KIND": self.kind,
            "HERMSD_MESSAGE": self.message,
            "HERMSD_TUN": self.tun,
            "HERMSD_PV": number(self.pv),
            "HERMSD_SETPOINT": number(self.setpoint),
            "HERMSD_OUTPUT": number(self.output),
            "HERMSD_TIME": self.time(),
            "HERMSD_SUPPRESSED": str(self.suppressed),
        }


class Alerts:
    """The queue, the rate limit and the worker that runs the command.

    `warn` receives every failure as one line; it is called from the worker thread (and from
    the caller of `send` for a full queue), so it must be thread-safe.
    """

    def __init__(
        self, config: AlertsConfig, warn: Callable[[str], None], queue_size: int = QUEUE_SIZE
    ) -> None:
        self.config = config  # replaced on a reload; each event keeps the one it was sent under
        self._warn = warn
        self._queue: queue.Queue[tuple[Event, AlertsConfig] | None] = queue.Queue(queue_size)
        self._last_sent: dict[tuple[str, str], float] = {}
        self._held_back: dict[tuple[str, str], int] = {}
        self._latest_held: dict[tuple[str, str], tuple[Event, float]] = {}
        self._latest_of_kind: dict[str, float] = {}  # when each kind's last event came
        self._child: subprocess.Popen[bytes] | None = None
        self._child_lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self.dropped = 0  # events lost to a full queue
        self.failed = 0  # commands that failed, timed out or could not be started

    def start(self) -> None:
        """Start the worker if there is a command to run (called again after a reload)."""
        if self._thread is None and self.config.command is not None:
            self._thread = threading.Thread(target=self._work, name="hermsd-alerts", daemon=True)
            self._thread.start()

    def send(self, event: Event, t: float) -> None:
        """Hand `event` to the worker unless it is not wanted or too soon; never blocks.

        `t` is the loop's monotonic time. An event within `min_interval` of the last one sent
        of the same event and kind is held back and counted in the next one sent; `flush`
        sends it once that interval has passed if it is still its kind's latest news.
        """
        config = self.config
        if config.command is None or event.event not in config.events:
            return
        key = (event.event, event.kind)
        self._latest_of_kind[event.kind] = t
        last = self._last_sent.get(key)
        if last is not None and t - last < config.min_interval:
            self._held_back[key] = self._held_back.get(key, 0) + 1
            self._latest_held[key] = (event, t)
            return
        self._dispatch(key, event, t)

    def flush(self, t: float) -> None:
        """Send each held-back event whose interval has passed and that nothing of its kind
        followed: an alarm raised again soon after it cleared must not leave "cleared" as
        the brewer's last word while the heater is off. Called by the loop each period."""
        if self.config.command is None:  # a reload took the command away
            self._latest_held.clear()
            return
        for key, (event, when) in list(self._latest_held.items()):
            if t - self._last_sent[key] < self.config.min_interval:
                continue
            del self._latest_held[key]
            if self._latest_of_kind[event.kind] == when:  # else moot: counted in the next
                self._held_back[key] -= 1  # sent itself, not counted in itself
                self._dispatch(key, event, t)

    def _dispatch(self, key: tuple[str, str], event: Event, t: float) -> None:
        self._last_sent[key] = t
        self._latest_held.pop(key, None)
        held_back = self._held_back.pop(key, 0)
        if held_back:
            event = dataclasses.replace(event, suppressed=held_back)
        try:
            self._queue.put_nowait((event, self.config))
        except queue.Full:
            self.dropped += 1
            self._warn(
                f"alert queue full: {event.event} alert dropped ({self.dropped} since start)"
            )

    def close(self, timeout: float) -> bool:
        """Let the worker run what is queued for at most `timeout` s (real time), then stop it
        and kill a child still running; False if anything was left unsent."""
        thread = self._thread
        if thread is None:
            return True
        deadline = time.monotonic() + timeout
        with contextlib.suppress(queue.Full):  # a full queue: the worker gets the time anyway
            self._queue.put(None, timeout=timeout)
        thread.join(max(0.0, deadline - time.monotonic()))
        if not thread.is_alive():
            return True
        left = 0
        while True:  # what is still queued stays unsent: the worker stops after its child
            try:
                left += self._queue.get_nowait() is not None
            except queue.Empty:
                break
        self._queue.put_nowait(None)
        with self._child_lock:
            if self._child is not None:
                _signal_group(self._child)  # the worker reaps it: no wait here
        thread.join(REAP_WAIT)  # the worker says what the kill did to the command
        self._warn(
            f"alerts not finished {timeout:g} s after shutdown: the command running was "
            f"killed, {left} more left unsent"
        )
        return False

    def _work(self) -> None:
        leave_real_time()
        while (item := self._queue.get()) is not None:
            event, config = item
            try:
                problem = self._run(event, config)
            except Exception as error:  # the worker must outlive one bad run
                problem = f"could not be run: {error!r}"
            if problem is not None:
                self.failed += 1
                self._warn(f"alert command for {event.event} {problem}")

    def _run(self, event: Event, config: AlertsConfig) -> str | None:
        """Run the command for `event`; what went wrong, or None."""
        assert config.command is not None
        argv = list(config.command)
        try:
            child = subprocess.Popen(
                argv,
                stdin=subprocess.PIPE,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.PIPE,
                env={**os.environ, **event.environment()},
                start_new_session=True,  # a Ctrl-C on the daemon's terminal is not for it
            )
        except OSError as error:
            return f"could not start {argv[0]!r}: {error.strerror or error}"
        with self._child_lock:
            self._child = child
        try:
            with child:  # reaps it on leaving: the kill must come first
                try:
                    _, stderr = child.communicate(event.as_json().encode(), config.timeout)
                except subprocess.TimeoutExpired:
                    _kill(child)
                    return f"killed after {config.timeout:g} s (alerts.timeout)"
        finally:
            with self._child_lock:
                self._child = None
        if child.returncode < 0:
            return f"killed by {_signal_name(-child.returncode)}"
        if child.returncode != 0:
            said = stderr.decode(errors="replace").strip().splitlines()
            why = f": {said[-1][:200]}" if said else ""
            return f"failed with exit status {child.returncode}{why}"
        return None


def _kill(child: subprocess.Popen[bytes]) -> None:
    """SIGKILL the child's process group (it leads one), so that whatever it started dies with
    it and no grandchild keeps the pipes open; then reap it."""
    _signal_group(child)
    child.wait()


def _signal_group(child: subprocess.Popen[bytes]) -> None:
    with contextlib.suppress(ProcessLookupError):  # already gone
        os.killpg(child.pid, signal.SIGKILL)


def _signal_name(number: int) -> str:
    try:
        return signal.Signals(number).name
    except ValueError:  # a real-time signal has no name of its own
        return f"signal {number}"


def leave_real_time() -> None:
    """Ordinary priority for the calling thread and what it starts.

    The loop thread runs SCHED_FIFO with SCHED_RESET_ON_FORK, so a thread it starts is
    ordinary already; this holds whichever thread starts the worker. An alert command must
    never compete with the loop.
    """
    policy = os.sched_getscheduler(0) & ~os.SCHED_RESET_ON_FORK
    if policy in (os.SCHED_FIFO, os.SCHED_RR):
        os.sched_setscheduler(0, os.SCHED_OTHER | os.SCHED_RESET_ON_FORK, os.sched_param(0))
