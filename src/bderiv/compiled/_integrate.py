"""The driver: one stretch of one region, from ``t0`` to ``t_final`` or the first event.

:func:`drive_stretch` is compiled once (at its first call, then cached on disk): the
model's dispatchers come as first-class functions (pointers, of the types of :mod:`._rhs`)
in one struct (:mod:`._model`) whose type is the same for every model, so a new model does
not recompile the driver. It repeats
``solve_ivp(method="DOP853")``'s loop: the first step by ``select_initial_step``, each step
tried and shrunk until the error norm is below one, the events evaluated at each accepted
step, and at a crossing the dense output built and the crossing located on it.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ._dop853 import (
    INTERPOLATOR_POWER,
    N_STAGES,
    N_STAGES_EXTENDED,
    dense_coefficients,
    dense_eval,
    error_norm,
    initial_step,
    step,
    step_factor,
)
from ._rhs import OK, call_events, rhs
from ._watch import crossed, locate

#: the stretch reached ``t_final`` / stopped at an event crossing / the step size fell
#: below 10 ulp of t (scipy's TOO_SMALL_STEP); other codes: a failed check of :mod:`._rhs`
FINISHED = -1
EVENT = -2
STEP_UNDERFLOW = -3
#: entries of the returned counters
NFEV, NJEV, N_STEPS, N_REJECTED = range(4)

@njit(cache=True)
def _record(ts, xs, count, t, y, d):
    """Append ``(t, y[:d])`` to the record, doubling its buffers when full."""
    if count == ts.size:
        ts2 = np.empty(2 * ts.size)
        xs2 = np.empty((2 * ts.size, d))
        ts2[:count] = ts
        xs2[:count] = xs
        ts, xs = ts2, xs2
    ts[count] = t
    xs[count] = y[:d]
    return ts, xs, count + 1


@njit(cache=True)
def drive_stretch(model, variational, n_events, mask, d, t0, y0, t_final, rtol, atol,
                  max_step, first_step):
    """Integrate region ``mask`` from ``(t0, y0)`` to ``t_final`` or the first crossing.

    ``y0`` is the state (length d) or the state and the sensitivity (length d + d * d,
    ``variational``); ``atol`` has one entry per component of ``y0``; ``first_step`` 0
    selects it as scipy does. No validation.

    Returns
    -------
    status : int
        ``FINISHED``, ``EVENT``, ``STEP_UNDERFLOW`` or a failed check of :mod:`._rhs`.
    t_end : float
    y_end : ndarray, shape (m,)
    ts : ndarray, shape (N,)
        Times of the record (the start, the accepted steps, the stop).
    xs : ndarray, shape (N, d)
    active : ndarray, shape (n,), bool
        Events that crossed in the last step.
    roots : ndarray, shape (n,)
        Their crossing times; NaN for the others.
    counts : ndarray, shape (4,), int64
        ``NFEV``, ``NJEV``, ``N_STEPS``, ``N_REJECTED``.
    bad : ndarray, shape (d,)
        The state of a failed check or of the step-size underflow.
    t_bad : float
        Its time.
    """
    field, jac, events = model.field, model.jacobian, model.events
    m = y0.size
    counts = np.zeros(4, dtype=np.int64)
    bad = np.zeros(d)
    active = np.zeros(n_events, dtype=np.bool_)
    roots = np.full(n_events, np.nan)
    K = np.empty((N_STAGES_EXTENDED, m))
    F = np.empty((INTERPOLATOR_POWER, m))
    work = np.empty((3, m))
    y = y0.copy()
    y_new = np.empty(m)
    g = np.empty(n_events)
    g_new = np.empty(n_events)
    x = np.empty(d)
    ts = np.empty(64)
    xs = np.empty((64, d))
    count = 0
    ts, xs, count = _record(ts, xs, count, t0, y, d)
    jev = 1 if variational else 0

    t = t0
    status = rhs(field, jac, variational, mask, d, y, K[0], bad)
    counts[NFEV] += 1
    counts[NJEV] += jev
    if status == OK:
        status = call_events(events, y[:d], n_events, g, bad)
    if status != OK:
        return status, t, y, ts[:count], xs[:count], active, roots, counts, bad, t
    h_abs = first_step
    if h_abs == 0.0:
        status, h_abs = initial_step(field, jac, variational, mask, d, t0, y, K[0], t_final,
                                     max_step, rtol, atol, work, bad)
        counts[NFEV] += 1
        counts[NJEV] += jev
        if status != OK:
            return status, t, y, ts[:count], xs[:count], active, roots, counts, bad, t

    while True:
        min_step = 10.0 * abs(np.nextafter(t, np.inf) - t)
        h_abs = min(max(h_abs, min_step), max_step)
        rejected = False
        while True:  # scipy's RungeKutta._step_impl
            if h_abs < min_step:
                bad[:] = y[:d]
                return STEP_UNDERFLOW, t, y, ts[:count], xs[:count], active, roots, counts, \
                    bad, t
            t_new = min(t + h_abs, t_final)
            h = t_new - t
            h_abs = abs(h)
            status = step(field, jac, variational, mask, d, y, h, K, y_new, work[0], bad)
            counts[NFEV] += N_STAGES
            counts[NJEV] += jev * N_STAGES
            if status != OK:
                return status, t, y, ts[:count], xs[:count], active, roots, counts, bad, t
            err = error_norm(K, h, y, y_new, rtol, atol)
            h_abs *= step_factor(err, rejected)
            if err < 1.0:
                break
            rejected = True
            counts[N_REJECTED] += 1
        counts[N_STEPS] += 1
        status = call_events(events, y_new[:d], n_events, g_new, bad)
        if status != OK:
            return status, t_new, y_new, ts[:count], xs[:count], active, roots, counts, bad, \
                t_new
        if n_events > 0 and crossed(g, g_new, mask, active):
            status = dense_coefficients(field, jac, variational, mask, d, y, y_new, h, K, F,
                                        work[0], bad)
            counts[NFEV] += N_STAGES_EXTENDED - N_STAGES - 1
            counts[NJEV] += jev * (N_STAGES_EXTENDED - N_STAGES - 1)
            t_stop = t_new
            for k in range(n_events):
                if active[k] and status == OK:
                    status, roots[k] = locate(events, k, F, y, t, t_new, x, g_new, bad)
                    t_stop = min(t_stop, roots[k])
            if status != OK:
                return status, t_new, y_new, ts[:count], xs[:count], active, roots, counts, \
                    bad, t_new
            dense_eval(F, y, t, h, t_stop, m, y_new)
            ts, xs, count = _record(ts, xs, count, t_stop, y_new, d)
            return EVENT, t_stop, y_new, ts[:count], xs[:count], active, roots, counts, bad, \
                t_stop
        t = t_new
        y[:] = y_new
        K[0] = K[N_STAGES]
        g[:] = g_new
        ts, xs, count = _record(ts, xs, count, t, y, d)
        if t >= t_final:
            return FINISHED, t, y, ts[:count], xs[:count], active, roots, counts, bad, t
