"""The sides of the surfaces at a stretch's ends: a stretch that starts exactly on a
surface read by solve_ivp on the side its region says (:func:`on_side_at_start`), and the
region after a stop checked against the event values there (:func:`check_sides`,
:func:`check_carried`; their arithmetic is :mod:`bderiv.models.compiled.rules`, which the
compiled run calls too)."""

from __future__ import annotations

import numpy as np

from ..._support._format import format_mask
from ..._support._validate import scratch
from ._python_rules import rules

__all__ = ["check_carried", "check_sides", "on_side_at_start"]


def on_side_at_start(funcs, t0, mask, n):
    """solve_ivp event functions for a stretch from ``t0`` that read an event exactly on
    its surface at ``t0`` on the side its bit of ``mask`` says.

    solve_ivp takes a value 0 at a step's start as the end of a crossing, and places the
    root there: a stretch that starts exactly on a surface (a located stop can land with
    ``h_k == 0.0``) would otherwise stop at once, crossing nothing.

    Parameters
    ----------
    funcs : list of callables ``f(t, y)``
        The terminal event functions, the first ``n`` for the events in order (further
        ones, a section, are kept as they are).
    t0 : float
    mask : int
    n : int

    Returns
    -------
    list of callables
        With the ``terminal`` and ``direction`` attributes of ``funcs``.

    Examples
    --------
    >>> def f(t, y):
    ...     return y[0]
    >>> g, = on_side_at_start([f], 1.0, 0b0, 1)
    >>> float(g(1.0, [0.0])) < 0.0, float(g(1.5, [0.0]))
    (True, 0.0)
    """
    tiny = np.finfo(np.float64).tiny

    def on_side(func, side):
        def ev(t, y):
            value = func(t, y)
            return side * tiny if t == t0 and value == 0.0 else value

        ev.terminal = getattr(func, "terminal", False)
        ev.direction = getattr(func, "direction", 0)
        return ev

    return ([on_side(f, 1.0 if mask >> k & 1 else -1.0) for k, f in enumerate(funcs[:n])]
            + list(funcs[n:]))


def check_sides(h, mask, window, t):
    """Refuse a region ``mask`` that disagrees with the event values ``h`` (n,) after the
    stop at ``t`` (its group switched, its resets applied): every event must be on the
    side its bit says (set: ``h_k > 0``), or within its ``window`` (n,) of the surface (a
    located event a rounding across it, an event switched with it on its way there: the
    excursion screen looks for a return inside the steps from such a start,
    :mod:`bderiv.models.events.excursions`).

    Raises
    ------
    ValueError
        Naming the time, the event, its value, its window and the mask.

    Examples
    --------
    >>> check_sides(np.array([-1.0, 1e-19]), 0b00, np.array([1e-9, 1e-9]), 0.5)
    >>> check_sides(np.array([-1.0, 1e-3]), 0b00, np.array([1e-9, 1e-9]), 0.5)
    Traceback (most recent call last):
    ...
    ValueError: after the stop at t=0.5 event 1 is on the wrong side of its surface:
    h_1 = 0.001, beyond its window 1e-09 (the accuracy of the stop), where region mask 0b00
    (bit k set: h_k > 0) says h_1 < 0; the run lost track of a crossing (an internal error:
    please report it with the model)
    """
    h = scratch(h)
    k = rules.wrong_side(h, int(mask), scratch(window))
    if k < 0:
        return
    says = ">" if mask >> k & 1 else "<"
    raise ValueError(
        f"after the stop at t={t:.10g} event {k} is on the wrong side of its surface: "
        f"h_{k} = {h[k]:.3g}, beyond its window {window[k]:.3g} (the accuracy of the stop), "
        f"where region mask {format_mask(int(mask), h.size)} (bit k set: h_k > 0) says "
        f"h_{k} {says} 0; the run lost track of a crossing (an internal error: please "
        f"report it with the model)"
    )


def check_carried(system, h, mask, window, group, x, t):
    """Refuse an event that reads a rounding across its surface after the stop at ``t``
    (``h`` (n,) at the state ``x`` after the group ``group``, within its ``window``: what
    :func:`check_sides` lets pass) and that the field of region ``mask`` carries further
    across (:func:`bderiv.models.compiled.rules.carried_across`; both paths).

    Its crossing is at once, at the stop's point, and the integrator reads the event across
    at both ends of every step: it would be lost, the run going on in a region the state
    has left. It comes where events cross in turn at one point: the end of a trajectory
    that spirals into the intersection of their surfaces faster than the crossings can be
    counted (:mod:`bderiv.models.events.zeno`), or a corner met within the accuracy.

    Raises
    ------
    ValueError
        Naming the time, the event, its value, its window, its rate and the region.
    """
    h, window = scratch(h), scratch(window)
    skip = sum(1 << k for k in group)
    if not rules.reads_across(h, int(mask), window, skip):
        return
    J, F = scratch(system.eval_event_jacobian(x)), scratch(system.eval_field(x, mask))
    k = rules.carried_across(h, int(mask), window, skip, J, F)
    if k < 0:
        return
    says = ">" if mask >> k & 1 else "<"
    raise ValueError(
        f"after the events {list(group)} at t={t:.10g} event {k} is a rounding across its "
        f"surface (h_{k} = {h[k]:.3g}, within its window {window[k]:.3g}, where region mask "
        f"{format_mask(int(mask), h.size)} says h_{k} {says} 0) and the field of that "
        f"region carries it further across (dh_{k}/dt = {float(J[k] @ F):.3g}): it crosses "
        f"at once, at the same point, and the integrator cannot locate that crossing "
        f"(events crossing in turn at one point: a trajectory that spirals into the "
        f"intersection of their surfaces, a Zeno accumulation, or a corner met within the "
        f"integration accuracy); end the run before t={t:.10g}, or tighten rtol and atol"
    )
