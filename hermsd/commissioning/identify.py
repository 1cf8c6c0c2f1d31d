"""Identification: the first-order-plus-dead-time model of the tun that fits a logged day.

One fitting code for every user: `hermsd replay --what-if` runs the day again on the model,
`hermsd tune FILE...` turns it into settings.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import operator
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import NamedTuple, Protocol

from hermsd.control import linsys
from hermsd.safety.limits import vapour_pressure_ratio


class IdentifyError(ValueError):
    """A log that does not show the tun well enough to fit; the message says what is missing."""


class _Numbered(Protocol):
    @property
    def k(self) -> int: ...


class LoggedDay(Protocol):
    """What the fit needs of a day's log: its period records and their times."""

    @property
    def periods(self) -> Sequence[_Numbered]: ...

    @property
    def elapsed(self) -> Sequence[float]: ...


class Upset(Protocol):
    """A disturbance the model has no input for (cold water), at `at` s."""

    @property
    def at(self) -> float: ...


@dataclass(frozen=True, slots=True)
class TunModel:
    """τ·dT/dt = −(T − ambient) + K·u(t − θ) − E·g(T), T = `start` at the first period.

    E (`evaporation`) is an open pot's evaporation at 66 °C over its linear losses, in °C
    (0: lidded), and g(T) its physical shape, the vapour pressure of water at T over that at
    66 °C (hermsd.safety.supervisor.vapour_pressure_ratio): only its scale is fitted.
    """

    gain: float  # K, °C/%
    tau: float  # s
    dead_time: float  # θ, s
    ambient: float  # °C
    start: float  # °C
    rms: float  # °C, of the fit
    fit_s: float  # s of log the fit used
    evaporation: float = 0.0  # E, °C

    def at_hold(self, hold: float) -> TunModel:
        """The first-order model that holds `hold` °C at the same duty as this one, with the
        same K/τ (the element's heating rate): K_h = K·D/(D + E·g(hold)), D = hold − ambient,
        and τ_h likewise. Its K is the static gain at the hold (the duty that holds it), which
        the controller's feed-forward and the supervisor's loss watch need; lidded, itself."""
        if self.evaporation == 0.0:
            return self
        ratio = _hold_ratio(hold - self.ambient, self.evaporation, hold)
        return dataclasses.replace(
            self, gain=self.gain * ratio, tau=self.tau * ratio, evaporation=0.0
        )


def _hold_ratio(drive: float, evaporation: float, hold: float) -> float:
    """D/(D + E·g(hold)): the linear losses' share of the loss at the hold."""
    return drive / (drive + evaporation * vapour_pressure_ratio(hold))


MAX_DEAD_TIME_S = 900.0
TAU_RANGE_S = (10.0, 1e6)
MIN_FIT_PERIODS = 60
MIN_DUTY_SPAN = 20.0  # %: the fit needs the duty to move for K and τ to show


def fit_span(log: LoggedDay, drops: Sequence[Upset], period_s: float) -> int:
    """How many periods from the first the fit may use: up to a drop, a gap or a restart."""
    end = drops[0].at if drops else math.inf
    periods, elapsed = log.periods, log.elapsed
    n = 1
    while n < len(periods):
        record, previous = periods[n], periods[n - 1]
        if elapsed[n] > end or record.k != previous.k + 1:
            break
        if abs(elapsed[n] - elapsed[n - 1] - period_s) > 0.25 * period_s:
            break
        n += 1
    return n


def identify(
    pvs: Sequence[float | None],
    duties: Sequence[float],
    period_s: float,
    ambient: float | None = None,
    evaporation: bool = False,
) -> TunModel:
    """The FOPTD model whose response to `duties` fits `pvs` best (least squares).

    One sample per control period; `duties[k]` is the duty of the span ending at sample k
    (a period record's `applied`), and before the first one the duty is taken to have stood
    at it. For a given τ and θ (a whole number of periods) the model is linear in the
    ambient temperature, the initial offset from equilibrium and K:
    T_k = T_amb + x0·a^k + K·z_{k−d}, with a = e^(−Ts/τ) and z the duty through the
    discrete first-order lag z_k = a·z_{k−1} + (1 − a)·u_k; those three come from the
    normal equations. θ is searched over whole periods up to MAX_DEAD_TIME_S (every fourth,
    then around the best), τ by golden section on log τ, in turn until θ stays put; then θ
    a period at a time with τ refitted, while the error falls.

    `ambient`: the room's temperature when it is known (a thermometer): then only x0 and K
    are fitted. A heat-up much shorter than τ hardly bends, and a free ambient then trades
    off against K and τ together (K/τ stays right); a known one pins K through the hold.

    `evaporation`: the tun is an open pot (tun.lid off), so E is fitted too, as a fourth
    linear parameter with the regressor g(PV) through the same lag (not delayed: the
    evaporation acts on the water the sensor reads). A lidded tun is never given one: on a
    heat-up that stops well below the hold, E trades off against K and τ and would be found
    where there is none. A negative E (no evaporation shows, and noise) gives the lidded fit:
    at the hold it would make the gain grow, or divide by zero.
    """
    n = len(pvs)
    valid = [pv is not None for pv in pvs]
    count = sum(valid)
    if count < MIN_FIT_PERIODS:
        raise IdentifyError(
            f"cannot fit a model of the tun: {count} periods with a PV before the first "
            f"disturbance, at least {MIN_FIT_PERIODS} needed"
        )
    if max(duties) - min(duties) < MIN_DUTY_SPAN:
        raise IdentifyError(
            "cannot fit a model of the tun: the duty hardly moved before the first "
            f"disturbance (less than {MIN_DUTY_SPAN:g} %), so gain and time constant do not show"
        )
    fit, mean = _prepared(pvs, duties, period_s, ambient, evaporation)
    log_tau, lag = fit.along_the_valley(*fit.descend(math.log(n * period_s)))
    sse, solution = fit.solve(log_tau, lag)
    offset, x0, gain = solution[:3]
    if not gain > 0:
        raise IdentifyError("cannot fit a model of the tun: the PV does not rise with the duty")
    evaporated = solution[3] if evaporation else 0.0
    if evaporated < 0.0:  # losses that shrink as it warms are no evaporation: none shows
        return identify(pvs, duties, period_s, ambient, evaporation=False)
    ambient = offset + mean
    return TunModel(
        gain=gain,
        tau=math.exp(log_tau),
        dead_time=lag * period_s,
        ambient=ambient,
        start=ambient + x0 + gain * duties[0] - evaporated * fit.shape_first,
        rms=math.sqrt(max(sse, 0.0) / count),
        fit_s=n * period_s,
        evaporation=evaporated,
    )


def _prepared(
    pvs: Sequence[float | None],
    duties: Sequence[float],
    period_s: float,
    ambient: float | None,
    evaporation: bool = False,
) -> tuple[_Fit, float]:
    """The fit's sums for PV less its mean (which keeps the normal equations well scaled),
    or less the known ambient temperature (the offset is then held at 0)."""
    values = [pv for pv in pvs if pv is not None]
    mean = sum(values) / len(values) if ambient is None else ambient
    weights = [0.0 if pv is None else 1.0 for pv in pvs]
    temps = [0.0 if pv is None else pv - mean for pv in pvs]
    max_lag = max(0, min(round(MAX_DEAD_TIME_S / period_s), len(pvs) // 4))
    shape = None
    if evaporation:  # g(PV), a missing PV taken as the last one read
        last = values[0]
        shape = []
        for pv in pvs:
            last = last if pv is None else pv
            shape.append(vapour_pressure_ratio(last))
    fit = _Fit(
        temps, weights, duties, max_lag, period_s, fixed_offset=ambient is not None, shape=shape
    )
    return fit, mean


@dataclass(frozen=True, slots=True)
class Uncertainty:
    """One standard deviation of each fitted parameter, and what the residuals were worth."""

    gain: float  # °C/%
    tau: float  # s
    dead_time: float  # s
    ambient: float  # °C
    effective_samples: float  # periods, after the residuals' correlation


UNCERTAINTY_METHOD = (
    "noise: linearised least squares, covariance s²·(JᵀJ)⁻¹ of (ambient, x0, K, ln τ) at the "
    "fit, s² scaled by (1+ρ)/(1−ρ) for the residuals' lag-1 autocorrelation ρ; model: half "
    "the mean change of K and τ when θ is moved one period either way and τ refitted (θ is "
    "fitted in whole periods, and a sensor's own lag or the PV's averaging is no pure delay), "
    "added in quadrature; θ: the whole periods whose error stays within that s² of the best, "
    "at least ±half a period; an open pot: E joins the parameters, and the covariance is "
    "carried to K and τ at the hold by their first derivatives"
)


def uncertainty(
    pvs: Sequence[float | None],
    duties: Sequence[float],
    period_s: float,
    model: TunModel,
    ambient: float | None = None,
    hold: float | None = None,
) -> Uncertainty:
    """How well `pvs` pin down `model` (as `identify` fitted it to them); see UNCERTAINTY_METHOD.

    A brew day's residuals are not white (the sensor's 0.0625 °C steps, slow drifts of the
    losses), so the plain formula would claim too much: the AR(1) factor counts the samples
    that are worth one independent one each. θ is held at its fit for the others.

    `hold`: for a model fitted with an evaporation term, the K and τ whose spread is given
    are those of `model.at_hold(hold)` (the linearised covariance carried through it).
    """
    evaporation = hold is not None and model.evaporation != 0.0
    fit, mean = _prepared(pvs, duties, period_s, ambient, evaporation)
    log_tau, lag = math.log(model.tau), round(model.dead_time / period_s)
    sse, solution = fit.solve(log_tau, lag)
    offset, x0, gain = solution[:3]
    evaporated = solution[3] if evaporation else 0.0

    def parts(log_tau: float) -> tuple[list[float], list[float], list[float]]:
        """a^k, z_{k−d} and e: the response is offset + x0·a^k + K·z_{k−d} + E·e."""
        series = fit._series(log_tau)
        z = series.lagged[fit.max_lag - lag : fit.max_lag - lag + fit.n]
        return series.powers, z, series.shaped or [0.0] * fit.n

    def response(log_tau: float) -> list[float]:
        powers, z, e = parts(log_tau)
        return [
            x0 * p + gain * zk + evaporated * ek for p, zk, ek in zip(powers, z, e, strict=True)
        ]

    step = 1e-4  # in ln τ: a central difference for the one parameter the fit is not linear in
    below, above = response(log_tau - step), response(log_tau + step)
    slope = [(b - a) / (2 * step) for a, b in zip(below, above, strict=True)]
    powers, z, e = parts(log_tau)
    fitted = response(log_tau)
    # the columns of (offset, x0, K, ln τ, E), the rows where a PV was read
    rows = [
        (w, w * p, w * zk, w * d, w * ek)
        for w, p, zk, d, ek in zip(fit.weights, powers, z, slope, e, strict=True)
        if w > 0
    ]
    residuals = [
        t - offset - f for t, f, w in zip(fit.temps, fitted, fit.weights, strict=True) if w > 0
    ]
    count = len(residuals)
    squares = _dot(residuals, residuals)
    rho = _dot(residuals[:-1], residuals[1:]) / squares if squares > 0 else 0.0
    rho = min(max(rho, 0.0), 0.999)
    inflation = (1.0 + rho) / (1.0 - rho)
    fitted_params = [1, 2, 3] if fit.fixed_offset else [0, 1, 2, 3]
    if evaporation:
        fitted_params.append(4)
    s2 = max(sse, 0.0) / max(count - len(fitted_params) - 1, 1) * inflation
    columns = [[r[i] for r in rows] for i in fitted_params]
    normal = [[_dot(a, b) for b in columns] for a in columns]
    covariance = [[0.0] * 5 for _ in range(5)]
    for i, param in enumerate(fitted_params):
        unit = [1.0 if j == i else 0.0 for j in range(len(fitted_params))]
        try:
            column = linsys.solve(normal, unit)
        except ValueError:
            return Uncertainty(math.inf, math.inf, math.inf, math.inf, count / inflation)
        for j, other in enumerate(fitted_params):
            covariance[other][param] = column[j].real * s2
    # the sensitivities of the reported K and τ to (offset, x0, K, ln τ, E)
    gain_grad, tau_grad = [0.0, 0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, model.tau, 0.0]
    if evaporation and hold is not None:
        drive, shape = hold - (offset + mean), vapour_pressure_ratio(hold)
        ratio = _hold_ratio(drive, evaporated, hold)
        per_e = -drive * shape / (drive + evaporated * shape) ** 2  # ∂ratio/∂E
        per_offset = -evaporated * shape / (drive + evaporated * shape) ** 2  # ∂ratio/∂offset
        gain_grad = [gain * per_offset, 0.0, ratio, 0.0, gain * per_e]
        tau_grad = [model.tau * per_offset, 0.0, 0.0, model.tau * ratio, model.tau * per_e]

    def variance(grad: list[float]) -> float:
        total = math.fsum(grad[i] * covariance[i][j] * grad[j] for i in range(5) for j in range(5))
        return max(total, 0.0)

    def reported(other_lag: int) -> tuple[float, float]:
        """K and τ refitted with θ at `other_lag` periods (at the hold, with evaporation)."""
        other_log_tau = fit.best_log_tau(other_lag)
        other = fit.solve(other_log_tau, other_lag)[1]
        k, tau = other[2], math.exp(other_log_tau)
        if evaporation and hold is not None:
            ratio = _hold_ratio(hold - (other[0] + mean), other[3], hold)
            k, tau = k * ratio, tau * ratio
        return k, tau

    centre = reported(lag) if evaporation else (gain, model.tau)
    moved = [reported(other) for other in (lag - 1, lag + 1) if 0 <= other <= fit.max_lag]
    model_gain = sum(abs(k - centre[0]) for k, _ in moved) / (2 * len(moved)) if moved else 0.0
    model_tau = sum(abs(t - centre[1]) for _, t in moved) / (2 * len(moved)) if moved else 0.0
    threshold = sse + s2
    low = high = lag
    while low > 0 and fit.error(log_tau, low - 1) <= threshold:
        low -= 1
    while high < fit.max_lag and fit.error(log_tau, high + 1) <= threshold:
        high += 1
    return Uncertainty(
        gain=math.hypot(math.sqrt(variance(gain_grad)), model_gain),
        tau=math.hypot(math.sqrt(variance(tau_grad)), model_tau),
        dead_time=max((high - low) / 2.0, 0.5) * period_s,
        ambient=math.sqrt(max(covariance[0][0], 0.0)),
        effective_samples=count / inflation,
    )


class _Series(NamedTuple):
    """What the fit needs of one τ: w·a^k, a^k, and z (extended back by max_lag) and z²;
    with an evaporation term, −g(PV) through the same lag (e), w·e, and the sums of w·e,
    w·e·a^k, w·e² and (T − mean)·e, which do not depend on θ."""

    w_powers: list[float]
    powers: list[float]
    lagged: list[float]
    squares: list[float]
    shaped: list[float] | None = None
    w_shaped: list[float] | None = None
    shaped_sums: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)


class _Fit:
    """Sums for the least-squares fit of one θ and τ, each in O(n) at C speed."""

    def __init__(
        self,
        temps: list[float],
        weights: list[float],
        duties: Sequence[float],
        max_lag: int,
        period_s: float,
        *,
        fixed_offset: bool = False,
        shape: list[float] | None = None,
    ) -> None:
        self.temps, self.weights, self.duties = temps, weights, list(duties)
        self.max_lag, self.period_s = max_lag, period_s
        self.fixed_offset = fixed_offset
        self.shape = shape
        self.shape_first = shape[0] if shape else 0.0
        self.n = len(temps)
        self.total_w = sum(weights)
        self.sum_t = _dot(weights, temps)
        self.sum_tt = _dot(temps, temps)
        self._cached: tuple[float, _Series] | None = None

    def _series(self, log_tau: float) -> _Series:
        if self._cached is not None and self._cached[0] == log_tau:
            return self._cached[1]
        a = math.exp(-self.period_s / math.exp(log_tau))
        b = 1.0 - a
        powers = list(
            itertools.accumulate(itertools.repeat(a, self.n - 1), operator.mul, initial=1.0)
        )
        first = self.duties[0]
        lagged = [first] * self.max_lag  # before the log: the duty stood at its first value
        lagged.extend(itertools.accumulate(self.duties, lambda z, u: a * z + b * u, initial=first))
        del lagged[self.max_lag]  # the initial value itself (z_{−1}) is not a sample
        shaped = w_shaped = None
        sums = (0.0, 0.0, 0.0, 0.0)
        if self.shape is not None:
            filtered = itertools.accumulate(
                self.shape, lambda e, g: a * e + b * g, initial=self.shape[0]
            )
            shaped = [-e for e in itertools.islice(filtered, 1, None)]
            w_shaped = list(map(operator.mul, self.weights, shaped))
            sums = (
                sum(w_shaped),
                _dot(w_shaped, powers),
                _dot(w_shaped, shaped),
                _dot(self.temps, shaped),
            )
        series = _Series(
            list(map(operator.mul, self.weights, powers)),
            powers,
            lagged,
            [z * z for z in lagged],
            shaped,
            w_shaped,
            sums,
        )
        self._cached = (log_tau, series)
        return series

    def solve(self, log_tau: float, lag: int) -> tuple[float, tuple[float, ...]]:
        """(sum of squared errors, (offset, x0, K[, E])) of the best fit for τ and θ = lag
        periods."""
        series = self._series(log_tau)
        start, stop = self.max_lag - lag, self.max_lag - lag + self.n
        z = series.lagged[start:stop]
        w, w_powers = self.weights, series.w_powers
        s_p = sum(w_powers)
        s_z = _dot(w, z)
        gram = (
            (self.total_w, s_p, s_z),
            (s_p, _dot(w_powers, series.powers), _dot(w_powers, z)),
            (s_z, _dot(w_powers, z), _dot(w, series.squares[start:stop])),
        )
        rhs = (self.sum_t, _dot(w_powers, self.temps), _dot(self.temps, z))
        if series.w_shaped is not None:
            return self._solve_with_evaporation(series, _dot(series.w_shaped, z), gram, rhs)
        if self.fixed_offset:  # the offset's equation becomes offset = 0
            gram = ((1.0, 0.0, 0.0), (0.0, *gram[1][1:]), (0.0, *gram[2][1:]))
            rhs = (0.0, rhs[1], rhs[2])
        solution = _solve3(gram, rhs)
        if solution is None:
            return math.inf, (0.0, 0.0, 0.0)
        return self.sum_tt - _dot(solution, rhs), solution

    def _solve_with_evaporation(
        self,
        series: _Series,
        s_ez: float,
        gram: tuple[tuple[float, float, float], ...],
        rhs: tuple[float, float, float],
    ) -> tuple[float, tuple[float, ...]]:
        """The normal equations bordered by the evaporation's column e (solve's fourth
        parameter, `s_ez` = Σw·e·z at this θ); with a known ambient the offset's row and
        column are left out."""
        s_e, s_ep, s_ee, s_te = series.shaped_sums
        border = (s_e, s_ep, s_ez)
        rows = [[*gram[i], border[i]] for i in range(3)]
        rows.append([*border, s_ee])
        vector = [*rhs, s_te]
        kept = range(1, 4) if self.fixed_offset else range(4)
        try:
            solved = linsys.solve(
                [[rows[i][j] for j in kept] for i in kept], [vector[i] for i in kept]
            )
        except ValueError:
            return math.inf, (0.0, 0.0, 0.0, 0.0)
        values = [x.real for x in solved]
        solution = (0.0, *values) if self.fixed_offset else tuple(values)
        return self.sum_tt - _dot(solution, vector), solution

    def descend(self, log_tau: float) -> tuple[float, int]:
        """From τ = e^log_tau, the best θ and τ in turn, until θ stays put: a local minimum."""
        log_tau = min(max(log_tau, math.log(TAU_RANGE_S[0])), math.log(TAU_RANGE_S[1]))
        lag = self.best_lag(log_tau)
        for _ in range(6):
            log_tau = self.best_log_tau(lag)
            previous, lag = lag, self.best_lag(log_tau)
            if lag == previous:
                break
        return log_tau, lag

    def along_the_valley(self, log_tau: float, lag: int) -> tuple[float, int]:
        """The valley runs across τ and θ together, where turns of one at a time stall: walk
        θ a period at a time either way, τ refitted at each, while the error falls."""
        best, least = (log_tau, lag), self.error(log_tau, lag)
        for step in (-1, 1):
            while 0 <= best[1] + step <= self.max_lag:
                other = best[1] + step
                candidate = (self.best_log_tau(other), other)
                error = self.error(*candidate)
                if error >= least:
                    break
                best, least = candidate, error
        return best

    def error(self, log_tau: float, lag: int) -> float:
        return self.solve(log_tau, lag)[0]

    def best_lag(self, log_tau: float) -> int:
        """Every fourth lag, then the neighbours of the best: the error is smooth in θ."""
        coarse = min(range(0, self.max_lag + 1, 4), key=lambda lag: self.error(log_tau, lag))
        near = range(max(0, coarse - 3), min(self.max_lag, coarse + 3) + 1)
        return min(near, key=lambda lag: self.error(log_tau, lag))

    def best_log_tau(self, lag: int) -> float:
        low, high = map(math.log, TAU_RANGE_S)
        return _golden(lambda log_tau: self.error(log_tau, lag), low, high)


def _dot(x: Sequence[float], y: Sequence[float]) -> float:
    total: float = sum(map(operator.mul, x, y))
    return total


def _solve3(
    m: tuple[tuple[float, float, float], ...], v: tuple[float, float, float]
) -> tuple[float, float, float] | None:
    """Cramer's rule; None when the system is (numerically) singular."""

    def det(a: Sequence[Sequence[float]]) -> float:
        return (
            a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
            - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
            + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0])
        )

    d = det(m)
    scale = math.prod(max(abs(x) for x in row) for row in m)
    if scale == 0 or abs(d) <= 1e-12 * scale:
        return None
    columns = []
    for j in range(3):
        replaced = [[v[i] if c == j else m[i][c] for c in range(3)] for i in range(3)]
        columns.append(det(replaced) / d)
    return columns[0], columns[1], columns[2]


def _golden(f: Callable[[float], float], low: float, high: float, tolerance: float = 1e-5) -> float:
    """The minimum of a unimodal f on [low, high] by golden-section search."""
    ratio = (math.sqrt(5.0) - 1.0) / 2.0
    c, d = high - ratio * (high - low), low + ratio * (high - low)
    fc, fd = f(c), f(d)
    while high - low > tolerance:
        if fc <= fd:
            high, d, fd = d, c, fc
            c = high - ratio * (high - low)
            fc = f(c)
        else:
            low, c, fc = c, d, fd
            d = low + ratio * (high - low)
            fd = f(d)
    return (low + high) / 2.0
