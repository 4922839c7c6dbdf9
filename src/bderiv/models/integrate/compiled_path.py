"""One stretch of a region in compiled code: the compiled integrator of a run.

:class:`CompiledStretches` is :class:`bderiv.models.integrate.scipy_path.ScipyStretches`'s twin
for a
model whose ``field``, ``events`` (and ``field_jacobian``, and the section) are numba
dispatchers: the stretch runs in :mod:`bderiv.models.compiled`'s driver (scipy's DOP853, no Python
call per step) and comes back with solve_ivp's fields (``t``, ``y``, ``t_events``,
``status``, and ``sol``, the state's dense output; ``pieces``, the dense output of each
integration of the stretch), so that everything at a stop (location,
grouping, crossings inside a step, the final time) is the same code for both integrators:
:func:`bderiv.models.integrate.run.run`, :mod:`bderiv.models.events.locate`,
:mod:`bderiv.models.events.crossings`,
:mod:`bderiv.models.events.excursions`, :mod:`bderiv.models.events.finaltime`.
"""

from __future__ import annotations

import numpy as np

from ..compiled import EVENT, dense_at
from ..events.excursions import without_lost_crossings


class DenseOutput:
    """The state's dense output over a compiled stretch: ``sol(t)``, shape (d,) or
    (d, len(t)), scipy's ``Dop853DenseOutput`` on each step (evaluated in compiled code).

    Parameters
    ----------
    steps : ndarray, shape (S, 2)
        Start time and size of each step.
    F : ndarray, shape (S, 7, d)
        The coefficients of each step.
    y_old : ndarray, shape (S, d)
        The state at each step's start.
    """

    def __init__(self, steps, F, y_old):
        self.steps, self.F, self.y_old = steps, F, y_old
        self._record = None  # the contiguous arrays dense_at takes, made at the first call

    def __call__(self, t):
        if self._record is None:
            self._record = (np.ascontiguousarray(self.steps[:, 0]),
                            np.ascontiguousarray(self.steps[:, 1]), self.F,
                            np.ascontiguousarray(self.y_old))
        y = dense_at(*self._record, np.atleast_1d(t))
        return y[0] if np.ndim(t) == 0 else y.T


#: the crossing times of an event that did not stop a stretch (shared: read-only)
_NO_CROSSING = np.empty(0)
_NO_CROSSING.flags.writeable = False


class CompiledSolution:
    """A compiled stretch with solve_ivp's fields: ``t`` (N,), ``y`` (m, N), ``t_events``
    (the earliest crossing's event; one list per watched value), ``status`` (1: stopped at
    a crossing, 0: at the final time), ``sol`` (:class:`DenseOutput` of the state),
    ``first_step_end`` (the end of the first step, beyond the stop when it is in it)."""

    def __init__(self, out, d, watched):
        self.t, self.y = out.ts, out.ys.T
        self.status = 1 if out.status == EVENT else 0
        self.t_events = [_NO_CROSSING] * watched
        if self.status:  # as solve_ivp's terminal events: the first root, lowest index
            first = out.roots.tolist().index(out.t_end)
            self.t_events[first] = np.array([out.t_end])
        self.sol = DenseOutput(out.steps, out.Fd, out.ys[:-1, :d])  # >= 1 step each
        # the end of the first step (beyond the stop when an event stopped it there)
        self.first_step_end = float(out.steps[0, 0] + out.steps[0, 1])


class CompiledStretches:
    """The stretches of a run in compiled code: ``stretches(x, t, t_final, mask, options,
    variational) -> CompiledSolution``.

    Parameters
    ----------
    system : ModelCalls (``HybridSystem.calls``)
        Its compiled model (``system.compiled``), and its checked evaluations at stops.
    section : numba dispatcher, optional
        ``section(x) -> float``: watched upward after the events.
    stops : StopCalls, optional
        The run's evaluations at the stops
        (:class:`bderiv.models.events.stopcalls.StopCalls`), for the search of crossings
        inside the steps; default ``system``.
    watch : SimulationProgress, optional
        The run's bar, told the time reached after each slice of steps.
    """

    def __init__(self, system, section=None, stops=None, watch=None):
        self.system, self.model, self.section = system, system.compiled, section
        self.stops = system if stops is None else stops
        self.watch = watch

    def __call__(self, x, t, t_final, mask, options, variational):
        """Integrate region ``mask`` from ``(t, x)`` until ``t_final``, an event or the
        section; the state and its (d, d) sensitivity (row-major) with ``variational``."""
        system, d = self.system, self.system.dim
        watched = system.n_events + (self.section is not None)
        if variational:
            system.check_compiled_jacobian(x, mask)
            y0 = np.concatenate((x, np.eye(d).ravel()))
        else:
            y0 = x

        pieces = []  # each integration's start and dense output (record.dense_state)

        def solve(start, y_start, stop):
            out = self.model.stretch(
                y_start, start, stop, mask, rtol=options.rtol, atol=options.atol,
                max_step=options.max_step, variational=variational, section=self.section,
                forced=self.section is not None and start == 0.0, on_side=start == t,
                watch=self.watch)
            sol = CompiledSolution(out, d, watched)
            pieces.append((start, sol.sol))
            return sol

        sol = without_lost_crossings(self.stops, mask, options, solve, t, y0, t_final,
                                     events_at=self.model.events_rows)
        sol.pieces = pieces
        return sol
