"""A first-order network whose events change each other's rates (any n, d = n or 2n).

State ``x`` (n) and, in the extended variant, ``y`` (n). Region ``B`` (bit j set iff event j
happened) sets the rate exponents ``E[B, k] = sum_{j in B} W[j, k]``:

    x_k' = r_k exp(s tanh(E[B, k])) (1 + 0.2 tanh(x_{k+1}))          (indices mod n)
    y_k' = exp(s tanh(E2[B, k])) - 0.5 y_k + 0.3 tanh(x_k)              (extended only)
    h_k  = x_k + a sin(x_{k+1}) (+ c tanh(y_k))                          (event k)

With ``r_k`` in [0.8, 1.2], ``s = 0.7``, ``a = 0.04``, ``c = 0.02`` every rate of every event is
positive near the trajectory (transversality) while the rates change by factors up to 4
after events, so a perturbation's event order is often not the order of its first-order
impact times. The event point is ``rho = 0``; ``x0`` is ``rho`` flowed back for one time unit
with the pre-event field, so all n events happen together at ``t_event = 1``.

The corner table of all ``2**n`` regions is built without a loop over masks (the exponent
table doubles one event at a time), and the Jacobians are analytic, so n = 16..20 works.
"""

from __future__ import annotations

import numpy as np
from numba.extending import register_jitable

from .._support._validate import check_bool, check_number
from .._support._validate_ints import check_int
from ._common import Example, check_start, flow_back

__all__ = ["network"]

_S = 0.7  # rate exponent scale
_A = 0.04  # event coupling to the next x
_C = 0.02  # event coupling to y (extended)


def _exponent_table(W):
    """E (2**n, n): E[B] = sum of rows W[j] for j in B, by doubling (no loop over masks)."""
    n = W.shape[0]
    E = np.zeros((1 << n, W.shape[1]))
    for j in range(n):
        size = 1 << j
        np.add(E[:size], W[j], out=E[size : 2 * size])
    return E


# The model's functions: plain functions of ``x = (state, r, W, W2, n, extended)``, the
# state (d) followed by the parameters, the rates ``r`` (n), the couplings ``W`` and ``W2``
# (n * n each, row by row; ``W2`` zero unless extended), ``n`` and ``extended`` (0 or 1):
# for Python as they are, and for numba compiled once for every n and set of values (a
# closure over the values was compiled again for each network).
@register_jitable
def _parts(x):
    """``(n, d, xs, r, W, W2)`` of ``x`` (the state, its first n components, the
    parameters: views)."""
    n = int(x[-2])
    d = 2 * n if x[-1] != 0.0 else n
    r = x[d:d + n]
    W = x[d + n:d + n + n * n].reshape((n, n))
    W2 = x[d + n + n * n:d + n + 2 * n * n].reshape((n, n))
    return n, d, x[:n], r, W, W2


@register_jitable
def _next(n):
    """x_{k+1}'s index, mod n."""
    return (np.arange(n) + 1) % n


def field(x, mask):
    """The field in region ``mask``: (d,)."""
    n, d, xs, r, W, W2 = _parts(x)
    bits = ((mask >> np.arange(n)) & 1).astype(np.float64)  # bit j: event j happened
    fx = r * np.exp(_S * np.tanh(bits @ W)) * (1 + 0.2 * np.tanh(xs[_next(n)]))
    if d == n:
        return fx
    fy = np.exp(_S * np.tanh(bits @ W2)) - 0.5 * x[n:d] + 0.3 * np.tanh(xs)
    return np.concatenate((fx, fy))


def field_jacobian(x, mask):
    """The field's Jacobian by the state: (d, d)."""
    n, d, xs, r, W, W2 = _parts(x)
    nxt = _next(n)
    bits = ((mask >> np.arange(n)) & 1).astype(np.float64)
    scale = r * np.exp(_S * np.tanh(bits @ W))
    J = np.zeros((d, d))
    for k in range(n):
        J[k, nxt[k]] += scale[k] * 0.2 / np.cosh(x[nxt[k]]) ** 2
        if d > n:
            J[n + k, n + k] = -0.5
            J[n + k, k] = 0.3 / np.cosh(x[k]) ** 2
    return J


def events(x):
    """The event values: (n,)."""
    n, d, xs, r, W, W2 = _parts(x)
    h = xs + _A * np.sin(xs[_next(n)])
    if d > n:
        h = h + _C * np.tanh(x[n:d])
    return h


def event_jacobian(x):
    """The events' Jacobian by the state: (n, d)."""
    n, d, xs, r, W, W2 = _parts(x)
    nxt = _next(n)
    D = np.zeros((n, d))
    for k in range(n):
        D[k, k] += 1.0
        D[k, nxt[k]] += _A * np.cos(x[nxt[k]])
        if d > n:
            D[k, n + k] = _C / np.cosh(x[n + k]) ** 2
    return D


def corner_field(x):
    """Every region's field at ``x``: (2**n, d) (Python only: the table of exponents is
    built by doubling, no loop over the regions)."""
    n, d, xs, r, W, W2 = _parts(x)
    rates = np.tanh(_exponent_table(W))
    rates *= _S
    np.exp(rates, out=rates)
    rates *= r * (1 + 0.2 * np.tanh(xs[_next(n)]))
    if d == n:
        return rates
    fy = np.tanh(_exponent_table(W2))
    fy *= _S
    np.exp(fy, out=fy)
    fy += -0.5 * x[n:d] + 0.3 * np.tanh(xs)
    return np.concatenate((rates, fy), axis=1)


FUNCTIONS = {"field": field, "events": events, "event_jacobian": event_jacobian,
             "field_jacobian": field_jacobian, "corner_field": corner_field}


def network(n=3, *, extended=False, seed=0, coupling=1.0, t_event=1.0, t_after=0.5,
            compiled=False):
    """The rate-changing network with n simultaneous events at ``rho = 0``.

    Parameters
    ----------
    n : int
        Number of events (and of x coordinates); 1 <= n <= 20 is practical.
    extended : bool
        If True, d = 2n (extra coordinates y that events only see weakly), else d = n.
    seed : int
        Seed of the random rates ``r`` and couplings ``W``.
    coupling : float
        Standard deviation of the couplings ``W[j, k]`` (how strongly event j changes
        the rate of event k).
    t_event, t_after : float
        The events happen at ``t_event`` from ``x0``; ``t_final = t_event + t_after``.
    compiled : bool
        The model's functions compiled with numba (they run on the compiled integrator;
        the corner table stays Python), else Python functions: the same equations.

    Returns
    -------
    Example
    """
    n = check_int(n, "n", low=1, high=24)  # an integer: int(n) made 2.5 into 2
    extended = check_bool(extended, "extended")
    coupling = check_number(coupling, "coupling", low=-np.inf, strict=False)
    rng = np.random.default_rng(seed)
    r = rng.uniform(0.8, 1.2, n)
    W = float(coupling) * rng.standard_normal((n, n))
    W2 = float(coupling) * rng.standard_normal((n, n)) if extended else np.zeros((n, n))
    params = np.concatenate((r, W.ravel(), W2.ravel(), [n, float(extended)]))
    d = 2 * n if extended else n
    rho = np.zeros(d)
    x0 = flow_back(lambda x: field(np.concatenate((x, params)), 0), rho, t_event)
    ex = Example.from_functions(
        FUNCTIONS,
        compiled=compiled,
        params=params,
        n_events=n,
        dim=d,
        rho=rho,
        x0=x0,
        t_event=t_event,
        t_after=t_after,
        name=f"network(n={n}{', extended' if extended else ''})",
        description=(
            f"first-order network, n = {n} events, d = {d}; each event changes the "
            "rates of the others, so perturbations change order"
        ),
    )
    return check_start(ex, {"n": n, "seed": seed, "coupling": float(coupling),
                            "t_event": float(t_event), "t_after": float(t_after)})
