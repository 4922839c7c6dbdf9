"""The ``models`` families of ``tools/fuzz.py``: seeded hybrid models, written once.

Each model is drawn (seeded) as the parameter vector of six plain functions written in the
loop style numba accepts (``field``, ``field_jacobian``, ``events``, ``event_jacobian``,
``reset``, ``reset_jacobian`` below: every one takes ``x`` of shape (d + m,), the state
followed by the parameters, whose last two entries are n and d), so that their
``numba.njit`` is compiled once per process (and cached on disk) whatever the model.
``tools/fuzz_twins.py`` runs them as Python functions and compiled, and compares.

Families (keys of ``FAMILIES``): ``models-plain`` (fields ``A_mask x + b_mask + c_mask
sin(x_next)``, a common part and a per-region one; events affine or quadratic; the first
crossing at a drawn point), ``-sim`` (two or three events through one point of the
trajectory: simultaneous to rounding; constant fields in half of them: exactly),
``-near`` (their crossings ``gap`` = 1e-12..1e-6 apart), ``-graze`` (an event whose value
peaks at ``delta`` = 0 or +-1e-14..1e-6 of its surface), ``-resets`` (event k reads
coordinate k alone; its reset jumps that coordinate across, in 70 %, and maps a coordinate
of its own affinely: the resets commute; in a fifth of the models two events share that
coordinate: they do not), ``-final`` (a ``-sim`` or ``-near`` model stopped at its group
or 1e-12..1e-7 from it). Each model knows its designed gaps and the time a stop resolves
(``window_time``), to tell a decision at the accuracy's edge (``Model.borderline``).
"""

from __future__ import annotations

import numba
import numpy as np
from numba.extending import register_jitable
from scipy.integrate import solve_ivp

from bderiv import HybridSystem

#: both integrators run with these (the defaults): DOP853's step control keeps each step's
#: error below ``ATOL + RTOL |x|``
RTOL, ATOL = 1e-10, 1e-12

# -- the model's functions, written once (Python calls them as they are) -------------------
@register_jitable
def _sizes(x):
    """(n, d, first entry of the events' block, of rho, of the resets' block)."""
    d, n = int(x[x.size - 1].real), int(x[x.size - 2].real)
    events = d + (1 << n) * (d * d + 2 * d)
    rho = events + n * (2 * d + 2)
    return n, d, events, rho, rho + d


def field(x, mask):
    """``A x + b + c_i sin(x_{i+1})`` of region ``mask`` (its block of d d + 2 d values)."""
    n, d, _, _, _ = _sizes(x)
    base = d + mask * (d * d + 2 * d)
    out = np.zeros_like(x[:d])
    for i in range(d):
        s = x[base + d * d + i] + x[base + d * d + d + i] * np.sin(x[(i + 1) % d])
        for j in range(d):
            s += x[base + i * d + j] * x[j]
        out[i] = s
    return out


def field_jacobian(x, mask):
    n, d, _, _, _ = _sizes(x)
    base = d + mask * (d * d + 2 * d)
    J = np.zeros((d, d))
    for i in range(d):
        for j in range(d):
            J[i, j] = x[base + i * d + j].real
        k = (i + 1) % d
        J[i, k] += (x[base + d * d + d + i] * np.cos(x[k])).real
    return J


def events(x):
    """``h_k = D_k (x - rho) + q_k sum_j W_kj (x_j - rho_j)^2 + e_k``."""
    n, d, ev, rho, _ = _sizes(x)
    out = np.zeros_like(x[:n])
    for k in range(n):
        base = ev + k * (2 * d + 2)
        s = x[base + 2 * d + 1]
        for j in range(d):
            dx = x[j] - x[rho + j]
            s += x[base + j] * dx + x[base + 2 * d] * x[base + d + j] * dx * dx
        out[k] = s
    return out


def event_jacobian(x):
    n, d, ev, rho, _ = _sizes(x)
    J = np.zeros((n, d))
    for k in range(n):
        base = ev + k * (2 * d + 2)
        for j in range(d):
            J[k, j] = (x[base + j] + 2.0 * x[base + 2 * d] * x[base + d + j]
                       * (x[j] - x[rho + j])).real
    return J


def reset(x, mask, k):
    """Event k's reset: coordinate p_k moves by s_k across the surface (the crossing's
    direction), coordinate v_k -> a_k x_{v_k} + b_k (block (s, a, b, p, v) of event k)."""
    n, d, _, _, rs = _sizes(x)
    base = rs + 5 * k
    out = x[:d].copy()
    p, v = int(x[base + 3].real), int(x[base + 4].real)
    out[p] += -x[base] if mask >> k & 1 else x[base]
    out[v] = x[base + 1] * x[v] + x[base + 2]
    return out


def reset_jacobian(x, mask, k):
    n, d, _, _, rs = _sizes(x)
    J = np.eye(d)
    v = int(x[rs + 5 * k + 4].real)
    J[v, v] = x[rs + 5 * k + 1].real
    return J


FUNCTIONS = (field, field_jacobian, events, event_jacobian, reset, reset_jacobian)
_COMPILED = []


def compiled():
    """The njit of the six functions, made once per process (compiled at the first run,
    cached on disk beside this file)."""
    if not _COMPILED:
        _COMPILED.extend(numba.njit(f, cache=True) for f in FUNCTIONS)
    return tuple(_COMPILED)


# -- drawing a model ------------------------------------------------------------------------
class Model:
    """A drawn model: ``p`` (the parameters), sizes, start, final time, the designed gaps
    (time between the crossings of the designed events) and the time each designed
    event's stop resolves (``window_time``)."""

    def __init__(self, family, n, d, p, x0, t_final, resets, gaps, window_time, rng,
                 final_gaps=()):
        self.family, self.n, self.d, self.p = family, n, d, p
        self.final_gaps = final_gaps
        self.x0, self.t_final, self.resets = x0, t_final, resets
        self.gaps, self.window_time = gaps, window_time
        self.V = rng.standard_normal((0, d))
        self.complex_step = (False, False)
        #: ``-graze``: (the grazing event, its designed peak, how well its value is known)
        self.graze = None

    def systems(self):
        """``(python, compiled)`` HybridSystems of the model (fresh: nothing checked); the
        compiled one without the field's or the events' Jacobian where ``complex_step``
        says (its complex step then: exact to rounding, as the given ones)."""
        out = []
        for fns, drop in ((FUNCTIONS, (False, False)), (compiled(), self.complex_step)):
            f, fj, ev, ej, r, rj = fns
            kw = dict(reset=r, reset_jacobian=rj) if self.resets else {}
            out.append(HybridSystem(f, ev, n_events=self.n, dim=self.d,
                                    field_jacobian=None if drop[0] else fj,
                                    event_jacobian=None if drop[1] else ej, params=self.p,
                                    **kw))
        return out

    def borderline(self, tol) -> bool:
        """Whether a designed gap is at the edge of a decision: within a factor 3 of the
        time the stop resolves, or within 1e-3 of ``tol`` (simultaneity_tol); the gap
        between the designed group and a final time near it too (0 included)."""
        w = max(self.window_time)
        if any(g <= 3 * w or abs(g - tol) <= 1e-3 * tol for g in self.final_gaps):
            return True
        return any(g > 0 and (w / 3 <= g <= 3 * w or abs(g - tol) <= 1e-3 * tol)
                   for g, w in zip(self.gaps, self.window_time, strict=True))


def _flow_back(fn, p, mask, rho, t):
    """The state from which region ``mask``'s field reaches ``rho`` after time t."""
    sol = solve_ivp(lambda _, y: -fn(np.concatenate((y, p)), mask), (0.0, t), rho,
                    method="DOP853", rtol=1e-13, atol=1e-15)
    return sol.y[:, -1]


def draw(rng, family, m):
    """One model of ``family`` (a key of ``FAMILIES``) and ``m`` directions."""
    final = family == "models-final"
    if final:
        family = "models-sim" if rng.random() < 0.5 else "models-near"
    with_resets = family == "models-resets"
    n = int(rng.integers(1, 4)) if with_resets else int(rng.integers(1, 5))
    d = 2 * n if with_resets else int(rng.integers(max(2, n), 7))
    if family in ("models-sim", "models-near") and n == 1:
        n, d = 2, max(d, 2)
    N = 1 << n
    # fields: a common one plus a per-region perturbation, so that rates keep their signs
    # across surfaces often (else most crossings are refused as crossing back)
    spread = 10.0 ** rng.uniform(-1.5, -0.3)
    constant = family == "models-sim" and rng.random() < 0.5
    A = (0.3 * rng.standard_normal((d, d)) + spread * rng.standard_normal((N, d, d))) \
        * (not constant)
    b = rng.standard_normal(d) + spread * rng.standard_normal((N, d))
    c = (0.3 * rng.standard_normal(d) + spread * rng.standard_normal((N, d))) \
        * (not constant and rng.random() < 0.6)
    D = rng.standard_normal((n, d))
    W = rng.standard_normal((n, d))
    q = 0.3 * rng.standard_normal(n) * (rng.random(n) < 0.5)
    e = np.zeros(n)
    rho = rng.standard_normal(d)
    mask0 = int(rng.integers(0, N))
    designed = (1 if family in ("models-plain", "models-graze") else
                int(rng.integers(1, n + 1)) if with_resets else
                int(rng.integers(2, min(n, 3) + 1)))
    S = rng.choice(n, designed, replace=False)
    if family == "models-graze":
        S = [k for k in range(n) if not mask0 >> k & 1][:1]
        if not S:
            mask0 &= ~1
            S = [0]
    reset_block = np.zeros((n, 5))
    if with_resets:
        D = np.diag(rng.choice([-1.0, 1.0], n) * rng.uniform(0.5, 2.0, n)) @ np.eye(n, d)
        W = np.eye(n, d)
        for k in range(n):  # the field moves coordinate k clearly at rho
            f0 = field(np.concatenate((rho, _params(A, b, c, D, W, q, e, rho, reset_block,
                                                     n, d))), mask0)
            b[mask0, k] += rng.choice([-1.0, 1.0]) * rng.uniform(0.5, 1.5) - f0[k]
        reset_block[:, 1] = rng.uniform(-0.9, 0.9, n)
        reset_block[:, 2] = 0.3 * rng.standard_normal(n)
        reset_block[:, 3] = np.arange(n)
        reset_block[:, 4] = n + np.arange(n)
        if n > 1 and rng.random() < 0.2:  # two events' resets on one coordinate
            reset_block[1, 4] = n
    p = _params(A, b, c, D, W, q, e, rho, reset_block, n, d)
    f0 = field(np.concatenate((rho, p)), mask0)
    J0 = field_jacobian(np.concatenate((rho, p)), mask0)
    t_star = rng.uniform(0.3, 1.0)
    gaps = np.zeros(len(S))
    for i, k in enumerate(S):
        up = 1.0 if not mask0 >> k & 1 else -1.0
        if family == "models-graze":  # D_k . f0 = 0, d^2 h / dt^2 = D_k J0 f0 < 0
            for _ in range(50):
                r = rng.standard_normal(d)
                r -= (r @ f0) / (f0 @ f0) * f0
                curv = r @ J0 @ f0
                if abs(curv) > 0.1 * np.linalg.norm(r) * np.linalg.norm(J0 @ f0):
                    break
            D[k], q[k] = -np.sign(curv) * r, 0.0
            e[k] = rng.choice([0.0, 1.0, -1.0]) * 10.0 ** rng.uniform(-14, -6)
            continue
        if not with_resets:  # rate D_k . f0 of the crossing's sign, clearly
            u = f0 / np.linalg.norm(f0)
            for _ in range(50):
                D[k] = up * rng.uniform(0.4, 1.0) * u + 0.5 * rng.standard_normal(d)
                if up * (D[k] @ f0) > 0.3 * np.linalg.norm(D[k]) * np.linalg.norm(f0):
                    break
        if with_resets and up * (D[k] @ f0) < 0:
            D[k] = -D[k]
        rate = D[k] @ f0
        if family == "models-near" and i > 0:
            gaps[i] = 10.0 ** rng.uniform(-12, -6)
            e[k] = -rate * gaps[i]  # crosses gaps[i] after the others (first order)
    if with_resets:  # a jump across the surface in 70 %: upward, along +D_kk
        jump = rng.uniform(0.01, 0.1, n) * (rng.random(n) < 0.7)
        reset_block[:, 0] = np.sign(D[np.arange(n), np.arange(n)]) * jump
    p = _params(A, b, c, D, W, q, e, rho, reset_block, n, d)
    x0 = _flow_back(field, p, mask0, rho, t_star)
    h0 = events(np.concatenate((x0, p)))
    for k in range(n):  # the other events well away from x0, on mask0's side
        if k not in S:
            e[k] += (1.0 if mask0 >> k & 1 else -1.0) * rng.uniform(0.2, 1.5) - h0[k]
    p = _params(A, b, c, D, W, q, e, rho, reset_block, n, d)
    t_final = t_star + rng.uniform(0.2, 1.5)
    if final:
        t_final = t_star + rng.choice([0.0, 1.0, -1.0]) * 10.0 ** rng.uniform(-12, -7)
    # the time a stop resolves: err = 10 (atol + rtol |x|) per coordinate, read by |D_k|
    err = 10 * (ATOL + RTOL * np.maximum(np.abs(x0), np.abs(rho)))
    sigma = np.abs(D[S]) @ err / np.maximum(np.abs(D[S] @ f0), 1e-300)
    window = sigma + sigma.max()
    model = Model(family if not final else "models-final", n, d, p, x0, t_final, with_resets,
                  np.abs(gaps - gaps.min()), window, rng,
                  np.abs(t_final - t_star - gaps) if final else ())
    model.V = rng.standard_normal((m, d))
    model.complex_step = tuple(rng.random(2) < 0.3)
    if family == "models-graze":
        model.graze = (int(S[0]), float(e[S[0]]), float(np.abs(D[S[0]]) @ err))
    return model


def _params(A, b, c, D, W, q, e, rho, resets, n, d):
    blocks = np.concatenate((A.reshape(1 << n, d * d), b, c), axis=1)
    ev = np.concatenate((D, W, q[:, None], e[:, None]), axis=1)
    return np.concatenate((blocks.ravel(), ev.ravel(), rho, resets.ravel(), [n, d]))


FAMILIES = ("models-plain", "models-sim", "models-near", "models-graze", "models-resets",
            "models-final")
