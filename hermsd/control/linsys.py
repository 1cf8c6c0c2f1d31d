"""Small linear-systems arithmetic in pure Python: exact sampling and poles of models of a few
states (the Pi has no numpy, and nothing here needs more than a 6 × 6 matrix).

Matrices are lists of rows; polynomials are coefficient lists, highest power first.
"""

from __future__ import annotations

import cmath
import math
from collections.abc import Sequence

Matrix = list[list[float]]
Vector = list[float]


def identity(n: int) -> Matrix:
    return [[1.0 if i == j else 0.0 for j in range(n)] for i in range(n)]


def mat_mul(a: Sequence[Sequence[float]], b: Sequence[Sequence[float]]) -> Matrix:
    columns = list(zip(*b, strict=True))
    return [
        [math.fsum(x * y for x, y in zip(row, col, strict=True)) for col in columns] for row in a
    ]


def mat_vec(a: Sequence[Sequence[float]], x: Sequence[float]) -> Vector:
    return [math.fsum(v * w for v, w in zip(row, x, strict=True)) for row in a]


def solve(a: Sequence[Sequence[complex]], b: Sequence[complex]) -> list[complex]:
    """x with A·x = b (Gaussian elimination, partial pivoting; complex, for s = jω)."""
    n = len(a)
    m = [[*row, rhs] for row, rhs in zip(a, b, strict=True)]
    for col in range(n):
        pivot = max(range(col, n), key=lambda row: abs(m[row][col]))
        if m[pivot][col] == 0:
            raise ValueError("the matrix is singular")
        m[col], m[pivot] = m[pivot], m[col]
        for row in range(col + 1, n):
            f = m[row][col] / m[col][col]
            m[row] = [x - f * y for x, y in zip(m[row], m[col], strict=True)]
    x = [0j] * n
    for row in reversed(range(n)):
        x[row] = (m[row][n] - sum(m[row][k] * x[k] for k in range(row + 1, n))) / m[row][row]
    return x


def expm(a: Sequence[Sequence[float]]) -> Matrix:
    """e^A by scaling and squaring: a Taylor series to round-off on A/2^s, |A/2^s|_1 ≤ 1/2."""
    n = len(a)
    norm = max(math.fsum(abs(a[i][j]) for i in range(n)) for j in range(n)) if n else 0.0
    squarings = max(0, math.ceil(math.log2(norm / 0.5))) if norm > 0.5 else 0
    scale = 2.0**-squarings
    scaled = [[x * scale for x in row] for row in a]
    result = identity(n)
    term = identity(n)
    for k in range(1, 30):  # |A/2^s| ≤ 1/2: the 30th term is below 1e-40 of the first
        term = [[x / k for x in row] for row in mat_mul(term, scaled)]
        result = [
            [r + t for r, t in zip(rr, tr, strict=True)]
            for rr, tr in zip(result, term, strict=True)
        ]
    for _ in range(squarings):
        result = mat_mul(result, result)
    return result


def zoh(
    a: Sequence[Sequence[float]], b: Sequence[Sequence[float]], h: float
) -> tuple[Matrix, Matrix]:
    """(Ad, Bd) of x' = A·x + B·u with u held over each period h: exact at the samples.

    From e^(M·h) of M = [[A, B], [0, 0]], whose top blocks are Ad = e^(A·h) and
    Bd = ∫0^h e^(A·s) ds · B.
    """
    n, m = len(a), len(b[0])
    augmented = [[*(x * h for x in a[i]), *(x * h for x in b[i])] for i in range(n)]
    augmented += [[0.0] * (n + m) for _ in range(m)]
    e = expm(augmented)
    return [row[:n] for row in e[:n]], [row[n:] for row in e[:n]]


def char_poly(a: Sequence[Sequence[float]]) -> list[float]:
    """det(s·I − A), highest power first (Faddeev–LeVerrier; fine for a few states)."""
    n = len(a)
    coefficients = [1.0]
    m = [[0.0] * n for _ in range(n)]
    for k in range(1, n + 1):
        m = mat_mul(a, m)
        for i in range(n):
            m[i][i] += coefficients[-1]
        am = mat_mul(a, m)
        coefficients.append(-math.fsum(am[i][i] for i in range(n)) / k)
    return coefficients


def poly_eval(p: Sequence[complex], s: complex) -> complex:
    value = 0j
    for c in p:
        value = value * s + c
    return value


def poly_mul(p: Sequence[float], q: Sequence[float]) -> list[float]:
    out = [0.0] * (len(p) + len(q) - 1)
    for i, x in enumerate(p):
        for j, y in enumerate(q):
            out[i + j] += x * y
    return out


def poly_add(p: Sequence[float], q: Sequence[float]) -> list[float]:
    width = max(len(p), len(q))
    p = [0.0] * (width - len(p)) + list(p)
    q = [0.0] * (width - len(q)) + list(q)
    return [x + y for x, y in zip(p, q, strict=True)]


def poly_roots(p: Sequence[float]) -> list[complex]:
    """All roots of a real polynomial (Aberth–Ehrlich iteration), sorted by real part.

    Converges for distinct roots to round-off; repeated roots come out to about the square
    root of round-off, which is why callers compare with a tolerance.
    """
    lead = p[0]
    if lead == 0.0:
        raise ValueError("the leading coefficient must not be 0")
    monic = [c / lead for c in p]
    n = len(monic) - 1
    if n == 0:
        return []
    radius = 1.0 + max(abs(c) for c in monic[1:])  # Cauchy's bound: every root lies inside
    derivative = [c * (n - i) for i, c in enumerate(monic[:-1])]
    roots = [radius * cmath.exp(1j * (2.0 * math.pi * k / n + 0.4)) for k in range(n)]
    for _ in range(500):
        moved = 0.0
        for i, z in enumerate(roots):
            value = poly_eval(monic, z)
            if value == 0:
                continue
            ratio = value / poly_eval(derivative, z)
            repulsion = sum(1.0 / (z - w) for j, w in enumerate(roots) if j != i)
            correction = ratio / (1.0 - ratio * repulsion)
            roots[i] = z - correction
            moved = max(moved, abs(correction) / max(abs(z), 1e-300))
        if moved < 1e-15:
            break
    return sorted(
        (complex(z.real, 0.0) if abs(z.imag) <= 1e-12 * abs(z) else z for z in roots),
        key=lambda z: (z.real, z.imag),
    )


def eigenvalues(a: Sequence[Sequence[float]]) -> list[complex]:
    """The eigenvalues of a small matrix, as the roots of its characteristic polynomial."""
    return poly_roots(char_poly(a))


def observer_gains(ts: float, track: float, bias: float) -> tuple[float, float]:
    """(L1, L2) of the PV/bias observer with poles e^(−Ts/track) and e^(−Ts/bias).

    Error dynamics of predict-then-correct on x = (PV, bias), A = [[1, Ts], [0, 1]]:
    z² − (2 − L1 − Ts·L2)·z + (1 − L1), so L1 = 1 − p1·p2 and Ts·L2 = (1 − p1)·(1 − p2).
    """
    p1 = math.exp(-ts / track)
    p2 = math.exp(-ts / bias)
    return 1.0 - p1 * p2, (1.0 - p1) * (1.0 - p2) / ts
