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

from .._validate import check_bool
from ._common import Example, flow_back

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


class _Network:
    def __init__(self, n, extended, seed, coupling):
        rng = np.random.default_rng(seed)
        self.n = n
        self.extended = extended
        self.d = 2 * n if extended else n
        self.r = rng.uniform(0.8, 1.2, n)
        self.W = coupling * rng.standard_normal((n, n))
        self.W2 = coupling * rng.standard_normal((n, n)) if extended else None
        self.nxt = (np.arange(n) + 1) % n

    def _mask_bits(self, mask):
        return ((int(mask) >> np.arange(self.n)) & 1).astype(np.float64)

    def field(self, x, mask):
        n = self.n
        bits = self._mask_bits(mask)
        xs = x[:n]
        fx = self.r * np.exp(_S * np.tanh(bits @ self.W)) * (1 + 0.2 * np.tanh(xs[self.nxt]))
        if not self.extended:
            return fx
        y = x[n:]
        fy = np.exp(_S * np.tanh(bits @ self.W2)) - 0.5 * y + 0.3 * np.tanh(xs)
        return np.concatenate((fx, fy))

    def corner_field(self, x):
        n = self.n
        xs = x[:n]
        rates = np.tanh(_exponent_table(self.W))
        rates *= _S
        np.exp(rates, out=rates)
        rates *= self.r * (1 + 0.2 * np.tanh(xs[self.nxt]))
        if not self.extended:
            return rates
        fy = np.tanh(_exponent_table(self.W2))
        fy *= _S
        np.exp(fy, out=fy)
        fy += -0.5 * x[n:] + 0.3 * np.tanh(xs)
        return np.concatenate((rates, fy), axis=1)

    def field_jacobian(self, x, mask):
        n, d = self.n, self.d
        bits = self._mask_bits(mask)
        xs = x[:n]
        J = np.zeros((d, d))
        scale = self.r * np.exp(_S * np.tanh(bits @ self.W))
        J[np.arange(n), self.nxt] += scale * 0.2 / np.cosh(xs[self.nxt]) ** 2
        if self.extended:
            J[n + np.arange(n), n + np.arange(n)] = -0.5
            J[n + np.arange(n), np.arange(n)] = 0.3 / np.cosh(xs) ** 2
        return J

    def events(self, x):
        n = self.n
        xs = x[:n]
        h = xs + _A * np.sin(xs[self.nxt])
        if self.extended:
            h = h + _C * np.tanh(x[n:])
        return h

    def event_jacobian(self, x):
        n = self.n
        xs = x[:n]
        D = np.zeros((n, self.d))
        D[np.arange(n), np.arange(n)] += 1.0
        D[np.arange(n), self.nxt] += _A * np.cos(xs[self.nxt])
        if self.extended:
            D[np.arange(n), n + np.arange(n)] = _C / np.cosh(x[n:]) ** 2
        return D


def network(n=3, *, extended=False, seed=0, coupling=1.0, t_event=1.0, t_after=0.5):
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

    Returns
    -------
    Example
    """
    n = int(n)
    if not 1 <= n <= 24:
        raise ValueError(f"n must be in 1..24, got {n}")
    net = _Network(n, check_bool(extended, "extended"), seed, float(coupling))
    rho = np.zeros(net.d)
    x0 = flow_back(lambda x: net.field(x, 0), rho, t_event)
    return Example.from_model(
        net,
        n_events=n,
        dim=net.d,
        rho=rho,
        x0=x0,
        t_event=t_event,
        t_after=t_after,
        name=f"network(n={n}{', extended' if extended else ''})",
        description=(
            f"first-order network, n = {n} events, d = {net.d}; each event changes the "
            "rates of the others, so perturbations change order"
        ),
    )
