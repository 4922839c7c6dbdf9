"""The driver: one stretch of one region, from ``t0`` to ``t_final`` or the first event.

:func:`drive_stretch` is compiled once (at its first call, then cached on disk): the
model's dispatchers come as first-class functions (pointers, of the types of :mod:`._rhs`)
in one struct (:mod:`._model`) whose type is the same for every model, so a new model does
not recompile the driver. It repeats
``solve_ivp(method="DOP853")``'s loop: the first step by ``select_initial_step``, each step
tried and shrunk until the error norm is below one, the events evaluated at each accepted
step, and at a crossing the dense output built and the crossing located on it.

A call returns after ``max_steps`` accepted steps (``PAUSED``, with the next step size):
called again from there with that first step, it goes on with the same steps, so that a
long stretch comes back to Python (and to Ctrl-C) now and then.
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
    dense_point,
    error_norm,
    initial_step,
    stages,
    step_factor,
    step_point,
)
from ._rhs import OK, call_events, rhs, state_events
from ._watch import crossed, locate

#: the stretch reached ``t_final`` / stopped at an event crossing / the step size fell
#: below 10 ulp of t (scipy's TOO_SMALL_STEP) / returned after ``max_steps`` steps; other
#: codes: a failed check of :mod:`._rhs`
FINISHED = -1
EVENT = -2
STEP_UNDERFLOW = -3
PAUSED = -4
#: entries of the returned counters
NFEV, NJEV, N_STEPS, N_REJECTED = range(4)
_DENSE_EXTRA = N_STAGES_EXTENDED - N_STAGES - 1
#: the value of an event at 0 at a run's stretch's start, on its side (``on_side``)
_TINY = np.finfo(np.float64).tiny


@njit(cache=True, inline="always")
def room(a, need):
    """``a``, or a copy of it (its dtype) with room for ``need`` rows along its first axis:
    at least twice as many."""
    if need <= a.shape[0]:
        return a
    b = np.empty((max(2 * a.shape[0], need),) + a.shape[1:], dtype=a.dtype)
    flat, old = b.ravel(), a.ravel()
    # element loops here and in the compiled run, no slice assignment of an array: numba
    # compiles that one's shape-mismatch error (its message formats the shapes: str of
    # ints, join) for each pair of dimensions, about a second of CPU each
    for i in range(old.size):
        flat[i] = old[i]
    return b


@njit(cache=True)
def _stopped(status, t, y, ts, ys, gs, count, steps, Fd, n_dense, active, roots, counts,
             bad, t_bad, h_abs):
    """The driver's result tuple (records cut to their lengths)."""
    return (status, t, y, ts[:count], ys[:count], steps[:n_dense], Fd[:n_dense], active,
            roots, counts, bad, t_bad, h_abs, gs[:count])


@njit(cache=True, nogil=True)
def drive_stretch(model, jac_mode, variational, with_section, n_events, mask, d, t0, y0,
                  t_final, rtol, atol, max_step, first_step, forced, on_side, max_steps,
                  dense):
    """Integrate region ``mask`` from ``(t0, y0)`` to ``t_final`` or the first crossing.

    ``y0`` is the state (length d) or the state and the sensitivity (length d + d * d,
    ``variational``, J by ``jac_mode``); ``atol`` has one entry per component of ``y0``;
    ``first_step`` 0 selects it as scipy does. ``n_events`` values are watched: the model's
    events, and its section last when ``with_section`` (upward: its bit of ``mask`` is
    clear); the value of event ``forced`` (-1: none) reads 1 at the start (a run that
    starts on its section counts only a return from below). With ``on_side`` (a run's
    stretch), a model event whose value at ``t0`` is 0 reads ``+-tiny`` on the side its
    bit of ``mask`` says there, as :func:`bderiv.models.events.sides.on_side_at_start`
    makes solve_ivp read it (else a value leaving 0 counts as a crossing at ``t0``). No
    validation.

    Returns
    -------
    status : int
        ``FINISHED``, ``EVENT``, ``PAUSED``, ``STEP_UNDERFLOW`` or a failed check of
        :mod:`._rhs`.
    t_end : float
    y_end : ndarray, shape (m,)
    ts, ys : ndarray, shapes (N,), (N, m)
        The record: the start, every accepted step's end, the stop.
    steps, Fd : ndarray, shapes (S, 2), (S, 7, d)
        With ``dense`` (else empty): each step's start time and size, and the
        coefficients of the state's dense output over it (the last step's cover the whole
        step, also when the stretch stopped inside it).
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
    h_abs : float
        The size of the next step (to go on after ``PAUSED``).
    gs : ndarray, shape (N, n_events)
        The watched values at the record's states (the driver's own evaluations: the same
        bits as a call at ``ys[i]``); NaN in the row of an event stop (not evaluated
        there).
    """
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
    ys = np.empty((64, m))
    gs = np.full((64, n_events), np.nan)
    steps = np.empty((64 if dense else 0, 2))
    Fd = np.empty((64 if dense else 0, INTERPOLATOR_POWER, d))
    ts[0] = t0
    for j in range(m):
        ys[0, j] = y[j]
    # int64 values, never literals: a callee is compiled for each literal type it sees
    # (room for 0 and 1 while the loop is typed, _stopped for each status code)
    count, n_dense = np.int64(1), np.int64(0)
    jev = 1 if variational else 0

    t = t0
    status = rhs(model, jac_mode, variational, mask, d, y, K[0], bad)
    counts[NFEV] += 1
    counts[NJEV] += jev
    if status == OK:  # not inlined (the step's call is): once per stretch
        status = call_events(model, with_section, y[:d], n_events, g, bad)
    if status != OK:
        return _stopped(status, t, y, ts, ys, gs, count, steps, Fd, n_dense, active, roots,
                        counts, bad, t, 0.0)
    for k in range(n_events):
        gs[0, k] = g[k]
    if on_side:
        for k in range(n_events - with_section):
            if g[k] == 0.0:
                g[k] = _TINY if mask >> k & 1 else -_TINY
    if forced >= 0:
        g[forced] = 1.0
    h_abs = first_step
    if h_abs == 0.0:
        status, h_abs = initial_step(model, jac_mode, variational, mask, d, t0, y, K[0],
                                     t_final, max_step, rtol, atol, work, bad)
        counts[NFEV] += 1
        counts[NJEV] += jev
        if status != OK:
            return _stopped(status, t, y, ts, ys, gs, count, steps, Fd, n_dense, active, roots,
                            counts, bad, t, 0.0)

    while True:
        min_step = 10.0 * abs(np.nextafter(t, np.inf) - t)
        h_abs = min(max(h_abs, min_step), max_step)
        rejected = False
        while True:  # scipy's RungeKutta._step_impl
            if h_abs < min_step:
                for j in range(d):
                    bad[j] = y[j]
                return _stopped(np.int64(STEP_UNDERFLOW), t, y, ts, ys, gs, count,
                                steps, Fd, n_dense,
                                active, roots, counts, bad, t, h_abs)
            t_new = min(t + h_abs, t_final)
            h = t_new - t
            h_abs = abs(h)
            # the step: stages 1 to 12, each point through y_new, the last the solution
            status = stages(model, jac_mode, variational, mask, d, y, K, 1, N_STAGES + 1, h,
                            m, y_new, bad, step_point)
            counts[NFEV] += N_STAGES
            counts[NJEV] += jev * N_STAGES
            if status != OK:
                return _stopped(status, t, y, ts, ys, gs, count, steps, Fd, n_dense, active,
                                roots, counts, bad, t, h_abs)
            err = error_norm(K, h, y, y_new, rtol, atol, work)
            h_abs *= step_factor(err, rejected)
            if err < 1.0:
                break
            rejected = True
            counts[N_REJECTED] += 1
        counts[N_STEPS] += 1
        status = state_events(model, with_section, y_new, d, n_events, g_new, bad)
        if status != OK:
            return _stopped(status, t_new, y_new, ts, ys, gs, count, steps, Fd, n_dense, active,
                            roots, counts, bad, t_new, h_abs)
        event = n_events > 0 and crossed(g, g_new, mask, active)
        # at a crossing the whole vector's dense output (the stop's state and sensitivity),
        # else the state's, computed straight into the record when that is all it needs
        whole = event and variational
        if dense:
            steps = room(steps, n_dense + 1)
            Fd = room(Fd, n_dense + 1)
            steps[n_dense, 0] = t
            steps[n_dense, 1] = h
        coef = F if whole or not dense else Fd[n_dense]
        if event or dense:
            status = stages(model, jac_mode, whole, mask, d, y, K, N_STAGES + 1,
                            N_STAGES_EXTENDED, h, coef.shape[1], work[0], bad, dense_point)
            if status == OK:
                dense_coefficients(y, y_new, h, K, coef)
            counts[NFEV] += _DENSE_EXTRA
            counts[NJEV] += _DENSE_EXTRA if whole else 0
            if status != OK:
                return _stopped(status, t_new, y_new, ts, ys, gs, count, steps, Fd, n_dense,
                                active, roots, counts, bad, t_new, h_abs)
            if dense:
                if whole:
                    for i in range(INTERPOLATOR_POWER):
                        for j in range(d):
                            Fd[n_dense, i, j] = F[i, j]
                n_dense += 1
        ts = room(ts, count + 1)
        ys = room(ys, count + 1)
        gs = room(gs, count + 1)
        if event:
            t_stop = t_new
            for k in range(n_events):
                if active[k] and status == OK:
                    status, roots[k] = locate(model, with_section, k, g[k], coef, y, t,
                                              t_new, x, g_new, bad)
                    t_stop = min(t_stop, roots[k])
            if status != OK:
                return _stopped(status, t_new, y_new, ts, ys, gs, count, steps, Fd, n_dense,
                                active, roots, counts, bad, t_new, h_abs)
            dense_eval(coef, y, t, h, t_stop, m, y_new)
            ts[count] = t_stop
            for j in range(m):
                ys[count, j] = y_new[j]
            for k in range(n_events):
                gs[count, k] = np.nan  # the stop's values are not evaluated
            return _stopped(np.int64(EVENT), t_stop, y_new, ts, ys, gs, count + 1,
                            steps, Fd, n_dense,
                            active, roots, counts, bad, t_stop, h_abs)
        t = t_new
        for j in range(m):  # element loops: no views, no slice assignments
            y[j] = y_new[j]
            K[0, j] = K[N_STAGES, j]
            ys[count, j] = y_new[j]
        for k in range(n_events):
            g[k] = g_new[k]
            gs[count, k] = g_new[k]
        ts[count] = t
        count += 1
        if t >= t_final:
            return _stopped(np.int64(FINISHED), t, y, ts, ys, gs, count,
                            steps, Fd, n_dense, active,
                            roots, counts, bad, t, h_abs)
        if counts[N_STEPS] >= max_steps:
            return _stopped(np.int64(PAUSED), t, y, ts, ys, gs, count, steps, Fd, n_dense, active,
                            roots, counts, bad, t, h_abs)
