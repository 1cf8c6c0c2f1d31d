"""Replay: read a brew day's MCAP logs back, measure them, re-run the controller, ask what if.

The files of one day (finished `.mcap` or cut `.mcap.part`) are read in the order of their
first record, whatever order they are named in; a file named twice, and files of different
runs of the daemon that overlap in time (two simulated days logged into one folder), are
refused, while runs that follow each other are one day with a restart. Within a file,
config and period records are put in the order of the daemon's monotonic time `t` (a config
before a period of the same `t`: the daemon records a reload before the period it takes
effect in). Times in the summary are seconds since the first period, on one clock across
files: when `t` starts again (a reboot between files) the wall-clock gap of the log times
joins the two.

- `summarise`: what `hermsd replay FILE...` prints. The metrics are those of `hermsd
  simulate` (hermsd.metrics), measured on the logged PV rather than the simulated water.
- `verify`: the logged controller re-run on the logged inputs, every step bit for bit, and
  what the daemon's watches logged of each period derived again from them; only for a log
  of this hermsd's control law (`pid.CONTROL_LAW_VERSION`), which its config records name.
- `what_if`: a first-order-plus-dead-time model of the tun fitted to the logged duty and PV,
  and the day run again through the daemon on that model with other settings.
"""

from __future__ import annotations

import csv
import dataclasses
import itertools
import math
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hermsd.commissioning.identify import IdentifyError, TunModel, fit_span, identify
from hermsd.config import read
from hermsd.config import schema as config_module
from hermsd.control.element2 import MidRangeController, SplitController, TwoElementController
from hermsd.control.factory import make_controller, shared_out, total_watts
from hermsd.control.pid import CONTROL_LAW_VERSION, Controller, PlantModel
from hermsd.control.predictive import (
    cold_water_seen,
    full_power_now,
    known_load,
    readings_seen,
)
from hermsd.control.reach import PREFIX as REACH_PREFIX
from hermsd.control.reach import ReachWatch
from hermsd.log.reader import (
    _PERIOD_FIELDS,
    Drop,
    Log,
    LoggedConfig,
    ReplayError,
    _is_number,
    _lookup,
    alarms,
    sudden_drops,
)
from hermsd.log.topics import PART_SUFFIX
from hermsd.metrics import LOGGED_TEMPERATURE, Metrics, Sample, compute, report
from hermsd.program.quality import mash_from_events, step_quality
from hermsd.program.readiness import SCHEDULE_EVENTS
from hermsd.runtime.build import (
    element2_watts,
    element_watch,
    keep_probe,
    reach_period,
    reach_restarts,
    retunes,
    said_dead,
    take_heat_up,
    watch_changes,
)
from hermsd.runtime.mash_control import MASH_PREFIX
from hermsd.runtime.period import PeriodRecord
from hermsd.safety.current_watch import CurrentWatch, current_watch, words
from hermsd.safety.current_watch import Sample as CurrentSample
from hermsd.safety.element_watch import ElementWatch

if TYPE_CHECKING:
    from hermsd.sim.scenario import Event


WHAT_IF_KEYS = config_module.TUNING_KEYS  # what a new tune may change


# -- reading ------------------------------------------------------------------------------------


# -- the summary --------------------------------------------------------------------------------


def _report(metrics: Metrics) -> dict[str, Any]:
    """hermsd.metrics' report without the SSR's edges, which period records do not hold."""
    reported = report(metrics)
    del reported["ssr_edges_per_hour"]
    return reported


def disturbances(log: Log, drops: list[Drop]) -> list[float]:
    """When the tun was upset from outside: setpoint or mode changed, cold water poured in."""
    times = [drop.at for drop in drops]
    for (a, _), (b, t) in itertools.pairwise(zip(log.periods, log.elapsed, strict=True)):
        if b.setpoint != a.setpoint or b.mode != a.mode:
            times.append(t)
    return sorted(times)


def measure(
    periods: Sequence[PeriodRecord],
    elapsed: Sequence[float],
    upsets: list[float],
    period_s: float,
) -> Metrics:
    """hermsd.metrics on the PV of period records (periods without a PV are left out)."""
    samples = [
        Sample(t, r.setpoint, r.pv, r.output)
        for r, t in zip(periods, elapsed, strict=True)
        if r.pv is not None
    ]
    end = elapsed[-1] + period_s if elapsed else 0.0
    return compute(samples, upsets, end)


def delivered(log: Log) -> tuple[float | None, float | None]:
    """(mean applied duty %, energy kWh) over the periods recovered.

    A period's `applied` is the duty of the span since the period before it, so it is
    weighed by that span; after missing records, by one control period. The element's
    watts come from the config in force; without one the energy is unknown (None). A second
    element's energy (its duty as switched, `switched2`) is added; the mean duty is the
    SSR's.
    """
    watts: float | None = None
    watts2 = 0.0
    watts_known = True
    duty_s = span_s = joules = 0.0
    period_s = log.period_s()
    previous: PeriodRecord | None = None
    for entry in log.entries:
        if isinstance(entry, LoggedConfig):
            watts = _lookup(entry.config, "tun", "element_watts")
            watts2 = _lookup(entry.config, "element2", "watts") or 0.0
            continue
        if previous is not None and entry.k == previous.k + 1 and entry.t >= previous.t:
            span = entry.t - previous.t
        else:
            span = period_s if entry.k > 1 else 0.0  # the first period of a run follows nothing
        previous = entry
        duty_s += entry.applied * span
        span_s += span
        if watts is None:
            watts_known = False
        else:
            joules += watts * entry.applied / 100.0 * span
            if _is_number(entry.switched2):
                joules += watts2 * entry.switched2 / 100.0 * span
    if span_s == 0:
        return None, None
    return duty_s / span_s, joules / 3.6e6 if watts_known else None


def timing(log: Log) -> dict[str, Any]:
    """How well the loop kept time: the worst of the timing records, and what was lost."""
    records = log.timings

    def worst(key: str) -> float | None:
        values = [r[key] for r in records if _is_number(r.get(key))]
        return round(max(values) * 1000.0, 3) if values else None

    return {
        "records": len(records),
        "period_lateness_p99_ms": worst("period_lateness_p99"),
        "period_lateness_max_ms": worst("period_lateness_max"),
        "edge_error_p99_ms": worst("edge_error_p99"),
        "edge_error_max_ms": worst("edge_error_max"),
        "overruns": _total(r.get("overruns") for r in records),
        "dropped": _total(r.get("dropped") for r in records),
    }


def _total(counts: Iterable[object]) -> int:
    """The sum of counters that each run of the daemon starts again from zero."""
    total = previous = 0
    for count in counts:
        if not isinstance(count, int):
            continue
        total += count - previous if count >= previous else count
        previous = count
    return total


def summarise(log: Log) -> dict[str, Any]:
    """What `hermsd replay` prints: what was recovered, how the day went, what it cost."""
    period_s = log.period_s()
    drops = sudden_drops(log.elapsed, [p.pv for p in log.periods])
    metrics = measure(log.periods, log.elapsed, disturbances(log, drops), period_s)
    mean_applied, energy = delivered(log)
    algorithms = list(dict.fromkeys(p.algorithm for p in log.periods))
    return {
        "files": [dataclasses.asdict(f) for f in log.files],
        "runs": log.runs,  # more than one: the daemon restarted during the day
        "start_utc": time.strftime(
            "%Y-%m-%dT%H:%M:%SZ", time.gmtime(log.log_time_ns[0] // 1_000_000_000)
        ),
        "periods": len(log.periods),
        "duration_s": round(log.elapsed[-1], 3),
        "algorithm": ", ".join(algorithms),
        "cold_water_at_s": [round(d.at, 1) for d in drops],
        "temperature": LOGGED_TEMPERATURE,
        **_report(metrics),
        "mean_applied_pct": None if mean_applied is None else round(mean_applied, 2),
        "energy_kwh": None if energy is None else round(energy, 3),
        "alarms": alarms(log),
        "timing": timing(log),
        "tun_model": next((c.model for c in reversed(log.configs) if c.model), None),
        # None: the safety limits held for any tun the config may describe (nothing measured)
        "safety_tun_model": log.configs[-1].safety_model if log.configs else None,
        "learning": learning(log),
        # When full power could not reach the setpoint, or the HLT at its most the mash's
        # rest, and when that cleared (hermsd.control.reach).
        "reach": [
            {"at_s": round(e.at, 3), "message": e.message}
            for e in log.events
            if e.message.startswith((REACH_PREFIX, MASH_PREFIX))
        ],
        "steps": step_quality(
            zip(log.elapsed, log.periods, strict=True),
            mash_from_events((e.event, e.step) for e in log.program),
        ),
        # What a ready_by schedule decided (the climb, the release, a late warning), and why.
        "schedule": [
            {"at_s": round(e.at, 3), "event": e.event, "message": e.message}
            for e in log.program
            if e.event in SCHEDULE_EVENTS
        ],
    }


LEARNING_EVENTS = ("heat-up measure", "learned ")
"""How the daemon's events about measuring and learning the tun begin."""


def learning(log: Log) -> list[dict[str, Any]]:
    """What the controller measured and the daemon learned (or refused), in order."""
    return [
        {"at_s": round(e.at, 3), "message": e.message}
        for e in log.events
        if e.message.startswith(LEARNING_EVENTS)
    ]


# -- verify -------------------------------------------------------------------------------------


def logged_model(entry: LoggedConfig) -> PlantModel | None:
    """The tun's model a config record says was in force (None in older logs: the keys';
    without `measured`, before control law 6: not measured)."""
    if entry.model is None:
        return None
    measured = entry.model.get("measured", False)
    if not isinstance(measured, bool):
        raise ValueError(f"the model logged with it is not one: measured is {measured!r}")
    try:
        return PlantModel(
            **{k: float(entry.model[k]) for k in ("gain", "tau", "dead_time", "ambient")},
            measured=measured,
        )
    except (KeyError, TypeError, ValueError) as error:
        raise ValueError(f"the model logged with it is not one: {error}") from None


@dataclass(frozen=True, slots=True)
class Mismatch:
    """The first value the re-run controller did not reproduce."""

    k: int
    t: float
    name: str
    logged: float | None
    recomputed: float | None


@dataclass(frozen=True, slots=True)
class OtherLaw:
    """A log whose decisions a control law other than this hermsd's made: not re-run, for
    this hermsd's laws would decide otherwise (`pid.CONTROL_LAW_VERSION`)."""

    logged: int | None  # the first other law its config records name (None: none, before 1)
    runs: int  # the law this hermsd runs
    in_part: bool  # some of its config records name this hermsd's law (an upgrade that day)


@dataclass(frozen=True, slots=True)
class Verification:
    """What `verify` found: how many steps it reproduced, and the first it did not."""

    verified: int  # controller steps reproduced bit for bit
    unknown_state: int  # steps after missing records and before the next reset: not re-run
    mismatch: Mismatch | None
    other_law: OtherLaw | None = None  # the log is another law's: nothing re-run


def other_law(entries: Iterable[LoggedConfig | PeriodRecord]) -> OtherLaw | None:
    """The control law of a log's config records, when any is not this hermsd's."""
    laws = [e.control_law for e in entries if isinstance(e, LoggedConfig)]
    others = [law for law in laws if law != CONTROL_LAW_VERSION]
    if not others:
        return None
    return OtherLaw(others[0], CONTROL_LAW_VERSION, len(others) < len(laws))


def verify(entries: Sequence[LoggedConfig | PeriodRecord]) -> Verification:
    """Re-run the logged controller on the logged inputs, by the daemon's rules: only in a
    log whose config records all name this hermsd's control law (`other_law`; a log of
    another law is not re-run, its decisions another law's).

    A config record makes a new controller (the repeat of the one in force that opens every
    rotated file, as `load` marks it, does not, nor does a reload that leaves the tuning, the
    tun and the model as they were: the daemon keeps its controller then). The controller
    steps in auto mode when heating is allowed and there is a PV, after `reset(pv,
    reset_from)` if `reset_from` is set; its output and its p, i, d terms must equal the
    logged ones exactly (midrange: u2 too, the second element's logged applied2 handed in
    first, as the daemon does; two elements under any other controller: u2 too, its logged
    applied2, on2 and free2 handed in first). The daemon resets the controller on its first
    step and after every hold, reload or return to auto, so where records are missing the
    check resumes at the next reset.

    A period's `full_from` (the reading after which the controller asked for full power at
    once) must be what `predictive.full_power_now` gives on its readings, with the controller
    as the step of the record before it left it; None where no step came before it. Where
    it is set, the step that closes the period carries full power on as the daemon's did
    (`predictive.cold_water_seen`).

    A period's `ceiling` must be what a reach watch names that was fed every period as the
    daemon fed its own (`daemon.reach_period`: the record, the model and the config in
    force, and the dead time of the controller's heat-up measurement, re-run here), made
    afresh at each start and measuring afresh where a reload changed full power
    (`daemon.reach_restarts`); after missing records, not until the next start (the blocks it
    measured over them are not known).
    """
    other = other_law(entries)
    if other is not None:
        return Verification(0, 0, None, other)
    controller = None
    in_force_model: dict[str, Any] | None = None
    control: config_module.ControlConfig | None = None
    known = False  # whether the controller's state is that of the daemon's
    previous_k: int | None = None
    stepped: tuple[Controller, PeriodRecord] | None = None  # the last step, if fresh and known
    watch: ElementWatch | None = None  # the element watch as the daemon's, once known
    watched: config_module.Config | None = None  # the config it was made for
    reach: ReachWatch | None = None  # the reach watch as the daemon's, once known
    model: PlantModel | None = None  # the tun's model in force, as logged
    fed: PeriodRecord | None = None  # the last period, not yet fed to `reach`
    current: CurrentWatch | None = None  # the current input's watch as the daemon's, once known
    dead_said: list[int] = []  # the elements the last period said give no heat
    verified = unknown = 0

    def ceiling_mismatch() -> Mismatch | None:
        """The last period fed to the reach watch after its step, as the daemon fed it: by
        the next entry the controller's heat-up fit is the one the daemon's had then."""
        if fed is None or reach is None or controller is None or watched is None or model is None:
            return None
        return _ceiling_mismatch(reach, fed, model, watched, controller)

    for entry in entries:
        mismatch = ceiling_mismatch()
        if mismatch is not None:
            return Verification(verified, unknown, mismatch)
        fed = None
        if isinstance(entry, LoggedConfig):
            if entry.repeat:
                continue
            try:
                whole = read.from_dict(entry.config)
                if entry.reason == "start" or (watched and watch_changes(watched, whole)):
                    kept, watch = watch, element_watch(whole) if element2_watts(whole) else None
                    same = watched is not None and watched.tun == whole.tun
                    if entry.reason != "start" and same and kept and watch:
                        watch.keep_probed(kept)
                    dead_said = sorted(watch.suspect) if watch is not None else []
                if entry.reason == "start":
                    reach = ReachWatch()
                    current = current_watch(whole)
                elif reach is not None and watched is not None and reach_restarts(watched, whole):
                    reach.restart()
                same_tun = watched is not None and watched.tun == whole.tun
                before, watched = watched, whole
                reloaded = whole.control
                same_model = in_force_model == entry.model
                if (
                    entry.reason == "reload"
                    and control
                    and not retunes(control, reloaded)
                    and same_model
                    and same_tun  # the daemon makes a new controller for a new tun
                ):
                    control = reloaded  # a new setpoint or mode: the same controller goes on
                    continue
                control = reloaded
                in_force_model = entry.model
                model = logged_model(entry)
                made = make_controller(control, model)
                unknown_probe = controller is None and same_tun  # what it would keep is not known
                previous, controller = controller, shared_out(whole, made)
                if entry.reason == "reload" and before is not None:
                    keep_probe(before, whole, previous, controller)
                    if unknown_probe and isinstance(controller, SplitController):
                        controller = None if controller.probe is not None else controller
            except (config_module.ConfigError, ValueError) as error:
                detail = str(error).replace("\n", "; ")
                raise ReplayError(f"the config logged at t {entry.t!r} s: {detail}") from None
            known = False
            if entry.reason == "start":
                previous_k, stepped = None, None
            continue
        record = entry
        if record.k != (previous_k or 0) + 1:
            reach = None  # what the missing periods told it is not known
            current = None
        if current is not None and record.current is not None:
            try:
                samples = [CurrentSample.from_logged(item) for item in record.current]
            except (TypeError, ValueError):
                raise ReplayError(f"period k={record.k}: a current sample is malformed") from None
            said = [line for sample in samples for line in words(*current.sample(sample))]
            if said != record.current_said:
                name = f"current_said {record.current_said} (derived {said})"
                return Verification(
                    verified, unknown, Mismatch(record.k, record.t, name, None, None)
                )
        fed = record
        if previous_k is not None and record.k != previous_k + 1:
            known = False
            stepped = None
            watch = None  # what the missing periods told it is not known
            probe = controller.probe if isinstance(controller, SplitController) else None
            if probe is not None and not probe.done:
                # The daemon's heat-up check may have run in them: its state is not known
                # until a new controller, so nothing after is held against this one.
                controller = None
        # The probe's finding of the step before, taken as the daemon takes it.
        probed = controller.probe_result() if isinstance(controller, SplitController) else None
        if controller is None:
            watch = None  # the heat-up fit the daemon's watch held is not known
        elif watch is not None and record.switched2 is not None:
            take_heat_up(watch, controller)
            if probed is not None and probed.element is not None:
                watch.blame(record.t, probed.element, probed.message)
            watch.period(
                record.t,
                record.pv,
                record.hlt_target,
                record.applied,
                record.switched2,
                record.state == "ok",
                record.pump,
            )
            if record.no_heat is not None and sorted(watch.suspect) != record.no_heat:
                name = f"no_heat {record.no_heat} (derived {sorted(watch.suspect)})"
                return Verification(
                    verified, unknown, Mismatch(record.k, record.t, name, None, None)
                )
        if stepped is not None or known:
            full_from = _full_from(stepped, record.readings)
            if record.full_from != full_from:
                mismatch = Mismatch(record.k, record.t, "full_from", record.full_from, full_from)
                return Verification(verified, unknown, mismatch)
        stepped = None
        previous_k = record.k
        # The elements the step was shared out without: as the period before said them.
        no_heat, dead_said = dead_said, record.no_heat or []
        if not (record.mode == "auto" and record.heater_allowed and record.pv is not None):
            continue
        if record.state == "scheduled":  # a program waits for its time: the heater held off
            continue
        if controller is None:
            unknown += 1
            continue
        if isinstance(controller, MidRangeController):
            if not (_is_number(record.applied2) and _is_number(record.u2)):
                raise ReplayError(f"period k={record.k}: a midrange period without u2, applied2")
            controller.applied2 = record.applied2  # what the daemon handed in, as logged
        if isinstance(controller, SplitController):
            if not (
                _is_number(record.applied2)
                and isinstance(record.on2, bool)
                and isinstance(record.free2, bool)
            ):
                raise ReplayError(f"period k={record.k}: a two-element period without its state")
            controller.applied2 = record.applied2
            controller.on2, controller.free2 = record.on2, record.free2
            said_dead(controller, no_heat)
        try:
            if record.coil_load is not None and watched is not None:  # the HERMS's outer loop
                starts_in = record.pump_in or 0.0
                ends_in = math.inf if record.pump_stop_in is None else record.pump_stop_in
                basis = record.coil_k or 0.0
                known_load(
                    controller,
                    record.coil_load,
                    total_watts(watched),
                    starts_in,
                    ends_in,
                    basis,
                    met=record.coil_load_met is not False,
                )
            if record.reset_from is not None:
                controller.reset(record.pv, record.reset_from)
                known = True
            if not known:
                unknown += 1
                continue
            if record.full_from is not None:
                cold_water_seen(controller)
            readings_seen(controller, record.readings)
            output = controller.step(record.hlt_target, record.pv, record.applied)
        except ValueError as error:
            raise ReplayError(f"period k={record.k}: the controller refused it: {error}") from None
        p, i, d = controller.terms
        compared = [
            ("output", record.output, output),
            ("p", record.p, p),
            ("i", record.i, i),
            ("d", record.d, d),
        ]
        if isinstance(controller, TwoElementController) and record.u2 is not None:
            compared.append(("u2", record.u2, controller.u2))
        for name, logged, recomputed in compared:
            if logged != recomputed:
                return Verification(
                    verified, unknown, Mismatch(record.k, record.t, name, logged, recomputed)
                )
        stepped = (controller, record)
        verified += 1
    return Verification(verified, unknown, ceiling_mismatch())


def _ceiling_mismatch(
    reach: ReachWatch,
    record: PeriodRecord,
    model: PlantModel,
    config: config_module.Config,
    controller: Controller,
) -> Mismatch | None:
    """Feed `reach` the period of `record` as the daemon did; a Mismatch when the ceiling it
    names then is not the logged one."""
    reach_period(reach, record, model, config, controller)
    if record.ceiling == reach.ceiling:
        return None
    return Mismatch(record.k, record.t, "ceiling", record.ceiling, reach.ceiling)


def _full_from(
    stepped: tuple[Controller, PeriodRecord] | None, readings: list[float]
) -> int | None:
    """After how many of a period's `readings` the daemon asks for full power (see
    `Daemon._act_on_drop`), given the controller and the record of the step before them."""
    if stepped is None:
        return None
    controller, before = stepped
    if before.pv is None:
        return None
    for n in range(1, len(readings) + 1):
        if full_power_now(controller, before.hlt_target, before.pv, readings[:n]):
            return n
    return None


# -- what if ------------------------------------------------------------------------------------


WHAT_IF_LOGGED = "logged"  # --what-if logged: the day again with the settings it had


def parse_what_if(text: str) -> dict[str, Any]:
    """`kc=100,ti=900,algorithm=type_a` as control settings (checked later, like the file).

    A log file's name in their place (`--what-if day.mcap`) is said as such.
    """
    if text.strip() == WHAT_IF_LOGGED:
        return {}
    if "=" not in text and (text.endswith((".mcap", PART_SUFFIX)) or Path(text).exists()):
        raise ReplayError(
            f"--what-if takes settings, not the log file {text!r}: write --what-if "
            f"kc=80,ti=600 (or --what-if {WHAT_IF_LOGGED} for the logged ones) after the files"
        )
    settings: dict[str, Any] = {}
    for item in filter(None, (part.strip() for part in text.split(","))):
        key, sep, value = (s.strip() for s in item.partition("="))
        if not sep or key not in WHAT_IF_KEYS:
            raise ReplayError(
                f"--what-if: {item!r} is not key=value with a key of {', '.join(WHAT_IF_KEYS)} "
                "(name the files before --what-if)"
            )
        settings[key] = _scalar(value)
    return settings


def _scalar(text: str) -> Any:
    if text.lower() in ("null", "none", ""):
        return None
    try:
        return float(text)
    except ValueError:
        return text


@dataclass(frozen=True, slots=True)
class WhatIf:
    """The fitted tun, and the day as logged beside the day with the new settings."""

    model: TunModel
    settings: dict[str, dict[str, Any]]  # "logged" and "what_if": the control settings
    logged: dict[str, Any]  # metrics of the log
    what_if: dict[str, Any]  # metrics of the run with the new settings


def what_if(log: Log, overrides: dict[str, Any]) -> WhatIf:
    """The day again on the fitted tun, with `overrides` of the logged control settings.

    The fit uses the log up to the first sudden drop (cold water: a disturbance the model
    has no input for) or the first gap. The run starts from the fitted initial temperature
    with the config logged first, and repeats the log's setpoint and mode changes; each
    drop is poured in again as water at the fitted ambient temperature, in the amount that
    gives the drop logged. Faults are not repeated.
    """
    from hermsd.sim.scenario import Scenario, ScenarioError, effective_config
    from hermsd.sim.scenario import run as run_scenario  # the simulator only when asked for

    configs = log.configs
    if not configs:
        raise ReplayError("--what-if: no config record recovered, so no settings to start from")
    try:
        base = read.from_dict(configs[0].config)
    except config_module.ConfigError as error:
        detail = str(error).replace("\n", "; ")
        raise ReplayError(f"the config logged at t {configs[0].t!r} s: {detail}") from None
    scenario = Scenario(
        name="what-if", setpoint=log.periods[0].setpoint, config={"control": overrides}
    )
    try:  # the settings are checked before the fit and the run
        settings = effective_config(base, scenario).control
    except ScenarioError as error:
        raise ReplayError(f"--what-if: {error}".replace("\n", "; ")) from None
    period_s = base.control.period
    pvs = [p.pv for p in log.periods]
    drops = sudden_drops(log.elapsed, pvs)
    upsets = disturbances(log, drops)
    n = fit_span(log, drops, period_s)
    try:
        model = identify(pvs[:n], [p.applied for p in log.periods[:n]], period_s)
    except IdentifyError as error:
        raise ReplayError(str(error)) from None
    plant = {
        "model": "foptd",
        "gain_c_per_pct": model.gain,
        "tau_s": model.tau,
        "dead_time_s": model.dead_time,
        "ambient_c": model.ambient,
        "start_c": model.start,
        "litres": base.tun.litres,
        "element_watts": base.tun.element_watts,
    }
    scenario = dataclasses.replace(
        scenario,
        duration=log.elapsed[-1] + period_s,
        plant=plant,
        events=tuple(_replayed_events(log, base, model, drops)),
    )
    try:
        runs = run_scenario(scenario, base, keep_records=True).records
    except ScenarioError as error:
        raise ReplayError(f"--what-if: {error}".replace("\n", "; ")) from None
    return WhatIf(
        model=model,
        settings={
            "logged": {key: getattr(base.control, key) for key in WHAT_IF_KEYS},
            "what_if": {key: getattr(settings, key) for key in WHAT_IF_KEYS},
        },
        logged=_report(measure(log.periods, log.elapsed, upsets, period_s)),
        what_if=_report(measure(runs, [r.t for r in runs], upsets, period_s)),
    )


def _replayed_events(
    log: Log, base: config_module.Config, model: TunModel, drops: list[Drop]
) -> list[Event]:
    """The scenario events that repeat the log's operator actions and its cold water."""
    from hermsd.sim.scenario import Event

    period_s = base.control.period
    events: list[Event] = []
    setpoint = log.periods[0].setpoint
    mode, manual = base.control.mode, base.control.manual_output
    for record, t in zip(log.periods, log.elapsed, strict=True):
        at = max(0.0, t - period_s / 2)  # between periods: applied at this one
        if record.setpoint != setpoint:
            setpoint = record.setpoint
            events.append(Event(at, "setpoint", setpoint))
        manual_now = record.state == "manual"  # in manual mode and heating: output is the user's
        if manual_now and (mode != "manual" or record.output != manual):
            mode, manual = "manual", record.output
            events.append(Event(at, "output", manual))
        elif record.mode == "auto" and mode != "auto":
            mode = "auto"
            events.append(Event(at, "mode", "auto"))
    litres = base.tun.litres
    for drop in drops:
        if drop.after - model.ambient <= 0.1 or not 0.0 <= model.ambient <= 100.0:
            continue  # the drop cannot be water at the ambient temperature
        added = litres * (drop.before - drop.after) / (drop.after - model.ambient)
        events.append(Event(drop.at, "add_water", {"litres": added, "temp": model.ambient}))
        litres += added
    events.sort(key=lambda e: e.at)
    return events


# -- CSV and plot -------------------------------------------------------------------------------


def write_csv(log: Log, path: Path) -> None:
    """One row per period with every field of its record; lists joined by spaces."""
    with path.open("w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f)
        writer.writerow(_PERIOD_FIELDS)
        for record in log.periods:
            writer.writerow(_cell(getattr(record, name)) for name in _PERIOD_FIELDS)


def _cell(value: object) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, list):
        return " ".join(map(str, value))
    return repr(value) if isinstance(value, float) else str(value)


def plot(log: Log, path: Path) -> None:
    """The day drawn for a brewer to read at a glance (hermsd.log.dayplot; needs matplotlib)."""
    from hermsd.log import dayplot

    dayplot.save(log, path)
