"""Latched alarms across restarts: stored whenever they change (off the loop, by the saver),
raised again at a start, a failed save said and tried again; and the learned model's save."""

from __future__ import annotations

import logging
import time
from functools import partial

from hermsd.runtime.loop_state import LoopState
from hermsd.runtime.saver import Outcome
from hermsd.safety.latches import LatchedAlarm, Latches, StateError

LATCH_SAVE_RETRY_S = 30.0  # a failed save of the latched alarms is tried again this often


def latch_save_failed_text(outcome: Outcome, on_disk: list[str]) -> str:
    """A failed save of the latched alarms, said with what a restart would then find.

    The heater is not held off for it: a latched alarm already holds it off (in memory, until
    the brewer clears it), and a start refuses a state directory it cannot write a latch
    file to (`cli._claim_state_directory`); a failed save of fewer alarms errs safe (a
    restart raises the stored ones again). What is left is a crash in the window before the
    disk works again, and that is said here, loudly.
    """
    failed = f"saving latched alarms failed: {outcome.error}"
    lost = [kind for kind in outcome.tag if kind not in on_disk]
    if not lost:
        return f"{failed} (a restart finds {', '.join(on_disk) or 'none'}, as on disk)"
    return (
        f"{failed}: {', '.join(lost)} will NOT survive a restart (the heater stays off "
        f"while latched; tried again every {LATCH_SAVE_RETRY_S:g} s)"
    )


class LatchKeeping(LoopState):
    """The Daemon's latched alarms on disk."""

    def _restore_latches(self, stored: Latches, t: float) -> None:
        """Raise again the alarms latched before a restart, unless `safety.reset` moved on."""
        if stored.alarms and stored.reset != self.config.safety.reset:
            kinds = ", ".join(a.kind for a in stored.alarms)
            self._event(logging.WARNING, f"alarms reset by safety.reset: {kinds}", t)
            self._save_latches(t)
            return
        for alarm in stored.alarms:
            when = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime(alarm.wall_ns / 1e9))
            self._latched_wall_ns[alarm.kind] = alarm.wall_ns
            self._latched_messages[alarm.kind] = alarm.message  # stored again without the note
            message = f"{alarm.message} (latched {when}, before a restart)"
            self.supervisor.restore_latched(t, alarm.kind, message, alarm.values)
        self._drain_alarms(t)
        self._poll_reset_request(t)

    def _poll_reset_request(self, t: float) -> None:
        if self.latches is None:
            return
        try:
            kinds = self.latches.take_reset_request()
        except (OSError, StateError) as error:
            self._event(logging.ERROR, f"reading the reset request failed: {error}", t)
            return
        if kinds is not None:
            self._event(logging.INFO, f"reset-alarm asked for: {', '.join(kinds) or 'nothing'}", t)
            self._apply_reset(t, kinds)

    def _save_latches(self, t: float) -> None:
        """Store the latched alarms whenever they change; a disk error is said, not fatal."""
        if self.latches is None:
            return
        alarms = self.supervisor.latched_alarms()
        stored = Latches(
            tuple(
                LatchedAlarm(
                    a.kind,
                    self._latched_wall_ns.get(a.kind, 0),
                    self._latched_messages.get(a.kind, a.message),
                    a.values,
                )
                for a in alarms
            ),
            self.config.safety.reset,
        )
        self._tried_latches = [alarm.kind for alarm in alarms]
        self._latches_handed_at = t
        self.saver.save("latches", partial(self.latches.save, stored), self._tried_latches)
        self._take_saves(t)

    @property
    def latches_not_saved(self) -> str | None:
        """Why the latched alarms could not be saved, while they cannot (None: saved)."""
        return self._latch_failing

    def _take_saves(self, t: float) -> None:
        """Say what became of the saves done since the last period (or reading)."""
        for outcome in self.saver.take():
            if outcome.kind == "latches":
                self._latches_saved(outcome, t)
            elif outcome.kind == "coil" and outcome.error is not None:
                self._event(logging.ERROR, f"saving the coil's K failed: {outcome.error}", t)
            elif outcome.kind == "coil":  # the coil's K alone (MashSide._keep_coil)
                coil = outcome.tag
                kept = f"{coil.conductance:.0f} ± {coil.sd:.0f} W/K"
                self._event(logging.INFO, f"kept the coil's K, {kept}: the next start's", t)
            elif outcome.error is not None:
                self._event(logging.ERROR, f"saving the learned model failed: {outcome.error}", t)
            else:
                self._learned_since = outcome.tag
                what = outcome.tag.describe()
                self._event(logging.INFO, f"learned the tun: {what}; used from the next start", t)

    def _saving_latches(self) -> bool:
        return "latches" in self.saver.waiting()

    def _latches_saved(self, outcome: Outcome, t: float) -> None:
        if outcome.error is not None:
            # Tried again, quietly, until it lands: a latch missing from disk is cleared by
            # any restart, and the heater would come back on over the fault.
            self._latch_retry_at = t + LATCH_SAVE_RETRY_S
            if self._latch_failing is None or self._latch_slow:
                self._event(logging.ERROR, latch_save_failed_text(outcome, self._saved_latches), t)
            self._latch_failing, self._latch_slow = outcome.error, False
            return
        self._saved_latches, self._latch_slow = outcome.tag, False
        if self._latch_failing is not None:
            self._latch_failing = None
            self._event(logging.INFO, "latched alarms saved after a failed save", t)

    def _close_saves(self, t: float, wait: float) -> None:
        """At the stop: a latch save that failed once more (the loop retries no longer), the
        saves handed over waited for (at most `wait` s), and what was not saved said."""
        if self._latch_failing is not None and not self._saving_latches():
            self._save_latches(t)
        unsaved = self.saver.close(wait)
        self._take_saves(t)
        what = []
        if "latches" in unsaved or self._latch_failing is not None:
            meant, stored = (
                ", ".join(k) or "none" for k in (self._tried_latches, self._saved_latches)
            )
            what.append(f"the latched alarms ({meant}; on disk: {stored})")
        if "model" in unsaved:
            what.append("the learned model")
        if what:
            self._event(logging.ERROR, f"not saved at the stop: {' and '.join(what)}", t)
