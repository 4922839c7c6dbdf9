"""The B-derivative of a Poincare (first-return) map: ReturnMap and its assembly.

For a section ``s(x) = 0`` crossed upward and a start point x0 on it, the return map
``P(x) = Phi(T(x), x)`` follows the flow to the next upward crossing, at the return time
``T(x)``. Its B-derivative is the flow map's, ``D = L_m . M_m . ... . M_1 . L_0`` (see
:mod:`bderiv.analysis.flowmap`), followed by the correction for the change in return time: a
perturbation w of the final state moves the crossing by ``dT = -(n . w) / (n . F)``
(n the section's gradient, F the field at ``P(x0)``), so

    DP = Pi . D,      Pi = I - F n^T / (n . F)

(the projection along the flow onto the section's tangent space at ``P(x0)``). Folding
``Pi`` into the last linear stage makes :class:`ReturnMap` a
:class:`~bderiv.analysis.flowmap.FlowBDerivative`: evaluation, event times, orders and pieces come
with it. ``Pi`` is singular (it kills the flow direction), so the inverse is the section's
one: ``Pi_0 . D^-1`` with ``Pi_0`` the projection at x0 (``D^-1`` maps ``F(P(x0))`` to
``F(x0)``: a shift in time, exact for the piecewise-linear maps too).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .._numerics import GRAZING_RTOL
from ..models.integrate.run import ENDS, run
from ._flowstages import read_only_copy
from .flowmap import FlowBDerivative

__all__ = ["ReturnMap", "ReturnRun", "flow_projection", "return_map"]


def flow_projection(normal, field) -> np.ndarray:
    """``I - field normal^T / (normal . field)``: shape (d, d); along the flow onto the
    hyperplane ``normal . w = 0``."""
    normal, field = np.asarray(normal, float), np.asarray(field, float)
    return np.eye(normal.size) - np.outer(field, normal) / (normal @ field)


class ReturnMap(FlowBDerivative):
    """The piecewise-linear B-derivative of a Poincare map at a point of its section.

    Maps tangent vectors ``(..., d)`` at x0 to tangent vectors at ``P(x0)`` (on the
    section's tangent space there). Built by :meth:`HybridSystem.return_map
    <bderiv.analysis.system.HybridSystem.return_map>`.

    Parameters
    ----------
    flow : FlowBDerivative
        The flow map's B-derivative from x0 to ``P(x0)`` (``t_final`` the return time).
    normal, field : array_like, shape (d,)
        Section gradient and vector field at ``P(x0)``.
    normal_start, field_start : array_like, shape (d,)
        The same at x0 (for the inverse and the tangent basis).

    Attributes
    ----------
    flow : FlowBDerivative
        The flow map's B-derivative (without the return-time correction).
    period : float
        Return time ``T(x0)``.
    projection, start_projection : ndarray, shape (d, d)
        ``Pi`` at ``P(x0)`` and ``Pi_0`` at x0 (read-only).
    tangent_basis : ndarray, shape (d, d - 1)
        Orthonormal basis of the section's tangent space at x0 (read-only).
    """

    def __init__(self, flow, *, normal, field, normal_start, field_start):
        if not isinstance(flow, FlowBDerivative):
            raise TypeError(f"flow must be a FlowBDerivative, got {type(flow).__name__}")
        projection = flow_projection(normal, field)
        linear = [*flow.linear[:-1], projection @ flow.linear[-1]]
        super().__init__(linear, flow.jumps, group_times=flow.group_times,
                         group_events=flow.group_events, group_masks=flow.group_masks,
                         x0=flow.x0, x_final=flow.x_final,
                         t_final=flow.t_final)
        self.flow = flow
        self.period = flow.t_final
        self.projection = read_only_copy(projection)
        self.start_projection = read_only_copy(flow_projection(normal_start, field_start))
        n0 = np.asarray(normal_start, float)
        basis = np.linalg.svd(n0[None, :])[2][1:].T  # the right singular vectors after n0
        self.tangent_basis = read_only_copy(basis)

    def __repr__(self):
        sizes = [bd.n_events for bd in self.jumps]
        return f"ReturnMap(dim={self.dim}, groups={sizes}, period={self.period:.10g})"

    def __setstate__(self, state):
        super().__setstate__(state)
        for arr in (self.projection, self.start_projection, self.tangent_basis):
            arr.setflags(write=False)

    def inverse(self, W, out=None, *, chunk_size=None, progress=None):
        """The inverse on the section: tangent vectors at ``P(x0)`` to those at x0.

        ``Pi_0 . D^-1(W)``: for W tangent to the section at ``P(x0)`` it gives the v
        tangent at x0 with ``self(v) = W``; a component of W along the flow is dropped.

        Parameters
        ----------
        W : array_like, shape (..., d)
        out, chunk_size, progress : optional
            As for :meth:`FlowBDerivative.inverse`.

        Returns
        -------
        ndarray, shape (..., d)
        """
        V = self.flow.inverse(W, out=out, chunk_size=chunk_size, progress=progress)
        res = V @ self.start_projection.T
        if out is None:
            return res
        out[...] = res
        return out


class ReturnRun(NamedTuple):
    """A return map and the run it was built from (:func:`return_map`).

    Attributes
    ----------
    map : ReturnMap
    trajectory : Trajectory
        The trajectory from x0 to the return (with its event groups).
    """

    map: ReturnMap
    trajectory: object


def return_map(system, x0, section, *, t_max, tol, options) -> ReturnRun:
    """Integrate once around from x0 to the section and build the :class:`ReturnMap`.

    Parameters
    ----------
    system : HybridSystem
    x0 : ndarray, shape (d,)
        Checked start point, with ``|section(x0)| <= tol``.
    section : bderiv.models.section.Section
        The checked section.
    t_max : float
        Longest time to wait for the return.
    tol : float
        Largest accepted ``|section(x0)|``.
    options : SolverOptions
        The run's settings, ``simultaneity_tol`` set.

    Returns
    -------
    ReturnRun

    Raises
    ------
    ValueError
        If x0 is not on the section, if the flow does not cross it upward and
        transversally at x0 or at the return, if it does not return before ``t_max``, or
        if an event group lies within ``options.simultaneity_tol`` of the start or the
        return.
    """
    value = section(x0)
    if abs(value) > tol:
        raise ValueError(f"x0 is not on the section: section(x0) = {value:.3g}, beyond "
                         f"tol={tol:g}")
    n0 = section.gradient(x0)
    F0 = system.calls.eval_field(x0, system.calls.start_mask(x0))
    _check_section_crossing(n0, F0, "x0", 0.0)
    traj = run(system.calls, x0, t_max, options=options, variational=True, section=section,
               record=ENDS)
    period = float(traj.t[-1])
    for g in traj.groups:
        if min(g.time, period - g.time) <= options.simultaneity_tol:
            raise ValueError(
                f"event group {g.events} at t={g.time:.10g} is within simultaneity_tol="
                f"{options.simultaneity_tol:g} of the section (return time {period:.10g}): the "
                f"return map is not piecewise differentiable there; move the section"
            )
    nT = section.gradient(traj.x_final)
    FT = system.calls.eval_field(traj.x_final, traj.mask_final)
    _check_section_crossing(nT, FT, "the return point", period)
    flow = system.flow_map_along(traj)
    return ReturnRun(ReturnMap(flow, normal=nT, field=FT, normal_start=n0, field_start=F0),
                     traj)


def _check_section_crossing(normal, field, where, t):
    """Refuse a section that the flow does not cross upward and transversally."""
    rate = float(normal @ field)
    if not rate > GRAZING_RTOL * np.linalg.norm(normal) * np.linalg.norm(field):
        raise ValueError(
            f"the flow must cross the section upward and transversally, but at {where} "
            f"(t={t:.10g}) the rate of section(x) is {rate:.3g} (section gradient . field)"
        )
