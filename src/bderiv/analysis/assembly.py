"""The B-derivatives a model gives: at one group of events, and along a trajectory.

:func:`group_bderivative` samples a model at a group's event point (event Jacobian rows,
region fields where the state lands, resets and their Jacobians) and builds the group's
:class:`~bderiv.engine.bderivative.BDerivative` in the group's local orientation;
:func:`flow_map_along` composes one per group of a trajectory integrated with its
variational equations into a :class:`~bderiv.analysis.flowmap.FlowBDerivative` (mathematics.md
sections 2, 7 and 9). Here rather than in :mod:`bderiv.analysis.flowmap`, which only composes given
stages: the assembly needs the model, and the map should not import the model side.
"""

from __future__ import annotations

import numpy as np

from .._limits import SIDE_SHRINK, SIDE_STEP
from .._numerics import RESET_MISMATCH
from .._support._format import format_mask, noted_at, transversality_message
from .._support._tables import INT64_EVENTS, block_bits, dense_table_bytes
from .._support._validate import check_memory
from ..engine.bderivative import BDerivative
from ..models.events.crossings import apply_resets, landing
from ..models.events.finaltime import FinalTimeMap
from .flowmap import FlowBDerivative

__all__ = ["flow_map_along", "group_bderivative", "merge_groups", "point_bderivative",
           "spread_masks"]


def spread_masks(events, mask_before):
    """Global masks of all 2**g local masks of a group (bit j of local: event events[j]
    crossed, i.e. its bit of ``mask_before`` flipped, whichever the direction): int64, or
    Python ints where a bit beyond 62 is set or flipped."""
    wide = max(events, default=0) >= INT64_EVENTS or mask_before >> INT64_EVENTS
    glob = np.empty(1 << len(events), dtype=object if wide else np.int64)
    glob[0] = mask_before
    for j, k in enumerate(events):  # the local masks with bit j set: those without, flipped
        glob[1 << j : 2 << j] = glob[: 1 << j] ^ (1 << k if wide else np.int64(1) << k)
    return glob


def group_bderivative(system, x, events, mask_before, mask_after=None, *, where="at rho",
                      event_jacobian=None, hint=""):
    """BDerivative of the group ``events`` at ``x`` (a checked state: float64, (d,),
    finite) entered from region ``mask_before``.

    Built in the group's local orientation: the rows of ``Dh`` of the events crossed
    downward (bit set in ``mask_before``) are negated, and local mask bit j means
    "event ``events[j]`` happened". Its global bit is flipped, except for the events
    whose bits ``mask_after`` (default: all flipped) keeps: a reset sent the state back
    (a bounce, a leg swap), and the field after it is that of the region it came from
    (mathematics.md section 9). Only the rates of pending events must be positive.
    ``event_jacobian`` (n, d): the checked event Jacobian at ``x`` when the caller has it
    (the stop's, :class:`~bderiv.models.events.crossings.EventGroup`), else evaluated;
    ``hint`` ends a transversality refusal (what the caller's point assumes).
    """
    calls = system.calls
    events = tuple(int(k) for k in events)
    # the group's 2**g regions are sampled from the model and kept as a dense table
    check_memory(dense_table_bytes(len(events), calls.dim), None,
                 f"the corner tables of {len(events)} events at once (the fields of their "
                 f"2**{len(events)} regions, sampled from the model)")
    sign = np.array([-1.0 if mask_before >> k & 1 else 1.0 for k in events])
    if event_jacobian is None:
        event_jacobian = calls.eval_event_jacobian(x)
    Dh = sign[:, None] * event_jacobian[list(events)]
    _refuse_state_switching(calls, x, events, Dh, mask_before, where)
    glob = spread_masks(events, mask_before)  # every event's bit flipped
    if calls.has_resets:
        base, R = sample_resets(calls, x, events, glob, Dh, sign, where)
        lands = (1 << len(events)) - 1  # local bits of the events whose bit flips
        if mask_after is not None:
            lands = sum(1 << j for j, k in enumerate(events)
                        if (mask_before ^ mask_after) >> k & 1)
        regions = glob[np.arange(glob.size) & lands]  # the bits of bounces kept
        F = np.array([calls.eval_field(b, int(m)) for b, m in zip(base, regions,
                                                                 strict=True)])
    else:
        F = calls.corners_at(x, glob)
    G = F @ Dh.T
    ok = G > 0
    if calls.has_resets:  # the rates of the events that happened may have either sign
        ok |= block_bits(slice(0, G.shape[0]), len(events)) != 0
    if np.count_nonzero(ok) != ok.size:
        i, j = (int(v) for v in np.argwhere(~ok)[0])
        region = format_mask(int(glob[i]), calls.n_events)
        if sign[j] < 0:
            where += f" (event {events[j]} crossed downward: the rate is that of -h)"
        raise ValueError(transversality_message(events[j], region, G[i, j], where) + hint)
    if calls.has_resets:
        try:
            return BDerivative._from_checked(Dh, F, resets=R, reset_tol=calls.reset_tol)
        except ValueError as exc:  # the existence check: say where
            raise ValueError(f"{where} (events {list(events)}): {exc}") from None
    return BDerivative._from_checked(Dh, F)  # Dh, F: made here from checked samples


def sample_resets(calls, x, events, glob, Dh, sign, where):
    """Base points and reset Jacobians of a group (mathematics.md section 9), by the
    model's checked ``calls``.

    ``base[B]`` (2**g, d) is ``x`` moved by the resets of the events of local mask B
    (ascending; each called with the global mask before its crossing), ``R[B, j]``
    (2**g, g, d, d) the Jacobian of the reset of ``events[j]`` at ``base[B]``. Refuses
    resets that move a pending surface or change its gradient (beyond ``reset_tol``
    relative to ``|Dh_k|``): the events would not stay simultaneous.
    """
    g, d = len(events), calls.dim
    base = np.empty((1 << g, d))
    base[0] = x
    R = np.zeros((1 << g, g, d, d))
    h0, tol = calls.eval_events(x)[list(events)], calls.reset_tol
    scale = np.abs(Dh).sum(axis=1) * max(1.0, float(np.abs(x).max()))
    for B in range(1 << g):
        if B:
            top = B.bit_length() - 1
            rest = B & ~(1 << top)
            base[B] = calls.eval_reset(base[rest], int(glob[rest]), events[top])
        pending = [j for j in range(g) if not B >> j & 1]
        h = calls.eval_events(base[B])[list(events)]
        Dh_B = sign[:, None] * calls.eval_event_jacobian(base[B])[list(events)]
        for j in pending:
            moved = max(abs(h[j] - h0[j]) / scale[j],
                        float(np.abs(Dh_B[j] - Dh[j]).max() / np.abs(Dh[j]).max()))
            if not moved <= tol:
                raise ValueError(
                    f"{where}: the resets of the events of region "
                    f"{format_mask(int(glob[B]), calls.n_events)} move the surface of "
                    f"event {events[j]}, still pending (value or gradient, by {moved:.3g} "
                    f"relative, tolerance {tol:g}): the events would not stay "
                    f"simultaneous and the flow has no B-derivative there"
                )
            R[B, j] = calls.eval_reset_jacobian(base[B], int(glob[B]), events[j])
    return base, R


def _refuse_state_switching(calls, x, events, Dh, mask, where) -> None:
    """Refuse a field that jumps across an event's surface with the region ``mask`` held:
    one that switches on the state (``2.0 if x[1] > 0 else 1.0``) and ignores its mask.
    Its corners sampled at the event point are all one region's, and the map was the
    identity, silently (the flow jumps there). A jump stays as the step across shrinks
    by SIDE_SHRINK; a smooth field's change (or a kink's) shrinks with it."""
    scale = max(1.0, float(np.abs(x).max()))
    for j, k in enumerate(events):
        length = np.hypot.reduce(Dh[j])  # (not squared: a gradient of 1e-200 is one)
        if not 0.0 < length < np.inf:  # no surface to cross: transversality says so
            continue
        normal = Dh[j] / length
        jumps = []
        for step in (SIDE_STEP * scale, SIDE_STEP * scale / SIDE_SHRINK):
            ahead = calls.eval_field(x + step * normal, mask)
            behind = calls.eval_field(x - step * normal, mask)
            jumps.append(float(np.abs(ahead - behind).max()))
            size = max(float(np.abs(ahead).max()), float(np.abs(behind).max()))
        if jumps[1] > 0.5 * jumps[0] and jumps[1] > 1e-9 * size:
            raise ValueError(
                f"field(x, mask={format_mask(mask, calls.n_events)}) jumps by {jumps[1]:.3g} "
                f"across the surface of event {k} {where}, with the mask held: the field "
                f"switches on the state there, not on its mask. Each region's field must "
                f"be smooth across the surfaces (bit k of mask says which side of event k "
                f"the state is on): write the switch with the mask")


def _group_map(system, g):
    """:func:`group_bderivative` of the event group ``g`` of a run (the time on the note
    of an exception a model's function raises there: a reset's Jacobian, say)."""
    with noted_at(g.time):
        return group_bderivative(system, g.state, g.events, g.mask_before, g.mask_after,
                                 where=f"at the event point at t={g.time:.10g}",
                                 event_jacobian=g.event_jacobian)


class ResetAtStart(ValueError):
    """A first event group with resets within ``simultaneity_tol`` of the start
    (:func:`_refuse_reset_at_start`): ``time`` its time, ``events`` its events."""

    def __init__(self, message, time, events):
        super().__init__(message)
        self.time, self.events = time, events


def _refuse_reset_at_start(groups, tol) -> None:
    """Refuse a first event group with resets within ``tol`` after the start (t = 0): a
    perturbation of the start larger than that crosses its surface before the start,
    where the reset does not apply, and the flow jumps (no B-derivative), as for a group
    with resets at the final time."""
    if groups and groups[0].time <= tol:
        g = groups[0]
        raise ResetAtStart(
            f"an event group with resets at the start: event(s) {list(g.events)} cross at "
            f"t = {g.time:.3g}, within simultaneity_tol={tol:g} of it, so a perturbation of "
            f"x0 larger than that starts beyond their surface, the reset never applies and "
            f"the flow map jumps there: it has no B-derivative. Start farther from the "
            f"surface (or after the impact), or pass a simultaneity_tol below {g.time:.3g} "
            f"for the map of the perturbations smaller than that", g.time, list(g.events))


def flow_map_along(system, traj):
    """The :class:`FlowBDerivative` along a trajectory integrated with its variational
    equations (``run(..., variational=True)``): one BDerivative per event group.

    Groups switched within the run's ``simultaneity_tol`` of the first of them, with no
    event in two of them, are merged into one (:func:`merge_groups`): the run switched
    each at its own time, so its state is the true one, and the map is the group's
    B-derivative at the nearby point where they are simultaneous (its entries off by the
    first order of the gap), which a perturbation larger than the gap meets.
    ``FlowBDerivative.group_spreads`` says how far apart each group's events were; a
    ``simultaneity_tol`` below the gap gives the map of the separated events instead.
    """
    groups, linear = list(traj.groups), list(traj.linear)
    if len(linear) != len(groups) + 1:
        raise ValueError(f"traj holds no sensitivities (traj.linear has {len(linear)} "
                         f"matrices for {len(groups)} event groups; simulate does not "
                         f"integrate them): call flow_bderivative(x0, t_final), which does")
    if system.calls.has_resets:
        _refuse_reset_at_start(groups, traj.simultaneity_tol)
    times = [(g.time, g.time) for g in groups]
    final_field = system.calls.eval_field(traj.x_final, traj.mask_final)
    if traj.final_pending:  # a group just after t_final: its map is stopped there too
        groups.append(traj.final_group)
        linear.append(np.eye(system.calls.dim))
        times.append((min(traj.final_times), max(traj.final_times)))
        final_field = system.calls.eval_field(traj.x_final, traj.final_group.mask_after)
    apart = landed_by_resets(system.calls) if system.calls.has_resets else None
    groups, linear, spreads = merge_groups(groups, linear, times, traj.simultaneity_tol,
                                           apart)
    jumps = [_group_map(system, g) for g in groups]
    if traj.final_group is not None:  # the final time is one more event of the group
        jumps[-1] = FinalTimeMap(jumps[-1])
    return FlowBDerivative(
        linear, jumps, final_field=final_field,
        group_times=[g.time for g in groups], group_events=[g.events for g in groups],
        group_masks=[(g.mask_before, g.mask_after) for g in groups], group_spreads=spreads,
        group_states=[g.state for g in groups], x0=traj.x[0], x_final=traj.x_final,
        t_final=float(traj.t[-1]),
    )


def merge_groups(groups, linear, times, tol, apart=None):
    """Consecutive event groups within ``tol`` of the first of them merged into one,
    unless ``apart(head, group)`` (:func:`landed_by_resets`).

    Parameters
    ----------
    groups : list of EventGroup
        In time order.
    linear : list of ndarray (d, d)
        The stages around them: ``len(groups) + 1``.
    times : list of (float, float)
        The first and last crossing time of each group's events.
    tol : float
        A group joins the one before when its last event crosses within ``tol`` of the
        first event of that one and none of its events is in it (an event crossed and
        crossed back is two crossings, never one group).

    Returns
    -------
    groups, linear, spreads
        The merged groups (each at the state, time and event Jacobian of its first, with
        the masks before the first and after the last), their stages (the stages between
        merged groups dropped: the identity to the first order of the gap), and each
        group's spread: its last crossing time less its first.

    Examples
    --------
    >>> from bderiv.models.events.crossings import EventGroup
    >>> a = EventGroup(1.0, (0,), 0b00, 0b01, np.zeros(2))
    >>> b = EventGroup(1.0 + 5e-8, (1,), 0b01, 0b11, np.ones(2))
    >>> merged, stages, spreads = merge_groups([a, b], [np.eye(2)] * 3,
    ...                                        [(1.0, 1.0), (1.0 + 5e-8, 1.0 + 5e-8)], 1e-7)
    >>> merged[0].events, merged[0].mask_after, len(stages), [round(s, 12) for s in spreads]
    ((0, 1), 3, 2, [5e-08])
    """
    out, stages, spreads = [], [linear[0]], []
    first = 0.0
    for g, (start, end), after in zip(groups, times, linear[1:], strict=True):
        if out and end - first <= tol and not set(g.events) & set(out[-1].events) and \
                not (apart is not None and apart(out[-1], g)):
            head = out[-1]
            out[-1] = head._replace(events=tuple(sorted(head.events + g.events)),
                                    mask_after=g.mask_after, state_after=g.state_after)
            stages[-1] = after
            spreads[-1] = max(spreads[-1], end - first)
            continue
        out.append(g)
        stages.append(after)
        first = start
        spreads.append(end - start)
    return out, stages, spreads


def landed_by_resets(calls):
    """``apart(head, group)``: whether the resets of the group ``head`` moved the surface
    of an event of ``group`` (its value, by more than ``reset_tol`` relative as
    :func:`sample_resets` measures it). Such events are crossed because of those resets
    (a reset that sets a contact's coordinate to 0 puts the state on its surface), after
    them from every nearby start, however close in time: their group stays apart.
    Merged, they were taken as simultaneous with the head's and refused, the flow said
    to have no B-derivative where it is smooth."""

    def apart(head, group):
        events = list(group.events)
        before = calls.eval_events(head.state)[events]
        after = calls.eval_events(head.state_after)[events]
        scale = np.abs(calls.eval_event_jacobian(head.state)[events]).sum(axis=1) * \
            max(1.0, float(np.abs(head.state).max()))
        return bool(np.any(np.abs(after - before) > calls.reset_tol * scale))

    return apart


def point_bderivative(system, rho, tol):
    """The BDerivative of all n events at ``rho`` (checked: every event value within
    ``tol``), entered from region 0: :meth:`HybridSystem.bderivative
    <bderiv.analysis.system.HybridSystem.bderivative>`. With resets, where each event lands is
    decided by :func:`bderiv.models.events.crossings.landing` as in a simulation, and the resets
    must
    commute as maps (:func:`bderiv.models.events.crossings.apply_resets`), rho taken to be
    accurate to
    ``reset_tol`` relative (of ``max(1, max |rho|)``).
    """
    calls = system.calls
    hint = ("; rho is entered from region 0, every event crossed upward (from h_k < 0): for "
            "one crossed downward negate its h_k, or take flow_bderivative, which orients "
            "each group")
    if not calls.has_resets:
        return group_bderivative(system, rho, range(calls.n_events), 0, hint=hint)
    events, accuracy = list(range(calls.n_events)), calls.reset_tol * max(
        1.0, float(np.abs(rho).max()))
    context = (f"at rho (taken as t=0, its integration accuracy as reset_tol="
               f"{calls.reset_tol:g} relative)")
    after = apply_resets(calls, events, 0, rho, 0.0, np.inf)  # orders compared below
    window = np.maximum(accuracy * np.abs(calls.eval_event_jacobian(after)).sum(axis=1), tol)
    try:
        mask_after = landing(calls, events, 0, after, window)
    except ValueError as exc:
        raise ValueError(f"{context}: {exc}") from None
    bd = group_bderivative(system, rho, events, 0, mask_after, hint=hint)
    try:
        apply_resets(calls, events, 0, rho, 0.0, RESET_MISMATCH * accuracy)
    except ValueError as exc:
        raise ValueError(f"{context}: {exc}") from None
    return bd
