"""A Gaussian pushed through a piecewise-linear map: sigma directions, the mixture of
pieces, or one piece.

The perturbation ``delta ~ N(0, P)`` of the start goes through the local map ``y =
M(delta)`` (:class:`~bderiv.estimate.localmap.LocalMap`), continuous and piecewise
linear: each ``delta`` takes the piece of its own event orders. ``y`` is not Gaussian and
its mean is not 0. Three ways to give its first two moments:

- ``"sigma"``: the ``2 d`` sigma directions ``+-sqrt(d) s_j`` (``s_j`` the columns of the
  symmetric square root of P, weights ``1 / (2 d)``), each through its own piece:
  an unscented transform through ``M``. Exact where ``M`` is linear on the span of the
  directions; otherwise an approximation, as the unscented transform is for any
  nonlinear map.
- ``"mixture"``: exact. The flow meets one group with two pieces (two events, or one
  event and the step's end), the others with one: ``y = B (J(A delta + c) - J(c))``,
  ``A`` and ``B`` linear. The two orders' cones are the half-spaces ``a . u > 0`` and
  ``< 0`` of the vector ``u = A delta + c`` entering the group
  (:meth:`LocalMap.boundary`), so the probability of each order under the prior is
  ``Phi(+-a.c / sqrt(a' A P A' a))`` and the moments of ``u`` on each side are those of
  a Gaussian cut by a hyperplane (closed form); each side goes through its piece.
  Refused for flows with more pieces (use ``"sigma"``).
- ``"piece"``: one piece for all (a salted filter): ``M_s P M_s^T``, mean shift 0, ``s``
  the mean's own event orders, or those of a given priority of the events.
- ``"auto"``: ``"mixture"`` where it applies (:func:`mixture_refusal` says why not),
  else ``"sigma"``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.special import ndtr

from ..models.events.finaltime import FinalTimeMap

METHODS = ("auto", "mixture", "sigma", "piece")


class PushForward(NamedTuple):
    """The first two moments of ``M(delta)``, ``delta ~ N(0, P)``.

    Attributes
    ----------
    mean : ndarray, shape (d,)
        ``E[M(delta)]`` (0 for ``"piece"``).
    cov : ndarray, shape (d, d)
        ``Cov[M(delta)]``.
    order_probabilities : list of dict
        One per event group: local event order (tuple) -> probability under the prior
        (``"mixture"``: exact; ``"sigma"``: the weights of the sigma directions taking it,
        multiples of ``1 / (2 d)``, coarse; ``"piece"``: 1 for the piece used).
    method : str
        The method that gave them (``"auto"`` resolved).
    """

    mean: np.ndarray
    cov: np.ndarray
    order_probabilities: list
    method: str = ""


def sqrt_psd(P):
    """The symmetric square root (d, d) of a positive semi-definite P (d, d)."""
    w, U = np.linalg.eigh(P)
    return (U * np.sqrt(np.clip(w, 0.0, None))) @ U.T


def push_sigma(local, P) -> PushForward:
    """The unscented transform of N(0, P) through ``local`` (module docstring)."""
    d = local.dim
    S = np.sqrt(d) * sqrt_psd(P)
    X = np.concatenate([S.T, -S.T])  # (2d, d): each row a sigma direction
    inputs, Y = local.stage_inputs(X)
    mean = Y.mean(axis=0)
    R = Y - mean
    cov = R.T @ R / len(X)
    probs = []
    for J, W in zip(local.D.jumps, inputs, strict=True):
        found, counts = np.unique(J.orders(W), axis=0, return_counts=True)
        probs.append({tuple(int(k) for k in o): c / len(X) for o, c in
                      zip(found, counts, strict=True)})
    return PushForward(mean, 0.5 * (cov + cov.T), probs, "sigma")


def push_auto(local, P) -> PushForward:
    """``push_mixture`` where it applies, else ``push_sigma``."""
    return push_sigma(local, P) if mixture_refusal(local) else push_mixture(local, P)


def push_piece(local, P, priority=None) -> PushForward:
    """One piece for every perturbation (a salted filter): in each group the order of the
    mean's own trajectory (the order of the group's offset; (0, 1, ...) for a group at
    one stop), or, given ``priority`` (a sequence of global event indices), the events of
    each group in that order (a filter that assumes which contact comes first). A group
    at the step's end keeps the mean's order."""
    D = local.D
    orders = []
    for i, c in enumerate(local.offsets):
        J, events = D.jumps[i], D.group_events[i]
        if priority is not None and not isinstance(J, FinalTimeMap):
            missing = [k for k in events if k not in priority]
            if missing:
                raise ValueError(f"priority {tuple(priority)} does not rank events "
                                 f"{missing} of group {i} {events}")
            orders.append(tuple(sorted(range(len(events)),
                                       key=lambda j: list(priority).index(events[j]))))
        elif c is None:
            orders.append(tuple(range(J.n_events)))
        else:
            orders.append(tuple(int(k) for k in J.orders(c[None, :])[0]))
    M = D.piece([list(o) for o in orders])
    cov = M @ P @ M.T
    return PushForward(np.zeros(local.dim), 0.5 * (cov + cov.T),
                       [{o: 1.0} for o in orders], "piece")


def _cut_moments(mu, Sig, a, side):
    """Probability, mean and second moment about 0 of ``u ~ N(mu, Sig)`` on the side
    ``side * a . u > 0`` of the hyperplane: (float, (d,), (d, d))."""
    s2 = float(a @ Sig @ a)
    if not s2 > 0:  # the prior does not reach across: one side holds all of it, and a
        # prior on the boundary itself, where the two pieces agree, order (0, 1)'s side (a
        # review: it was neither's, and the covariance 0)
        inside = side * float(a @ mu) > 0 or (float(a @ mu) == 0 and side > 0)
        p = 1.0 if inside else 0.0
        return p, mu * p, (Sig + np.outer(mu, mu)) * p
    sd = np.sqrt(s2)
    alpha = side * float(a @ mu) / sd  # standardised distance of the mean into the side
    p = float(ndtr(alpha))
    if p == 0.0:
        return 0.0, np.zeros_like(mu), np.zeros_like(Sig)
    lam = np.exp(-0.5 * alpha * alpha) / np.sqrt(2 * np.pi) / p  # phi(alpha) / Phi(alpha)
    z_mean = side * lam  # mean of the standardised a.u - a.mu on the side
    z_var = 1.0 - alpha * lam - lam * lam
    k = Sig @ a / sd  # regression of u on the standardised a.u
    m = mu + k * z_mean
    second = Sig - np.outer(k, k) + np.outer(k, k) * z_var + np.outer(m, m)
    return p, p * m, p * second


def push_mixture(local, P) -> PushForward:
    """The exact moments of ``local(delta)``, ``delta ~ N(0, P)``, for a flow with one
    group of two pieces (module docstring)."""
    D, d = local.D, local.dim
    refusal = mixture_refusal(local)
    if refusal:
        raise ValueError(refusal)
    multi = [i for i, J in enumerate(D.jumps) if J.n_events > 1]
    if not multi:
        return push_piece(local, P)._replace(method="mixture")
    (g,) = multi
    A = _before(local, g)
    B = _after(local, g)
    c = np.zeros(d) if local.offsets[g] is None else local.offsets[g]
    Sig = A @ P @ A.T
    a = local.boundary(g)
    J = D.jumps[g]
    Jc = J.apply(c[None, :])[0]
    mean_u = np.zeros(d)
    second = np.zeros((d, d))
    probs = {}
    for order, side in (((0, 1), 1.0), ((1, 0), -1.0)):
        p, m1, m2 = _cut_moments(c, Sig, a, side)
        Pc = local.piece_of(g, order)
        probs[order] = p
        mean_u += Pc @ m1
        second += Pc @ m2 @ Pc.T
    mean_y = mean_u - Jc  # E[J(u)] - J(c), before the stages after the group
    cov_y = second - np.outer(mean_u, mean_u)
    cov = B @ cov_y @ B.T
    result = [{(0,): 1.0} if i != g else probs for i in range(D.n_groups)]
    return PushForward(B @ mean_y, 0.5 * (cov + cov.T), result, "mixture")


def mixture_refusal(local):
    """Why ``push_mixture`` does not apply to ``local`` (a message), or None: it needs at
    most one group of several events, that group of two local events, with a corner
    table (a boundary)."""
    D = local.D
    multi = [i for i, J in enumerate(D.jumps) if J.n_events > 1]
    if len(multi) > 1 or any(D.jumps[i].n_events > 2 for i in multi):
        return (f"method='mixture' is exact for one event group of two pieces; this step "
                f"meets groups {[D.group_events[i] for i in multi]} (their pieces "
                f"multiply): use method='sigma'")
    for i in multi:
        J = D.jumps[i]
        if (J.augmented if isinstance(J, FinalTimeMap) else J).rates is None:
            return (f"method='mixture' needs the corner table of group {i}, a corner "
                    f"model has none: use method='sigma'")
    return None


def _before(local, g):
    """The linear map (d, d) from the start to the vector entering group g (the groups
    before it have one piece)."""
    D = local.D
    A = D.linear[0]
    for i in range(g):
        A = D.linear[i + 1] @ local.piece_of(i, (0,)) @ A
    return A


def _after(local, g):
    """The linear map (d, d) from group g's image to the end."""
    D = local.D
    B = D.linear[g + 1]
    for i in range(g + 1, D.n_groups):
        B = D.linear[i + 1] @ local.piece_of(i, (0,)) @ B
    return B
