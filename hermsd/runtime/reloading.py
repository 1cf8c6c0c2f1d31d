"""The loop's reload: the config file polled at each period boundary (or at SIGHUP), an edit
taken without a bump (setpoint, mode, tuning) or rejected, keys that need a restart kept."""

from __future__ import annotations

import logging

from hermsd.config import read, rules
from hermsd.config.schema import Config, ConfigError
from hermsd.control import predictive
from hermsd.runtime.build import (
    control_law,
    element_watch,
    keep_probe,
    learner,
    model_in_force,
    planner,
    reach_restarts,
    retunes,
    safety_limits,
    watch_changes,
)
from hermsd.runtime.loop_state import LoopState


class Reloading(LoopState):
    """The Daemon's configuration changes."""

    def request_reload(self) -> None:
        """Read the config file again at the next period boundary (SIGHUP; signal-safe)."""
        self._reload_requested = True

    def reload(self, config: Config) -> None:
        """Apply `config` at the next period boundary, as a reload of the file would."""
        self._pending.append(lambda t: self._apply_config(config, t))

    def _poll_config(self, t: float) -> None:
        """Apply the config file if it changed (or SIGHUP asked); reject it if it is invalid."""
        if self.config_file is None:
            if self._reload_requested:
                self._reload_requested = False
                self._event(logging.WARNING, "reload asked, but there is no config file", t)
            return
        result = self.config_file.poll(force=self._reload_requested)
        if result is None:
            return  # unchanged, or still being written: the next period reads it
        self._reload_requested = False
        if self.notifier is not None:
            self.notifier.reloading()
        if isinstance(result, ConfigError):
            self._reject_config(str(result), t)
        else:
            self._apply_config(result, t)
        if self.notifier is not None:
            self.notifier.ready()

    def _reject_config(self, why: str, t: float) -> None:
        self._config_problem = why
        self._event(logging.ERROR, f"config rejected, still running on the last good one: {why}", t)

    def _apply_config(self, edited: Config, t: float) -> None:
        """Take a valid edit: setpoint, mode and tuning without a bump; limits at once.

        Keys that open devices or fix the schedule keep their running values (said in the
        log); an edit that breaks a rule only together with those kept values is rejected.
        """
        old = self.config
        refused = read.restart_keys_changed(old, edited)
        new = read.keep_restart_keys(old, edited)
        broken = rules.broken_rules(new)
        if broken:
            kept = f" with the running {', '.join(refused)}" if refused else ""
            self._reject_config(f"{'; '.join(broken)}{kept}", t)
            return
        self._config_problem = None
        changed = read.differences(old, new)
        if refused:
            running = ", ".join(f"{key} {read.value_at(old, key)!r}" for key in refused)
            self._event(
                logging.WARNING,
                f"config: {', '.join(refused)} need a restart (systemctl restart hermsd); "
                f"still running with {running}",
                t,
            )
        if not changed:
            self._event(logging.INFO, "config reloaded: nothing to change", t)
            return
        self.config = new
        self._learner.interrupt()
        self._reloaded_at = t
        self._event(logging.INFO, f"config reloaded: {', '.join(changed)} changed", t)
        self._take_changes(old, new, set(changed), t)
        self._record_config("reload", t)  # with the model the changes put in force

    def _take_changes(self, old: Config, new: Config, changed: set[str], t: float) -> None:
        control = new.control
        self.alerts.config = new.alerts
        self.alerts.start()  # if the reload gave the first command
        if "control.setpoint" in changed:
            self._apply_setpoint(control.setpoint, t)
        if retunes(old.control, new.control) or old.tun != new.tun:
            self.model_choice = model_in_force(self._stored_model, new)
            self.model = self.model_choice.model
            before = self.controller
            self.controller = control_law(new, self.model)
            keep_probe(old, new, before, self.controller)
            self._heat_up_seen = predictive.heat_up_fit(self.controller)
            self._learner = learner(new, self.model)
            if not self._held:  # bumpless: the new controller starts from the output in force
                self._held = True
                self._resume_output = self.output
        remade = old.herms != new.herms or old.tun != new.tun or old.output != new.output
        if remade or retunes(old.control, new.control):
            self._remake_mash_control(new)  # with the model and the SSR's pulses now in force
        if self.element_watch is not None and watch_changes(old, new):
            watched, self.element_watch = self.element_watch, element_watch(new)
            if old.tun == new.tun:  # its references were of the old tun, not its probe
                self.element_watch.keep_probed(watched)
        if reach_restarts(old, new):
            self._say_reach(self.reach.restart(), t)  # another full power
        if control.mode == "manual" and changed & {"control.mode", "control.manual_output"}:
            self._apply_manual(control.manual_output, t)
        elif control.mode == "auto" and changed & {"control.mode", "control.manual_output"}:
            self._apply_auto(t)
        elif "control.max_output" in changed and self.mode == "manual":
            self._apply_manual(self.manual_output, t)  # the new power limit holds at once
        if self.program.active:  # the setpoint it returns to, and the one it holds now
            self._keep_after_below_cut_out(t)
            self._stop_program_over_cut_out(self.setpoint, t)
        elif self.setpoint >= new.safety.max_temp:  # set at runtime, and above the new cut-out
            self._event(
                logging.WARNING,
                f"setpoint {self.setpoint:g} °C is not below the new safety.max_temp: "
                "back to the file's",
                t,
            )
            self._apply_setpoint(control.setpoint, t)
        if any(key.startswith(("safety.", "tun.")) for key in changed) or retunes(
            old.control, new.control
        ):
            if old.tun != new.tun:
                self._limits_fit = None  # a heat-up of another tun
                self._limits_dead = frozenset()  # … whose watch has said nothing yet
                self.supervisor.forget_hold()  # and its hold
            self.supervisor.limits = safety_limits(
                new, self._measured_tun(new), self._limits_fit, self._limits_dead
            )
        if changed & {"safety.max_temp", "safety.hysteresis"}:
            self._reprogram_sensor(t)
        if "safety.reset" in changed:
            self._apply_reset(t)
            self._save_latches(t)  # later latches are stored under the new counter
        if any(key.startswith("output.") for key in changed):
            self.planner = planner(new, self.model)
