"""Seeded families of adversarial systems for the differential fuzz test (``test_fuzz.py``).

Each ``fam_*(rng, m)`` draws one system and ``m`` queries as a :class:`Case`: huge entries,
tiny rates, mixed scales, scalings to the float64 limits, exact ties, n > d, own-rates and
additive tables near the fast-path boundary, structured models with pairs, and a corner
function (``WAVY``). The helpers (``own_rate_table``, ``structured_corners``, ``WAVY``)
also build the repros of ``test_reliability.py``.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numba
import numpy as np
from chain_tolerance import chain_scale, oracle, table_corners
from reference import random_system, ref_corner_points, tie_point

from bderiv import BDerivative, CornerFunction, StructuredCorners


@dataclass
class Case:
    """``F``: what ``BDerivative`` gets (a table or a corner model); ``ref``: what the
    oracle gets (a table, or a function of the flags of any batch of regions).
    ``exps = (a, b, c)``: ``BDerivative`` gets ``2**a Dh``, ``2**b F`` (a table) and
    ``2**c V``; the oracle runs unscaled, and its answers are scaled by ``2**c``, its
    event times by ``2**(c - b)``. ``resets``: reset Jacobians (2**n, n, d, d) of a table,
    or None."""

    family: str
    Dh: np.ndarray
    F: object
    ref: object
    V: np.ndarray
    exps: tuple = (0, 0, 0)
    resets: object = None

    def corners(self, hap) -> np.ndarray:
        """The corners of regions given as (..., n) flags."""
        if isinstance(self.ref, np.ndarray):
            return table_corners(self.ref)(hap)
        return np.asarray(self.ref(hap), dtype=float)


def queries(rng, m, d):
    """Gaussian vectors with sizes spread over six decades, and a few axis-aligned ones."""
    V = rng.standard_normal((m, d)) * 10.0 ** rng.uniform(-3, 3, (m, 1))
    V[: m // 8] = np.round(V[: m // 8])
    return V


def fam_random(rng, m):
    n = int(rng.integers(1, 7))
    d = int(rng.integers(n, 8))
    Dh, F = random_system(rng, n, d)
    return Case("random", Dh, F, F, queries(rng, m, d))


def fam_wide(rng, m):
    """n > d: more events than dimensions (Dh rank deficient)."""
    d = int(rng.integers(1, 5))
    n = int(rng.integers(d + 1, 7))
    Dh, F = random_system(rng, n, d)
    return Case("n>d", Dh, F, F, queries(rng, m, d))


def kernel_basis(Dh):
    """Orthonormal columns spanning ker Dh, shape (d, d - rank)."""
    _, s, vt = np.linalg.svd(Dh)
    rank = int((s > 1e-12 * s.max()).sum())
    return vt[rank:].T


def fam_huge(rng, m):
    """One huge entry: in a random place of F or Dh (often refused: transversality), a
    whole corner scaled up, or a corner moved far along ker Dh (rates unchanged)."""
    n = int(rng.integers(1, 6))
    d = int(rng.integers(n, 8))
    Dh, F = random_system(rng, n, d)
    big = 10.0 ** rng.uniform(4, 14)
    where = rng.integers(4)
    K = kernel_basis(Dh)
    if where == 0:
        F[rng.integers(F.shape[0]), rng.integers(d)] = big * rng.choice([-1, 1])
    elif where == 1:
        Dh[rng.integers(n), rng.integers(d)] = big * rng.choice([-1, 1])
    elif where == 2 or K.shape[1] == 0:
        F[rng.integers(F.shape[0])] *= big
    else:
        F[rng.integers(F.shape[0])] += 10.0 ** rng.uniform(3, 9) * K[:, 0]
    return Case("huge", Dh, F, F, queries(rng, m, d))


def fam_mixed(rng, m):
    """Coordinates scaled by powers of two over +-14 binary orders (more is refused as
    grazing: the rates become tiny next to |F| |Dh|), rows of Dh over +-60; the answer
    must be the unscaled one, scaled (bitwise, when neither refuses)."""
    n = int(rng.integers(1, 6))
    d = int(rng.integers(n, 8))
    Dh, F = random_system(rng, n, d)
    V = queries(rng, m, d)
    col = 2.0 ** rng.integers(-14, 15, d)
    row = 2.0 ** rng.integers(-60, 61, n)
    case = Case("mixed", Dh / col * row[:, None], F * col, F * col, V * col)
    try:
        expected = BDerivative(Dh, F, fast_paths=False)(V) * col
        got = BDerivative(case.Dh, case.F, fast_paths=False)(case.V)
    except ValueError:  # grazing is judged by Euclidean norms, which scaling changes
        return case
    np.testing.assert_array_equal(got, expected, err_msg="scaled coordinates")
    return case


def fam_extreme(rng, m):
    """A random system scaled by powers of two up to 2**+-1000 (``Case.exps``): the answer
    is the unscaled one, scaled, or a refusal naming overflow when some magnitude on the
    way exceeds float64. Exponents are drawn so that nothing needs subnormal numbers (those
    are refused as underflow: ``test_reliability.test_underflowing_rates``)."""
    n = int(rng.integers(1, 6))
    d = int(rng.integers(n, 8))
    Dh, F = random_system(rng, n, d)
    while True:
        a, b, c = (int(e) for e in rng.integers(-1000, 1001, 3))
        if min(a, b, c, a + b, a + c, c - b) >= -960:
            break
    return Case("extreme", Dh, F, F, queries(rng, m, d), (a, b, c))


def fam_tiny_rates(rng, m):
    """Rates tiny next to |F| |Dh|: large components along ker Dh, or one event whose
    rates are 1e-8 of the others' (a row of Dh scaled down, its own column of F small)."""
    n = int(rng.integers(1, 6))
    d = int(rng.integers(n, 8))
    Dh, F = random_system(rng, n, d)
    K = kernel_basis(Dh)
    if K.shape[1] and rng.random() < 0.5:
        F = F + 10.0 ** rng.uniform(2, 9) * rng.standard_normal((F.shape[0], K.shape[1])) @ K.T
    else:
        Dh[rng.integers(n)] *= 10.0 ** rng.uniform(-10, -4)
    return Case("tiny-rates", Dh, F, F, queries(rng, m, d))


def own_rate_table(rng, n, d, additive):
    """A table whose rate G[mask, k] is G0[k] or Gf[k] by bit k (additive: F[mask] =
    F0 + sum A[k]); Dh a scaled permutation of eye(n, d) so the table is exact."""
    Dh = np.zeros((n, d))
    cols = rng.permutation(d)[:n]
    Dh[np.arange(n), cols] = 2.0 ** rng.integers(-3, 4, n)
    bits = ((np.arange(2**n)[:, None] >> np.arange(n)) & 1).astype(float)
    g0 = rng.integers(1, 9, n).astype(float)
    gf = rng.integers(1, 9, n).astype(float)
    F = rng.integers(-4, 5, (2**n, d)).astype(float)
    if additive:
        F = rng.integers(-4, 5, d) + bits @ rng.integers(-4, 5, (n, d))
    F[:, cols] = (g0 + bits * (gf - g0)) / Dh[np.arange(n), cols]
    return Dh, F.astype(float)


def fam_fast_boundary(rng, m):
    """Own-rates or additive tables, then (each with probability 1/2) a real dependence of
    relative size 1e-16..1e-2 in one entry, a huge entry on a column no event sees, and
    mixed column scales: a fast path must be taken only when it is exact to rounding."""
    n = int(rng.integers(1, 7))
    d = int(rng.integers(n, 9))
    additive = bool(rng.integers(2))
    Dh, F = own_rate_table(rng, n, d, additive)
    if rng.random() < 0.5:
        mask, i = rng.integers(1, 2**n), rng.integers(d)
        F[mask, i] += 10.0 ** rng.uniform(-16, -2) * max(abs(F[mask, i]), 1.0)
    free = np.flatnonzero(~np.abs(Dh).any(axis=0))
    if free.size and rng.random() < 0.5:
        F[rng.integers(2**n), rng.choice(free)] = 10.0 ** rng.uniform(3, 10)
    if rng.random() < 0.5:
        col = 2.0 ** rng.integers(-14, 15, d)
        Dh, F = Dh / col, F * col
    V = queries(rng, m, d)
    g0 = F[0] @ Dh.T
    V[: m // 4, :] = 0.0  # exact first-order ties: t_k = s_k with repeated s
    s = rng.integers(0, 3, (m // 4, n)).astype(float)
    nz = np.abs(Dh).argmax(axis=1)
    V[np.arange(m // 4)[:, None], nz] = -s * g0 / Dh[np.arange(n), nz]
    return Case("additive" if additive else "own-rates", Dh, F, F, V)


def fam_ties(rng, m):
    """Queries on the boundaries between pieces (two events at the same time)."""
    n = int(rng.integers(2, 6))
    d = int(rng.integers(n, 8))
    Dh, F = random_system(rng, n, d)
    U, _ = ref_corner_points(Dh, F)
    V = np.empty((m, d))
    for q in range(m):
        V[q], _ = tie_point(U, rng.permutation(n), int(rng.integers(1, n)), rng)
    return Case("ties", Dh, F, F, V)


def structured_corners(F0, A, pairs, B):
    """The corners of a structured model, written from its definition (any batch)."""
    def corners(hap):
        h = np.asarray(hap, dtype=float)
        both = h[..., pairs[:, 0]] * h[..., pairs[:, 1]]
        return F0 + h @ A + both @ B
    return corners


def fam_structured(rng, m):
    """Structured corners with pairs; some with own rates (A[k] moves only h_k's rate,
    pair jumps in ker Dh), then perturbed like ``fam_fast_boundary``; some with pair
    jumps large enough to violate transversality on some chains (refused per query)."""
    n = int(rng.integers(2, 11))
    d = int(rng.integers(2, 11))
    e = rng.standard_normal(d)
    e /= np.linalg.norm(e)
    Dh = e + 0.4 * rng.uniform(-1, 1, (n, d)) / np.sqrt(d)
    F0 = e * rng.uniform(0.5, 2.0)
    p = int(rng.integers(0, n + 1))
    pairs = np.array([rng.choice(n, 2, replace=False) for _ in range(p)],
                     dtype=np.int64).reshape(p, 2)
    size = rng.choice([0.05, 0.3, 1.0, 3.0])
    A = size * rng.standard_normal((n, d)) / n
    B = size * rng.standard_normal((p, d)) / n
    K = kernel_basis(Dh)
    if rng.random() < 0.4:  # own rates: Dh[j] . A[k] = 0 for j != k, Dh @ B = 0
        pinv = np.linalg.pinv(Dh)
        A = (pinv * rng.uniform(-0.4, 1.0, n)).T + rng.standard_normal((n, K.shape[1])) @ K.T
        B = rng.standard_normal((p, K.shape[1])) @ K.T
        if rng.random() < 0.5:
            A[rng.integers(n)] += 10.0 ** rng.uniform(-16, -2) * Dh[rng.integers(n)]
    if K.shape[1] and rng.random() < 0.3:
        A[rng.integers(n)] += 10.0 ** rng.uniform(4, 12) * K[:, 0]
    return Case("structured", Dh, StructuredCorners(F0, A, pairs, B),
                structured_corners(F0, A, pairs, B), queries(rng, m, d))


def wavy(happened, out):
    """A corner function with irregular corners around (1, ..., 1)."""
    s = 0.0
    for k in range(happened.shape[0]):
        s += happened[k] * (k + 1.0)
    for i in range(out.shape[0]):
        out[i] = 1.0 + 0.45 * math.sin(s * (0.7 + 0.3 * i) + i)


WAVY = CornerFunction(numba.njit(wavy))


def wavy_corners(d):
    """``wavy`` in plain Python on any batch of regions (the oracle's corners)."""
    def corners(hap):
        hap = np.asarray(hap, dtype=float)
        out = np.empty(hap.shape[:-1] + (d,))
        for idx in np.ndindex(hap.shape[:-1]):
            wavy(hap[idx], out[idx])
        return out
    return corners


def fam_function(rng, m):
    """The corner function ``wavy`` with random positive event normals."""
    n = int(rng.integers(1, 7))
    d = int(rng.integers(1, 8))
    Dh = rng.uniform(0.05, 1.0, (n, d)) * 10.0 ** rng.uniform(-3, 3, (n, 1))
    return Case("function", Dh, WAVY, wavy_corners(d), queries(rng, m, d))


def scaled_reference(case: Case):
    """The oracle's answers and tolerances at the scale ``BDerivative`` works at, and
    ``peak``: log2 of the largest magnitude met on each chain there."""
    a, b, c = case.exps
    Dh, V = case.Dh, case.V
    x, t, o = oracle(Dh, case.ref, V)
    with np.errstate(all="ignore"):
        S, S_back, dt, rates = chain_scale(Dh, case.corners, V, t, o)
        peak = np.maximum.reduce([
            np.log2(S.max(axis=1)) + c, np.log2(S_back.max(axis=1)) + c,
            np.log2((np.abs(t) + dt).max(axis=1)) + c - b,
            np.log2(np.abs(V) @ np.abs(Dh).max(axis=0)) + a + c,
            np.log2(np.abs(rates).max(axis=(1, 2))) + a + b])
        return dict(V=np.ldexp(V, c), x=np.ldexp(x, c), S=np.ldexp(S, c),
                    S_back=np.ldexp(S_back, c), t=np.ldexp(t, c - b),
                    dt=np.ldexp(dt, c - b), rates=rates, peak=peak)


def named_rate_is_not_positive(case: Case, msg: str) -> bool:
    """Whether the rate that a transversality refusal names is <= 0 (to rounding): the
    region can be off the oracle's chain (the inverse's chain, another order at a tie)."""
    found = re.search(r"event (\d+) has rate \S+ <= 0 in region mask 0b([01]+)", msg)
    assert found, f"the refusal names no event and region: {msg}"
    k, hap = int(found[1]), np.array([int(ch) for ch in found[2][::-1]])
    corner = case.corners(hap)
    return case.Dh[k] @ corner <= 1e-12 * (np.abs(case.Dh[k]) @ np.abs(corner))


def time_beyond_float64(case: Case, i: int) -> bool:
    """Whether some event time of query i, at the scale ``BDerivative`` gets (2**(c - b)
    times the oracle's), is beyond the normal float64 numbers (judged on the exponents,
    with a factor 2 of margin for rounding)."""
    _, b, c = case.exps
    _, t, _ = oracle(case.Dh, case.ref, case.V[i : i + 1])
    e = np.frexp(t[0])[1] + c - b
    return bool(((t[0] != 0) & ((e >= 1024) | (e <= -1021))).any())


FAMILIES = (fam_random, fam_wide, fam_huge, fam_mixed, fam_extreme, fam_tiny_rates,
            fam_fast_boundary, fam_ties, fam_structured)

