"""Building a daemon's parts from its config and the state directory: the safety limits in
force, the tun's model (stored, measured or prior), the element watch and probe, the reach
watch's periods, the second element's power."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from hermsd.config import schema as config_module
from hermsd.config.schema import Config, ControlConfig
from hermsd.control import factory, pid, predictive
from hermsd.control.element2 import SplitController
from hermsd.control.factory import full_power, full_power_share, total_watts
from hermsd.control.learning import LearnedModel, Learner, ModelStore, implausible_here
from hermsd.control.reach import ReachWatch, Said
from hermsd.control.watches import HeatUpFit
from hermsd.hardware.current_sense import two_reads_part
from hermsd.hardware.outputs import window_length
from hermsd.hardware.ssr import TimeProportionalPlanner
from hermsd.program.readiness import known_dead_time
from hermsd.runtime.period import PeriodRecord
from hermsd.safety.element_watch import ElementReport, ElementWatch, named_dead
from hermsd.safety.limits import MeasuredTun, SafetyLimits


def safety_limits(
    config: Config,
    model: MeasuredTun | None = None,
    heat_up: HeatUpFit | None = None,
    dead: frozenset[int] = frozenset(),
) -> SafetyLimits:
    """The supervisor's limits: from `model` (the tun as measured) where given, else safe for
    any tun the config could be describing (see `SafetyLimits.derive`); tightened by the
    day's `heat_up` where it was measured and no model was (`SafetyLimits.with_heat_up`).
    Elements said `dead` (of two, no longer asked) leave full power the other's share: a
    tun that one cannot hold then falls at its full power, and latches as it did at both's."""
    s = config.safety
    watts = {1: config.tun.element_watts, 2: element2_watts(config)}
    live = 100.0 * (1.0 - sum(watts[e] for e in dead) / total_watts(config))
    limits = SafetyLimits.derive(
        litres=config.tun.litres,
        element_watts=total_watts(config),
        period=config.control.period,
        read_interval=config.sensor.read_interval,
        model=model,
        max_temp=s.max_temp,
        hysteresis=s.hysteresis,
        plausible_min=s.plausible_min,
        plausible_max=s.plausible_max,
        max_step=s.max_step,
        fault_reads=s.fault_reads,
        resume_reads=s.resume_reads,
        stale_after=s.stale_after,
        dead_time=s.dead_time,
        heater_watch=s.heater_watch,
        heater_min_rise=s.heater_min_rise,
        ssr_watch=s.ssr_watch,
        ssr_max_rise=s.ssr_max_rise,
        dry_fire_factor=s.dry_fire_factor,
        stuck_time=s.stuck_time,
        stuck_output_change=s.stuck_output_change,
        stall_periods=s.stall_periods,
        max_output=min(full_power_share(config), live),
        two_elements=element2_watts(config) > 0.0,
    )
    if heat_up is None or heat_up.refused is not None:
        return limits
    return limits.with_heat_up(heat_up.rate, heat_up.dead_time, total_watts(config))


def element_watch(config: Config) -> ElementWatch:
    """The watch of both elements' heat, judged over the controller's dead time (not while a
    HERMS coil's pump may run)."""
    return ElementWatch(
        config.tun.element_watts,
        element2_watts(config),
        config.control.dead_time,
        coil=config.mash_sensor.fitted,
    )


def take_heat_up(watch: ElementWatch, controller: pid.Controller) -> None:
    """Hand the watch the controller's heat-up fit, if it has one it took."""
    fit = predictive.heat_up_fit(controller)
    if fit is not None and fit.refused is None:
        watch.heat_up(fit.rate, fit.dead_time)


def said_dead(controller: pid.Controller, no_heat: Iterable[int]) -> None:
    """Share the load out without the element the watch says gives no heat (1 or 2), so that
    the other holds the tun (docs/two-elements.md); from the period before the step."""
    if isinstance(controller, SplitController):
        controller.split.dead = named_dead(no_heat)
        predictive.on_two_elements(controller.inner, one_left=bool(controller.split.dead))


def left_out(report: ElementReport, controller: pid.Controller) -> str:
    """What a dead element's warning adds where the share-out leaves it out (`said_dead`)."""
    if not (report.raised and named_dead([report.element])):
        return ""
    if not isinstance(controller, SplitController):
        return ""
    other = 3 - report.element
    return (
        f"; element {report.element} is no longer asked, element {other} holds the tun alone "
        "until a restart"
    )


def watch_changes(old: Config, new: Config) -> bool:
    """Whether a reload starts the element watch afresh (replay does as the daemon)."""
    return old.tun != new.tun or old.control.dead_time != new.control.dead_time


def keep_probe(
    old: Config,
    new: Config,
    before: pid.Controller | None,
    after: pid.Controller | None,
) -> None:
    """A reload that keeps the tun (its litres and element; the second element's keys need a
    restart) keeps what the heat-up's probe found: the new controller goes on with the old
    one's probe once that is done (not tried again; a finding not yet taken is taken from
    it). A new tun is probed afresh. Replay does as the daemon."""
    if old.tun != new.tun or not isinstance(after, SplitController):
        return
    if isinstance(before, SplitController) and before.probe is not None and before.probe.done:
        after.probe = before.probe


def reach_period(
    reach: ReachWatch,
    record: PeriodRecord,
    model: pid.PlantModel,
    config: Config,
    controller: pid.Controller,
) -> Said | None:
    """Feed `reach` the period of `record` (before its `ceiling`), with the model, the config
    and the controller in force after the period's step: the daemon does, and replay's check
    does again from the log. Full power (`config.full_power`) and the dead time are a
    ready_by heat-up's."""
    full = (
        record.state == "ok"
        and record.mode == "auto"
        and full_power(config).reached(record.applied, record.switched2)
    )
    dead_time = known_dead_time(model, predictive.heat_up_fit(controller))
    max_output = config.control.max_output
    return reach.period(record.t, record.hlt_target, record.pv, full, dead_time, max_output)


def reach_restarts(old: Config, new: Config) -> bool:
    """Whether a reload gives another full power, measured afresh (replay does as the
    daemon)."""
    return full_power(old) != full_power(new)


def element2_watts(config: Config) -> float:
    """The second element's power (0 when none is fitted): the supervisor judges the total."""
    return config.element2.watts if config.element2.backend != "none" else 0.0


@dataclass(frozen=True, slots=True)
class ModelChoice:
    """The tun's model in force and where it came from: "learned" (the state directory),
    "measured" (the control.model_* keys `hermsd tune --write` wrote) or "prior" (a guess
    from tun.litres and tun.element_watts)."""

    model: pid.PlantModel
    source: str
    basis: LearnedModel | None = None  # the measurement, at the fill it was made with

    @property
    def measured(self) -> pid.PlantModel | None:
        """The model, if it was measured: what the supervisor's limits may be tightened by."""
        return None if self.basis is None else self.model

    def describe(self) -> str:
        if self.basis is None:
            return "the prior from tun.litres and tun.element_watts (nothing measured)"
        what = "learned" if self.source == "learned" else "measured by hermsd tune (control keys)"
        return f"{what}: {self.basis.describe()}"


def model_in_force(stored: LearnedModel | None, config: Config) -> ModelChoice:
    """The model the controller and the supervisor use. `control.learn` on: what was learned
    (kept up to date by the daemon itself), else what `hermsd tune` measured; pinned: the
    measured one, else what was learned; off: the measured one only. A measurement is
    rescaled to the configured litres; one the fill takes out of the controller's range is
    passed over. Neither: the config's prior. With a second element fitted, only what was
    learned on both (their total drives the one controller); `hermsd tune` measures one,
    and mid-ranging's two controllers learn nothing: the prior."""
    learn = config.control.learn
    two = element2_watts(config) > 0.0
    if two and config.control.algorithm == "midrange":
        return ModelChoice(factory.prior_model(config), "prior")
    here = stored is not None and learn != "off" and not_this_tun(stored, config) is None
    candidates = [
        ("learned", stored if here else None),
        ("measured", None if two else factory.measured_model(config)),
    ]
    if learn != "on":
        candidates.reverse()
    low, high = pid.MODEL_GAIN_RANGE  # a fill far from the measured one can leave it
    for source, basis in candidates:
        if basis is not None:
            model = basis.plant_model(config.tun.litres)
            if low <= model.gain <= high:
                return ModelChoice(model, source, basis)
    return ModelChoice(factory.prior_model(config), "prior")


def stored_model(models: ModelStore, config: Config) -> tuple[LearnedModel | None, str | None]:
    """What `models` holds, if it can be the configured tun's; else (None, why: said in the
    log as a learned model ignored), as `ModelStore.load` says a damaged file."""
    model, problem = models.load()
    why = not_this_tun(model, config) if model is not None else None
    if why is not None:
        return None, f"{models.path}: {why}"
    return model, problem


def not_this_tun(model: LearnedModel, config: Config) -> str | None:
    """Why a learned model cannot be the configured tun's (`learning.implausible_here`): its
    rate is the full power of another number of elements than the config fits."""
    fitted = elements(config)
    if model.elements != fitted:
        learned, now = (COUNT_WORDS.get(n, str(n)) for n in (model.elements, fitted))
        return f"learned on {learned} element(s), where the config fits {now}"
    litres = config.tun.litres
    full_rate = factory.total_watts(config) / (factory.WATER_J_PER_LITRE_K * litres)
    return implausible_here(model, litres=litres, full_rate=full_rate)


def elements(config: Config) -> int:
    """How many elements the config fits (the one controller drives their total)."""
    return 2 if element2_watts(config) else 1


COUNT_WORDS = {1: "one", 2: "two"}


def measured_tun(
    config: Config, stored: LearnedModel | None, given: MeasuredTun | None
) -> MeasuredTun | None:
    """The tun as measured for the supervisor's limits: `given`, else the model in force
    if it was measured (learned, or by `hermsd tune`); None before anything is measured (the
    config's prior is a guess, and the limits then hold for any tun it may describe).

    The learned losses are referred to `control.model_ambient` a, not the real room:
    they reproduce the hold's measured power at the setpoint s, so the supervisor's bound
    there (×1.5, a room 10 °C colder than a) is 1.5·(s − a + 10)/(s − a) times the true
    losses whatever the room is (×1.83 at 66 °C and a = 20 °C).
    """
    if given is not None:
        return given
    return model_in_force(stored, config).measured


def control_law(config: Config, model: pid.PlantModel) -> pid.Controller:
    """The control law the config names, on `model`, with the second element's share."""
    return factory.shared_out(config, factory.make_controller(config.control, model))


def learner(config: Config, model: pid.PlantModel) -> Learner:
    """The learner of the tun's model, from the model in force."""
    return Learner(litres=config.tun.litres, ambient=model.ambient, period=config.control.period)


def planner(config: Config, model: pid.PlantModel) -> TimeProportionalPlanner:
    """The SSR's window planner for the config's outputs: its band what keeps the water's
    whole swing (the band's, and a pulse's of two windows at 50 %) within `output.swing` at
    the SSR's element's full-power rate on `model`, at most a window (docs/ssr-band.md).
    With a current input fitted, no pulse or gap shorter than two of its reads take
    (`two_reads_part`), unless the config's own minimums leave no room for that in the window."""
    out = config.output
    window = window_length(config)
    min_on, min_off = out.min_on, out.min_off
    if config.current.fitted:
        least = two_reads_part(out.mains_hz)
        if max(min_on, least) + max(min_off, least) < window:
            min_on, min_off = max(min_on, least), max(min_off, least)
    rate = ssr_rate(config, model)
    band = min(window, max(0.0, out.swing / (2.0 * rate) - window / 4.0))
    return TimeProportionalPlanner(window, out.mains_hz, min_on, min_off, band)


def ssr_rate(config: Config, model: pid.PlantModel) -> float:
    """°C/s the SSR's element heats the water at full power on `model` (its share of the
    model's rate: a second element is on its own contactor, outside the planner)."""
    return model.rate * config.tun.element_watts / total_watts(config)


def water_swing(config: Config, model: pid.PlantModel) -> float:
    """°C the water swings at most under the SSR's pulses on `model` (`planner`'s)."""
    return planner(config, model).swing(ssr_rate(config, model))


def _tun_fields(model: MeasuredTun | None) -> dict[str, float] | None:
    """A measured tun as the log keeps it (None: the limits hold for any tun)."""
    if model is None:
        return None
    return {k: getattr(model, k) for k in ("gain", "tau", "dead_time", "ambient")}


def retunes(old: ControlConfig, new: ControlConfig) -> bool:
    """Whether a reload from `old` to `new` needs a new controller (bumplessly reset)."""
    return any(getattr(old, key) != getattr(new, key) for key in config_module.TUNING_KEYS)
