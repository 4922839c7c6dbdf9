"""The flow's piecewise-linear map around a filter's mean, event groups off-centre.

A predict step integrates the mean ``m`` over ``[0, dt]`` and takes the flow's
B-derivative ``D`` there with a wide ``simultaneity_tol`` (the filter's ``window``): events
of the mean's trajectory that cross within the window of each other are one group, whose
map is built at the state ``rho_1`` of its first crossing, as if they were simultaneous
there (docs/mathematics.md, section 7, "Events close together"; ``rho_1`` is the run's
own, ``D.group_states``). The mean itself is off
that simultaneous point: at ``rho_1`` the group's other events are still ahead, by their
values ``h_k(rho_1) < 0``. To first order the true local map around the mean is the
group's map moved to the offset ``c`` with ``Dh c = h(rho_1)`` (local orientation):

    u  ->  J(u + c) - J(c)

(``J`` the group's map, ``u`` the perturbation entering it), which selects the order the
mean's own trajectory takes for perturbations smaller than the gap and both orders for
larger ones. :class:`LocalMap` composes the linear stages of ``D`` with its groups so
moved. A group at exactly one stop has ``c = 0``: ``LocalMap`` is then ``D``.

The window itself comes from the prior (:func:`derived_window`): a few standard
deviations of the event times of the mean's trajectory under the prior, first order; and
a step that ends within the window of an event keeps that event on the mean's side
(:func:`end_gap`: the window is shrunk below the distance to the step's end).
"""

from __future__ import annotations

import numpy as np

from ..models.events.finaltime import FinalTimeMap

#: event-time standard deviations that the derived window spans: two events of the mean's
#: trajectory further apart than it reorder with probability below 1e-3 under the prior
WINDOW_SDS = 5.0
#: a step may end no nearer an event of the mean's trajectory than this many standard
#: deviations of the event's time under the prior: nearer, part of the prior crosses it
#: before the end and part after (0.3 % beyond three), a split no Gaussian step holds
END_SDS = 3.0


class LocalMap:
    """``delta -> Phi(T, m + delta) - Phi(T, m)`` to first order: ``D`` with off-centre
    groups.

    Parameters
    ----------
    D : FlowBDerivative
        The flow's B-derivative at the mean (dimension d).
    offsets : sequence of (ndarray (d,) or None)
        One per event group of ``D``: the offset ``c`` of the group's map (None: 0).

    Attributes
    ----------
    D, offsets, dim
    """

    def __init__(self, D, offsets):
        self.D, self.dim = D, D.dim
        self.offsets = tuple(None if c is None else np.asarray(c, float) for c in offsets)
        if len(self.offsets) != D.n_groups:
            raise ValueError(f"need one offset per event group ({D.n_groups}), got "
                             f"{len(self.offsets)}")

    def stage_inputs(self, V):
        """The rows entering each group (with their offsets added) and the images:
        ``(list of (m, d) arrays, (m, d) array)`` for rows ``V`` (m, d)."""
        W = V @ self.D.linear[0].T
        inputs = []
        for J, c, L in zip(self.D.jumps, self.offsets, self.D.linear[1:], strict=True):
            if c is None:
                inputs.append(W)
                W = J.apply(W)
            else:
                inputs.append(W + c)
                W = J.apply(W + c) - J.apply(c[None, :])
            W = W @ L.T
        return inputs, W

    def __call__(self, V):
        """The local map of rows ``V`` (m, d): (m, d)."""
        return self.stage_inputs(np.atleast_2d(np.asarray(V, float)))[1]

    def orders(self, V):
        """Local event order of each group for rows ``V`` (m, d): list of (m, n_g) int64."""
        inputs, _ = self.stage_inputs(np.atleast_2d(np.asarray(V, float)))
        return [J.orders(W) for J, W in zip(self.D.jumps, inputs, strict=True)]

    def piece_of(self, i, order):
        """Group i's linear piece (d, d) for a local event order."""
        return np.array(self.D.jumps[i].piece(list(order)))

    def boundary(self, i):
        """Group i's tie of its two local events: ``a`` (d,) such that a vector ``u``
        entering the group (offset included) takes the order (0, 1) iff ``a . u > 0``.

        At a tie both events cross together from the region before the group, at the
        first-order times ``t_k(u) = -Dh_k u / G[0, k]``: order (0, 1) iff
        ``t_0 < t_1``. Only for groups of two local events (a final-time group: one event
        and the final time).
        """
        J = self.D.jumps[i]
        if J.n_events != 2:
            raise ValueError(f"group {i} has {J.n_events} local events; the boundary of "
                             f"two pieces needs 2")
        B = J.augmented if isinstance(J, FinalTimeMap) else J
        if B.rates is None:
            raise ValueError(f"group {i}'s map has no corner table (a corner model): its "
                             f"boundary is not available")
        a = B.Dh[0] / B.rates[0, 0] - B.Dh[1] / B.rates[0, 1]
        return np.array(a[: self.dim])


def group_offsets(model, D, traj=None):
    """The offset ``c`` (d,) of each event group of ``D`` (None where the group crossed
    at one stop): ``Dh c = h(rho_1)`` in the group's local orientation, least squares.

    Parameters
    ----------
    model : HybridSystem
    D : FlowBDerivative
        The flow map at the mean, its groups merged within the filter's window.
    traj : Trajectory, optional
        The mean's trajectory over the same span (its groups each at its own stop): the
        state before a group with a spread is that of its stop nearest the group's time.
        Default: the flow map's own (``D.group_states``, the state at each group's first
        crossing in the run the map was built along; a map from ``flow_bderivative`` has
        them).

    Raises
    ------
    ValueError
        For a merged group at the final time (events about to cross after the step's end
        within the window): shorten the window or move the step's end; and for a map
        that holds no group states or masks (one built by hand) without ``traj``.
    """
    offsets = []
    for i, (J, spread) in enumerate(zip(D.jumps, D.group_spreads, strict=True)):
        if spread == 0.0:
            offsets.append(None)
            continue
        if isinstance(J, FinalTimeMap):
            raise ValueError(
                f"event group {i} ({D.group_events[i]}) lies within the window of the "
                f"step's end, its events {spread:.3g} apart: the filter does not offset a "
                f"group at the final time; choose dt so that the step does not end within "
                f"the window of an event of the mean's trajectory, or a smaller window")
        if traj is not None:
            first = min(traj.groups, key=lambda g: abs(g.time - D.group_times[i]))
            state = first.state
            mask_before = D.group_masks[i][0] if D.group_masks else first.mask_before
        elif len(D.group_states) == len(D.jumps) and D.group_masks:
            state, mask_before = D.group_states[i], D.group_masks[i][0]
        else:
            raise ValueError("D does not hold its groups' states and masks (a map from "
                             "flow_bderivative does): pass traj, the mean's trajectory")
        events = D.group_events[i]
        h = model.calls.eval_events(state)
        sign = np.array([-1.0 if mask_before >> k & 1 else 1.0 for k in events])
        c, *_ = np.linalg.lstsq(J.Dh, sign * h[list(events)], rcond=None)
        offsets.append(c)
    return offsets


def event_time_sds(D, P):
    """The standard deviation (first order) of the time of each event of ``D`` under the
    prior ``N(0, P)`` (d, d) of the start: an array (n_events,), in the order of
    ``D.group_events`` flattened (a group at the final time: its events, not the final
    time).

    Each square-root direction ``s_j`` of P (and ``-s_j``) enters each group through the
    stages before it; the group's event times of those vectors (``event_times``, linear
    in the vector within a piece) give the variance ``sum_j t_k(s_j)^2``.
    """
    S = _square_root(P)
    inputs, _ = LocalMap(D, [None] * D.n_groups).stage_inputs(np.concatenate([S, -S]))
    sds = []
    for J, W in zip(D.jumps, inputs, strict=True):
        n = J.n_events - 1 if isinstance(J, FinalTimeMap) else J.n_events
        times = J.event_times(W)[0][:, :n]
        sds.append(np.sqrt(0.5 * np.sum(times * times, axis=0)))
    return np.concatenate(sds) if sds else np.zeros(0)


def derived_window(D, P):
    """``WINDOW_SDS`` times the largest event-time standard deviation of ``D``'s events
    under the prior P (:func:`event_time_sds`); 0 without events."""
    sds = event_time_sds(D, P)
    return WINDOW_SDS * float(sds.max()) if sds.size else 0.0


def end_sds(model, D, dt, P):
    """How far the step's end ``dt`` is from each event of the mean's trajectory, in
    standard deviations of the event's time under the prior P (d, d), first order: the
    events ``D`` holds (their times and :func:`event_time_sds`) and those about to cross
    after ``dt`` (``-h_k / r_k`` at ``D.x_final``, ``r_k = Dh_k f`` their rate, the
    spread of their time ``|Dh_k D(s)| / r_k`` over the square roots s of P). Returns
    ``(distance in sds, the gap in seconds, its sd)`` of the nearest, or None."""
    found = [(dt - t, sd) for t, sd in zip(
        [t for t, ev in zip(D.group_times, D.group_events, strict=True) for _ in ev],
        event_time_sds(D, P), strict=True)]
    ahead, Dh, rate = _coming(model, D)
    if ahead.size:
        moved = D(_square_root(P)) @ Dh.T  # (d, k)
        sds = np.sqrt(np.sum(moved * moved, axis=0)) / np.abs(rate)
        found += list(zip(ahead.tolist(), sds.tolist(), strict=True))
    with np.errstate(divide="ignore", invalid="ignore"):
        return min(((gap / sd if sd > 0 else np.inf, gap, sd) for gap, sd in found),
                   default=None)


def end_gap(model, D, dt):
    """The time between the step's end ``dt`` and the nearest event of the mean's
    trajectory: those ``D`` holds (crossed before ``dt``) and those about to cross after
    it (first order at ``D.x_final``: ``-h_k / (Dh_k f)`` where positive). ``inf`` when
    there is none."""
    gaps = [dt - t for t in D.group_times] + _coming(model, D)[0].tolist()
    return min(gaps, default=np.inf)


def _coming(model, D):
    """The events about to cross after the step's end, first order at ``D.x_final``: their
    times from the end ``-h_k / r_k`` (k,), event Jacobian rows (k, d) and rates ``r_k =
    Dh_k f`` (k,), for the k events whose time is finite and not negative."""
    x = np.asarray(D.x_final)
    h = np.asarray(model.calls.eval_events(x), float)
    Dh = np.asarray(model.calls.eval_event_jacobian(x), float)
    rate = Dh @ np.asarray(D.final_field)
    with np.errstate(divide="ignore", invalid="ignore"):
        ahead = -h / rate
    coming = np.flatnonzero(np.isfinite(ahead) & (ahead >= 0))
    return ahead[coming], Dh[coming], rate[coming]


def _square_root(P):
    """(d, d): rows whose outer products sum to the covariance P (its eigenvectors scaled
    by the square roots of the eigenvalues, negative roundings clipped)."""
    w, U = np.linalg.eigh(P)
    return (U * np.sqrt(np.clip(w, 0.0, None))).T
