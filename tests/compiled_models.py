"""Numba twins of bundled example models, for the tests of the compiled path.

Each factory returns ``numba.njit`` functions computing what the example's Python model
computes (the formulas written again, loop style, as one writes for numba): the same model
on both integrators. The fields take complex input (complex step) unless said otherwise.

The functions of a model are made once per process (``functools.cache``), and the tests
of one process share them; they are cached on disk (numba keys a closure by the values it
holds), so the other worker loads them. ``fresh=True`` makes new ones (a model none of
this process's runs has seen; loaded from the disk where compiled before).
"""

from __future__ import annotations

import _thread
import contextlib
import functools
import signal
import threading
import time

import numba
import numpy as np

from bderiv.analysis.system import HybridSystem
from bderiv.examples import chair, pronking

G = 9.81


@functools.cache
def pronking_functions(legs, stiffness=400.0, damping=2.0, gain=4.0, v_ref=2.0,
                       coupling=0.5, half_base=0.4, leg=0.5, inertia=0.16):
    """``field, events, event_jacobian`` of ``gaits.pronking(legs=legs)`` (its formulas:
    the totals of two legs shared by all, extra thrust gain while all legs touch)."""
    share = 2.0 / legs
    K, C, gain = share * stiffness, share * damping, share * gain
    a = np.linspace(-half_base, half_base, legs)
    all_down = (1 << legs) - 1

    @numba.njit(cache=True)
    def field(x, mask):
        c, s = np.cos(x[1]), np.sin(x[1])
        g = gain * (1.0 + coupling) if mask == all_down else gain
        thrust = g * (1.0 - x[2] ** 2 / v_ref**2) * x[2]
        out = np.empty_like(x)
        out[0], out[1] = x[2], x[3]
        out[2], out[3] = -G + 0.0 * x[0], 0.0 * x[0]
        for k in range(legs):
            if mask >> k & 1:
                rx = a[k] * c + leg * s
                height = x[0] + a[k] * s - leg * c
                f = -K * height - C * (x[2] + x[3] * rx) + thrust
                out[2] += f
                out[3] += rx * f / inertia
        return out

    @numba.njit(cache=True)
    def events(x):
        out = np.empty(legs)
        for k in range(legs):
            out[k] = -(x[0] + a[k] * np.sin(x[1]) - leg * np.cos(x[1]))
        return out

    @numba.njit(cache=True)
    def event_jacobian(x):
        D = np.zeros((legs, 4))
        for k in range(legs):
            D[k, 0] = -1.0
            D[k, 1] = -(a[k] * np.cos(x[1]) + leg * np.sin(x[1]))
        return D

    return field, events, event_jacobian


@numba.njit(cache=True)
def apex_section(x):
    """The apex ``-vz`` (gaits.apex_section)."""
    return -x[2]


def pronking_pair(legs, fresh=False):
    """``(example, compiled system)``: gaits.pronking(legs) and its numba twin (its
    functions new ones when ``fresh``)."""
    ex = pronking(legs=legs)
    make = pronking_functions.__wrapped__ if fresh else pronking_functions
    field, events, event_jacobian = make(legs)
    return ex, HybridSystem(field, events, n_events=legs, dim=4,
                            event_jacobian=event_jacobian)


@functools.cache
def chair_functions(stiffness=400.0, damping=4.0, mode_damping=1.0, friction=1.0,
                    inertia=0.1):
    """``field, events, event_jacobian`` of ``examples.chair()`` (its legs and formulas)."""
    theta = 0.1
    a0, b0, a1 = -0.5, -0.4, 0.6
    legs = np.array([[a0, b0], [a1, b0 + (a0 - a1) * np.tan(theta)]])

    @numba.njit(cache=True)
    def field(x, mask):
        c, s = np.cos(x[2]), np.sin(x[2])
        c_leg = damping * (1.0 + mode_damping) if mask & 3 == 3 else damping
        out = np.empty_like(x)
        out[0], out[1], out[2] = x[3], x[4], x[5]
        out[3], out[4], out[5] = 0.0 * x[0], -G + 0.0 * x[0], 0.0 * x[0]
        for k in range(2):
            if mask >> k & 1:
                rx = legs[k, 0] * c - legs[k, 1] * s
                rz = legs[k, 0] * s + legs[k, 1] * c
                fz = -stiffness * (x[1] + rz) - c_leg * (x[4] + x[5] * rx)
                fx = -friction * (x[3] - x[5] * rz)
                out[3] += fx
                out[4] += fz
                out[5] += (rx * fz - rz * fx) / inertia
        return out

    @numba.njit(cache=True)
    def events(x):
        c, s = np.cos(x[2]), np.sin(x[2])
        out = np.empty(2)
        for k in range(2):
            out[k] = -(x[1] + legs[k, 0] * s + legs[k, 1] * c)
        return out

    @numba.njit(cache=True)
    def event_jacobian(x):
        c, s = np.cos(x[2]), np.sin(x[2])
        D = np.zeros((2, 6))
        for k in range(2):
            D[k, 1] = -1.0
            D[k, 2] = -(legs[k, 0] * c - legs[k, 1] * s)
        return D

    return field, events, event_jacobian


def chair_pair():
    """``(example, compiled system)``: examples.chair() and its numba twin."""
    ex = chair()
    field, events, event_jacobian = chair_functions()
    return ex, HybridSystem(field, events, n_events=2, dim=6, event_jacobian=event_jacobian)


@numba.njit(cache=True)
def slow_rotation(x, mask):
    """A rotation that never reaches ``far_event``: a run as long as ``t_final`` says
    (the Ctrl-C tests)."""
    return np.array([x[1], -x[0]])


@numba.njit(cache=True)
def far_event(x):
    return np.array([x[0] - 2.0])  # never reached


#: a run of ``slow_rotation`` to this time at ``max_step=1e-3`` takes 1e7 steps: seconds,
#: so that a Ctrl-C test whose interrupt never arrives fails instead of running for hours
LONG_RUN = 1e4


@contextlib.contextmanager
def ctrl_c_after(seconds):
    """Ctrl-C (SIGINT, delivered as Python delivers it) ``seconds`` into the block, which
    gets the start time. SIGINT is taken as an interactive session takes it: a background
    job (``pytest &`` from a script: bash starts it with SIGINT ignored, and Python then
    installs no handler) would never see a KeyboardInterrupt."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    timer = threading.Timer(seconds, _thread.interrupt_main, args=(signal.SIGINT,))
    try:
        timer.start()
        yield time.perf_counter()
    finally:
        timer.cancel()
        signal.signal(signal.SIGINT, previous)


@functools.cache
def _twin(fn):
    """``numba.njit(fn)``, one per function and process (its constants are parameters: the
    tests of one function share its compilation)."""
    return numba.njit(cache=True)(fn)


def on_path(path, field, field_jacobian, events, event_jacobian, *, n_events, dim, params):
    """A model of four Python functions on ``path``: ``"compiled"`` (their ``numba.njit``
    twins, on the compiled integrator) or ``"python"`` (scipy's ``solve_ivp``)."""
    fns = (field, field_jacobian, events, event_jacobian)
    if path == "compiled":
        fns = tuple(_twin(f) for f in fns)
    f, fj, ev, ej = fns
    system = HybridSystem(f, ev, n_events=n_events, dim=dim, field_jacobian=fj,
                          event_jacobian=ej, params=params)
    assert (system.compiled is not None) == (path == "compiled")
    return system
