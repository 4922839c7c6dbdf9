"""The compiled driver's cost per step against a bare DOP853 loop, in one process.

``python benchmarks/driver_step.py`` takes the pronking body of ``compiled_path.py`` at
d = 8 and d = 44 (legs, modes = (2, 0) and (8, 12)), simulates one stride once to find its
stretches (start time, state, region), then times inside numba (no Python per stretch):

- ``driver``: ``_integrate.drive_stretch`` over the stride's stretches, as the compiled run
  calls it, with the dense output (``dense``) and without (``plain``);
- ``bare``: a DOP853 loop over the same stretches with the driver's stage kernel, error
  norm and step control, the field called directly (not through the model's struct) on a
  fresh copy of x, the events read at every step, and no checks, records or crossing
  search (each stretch run to the driver's end).

Rounds alternate the jobs; each number is the min over ``ROUNDS`` of the thread's CPU time
(the machine is shared) per accepted step. ``driver / bare`` is what the driver's own
bookkeeping costs: the checks of every output, the events watched, the records, the
model's struct.
"""

from __future__ import annotations

import gc
import os
import time

import numpy as np
from compiled_path import T_FINAL, body, systems  # the benchmark's pronking body
from numba import njit

from bderiv.models.compiled._dop853 import (
    N_STAGES,
    N_STAGES_EXTENDED,
    D,
    dense_point,
    error_norm,
    step_factor,
    step_point,
)
from bderiv.models.compiled._integrate import N_STEPS, drive_stretch

os.environ.setdefault("BDERIV_INTEGRATOR", "compiled")  # compiled from the first run

ROUNDS = 30
RTOL, ATOL = 1e-10, 1e-12
SIZES = ((2, 0), (8, 12))


@njit(inline="always")
def _rates(field, mask, y, K, first, last, h, points, point):
    """Stages first..last-1: point into ``points`` (by ``point``, as the driver's
    ``stages``), the field there (a fresh copy of x)."""
    d = y.size
    for s in range(first, last):
        point(y, K, s, h, d, points)
        a = np.empty(d)
        for j in range(d):
            a[j] = points[j]
        f = field(a, mask)
        for j in range(d):
            K[s, j] = f[j]


@njit
def bare_stretch(field, events, mask, y0, t0, t1, dense):
    """DOP853 from ``(t0, y0)`` to ``t1`` (first step 1e-3), the field called directly:
    the accepted steps."""
    d = y0.size
    K = np.empty((N_STAGES_EXTENDED, d))
    F = np.empty((7, d))
    work = np.empty((3, d))
    atol = np.full(d, ATOL)
    y, y_new = y0.copy(), np.empty(d)
    t, h_abs, steps = t0, 1e-3, 0
    K[0] = field(y.copy(), mask)
    while t < t1:
        h_abs = max(h_abs, 10.0 * abs(np.nextafter(t, np.inf) - t))
        rejected = False
        while True:
            t_new = min(t + h_abs, t1)
            h = t_new - t
            _rates(field, mask, y, K, 1, N_STAGES + 1, h, y_new, step_point)
            err = error_norm(K, h, y, y_new, RTOL, atol, work)
            h_abs = abs(h) * step_factor(err, rejected)
            if err < 1.0:
                break
            rejected = True
        events(y_new.copy())
        if dense:  # the driver's dense output: the extra stages, then dense_coefficients' sums
            _rates(field, mask, y, K, N_STAGES + 1, N_STAGES_EXTENDED, h, work[0],
                   dense_point)
            for j in range(d):
                dy = y_new[j] - y[j]
                F[0, j] = dy
                F[1, j] = h * K[0, j] - dy
                F[2, j] = 2.0 * dy - h * (K[N_STAGES, j] + K[0, j])
            for i in range(D.shape[0]):
                for j in range(d):
                    acc = 0.0
                    for r in range(N_STAGES_EXTENDED):
                        acc += D[i, r] * K[r, j]
                    F[3 + i, j] = h * acc
        t = t_new
        y[:] = y_new
        K[0] = K[N_STAGES]
        steps += 1
    return steps


@njit
def bare_stride(field, events, masks, y0s, t0s, t1s, dense):
    """``bare_stretch`` over the stride's stretches: the accepted steps."""
    steps = 0
    for i in range(t0s.size):
        steps += bare_stretch(field, events, masks[i], y0s[i], t0s[i], t1s[i], dense)
    return steps


@njit
def driver_stride(model, jac_mode, n, masks, y0s, t0s, t1s, dense):
    """``drive_stretch`` over the stride's stretches (each to its event or ``t1``): the
    accepted steps and the end times."""
    steps = 0
    ends = np.empty(t0s.size)
    d = y0s.shape[1]
    atol = np.full(d, ATOL)
    for i in range(t0s.size):
        out = drive_stretch(model, jac_mode, False, False, n, masks[i], d, t0s[i], y0s[i],
                            t1s[i], RTOL, atol, np.inf, 1e-3, np.int64(-1), np.bool_(False),
                            np.int64(10**9), dense)
        steps += out[9][N_STEPS]
        ends[i] = out[1]
    return steps, ends


def cpu_time(job):
    """The thread's CPU time of one call of ``job``."""
    start = time.thread_time()
    job()
    return time.thread_time() - start


def measure(k, p):
    """Per-step times of the driver and the bare loop on the (k, p) body's stride."""
    system, _, x0 = systems(k, p)
    field, events, _ = body(k, p)
    run = system.simulate(x0, T_FINAL)
    starts = [(0.0, x0, 0)] + [(g.time, g.state_after, g.mask_after) for g in run.groups]
    t0s = np.array([s[0] for s in starts])
    y0s = np.array([s[1] for s in starts])
    masks = np.array([s[2] for s in starts], dtype=np.int64)
    model, jac_mode = system.compiled.struct(None), system.compiled.jac_mode
    t1s = np.full(t0s.size, T_FINAL)
    _, ends = driver_stride(model, jac_mode, np.int64(k), masks, y0s, t0s, t1s, True)
    jobs = {}
    for dense in (True, False):
        name = "dense" if dense else "plain"
        jobs["driver " + name] = (lambda dense=dense: driver_stride(
            model, jac_mode, np.int64(k), masks, y0s, t0s, t1s, dense)[0])
        jobs["bare " + name] = (lambda dense=dense: bare_stride(
            field, events, masks, y0s, t0s, ends, dense))
    steps = {name: job() for name, job in jobs.items()}  # compile
    times = {name: [] for name in jobs}
    gc.disable()
    try:
        for _ in range(ROUNDS):
            for name, job in jobs.items():
                times[name].append(cpu_time(job))
    finally:
        gc.enable()
    return x0.size, {name: 1e6 * min(times[name]) / steps[name] for name in jobs}, steps


def main():
    for k, p in SIZES:
        d, per_step, steps = measure(k, p)
        print(f"d = {d}: accepted steps " + ", ".join(f"{n} {s}" for n, s in steps.items()))
        for kind in ("dense", "plain"):
            drv, bare = per_step["driver " + kind], per_step["bare " + kind]
            print(f"  {kind}: driver {drv:.2f} us/step, bare loop {bare:.2f} us/step, "
                  f"driver / bare {drv / bare:.2f}")


if __name__ == "__main__":
    main()
