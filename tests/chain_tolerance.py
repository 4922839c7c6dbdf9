"""The tolerance of the differential fuzz test: ``bderiv`` against the oracle of
``reference.py``, each component against the size of what is summed into it.

The map is continuous across ties, so values are compared, not orders, and each component
against the size of what is summed into it along the query's chain (:func:`chain_scale`).
With ``C_j`` the corners along the oracle's chain, ``t_j`` its event times, ``k`` the j-th
event and ``r_j = Dh_k . C_{j-1}`` its rate when it happens,
``x_i = u_i + sum_j t_j (C_{j-1,i} - C_{j,i})`` is computed to ``~ n eps S_i``,

    S_i = |u_i| + sum_j |t_j| (|C_{j-1,i}| + |C_{j,i}| + max_l |C_{l,i}|)
          + sum_j dt_j |C_{j-1,i} - C_{j,i}|,
    dt_j = (|Dh_k| . (|u| + sum_{l<j} |t_l| (|C_{l-1}| + |C_l|) + |t_j| |C_{j-1}|)
            + sum_{l<j} dt_l |Dh_k| . |C_{l-1} - C_l|) / r_j,

``dt_j`` being the first-order sensitivity of ``t_j`` to the rounding of what it is
computed from (``Dh_k . x`` so far, the rate, the earlier times), and ``max_l |C_{l,i}|``
the size to whose rounding the corners are known (a table built in floating point from
additive parts is additive only to that: a fast path takes it as additive, legitimately).
The inverse of ``M(u)``, known to ``~ eps S``, is held to the same sum taken backwards
from ``S`` (``S_back``).
At a near tie (consecutive times within ``RTOL``) and where bderiv's order differs from
the oracle's, the other chain's scales count too: the map is continuous there, but the
tie gap (of rounding size) is magnified by the corners of the regions the other order
passes, which can be far larger.
``RTOL = 1e-9`` of these scales leaves a wide margin: in 1.1e6 evaluations (the slow
variant) the largest ratio of error to tolerance met was ~5e-7 on the selection, ~1e-3
where a fast path takes a deviation below its threshold for rounding; while the wrong answers the
families provoke (a fast path taken on a real dependence of relative size >= 1e-8, a wrong
region, a wrong order away from a tie) are orders of magnitude beyond it:
``test_fuzz.test_tolerance_flags_the_known_wrong_answers`` shows it on the repros of issue 9.
"""

from __future__ import annotations

import numpy as np
from reference import ref_apply, ref_event_times, ref_inverse

RTOL = 1e-9


def table_corners(F):
    """Corners of the (2**n, d) table ``F`` on regions given as (..., n) 0/1 flags."""
    F = np.asarray(F, dtype=float)
    n = F.shape[0].bit_length() - 1
    weights = 1 << np.arange(n, dtype=np.int64)
    return lambda hap: F[np.asarray(hap, dtype=np.int64) @ weights]


def _scale_along(Dh, C, start, t, events):
    """S and dt of one pass along chains (module docstring): ``C`` (m, n + 1, d) the
    corners in the order visited, ``start`` (m, d) the size of the input (its uncertainty),
    ``t`` (m, n) the |times| and ``events`` (m, n) the events in the order they switch;
    event ``events[:, j]`` switches at the rate ``Dh[k] . C[:, j]``."""
    m, n = events.shape
    absC = np.abs(C)
    jumps = np.abs(np.diff(C, axis=1))  # (m, n, d)
    absDh = np.abs(Dh)[events]  # (m, n, d): |Dh| of the j-th event
    hit = np.einsum("mjd,mjd->mj", Dh[events], C[:, :-1])  # its rate when it switches
    dt = np.zeros((m, n))
    before = start  # |u| + the steps before the j-th event
    for j in range(n):
        size = before + t[:, j, None] * absC[:, j]  # with the rounding of the rate itself
        acc = np.einsum("md,md->m", absDh[:, j], size)
        acc += np.einsum("ml,mld,md->m", dt[:, :j], jumps[:, :j], absDh[:, j])
        dt[:, j] = acc / hit[:, j]
        before = before + t[:, j, None] * (absC[:, j] + absC[:, j + 1])
    data = t.sum(axis=1)[:, None] * absC.max(axis=1)  # the corners known to their rounding
    return before + data + np.einsum("mj,mjd->md", dt, jumps), dt


def _one_chain(Dh, corners, V, times, orders):
    """S, S_back, dt and the rates along the chains of ``orders`` (see chain_scale)."""
    m, n = orders.shape
    hap = np.zeros((m, n + 1, n), dtype=np.uint8)
    rows = np.arange(m)
    for j in range(n):
        hap[:, j + 1] = hap[:, j]
        hap[rows, j + 1, orders[:, j]] = 1
    C = np.asarray(corners(hap), dtype=float).reshape(m, n + 1, -1)
    t = np.abs(np.take_along_axis(times, orders, axis=1))  # |t| in event order
    S, dt_seq = _scale_along(Dh, C, np.abs(V), t, orders)
    # backwards: the last event first, at the rate of the region where it has happened
    S_back, _ = _scale_along(Dh, C[:, ::-1], S, t[:, ::-1], orders[:, ::-1])
    dt = np.empty_like(dt_seq)
    np.put_along_axis(dt, orders, dt_seq, axis=1)
    return S, S_back, dt, C @ Dh.T


def chain_scale(Dh, corners, V, times, orders):
    """The error scales of the queries ``V`` (m, d) along their chains (module docstring).

    Where two consecutive events are tied to within ``RTOL`` of their times, the chain
    with the two swapped is as likely (the map is continuous there, but the other order
    can pass through a region with much larger corners): the scales are then the larger
    of the two chains'.

    Parameters
    ----------
    Dh : ndarray, shape (n, d)
    corners : callable
        Corners on regions given as 0/1 flags, shape (..., n) -> (..., d).
    V : ndarray, shape (m, d)
    times, orders : ndarray, shape (m, n)
        Event times (``times[q, k]``: event k) and orders.

    Returns
    -------
    S : ndarray, shape (m, d)
        Per-component scale of ``M(V)``.
    S_back : ndarray, shape (m, d)
        The same for ``M^-1`` evaluated at ``M(V)`` known to ``~ eps S`` (back to ``V``).
    dt : ndarray, shape (m, n)
        ``dt[q, k]``: the sensitivity of the time of event k.
    rates : ndarray, shape (m, n + 1, n)
        Every rate of every region on each chain (to judge refusals).
    """
    S, S_back, dt, rates = _one_chain(Dh, corners, V, times, orders)
    t_seq = np.take_along_axis(times, orders, axis=1)
    dt_seq = np.take_along_axis(dt, orders, axis=1)
    for j in range(orders.shape[1] - 1):
        size = np.abs(t_seq[:, j : j + 2]).sum(axis=1) + dt_seq[:, j : j + 2].sum(axis=1)
        near = np.flatnonzero(np.abs(t_seq[:, j + 1] - t_seq[:, j]) <= RTOL * size)
        if near.size:
            swapped = orders[near]
            swapped[:, [j, j + 1]] = swapped[:, [j + 1, j]]
            alt = _one_chain(Dh, corners, V[near], times[near], swapped)
            for arr, other in zip((S, S_back, dt), alt, strict=False):
                arr[near] = np.maximum(arr[near], other)
    return S, S_back, dt, rates


def oracle(Dh, corners_or_table, V):
    """The oracle on every row: (x, times, orders), each row-stacked."""
    xs, ts, os_ = [], [], []
    for u in V:
        times, order = ref_event_times(Dh, corners_or_table, u)
        xs.append(ref_apply(Dh, corners_or_table, u))
        ts.append(times)
        os_.append(order)
    return np.array(xs), np.array(ts), np.array(os_, dtype=np.int64)


def assert_matches_oracle(bd, Dh, F, V, times=True):
    """``bd(V)``, ``bd.inverse`` of the oracle's answers (back to ``V``) and, with
    ``times``, ``bd.event_times(V)`` agree with the oracle within the tolerance of the
    module docstring (``F``: the table of ``bd``'s corners)."""
    V = np.atleast_2d(np.asarray(V, dtype=float))
    x, t, o = oracle(Dh, F, V)
    S, S_back, dt, _ = chain_scale(Dh, table_corners(F), V, t, o)
    checks = [("apply", bd(V), x, S), ("inverse", bd.inverse(x), V, S_back),
              ("ref_inverse", [ref_inverse(Dh, F, w) for w in x], V, S_back)]
    if times:
        checks.append(("event_times", bd.event_times(V)[0], t, np.abs(t) + dt))
    for name, got, want, scale in checks:
        ratio = excess(got, want, scale)
        i = int(np.argmax(ratio))
        assert ratio[i] <= 1, (f"{name}, row {i}: {ratio[i]:.3g} x the tolerance off the "
                               f"oracle\nu = {V[i]}\ngot = {np.asarray(got)[i]}\n"
                               f"oracle = {want[i]}")


def excess(actual, expected, scale):
    """Per-row worst ``|actual - expected| / (RTOL * scale)`` (> 1: outside tolerance)."""
    with np.errstate(all="ignore"):
        err = np.abs(np.asarray(actual) - expected)
        ratio = np.where(err == 0, 0.0, err / (RTOL * scale))
    return ratio.max(axis=1)

