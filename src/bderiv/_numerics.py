"""The numbers compiled into bderiv's kernels, each with where its value comes from.

The tolerances, sizes and limits that njit code reads (as globals of a compiled module, or
through a constant computed from one): numba compiles their values in, so this file is
part of the digest that names every cached kernel (``_kernels._core.SOURCES``,
``models.compiled._cached``), and editing a value here compiles the kernels again. Every
other number, and each default read by Python code only, is in ``bderiv._limits``, whose
file keys no cache: a change of a CLI or plot default compiles nothing
(``tests/test_numerics.py`` checks that no njit code reads a value of ``_limits``).

What a number is and how it is documented follow ``_limits``'s rules (a ``#:`` line: what
it is, and where its value comes from); a value read by both kinds of code is here.
This module imports nothing of bderiv: it is the bottom of the layers.
"""

from __future__ import annotations

import numpy as np

_EPS = float(np.finfo(np.float64).eps)

# --- integration ------------------------------------------------------------------------

#: smallest rtol solve_ivp honours (it raises smaller ones to this, with a warning: scipy's
#: ``100 * EPS``); both integrators refuse smaller ones, and the event location's tighter
#: integrations stop at it.
MIN_RTOL = 100 * _EPS
#: global over local error of the integrator: an adaptive Runge-Kutta method keeps each
#: step's error below atol + rtol |x_i|; the error of the state at a stop, a sum of such
#: step errors, is a modest multiple of it (a judgement).
GLOBAL_ERROR_FACTOR = 10.0
#: each tighter integration of an undecided stretch divides rtol and atol by this (a
#: judgement: two digits per try reach MIN_RTOL from the default in two tries).
REFINE_FACTOR = 100.0
#: the compiled event root: scipy's tolerances of the event equation
#: (``ivp.solve_event_equation``: 4 EPS absolute and relative) and brentq's default
#: iteration cap, so that both integrators place an event alike.
EVENT_XTOL = 4.0 * _EPS
EVENT_RTOL = 4.0 * _EPS
EVENT_MAX_ITER = 100

# --- events at a stop -------------------------------------------------------------------

#: a crossing whose rate ``|Dh_k . F|`` is at most this times ``|Dh_k| |F|`` is grazing;
#: the default ``transversality_tol`` of ``BDerivative`` (a judgement: far above the
#: rounding of the product, about d EPS; a rate this small against its factors does not
#: decide the order of the crossings).
GRAZING_RTOL = 1e-9
#: resets of simultaneous events whose results differ by more than this times the
#: accuracy of the state at the stop do not commute (a judgement: three orders above the
#: accuracy, far below a real difference).
RESET_MISMATCH = 1e3
#: groups of up to this many events have their resets compared in every order (4! = 24
#: orders; larger groups also in descending order only: a judgement of cost).
ORDERS_CHECKED = 4

# --- the excursion screen (surfaces crossed and crossed back inside a step) ------------

#: how far above the highest sample a peak may rise, in units of the samples' spread
#: around it, for its bracket to be searched (a parabola rises at most by the spread; the
#: factor ten is a margin for higher-order terms, a judgement).
REACH = 10.0
#: samples of a bracket, screened again before a peak is searched: most brackets are
#: dropped at this finer spacing, and the rest are eight times shorter.
FINE_SAMPLES = 17
#: the reach on those samples: a parabola through three equally spaced samples peaks
#: above the highest by at most a quarter of its drop to the lower neighbour.
FINE_REACH = 1.0

# --- derivatives of user functions (``_numdiff``, the compiled Jacobians) ---------------

#: variables smaller than this (not 0) take it as their scale (steps far below rounding);
#: also the compiled central differences'.
SCALE_FLOOR = 2.0**-20
#: compiled complex step: the imaginary step relative to the coordinate's scale (no
#: cancellation, so any tiny step is exact to rounding; this one keeps x + ih far from
#: underflow)
COMPLEX_STEP = 2.0**-60
#: compiled central differences: the step relative to the coordinate's scale, about
#: EPS^(1/3) (truncation h^2 against rounding EPS / h); the scale is ``max(|x_j|, 1)``
#: (scipy's ``approx_derivative``): the magnitude of a coordinate near 0 says nothing of
#: the scale on which the field varies in it, and a step from it is all rounding
CENTRAL_STEP = 2.0**-17

# --- B-derivatives: tables, fast paths, scaling -----------------------------------------

#: a query whose nonzero entries are within 2**+-QUERY_BAND keeps the chain of tables
#: scaled within 2**+-TABLE_BAND far from both ends of the float64 range; kernels may run
#: such queries as given (what the scaled query gives, scaled).
QUERY_BAND = 256

# --- kernels and threads ----------------------------------------------------------------

#: queries per parallel task. Threads take tasks one at a time (dynamic schedule), so a
#: thread that the OS delays does not hold the other back; 256 queries take far longer
#: than the start-up of the second thread (docs/benchmarks.md, "Kernel design choices,
#: measured").
TASK_QUERIES = 256
#: insertion sort up to this many events, merge sort above (fast-path orders; a
#: judgement: insertion sort's n^2 / 4 moves are cheaper than merge sort's overhead for a
#: few dozen events).
INSERTION_SORT_MAX = 24
