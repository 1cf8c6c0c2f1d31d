"""The seed's PID forms, each a direct transcription of its discrete-time equation (type A,
type A filtered, Takahashi, back-calculation; velocity PI is Takahashi with Td = 0)."""

from __future__ import annotations

import math

from hermsd.control.pid import _INF, Params, _Base, _lowpass, _number


class _TypeA(_Base):
    """Eq. 08: u_k = p1·u_{k−1} + p2·u_{k−2} + k0·e_k + k1·e_{k−1} + k2·e_{k−2}.

    `terms` are the increments of the three branches of eq. 05-3 (P, trapezoidal I, filtered
    D); in linear operation without `applied` they add up to u_k − u_{k−1}.
    """

    __slots__ = (
        "_ci",
        "_d1",
        "_e1",
        "_e2",
        "_half_ci",
        "_k0",
        "_k1",
        "_k2",
        "_kc",
        "_kdd",
        "_p1",
        "_p2",
        "_u2",
    )

    def __init__(self, params: Params) -> None:
        super().__init__(params)
        kc, ti, td, ts = params.kc, params.ti, params.td, params.ts
        gamma = params.tf if params.tf > 0.0 else 0.5 * ts
        inv_ti = 1.0 / ti if ti > 0.0 else 0.0
        alpha = ts + 2.0 * gamma
        # eq. 06, with 1/Ti = 0 when there is no integral
        self._k0 = kc * (1.0 + ts * inv_ti / 2.0 + 2.0 * td / alpha)
        self._k1 = kc * (ts * ts * inv_ti - 4.0 * gamma - 4.0 * td) / alpha
        self._k2 = (
            kc
            * (2.0 * gamma - ts + ts * ts * inv_ti / 2.0 - gamma * ts * inv_ti + 2.0 * td)
            / alpha
        )
        self._p1 = 4.0 * gamma / alpha
        self._p2 = (ts - 2.0 * gamma) / alpha
        self._kc = kc
        self._ci = kc * ts * inv_ti
        self._half_ci = 0.5 * self._ci
        self._kdd = 2.0 * kc * td / alpha
        self._e1 = self._e2 = self._u2 = self._d1 = 0.0

    def _prime(self, sp: float, pv0: float) -> None:
        self._e1 = self._e2 = sp - pv0
        self._u2 = self._output - self._ci * self._e1
        self._d1 = 0.0

    def _advance(self, sp: float, pv: float, previous: float) -> float:
        e = sp - pv
        e1 = self._e1
        v = (
            self._p1 * previous
            + self._p2 * self._u2
            + self._k0 * e
            + self._k1 * e1
            + self._k2 * self._e2
        )
        d = self._kdd * (e - e1) - self._p2 * self._d1
        self._terms = (self._kc * (e - e1), self._half_ci * (e + e1), d - self._d1)
        self._d1 = d
        self._e2 = e1
        self._e1 = e
        self._u2 = previous
        return v


class _TypeAFiltered(_Base):
    """Eq. 11c + 12: velocity form, D on the low-pass filtered error."""

    __slots__ = ("_ci", "_e1", "_fa", "_fb", "_filtered", "_kc", "_kd", "_lpf1", "_lpf2")

    def __init__(self, params: Params) -> None:
        super().__init__(params)
        self._kc = params.kc
        self._ci = params.kc * params.ts / params.ti if params.ti > 0.0 else 0.0
        self._kd = params.kc * params.td / params.ts
        self._filtered = params.tf > 0.0
        self._fa, self._fb = _lowpass(params.tf, params.ts)
        self._e1 = self._lpf1 = self._lpf2 = 0.0

    def _prime(self, sp: float, pv0: float) -> None:
        self._e1 = self._lpf1 = self._lpf2 = sp - pv0

    def _advance(self, sp: float, pv: float, previous: float) -> float:
        e = sp - pv
        e1 = self._e1
        lpf1 = self._lpf1
        lpf = self._fa * lpf1 + self._fb * (e + e1) if self._filtered else e
        p = self._kc * (e - e1)
        i = self._ci * e
        d = self._kd * (lpf - 2.0 * lpf1 + self._lpf2)
        self._terms = (p, i, d)
        self._e1 = e
        self._lpf2 = lpf1
        self._lpf1 = lpf
        return previous + p + i + d


class _Takahashi(_Base):
    """Eq. 14 (type C): P and D on PV, I on the error; D optionally on eq. 11c-filtered PV."""

    __slots__ = ("_ci", "_f1", "_f2", "_fa", "_fb", "_filtered", "_kc", "_kd", "_pv1")

    def __init__(self, params: Params) -> None:
        super().__init__(params)
        self._kc = params.kc
        self._ci = params.kc * params.ts / params.ti
        self._kd = params.kc * params.td / params.ts
        self._filtered = params.tf > 0.0
        self._fa, self._fb = _lowpass(params.tf, params.ts)
        self._pv1 = self._f1 = self._f2 = 0.0

    def _prime(self, sp: float, pv0: float) -> None:
        self._pv1 = self._f1 = self._f2 = pv0

    def _advance(self, sp: float, pv: float, previous: float) -> float:
        pv1 = self._pv1
        f1 = self._f1
        f = self._fa * f1 + self._fb * (pv + pv1) if self._filtered else pv
        p = self._kc * (pv1 - pv)
        i = self._ci * (sp - pv)
        d = self._kd * (2.0 * f1 - f - self._f2)
        self._terms = (p, i, d)
        self._pv1 = pv
        self._f2 = f1
        self._f1 = f
        return previous + p + i + d


class _BackCalculation(_Base):
    """Positional PID with back-calculation anti-windup; `terms` are (P_k, I_k, D_k).

    The integral update of period k needs that period's actual output, which arrives with
    the next step: so each step first completes the previous period's update.
    """

    __slots__ = (
        "_e",
        "_f1",
        "_fa",
        "_fb",
        "_filtered",
        "_i",
        "_kc",
        "_kd",
        "_ki",
        "_kt",
        "_pv1",
        "_v",
    )

    def __init__(self, params: Params) -> None:
        super().__init__(params)
        self._kc = params.kc
        self._ki = params.kc * params.ts / params.ti if params.ti > 0.0 else 0.0
        self._kt = params.ts / params.tt if params.tt is not None else 0.0
        self._kd = params.kc * params.td / params.ts
        self._filtered = params.tf > 0.0
        self._fa, self._fb = _lowpass(params.tf, params.ts)
        self._e = self._v = self._i = self._f1 = self._pv1 = 0.0

    def _prime(self, sp: float, pv0: float) -> None:
        # the pending update becomes exactly zero: no error yet, and v equals the start output
        self._pv1 = self._f1 = pv0
        self._i = self._output - self._kc * (sp - pv0)
        self._e = 0.0
        self._v = self._output

    def _advance(self, sp: float, pv: float, previous: float) -> float:
        i = self._i + self._ki * self._e + self._kt * (previous - self._v)
        f1 = self._f1
        f = self._fa * f1 + self._fb * (pv + self._pv1) if self._filtered else pv
        e = sp - pv
        p = self._kc * e
        d = -self._kd * (f - f1)
        v = p + i + d
        self._terms = (p, i, d)
        self._i = i
        self._e = e
        self._v = v
        self._pv1 = pv
        self._f1 = f
        return v


def table1(
    K: float, tau: float, theta: float, a_star: float
) -> dict[str, tuple[float, float, float]]:
    """(kc, ti, td) of every Table 1 rule, by name; td = 0 for the PI rules.

    K: process gain [°C/%], tau: time constant [s], theta: dead time [s], a_star: normalised
    slope of the open-loop step response [°C/(%·s)]. Kc comes out in %/°C, Ti and Td in s.
    """
    gain = _number("K", K, math.ulp(0.0), _INF, "> 0 °C/% and finite")
    tau = _number("tau", tau, math.ulp(0.0), _INF, "> 0 s and finite")
    theta = _number("theta", theta, math.ulp(0.0), _INF, "> 0 s and finite")
    slope = _number("a_star", a_star, math.ulp(0.0), _INF, "> 0 °C/(%·s) and finite")
    ratio = theta / tau
    process = tau / (gain * theta)
    return {
        "zn_open_pid": (1.2 / (theta * slope), 2.0 * theta, 0.5 * theta),
        "zn_open_pi": (0.9 / (theta * slope), 3.33 * theta, 0.0),
        "zn_closed_pid": (1.2 * process, 2.0 * theta, 0.5 * theta),
        "zn_closed_pi": (0.9 * process, 3.33 * theta, 0.0),
        "cohen_coon_pid": (
            process * (theta / (4.0 * tau) + 4.0 / 3.0),
            theta * (32.0 * tau + 6.0 * theta) / (13.0 * tau + 8.0 * theta),
            theta * 4.0 * tau / (2.0 * theta + 11.0 * tau),
        ),
        "cohen_coon_pi": (
            process * (theta / (12.0 * tau) + 9.0 / 10.0),
            theta * (30.0 * tau + 3.0 * theta) / (9.0 * tau + 20.0 * theta),
            0.0,
        ),
        "itae_load_pid": (
            1.357 / gain * ratio**-0.947,
            tau / 0.842 * ratio**0.738,
            0.381 * tau * ratio**0.995,
        ),
        "itae_load_pi": (0.859 / gain * ratio**-0.977, tau / 0.674 * ratio**0.680, 0.0),
    }
