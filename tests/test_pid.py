"""The PID controllers against their equations, and the behaviour a brewer relies on.

The reference implementations below are written from the equations of the HERMS PID calculus
document (eq. 05-4 to 14), the windup/bumpless-transfer notes (eq. 3.13) and the tracking
anti-windup formula, not from hermsd.control.pid: the eq. 08 coefficients, for instance, are
expanded here from the polynomial products of eq. 05-4 rather than copied from eq. 06.
"""

from __future__ import annotations

import itertools
import math
import random
from collections.abc import Callable, Sequence

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hermsd.control import laws, pid
from hermsd.control import seed as control_seed

Sample = tuple[float, float, float | None]  # (sp, pv, applied)

TS = 5.0
# Table 2, ITAE-load rows: the document's tuning for this HLT.
ITAE_PID = {"kc": 80.8, "ti": 489.0, "td": 44.9}
ITAE_PI = {"kc": 59.2, "ti": 810.2}
# A gentle tuning: Kc so small that a prompt release after saturation cannot come from a
# big P term; it must come from an integral that did not wind up.
GENTLE_PID = {"kc": 2.0, "ti": 489.0, "td": 44.9}
GENTLE_PI = {"kc": 2.0, "ti": 489.0}
WIDE = {"out_min": -1e12, "out_max": 1e12}


def tuning(name: str, gentle: bool = False) -> dict[str, float]:
    if name == "velocity_pi":
        return dict(GENTLE_PI if gentle else ITAE_PI)
    return dict(GENTLE_PID if gentle else ITAE_PID)


def clamp(value: float, lo: float, hi: float) -> float:
    return min(max(value, lo), hi)


# ---------------------------------------------------------------- reference implementations


def polymul(a: Sequence[float], b: Sequence[float]) -> list[float]:
    """Product of two polynomials in z⁻¹ (coefficient lists, constant term first)."""
    out = [0.0] * (len(a) + len(b) - 1)
    for i, x in enumerate(a):
        for j, y in enumerate(b):
            out[i + j] += x * y
    return out


def eq08_coefficients(
    kc: float, ti: float, td: float, ts: float, gamma: float
) -> tuple[list[float], float, float]:
    """([k0, k1, k2], p1, p2) expanded from eq. 05-4: numerator over (1 − z⁻¹)(1 + p·z⁻¹)."""
    p = (ts - 2 * gamma) / (ts + 2 * gamma)
    integral = ts / (2 * ti) if ti else 0.0
    numerator = [
        a + b + c
        for a, b, c in zip(
            polymul([1, -1], [1, p]),
            [integral * x for x in polymul([1, 1], [1, p])],
            [2 * td / (ts + 2 * gamma) * x for x in polymul([1, -1], [1, -1])],
            strict=True,
        )
    ]
    denominator = polymul([1, -1], [1, p])  # 1 − p1·z⁻¹ − p2·z⁻²
    return [kc * x for x in numerator], -denominator[1], -denominator[2]


def reference_eq08(
    kc: float,
    ti: float,
    td: float,
    ts: float,
    gamma: float,
    samples: Sequence[Sample],
    u_start: float = 0.0,
    lo: float = -1e12,
    hi: float = 1e12,
) -> list[float]:
    """Eq. 08. History from the first sample: e_{-1} = e_{-2} = e_0, u_{-1} = u_start and
    u_{-2} = u_start − Kc·Ts/Ti·e_0 (the ramp eq. 08 follows at a constant error). A given
    `applied` replaces u_{k−1}; the value used becomes u_{k−2} of the next step."""
    (k0, k1, k2), p1, p2 = eq08_coefficients(kc, ti, td, ts, gamma)
    e1 = e2 = samples[0][0] - samples[0][1]
    u1 = u_start
    u2 = u_start - (kc * ts / ti if ti else 0.0) * e1
    out = []
    for index, (sp, pv, applied) in enumerate(samples):
        if index and applied is not None:
            u1 = clamp(applied, lo, hi)
        e = sp - pv
        u = clamp(p1 * u1 + p2 * u2 + k0 * e + k1 * e1 + k2 * e2, lo, hi)
        out.append(u)
        e2, e1 = e1, e
        u2, u1 = u1, u
    return out


def reference_eq12(
    kc: float,
    ti: float,
    td: float,
    ts: float,
    gamma: float,
    samples: Sequence[Sample],
    u_start: float = 0.0,
    lo: float = -1e12,
    hi: float = 1e12,
) -> list[float]:
    """Eq. 11c + 12; γ = 0 means lpf = e. History: e and lpf start at e_0, u at u_start."""
    e1 = lpf1 = lpf2 = samples[0][0] - samples[0][1]
    u1 = u_start
    out = []
    for index, (sp, pv, applied) in enumerate(samples):
        if index and applied is not None:
            u1 = clamp(applied, lo, hi)
        e = sp - pv
        if gamma:
            lpf = (2 * gamma - ts) / (2 * gamma + ts) * lpf1 + ts / (ts + 2 * gamma) * (e + e1)
        else:
            lpf = e
        integral = ts * e / ti if ti else 0.0
        u = u1 + kc * ((e - e1) + integral + td / ts * (lpf - 2 * lpf1 + lpf2))
        u1 = clamp(u, lo, hi)
        out.append(u1)
        e1, lpf2, lpf1 = e, lpf1, lpf
    return out


def reference_eq14(
    kc: float,
    ti: float,
    td: float,
    ts: float,
    gamma: float,
    samples: Sequence[Sample],
    u_start: float = 0.0,
    lo: float = -1e12,
    hi: float = 1e12,
) -> list[float]:
    """Eq. 14; with γ > 0 the D term's PV histories come from the eq. 11c filter of PV."""
    x1 = f1 = f2 = samples[0][1]
    u1 = u_start
    out = []
    for index, (sp, pv, applied) in enumerate(samples):
        if index and applied is not None:
            u1 = clamp(applied, lo, hi)
        if gamma:
            f = (2 * gamma - ts) / (2 * gamma + ts) * f1 + ts / (ts + 2 * gamma) * (pv + x1)
        else:
            f = pv
        e = sp - pv
        u = u1 + kc * ((x1 - pv) + ts * e / ti + td / ts * (2 * f1 - f - f2))
        u1 = clamp(u, lo, hi)
        out.append(u1)
        x1, f2, f1 = pv, f1, f
    return out


def reference_velocity_pi(
    kp: float, ki: float, dt: float, samples: Sequence[Sample], lo: float, hi: float
) -> list[float]:
    """Eq. 3.13/3.14 of the bumpless-transfer notes, with the field-measured MV (type 2)."""
    mv = clamp(0.0, lo, hi)
    pv_prev = samples[0][1]
    out = []
    for index, (sp, pv, applied) in enumerate(samples):
        if index and applied is not None:
            mv = clamp(applied, lo, hi)
        mv = clamp(mv + kp * (-pv + pv_prev) + dt * ki * (sp - pv), lo, hi)
        out.append(mv)
        pv_prev = pv
    return out


def reference_back_calculation(
    kc: float,
    ti: float,
    td: float,
    ts: float,
    tt: float,
    samples: Sequence[Sample],
    lo: float,
    hi: float,
) -> list[float]:
    """v_k = Kc·e_k + I_k − Kc·Td/Ts·(pv_k − pv_{k−1}), u_k = clamp(v_k),
    I_{k+1} = I_k + Kc·Ts/Ti·e_k + Ts/Tt·(u_actual,k − v_k), u_actual = applied or u_k.
    Starts at u = clamp(0): I_0 = clamp(0) − Kc·e_0, pv_{−1} = pv_0."""
    sp0, pv0, _ = samples[0]
    integral = clamp(0.0, lo, hi) - kc * (sp0 - pv0)
    pv1 = pv0
    out: list[float] = []
    e_prev = v_prev = u_prev = 0.0
    for index, (sp, pv, applied) in enumerate(samples):
        if index:
            actual = u_prev if applied is None else clamp(applied, lo, hi)
            integral += kc * ts / ti * e_prev + ts / tt * (actual - v_prev)
        e = sp - pv
        v = kc * e + integral - kc * td / ts * (pv - pv1)
        u = clamp(v, lo, hi)
        out.append(u)
        e_prev, v_prev, u_prev, pv1 = e, v, u, pv
    return out


def brewing_samples(seed: int, count: int = 4000, applied: bool = False) -> list[Sample]:
    """A wandering setpoint and a noisy PV, half of it quantised to the LM92's 0.0625 °C."""
    rng = random.Random(seed)
    sp, pv = 66.0, 40.0
    samples: list[Sample] = []
    for _ in range(count):
        if rng.random() < 0.01:
            sp = rng.uniform(20.0, 80.0)
        pv += rng.gauss(0.0, 0.3)
        if rng.random() < 0.005:
            pv += rng.uniform(-5.0, 5.0)
        measured = round(pv / 0.0625) * 0.0625 if rng.random() < 0.5 else pv
        delivered = rng.uniform(-10.0, 110.0) if applied and rng.random() < 0.7 else None
        samples.append((sp, measured, delivered))
    return samples


def run(controller: pid.Controller, samples: Sequence[Sample]) -> list[float]:
    return [controller.step(sp, pv, applied) for sp, pv, applied in samples]


def assert_matches(actual: Sequence[float], expected: Sequence[float]) -> None:
    """Equal to float rounding: relative 1e-9 of the sequence's scale."""
    assert len(actual) == len(expected)
    scale = max(1.0, *(abs(x) for x in expected))
    worst = max(abs(a - b) for a, b in zip(actual, expected, strict=True))
    assert worst <= 1e-9 * scale, f"worst deviation {worst} at scale {scale}"


# ------------------------------------------------------------------------------ exactness


@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize(
    "gains",
    [ITAE_PID, {"kc": 3.0, "ti": 120.0, "td": 200.0}, {"kc": 40.0, "ti": 0.0, "td": 30.0}],
)
def test_type_a_is_eq08(seed: int, gains: dict[str, float]) -> None:
    samples = brewing_samples(seed)
    gamma = 0.1 * gains["td"]
    controller = laws.create("type_a", ts=TS, tf=gamma, **gains, **WIDE)
    assert_matches(
        run(controller, samples), reference_eq08(ts=TS, gamma=gamma, samples=samples, **gains)
    )


def test_type_a_default_filter_is_eq08_with_the_default_gamma() -> None:
    # In the linear range the default owes nothing: eq. 08 exactly, at γ = default_tf.
    samples = brewing_samples(4)
    controller = laws.create("type_a", ts=TS, **ITAE_PID, **WIDE)
    gamma = pid.default_tf(ITAE_PID["kc"], ITAE_PID["td"])
    expected = reference_eq08(ts=TS, gamma=gamma, samples=samples, **ITAE_PID)
    assert_matches(run(controller, samples), expected)


def test_type_a_without_filter_is_the_backward_difference() -> None:
    """tf = 0: eq. 08 at γ = Ts/2, which by hand is the velocity form u_k = u_{k−1} +
    Kc·[(e_k − e_{k−1}) + Ts/(2Ti)·(e_k + e_{k−1}) + Td/Ts·(e_k − 2e_{k−1} + e_{k−2})]."""
    samples = brewing_samples(5)
    kc, ti, td = ITAE_PID["kc"], ITAE_PID["ti"], ITAE_PID["td"]
    e1 = e2 = samples[0][0] - samples[0][1]
    u = 0.0
    expected = []
    for sp, pv, _ in samples:
        e = sp - pv
        u += kc * ((e - e1) + TS / (2 * ti) * (e + e1) + td / TS * (e - 2 * e1 + e2))
        expected.append(u)
        e2, e1 = e1, e
    controller = laws.create("type_a", ts=TS, tf=0.0, **ITAE_PID, **WIDE)
    assert_matches(run(controller, samples), expected)


def test_type_a_uses_eq06_k2_not_the_listing() -> None:
    """At a constant error eq. 08 ramps by Kc·Ts/Ti·e per period (hand: the steady ramp c of
    u_k − p1·u_{k−1} − p2·u_{k−2} = (k0+k1+k2)·e is c = (k0+k1+k2)·e·(Ts+2γ)/(2Ts), and with
    eq. 06 k0+k1+k2 = 2·Kc·Ts²/(Ti·(Ts+2γ))). The listing's k2 (2·Ti for 2·Td) adds
    Kc·(Ti − Td)/Ts·e per period: about 72 000 %/period here instead of 8.26."""
    kc, ti = ITAE_PID["kc"], ITAE_PID["ti"]
    controller = laws.create("type_a", ts=TS, tf=4.49, **ITAE_PID, **WIDE)
    error = 10.0
    outputs = [controller.step(66.0, 66.0 - error) for _ in range(50)]
    slope = kc * TS / ti * error
    assert outputs[0] == pytest.approx(slope, rel=1e-12)
    for before, after in itertools.pairwise(outputs):
        assert after - before == pytest.approx(slope, rel=1e-9)


def test_type_a_filtered_is_eq12() -> None:
    for seed, gains in [(6, ITAE_PID), (7, {"kc": 5.0, "ti": 0.0, "td": 100.0})]:
        samples = brewing_samples(seed)
        gamma = 0.1 * gains["td"]
        controller = laws.create("type_a_filtered", ts=TS, tf=gamma, **gains, **WIDE)
        expected = reference_eq12(ts=TS, gamma=gamma, samples=samples, **gains)
        assert_matches(run(controller, samples), expected)


def test_type_a_filtered_without_filter_is_eq10() -> None:
    samples = brewing_samples(8)
    controller = laws.create("type_a_filtered", ts=TS, tf=0.0, **ITAE_PID, **WIDE)
    assert_matches(
        run(controller, samples), reference_eq12(ts=TS, gamma=0.0, samples=samples, **ITAE_PID)
    )


@pytest.mark.parametrize("seed", [9, 10])
def test_takahashi_is_eq14(seed: int) -> None:
    samples = brewing_samples(seed)
    controller = laws.create("takahashi", ts=TS, tf=0.0, **ITAE_PID, **WIDE)
    assert_matches(
        run(controller, samples), reference_eq14(ts=TS, gamma=0.0, samples=samples, **ITAE_PID)
    )


def test_takahashi_filtered_d_sees_eq11c_filtered_pv() -> None:
    samples = brewing_samples(11)
    controller = laws.create("takahashi", ts=TS, tf=4.49, **ITAE_PID, **WIDE)
    assert_matches(
        run(controller, samples), reference_eq14(ts=TS, gamma=4.49, samples=samples, **ITAE_PID)
    )


def test_velocity_forms_clamp_and_track_applied_as_their_equations_say() -> None:
    """With the real 0–100 % limits and an `applied` that often differs from the request."""
    samples = brewing_samples(12, applied=True)
    # The seeds' forms as written, limits included: asked for by an explicit tf.
    seed_form = {"type_a": 4.49, "type_a_filtered": 4.49, "takahashi": 0.0}
    cases: list[tuple[str, Callable[[], list[float]]]] = [
        (
            "type_a",
            lambda: reference_eq08(ts=TS, gamma=4.49, samples=samples, lo=0, hi=100, **ITAE_PID),
        ),
        (
            "type_a_filtered",
            lambda: reference_eq12(ts=TS, gamma=4.49, samples=samples, lo=0, hi=100, **ITAE_PID),
        ),
        (
            "takahashi",
            lambda: reference_eq14(ts=TS, gamma=0.0, samples=samples, lo=0, hi=100, **ITAE_PID),
        ),
    ]
    for name, reference in cases:
        controller = laws.create(name, ts=TS, tf=seed_form[name], **ITAE_PID)
        assert_matches(run(controller, samples), reference())


def test_velocity_pi_is_the_bumpless_pi_with_field_measured_mv() -> None:
    samples = brewing_samples(13, applied=True)
    kc, ti = ITAE_PI["kc"], ITAE_PI["ti"]
    expected = reference_velocity_pi(kp=kc, ki=kc / ti, dt=TS, samples=samples, lo=0.0, hi=100.0)
    assert_matches(run(laws.create("velocity_pi", ts=TS, **ITAE_PI), samples), expected)


@pytest.mark.parametrize("with_applied", [False, True])
def test_back_calculation_follows_the_tracking_formula(with_applied: bool) -> None:
    samples = brewing_samples(14, applied=with_applied)
    controller = laws.create("back_calculation", ts=TS, tf=0.0, tt=150.0, **ITAE_PID)
    expected = reference_back_calculation(
        ts=TS, tt=150.0, samples=samples, lo=0.0, hi=100.0, **ITAE_PID
    )
    assert_matches(run(controller, samples), expected)


def test_terms_add_up_to_the_step_in_linear_operation() -> None:
    samples = brewing_samples(15, count=500)
    for name in pid.ALGORITHMS:
        controller = laws.create(name, ts=TS, **tuning(name), **WIDE)
        previous = controller.output
        for sp, pv, _ in samples:
            u = controller.step(sp, pv)
            total = sum(controller.terms)
            if name in ("back_calculation", "predictive"):  # positional: P + I + D is u
                assert total == pytest.approx(u, rel=1e-9, abs=1e-6)
            else:  # increments
                assert total == pytest.approx(u - previous, rel=1e-9, abs=1e-6)
            previous = u


def test_type_a_without_filter_does_not_ring_after_the_clamp() -> None:
    """Literal γ = 0 puts eq. 08's pole at z = −1: after the clamp has held both u_{k−1} and
    u_{k−2} at 100 %, the release alternates for ever. tf = 0 must settle instead."""
    kc, ti = 0.5, 489.0
    pinned: list[Sample] = [(100.0, 60.0, None)] * 50
    released: list[Sample] = [(60.0, 60.0, None)] * 20
    literal = reference_eq08(kc, ti, 0.0, TS, 0.0, pinned + released, 100.0, lo=0.0, hi=100.0)
    assert abs(literal[-1] - literal[-2]) > 0.1  # the undamped alternation this guards against
    controller = laws.create("type_a", kc=kc, ti=ti, ts=TS)
    controller.reset(60.0, 100.0)
    outputs = run(controller, pinned + released)
    assert outputs[49] == 100.0
    assert outputs[50] < 100.0
    assert all(abs(b - a) < 1e-9 for a, b in itertools.pairwise(outputs[51:]))


# --------------------------------------------------------------------------------- windup


@pytest.mark.parametrize("gentle", [False, True])
@pytest.mark.parametrize("name", pid.ALGORITHMS)
def test_infeasible_setpoint_does_not_wind_up(name: str, gentle: bool) -> None:
    """An hour at an unreachable 100 °C (PV stuck at 60), then a setpoint below PV."""
    controller = laws.create(name, ts=TS, **tuning(name, gentle))
    pinned = [controller.step(100.0, 60.0) for _ in range(720)]
    assert pinned[-360:] == [100.0] * 360  # the last half hour pinned at the limit
    after = [controller.step(50.0, 60.0) for _ in range(2)]
    assert min(after) < 100.0


SEED_ALGORITHMS = tuple(a for a in pid.ALGORITHMS if a != "predictive")


@pytest.mark.parametrize("name", SEED_ALGORITHMS)
def test_resume_after_a_hold_is_bumpless(name: str) -> None:
    """Ten minutes without step calls while PV sags 0.5 °C, then reset(pv, output_before)."""
    gains = tuning(name)
    kc, ti = gains["kc"], gains["ti"]
    twin = []
    for _ in range(2):
        controller = laws.create(name, ts=TS, **gains)
        controller.reset(65.8, 40.0)
        for _ in range(3):
            controller.step(66.0, 65.8)
        twin.append(controller)
    held, unreset = twin
    before = held.output
    held.reset(65.3, before)
    resumed = held.step(66.0, 65.3)
    p_step = kc * TS / ti * (66.0 - 65.3)  # Δe = 0: the PV given to reset is the PV stepped
    assert abs(resumed - before) <= p_step + 1e-9
    # Without the reset the stale history kicks: the guard above is not vacuous.
    assert abs(unreset.step(66.0, 65.3) - before) > 5 * p_step


@pytest.mark.parametrize("name", SEED_ALGORITHMS)
def test_manual_to_auto_starts_from_the_manual_output(name: str) -> None:
    gains = tuning(name)
    controller = laws.create(name, ts=TS, **gains)
    controller.reset(62.0, 35.0)
    assert controller.output == 35.0
    # `applied` on the first step after reset is ignored: reset already said 35 %.
    first = controller.step(66.0, 62.0, applied=0.0)
    assert abs(first - 35.0) <= gains["kc"] * TS / gains["ti"] * 4.0 + 1e-9


def test_reset_pv_is_the_history_the_next_step_works_from() -> None:
    """reset(60, 30), then PV 60.5 with the setpoint at 66. By hand: eq. 14 with
    PV_{k−1} = PV_{k−2} = 60 gives 30 + Kc·[(60 − 60.5) + Ts/Ti·5.5 + Td/Ts·(120 − 60.5 − 60)];
    the positional form gives 30 + Kc·(60 − 60.5) − Kc·Td/Ts·(60.5 − 60), its integral moving
    only from the next period."""
    kc, ti, td = ITAE_PID["kc"], ITAE_PID["ti"], ITAE_PID["td"]
    expected = {
        "takahashi": 30.0 + kc * ((60.0 - 60.5) + TS / ti * 5.5 + td / TS * (120.0 - 60.5 - 60.0)),
        "back_calculation": 30.0 + kc * (60.0 - 60.5) - kc * td / TS * (60.5 - 60.0),
    }
    for name, output in expected.items():
        controller = laws.create(name, ts=TS, tf=0.0, **ITAE_PID, **WIDE)
        controller.reset(60.0, 30.0)
        assert controller.step(66.0, 60.5) == pytest.approx(output, rel=1e-12)


@pytest.mark.parametrize("name", SEED_ALGORITHMS)
def test_first_step_has_no_derivative_kick(name: str) -> None:
    """From 20 °C towards 66 °C: the listing's zero history would add Kc·Td/Ts·20 ≈ 14500 %."""
    gains = tuning(name)
    controller = laws.create(name, ts=TS, **gains, **WIDE)
    first = controller.step(66.0, 20.0)
    assert abs(first) <= gains["kc"] * TS / gains["ti"] * 46.0 + 1e-9


def test_first_step_starts_from_the_clamped_zero() -> None:
    # For predictive, a room at which 20 % holds 66 °C: its model then predicts no change.
    model = pid.PlantModel(ambient=66.0 - pid.SEED_HLT.gain * 20.0)
    for name in pid.ALGORITHMS:
        controller = laws.create(
            name, ts=TS, **tuning(name), out_min=20.0, out_max=80.0, model=model
        )
        assert controller.output == 20.0
        assert controller.step(66.0, 66.0) == pytest.approx(20.0, abs=1e-9)


@pytest.mark.parametrize("name", ["takahashi", "velocity_pi"])
def test_setpoint_step_moves_only_the_integral(name: str) -> None:
    gains = tuning(name)
    controller = laws.create(name, ts=TS, **gains)
    controller.reset(60.0, 30.0)
    for _ in range(5):
        controller.step(62.0, 60.0)
    before = controller.output
    after = controller.step(70.0, 60.0)
    p, i, d = controller.terms
    assert (p, d) == (0.0, 0.0)
    assert i == pytest.approx(gains["kc"] * TS / gains["ti"] * 10.0, rel=1e-12)
    assert after - before == pytest.approx(i, rel=1e-12)


# ------------------------------------------------------------------- tracking of `applied`


@pytest.mark.parametrize("name", ["type_a_filtered", "takahashi", "velocity_pi"])
def test_velocity_forms_restart_from_what_was_applied(name: str) -> None:
    """Constant PV and error: eq. 12/14 and eq. 3.13 reduce to u_k = applied + Kc·Ts/Ti·e."""
    gains = tuning(name)
    controller = laws.create(name, ts=TS, **gains)
    increment = gains["kc"] * TS / gains["ti"] * 10.0
    output = controller.step(70.0, 60.0)
    for _ in range(720):
        applied = 0.5 * output
        output = controller.step(70.0, 60.0, applied)
        assert output == pytest.approx(applied + increment, rel=1e-12)
    assert output == pytest.approx(2 * increment, rel=1e-9)  # the fixed point, far below 100 %


def test_back_calculation_integral_tracks_the_actual_output() -> None:
    """Feasible error e = 10 with the element delivering half the request: the tracking loop
    settles where ΔI = 0, i.e. Kc·Ts/Ti·e = Ts/Tt·(v − actual), so v − actual = Tt·Kc·e/Ti."""
    kc, ti, tt = 2.0, 489.0, 150.0
    controller = laws.create("back_calculation", kc=kc, ti=ti, td=44.9, ts=TS, tt=tt)
    output = controller.step(70.0, 60.0)
    for _ in range(2000):
        applied = 0.5 * output
        output = controller.step(70.0, 60.0, applied)
    unlimited = sum(controller.terms)
    assert unlimited - applied == pytest.approx(tt * kc * 10.0 / ti, rel=1e-6)


def half(output: float) -> float:
    return 0.5 * output


def floor_to_ten(output: float) -> float:
    return math.floor(output / 10.0) * 10.0


@pytest.mark.parametrize("deliver", [half, floor_to_ten])
@pytest.mark.parametrize("name", pid.ALGORITHMS)
def test_shortfall_of_applied_neither_runs_away_nor_delays_the_release(
    name: str, deliver: Callable[[float], float]
) -> None:
    gains = tuning(name, gentle=True)
    controller = laws.create(name, ts=TS, tt=150.0 if name == "back_calculation" else None, **gains)
    output = controller.step(100.0, 60.0)
    for _ in range(720):
        applied = deliver(output)
        output = controller.step(100.0, 60.0, applied)
        # Bounded: without tracking a positional integral would have grown by
        # Kc·Ts/Ti·40 per period, to ≈ 590 % after the hour. predictive's P acts on a 40 °C
        # error with its time-optimal gain; its integral's counterpart is the holding duty.
        terms = controller.terms[1:2] if name == "predictive" else controller.terms
        assert all(abs(term) <= 200.0 for term in terms)
    last_applied = deliver(output)
    released = [controller.step(50.0, 60.0, last_applied)]
    released.append(controller.step(50.0, 60.0, deliver(released[0])))
    assert min(released) < max(last_applied, 1e-9)


# --------------------------------------------------------------------- closed loop (FOPTD)


def regulate(name: str, quantum: float | None) -> list[float]:
    """Six hours from 20 °C to 66 °C on the document's identified HLT: K = 1.689 °C/%,
    τ = 14961 s, θ = 115 s, exact zero-order-hold discretisation at Ts = 5 s. With a quantum,
    the output stage delivers multiples of it and carries the residue; `applied` is fed back."""
    gain, tau, dead_steps = 1.689, 14961.0, 23
    decay = math.exp(-TS / tau)
    controller = laws.create(name, ts=TS, **tuning(name))
    pipeline = [0.0] * dead_steps
    rise = 0.0
    residue = 0.0
    applied = None
    temperatures = []
    for _ in range(4320):
        pv = 20.0 + rise
        temperatures.append(pv)
        request = controller.step(66.0, pv, applied)
        if quantum is None:
            delivered = request
        else:
            delivered = math.floor((request + residue) / quantum + 1e-9) * quantum
            residue += request - delivered
            applied = delivered
        pipeline.append(delivered)
        rise = decay * rise + (1.0 - decay) * gain * pipeline.pop(0)
    return temperatures


@pytest.mark.parametrize("quantum", [None, 10.0])
@pytest.mark.parametrize("name", pid.ALGORITHMS)
def test_each_algorithm_holds_the_identified_hlt_in_band(name: str, quantum: float | None) -> None:
    temperatures = regulate(name, quantum)
    assert max(temperatures) <= 66.5
    assert all(abs(t - 66.0) <= 0.5 for t in temperatures[-720:])  # the whole last hour


# --------------------------------------------------------------------- parameters


@pytest.mark.parametrize(
    ("name", "changes", "parameter"),
    [
        ("type_a", {"kc": 0.0}, "kc"),
        ("type_a", {"kc": -1.0}, "kc"),
        ("type_a", {"kc": math.nan}, "kc"),
        ("type_a", {"kc": math.inf}, "kc"),
        ("type_a", {"kc": "80"}, "kc"),
        ("type_a", {"kc": True}, "kc"),
        ("type_a", {"ti": -1.0}, "ti"),
        ("type_a", {"ti": math.nan}, "ti"),
        ("type_a", {"ti": 1e-4}, "ti"),
        ("type_a", {"td": -0.1}, "td"),
        ("type_a", {"td": math.inf}, "td"),
        ("type_a", {"ts": 0.0}, "ts"),
        ("type_a", {"ts": -5.0}, "ts"),
        ("type_a", {"ts": math.nan}, "ts"),
        ("type_a", {"tf": -1.0}, "tf"),
        ("type_a_filtered", {"tf": math.nan}, "tf"),
        ("type_a", {"out_min": math.nan}, "out_min"),
        ("type_a", {"out_max": math.inf}, "out_max"),
        ("type_a", {"out_min": 100.0, "out_max": 100.0}, "out_min"),
        ("type_a", {"out_min": 50.0, "out_max": 10.0}, "out_min"),
        ("back_calculation", {"tt": 1.0}, "tt"),
        ("back_calculation", {"tt": math.nan}, "tt"),
        ("back_calculation", {"ti": 0.0, "tt": 100.0}, "tt"),
        ("takahashi", {"tt": 100.0}, "tt"),
        ("takahashi", {"ti": 0.0}, "ti"),
        ("velocity_pi", {"ti": 0.0, "td": 0.0}, "ti"),
        ("velocity_pi", {}, "td"),
        ("velocity_pi", {"td": 0.0, "tf": 1.0}, "tf"),
    ],
)
def test_bad_parameters_are_named(name: str, changes: dict[str, object], parameter: str) -> None:
    arguments: dict[str, object] = {"kc": 80.8, "ti": 489.0, "td": 44.9, "ts": TS} | changes
    with pytest.raises(ValueError, match=rf"^{parameter}=") as caught:
        laws.create(name, **arguments)  # type: ignore[arg-type]
    assert "\n" not in str(caught.value)


def test_unknown_algorithm_is_named() -> None:
    with pytest.raises(ValueError, match="algorithm 'pid_reg2' is unknown"):
        laws.create("pid_reg2", kc=1.0, ti=1.0)


def test_defaults_are_resolved_as_documented() -> None:
    # Td/10 = 4.49 s is raised until one LSB kicks at most 10 %: Kc·Td·0.0625/10 = 22.67 s.
    for name in ("type_a", "type_a_filtered", "takahashi", "back_calculation"):
        assert laws.create(name, **ITAE_PID).params.tf == pytest.approx(80.8 * 44.9 * 0.00625)
    assert laws.create("type_a", kc=1.0, ti=489.0, td=44.9).params.tf == pytest.approx(4.49)
    back = laws.create("back_calculation", **ITAE_PID).params
    assert back.tt is not None
    assert back.tt == pytest.approx(math.sqrt(489.0 * 44.9))
    assert back.td <= back.tt <= back.ti
    assert laws.create("back_calculation", kc=1.0, ti=489.0).params.tt == 489.0
    assert laws.create("back_calculation", kc=1.0, ti=2.0, ts=TS).params.tt == TS
    assert laws.create("back_calculation", kc=1.0, ti=0.0).params.tt is None
    assert laws.create("type_a", kc=1.0, ti=1.0).params.ts == 5.0
    assert pid.ALGORITHMS == (
        "predictive",
        "type_a",
        "type_a_filtered",
        "takahashi",
        "back_calculation",
        "velocity_pi",
    )


# ------------------------------------------------------------------------------ tuning


def test_table1_reproduces_table2() -> None:
    # Table 2 of the document, typed in: Kc [%/°C], Ti [s], Td [s] (0 for "--").
    table2 = {
        "zn_open_pid": (156.2, 230.0, 57.5),
        "zn_open_pi": (117.2, 383.0, 0.0),
        "zn_closed_pid": (92.4, 230.0, 57.5),
        "zn_closed_pi": (69.3, 383.0, 0.0),
        "cohen_coon_pid": (102.8, 282.2, 41.8),
        "cohen_coon_pi": (69.4, 377.2, 0.0),
        "itae_load_pid": (80.8, 489.0, 44.9),
        "itae_load_pi": (59.2, 810.2, 0.0),
    }
    rules = control_seed.table1(K=1.689, tau=14961.0, theta=115.0, a_star=6.68e-5)
    assert rules.keys() == table2.keys()
    for name, printed in table2.items():
        for computed, value in zip(rules[name], printed, strict=True):
            assert computed == pytest.approx(value, abs=0.1), name


@pytest.mark.parametrize("parameter", ["K", "tau", "theta", "a_star"])
def test_table1_rejects_a_bad_model(parameter: str) -> None:
    model = {"K": 1.689, "tau": 14961.0, "theta": 115.0, "a_star": 6.68e-5, parameter: 0.0}
    with pytest.raises(ValueError, match=rf"^{parameter}="):
        control_seed.table1(**model)


# ------------------------------------------------------------------------------ properties

finite_temperatures = st.floats(-pid.MAX_ABS_TEMPERATURE, pid.MAX_ABS_TEMPERATURE)
brewing_temperatures = st.floats(0.0, 110.0)
temperatures = st.one_of(brewing_temperatures, finite_temperatures)
applied_values = st.one_of(
    st.none(), st.floats(-1e3, 1e3), st.floats(allow_nan=False, allow_infinity=False)
)


@st.composite
def controller_specs(draw: st.DrawFn) -> tuple[str, dict[str, float | None]]:
    """Any algorithm with any parameters inside the documented domain."""
    name = draw(st.sampled_from(pid.ALGORITHMS))
    times = st.floats(pid.MIN_TIME, pid.MAX_TIME)
    ts = draw(st.one_of(st.floats(pid.MIN_TIME, 60.0), times))
    needs_integral = name in ("takahashi", "velocity_pi")
    ti = draw(times if needs_integral else st.one_of(st.just(0.0), times))
    td = 0.0 if name == "velocity_pi" else draw(st.one_of(st.just(0.0), times))
    tf = None if name == "velocity_pi" else draw(st.one_of(st.none(), st.just(0.0), times))
    tt = None
    if name == "back_calculation" and ti > 0.0:
        tt = draw(st.one_of(st.none(), st.floats(ts, pid.MAX_TIME)))
    out_min = draw(st.floats(-pid.MAX_ABS_OUTPUT_LIMIT, pid.MAX_ABS_OUTPUT_LIMIT / 2))
    out_max = draw(st.floats(out_min, pid.MAX_ABS_OUTPUT_LIMIT).filter(lambda hi: hi > out_min))
    kc = draw(st.floats(1e-6, pid.MAX_KC))
    return name, {
        "kc": kc,
        "ti": ti,
        "td": td,
        "ts": ts,
        "tf": tf,
        "tt": tt,
        "out_min": out_min,
        "out_max": out_max,
    }


steps = st.tuples(st.just("step"), temperatures, temperatures, applied_values)
resets = st.tuples(st.just("reset"), temperatures, st.floats(-1e13, 1e13), st.none())
operations = st.lists(st.one_of(steps, steps, steps, resets), max_size=60)


def apply(controller: pid.Controller, operation: tuple[str, float, float, float | None]) -> float:
    kind, first, second, applied = operation
    if kind == "reset":
        controller.reset(first, second)
        return controller.output
    return controller.step(first, second, applied)


@settings(max_examples=200, deadline=None)
@given(controller_specs(), operations)
def test_outputs_stay_in_bounds_and_finite(
    spec: tuple[str, dict[str, float | None]], ops: list[tuple[str, float, float, float | None]]
) -> None:
    name, parameters = spec
    controller = laws.create(name, **parameters)  # type: ignore[arg-type]
    lo, hi = controller.params.out_min, controller.params.out_max
    for operation in ops:
        output = apply(controller, operation)
        assert lo <= output <= hi
        assert all(math.isfinite(term) for term in controller.terms)


@settings(max_examples=100, deadline=None)
@given(controller_specs(), operations)
def test_same_inputs_give_identical_outputs(
    spec: tuple[str, dict[str, float | None]], ops: list[tuple[str, float, float, float | None]]
) -> None:
    name, parameters = spec
    first = laws.create(name, **parameters)  # type: ignore[arg-type]
    second = laws.create(name, **parameters)  # type: ignore[arg-type]
    for operation in ops:
        assert apply(first, operation) == apply(second, operation)
        assert first.terms == second.terms


bad_numbers = st.sampled_from([math.nan, math.inf, -math.inf])
REJECTED_CALLS: dict[str, Callable[[pid.Controller, float], object]] = {
    "sp": lambda controller, bad: controller.step(bad, 60.0),
    "pv": lambda controller, bad: controller.step(66.0, bad),
    "applied": lambda controller, bad: controller.step(66.0, 60.0, bad),
    "reset_pv": lambda controller, bad: controller.reset(bad, 50.0),
    "reset_output": lambda controller, bad: controller.reset(60.0, bad),
}


@settings(max_examples=120, deadline=None)
@given(
    controller_specs(),
    operations,
    operations,
    st.sampled_from(sorted(REJECTED_CALLS)),
    st.one_of(bad_numbers, st.sampled_from([2e6, -2e6])),
)
def test_rejected_inputs_leave_the_state_untouched(
    spec: tuple[str, dict[str, float | None]],
    before: list[tuple[str, float, float, float | None]],
    after: list[tuple[str, float, float, float | None]],
    where: str,
    bad: float,
) -> None:
    if where in ("applied", "reset_output") and math.isfinite(bad):
        bad = math.nan  # those two take any finite value
    name, parameters = spec
    tested = laws.create(name, **parameters)  # type: ignore[arg-type]
    twin = laws.create(name, **parameters)  # type: ignore[arg-type]
    for operation in before:
        apply(tested, operation)
        apply(twin, operation)
    with pytest.raises(ValueError, match=where.removeprefix("reset_")):
        REJECTED_CALLS[where](tested, bad)
    assert tested.output == twin.output
    assert tested.terms == twin.terms
    for operation in after:
        assert apply(tested, operation) == apply(twin, operation)
        assert tested.terms == twin.terms


def test_predictive_resume_after_a_hold_moves_by_the_error_change_only() -> None:
    # Positional P: after a ten-minute hold in which the water cooled by 0.2 °C, the first
    # output may move by what P makes of that change (Kc·0.2 = 24 %) plus one integral step,
    # nothing more; it may not jump to where a fresh start would put it.
    kc, ti = 120.0, 800.0
    controller = laws.create("predictive", kc=kc, ti=ti)
    controller.reset(65.95, 27.0)
    before = controller.step(66.0, 65.95)
    controller.reset(65.75, before)  # held for ten minutes: no steps, then reset
    after = controller.step(66.0, 65.75)
    p_step = kc * abs(0.25 - 0.05) + kc * TS / ti * 0.25
    assert abs(after - before) <= p_step + 1e-9


# --------------------------------------------------------------------- the velocity forms' limits


def test_a_one_lsb_step_ratchets_the_plain_takahashi_at_its_limit() -> None:
    """The issue this default guards against, by hand from eq. 14 (tf = 0, the ITAE set), from
    27 % at the setpoint: PV steps up one LSB δ and stays. The D kick −Kc·Td/Ts·δ = −45.34
    with ΔP = −Kc·δ and I = −Kc·Ts/Ti·δ is cut at 0 %; a period later the D term returns
    +45.34 in full: 45.29 %, where the unlimited form would be back at 21.85 %."""
    kc, ti, td = ITAE_PID["kc"], ITAE_PID["ti"], ITAE_PID["td"]
    controller = laws.create("takahashi", ts=TS, tf=0.0, **ITAE_PID)
    controller.reset(66.0, 27.0)
    assert controller.step(66.0, 66.0) == pytest.approx(27.0, abs=1e-12)
    delta = 0.0625
    i = kc * TS / ti * -delta
    assert controller.step(66.0, 66.0 + delta) == 0.0
    assert controller.step(66.0, 66.0 + delta) == pytest.approx(kc * td / TS * delta + i)


@pytest.mark.parametrize("name", ["type_a", "type_a_filtered", "takahashi"])
def test_the_default_velocity_forms_do_not_ratchet_at_a_limit(name: str) -> None:
    """Near 0 % the PV flickers by one LSB about the setpoint (no net error). The seed's plain
    form (tf = 0) keeps every return of a kick the limit cut and climbs to near 50 %; the
    default (filtered, and owing the cut back) stays within a few % of where it was."""
    outputs = {}
    for label, extra in (("default", {}), ("plain", {"tf": 0.0})):
        controller = laws.create(name, ts=TS, **ITAE_PID, **extra)
        controller.reset(66.0, 5.0)
        trace = [controller.step(66.03125, 66.0 + 0.0625 * (k % 2)) for k in range(400)]
        outputs[label] = sum(trace[-100:]) / 100
    assert outputs["default"] < 10.0
    assert outputs["plain"] > 40.0


def regulate_noisy(name: str, gains: dict[str, float], seed: int) -> list[float]:
    """Six hours from 20 °C on the seed's HLT (as `regulate`), the PV read through the LM92:
    Gaussian noise of 0.03 °C, truncated to 0.0625 °C; the tun's own temperature returned."""
    gain, tau, dead_steps = 1.689, 14961.0, 23
    decay = math.exp(-TS / tau)
    controller = laws.create(name, ts=TS, **gains)
    rng = random.Random(seed)
    pipeline = [0.0] * dead_steps
    rise = 0.0
    temperatures = []
    for _ in range(4320):
        temperatures.append(20.0 + rise)
        pv = math.floor((20.0 + rise + rng.gauss(0.0, 0.03)) / 0.0625) * 0.0625
        pipeline.append(controller.step(66.0, pv))
        rise = decay * rise + (1.0 - decay) * gain * pipeline.pop(0)
    return temperatures


@pytest.mark.parametrize("name", SEED_ALGORITHMS)
def test_each_textbook_form_settles_with_noise_on_its_recommended_settings(name: str) -> None:
    # config/hermsd.yaml recommends the ITAE-load set (kc 80.8, ti 489, td 44.9; the PI set
    # for velocity_pi), tf and tt at their defaults.
    temperatures = regulate_noisy(name, tuning(name), seed=3)
    last_hour = temperatures[-720:]
    assert max(last_hour) - min(last_hour) <= 0.1  # no sustained oscillation
    assert sum(last_hour) / len(last_hour) == pytest.approx(66.0, abs=0.1)
