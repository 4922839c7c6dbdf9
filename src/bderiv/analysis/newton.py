"""The Newton step of :func:`bderiv.analysis.orbit.periodic_orbit`: the piecewise-linear
Newton equation solved by moving between the pieces of the return map's B-derivative
(:func:`newton_step`, docs/mathematics.md section 10), and the step taken on the Poincare
section, halved until it reduces the residual (:func:`damped_step`, :func:`onto_section`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .._limits import MAX_HALVINGS, MAX_PIECE_SWITCHES, PIECE_RTOL, T_MAX_PER_PERIOD
from .._support._format import format_state
from ..models.integrate.run import ENDS, run
from ..models.integrate.trajectory import NoReturn

__all__ = ["Damped", "NewtonStep", "damped_step", "newton_step", "onto_section"]


class NewtonStep(NamedTuple):
    """A piecewise-linear Newton step (:func:`newton_step`).

    Attributes
    ----------
    delta : ndarray, shape (d,)
    piece : tuple of tuples
        The piece of ``delta`` (one event order per group).
    switches : int
        Pieces tried before ``piece``.
    """

    delta: np.ndarray
    piece: tuple
    switches: int


def newton_step(R, r, normal, value, max_switches=MAX_PIECE_SWITCHES,
                keep=None) -> NewtonStep:
    """Solve the PL Newton equation ``r + R(delta) - delta = 0``, ``normal . delta =
    -value`` by moving between pieces, never listing them.

    Starting from the piece that ``-r`` selects, solve that piece's linear system, and
    move to the piece its solution selects until the solution lies in its own piece (then
    it solves the PL equation exactly), a piece comes back (a cycle) or ``max_switches``
    pieces were tried; then the solution with the smallest PL residual
    ``|r + R(delta) - delta|`` among those tried is taken: a generalized Newton step with
    that piece (docs/mathematics.md section 10).

    Parameters
    ----------
    R : FlowBDerivative
        The return map's B-derivative A (``R(V)``, ``R.orders``, ``R.piece``).
    r : ndarray, shape (d,)
        ``P(x) - x``.
    normal : ndarray, shape (d,)
        The section's gradient at x.
    value : float
        The section's value at x.
    max_switches : int
    keep : ndarray of int, optional
        The coordinates in the equation (default all): the others (cyclic) are left out
        of ``r + R(delta) - delta = 0`` and held, ``delta_i = 0``.

    Returns
    -------
    NewtonStep
    """
    d = R.dim
    keep = np.arange(d) if keep is None else np.asarray(keep)
    system = np.vstack((np.zeros((keep.size, keep.size)), normal[keep]))
    rhs = np.concatenate((-r[keep], [-value]))
    start = np.zeros(d)
    start[keep] = -r[keep]
    piece, tried, best = _piece_of(R, start), set(), None
    for switches in range(max_switches):
        A = R.piece(list(piece))
        system[:-1] = (A - np.eye(d))[np.ix_(keep, keep)]
        delta = np.zeros(d)
        delta[keep] = np.linalg.lstsq(system, rhs, rcond=None)[0]
        image = R(delta)
        if np.abs(image - A @ delta).max() <= PIECE_RTOL * np.abs(A).max() * np.abs(
                delta).max():
            return NewtonStep(delta, piece, switches)
        miss = np.abs((r + image - delta)[keep]).max()
        if best is None or miss < best[0]:
            best = (miss, delta, piece, switches)
        tried.add(piece)
        piece = _piece_of(R, delta)
        if piece in tried:
            break
    return NewtonStep(*best[1:])


def _piece_of(R, v):
    """The piece (one event order per group, tuples of local indices) that v selects."""
    return tuple(tuple(int(k) for k in order[0]) for order in R.orders(v[None]))


def onto_section(section, x, steps=20):
    """Move x onto ``section = 0`` along the gradient (Newton's method on s).

    Raises
    ------
    ValueError
        Where the section's gradient is 0 (or not finite) at a point off the section:
        no direction leads onto it from there (it divided by 0 and went on with NaN)."""
    x = np.array(x, dtype=np.float64)
    for _ in range(steps):
        value = section(x)
        if abs(value) <= 1e-13 * max(1.0, float(np.abs(x).max())):
            break
        g = section.gradient(x)
        norm2 = float(g @ g)
        if not 0.0 < norm2 < np.inf:
            raise ValueError(f"section's gradient is {format_state(g)} at x = "
                             f"{format_state(x)}, where section(x) = {value:.6g}: x_guess "
                             f"cannot be moved onto section = 0 along it (a section must "
                             f"change across the orbit: its gradient nonzero there)")
        x = x - value * g / norm2
    return x


class Damped(NamedTuple):
    """The end of a damped Newton step (:func:`damped_step`): the point ``x`` and the
    ``max |P(x) - x|`` (over the coordinates kept) its run gave, the ``residual``."""

    x: np.ndarray
    residual: float


def damped_step(system, section, x, delta, res, t_max, options, keep) -> Damped:
    """``x + delta`` (on the section), halved until ``max |P - x|`` (over the coordinates
    ``keep``) falls below ``res``; and that ``max |P - x|`` at it. ``options``: the run's
    settings (their ``simultaneity_tol`` is the iterates', 0)."""
    failure = ""
    for _ in range(MAX_HALVINGS + 1):
        trial = onto_section(section, x + delta)
        try:
            traj = run(system.calls, trial, t_max, options=options, section=section,
                       record=ENDS)
        except NoReturn:  # run's advice names its own argument, not periodic_orbit's
            failure = (f"; the last trial point did not return to the section within "
                       f"{t_max:g} (periodic_orbit waits {T_MAX_PER_PERIOD:g} times "
                       f"period_guess: pass a larger period_guess)")
            delta = delta / 2
            continue
        except ValueError as exc:  # an event at the section ...: a shorter step
            failure = f"; the last trial point failed: {exc}"
            delta = delta / 2
            continue
        returned = float(np.abs((traj.x_final - trial)[keep]).max())
        if returned < res:
            return Damped(trial, returned)
        delta = delta / 2
    raise RuntimeError(f"a Newton step from x = {x} could not reduce max |P(x) - x| = "
                       f"{res:.3g} in {MAX_HALVINGS} halvings: the guess is too far from "
                       f"a periodic orbit, or the orbit is degenerate (a multiplier 1)"
                       f"{failure}")
