"""A run's stretches and stops in compiled code, as long as every stop is a plain one.

:func:`run_stretches` repeats, in one compiled call, what the run loop of
:func:`bderiv.models.integrate.run.run` does for each stretch of a compiled model: the
driver integrates the region to the final time or the first crossing, the excursion
screen samples the dense output, the stop is examined (state error, rates, windows,
classes) and the group switched after its transversality checks, all by the rules of
:mod:`.rules` that the Python stop logic calls too, on the same values, so the bits are
the same. A stop that needs more is handed back: the function returns the run's state
before that stretch, and the Python loop integrates the stretch and decides its stop (a
peak to search inside a step, a return across a surface, undecided events of a
derivative, a refusal to word, a model with resets, a region whose field Jacobian is not
yet checked, a full step budget, a failed check of a user function). What this function
records is then exactly what the Python loop would have.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..._limits import REACH
from ._dop853 import dense_rows
from ._integrate import EVENT, FINISHED, N_STEPS, drive_stretch
from ._rhs import OK, argument, call_events, events_rows
from .rules import (
    GROUP,
    NEAR,
    UNDECIDED,
    classify,
    first_grazing,
    local_rates,
    peak_rows,
    return_sample,
    sample_times,
    state_error,
    tolerances,
    windows,
)

#: the run ended (final time or the section) / the next stretch is the Python loop's
ENDED = 0
HANDOFF = 1


@njit(cache=True)
def _room(a, need):
    """``a``, or a copy with room for ``need`` rows along its first axis (its dtype)."""
    if need <= a.shape[0]:
        return a
    b = np.empty((max(2 * a.shape[0], need),) + a.shape[1:], dtype=a.dtype)
    b[:a.shape[0]] = a
    return b


@njit(cache=True)
def _event_jacobian(model, x, n, d):
    """The model's event Jacobian at ``x``: ``(ok, J)``, J (n, d) checked (shape, finite)."""
    J = model.event_jacobian(argument(model, x))
    if J.shape[0] != n or J.shape[1] != d:
        return False, np.zeros((n, d))
    for v in J.ravel():
        if not np.isfinite(v):
            return False, J
    return True, np.ascontiguousarray(J).copy()


@njit(cache=True)
def _field(model, x, mask, d):
    """``(ok, field(x, mask))``, checked (shape, finite)."""
    f = model.field(argument(model, x), mask)
    if f.size != d:
        return False, f
    for v in f:
        if not np.isfinite(v):
            return False, f
    return True, f


@njit(cache=True)
def _plain_screen(model, sign, n, d, ts, ys, steps, Fd, J, atol, rtol):
    """Whether the excursion screen finds nothing to search on the stretch (no sampled
    peak that could reach a surface, no return across one); False also on a failed check."""
    count = ts.size
    times = np.empty(2 * count - 1)
    sample_times(ts, times)
    states = np.empty((times.size, d))
    dense_rows(np.ascontiguousarray(steps[:, 0]), np.ascontiguousarray(steps[:, 1]), Fd,
               np.ascontiguousarray(ys[:-1, :d]), times, states)
    H = np.empty((times.size, n))
    if events_rows(model, states, n, H, np.zeros(d)) != OK:
        return False
    scale = np.zeros(d)
    for r in range(times.size):
        for k in range(n):
            H[r, k] *= sign[k]
        for i in range(d):
            scale[i] = max(scale[i], abs(states[r, i]))
    err = np.empty(d)
    state_error(atol, rtol, scale, np.zeros(d), err)
    tol = np.empty(n)
    tolerances(J, err, tol)
    return return_sample(H, tol) < 0 and peak_rows(H, tol, True, REACH).shape[0] == 0


@njit(cache=True)
def run_stretches(model, jac_mode, variational, with_section, n, d, t, x, mask, scale, err,
                  t_final, rtol, atol, max_step, simultaneity_tol, all_checked, checked,
                  groups_left, budget):
    """The run's stretches from ``(t, x)`` in region ``mask`` while the stops are plain.

    ``scale``, ``err`` (d,): the largest ``|x_i|`` so far and the error bound carried into
    the stretch; ``atol`` (m,): the driver's, one per integrated component; ``checked``
    (int64 masks): the regions whose field Jacobian is checked (``variational``, unless
    ``all_checked``; a region outside them is handed back); ``groups_left``: the groups
    the run may still switch; ``budget``: accepted steps before handing back (Ctrl-C).

    Returns
    -------
    code : int
        ``ENDED`` or ``HANDOFF``.
    returned : bool
        The run ended at the section.
    t, x, mask, scale, err
        The run's state after the recorded stretches.
    T, X, M : ndarray, shapes (N,), (N, d), (N,)
        Their samples and masks (as ``Trajectory``'s).
    L : ndarray, shape (S, d, d)
        Their sensitivities at their ends (``variational``).
    group_t, group_bits, mask_before, mask_after : ndarray, shape (G,)
        Their event groups: time, events (bits), masks.
    group_x : ndarray, shape (G, d)
    group_J : ndarray, shape (G, n, d)
        The event Jacobian at each group's state (``variational``).
    steps : int
        Accepted steps taken, the stretch handed back included.
    """
    m = d * (d + 1) if variational else d
    T = np.empty(64)
    X = np.empty((64, d))
    M = np.empty(64, dtype=np.int64)
    L = np.empty((8 if variational else 0, d, d))
    group_t = np.empty(8)
    group_bits = np.empty(8, dtype=np.int64)
    mask_before = np.empty(8, dtype=np.int64)
    mask_after = np.empty(8, dtype=np.int64)
    group_x = np.empty((8, d))
    group_J = np.empty((8 if variational else 0, n, d))
    count, stretches, groups, steps = np.int64(0), np.int64(0), np.int64(0), np.int64(0)
    sign = np.empty(n)
    code, returned = HANDOFF, False
    while True:
        if variational and not all_checked and not (checked == mask).any():
            break
        for k in range(n):
            sign[k] = -1.0 if mask >> k & 1 else 1.0
        y0 = np.zeros(m)
        y0[:d] = x
        if variational:
            for i in range(d):
                y0[d + i * d + i] = 1.0
        forced = n if with_section and t == 0.0 else -1
        status, t_end, y_end, ts, ys, steps_, Fd, active, roots, counts, _, _, _ = \
            drive_stretch(model, jac_mode, variational, with_section, n + with_section, mask,
                          d, t, y0, t_final, rtol, atol, max_step, 0.0, forced,
                          budget - steps, True)
        steps += counts[N_STEPS]
        if status != EVENT and status != FINISHED:
            break
        x_end = y_end[:d].copy()
        ok, J = _event_jacobian(model, x_end, n, d)
        if not ok or not _plain_screen(model, sign, n, d, ts, ys, steps_, Fd, J, atol[0],
                                       rtol):
            break
        grown = scale.copy()
        for r in range(ts.size):
            for i in range(d):
                grown[i] = max(grown[i], abs(ys[r, i]))
        err_new = np.empty(d)
        state_error(atol[0], rtol, grown, err, err_new)
        first = -1  # the located crossing: the lowest index of the earliest root
        if status == EVENT:
            for k in range(n + with_section):
                if roots[k] == t_end:
                    first = k
                    break
        event = 0 <= first < n
        if event:
            h = np.empty(n)
            if call_events(model, False, x_end, n, h, np.empty(d)) != OK:
                break
            ok, F = _field(model, x_end, mask, d)
            if not ok:
                break
            Dh, rate = np.empty((n, d)), np.empty(n)
            local_rates(sign, J, F, Dh, rate)
            for k in range(n):
                h[k] *= sign[k]
            fired = np.zeros(n, dtype=np.bool_)
            fired[first] = True
            window, codes = np.empty(n), np.empty(n, dtype=np.int64)
            windows(Dh, rate, err_new, fired, window)
            classify(h, rate, window, fired, simultaneity_tol, codes)
            if (codes & NEAR).any() or (variational and (codes & UNDECIDED).any()):
                break
            group = (codes & GROUP) != 0
            if first_grazing(group, Dh, F) >= 0:
                break
            bits = np.int64(0)
            for k in range(n):
                if group[k]:
                    bits |= np.int64(1) << k
            new = mask ^ bits
            ok, F_new = _field(model, x_end, new, d)
            if not ok or first_grazing(group, Dh, F_new) >= 0 or groups >= groups_left:
                break
        # the stretch is the Python loop's too: recorded
        need = count + ts.size
        T, X, M = _room(T, need), _room(X, need), _room(M, need)
        for r in range(ts.size):
            T[count + r] = ts[r]
            X[count + r] = ys[r, :d]
            M[count + r] = mask
        count += ts.size
        if variational:
            L = _room(L, stretches + 1)
            L[stretches] = ys[-1, d:].reshape((d, d))
        stretches += 1
        t, x, scale, err = t_end, x_end, grown, err_new
        if status == EVENT and first == n:  # the return to the section
            code, returned = ENDED, True
            break
        if not event:
            code = ENDED
            break
        group_t, group_bits = _room(group_t, groups + 1), _room(group_bits, groups + 1)
        mask_before, mask_after = _room(mask_before, groups + 1), _room(mask_after, groups + 1)
        group_x = _room(group_x, groups + 1)
        group_t[groups], group_bits[groups] = t, bits
        mask_before[groups], mask_after[groups] = mask, new
        group_x[groups] = x
        if variational:
            group_J = _room(group_J, groups + 1)
            group_J[groups] = J
        groups += 1
        mask = new
        if t >= t_final:
            code = ENDED
            break
    return (code, returned, t, x, mask, scale, err, T[:count], X[:count], M[:count],
            L[:stretches], group_t[:groups], group_bits[:groups], mask_before[:groups],
            mask_after[:groups], group_x[:groups], group_J[:groups], steps)
