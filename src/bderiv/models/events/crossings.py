"""Event crossings at a stop of the integrator: the event log and the switching rule.

A region is named by the signs of the event functions (bit k of the mask set iff
``h_k(x) > 0``). A surface may be crossed upward (``h_k`` from negative to positive: the
bit is set) or downward (the bit is cleared), any number of times. At each stop of the
integrator :func:`switch` decides which events cross together (one :class:`EventGroup`),
checks every crossing is transversal before it, applies the resets, decides where each
event lands (:func:`landing`: on the far side, its bit flipped; back on the side it came
from, a bounce or a leg swap, its bit unchanged) and returns the mask after them. Which
events are at the stop is decided by the rules of :mod:`bderiv.models.events.locate` (each event's
window).

In a group's **local orientation** an event crossed downward has its function negated
(``-h_k``), so that every event of the group is crossed upward: the group's B-derivative
is then the one of mathematics.md (rows of ``Dh`` negated, mask bits flipped for those events).
"""

from __future__ import annotations

import itertools
from typing import NamedTuple

import numpy as np

from ..._numerics import GLOBAL_ERROR_FACTOR, GRAZING_RTOL, ORDERS_CHECKED, RESET_MISMATCH
from ..._support._format import format_mask, transversality_message
from ..._support._validate import scratch
from ._python_rules import rules
from .locate import examine, flags_of, state_error
from .stopcalls import orientation

__all__ = [
    "GLOBAL_ERROR_FACTOR",
    "EventGroup",
    "EventRecord",
    "apply_resets",
    "group_tolerance",
    "holds",
    "Switched",
    "landing",
    "switch",
]


def direction_name(direction: int) -> str:
    """``"upward"`` for +1, ``"downward"`` for -1."""
    return "upward" if direction > 0 else "downward"


class EventRecord(NamedTuple):
    """One line of the event log: ``event`` crossed at ``time``; ``mask`` is the region
    mask after its group.

    ``direction`` is +1 for an upward crossing (``h_k`` from negative to positive), -1 for
    a downward one. Its bit of ``mask`` is flipped, except after an impact whose reset
    sends the state back to the side it came from (a bounce, a leg swap: mathematics.md
    section 9, "Where a reset lands").
    """

    time: float
    event: int
    mask: int
    direction: int


class EventGroup(NamedTuple):
    """Events that crossed together at one stop of the integrator.

    Attributes
    ----------
    time : float
        Time of the first event of the group (the integrator's stop).
    events : tuple of int
        Global indices of the events that crossed, ascending.
    mask_before, mask_after : int
        Region masks before and after the group: ``mask_after = mask_before ^ bits`` of
        the events that landed on the far side (all of them without resets).
    state : ndarray, shape (d,)
        State at ``time``, before the group.
    state_after : ndarray, shape (d,)
        State after the group: ``state`` moved by the resets of its events (a model with
        resets), else ``state`` itself.
    event_jacobian : ndarray, shape (n, d), or None
        The checked event Jacobian at ``state`` as the stop evaluated it (kept by a run
        with variational equations, read-only, for the group's B-derivative), else None.
    directions : tuple of int (property)
        +1 (upward) or -1 (downward) for each event of ``events``.
    bounced : tuple of int (property)
        Events of the group whose reset sent the state back to the side it came from (a
        bounce, a leg swap): their bits of ``mask_after`` are not flipped.
    """

    time: float
    events: tuple
    mask_before: int
    mask_after: int
    state: np.ndarray
    state_after: np.ndarray | None = None
    event_jacobian: np.ndarray | None = None

    @property
    def directions(self) -> tuple:
        return tuple(-1 if self.mask_before >> k & 1 else 1 for k in self.events)

    @property
    def bounced(self) -> tuple:
        return tuple(k for k in self.events if not (self.mask_before ^ self.mask_after) >> k & 1)


class Switched(NamedTuple):
    """The switch at a stop (:func:`switch`).

    Attributes
    ----------
    group : list of int
        The events that cross, ascending.
    new : int
        The mask after them: the bits of the events that landed on the far side flipped
        (all of them without resets; :func:`landing`).
    x_after : ndarray, shape (d,)
        The state after their resets (:func:`apply_resets`; ``x`` without resets).
    """

    group: list
    new: int
    x_after: np.ndarray


def group_tolerance(Dh: np.ndarray, options, scale) -> np.ndarray:
    """Largest ``|h_k(x)|`` at which event k counts as being at the stop ``x``, from the
    state's error alone: shape (n,).

    The integrator keeps each component's step error below ``atol + rtol * |x_i|``; with
    ``scale`` the largest ``|x_i|`` met so far (a float, or one per component: shape (d,)),
    the state's error is bounded by :func:`bderiv.models.events.locate.state_error`, and ``h_k``
    moves by
    at most ``sum_i |Dh[k, i]| err_i``: only the components event k depends on count. At a
    stop, :func:`switch` adds the uncertainty of the stop's own time
    (:func:`bderiv.models.events.locate.windows`).

    Examples
    --------
    An event that does not depend on a large coordinate is not widened by it:

    >>> from bderiv.models.integrate.options import SolverOptions
    >>> group_tolerance(np.array([[1.0, 0.0]]), SolverOptions(), np.array([1e-3, 500.0]))
    array([1.1e-11])
    """
    Dh = scratch(Dh)
    err = state_error(options.atol, options.rtol,
                      np.broadcast_to(np.asarray(scale, dtype=np.float64), Dh.shape[1:]))
    out = np.empty(Dh.shape[0])
    rules.tolerances(Dh, scratch(err), out)
    return out


def switch(system, fired, mask, x, t, options, err, stop=None) -> Switched:
    """The events that cross at the stop ``(t, x)`` and the mask after them.

    Parameters
    ----------
    system : ModelCalls
        The model's checked calls (``HybridSystem.calls``).
    fired : list of int
        Events the integrator located at this stop.
    mask : int
        Region mask before the stop.
    x : ndarray, shape (d,)
    t : float
    options : SolverOptions
        The run's settings. Events at ``x`` to within their window
        (:func:`bderiv.models.events.locate.windows`) are switched with the located ones;
        those whose time is known only to more than its ``simultaneity_tol`` were settled
        before (:func:`bderiv.models.events.locate.settle`). Events
        within this time of crossing but measurably later are not switched: each stops the
        integrator at its own time, so the state is the true one (a flow map merges such
        groups: :func:`bderiv.analysis.assembly.flow_map_along`).
    err : ndarray, shape (d,)
        Bound on the error of ``x``, per component
        (:func:`bderiv.models.events.locate.state_error`).
    stop : Stop, optional
        :func:`bderiv.models.events.locate.examine` at ``x`` with these ``err`` and
        ``fired`` (:func:`bderiv.models.events.locate.settle` made it); made here when not
        given.

    Returns
    -------
    Switched
        ``group``, ``new``, ``x_after``.

    Raises
    ------
    ValueError
        On a grazing crossing (a rate that is not clearly of the crossing's sign before
        it, or after it where the state stays on the surface: the time, event and
        direction are named), and on resets that
        disagree, jump across another surface or leave the state on a surface it neither
        leaves nor crosses.
    """
    n = system.n_events
    if stop is None:
        stop = examine(system, mask, x, err, fired, options)
    sign, h, Dh, F, rate, window, classes = stop
    # crossed, located or not (two surfaces crossed in one step): always switched, so
    # none is ever lost (bderiv.models.events.locate.classify); events within
    # options.simultaneity_tol but measurably later are switched at their own time
    group = classes.group
    flags = flags_of(group, n)
    _check_crossings(group, flags, Dh, F, mask, "before", t, sign, n)
    if not system.has_resets:  # every event lands on the far side, and must move on
        new = mask ^ sum(1 << k for k in group)
        _check_crossings(group, flags, Dh, system.eval_field(x, new), new, "after", t, sign,
                         n)
        return Switched(group, new, x)
    x_after = apply_resets(system, group, mask, x, t, RESET_MISMATCH * float(err.max()))
    _check_jumps(sign * system.eval_events(x_after), group, window, t)
    return Switched(group, landing(system, group, mask, x_after, window, t), x_after)


def landing(system, group, mask, x_after, window, t=None):
    """The region mask after ``group``, crossed from region ``mask``, whose resets took the
    state to ``x_after`` (mathematics.md section 9, "Where a reset lands").

    In each event's crossing orientation (``s_k h_k`` crosses upward), with ``window`` (n,)
    the accuracy of the event values: an event that lands beyond its window on the far
    side has its bit flipped; one that lands beyond it on the side it came from (a leg
    swap) keeps its bit; on the surface, the flow decides: a rate in the region with the
    bit flipped that is clearly positive flips it (a crossing, an impact that stays in
    contact); one too small to tell (a plastic impact that stops the state on the surface)
    flips it where that region holds the state, its field or field Jacobian there not the
    same as the region's with the bit kept (a compliant or constrained stance:
    :func:`holds`); where the rate is clearly negative,
    one clearly negative in the region with the bit kept too keeps it (a bounce).

    Raises
    ------
    ValueError
        When the flow sends the state back in the region with the bit flipped and not in
        the region with it kept: it would slide along the surface (a Filippov sliding
        mode), which is not an event; and when a plastic landing is not held: the flow is
        the same on both sides of the surface, so the state would pass through it (the
        time, the event, and what to do are named: :func:`_refuse_unheld`).
    """
    n = system.n_events
    new = mask ^ sum(1 << k for k in group)
    sign = orientation(int(mask), n)
    h = sign * system.eval_events(x_after)
    Dh = sign[:, None] * system.eval_event_jacobian(x_after)
    field = system.eval_field(x_after, new)
    kept = 0
    for k in group:
        if h[k] > window[k]:
            continue
        if h[k] >= -window[k]:  # on the surface: the flow after the reset decides
            if _clearly_positive(Dh[k], field):  # moves on: contact continues
                continue
            back = system.eval_field(x_after, new ^ 1 << k)
            if not _clearly_positive(-Dh[k], field):  # stops on the surface (plastic)
                if not holds(system, x_after, new, new ^ 1 << k, field, back):
                    _refuse_unheld(k, h[k], window[k], float(Dh[k] @ field), new, sign[k], n,
                                   t)
                continue
            if not _clearly_positive(-Dh[k], back):
                at = "" if t is None else f" at t={t:.10g}"
                raise ValueError(
                    f"after the reset of event {k}{at} the state is on its surface "
                    f"(h_{k} = {h[k]:.3g}, within the accuracy {window[k]:.3g}) and the flow "
                    f"pushes it against the surface from both sides: the rate of h_{k} in "
                    f"the crossing's orientation is {float(Dh[k] @ field):.3g} in region "
                    f"{format_mask(new, n)} (the crossing completed) and "
                    f"{float(Dh[k] @ back):.3g} in region {format_mask(new ^ 1 << k, n)} "
                    f"(sent back), so the state would slide along the surface, which is "
                    f"not an event; event {k} crossed {direction_name(sign[k])}"
                )
        kept |= 1 << k
    if kept:  # some bounced: the rates in the region the state goes on in (the decisions
        # above read the region with every bit flipped)
        after = new ^ kept
        F = scratch(system.eval_field(x_after, after))
        k = rules.first_sent_back(flags_of(group, n), scratch(h), scratch(window),
                                  kept, scratch(Dh), F)
        if k >= 0:
            way = "bounced: the bit kept" if kept >> k & 1 else "crossed: the bit flipped"
            at = "" if t is None else f" at t={t:.10g}"
            raise ValueError(
                f"after the resets of events {list(group)}{at} event {k} is on its surface "
                f"(h_{k} = {h[k]:.3g}, within the accuracy {window[k]:.3g}; {way}) and the "
                f"region the state goes on in, {format_mask(after, n)}, sends it straight "
                f"back across (rate {float(Dh[k] @ F):.3g} of h_{k} in the crossing's "
                f"orientation): the group's landing is not an event; event {k} crossed "
                f"{direction_name(sign[k])}"
            )
    return new ^ kept


def holds(system, x, far, near, F_far=None, F_near=None) -> bool:
    """Whether region ``far`` holds a state ``x`` stopped on the surface between it and
    region ``near``: its field (``F_far``, evaluated when not given) or field Jacobian at
    ``x`` not the same as region ``near``'s (``F_near``), so the contact has dynamics of
    its own (:func:`bderiv.models.compiled.rules.same_flow`)."""
    F_far = system.eval_field(x, far) if F_far is None else F_far
    F_near = system.eval_field(x, near) if F_near is None else F_near
    J_far, J_near = (scratch(system.eval_field_jacobian(x, m)) for m in (far, near))
    return not rules.same_flow(scratch(F_near), scratch(F_far), J_near, J_far)


def _refuse_unheld(k, h, window, rate, far, sign, n, t):
    """Refuse a plastic landing of event k that region ``far`` does not hold (its flow
    the same as the region's on the near side): the state would pass through the surface
    (the bit flipped) or cross it again at once (kept: resting contact)."""
    at = "" if t is None else f" at t={t:.10g}"
    near = far ^ 1 << k
    until = "" if t is None else f" (t_final below {t:.10g})"
    raise ValueError(
        f"after the reset of event {k}{at} the state stops on its surface (h_{k} = {h:.3g}, "
        f"within the accuracy {window:.3g}; the rate of h_{k} in the crossing's orientation "
        f"is {rate:.3g}, too small to tell: a plastic impact, or a rebound too small to "
        f"follow at the end of an accumulation of impacts), but nothing holds it there: the "
        f"field of region {format_mask(far, n)} beyond the surface is the same as that of "
        f"region {format_mask(near, n)} before it (values and Jacobian), so with the bit "
        f"flipped the state would move on through the surface as if it were not there, and "
        f"with the bit kept it would cross it again at once (resting contact). Model the "
        f"contact as a region whose field holds the body on the surface (a compliant or "
        f"constrained stance), or end the run before this time{until}; event {k} crossed "
        f"{direction_name(sign)}"
    )


def _clearly_positive(dh, F) -> bool:
    """Whether the rate ``dh . F`` is positive beyond the grazing threshold
    (``GRAZING_RTOL |dh| |F|``: :func:`bderiv.models.compiled.rules.clearly_positive`)."""
    return bool(rules.clearly_positive(scratch(dh), scratch(F)))


def apply_resets(system, group, mask, x, t, accuracy):
    """The state after the resets of ``group`` from region ``mask`` at ``x`` (ascending
    order; each reset is called with the mask before its own crossing).

    Groups of up to ``ORDERS_CHECKED`` events are reset in every order, larger ones also
    in descending order; results further apart than ``accuracy`` (max norm) are refused:
    the resets do not commute, so the state after simultaneous events is not defined.
    """
    groups = (list(itertools.permutations(group)) if len(group) <= ORDERS_CHECKED
              else [tuple(group), tuple(reversed(group))])
    results = []
    for order in groups:
        y, b = x, mask
        for k in order:
            y = system.eval_reset(y, b, k)
            b ^= 1 << k
        results.append((order, y))
    first, y0 = results[0]
    for order, y in results[1:]:
        gap = float(np.abs(y - y0).max())
        if not gap <= accuracy:
            raise ValueError(
                f"the resets of events {list(group)}, simultaneous at t={t:.10g}, do not "
                f"commute: applied in the order {first} and {order} they give states "
                f"{gap:.3g} apart (max norm; accepted: {accuracy:.3g}, {RESET_MISMATCH:g} "
                f"times the integration accuracy), so the state after the events is not "
                f"defined and the flow has no B-derivative there"
            )
    return y0


def _check_jumps(h, group, tol, t):
    """Refuse resets that carry the state across the surface of an event not in the group
    (``h``: the event values after them, in the local orientation of the region before)."""
    for k in range(h.size):
        if k not in group and h[k] > tol[k]:
            raise ValueError(
                f"the resets of events {group} at t={t:.10g} carry the state across the "
                f"surface of event {k} (h_{k} = {h[k]:.3g} in the orientation it would be "
                f"crossed), a jump that is not a crossing; such models are not supported"
            )


def _check_crossings(group, flags, Dh, F, mask, when, t, sign, n):
    """Refuse a crossing of an event of ``group`` (``flags``: bool (n,)) whose rate
    ``Dh_k . F`` in region ``mask`` is not clearly positive (:func:`_clearly_positive`):
    grazing, or pushed back (``when``: "before" or "after" switching the group; ``Dh`` and
    ``sign``: the gradients and signs of the local orientation, all n events)."""
    k = rules.first_grazing(flags, scratch(Dh), scratch(F))
    if k >= 0:
        _refuse_crossing(k, Dh[k], F, mask, f"{when} switching events {group}", t, sign[k], n)


def _refuse_crossing(k, dh, F, mask, when, t, sign, n):
    """Refuse the crossing of event k (``dh``: its gradient in local orientation), whose
    rate ``dh . F`` in region ``mask`` is not clearly positive: grazing, or pushed back."""
    message = transversality_message(k, format_mask(mask, n), float(dh @ F),
                                     f"at t={t:.10g} {when}", GRAZING_RTOL * float(
                                         np.linalg.norm(dh) * np.linalg.norm(F)))
    message += " (the event would cross back)" if when.startswith("after") else (
        " (a grazing crossing)")
    downward = f" (the rate is that of -h_{k}, which crosses upward)" if sign < 0 else ""
    raise ValueError(f"{message}; event {k} crossed {direction_name(sign)}{downward}")

