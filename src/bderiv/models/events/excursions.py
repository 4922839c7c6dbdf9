"""Excursions inside a step: a surface crossed and crossed back between two step ends.

An integrator that compares the signs of the event functions at the ends of its steps
(solve_ivp's event detection) loses a surface that the trajectory crosses and crosses back
within one step: both ends are on the same side. An oscillator grazing its contact
surface for 0.03 time units, less than one DOP853 step, lost every one of its ten
contacts that way, and the final state was 31 % off, silently (docs/design.md,
"Excursions inside a step"). The rules below are plain functions of arrays (samples of
the dense output, event values, their windows), written once for any integrator; only
:func:`without_lost_crossings` deals with a solver. The samples and the peaks between them
(steps 1 and 2) are :mod:`bderiv.models.events.peaks`.

Along a stretch in one region every event is pending in its local orientation (``h_k < 0``
not yet crossed; the function negated for an event whose bit is set), so a crossing is a
point where ``h_k > 0``. With ``h`` sampled at the step ends (the integrator's own states)
and the midpoints of the steps (its dense output; :func:`sample_times`):

1. :func:`peak_brackets`: every sample that is a local maximum of ``h_k`` (not lower than
   its neighbours) and whose value could reach the surface,
   ``h_i + REACH (h_i - min(neighbours)) >= -tol_k``, gives a bracket: its neighbours'
   times. A smooth peak between samples rises above the highest sample by a fraction of
   the samples' spread; ``REACH`` is ten times that. The ends of the stretch are no peaks
   where the event is at its surface (just switched at the start, at the stop at the end).
2. The bracket is sampled again at ``FINE_SAMPLES`` points and screened with
   ``FINE_REACH``; on what is left :func:`peak_of` maximises ``h_k`` along the dense
   output (bounded Brent, to a relative time accuracy ``PEAK_XTOL``). A peak above
   ``tol_k`` is a crossing the integrator did not see; a peak within ``tol_k`` of the
   surface that rises above both ends of its bracket by more than ``tol_k`` cannot be
   decided at this accuracy (a grazing contact, where the flow has no B-derivative):
   refused. A peak at an end of the stretch is left to the switching rule
   (:func:`bderiv.models.events.crossings.switch`). A finer bracket at the end of the
   stretch where ``h_k`` rises (its rate ``Dh_k . F > 0`` there), or at its start where
   ``h_k`` falls, is not searched: with one maximum in the bracket (the search's own
   assumption: bounded Brent finds the maximum of such a function only) it is that end.
   These are the events about to cross just after a stop, or that crossed just before
   it (feet landing apart): the search found the end and gave it up, at about 25
   evaluations of the dense output and the events each (docs/mathematics.md, section 11).
3. :func:`_return`: a sample below the surface (``h_k < 0``) before a sample across it
   (``h_k > tol_k``, at no peak) is a return the integrator did not see: an event just
   switched, left a rounding on the side it came from by its located crossing, that
   comes back within the stretch's first step (both step ends read across).
   :func:`_start_dip`: such an event whose samples all read across until it rises in a
   step (both ends and the midpoint) is searched for its lowest value in that step; more
   than ``tol_k`` below the surface, or below it at all when a later sample reads the
   event clearly across (``h_k > tol_k``), it is a return the samples did not see either;
   never below it at all but clearly across later, it is refused (a return within a
   rounding of the surface, or none: undecidable).
4. :func:`_back_in_first_step`: a stretch that stops within its first step at an event
   that started it at its surface, leaving it, with a rate at the stop not clearly that
   of a crossing, has a return inside that step that the integrator's root search placed
   at the start, where the sides cannot be told apart: the return is searched from the
   deepest point of that excursion (bounded Brent on the step's dense output).
5. :func:`without_lost_crossings`: the stretch is integrated again from the last step end
   before the earliest lost crossing's bracket to its peak, where ``h_k > 0``, or, for a
   return, to the lowest sample (the deepest point: 3, 4) before it, and on from there:
   the sign change is at the ends of a step now, and the crossing is located as any
   other, its rate judged at its own point.

A step in which ``h_k`` rises and falls more than once is assumed to show one of its peaks
among the samples; a step long against the time scale of the events needs ``max_step``.
"""

from __future__ import annotations

import numpy as np

from ..._numerics import FINE_REACH, FINE_SAMPLES, REACH
from ..._support._validate import scratch
from ._python_rules import rules
from .crossings import group_tolerance
from .peaks import peak_brackets, peak_of, sample_times
from .stopcalls import StopCalls, local_rates

__all__ = ["REACH", "peak_brackets", "peak_of", "sample_times", "without_lost_crossings"]


def without_lost_crossings(system, mask, options, solve, t0, y0, t_end, events_at=None):
    """Integrate a stretch so that no surface is crossed unseen inside a step.

    Parameters
    ----------
    system : HybridSystem
        Its checked ``eval_events`` and ``eval_event_jacobian`` are used.
    mask : int
        The stretch's region (the events' local orientation).
    options : SolverOptions
        The tolerances of ``solve`` (for the windows,
        :func:`bderiv.models.events.crossings.group_tolerance`).
    solve : callable ``solve(t_start, y_start, t_stop) -> OdeResult``
        solve_ivp on the stretch's right-hand side and event functions, with dense output.
    t0 : float
    y0 : ndarray, shape (D,)
        Start of the stretch (the state first, then any variational part).
    t_end : float
    events_at : callable ``events_at(X) -> (m, n)``, optional
        The event values at the rows of ``X`` (m, d), checked (the compiled integrator
        gives them in one compiled call); default: ``system.eval_events`` row by row.

    Returns
    -------
    OdeResult-like
        ``t``, ``y``, ``t_events``, ``status``: the stretch up to its first crossing (now
        located), or to ``t_end``.

    Raises
    ------
    ValueError
        On a peak within the integration accuracy of a surface (undecidable).
    RuntimeError
        If a lost crossing is not located by the integration to its peak.
    """
    n = system.n_events
    sign = np.array([-1.0 if mask >> k & 1 else 1.0 for k in range(n)])
    if events_at is None:

        def events_at(X):
            return np.array([system.eval_events(x) for x in X])

    head_t, head_y = [], []
    sol = solve(t0, y0, t_end)
    while True:
        lost = _earliest_lost(system, mask, sign, options, sol, events_at)
        if lost is None:
            break
        i, t_peak, through = lost
        head_t.append(sol.t[:i])
        head_y.append(sol.y[:, :i])
        sol = solve(float(sol.t[i]), sol.y[:, i], t_peak)  # checked on the next pass
        if through and sol.status == 0:  # a step end below the surface: go on from it
            head_t.append(sol.t[:-1])
            head_y.append(sol.y[:, :-1])
            sol = solve(float(sol.t[-1]), sol.y[:, -1], t_end)
        elif sol.status != 1:
            raise RuntimeError(
                f"a crossing inside a step near t={t_peak:.10g} was not located by the "
                f"integration to its peak; pass a smaller max_step"
            )
    sol.t = np.concatenate([*head_t, sol.t])
    sol.y = np.concatenate([*head_y, sol.y], axis=1)
    return sol


def _earliest_lost(system, mask, sign, options, sol, events_at):
    """``(i, t, through)`` of the earliest crossing inside a step of ``sol``, or None: from
    the step end ``i`` integrate to the peak ``t`` (``through`` False), or to the time
    ``t`` below the surface before a return across it (``through`` True: :func:`_return`,
    :func:`_start_dip`)."""
    d = system.dim
    times = sample_times(sol.t)
    states = np.empty((times.size, d))
    states[0::2] = sol.y[:d].T  # the step ends: the integrator's own states
    states[1::2] = sol.sol(times[1::2])[:d].T  # the midpoints, on the dense output
    h = sign * events_at(states)
    scale = np.abs(states).max(axis=0)  # per component: only those an event reads count
    # the gradients at the stretch's end, the point the switching rule looks at (one
    # evaluation for both where the run keeps them: stopcalls.StopCalls)
    tol = group_tolerance(system.eval_event_jacobian(sol.y[:d, -1]), options, scale)
    # a peak at an end of the stretch is not an excursion: at the start the events were
    # just switched (one may sit a rounding across its surface), at the stop an event is
    # located, or across and switched with it (crossings.switch)
    rates = _EndRates(system, sign, mask, sol.y[:d, 0], sol.y[:d, -1])
    back = _back_in_first_step(system, mask, sign, sol, h, tol)
    if back is not None:
        return 0, back, True
    last = times.size - 1

    def value(t, k):
        return sign[k] * system.eval_events(sol.sol(t)[:d])[k]

    # a return the integrator did not see: (step end to integrate again from, time below)
    dip = _return(h, tol)
    through = None if dip is None else \
        (int(np.searchsorted(sol.t, times[dip], side="left")) - 1, float(times[dip]))
    start = _start_dip(h, tol, times, value)
    if start is not None and (through is None or start[1] < through[1]):
        through = start
    for k, lo, hi in peak_brackets(h, tol, stretch=True):
        if through is not None and times[lo] >= through[1]:
            break

        fine = np.empty(FINE_SAMPLES)
        rules.linspace(float(times[lo]), float(times[hi]), fine)
        v = sign[k] * events_at(sol.sol(fine)[:d].T)[:, k : k + 1]
        # a bracket at an end of the stretch that the event leaves from, or rises into,
        # peaks at that end, where the switching rule decides it (module docstring, 2)
        sub = [(a, b) for _, a, b in peak_brackets(v, tol[k : k + 1], reach=FINE_REACH)
               if not (lo == 0 and a == 0 and rates.start()[k] < 0.0)
               and not (hi == last and b == FINE_SAMPLES - 1 and rates.end()[k] > 0.0)]
        if not sub:
            continue
        t_peak, top = max((peak_of(lambda t, k=k: value(t, k), fine[a], fine[b])
                           for a, b in sub), key=lambda peak: peak[1])
        if not times[0] < t_peak < times[-1]:  # the ends were decided by the switching rule
            continue
        x_peak = sol.sol(t_peak)[:d]
        window = group_tolerance(system.eval_event_jacobian(x_peak)[k : k + 1], options,
                                 scale)[0]
        if top > window:
            return int(np.searchsorted(sol.t, times[lo], side="right")) - 1, t_peak, False
        if top >= -window and top > max(h[lo, k], h[hi, k]) + window:
            raise ValueError(
                f"event {k} comes within the integration accuracy of its surface at "
                f"t={t_peak:.10g} (its value peaks at {sign[k] * top:.3g}, known to "
                f"{window:.3g}): whether it crosses cannot be decided (a grazing contact, "
                f"where the flow has no B-derivative); tighten rtol and atol or move the "
                f"start point"
            )
    if through is not None:
        return (*through, True)
    return None


def _back_in_first_step(system, mask, sign, sol, h, tol):
    """A time inside the first step of ``sol`` where an event is clearly below its
    surface, when ``sol`` stopped within that step at a crossing of that event that is
    not clearly transversal, and the event started the stretch at its surface (just
    switched, leaving it); else None (module docstring, 4).

    The event then left its surface and came back across within the first step (a short
    excursion: an oscillator pushed back out of a region 9e-3 after entering it at rate
    0.014, in a step of 0.012). The integrator's event function reads the start on the
    side it leaves (:func:`bderiv.models.events.sides.on_side_at_start`) and the step's
    end across, and its root search settles within a rounding of the start, where the
    dense output cannot tell the sides apart and the rate is that of leaving: not a
    crossing. The deepest point of the excursion (bounded Brent on the step's dense
    output) is below the surface by the excursion's depth; integrated to it, the stretch
    has a step end on the side it left, and the return is located as any crossing, with
    its own rate.
    """
    if sol.status != 1 or sol.t.size != 2:
        return None
    d, x_stop = system.dim, sol.y[:system.dim, -1]
    Dh = sign[:, None] * system.eval_event_jacobian(x_stop)
    F = scratch(system.eval_field(x_stop, mask))
    for k in range(sign.size):
        if not (sol.t_events[k].size and abs(h[0, k]) <= tol[k]) or rules.clearly_positive(
                scratch(Dh[k]), F):
            continue

        def below(t, k=k):
            return -sign[k] * system.eval_events(sol.sol(t)[:d])[k]

        t_low, depth = peak_of(below, float(sol.t[0]), sol.first_step_end)
        if depth > tol[k]:
            return t_low
    return None


def _return(h, tol):
    """The earliest sample (index >= 1) below the surface, ``h_k < 0``, of an event that is
    across it, ``h_k > tol_k``, at a later sample; None if there is none.

    A stretch's integrator stops at the first crossing it sees, so a sample across a
    surface is one it did not see. Unless a peak between samples hides it, it is an event
    that started the stretch a rounding across its surface (just switched: the located
    crossing left it on the side it came from), left it and came back within the first
    step: both step ends read across, no sign change. Integrated again to the lowest
    sample before the return, the stretch has a step end below the surface there.
    """
    i = rules.return_sample(scratch(h), scratch(tol))
    return None if i < 0 else int(i)


def _start_dip(h, tol, times, value):
    """``(j, t)``: the earliest time t, inside step j, where an event that starts the
    stretch across its surface goes below it by more than its ``tol`` and comes back
    within the step, unseen; None if there is none (``value(t, k)``: event k on the dense
    output, local orientation).

    A located crossing can leave the switched event a rounding on the side it came from
    (its bit flipped, or kept by a bounce), so the next stretch starts with the event
    across: when it leaves its surface and comes back within a step, both ends of the
    step and its midpoint can read across, and the crossing is lost (the 1 g bar's
    liftoff leaving ``h_1 = +4e-22``: three crossings in 1.3 ms; docs/design.md,
    "Excursions inside a step"). Each step of the leading run of samples across in which
    the event rises above the step's start value (:func:`rules.start_dip_steps`; an event
    still on its way to its side falls) is searched for its lowest value along the dense
    output (bounded Brent, as a peak). A minimum below the surface by less than ``tol_k``
    counts too when a later sample reads the event clearly across: the dip of a group's
    member leaving at a small rate (-8.8e-5, back 5.7e-5 later, 1.2e-9 deep), else lost.
    """
    found = None
    for k, j in rules.start_dip_steps(scratch(h)).tolist():
        if found is not None and times[2 * j] >= found[1]:
            continue
        t_low, low = peak_of(lambda t, k=k: -value(t, k), times[2 * j], times[2 * j + 2])
        # within its tol below the surface, a dip is a return when the event is clearly
        # across later (the sample would be kept across the surface its bit does not say)
        later = 2 * j + 1 + int(np.argmax(h[2 * j + 1:, k]))
        if -low < -tol[k] or (-low < 0.0 and h[later, k] > tol[k]):
            found = (j, t_low)
        elif h[later, k] > tol[k]:
            # never below the surface, yet clearly across later: a return that the
            # dense output cannot show (a rebound or a leaving rate too small to follow),
            # or no crossing at all; neither can be located
            raise ValueError(
                f"event {k}, met by the stop at t={times[0]:.10g}, never reads below its "
                f"surface after it (its lowest value {-low:.3g} at t={t_low:.10g}) yet "
                f"reads {h[later, k]:.3g} across it at t={times[later]:.10g}, beyond its "
                f"accuracy {tol[k]:.3g}: the state went back across within a rounding of "
                f"the surface (a rebound too small to follow, as where impacts "
                f"accumulate, or a grazing contact), so whether and when it crossed cannot "
                f"be decided; end the run before t={times[0]:.10g}, tighten rtol and atol "
                f"or move the start point")
    return found


class _EndRates:
    """The events' rates ``Dh . F`` (local orientation) at the stretch's start and end,
    each evaluated at its first use: ``start()``, ``end()``, shape (n,).

    The end's gradients and field are those the switching rule asks for at the stop (kept
    by :class:`~bderiv.models.events.stopcalls.StopCalls`); the start's gradients are asked
    of the model itself, so that they do not replace the end's among the kept ones.
    """

    def __init__(self, system, sign, mask, x_start, x_end):
        self.system, self.sign, self.mask = system, sign, mask
        self.x_start, self.x_end = x_start, x_end
        self._start = self._end = None

    def start(self):
        if self._start is None:
            stops = self.system
            model = stops.system if isinstance(stops, StopCalls) else stops
            self._start = self._rate(model, self.x_start)
        return self._start

    def end(self):
        if self._end is None:
            self._end = self._rate(self.system, self.x_end)
        return self._end

    def _rate(self, model, x):
        return local_rates(self.sign, model.eval_event_jacobian(x),
                           self.system.eval_field(x, self.mask))[1]
