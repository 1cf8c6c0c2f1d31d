"""What the loop says of itself: the status line, the log's health, the config's record
(the Daemon's reporting, in a module of its own)."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import asdict
from typing import TYPE_CHECKING

from hermsd.config.read import to_dict
from hermsd.control import pid
from hermsd.control.reach import PREFIX
from hermsd.log.topics import CONFIG_TOPIC
from hermsd.runtime.build import _tun_fields
from hermsd.runtime.loop_state import LoopState
from hermsd.runtime.notify import WatchdogGate, status_line
from hermsd.safety.element_watch import no_heat_words

LOG_FAILING_REPEAT_S = 60.0  # a failing log is said again this often while it lasts


class Reporting(LoopState):
    """The Daemon's status line and notifier, the log's health and the config's record."""

    on_status: Callable[[str], None] | None
    _ready: bool
    _watchdog: WatchdogGate | None
    _output2: float | None
    _log_failing: str | None
    _log_failing_since: float
    _log_failing_said: float

    if TYPE_CHECKING:  # the Daemon's, and the MashSide's

        def _asked(self) -> float: ...

        def mash_words(self) -> str: ...

        def hlt_target(self) -> float: ...

    @property
    def log_failing(self) -> str | None:
        """Why the log cannot be written, while it cannot (None: it is written)."""
        return self._log_failing

    def status_text(self) -> str:
        state = ", ".join(self.supervisor.active) or ("manual" if self.mode == "manual" else "ok")
        if self._config_problem is not None:
            state += ", config rejected (see journal)"
        if self._log_failing is not None:
            state += f", log failing: {self._log_failing}"
        if self._latch_failing is not None:
            state += f", latched alarms not saved: {self._latch_failing}"
        if self.program.active:
            state += f", {self.program.status_words(self.clock.wall_ns())}"
        for element in sorted(self.element_watch.suspect if self.element_watch else ()):
            state += f", {no_heat_words(element)}"
        if self.reach.ceiling is not None:
            state += f", {PREFIX} near {self.reach.ceiling:.1f} °C"
        name, kind = self.config.tun.name, self.config.sensor.kind
        shown = name if kind == "lm92" else f"{name} ({kind})"  # the LM92's line as it was
        return status_line(
            shown,
            self._pv,
            self.hlt_target(),
            self._asked(),
            state,
            self._output2,
            self.mash_words(),
        )

    def _check_log(self, t: float) -> None:
        """Say that the log cannot be written at once, every minute while it lasts, and when
        it can again: control goes on without it, but nobody should learn it from a lost day."""
        failing: str | None = getattr(self.recorder, "failing", None)
        if failing is None:
            if self._log_failing is not None:
                self._log_failing = None
                lost = getattr(self.recorder, "lost", 0)
                self._event(
                    logging.WARNING,
                    f"log writing again after {t - self._log_failing_since:.0f} s failing "
                    f"({lost} records lost since start)",
                    t,
                )
            return
        if self._log_failing is None:
            self._log_failing_since = t
        elif t - self._log_failing_said < LOG_FAILING_REPEAT_S:
            self._log_failing = failing
            return
        self._log_failing, self._log_failing_said = failing, t
        lasting = t - self._log_failing_since
        since = f" for {lasting:.0f} s" if lasting > 0 else ""
        self._event(logging.WARNING, f"log failing{since}: {failing}; control goes on", t)

    def _report(self, now: float) -> None:
        self._check_log(now)
        text = self.status_text()
        if self.on_status is not None:
            self.on_status(text)
        notifier = self.notifier
        if notifier is None:
            return
        if not self._ready and self._pv is not None:
            self._ready = True  # outputs are set up and a good reading has arrived
            notifier.ready()
        notifier.status(text)
        if self._watchdog is not None and self._watchdog.due(now):
            notifier.watchdog()

    def _record_config(self, reason: str, t: float) -> None:
        if self.recorder is not None:
            self.recorder.write(
                CONFIG_TOPIC,
                self.clock.wall_ns(),
                {
                    "t": t,
                    "config": to_dict(self.config),
                    "reason": reason,
                    "model": asdict(self.model),
                    "safety_model": _tun_fields(self._measured_tun(self.config)),
                    "control_law": pid.CONTROL_LAW_VERSION,
                },
            )
