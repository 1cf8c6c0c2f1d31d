"""What the daemon learns of its tun from ordinary brew days, and where it keeps it.

The predictive controller measures the full-power heating rate and the dead time on every
heat-up by itself (`pid.HeatUpFit`). What it cannot measure there is the loss: that shows
in the hold, as the duty that keeps the setpoint. A `Learner` watches the periods of one
clean spell (auto mode, no alarm, no sensor fault, no reload, no reset after a hold): an
accepted heat-up fit followed by HOLD_S of steady hold gives one estimate of the tun, which
is checked for physical sense and then stored (`ModelStore`, atomically) for the next
start, where it replaces the prior the config describes.

The hold's first half hour is still the end of the approach: the water climbs its last
0.25 °C on more than the holding duty. The mean duty would take that heat for loss (1.6 %
too much on the seed's tun; on a 150 L one, 1 % of duty: the next heat-up settles 0.01 °C
high and creeps back over a quarter of an hour). So the loss is fitted to the model's own
balance, PV_k = PV_0 + heat_k − loss·excess_k, the heat being the duty that reached the
sensor a dead time late and the excess the PV above the room, both summed over the window:
a least-squares line over every period, which a LSB at either end of the window cannot
move as it moves a difference of two PVs.

The fill differs from one brew day to the next and nobody edits `tun.litres` for it, so
what is stored is referred to the litres configured when it was learned and rescaled by the
configured litres at the next start: the rate by V₀/V (element power over ρ·c·V), the loss
rate UA/(ρ·c·V) by (V₀/V)^⅓ (the wetted surface grows as V^⅔). A fill that differs from the
config without the config saying so is caught by the controller itself, which re-measures
the rate and dead time early in every heat-up.
"""

from __future__ import annotations

import contextlib
import json
import math
from collections import deque
from collections.abc import Iterable
from dataclasses import asdict, dataclass
from pathlib import Path

from hermsd.control.coil import MAX_CONDUCTANCE
from hermsd.control.pid import AMBIENT_RANGE, MAX_DEAD_TIME, RATE_BAND, SENSOR_LSB, PlantModel
from hermsd.control.watches import HeatUpFit, LineFit
from hermsd.files import write_atomically
from hermsd.safety.latches import StateError, read_state_json
from hermsd.safety.limits import FILL_RANGE

LEARNED_FILE = "learned-model.json"
HOLD_S = 1800.0
"""s of steady hold after an accepted heat-up before the loss is estimated."""
HOLD_BAND = 0.25
"""°C around the setpoint that counts as a steady hold."""
WATER_FALL = 2 * SENSOR_LSB
WATER_SPAN_S = 60.0
"""°C (2 LSB) below the highest PV of the last WATER_SPAN_S s: water came in, and the hold
starts anew. A hold's PV moves by an LSB in a minute, and noise on a period's mean (sd
0.02 °C) never by 2 LSB; water the window kept would be taken for loss (0.4 % of the volume
at 15 °C, a fall of 0.2 °C: a loss 8 % too high). Less than that still costs up to 4 %.
Noisier readings raise it by as much as they scatter more (`predictive.noise_scale`): at
0.06 °C of noise 2 LSB came from noise alone many times an hour, and no hold was long
enough to learn from (population tun 190, docs/sensors.md)."""
MIN_TAU = 600.0
MAX_TAU = 1e6
MIN_LITRES, MAX_LITRES = 1.0, 1000.0  # the range tun.litres may be configured in
"""s: a water tun loses heat slower than a cup of tea and faster than a vacuum flask."""


@dataclass(frozen=True, slots=True)
class LearnedModel:
    """The tun as measured: referred to `litres` (the configured fill when learned)."""

    rate: float  # °C/s at full power
    loss: float  # 1/s: UA/(ρ·c·V), losses referred to `ambient`
    dead_time: float  # s
    ambient: float  # °C
    litres: float
    wall_ns: int = 0  # when it was learned (UTC ns)
    # A HERMS coil's conductance K and its sd (W/K) as the day's pump runs showed it
    # (`coil.CoilEstimator`); 0 when none was learned. A file without them reads as 0.
    coil: float = 0.0
    coil_sd: float = 0.0
    # How many elements `rate` is at full power of: 2 where a second is fitted (the one
    # controller drives their total power). A file before it: 1.
    elements: int = 1

    @classmethod
    def from_plant(cls, model: PlantModel, litres: float) -> LearnedModel:
        """The tun as a FOPTD (K °C/%, τ, θ, room) measured with `litres` in it, as the
        learned quantities: rate 100·K/τ at full power, loss 1/τ; `plant_model` inverts it."""
        return cls(model.rate, 1.0 / model.tau, model.dead_time, model.ambient, litres)

    def plant_model(self, litres: float) -> PlantModel:
        """The FOPTD model at a configured fill of `litres`."""
        rate = self.rate * self.litres / litres
        loss = self.loss * (self.litres / litres) ** (1.0 / 3.0)
        return PlantModel(
            rate / (100.0 * loss), 1.0 / loss, self.dead_time, self.ambient, measured=True
        )

    def describe(self) -> str:
        return (
            f"full-power rate {self.rate * 60.0:.3f} °C/min, dead time {self.dead_time:.0f} s, "
            f"time constant {1.0 / self.loss:.0f} s (room {self.ambient:g} °C) at "
            f"{self.litres:g} L"
        )


def water_came(recent: Iterable[float], pv: float, noise: float) -> bool:
    """Whether `pv` lies `noise` × WATER_FALL or more below the highest of `recent` (the PVs
    of the last WATER_SPAN_S; `noise`: `predictive.noise_scale`): water poured in, and a hold
    measured across it would take it for loss."""
    return max(recent, default=pv) - pv >= noise * WATER_FALL


def implausible(model: LearnedModel) -> str | None:
    """Why `model` cannot be a water tun's, or None when it can."""
    values = (model.rate, model.loss, model.dead_time, model.ambient, model.litres)
    if not all(math.isfinite(v) for v in (*values, model.coil, model.coil_sd)):
        return "a value is not finite"
    if model.elements not in (1, 2):
        return f"{model.elements} elements: hermsd drives one or two"
    if not (0.0 <= model.coil <= MAX_CONDUCTANCE and model.coil_sd >= 0.0):
        return (
            f"coil conductance {model.coil:g} ± {model.coil_sd:g} W/K is not within "
            f"0–{MAX_CONDUCTANCE:g} W/K"
        )
    if not 0.0 < model.rate <= 1.0:
        return f"full-power rate {model.rate:.3g} °C/s is not within 0–1 °C/s"
    if not 1.0 / MAX_TAU <= model.loss <= 1.0 / MIN_TAU:
        tau = f"{1.0 / model.loss:.3g} s" if model.loss > 0.0 else "endless (no loss)"
        return f"time constant {tau} is not within {MIN_TAU:g}–{MAX_TAU:g} s"
    if not MIN_LITRES <= model.litres <= MAX_LITRES:
        return f"fill {model.litres:g} L is not within {MIN_LITRES:g}–{MAX_LITRES:g} L"
    if not 0.0 <= model.dead_time <= MAX_DEAD_TIME:
        return f"dead time {model.dead_time:.0f} s is not within 0–{MAX_DEAD_TIME:g} s"
    low, high = AMBIENT_RANGE
    if not low <= model.ambient <= high:
        return f"room {model.ambient:g} °C is not within −100…100 °C"
    return None


def implausible_here(model: LearnedModel, *, litres: float, full_rate: float) -> str | None:
    """Why `model` cannot be this tun's (`litres` configured, `full_rate` °C/s the element
    gives that water, P/(ρ·c·V)), or None when it can.

    Beyond `implausible`: the fill it was learned with must be one the supervisor's limits
    hold for before a measurement (half to twice the configured litres, safety.FILL_RANGE),
    and its rate, rescaled to the configured litres, one a heat-up on this tun could have
    measured (within pid.RATE_BAND of the element's rate: ¼–4×, the band a heat-up's fit is
    taken in). A rate 60× too high holds the water cold at 0.2 % output with no alarm; one
    too low is refused by the first heat-up, whose real rate the model then cannot follow.
    Its dead time is bound as a heat-up's fit bounds it (`implausible`).
    """
    why = implausible(model)
    if why is not None:
        return why
    if not litres / FILL_RANGE <= model.litres <= litres * FILL_RANGE:
        return f"fill {model.litres:g} L is not within half to twice the configured {litres:g} L"
    rate = model.rate * model.litres / litres  # as `plant_model` rescales it
    if not RATE_BAND[0] * full_rate <= rate <= RATE_BAND[1] * full_rate:
        return (
            f"full-power rate {rate * 60.0:.3g} °C/min at {litres:g} L is not within ¼–4× of "
            f"the {full_rate * 60.0:.3g} °C/min the element gives that water"
        )
    return None


class ModelStore:
    """`learned-model.json` in the state directory, next to the latches: the tun's learned
    model with the coil's K, or the coil's K alone (`save_coil`) while nothing is learned of
    the tun: a record with the tun's fields would be taken for a measured tun."""

    def __init__(self, directory: Path | str) -> None:
        self.path = Path(directory) / LEARNED_FILE

    def load(self) -> tuple[LearnedModel | None, str | None]:
        """(the stored model, None), (None, None) when none, (None, why) for a bad file.

        A bad file is not fatal: the prior is safe, so the daemon says why and goes on.
        """
        try:
            document = read_state_json(self.path)
        except StateError as error:
            return None, str(error)
        if document is None or _coil_alone(document):
            return None, None
        try:
            model = LearnedModel(
                float(document["rate"]),
                float(document["loss"]),
                float(document["dead_time"]),
                float(document["ambient"]),
                float(document["litres"]),
                int(document.get("wall_ns", 0)),
                float(document.get("coil", 0.0)),
                float(document.get("coil_sd", 0.0)),
                int(document.get("elements", 1)),
            )
        except (KeyError, TypeError, ValueError, OverflowError) as error:
            return None, f"{self.path}: not a learned model ({error})"
        why = implausible(model)
        if why is not None:
            return None, f"{self.path}: {why}"
        return model, None

    def load_coil(self) -> tuple[float, float] | None:
        """The coil's K and sd (W/K) the file keeps, with the tun's model or alone; None when
        there is none or the file cannot be read (`load` says why)."""
        try:
            document = read_state_json(self.path)
        except StateError:
            return None
        if not isinstance(document, dict):
            return None
        try:
            coil, sd = float(document["coil"]), float(document["coil_sd"])
        except (KeyError, TypeError, ValueError, OverflowError):
            return None
        if not 0.0 < coil <= MAX_CONDUCTANCE or sd < 0.0:
            return None
        return coil, sd

    def save_coil(self, coil: float, coil_sd: float, wall_ns: int) -> None:
        """Keep the coil's K alone, while no model of the tun is stored (OSError when the disk
        refuses); a model stored later carries it on (`MashSide.with_coil`)."""
        document = {"coil": coil, "coil_sd": coil_sd, "wall_ns": wall_ns}
        write_atomically(self.path, json.dumps(document, indent=1))

    def save(self, model: LearnedModel) -> None:
        """Replace the stored model atomically (OSError when the disk refuses)."""
        write_atomically(self.path, json.dumps(asdict(model), indent=1))

    def forget(self) -> bool:
        """Delete the stored model; False when there was none."""
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()
            return True
        return False


def _coil_alone(document: object) -> bool:
    """Whether a stored document is the coil's K alone (`ModelStore.save_coil`)."""
    return isinstance(document, dict) and "rate" not in document and "coil" in document


@dataclass(frozen=True, slots=True)
class Estimate:
    """One spell's outcome: a model to store, or why it was refused."""

    model: LearnedModel | None
    refused: str | None


class Learner:
    """Turns one clean spell (an accepted heat-up, then a steady hold) into an estimate."""

    __slots__ = (
        "_ambient",
        "_applied",
        "_balance",
        "_excess",
        "_fit",
        "_heat",
        "_hold_s",
        "_litres",
        "_period",
        "_recent",
        "done",
    )

    def __init__(self, *, litres: float, ambient: float, period: float) -> None:
        self._litres = litres
        self._ambient = ambient
        self._period = period
        self._fit: HeatUpFit | None = None
        # The duties applied over the last dead time, the oldest (now at the sensor) first.
        self._applied: deque[float] = deque()
        self._recent: deque[float] = deque(maxlen=max(1, round(WATER_SPAN_S / period)))
        self._balance = LineFit()
        self._heat = self._excess = self._hold_s = 0.0
        self.done = False  # one estimate per run: later spells would only repeat it

    def interrupt(self) -> None:
        """A fault, an alarm, manual mode, a reload or a reset: nothing before it counts."""
        self._fit = None
        self._applied = deque()
        self._recent.clear()
        self._restart_hold()

    def _restart_hold(self) -> None:
        self._balance = LineFit()
        self._heat = self._excess = self._hold_s = 0.0

    def heat_up(self, fit: HeatUpFit) -> None:
        """The controller measured a heat-up; a refused one starts nothing."""
        self.interrupt()
        if fit.refused is None:
            self._fit = fit
            # A period's duty moves the PV a dead time later, as in the controller's model.
            self._applied = deque(maxlen=round(fit.dead_time / self._period) + 1)

    def period(
        self, setpoint: float, pv: float, applied: float, *, noise: float
    ) -> Estimate | None:
        """One clean period in auto (`applied`: the duty of the period `pv` ends; `noise`: the
        readings' scatter over the bench's, `water_came`); the estimate once the hold after a
        heat-up is long enough."""
        fit = self._fit
        if fit is None or self.done:
            return None
        arrived = self._applied
        arrived.append(applied)
        recent = self._recent
        water = water_came(recent, pv, noise)
        recent.append(pv)
        if water or abs(pv - setpoint) > HOLD_BAND or len(arrived) < (arrived.maxlen or 0):
            self._restart_hold()  # not (or no longer) holding: start the hold anew
            return None
        if self._balance.n:
            self._heat += fit.rate * arrived[0] / 100.0 * self._period
            self._excess += (pv - self._ambient) * self._period
            self._hold_s += self._period
        self._balance.add(self._excess, pv - self._heat)
        if self._hold_s < HOLD_S:
            return None
        self.done = True
        if self._excess <= 0.0:
            return Estimate(None, f"the setpoint {setpoint:g} °C is not above the room")
        slope = self._balance.slope()
        loss = -slope if slope is not None else 0.0
        model = LearnedModel(fit.rate, loss, fit.dead_time, self._ambient, self._litres)
        why = implausible(model)
        return Estimate(None, why) if why else Estimate(model, None)
