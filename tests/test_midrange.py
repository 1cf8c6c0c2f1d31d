"""The mid-ranging controller against the two processes of the anti-windup seed.

Golden values come from the seed's equations and numbers, built here by hand: the process
matrices (bio-reactor eqs. 3-4; cooling system eq. 19 in observable canonical form), the
continuous closed loop, and a continuous simulation by RK4 of the seed's equations 6-8, 15-16.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import math
import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import pytest

from hermsd.control import linsys, midrange

Plant = tuple[list[list[float]], list[list[float]], list[float]]

BIO: Plant = ([[-2400.0, -5200.0], [0.0, -15.0]], [[210.0, 0.0], [0.0, 15.0]], [1.0, 0.0])
BIO_SETTINGS = {"k1": 10.0, "ti1": 1.0 / 120.0, "k2": 0.02, "ti2": 10.0 / 120.0}
BIO_LIMITS = {"u1_ref": 0.98 * 1200.0, "u1_min": 0.0, "u1_max": 1200.0}

# eq. 19: d = (s + 0.016)(s + 0.017)(s + 1.1), n1 = −7.8(s + 0.14)(s + 0.036),
# n2 = −1.1(s + 1.9)(s + 0.14), expanded by hand
_D = (1.133, 0.016 * 0.017 + 0.016 * 1.1 + 0.017 * 1.1, 0.016 * 0.017 * 1.1)
_N1 = (-7.8, -7.8 * (0.14 + 0.036), -7.8 * 0.14 * 0.036)
_N2 = (-1.1, -1.1 * (1.9 + 0.14), -1.1 * 1.9 * 0.14)
COOLING: Plant = (
    [[-_D[0], 1.0, 0.0], [-_D[1], 0.0, 1.0], [-_D[2], 0.0, 0.0]],
    [[_N1[0], _N2[0]], [_N1[1], _N2[1]], [_N1[2], _N2[2]]],
    [1.0, 0.0, 0.0],
)
COOLING_SETTINGS = {"k1": -0.03, "ti1": 1.0, "k2": -0.05, "ti2": 30.0}
COOLING_LIMITS = {"u1_ref": 0.0, "u1_min": -0.5, "u1_max": 0.5}

CASES = {
    "bio": (BIO, BIO_SETTINGS, BIO_LIMITS),
    "cooling": (COOLING, COOLING_SETTINGS, COOLING_LIMITS),
}


def _bench() -> ModuleType:
    """bench/midrange.py, whose linearisation of the implementation's loop is tested here."""
    path = Path(__file__).parents[1] / "bench" / "midrange.py"
    spec = importlib.util.spec_from_file_location("bench_midrange", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while being built
    spec.loader.exec_module(module)
    return module


BENCH = _bench()


def _continuous_closed_loop(name: str) -> list[list[float]]:
    """States (x, I1, I2) in deviations, r = 0: u1 = −K1·C·x + I1, u2 = −K2·u1 + I2."""
    (a, b, c), s, _ = CASES[name]
    n = len(a)
    u1 = [-s["k1"] * ci for ci in c] + [1.0, 0.0]
    u2 = [-s["k2"] * v for v in u1]
    u2[n + 1] += 1.0
    rows = [
        [(a[i][j] if j < n else 0.0) + b[i][0] * u1[j] + b[i][1] * u2[j] for j in range(n + 2)]
        for i in range(n)
    ]
    rows.append([-s["k1"] / s["ti1"] * ci for ci in c] + [0.0, 0.0])
    rows.append([-s["k2"] / s["ti2"] * v for v in u1])
    return rows


# ------------------------------------------------------------------ the numeric helpers


def test_expm_and_zoh_match_closed_forms() -> None:
    rotation = linsys.expm([[0.0, 2.0], [-2.0, 0.0]])
    assert rotation[0][0] == pytest.approx(math.cos(2.0), abs=1e-14)
    assert rotation[0][1] == pytest.approx(math.sin(2.0), abs=1e-14)
    # x' = −a·x + b·u held: Ad = e^(−a·h), Bd = b·(1 − e^(−a·h))/a, even for a·h ≫ 1
    for a, h in ((3.0, 0.1), (2400.0, 0.01)):
        ad, bd = linsys.zoh([[-a]], [[5.0]], h)
        assert ad[0][0] == pytest.approx(math.exp(-a * h), rel=1e-12, abs=1e-300)
        assert bd[0][0] == pytest.approx(5.0 * (1.0 - math.exp(-a * h)) / a, rel=1e-12)


def test_solve_complex_system() -> None:
    # right-hand sides built from x = 1, y = 1 − j
    x, y = linsys.solve([[1 + 1j, 2.0], [1.0, -1j]], [1 + 1j + 2 * (1 - 1j), 1 - 1j * (1 - 1j)])
    assert x == pytest.approx(1.0, abs=1e-15)
    assert y == pytest.approx(1 - 1j, abs=1e-15)
    with pytest.raises(ValueError, match="singular"):
        linsys.solve([[1.0, 2.0], [2.0, 4.0]], [1.0, 2.0])


def test_roots_and_characteristic_polynomial() -> None:
    # (s + 1)(s + 2)(s² + 2s + 5): roots −1, −2, −1 ± 2j
    p = linsys.poly_mul(linsys.poly_mul([1.0, 1.0], [1.0, 2.0]), [1.0, 2.0, 5.0])
    roots = linsys.poly_roots(p)
    for expected in (-2.0, -1.0 - 2j, -1.0 + 2j, -1.0):
        assert min(abs(z - expected) for z in roots) < 1e-12
    assert linsys.char_poly([[1.0, 2.0], [3.0, 4.0]]) == pytest.approx([1.0, -5.0, -2.0])


# ------------------------------------------------------------------ poles


@pytest.mark.parametrize(("name", "h"), [("bio", 1e-6), ("cooling", 1e-3)])
def test_closed_loop_poles_match_the_state_space(name: str, h: float) -> None:
    """The poles of the implementation's discrete loop (the controller under test and the
    exactly sampled process, linearised column by column through reset/step/terms; the
    bench's function, so its table is checked too) against the state space built here."""
    process = BENCH.BIO if name == "bio" else BENCH.COOLING
    continuous = linsys.eigenvalues(_continuous_closed_loop(name))
    coarse = BENCH.implementation_poles(process, 4.0 * h)
    fine = BENCH.implementation_poles(process, h)
    for p in continuous:
        error_coarse = min(abs(z - p) for z in coarse) / abs(p)
        error_fine = min(abs(z - p) for z in fine) / abs(p)
        assert error_fine < 2e-3, (name, p, fine)
        # first order in h (forward Euler): a quarter of h, about a quarter of the error
        assert error_fine < 0.3 * error_coarse + 1e-9, (p, error_coarse, error_fine)


def test_bio_poles_are_the_roots_of_the_transfer_function_loop() -> None:
    """1 + C1·G3 − C1·G3·G2·C2 = 0 multiplied out by hand, against the state space."""
    k1, ti1, k2, ti2 = (BIO_SETTINGS[k] for k in ("k1", "ti1", "k2", "ti2"))
    plant = linsys.poly_mul([1.0, 2400.0], [1.0, 15.0])
    c1_num = [k1 * ti1, k1]
    c2_num = [k2 * ti2, k2]
    poly = linsys.poly_add(
        linsys.poly_add(
            linsys.poly_mul([ti1 * ti2, 0.0, 0.0], plant),
            linsys.poly_mul(linsys.poly_mul(c1_num, [210.0 * ti2, 0.0]), [1.0, 15.0]),
        ),
        linsys.poly_mul(linsys.poly_mul(c1_num, c2_num), [5200.0 * 15.0]),
    )
    expected = linsys.poly_roots(poly)
    for p in linsys.eigenvalues(_continuous_closed_loop("bio")):
        assert min(abs(z - p) for z in expected) < 1e-8 * abs(p)


def _r_to_u2(name: str, s: complex, tt: float | None, ks: float = 0.0) -> complex:
    """r → u2 of the linear loop built here: nominal (tt None) or u1 held at a limit.

    States (x, I1, I2) in deviations; v1 = K1·(r − C·x) + I1. Nominal: u1 = v1, u2 = −K2·v1 +
    I2. Held: the constant limit drops out, İ1 gains −v1/Tt, C2 sees (1 + Ks)·v1 (eq. 15).
    """
    (a, b, c), p, _ = CASES[name]
    n = len(a)
    k1, k2 = p["k1"], p["k2"]
    # v1 = row·z + k1·r
    v1 = [-k1 * ci for ci in c] + [1.0, 0.0]
    gain = 1.0 if tt is None else 1.0 + ks
    u2 = [-k2 * gain * v for v in v1]
    u2[n + 1] += 1.0
    u2_r = -k2 * gain * k1
    u1_on = 1.0 if tt is None else 0.0
    leak = 0.0 if tt is None or math.isinf(tt) else 1.0 / tt
    rows = [
        [
            (a[i][j] if j < n else 0.0) + b[i][0] * u1_on * v1[j] + b[i][1] * u2[j]
            for j in range(n + 2)
        ]
        for i in range(n)
    ]
    rows.append([-k1 / p["ti1"] * ci for ci in c] + [0.0, 0.0])
    rows[n] = [x - leak * v for x, v in zip(rows[n], v1, strict=True)]
    rows.append([-k2 / p["ti2"] * gain * v for v in v1])
    column = [b[i][0] * u1_on * k1 + b[i][1] * u2_r for i in range(n)]
    column += [k1 / p["ti1"] - leak * k1, -k2 / p["ti2"] * gain * k1]
    shifted = [[(s if i == j else 0.0) - rows[i][j] for j in range(n + 2)] for i in range(n + 2)]
    z = linsys.solve(shifted, column)
    return sum(u * zi for u, zi in zip(u2, z, strict=True)) + u2_r


@pytest.mark.parametrize("name", ["bio", "cooling"])
def test_the_bode_comparison_uses_the_loops_own_transfer_functions(name: str) -> None:
    """The bench's eq. 5, eq. 14 and eq. 17 (with G3·G2, as derived) against the state
    spaces built here, over four decades about each fast loop's crossover."""
    process = BENCH.BIO if name == "bio" else BENCH.COOLING
    crossover = 213.3 if name == "bio" else 0.2472
    ti1 = CASES[name][1]["ti1"]
    for w in (crossover * 10.0**k for k in (-2, -1, 0, 1, 2)):
        s = 1j * w
        assert BENCH.g_nom(process, s) == pytest.approx(_r_to_u2(name, s, None), rel=1e-9)
        for tt, ks in ((ti1 / 3, 0.0), (4 * ti1, 0.0), (math.inf, 0.0), (ti1, 3.0), (ti1, 60.0)):
            expected = _r_to_u2(name, s, tt, ks)
            assert BENCH.g_sat(process, s, tt, ks) == pytest.approx(expected, rel=1e-9)


# ------------------------------------------------------------------ continuous reference


def _rk4_reference(
    name: str, r: float, tt1: float, ks: float, t_end: float, dt: float, every: int
) -> list[float]:
    """y at every `every`·dt of the seed's continuous loop (eqs. 6-8, 15-16), RK4 step dt."""
    (a, b, c), s, limits = CASES[name]
    n = len(a)
    lo, hi = limits["u1_min"] - limits["u1_ref"], limits["u1_max"] - limits["u1_ref"]

    def derivative(z: list[float]) -> list[float]:
        x, i1, i2 = z[:n], z[n], z[n + 1]
        e = r - sum(ci * xi for ci, xi in zip(c, x, strict=True))
        v1 = s["k1"] * e + i1
        u1 = min(max(v1, lo), hi)
        e2 = -(v1 + ks * (v1 - u1))
        u2 = s["k2"] * e2 + i2
        dx = [sum(a[i][k] * x[k] for k in range(n)) + b[i][0] * u1 + b[i][1] * u2 for i in range(n)]
        return [*dx, s["k1"] / s["ti1"] * e + (u1 - v1) / tt1, s["k2"] / s["ti2"] * e2]

    def moved(z: list[float], d: list[float], f: float) -> list[float]:
        return [zi + f * di for zi, di in zip(z, d, strict=True)]

    z = [0.0] * (n + 2)
    ys = [0.0]
    for k in range(1, round(t_end / dt) + 1):
        d1 = derivative(z)
        d2 = derivative(moved(z, d1, dt / 2))
        d3 = derivative(moved(z, d2, dt / 2))
        d4 = derivative(moved(z, d3, dt))
        z = [
            zi + dt / 6 * (p + 2 * q + 2 * u + w)
            for zi, p, q, u, w in zip(z, d1, d2, d3, d4, strict=True)
        ]
        if k % every == 0:
            ys.append(sum(ci * xi for ci, xi in zip(c, z[:n], strict=True)))
    return ys


def _discrete(name: str, r: float, tt1: float, ks: float, t_end: float, h: float) -> list[float]:
    (a, b, c), s, limits = CASES[name]
    ad, bd = linsys.zoh(a, b, h)
    controller = midrange.create(**s, **limits, h=h, tt1=tt1, ks=ks)
    controller.reset(0.0, limits["u1_ref"], 0.0)
    controller.step(0.0, 0.0)  # at rest at the operating point; then the step
    x = [0.0] * len(a)
    ys = [0.0]
    for _ in range(round(t_end / h)):
        u1, u2 = controller.step(r, ys[-1])
        du1 = u1 - limits["u1_ref"]
        x = [
            sum(ad[i][k] * x[k] for k in range(len(a))) + bd[i][0] * du1 + bd[i][1] * u2
            for i in range(len(a))
        ]
        ys.append(sum(ci * xi for ci, xi in zip(c, x, strict=True)))
    return ys


@pytest.mark.parametrize(
    ("name", "r", "tt1", "ks", "t_end", "dt", "h", "tolerance"),
    [
        # the seed's modified scheme in both examples; u1 saturates in both
        ("bio", 5.0, 1.0 / 120.0, 3.0, 0.2, 2.5e-6, 4e-5, 0.002),
        ("cooling", 10.0, 0.5, 60.0, 60.0, 2.5e-3, 0.02, 0.02),
    ],
)
def test_discrete_loop_tracks_the_continuous_one(
    name: str, r: float, tt1: float, ks: float, t_end: float, dt: float, h: float, tolerance: float
) -> None:
    """Within `tolerance` (in y's units: 0.04 % and 0.2 % of the step) at h, and first-order
    convergence: h/4 comes about four times closer (the RK4 reference's own error, at a
    step 16 and 8 times smaller, is far below both)."""
    every = round(h / 4 / dt)
    reference = _rk4_reference(name, r, tt1, ks, t_end, dt, every)
    coarse = _discrete(name, r, tt1, ks, t_end, h)
    fine = _discrete(name, r, tt1, ks, t_end, h / 4)
    error_coarse = max(abs(y - reference[4 * k]) for k, y in enumerate(coarse))
    error_fine = max(abs(y - reference[k]) for k, y in enumerate(fine))
    assert error_coarse < tolerance
    assert error_fine < 0.35 * error_coarse
    assert max(coarse) > 0.9 * r  # a real step response, not a flat line


# ------------------------------------------------------------------ bumpless transfer


def _cooling_controller(**overrides: float) -> midrange.MidRange:
    kwargs: dict[str, float] = {**COOLING_SETTINGS, **COOLING_LIMITS, "h": 0.05, "tt1": 0.5}
    kwargs.update(overrides)
    return midrange.create(**kwargs)


def test_reset_continues_from_the_given_outputs() -> None:
    controller = _cooling_controller(ks=60.0)
    for _ in range(50):  # run into saturation first
        controller.step(10.0, 0.0)
    assert controller.outputs[0] == -0.5
    controller.reset(3.0, 0.2, -0.01)  # manual → auto at the operator's outputs
    u1, u2 = controller.step(5.0, 3.0)
    assert u1 == pytest.approx(0.2, abs=1e-15)
    assert u2 == pytest.approx(-0.01, abs=1e-15)
    # PV moved by Δ since: the jump is the proportional kick −K1·Δ (+ K2's share), no more
    controller.reset(3.0, 0.2, -0.01)
    u1, u2 = controller.step(5.0, 3.1)
    assert u1 == pytest.approx(0.2 + 0.03 * 0.1, abs=1e-12)
    assert u2 == pytest.approx(-0.01 + 0.05 * 0.03 * 0.1, abs=1e-12)  # −K2·(+0.003)


def test_reset_clamps_and_the_start_is_the_reference() -> None:
    controller = _cooling_controller()
    assert controller.outputs == (0.0, 0.0)
    controller.reset(1.0, 7.0, 0.3)
    assert controller.outputs == (0.5, 0.3)
    assert controller.step(2.0, 1.0)[0] == pytest.approx(0.5, abs=1e-15)


def test_manual_outputs_are_tracked_so_auto_resumes_bumplessly() -> None:
    """Fed the operator's outputs as `applied`, the integral tracks them: the unlimited C1
    output settles where I's update vanishes, v1 = m1 + K1·Tt/Ti1·e (by hand from
    I_{k+1} = I_k + K1·h/Ti1·e + h/Tt·(m1 − v1))."""
    controller = _cooling_controller(tt1=2.0, h=0.1)
    m1, m2, sp, pv = 0.1, -0.02, 4.0, 3.5
    controller.reset(pv, m1, m2)
    for _ in range(400):  # 40 s = 20 Tt
        controller.step(sp, pv, applied=(m1, m2))
    p1, i1, _, _ = controller.terms
    assert p1 + i1 == pytest.approx(m1 + (-0.03) * 2.0 / 1.0 * (sp - pv), abs=1e-9)
    # at e = 0 the tracking is exact: auto resumes at the manual output
    for _ in range(400):
        controller.step(pv, pv, applied=(m1, m2))
    assert controller.step(pv, pv)[0] == pytest.approx(m1, abs=1e-9)


# ------------------------------------------------------------------ Ks = 0 is the standard


def _standard(
    k1: float, ti1: float, tt1: float, k2: float, ti2: float, h: float, lo: float, hi: float
) -> Callable[[float, float], tuple[float, float]]:
    """The standard scheme written out: C1 PI with tracking, C2 PI on u1_ref − v1."""
    state = {"i1": 0.0, "i2": 0.0, "e1": 0.0, "e2": 0.0, "v1": 0.0, "u1": 0.0}
    bi1, bi2, ar1 = k1 * h / ti1, k2 * h / ti2, h / tt1

    def step(sp: float, pv: float) -> tuple[float, float]:
        i1 = state["i1"] + bi1 * state["e1"] + ar1 * (state["u1"] - state["v1"])
        i2 = state["i2"] + bi2 * state["e2"] + 0.0
        e1 = sp - pv
        v1 = k1 * e1 + i1
        u1 = min(max(v1, lo), hi)
        e2 = 0.0 - v1
        u2 = k2 * e2 + i2
        state.update(i1=i1, i2=i2, e1=e1, e2=e2, v1=v1, u1=u1)
        return u1, u2

    return step


def test_ks_zero_is_the_standard_scheme_bit_for_bit() -> None:
    (a, b, _), s, _ = CASES["cooling"]
    h = 0.05
    ad, bd = linsys.zoh(a, b, h)
    reference = _standard(s["k1"], s["ti1"], 0.5, s["k2"], s["ti2"], h, -0.5, 0.5)
    controllers = [_cooling_controller(h=h, ks=ks) for ks in (0.0, 60.0)]
    xs = [[0.0] * 3 for _ in range(3)]
    assert reference(0.0, 0.0) == (0.0, 0.0)  # all at rest before the steps
    assert all(ctrl.step(0.0, 0.0) == (0.0, 0.0) for ctrl in controllers)
    saturated = 0
    for k in range(2000):
        r = 10.0 if k < 1000 else -5.0
        outs = [reference(r, xs[0][0])] + [
            ctrl.step(r, x[0]) for ctrl, x in zip(controllers, xs[1:], strict=True)
        ]
        assert outs[1] == outs[0]  # exact equality, every period
        saturated += abs(outs[0][0]) == 0.5
        xs = [
            [
                sum(ad[i][j] * x[j] for j in range(3)) + bd[i][0] * u1 + bd[i][1] * u2
                for i in range(3)
            ]
            for x, (u1, u2) in zip(xs, outs, strict=True)
        ]
    assert saturated > 100
    assert xs[2] != xs[0]  # Ks = 60 did act while saturated: the comparison can fail


def test_ks_acts_only_while_saturated() -> None:
    standard, modified = _cooling_controller(ks=0.0), _cooling_controller(ks=60.0)
    for pv in (0.0, 0.5, 1.0, 0.7):  # small errors: u1 stays inside ±0.5
        assert standard.step(1.0, pv) == modified.step(1.0, pv)


# ------------------------------------------------------------------ parameter checks


@pytest.mark.parametrize(
    ("change", "named"),
    [
        ({"k1": 0.0}, "k1="),
        ({"ti2": -1.0}, "ti2="),
        ({"h": math.nan}, "h="),
        ({"tt1": 0.01}, "tt1="),  # below h: the tracking would overshoot every period
        ({"ks": -1.0}, "ks="),
        ({"u1_ref": 0.5}, "u1_ref="),
        ({"u1_min": 1.0}, "u1_min="),
    ],
)
def test_bad_parameters_are_named(change: dict[str, float], named: str) -> None:
    with pytest.raises(ValueError, match=named):
        _cooling_controller(**change)


def test_bad_inputs_are_named() -> None:
    controller = _cooling_controller()
    with pytest.raises(ValueError, match="pv="):
        controller.step(1.0, math.inf)
    controller.step(1.0, 0.0)
    with pytest.raises(ValueError, match="applied u2="):
        controller.step(1.0, 0.0, applied=(0.0, math.nan))


# ------------------------------------------------------------------ the bench's claims table


def _sweep(best_at: dict[float, float]) -> dict[float, dict[float, tuple[float, ...]]]:
    """A made-up J sweep of the cooling system: at each step the least J (every horizon) at
    the Ks `best_at` names, J 1 there, 2 and 3 at the other two Ks."""
    grid = (0.0, 30.0, 60.0)
    return {
        step: {ks: (1.0,) * 3 if ks == best else (2.0 + grid.index(ks) % 2,) * 3 for ks in grid}
        for step, best in best_at.items()
    }


def test_a_ks_minimum_at_another_step_than_the_seeds_is_not_reproduced() -> None:
    """The seed states r = 10 °C for the cooling system: a least J at Ks = 60 with a step of
    20 is shown, but the claim is judged at r = 10, where it lies at Ks = 30."""
    status, evidence = BENCH.ks_minimum_claim(
        BENCH.COOLING, _sweep({5.0: 0.0, 10.0: 30.0, 20.0: 60.0})
    )
    assert status == "not reproduced"
    assert "least J at Ks = 30" in evidence
    assert "step 20, tf = 100 s" in evidence  # the rest of the sweep, shown


def test_a_ks_minimum_at_the_seeds_step_is_reproduced() -> None:
    status, evidence = BENCH.ks_minimum_claim(
        BENCH.COOLING, _sweep({5.0: 0.0, 10.0: 60.0, 20.0: 30.0})
    )
    assert status == "reproduced"
    assert "least J at Ks = 60" in evidence


def test_the_bench_cannot_judge_the_cooling_system_off_the_seeds_step() -> None:
    with pytest.raises(ValueError, match="the seed's step r = 10"):
        dataclasses.replace(BENCH.COOLING, step=20.0)
