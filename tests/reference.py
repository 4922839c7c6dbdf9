"""A plain, per-query NumPy oracle for the PL saltation map (written from mathematics.md alone).

Nothing here uses bderiv's evaluation code (only its random system generator). Every
function handles one vector (or one order) with explicit Python loops, so that each line
can be checked against mathematics.md by eye; ``F`` is a (2**n, d) table or, for corner models,
a function of the 0/1 flags of a region (then any n works: masks are Python integers):

- ``ref_event_times`` / ``ref_apply``: section 3 (selection with re-read rates),
- ``ref_inverse``: section 6,
- ``ref_piece`` / ``ref_det``: section 4 (product of saltation matrices, its determinant),
- ``ref_corner_points`` / ``ref_qp_apply``: section 5 (corner points, M_sigma = Q P^-1).

It also gives test systems: ``random_system`` (from ``bderiv.engine._baselines``: transversal
tables whose event order changes after events) and ``overtaking_system`` (the mathematics.md
section 3 example, where the order of the first-order impact times is not the true order).
"""

from __future__ import annotations

import itertools

import numpy as np
import scipy.linalg

from bderiv.engine._baselines import random_system  # noqa: F401  (the test systems' generator)


def rates(Dh, F):
    """Event-rate table G = F Dh^T, shape (2**n, n): G[mask, k] = rate of h_k in region mask."""
    return np.asarray(F, dtype=float) @ np.asarray(Dh, dtype=float).T


def chain(order):
    """Masks B_0 = 0, B_1, ..., B_n = full of an event order."""
    masks = [0]
    for k in order:
        masks.append(masks[-1] | (1 << int(k)))
    return masks


# --------------------------------------------------------------------------------------
# Section 3: forward substitution with re-read rates
# --------------------------------------------------------------------------------------
def _corner_lookup(F, n):
    """``corner(B)`` for an integer mask B (Python ints: any n): a row of the table F, or
    ``F(flags)`` when F is a function of the 0/1 flags of the n events (a corner model)."""
    if callable(F):
        return lambda B: np.asarray(F(np.array([(B >> k) & 1 for k in range(n)])), float)
    table = np.asarray(F, dtype=float)
    return lambda B: table[B]


def _forward(Dh, F, u, dtype=float):
    Dh = np.asarray(Dh, dtype=dtype)
    n = Dh.shape[0]
    lookup = _corner_lookup(F, n)
    corner = lambda B: np.asarray(lookup(B), dtype=dtype)  # noqa: E731
    x = np.array(u, dtype=dtype)
    g = Dh @ x
    B = 0
    times = np.zeros(n, dtype=dtype)
    order = []
    for _ in range(n):
        rate = Dh @ corner(B)
        best_k, best_t = -1, np.inf
        for k in range(n):
            if B & (1 << k):
                continue
            tau = -g[k] / rate[k]
            if tau < best_t:  # strict: ties go to the smallest event index
                best_k, best_t = k, tau
        B_new = B | (1 << best_k)
        x = x + best_t * (corner(B) - corner(B_new))
        g = g + best_t * (rate - Dh @ corner(B_new))
        times[best_k] = best_t
        order.append(best_k)
        B = B_new
    return x, times, np.array(order, dtype=np.int64)


def ref_apply(Dh, F, u, dtype=float):
    """M(u) for one pre-event vector u of shape (d,), mathematics.md section 3; ``dtype``:
    the arithmetic (``np.longdouble``: 11 more bits on x86, to measure float64 errors)."""
    return _forward(Dh, F, u, dtype)[0]


def ref_event_times(Dh, F, u):
    """(times, order): times[k] = time of event k, order[j] = the j-th event to happen."""
    _, times, order = _forward(Dh, F, u)
    return times, order


def ref_first_order_order(Dh, F, u):
    """The *wrong* shortcut of mathematics.md section 3: sort the first-order times
    -(Dh u)_k / G[0, k]."""
    G = rates(Dh, F)
    return np.argsort(-(np.asarray(Dh, float) @ np.asarray(u, float)) / G[0], kind="stable")


# --------------------------------------------------------------------------------------
# Section 6: the inverse, time running backwards
# --------------------------------------------------------------------------------------
def ref_inverse(Dh, F, w):
    """M^{-1}(w) for one post-event vector w, mathematics.md section 6."""
    Dh = np.asarray(Dh, dtype=float)
    n = Dh.shape[0]
    corner = _corner_lookup(F, n)
    x = np.array(w, dtype=float)
    g = Dh @ x
    B = (1 << n) - 1
    for _ in range(n):
        rate = Dh @ corner(B)
        best_k, best_t = -1, -np.inf
        for k in range(n):
            if not B & (1 << k):
                continue
            tau = -g[k] / rate[k]
            if tau > best_t:  # the last event to have happened
                best_k, best_t = k, tau
        B_new = B & ~(1 << best_k)
        x = x + best_t * (corner(B) - corner(B_new))
        g = g + best_t * (rate - Dh @ corner(B_new))
        B = B_new
    return x


# --------------------------------------------------------------------------------------
# Section 4: the linear piece of an order
# --------------------------------------------------------------------------------------
def ref_piece(Dh, F, order):
    """M_sigma = S_n ... S_1, S_j = I + (F[B_j] - F[B_{j-1}]) Dh[k_j]^T / (Dh[k_j].F[B_{j-1}])"""
    Dh = np.asarray(Dh, dtype=float)
    F = np.asarray(F, dtype=float)
    d = Dh.shape[1]
    masks = chain(order)
    M = np.eye(d)
    for j, k in enumerate(order, start=1):
        prev, cur = masks[j - 1], masks[j]
        S = np.eye(d) + np.outer(F[cur] - F[prev], Dh[k]) / (Dh[k] @ F[prev])
        M = S @ M
    return M


def ref_det(Dh, F, order):
    """det M_sigma = prod_j G[B_j, k_j] / G[B_{j-1}, k_j]."""
    G = rates(Dh, F)
    masks = chain(order)
    det = 1.0
    for j, k in enumerate(order, start=1):
        det *= G[masks[j], k] / G[masks[j - 1], k]
    return det


def all_orders(n):
    return [np.array(p, dtype=np.int64) for p in itertools.permutations(range(n))]


# --------------------------------------------------------------------------------------
# Section 5: corner points and M_sigma = Q P^-1
# --------------------------------------------------------------------------------------
def ref_corner_points(Dh, F):
    """(U, W), each (2**n, d): x_S = pinv(Dh) (1_S * G[S]), U = x_S - F[S] + F[0], W = x_S."""
    Dh = np.asarray(Dh, dtype=float)
    F = np.asarray(F, dtype=float)
    G = rates(Dh, F)
    n, d = Dh.shape
    pinv = np.linalg.pinv(Dh)
    U = np.zeros((2**n, d))
    W = np.zeros((2**n, d))
    for S in range(2**n):
        in_S = np.array([(S >> k) & 1 for k in range(n)], dtype=float)
        x = pinv @ (in_S * G[S])
        U[S] = x - F[S] + F[0]
        W[S] = x
    return U, W


def ref_qp_apply(Dh, F, u):
    """M(u) = Q P^{-1} u for the piece containing u (sigma from section 3), full-rank Dh."""
    Dh = np.asarray(Dh, dtype=float)
    n, d = Dh.shape
    U, W = ref_corner_points(Dh, F)
    _, order = ref_event_times(Dh, F, u)
    masks = chain(order)
    K = scipy.linalg.null_space(Dh) if d > n else np.zeros((d, 0))
    P = np.column_stack([U[B] for B in masks[1:]] + [K])
    Q = np.column_stack([W[B] for B in masks[1:]] + [K])
    return Q @ np.linalg.solve(P, np.asarray(u, dtype=float))


# --------------------------------------------------------------------------------------
# Tolerances
# --------------------------------------------------------------------------------------
#: Relative tolerance for comparing two evaluations of M. Each of the n steps of the
#: forward substitution adds t_j (F[B_{j-1}] - F[B_j]) to x, so rounding errors are a few
#: ulps of |u| + max|t| max|F| (the largest term summed), times a small factor per step;
#: the oracle's own evaluations (section 3, 4 and 5, inverse) agree to ~3e-14 of that
#: scale over thousands of random systems with n <= 8 and scales 1e-3..1e3. 1e-9 leaves
#: a wide margin for rounding while any wrong event order or wrong table row gives an
#: O(1) relative error (see the overtaking example: -11 instead of -3.8).
RTOL = 1e-9


def query_scale(Dh, F, u):
    """|u| + max_k |t_k| max|F|: the size of the terms the forward substitution sums."""
    times, _ = ref_event_times(Dh, F, u)
    return np.linalg.norm(u) + np.abs(times).max() * np.abs(F).max()


def component_scale(Dh, F, v):
    """Per-component size of what evaluating ``M`` or ``M^-1`` at ``v`` sums into each
    component (the scale of :func:`assert_maps_close`), shape (d,).

    ``v`` may be a pre-event or a post-event vector, so ``T`` is the larger total |time| of
    the chain from ``v`` and of the chain back from it (the times of ``M^-1(v)``). With
    ``c_i = max|F[:, i]|`` every state on the way and the answer are bounded component-wise
    by ``X = |v| + 2 T c``, and component i is a sum of such terms and of ``t (F[B] -
    F[B'])_i``: its rounding is a few ulps of ``X_i``, plus the error of the times times the
    jumps (``<= 2 c_i``). Each time is ``-(Dh_k . x) / rate`` with ``x`` known to ``~ eps X``
    and the rate one of ``G[:, k]`` (any order, so ties are covered): it is off by ``~ eps
    dt_k``, ``dt_k = |Dh_k| . X / min|G[:, k]|``. Hence

        S_i = X_i + 2 c_i sum_k dt_k.

    Unlike ``query_scale`` (the norm of the whole row and the largest entry of F), a huge
    column of F cannot hide an error in the others (issue 9, item 1). The bound on the
    times is loose by up to the ratio of the largest to the smallest rate of an event; the
    wrong component of issue 9 is still 2e4 times outside ``RTOL`` of it, and the largest
    error met in the suite's comparisons was ~5e-5 of it
    (``test_fuzz.test_assert_maps_close_flags_one_wrong_component``).
    """
    Dh = np.asarray(Dh, dtype=float)
    F = np.asarray(F, dtype=float)
    v = np.asarray(v, dtype=float)
    col = np.abs(F).max(axis=0)
    T = max(np.abs(ref_event_times(Dh, F, u)[0]).sum() for u in (v, ref_inverse(Dh, F, v)))
    X = np.abs(v) + 2 * T * col
    dt = (np.abs(Dh) @ X) / np.abs(rates(Dh, F)).min(axis=0)
    return X + 2 * col * dt.sum()


def assert_maps_close(Dh, F, V, actual, expected, rtol=RTOL):
    """Component-wise ``|actual - expected| <= rtol * component_scale(row of V)``.

    ``V`` (..., d): the vectors at which ``M`` or ``M^-1`` was evaluated; ``F``: the table."""
    V = np.asarray(V, dtype=float).reshape(-1, np.shape(Dh)[1])
    actual = np.asarray(actual).reshape(V.shape)
    expected = np.asarray(expected).reshape(V.shape)
    for i, u in enumerate(V):
        err = np.abs(actual[i] - expected[i])
        scale = component_scale(Dh, F, u)
        bad = np.flatnonzero(~(err <= rtol * scale))  # NaN fails too
        assert not bad.size, (
            f"row {i}, component {bad[0]}: |actual - expected| = {err[bad[0]]:.3g} > "
            f"{rtol:g} * {scale[bad[0]]:.3g}\nu = {u}\nactual   = {actual[i]}\n"
            f"expected = {expected[i]}"
        )


# --------------------------------------------------------------------------------------
# Evaluation of a triangulation (pre/post vertices, simplices, kernel basis) as cones
# --------------------------------------------------------------------------------------
def ref_tri_apply(pre, post, simplices, kernel, u, tol=1e-9):
    """Evaluate a PL map given by simplices with vertex 0 at the origin, one vector.

    Each simplex [0, i_1, ..., i_n] spans the cone of non-negative combinations of
    pre[i_1..i_n] (plus ker Dh, where the map is the identity). Find the cone holding u
    (weights >= -tol relative to their size) and map its weights to the post vertices.
    """
    u = np.asarray(u, dtype=float)
    best = None
    for s in simplices:
        assert s[0] == 0, "every simplex of the fan has the origin (mask 0) as a vertex"
        P = np.column_stack([pre[s[1:]].T, kernel])
        Q = np.column_stack([post[s[1:]].T, kernel])
        coef = np.linalg.lstsq(P, u, rcond=None)[0]
        lam = coef[: len(s) - 1]
        resid = np.linalg.norm(P @ coef - u)
        worst = lam.min() / max(np.abs(lam).max(), 1e-300)
        if resid <= 1e-9 * max(np.linalg.norm(u), 1e-300) and (best is None or worst > best[0]):
            best = (worst, Q @ coef)
    assert best is not None and best[0] >= -tol, "no simplex cone holds u"
    return best[1]


# --------------------------------------------------------------------------------------
# Test systems
# --------------------------------------------------------------------------------------
def overtaking_system(n, d=None, slow=0.1):
    """mathematics.md section 3 example generalised to n >= 3 events and d >= n dimensions.

    Dh = [I_n, 0], F = all ones except F[0b1] (after event 0 only), whose component 1 is
    ``slow``: after event 0, event 1 slows down until event 2 happens.
    With u = -(1, 2, ..., n) (zeros beyond n) the first-order times are 1, 2, ..., n,
    i.e. the order (0, 1, 2, ...), but event 1 is overtaken by event 2:

        t_0 = 1;  x_1 = -2 + (1 - slow) = -1 - slow;  event 2 at t = 3 (rate 1);
        back at rate 1: x_1 = -1 - slow - 3 (1 - slow) = -4 + 2 slow  ->  t_1 = 4 - 2 slow,

    which lies in (3, 4) for 0 < slow < 0.5, so the true order is (0, 2, 1, 3, ..., n-1)
    and M(u) = u with component 1 replaced by -(4 - 2 slow) (= -3.8 for slow = 0.1).

    Returns (Dh, F, u, true_order, expected_M_u, expected_times).
    """
    d = n if d is None else d
    if n < 3 or d < n or not 0 < slow < 0.5:
        raise ValueError("need n >= 3, d >= n, 0 < slow < 0.5")
    Dh = np.zeros((n, d))
    Dh[:, :n] = np.eye(n)
    F = np.ones((2**n, d))
    F[0b1, 1] = slow
    u = np.zeros(d)
    u[:n] = -np.arange(1, n + 1, dtype=float)
    t1 = 4 - 2 * slow
    order = np.array([0, 2, 1, *range(3, n)], dtype=np.int64)
    w = u.copy()
    w[1] = -t1
    times = np.arange(1, n + 1, dtype=float)
    times[1] = t1
    return Dh, F, u, order, w, times


def relabel(Dh, F, perm):
    """Rename events: new event j is old event perm[j] (rows of Dh and bits of the masks)."""
    perm = np.asarray(perm)
    n = len(perm)
    F2 = np.empty_like(F)
    for new_mask in range(2**n):
        old_mask = 0
        for j in range(n):
            if new_mask & (1 << j):
                old_mask |= 1 << int(perm[j])
        F2[new_mask] = F[old_mask]
    return Dh[perm], F2


def tie_point(U, order, j, rng):
    """A vector on the boundary between the pieces of ``order`` and of ``order`` with
    positions j-1 and j swapped (1 <= j <= n-1): the weight of U[B_j], t_{j+1} - t_j, is 0.
    Returns the vector and the swapped order."""
    n = len(order)
    masks = chain(order)
    lam = rng.uniform(0.2, 1.0, n - 1)
    lam[j - 1] = 0.0
    u = sum(lam[i - 1] * U[masks[i]] for i in range(1, n)) + rng.uniform(-1, 1) * U[-1]
    swapped = np.array(order).copy()
    swapped[[j - 1, j]] = swapped[[j, j - 1]]
    return u, swapped


# --------------------------------------------------------------------------------------
# Section 8: resets at the events (R[mask, k]: the Jacobian of crossing k from region mask)
# --------------------------------------------------------------------------------------
def ref_reset_flow(Dh, F, R, u):
    """M(u) with resets by following the sampled trajectory in physical time.

    The trajectory is x(t) = u + t F[0] long before the events; it moves with F[B] in
    region B, and when it reaches a pending surface (Dh_k x = 0) it jumps to R[B, k] x.
    After the last event x(t) = w + t F[full]; returns w. Nothing here uses virtual
    positions (the kernel's update); returns (w, times, order).
    """
    Dh, F, R = (np.asarray(a, dtype=float) for a in (Dh, F, R))
    n = Dh.shape[0]
    G = rates(Dh, F)
    t = min(-(Dh @ u) / G[0]) - 1.0  # before every event
    x = np.asarray(u, dtype=float) + t * F[0]
    B, times, order = 0, np.zeros(n), []
    for _ in range(n):
        pending = [k for k in range(n) if not B >> k & 1]
        wait = {k: -(Dh[k] @ x) / G[B, k] for k in pending}
        k = min(pending, key=lambda k: (wait[k], k))
        x = x + wait[k] * F[B]
        t += wait[k]
        x = R[B, k] @ x
        B |= 1 << k
        times[k] = t
        order.append(k)
    return x - t * F[B], times, np.array(order, dtype=np.int64)


def ref_reset_piece(Dh, F, R, order):
    """S_n ... S_1 with S_j = R_j + (F[B_j] - R_j F[B_{j-1}]) Dh[k_j]^T / G[B_{j-1}, k_j],
    R_j = R[B_{j-1}, k_j] (mathematics.md section 9)."""
    Dh, F, R = (np.asarray(a, dtype=float) for a in (Dh, F, R))
    masks = chain(order)
    M = np.eye(Dh.shape[1])
    for j, k in enumerate(order, start=1):
        prev, cur = masks[j - 1], masks[j]
        Rj = R[prev, k]
        M = (Rj + np.outer(F[cur] - Rj @ F[prev], Dh[k]) / (Dh[k] @ F[prev])) @ M
    return M


def ref_reset_apply_by_pieces(Dh, F, R, u):
    """M(u) as the piece of the one order whose event times, computed along that order,
    do not decrease (all n! orders tried; the first that fits, with a tolerance)."""
    Dh, F, R = (np.asarray(a, dtype=float) for a in (Dh, F, R))
    G = rates(Dh, F)
    for order in all_orders(Dh.shape[0]):
        x, B, last, fits = np.asarray(u, float), 0, -np.inf, True
        for k in order:
            t = -(Dh[k] @ x) / G[B, k]
            if t < last - 1e-9 * (1 + abs(last)):
                fits = False
                break
            x = R[B, k] @ (x + t * F[B]) - t * F[B | 1 << k]
            B, last = B | 1 << k, t
        if fits:
            return ref_reset_piece(Dh, F, R, order) @ u, order
    raise AssertionError("no order fits u")


def random_reset_system(rng, n, d, *, compatible=True, moving=False):
    """(Dh, F, R) with transversal rates and resets R of shape (2**n, n, d, d).

    In coordinates z = C x whose first n rows are Dh (C invertible), the reset of event j
    from region b keeps h_l for l != j, scales h_j by a_j(b) > 0, and maps the rest r
    (d - n coordinates) to D_j r + c_j(b) h_j. With D_j diagonal (``compatible``) the
    resets commute on every common tangent space h_j = h_k = 0 and move no other surface
    (mathematics.md section 9); dense random D_j do not commute (``compatible=False``), and
    ``moving=True`` adds h_l += r_0 for l != j, so that a reset moves the other surfaces.
    """
    from bderiv.engine._baselines import random_system as _random_system

    Dh, F = _random_system(rng, n, d)
    extra = rng.standard_normal((d - n, d))
    C = np.vstack([Dh, extra])
    while np.linalg.cond(C) > 1e3:
        extra = rng.standard_normal((d - n, d))
        C = np.vstack([Dh, extra])
    Ci = np.linalg.inv(C)
    D = [np.diag(rng.uniform(0.2, 1.5, d - n)) if compatible
         else np.eye(d - n) + 0.5 * rng.standard_normal((d - n, d - n)) for _ in range(n)]
    R = np.zeros((2**n, n, d, d))
    for b in range(2**n):
        for j in range(n):
            if b >> j & 1:
                continue
            A = np.eye(d)
            A[j, j] = rng.uniform(0.5, 2.0)
            A[n:, n:] = D[j]
            A[n:, j] = rng.standard_normal(d - n)
            if moving and d > n:
                A[[i for i in range(n) if i != j], n] = 1.0
            R[b, j] = Ci @ A @ C
    return Dh, F, R
