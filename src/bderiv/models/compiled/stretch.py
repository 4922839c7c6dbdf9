"""One stretch of one region, integrated in compiled code: :func:`integrate_stretch`.

The public face of the compiled integrator: it checks the arguments and the user's
compiled functions, runs the driver (:mod:`._integrate`) and turns its status into a
:class:`Stretch` or an error that names the function, the region and the state.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..._limits import DEFAULT_ATOL, DEFAULT_RTOL
from ..._numerics import MIN_RTOL
from ..._support._validate import check_number, check_real_array
from ._checks import check_compiled, raise_failed_run, raise_overflowed_run
from ._integrate import EVENT, FINISHED, N_REJECTED, N_STEPS, NFEV, NJEV
from ._model import bound_model
from ._rhs import JAC_GIVEN, no_events, no_jacobian
from ._slices import drive

#: largest number of events (one bit each of an int64 mask)
MAX_EVENTS = 63


@dataclass(frozen=True, eq=False)
class Stretch:
    """Result of :func:`integrate_stretch`.

    Attributes
    ----------
    t : ndarray, shape (N,)
        Times of the accepted steps, from ``t0`` to ``t_end`` (both included).
    x : ndarray, shape (N, d)
        States at ``t``.
    t_end : float
        ``t_final``, or the time of the first crossing.
    x_end : ndarray, shape (d,)
        State at ``t_end``.
    phi_end : ndarray, shape (d, d), or None
        Sensitivity ``d x(t_end) / d x(t0)`` of the smooth flow of the region (with a
        ``field_jacobian``), else None.
    event : bool
        True when the stretch stopped at a crossing.
    crossed : ndarray, shape (n,), bool
        Events that crossed (in the direction that flips their bit) in the last step.
    event_times : ndarray, shape (n,)
        Their crossing times on the dense output; NaN for the others. ``t_end`` is the
        smallest.
    n_steps, n_rejected, nfev, njev : int
        Accepted and rejected steps, calls of ``field`` and of ``field_jacobian``.
    """

    t: np.ndarray
    x: np.ndarray
    t_end: float
    x_end: np.ndarray
    phi_end: np.ndarray | None
    event: bool
    crossed: np.ndarray
    event_times: np.ndarray
    n_steps: int
    n_rejected: int
    nfev: int
    njev: int


def _tolerances(rtol, atol, d, variational):
    """Checked ``rtol`` and the per-component ``atol`` of the integrated vector."""
    rtol = check_number(rtol, "rtol")
    if not MIN_RTOL <= rtol < 1.0:
        raise ValueError(f"rtol must be in [{MIN_RTOL:.3g}, 1), got {rtol!r}")
    if np.ndim(atol) == 0:
        per_state = np.full(d, check_number(atol, "atol"))
    else:
        per_state = check_real_array(atol, "atol").astype(np.float64)
        if per_state.shape != (d,):
            raise ValueError(f"atol must be a number or an array of shape ({d},), got shape "
                             f"{per_state.shape}")
        if not (np.isfinite(per_state).all() and (per_state > 0).all()):
            raise ValueError(f"atol must be finite and > 0 in every entry, got {per_state}")
    # the sensitivity's row i (d x_i / d x0) is held to the tolerance of x_i
    full = np.concatenate((per_state, np.repeat(per_state, d))) if variational else per_state
    return rtol, np.ascontiguousarray(full)


def _start(x0, mask, t0, t_final, max_step, first_step):
    """Checked start state, mask, times and step bounds."""
    x0 = check_real_array(x0, "x0")
    if x0.ndim != 1 or x0.size == 0:
        raise ValueError(f"x0 must be a non-empty 1-D array, got shape {x0.shape}")
    if not np.isfinite(x0).all():
        raise ValueError(f"x0 must be finite, got {x0}")
    if isinstance(mask, bool) or not isinstance(mask, int | np.integer):
        raise TypeError(f"mask must be an int, got {type(mask).__name__} {mask!r}")
    if not 0 <= mask < 2**MAX_EVENTS:
        raise ValueError(f"mask must be in [0, 2**{MAX_EVENTS}) (one bit per event), got "
                         f"{mask!r}")
    t0 = check_number(t0, "t0", low=-np.inf)
    t_final = check_number(t_final, "t_final", low=t0)
    max_step = check_number(max_step, "max_step", allow_inf=True)
    first_step = 0.0 if first_step is None else check_number(first_step, "first_step")
    return np.ascontiguousarray(x0, dtype=np.float64), int(mask), t0, t_final, max_step, \
        first_step


def integrate_stretch(field, x0, t_final, *, mask=0, t0=0.0, events=None,
                      field_jacobian=None, rtol=DEFAULT_RTOL, atol=DEFAULT_ATOL, max_step=np.inf,
                      first_step=None) -> Stretch:
    """Integrate region ``mask`` from ``x0`` at ``t0`` to ``t_final`` or the first crossing.

    scipy's ``solve_ivp(method="DOP853")`` in compiled code: the same tableau, error norm,
    step-size control and first step, so the same steps on the same problem; events
    located on the 7th-order dense output as ``solve_ivp`` does (see ``docs/design.md``,
    "The compiled integrator").

    Parameters
    ----------
    field : numba dispatcher
        ``field(x, mask) -> (d,)`` float64, compiled (``numba.njit``) for
        ``(float64[::1], int64)``.
    x0 : array_like, shape (d,)
        Start state.
    t_final : float
        End time, > ``t0``.
    mask : int
        Region: bit k set = event k happened; event k is watched upward when its bit is
        clear, downward when set.
    t0 : float
        Start time.
    events : numba dispatcher, optional
        ``events(x) -> (n,)`` float64, n <= 63; None: no events.
    field_jacobian : numba dispatcher, optional
        ``field_jacobian(x, mask) -> (d, d)`` float64; given, the sensitivity is carried
        (``Phi' = J Phi``, ``Phi(t0) = I``) and its error controlled with the state's.
    rtol : float
        Relative tolerance, in ``[MIN_RTOL, 1)``.
    atol : float or array_like, shape (d,)
        Absolute tolerance, > 0 (per state component; the sensitivity's row i uses
        ``atol[i]``).
    max_step : float
        Largest step, > 0 (``inf``: no limit).
    first_step : float, optional
        First step; None selects it as scipy does.

    Returns
    -------
    Stretch

    Raises
    ------
    TypeError
        A function that is not compiled, or does not compile for the integrator's types.
    ValueError
        A function returned a wrong shape or a non-finite value (the message names it, the
        region and the state), or a bad argument; or the integration blew up (the state or
        its rate of change beyond the floating-point range: the message says so).
    RuntimeError
        The step size fell below 10 ulp of t.

    Examples
    --------
    >>> import numba, numpy as np
    >>> @numba.njit
    ... def rotate(x, mask):
    ...     return np.array([x[1], -x[0]])
    >>> @numba.njit
    ... def height(x):
    ...     return np.array([-x[0]])
    >>> s = integrate_stretch(rotate, [1.0, 0.0], 3.0, events=height)
    >>> s.event, round(s.t_end, 9)
    (True, 1.570796327)
    """
    x0, mask, t0, t_final, max_step, first_step = _start(x0, mask, t0, t_final, max_step,
                                                          first_step)
    d = x0.size
    variational = field_jacobian is not None
    rtol, atol = _tolerances(rtol, atol, d, variational)
    named = {"field": field}
    if variational:
        named["field_jacobian"] = field_jacobian
    if events is not None:
        named["events"] = events
    for name, fn in named.items():
        check_compiled(fn, name)
    events_fn = no_events if events is None else events
    n = int(np.asarray(events_fn(x0.copy())).size) if events is not None else 0
    if n > MAX_EVENTS:
        raise ValueError(f"events must return at most {MAX_EVENTS} values (one bit each of "
                         f"the mask), got {n}")
    y0 = np.concatenate((x0, np.eye(d).ravel())) if variational else x0
    model = bound_model(field, field_jacobian if variational else no_jacobian, events_fn)
    try:
        out = drive(model, JAC_GIVEN, variational, False, n, mask, d, t0, y0, t_final, rtol,
                    atol, max_step, first_step, -1, False, False)
    except ArithmeticError as exc:  # the driver's own (the functions' are status codes)
        raise_overflowed_run(exc, x0, t0, mask, n, lambda: field(x0.copy(), mask))
    if out.status not in (FINISHED, EVENT):
        raise_failed_run(out.status, named, out.bad, out.t_bad, mask, d, n)
    counts = out.counts
    return Stretch(
        t=out.ts, x=np.ascontiguousarray(out.ys[:, :d]), t_end=float(out.t_end),
        x_end=out.y_end[:d].copy(),
        phi_end=out.y_end[d:].reshape(d, d).copy() if variational else None,
        event=out.status == EVENT, crossed=out.active, event_times=out.roots,
        n_steps=int(counts[N_STEPS]), n_rejected=int(counts[N_REJECTED]),
        nfev=int(counts[NFEV]), njev=int(counts[NJEV]),
    )

