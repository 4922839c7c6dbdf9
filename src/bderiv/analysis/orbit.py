"""Periodic orbits of a hybrid system: Newton's method with the B-derivative, and the orbit.

:func:`periodic_orbit` solves ``P(x) = x`` on a Poincare section (``P`` the return map of
:mod:`bderiv.analysis.returnmap`). At an iterate x the return map's B-derivative ``A = DP(x)`` is
piecewise linear, and the Newton step solves the **piecewise-linear Newton equation
exactly** (the B-derivative Newton method of Pang, 1990):

    find delta with   (P(x) - x) + A(delta) - delta = 0,   grad s(x) . delta = -s(x),

by moving between pieces: solve the linear system of one piece (one event order per
group), read the piece that its solution selects, and repeat until the solution lies in
its own piece (``A(delta) = A_piece delta``), at most
:data:`~bderiv._limits.MAX_PIECE_SWITCHES` times (:mod:`bderiv.analysis.newton`);
the work does not grow with the number of pieces (a product of n! orders per group, 1.6e9
for two groups of eight feet), which are never listed (docs/mathematics.md section 10
says what is guaranteed). Why exactly and not "the piece at x": near
an orbit through a simultaneous-event point the iterates move between pieces, and the
solution of the true PL equation is the step that makes the first-order model of P vanish,
whichever piece it lands in; with the piece of x the step can point the wrong way and
cycle. When the events at an iterate are not simultaneous, A is a single linear piece
(the classical Jacobian of the side the iterate is on), and Newton's method converges
quadratically there as well: each smooth piece of P passes through the fixed point
(Kojima & Shindo, 1986). A step that does not reduce ``|P(x) - x|`` is halved.

The runs that test a Newton step use ``simultaneity_tol = 0`` (events are grouped only
when the integrator cannot tell them apart), so an iterate whose events are close but not
simultaneous is never refused. A map is built with the caller's tolerance where its
iterate may be the orbit: the guess (a stored orbit, say) and an iterate whose accepting
run already returns within the tolerance; it is then both the convergence test and the
orbit's map, built once. Where such a map fails the test and has merged events that are
apart at its iterate (its step would be a chord: Newton's method would converge only
linearly), or where the caller's tolerance refuses it, the map is built with 0. The
other iterates' maps are built with 0. Convergence is judged on the map returned.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._limits import (
    DEFAULT_T_MAX,
    DERIVATIVE_SIMULTANEITY_TOL,
    MULTIPLIER_PIECES,
    ON_SURFACE_TOL,
    ORBIT_MAX_ITER,
    ORBIT_TOL,
    RATE_ROUNDING,
    T_MAX_PER_PERIOD,
)
from .._numerics import GLOBAL_ERROR_FACTOR
from .._support._progress import search_bar
from .._support._validate import check_number
from .._support._validate_ints import check_positive_int
from ..models.integrate.options import SolverOptions, check_options
from ..models.integrate.run import ENDS, run
from ..models.integrate.trajectory import NoReturn, TooManyGroups
from ._arguments import check_burn_in, check_iterations, check_seed
from ._cyclic import (
    SHIFTS,
    check_cyclic,
    check_equivariance,
    check_independence,
    check_section_normal,
    kept,
    reduced_basis,
    undeclared,
    without_cyclic,
)
from .newton import damped_step, newton_step, onto_section
from .returnmap import return_map
from .stability import (
    Stability,
    check_growth_memory,
    growth_rate,
    piece_multipliers,
    verdict,
)

__all__ = ["NewtonIterate", "PeriodicOrbit", "periodic_orbit"]

#: integrator settings of the orbit search: the residual is only as good as the
#: integration, and Newton's method converges to within it.
ORBIT_OPTIONS = SolverOptions(rtol=1e-12, atol=1e-13,
                              simultaneity_tol=DERIVATIVE_SIMULTANEITY_TOL)


@dataclass(frozen=True)
class NewtonIterate:
    """One Newton iteration.

    Attributes
    ----------
    x : ndarray, shape (d,)
        The iterate.
    residual : float
        ``max |P(x) - x|`` there.
    step : float
        ``max |x_next - x|`` of the step taken (0 for the last iterate).
    piece : tuple
        The piece of the return map's B-derivative whose linear system gave the step: one
        event order per event group of the stride, each a tuple of the group's local event
        indices in the order they happen (``((0,), (0,))``: two groups of one event each,
        so a single linear piece). Empty for the last iterate, where no step was taken.
    switches : int
        Pieces tried before the step's piece (0: the first one was consistent).
    """

    x: np.ndarray
    residual: float
    step: float
    piece: tuple
    switches: int = 0

    def __str__(self):
        if not self.piece:
            return f"residual {self.residual:.3g} (converged: no step)"
        groups = ", ".join(f"group {i}: {' -> '.join(map(str, order))}"
                           for i, order in enumerate(self.piece))
        return (f"residual {self.residual:.3g}, step {self.step:.3g}, event orders "
                f"[{groups}] ({self.switches} piece switches)")


class PeriodicOrbit:
    """A periodic orbit found by :func:`periodic_orbit`.

    Attributes
    ----------
    system : HybridSystem
    section : callable
        The checked section (``section(x)`` and ``section.gradient(x)``).
    x0 : ndarray, shape (d,)
        The fixed point of the return map on the section.
    period : float
        Return time.
    trajectory : Trajectory
        One period from ``x0`` (its event groups with their directions).
    return_map : ReturnMap
        The B-derivative of the return map at ``x0``.
    residual : float
        ``max |P(x0) - x0|`` over the coordinates that are not cyclic (simulated).
    history : tuple of NewtonIterate
        The Newton iterations.
    cyclic : tuple of int
        The cyclic coordinates (left out of the fixed-point equation and the stability).
    advance : ndarray, shape (len(cyclic),)
        How far each cyclic coordinate advances per period, ``P(x0)_i - x0_i``.
    options : SolverOptions
        The integrator's settings the return map was built with.
    """

    def __init__(self, system, section, x0, trajectory, return_map, residual, history,
                 cyclic=(), advance=(), options=ORBIT_OPTIONS):
        self.system, self.section = system, section
        self.x0 = x0
        self.trajectory = trajectory
        self.return_map = return_map
        self.period = return_map.period
        self.residual = float(residual)
        self.history = tuple(history)
        self.cyclic = tuple(cyclic)
        self.advance = np.asarray(advance, dtype=np.float64)
        self.options = options

    @property
    def accuracy(self) -> float:
        """The relative accuracy of the return map, and so of a log growth rate of it:
        ``GLOBAL_ERROR_FACTOR * rtol`` of the integration that built it (as the state's
        error at a stop, :mod:`bderiv.models.events.locate`), never below the rounding
        of a step, ``RATE_ROUNDING``. A rate within it of 1 is undecided: a conservative
        gait's map is neutral, and its computed rate is 1 only to within it."""
        return max(GLOBAL_ERROR_FACTOR * self.options.rtol, RATE_ROUNDING)

    def __repr__(self):
        groups = [(round(g.time, 6), g.events, g.directions) for g in self.trajectory.groups]
        return (f"PeriodicOrbit(period={self.period:.10g}, residual={self.residual:.3g}, "
                f"groups={groups})")

    def sample(self, n_points=400):
        """One period simulated again with at most ``period / n_points`` per step (for
        figures: the solver's own steps can be few): a Trajectory."""
        n_points = check_positive_int(n_points, "n_points")
        options = ORBIT_OPTIONS.with_overrides(max_step=self.period / n_points)
        return self.system.simulate(self.x0, T_MAX_PER_PERIOD * self.period,
                                    section=self.section, options=options)

    def stability(self, n_directions=1000, iterations=1000, burn_in=None, seed=0) -> Stability:
        """The stability of the orbit, from the piecewise-linear return map.

        Iterates the return map's B-derivative on ``n_directions`` random directions
        tangent to the section (:func:`bderiv.analysis.stability.growth_rate`) and reports the
        Floquet multipliers of the pieces met most often (at most
        :data:`MULTIPLIER_PIECES`; every piece met is counted in ``visits``). The work
        grows with the directions and iterations, not with the number of pieces. See
        :mod:`bderiv.analysis.stability` for the method and its limits.

        Parameters
        ----------
        n_directions : int
            Directions in the batch.
        iterations : int
            Iterations of the map (>= 2).
        burn_in : int, optional
            Iterations not averaged, in ``[0, iterations - 2]`` (default
            ``iterations // 4``).
        seed : int
            Seed of the random directions, >= 0 (None: fresh entropy).

        Returns
        -------
        Stability
        """
        n_directions = check_positive_int(n_directions, "n_directions")
        iterations = check_iterations(iterations)
        burn_in, seed = check_burn_in(burn_in, iterations), check_seed(seed)
        R = self.return_map
        fmap, fmap_orders, basis = R, R.apply_orders, R.tangent_basis
        check_growth_memory(n_directions, basis.shape[0], iterations)  # before V0 exists
        if self.cyclic:  # the map on the other coordinates: a cyclic shift is neutral
            basis = reduced_basis(self.section.gradient(self.x0), self.cyclic, R.dim)
            fmap, fmap_orders = without_cyclic(R, list(self.cyclic))
        V0 = np.random.default_rng(seed).standard_normal((n_directions, basis.shape[1]))
        rates, spread, visits = growth_rate(fmap, V0 @ basis.T, iterations, burn_in,
                                            fmap_orders=fmap_orders)
        most = sorted(visits, key=visits.get, reverse=True)[:MULTIPLIER_PIECES]
        multipliers = {p: piece_multipliers(R.piece(list(p)), basis) for p in most}
        i = int(np.argmax(rates))
        spread_i = max(float(spread[i]), self.accuracy)
        return Stability(float(rates[i]), verdict(rates[i], spread_i), rates, spread_i,
                         multipliers, visits, int(iterations), burn_in, self.accuracy)


def periodic_orbit(system, x_guess, section, *, period_guess=None, tol=ORBIT_TOL,
                   max_iter=ORBIT_MAX_ITER, options=ORBIT_OPTIONS, cyclic=()):
    """Solve ``P(x) = x`` on the section by Newton's method with the B-derivative.

    Parameters
    ----------
    system : HybridSystem
    x_guess : ndarray, shape (d,)
        Checked start; it is first moved onto the section along the section's gradient.
    section : bderiv.models.section.Section
    period_guess : float, optional
        Expected period; the return is awaited for ``3 * period_guess`` (default 100).
    tol : float
        Stop when ``max |P(x) - x| <= tol * max(1, max |x|)``.
    max_iter : int
        Largest number of Newton iterations.
    options : SolverOptions
        The settings (default :data:`ORBIT_OPTIONS`); their ``simultaneity_tol`` is the
        orbit's return map's and the guess's (the runs that test a step use 0, and so do
        the maps of the iterates between: see the module's docstring).
    cyclic : sequence of int
        Coordinates the model and the section do not depend on (a forward position, a
        heading): left out of ``P(x) = x`` (they advance every stride) and of the
        stability; ``PeriodicOrbit.advance`` says by how much. Their independence is
        checked at the start (a shift by each of :data:`bderiv.analysis._cyclic.SHIFTS` must shift
        the return by the same and change nothing else) and at every iterate and the
        orbit (the return map's derivative along each must be the identity:
        :func:`bderiv.analysis._cyclic.check_equivariance`). A coordinate left out that the
        guess's return advances as a cyclic one would is named if the search then fails.

    Returns
    -------
    PeriodicOrbit

    Raises
    ------
    RuntimeError
        When Newton's method does not converge in ``max_iter`` iterations, or a step
        cannot reduce the residual (the last iterate and residual are named).
    ValueError
        From the orbit's return map (:func:`bderiv.analysis.returnmap.return_map`), for example
        when two events of the orbit are closer than ``simultaneity_tol`` in time but
        not at one point to within the integration accuracy (the message suggests a
        smaller ``simultaneity_tol``); and for a coordinate of ``cyclic`` that the model
        or the section depends on (named, with the measured dependence).
    """
    tol = check_number(tol, "tol")
    max_iter = check_positive_int(max_iter, "max_iter")
    t_max = (DEFAULT_T_MAX if period_guess is None
             else T_MAX_PER_PERIOD * check_number(period_guess, "period_guess"))
    check_options(options)
    iterates = options.with_overrides(simultaneity_tol=0.0)
    x = onto_section(section, x_guess)
    cyclic = check_cyclic(cyclic, x.size)
    keep = kept(cyclic, x.size)
    check_section_normal(section.gradient(x), cyclic, x)
    history, build = [], options  # the guess may be the orbit (a stored one)
    if cyclic:  # checked first: Newton's method fails, or finds a false gait, on a wrong choice
        starts = [x, *(x + c * np.eye(x.size)[i] for i in cyclic for c in SHIFTS)]
        returned, *shifted = [_at_iterate(0, start, t_max, lambda s=start: run(
            system.calls, s, t_max, options=iterates, section=section, record=ENDS)).x_final
            for start in starts]
        check_independence(returned, x, shifted, cyclic)
    advancing = []  # coordinates the guess's return advanced as a cyclic one would
    try:
        with search_bar(max_iter, "periodic_orbit", "Newton iterate") as bar:  # long searches
            for iteration in range(max_iter + 1):
                R, traj, built_with = _at_iterate(iteration, x, t_max, lambda x=x, b=build:
                                                  _build(system, x, section, t_max, b, iterates))
                check_equivariance(R, x, cyclic)
                r = R.x_final - x
                if iteration == 0 and not cyclic:  # moved by more than the run's error
                    size = float(np.abs(x).max())
                    moved = max(tol * max(1.0, size), GLOBAL_ERROR_FACTOR * (
                        iterates.atol + iterates.rtol * size))
                    advancing, r0 = undeclared(R, r, moved), r
                res = float(np.abs(r[keep]).max())
                bar(iteration, f"max |P(x) - x| = {res:.2g}")
                if _within(res, x, keep, tol):
                    break
                if iteration == max_iter:
                    raise RuntimeError(f"Newton's method did not converge in max_iter={max_iter} "
                                       f"iterations: max |P(x) - x| = {res:.3g} at x = {x}")
                if built_with != iterates and any(s > 0 for s in R.flow.group_spreads):
                    # events apart at x merged by the caller's tolerance: a step from that map is a
                    # chord, and Newton's method converges only linearly; the iterates' map instead
                    R, traj, built_with = _at_iterate(iteration, x, t_max, lambda x=x: _build(
                        system, x, section, t_max, iterates, iterates))
                    check_equivariance(R, x, cyclic)
                    r = R.x_final - x
                step = newton_step(R, r, section.gradient(x), section(x), keep=keep)
                damped = damped_step(system, section, x, step.delta, res, t_max, iterates, keep)
                history.append(NewtonIterate(x.copy(), res, float(np.abs(damped.x - x).max()),
                                             step.piece, step.switches))
                x = damped.x
                # converged already by the damped step's run: the next map is likely the orbit's,
                # so it is built with the caller's tolerance (and kept if the test passes on it)
                build = options if _within(damped.residual, x, keep, tol) else iterates
    except (ValueError, RuntimeError) as exc:  # a forward position left out of cyclic?
        if advancing and type(exc) in (ValueError, RuntimeError):
            raise type(exc)(f"{exc}; coordinates {advancing} advanced by "
                            f"{[float(v) for v in r0[advancing]]} at the guess and the "
                            f"return map's derivative along them is the shift itself: "
                            f"pass cyclic={advancing} (Newton's method cannot bring "
                            f"them back)") from exc
        raise
    history.append(NewtonIterate(x.copy(), res, 0.0, ()))
    if built_with != options:  # the map at x was built for the iteration only
        R, traj = _at_iterate(iteration, x, t_max, lambda: return_map(
            system, x, section, t_max=t_max, tol=ON_SURFACE_TOL, options=options))
        check_equivariance(R, x, cyclic)
    r = R.x_final - x
    return PeriodicOrbit(system, section, x, traj, R, float(np.abs(r[keep]).max()), history,
                         cyclic, r[list(cyclic)], options)


def _within(res, x, keep, tol) -> bool:
    """Whether the residual ``res`` (``max |P(x) - x|`` over ``keep``) meets the test of
    :func:`periodic_orbit`: ``res <= tol * max(1, max |x[keep]|)``."""
    return res <= tol * max(1.0, float(np.abs(x[keep]).max()))


def _at_iterate(iteration, x, t_max, call):
    """``call()``, its ValueError said at the Newton iterate it came from: the guess (0) or
    iterate k, its state, and for no return the argument that sets the time waited."""
    where = "the guess" if iteration == 0 else f"Newton iterate {iteration}"
    try:
        return call()
    except TooManyGroups as exc:  # its advice, a larger max_groups, is no argument here
        raise RuntimeError(
            f"periodic_orbit at {where}, x = {np.array2string(x, precision=6)}: the run did "
            f"not return to the section in {exc.max_groups} event groups (t = {exc.t:.6g} "
            f"of the {t_max:g} it waits, {T_MAX_PER_PERIOD:g} times period_guess): from "
            f"there the flow does not cross the section again, or chatters; pass a guess "
            f"nearer the orbit, a section the orbit crosses, or a period_guess nearer its "
            f"period") from exc
    except ValueError as exc:
        hint = ""
        if isinstance(exc, NoReturn):
            hint = (f" (periodic_orbit waits {T_MAX_PER_PERIOD:g} times period_guess for the "
                    f"return, {t_max:g} here: pass a larger period_guess, or a guess nearer "
                    f"the orbit)")
        raise ValueError(f"periodic_orbit at {where}, x = {np.array2string(x, precision=6)}: "
                         f"{exc}{hint}") from exc


def _build(system, x, section, t_max, options, iterates):
    """``(R, trajectory, settings)``: the return map at x with ``options``, else with
    ``iterates`` (``simultaneity_tol`` 0) where that refuses (two events of an iterate close
    in time but not at one point). Any other ValueError is tried again with 0 too (the one
    raised is the second attempt's: a failure takes two attempts), but not ``NoReturn``:
    the tolerance does not change where the run goes."""
    if options != iterates:
        try:
            return (*return_map(system, x, section, t_max=t_max, tol=ON_SURFACE_TOL,
                                options=options), options)
        except NoReturn:
            raise
        except ValueError:
            pass
    return (*return_map(system, x, section, t_max=t_max, tol=ON_SURFACE_TOL,
                        options=iterates), iterates)

