"""Time one stretch of the compiled DOP853 against solve_ivp on the same field.

``python benchmarks/compiled_integrator.py`` integrates ``x' = A x + 0.5 sin(x)`` (A: a
damped oscillator chain of dimension d = 8, 20, 40) from a fixed start until its first
coordinate falls through -0.5 (one event, located on the dense output), with
:func:`bderiv.models.compiled.integrate_stretch` and with ``solve_ivp(method="DOP853")`` on the
same field as a Python function (the dispatcher's own ``py_func``: the same code), both
with the sensitivity (variational equations, exact Jacobian) and without, in one process,
min of ``REPEATS`` runs each; the compiled path also with a loop-style version of the
field (what one writes for numba). It prints the steps, the times, the ratios, the
agreement of the end states and event times, the first call's cost (compiling the model's
functions; the driver itself loads from numba's disk cache) and one call of the field
compiled and in Python: both integrators spend their time in the field (and, with the
sensitivity, in the d x d products, BLAS in both), so the ratio follows the field's."""

from __future__ import annotations

import os
import time
from functools import partial

import numba
import numpy as np
from scipy.integrate import solve_ivp

from bderiv.models.compiled import integrate_stretch

os.environ.setdefault("BDERIV_INTEGRATOR", "compiled")  # compiled from the first run

RTOL, ATOL = 1e-10, 1e-12
DIMS = (8, 20, 40)
REPEATS = 15
LEVEL = -0.5


def chain(d):
    """A (d, d): masses on a line, springs to neighbours and ground, light damping."""
    k = d // 2
    K = 2.0 * np.eye(k) - np.eye(k, k=1) - np.eye(k, k=-1) + 0.3 * np.eye(k)
    A = np.zeros((d, d))
    A[:k, k:] = np.eye(k)
    A[k:, :k] = -K
    A[k:, k:] = -0.05 * np.eye(k)
    return A


def model(d):
    """The njit field (NumPy style and loop style: the same function), its Jacobian and the
    event of dimension d."""
    A = chain(d)

    @numba.njit
    def field(x, mask):
        return A @ x + 0.5 * np.sin(x)

    @numba.njit
    def field_loops(x, mask):
        out = np.empty(x.size)
        for i in range(x.size):
            acc = 0.5 * np.sin(x[i])
            for j in range(x.size):
                acc += A[i, j] * x[j]
            out[i] = acc
        return out

    @numba.njit
    def jacobian(x, mask):
        return A + np.diag(0.5 * np.cos(x))

    @numba.njit
    def events(x):
        return np.array([x[0] - LEVEL])

    return field, field_loops, jacobian, events


def best(fn, repeats=REPEATS):
    """Min wall time of ``repeats`` calls, and the last result."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - start)
    return min(times), out


def scipy_stretch(field, jacobian, events, x0, t_final, variational):
    """solve_ivp(DOP853) of the Python functions, as bderiv's Python path integrates."""
    f, J, g = field.py_func, jacobian.py_func, events.py_func
    d = x0.size

    def event(t, y):
        return g(y[:d])[0]

    event.terminal, event.direction = True, -1  # the compiled run: bit 0 set
    if not variational:
        return solve_ivp(lambda t, y: f(y, 0), (0.0, t_final), x0, method="DOP853",
                         rtol=RTOL, atol=ATOL, events=[event])

    def rhs(t, y):
        x = y[:d]
        return np.concatenate((f(x, 0), (J(x, 0) @ y[d:].reshape(d, d)).ravel()))

    y0 = np.concatenate((x0, np.eye(d).ravel()))
    return solve_ivp(rhs, (0.0, t_final), y0, method="DOP853", rtol=RTOL, atol=ATOL,
                     events=[event])


def field_call_costs(field, x0):
    """Seconds per call of the field in a compiled loop."""
    x = x0.copy()

    @numba.njit
    def loop(x, n):
        total = 0.0
        for _ in range(n):
            total += field(x, 0)[0]
        return total

    loop(x, 1)
    n = 20_000
    return best(lambda: loop(x, n))[0] / n


def python_call_cost(field, x0):
    """Seconds per call of the field's Python code."""
    n = 2_000
    return best(lambda: [field.py_func(x0, 0) for _ in range(n)])[0] / n


def main():
    print(f"one stretch to the first event, rtol {RTOL:g}, atol {ATOL:g}, min of {REPEATS}")
    print("compiled: the field's NumPy-style code (the same code solve_ivp runs in Python) "
          "and a loop-style version of it; field: one call of each (ns) and in Python (us)")
    print(f"{'d':>3} {'Phi':>4} {'steps':>6} {'compiled':>9} {'loops':>9} {'solve_ivp':>9} "
          f"{'ratio':>6} {'loops':>6} {'x_end rel':>9} {'t_event':>8} {'1st call':>8} "
          f"{'field ns/ns/us':>15}")
    for d in DIMS:
        field, field_loops, jacobian, events = model(d)
        x0 = np.zeros(d)
        x0[: d // 2] = np.linspace(1.0, 0.2, d // 2)
        costs = (field_call_costs(field, x0), field_call_costs(field_loops, x0),
                 python_call_cost(field, x0))
        for variational in (False, True):
            jac = jacobian if variational else None
            runs = [partial(integrate_stretch, f, x0, 50.0, mask=1, events=events,
                            field_jacobian=jac) for f in (field, field_loops)]
            start = time.perf_counter()
            runs[0]()
            first = time.perf_counter() - start
            runs[1]()
            (t_c, s), (t_l, _) = best(runs[0]), best(runs[1])
            t_p, sol = best(partial(scipy_stretch, field, jacobian, events, x0, 50.0,
                                    variational))
            x_ref = sol.y[:d, -1]
            rel = np.abs(s.x_end - x_ref).max() / np.abs(x_ref).max()
            dt = abs(s.t_end - sol.t_events[0][0])
            print(f"{d:>3} {'yes' if variational else 'no':>4} {s.n_steps:>6} "
                  f"{t_c * 1e3:>6.3f} ms {t_l * 1e3:>6.3f} ms {t_p * 1e3:>6.2f} ms "
                  f"{t_p / t_c:>5.0f}x {t_p / t_l:>5.0f}x {rel:>9.1e} {dt:>8.1e} "
                  f"{first:>6.2f} s {costs[0] * 1e9:>5.0f}/{costs[1] * 1e9:>4.0f}/"
                  f"{costs[2] * 1e6:>4.1f}")


if __name__ == "__main__":
    main()
