"""The NumPy side of :mod:`bderiv.jax`: what its callbacks compute, on whole batches.

JAX hands a callback its arrays with any leading shape (``vmap`` stacks batches in front;
an argument that is not batched comes with axes of size 1 there). Each function here
takes such arrays, broadcasts them to one leading shape, works on the rows and returns
float64 results of that leading shape. Nothing here imports jax.

- :class:`FlowHost`: the flow map of a :class:`~bderiv.analysis.system.HybridSystem` at
  ``t_final``, its B-derivative (built once per distinct start and kept in a small cache),
  the B-derivative applied to tangents and the transpose of one piece applied to
  co-tangents;
- :class:`MapHost`: the same three for a given piecewise-linear map (a
  :class:`~bderiv.BDerivative` or :class:`~bderiv.FlowBDerivative`) at the tangent
  itself.
"""

from __future__ import annotations

import functools

import numpy as np

from .._limits import SIMULATION_SIMULTANEITY_TOL

#: the exception types of bderiv's refusals, re-raised with the start point named
_REFUSALS = (ValueError, TypeError, RuntimeError)


def _rows(d: int, *arrays):
    """The arrays broadcast to one leading shape: ``(lead, [float64 (m, d) each])``."""
    arrays = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in arrays))
    lead = arrays[0].shape[:-1]
    return lead, [np.ascontiguousarray(a.reshape(-1, d)) for a in arrays]


def _by_start(starts: np.ndarray):
    """Group equal rows: ``[(row, indices of its copies)]``, one entry per distinct row
    (``vmap`` over tangents alone repeats one start point in every row)."""
    unique, inverse = np.unique(starts, axis=0, return_inverse=True)
    order = np.argsort(inverse.reshape(-1), kind="stable")
    bounds = np.cumsum(np.bincount(inverse.reshape(-1), minlength=len(unique)))[:-1]
    return list(zip(unique, np.split(order, bounds), strict=True))


def _refused(exc: Exception, where: str) -> Exception:
    """bderiv's refusal ``exc`` with the place in the batch said first (same base type),
    marked as bderiv's (JAX does not log it: :mod:`bderiv.jax._primitive`)."""
    kind = next(k for k in _REFUSALS if isinstance(exc, k))
    out = kind(f"{where}: {exc}")
    out.bderiv_refusal = True
    return out


class FlowHost:
    """The flow map ``x0 -> Phi(t_final, x0)`` of a system, its B-derivative and one piece.

    Parameters
    ----------
    system : HybridSystem
    t_final : float
    options : SolverOptions
        Settings of the simulations (primal and derivative); their ``simultaneity_tol`` is
        the B-derivative's (:meth:`~bderiv.analysis.system.HybridSystem.flow_bderivative`),
        the primal is :meth:`~bderiv.analysis.system.HybridSystem.simulate` with its own
        default.
    direction : ndarray, shape (d,), or None
        The tangent whose piece reverse mode transposes (None: only where the
        B-derivative has a single piece).
    cache_size : int
        B-derivatives kept (one per distinct start point, least recently used dropped).

    Examples
    --------
    >>> from bderiv.examples import chair
    >>> from bderiv.models.integrate.options import SolverOptions
    >>> ex = chair()
    >>> host = FlowHost(ex.system, ex.t_final, options=SolverOptions(simultaneity_tol=1e-7),
    ...                 direction=None, cache_size=8)
    >>> host.final_states(ex.x0[None]).shape
    (1, 6)
    """

    def __init__(self, system, t_final, *, options, direction, cache_size):
        self.system = system
        self.t_final = t_final
        self.options = options
        self.primal = options.with_overrides(simultaneity_tol=SIMULATION_SIMULTANEITY_TOL)
        self.direction = direction
        self.bderivative = functools.lru_cache(maxsize=cache_size)(self._bderivative)

    def final_states(self, x0) -> np.ndarray:
        """``Phi(t_final, x0)`` for starts ``(..., d)``: one simulation per distinct row."""
        d = self.system.dim
        lead, (starts,) = _rows(d, x0)
        out = np.empty_like(starts)
        for start, rows in _by_start(starts):
            try:
                traj = self.system.simulate(start, self.t_final, options=self.primal)
            except _REFUSALS as exc:
                raise _refused(exc, f"bderiv.jax.flow at x0 = {start.tolist()}") from None
            out[rows] = traj.x_final
        return out.reshape(lead + (d,))

    def _bderivative(self, key: bytes):
        start = np.frombuffer(key, dtype=np.float64)
        try:
            return self.system.flow_bderivative(start, self.t_final, options=self.options)
        except _REFUSALS as exc:
            raise _refused(exc, f"bderiv.jax.flow, B-derivative at x0 = {start.tolist()}"
                           ) from None

    def tangents(self, x0, t) -> np.ndarray:
        """``D(x0)(t)``, the B-derivative at each start applied to its tangent (exact at
        simultaneous events: each tangent goes through its own piece)."""
        return self._per_start(x0, t, lambda D, T: D(T))

    def cotangents(self, x0, w) -> np.ndarray:
        """``J(x0)^T w``: the transpose of the piece ``J`` that ``direction`` selects (the
        only piece where D is linear; refused where D has several and no direction was
        given)."""
        return self._per_start(x0, w, self._transpose)

    def _transpose(self, D, W):
        if self.direction is not None:
            return D.vjp(np.broadcast_to(self.direction, W.shape), W)
        try:
            piece = D.piece()
        except ValueError:
            where = [f"simultaneous events at t = {t:.10g}" for t, events
                     in zip(D.group_times, D.group_events, strict=True) if len(events) > 1]
            if D.stops_at_group:
                where.append("an event group at the final time")
            raise ValueError(
                f"reverse mode meets {' and '.join(where)}, where the flow's derivative "
                f"has several linear pieces and reverse mode transposes one of them: pass "
                f"direction= to flow() (a tangent (d,) at x0, whose piece is used), or use "
                f"forward mode (jax.jvp), exact in every direction"
            ) from None
        return W @ piece

    def _per_start(self, x0, V, fn) -> np.ndarray:
        d = self.system.dim
        lead, (starts, rows) = _rows(d, x0, V)
        out = np.empty_like(rows)
        for start, idx in _by_start(starts):
            D = self.bderivative(start.tobytes())
            try:
                out[idx] = fn(D, rows[idx])
            except _REFUSALS as exc:
                raise _refused(exc, f"bderiv.jax.flow at x0 = {start.tolist()}") from None
        return out.reshape(lead + (d,))


class MapHost:
    """A piecewise-linear map ``M`` (BDerivative or FlowBDerivative) on batches of tangents:
    ``M(u)``, the piece at u applied to ``du``, and its transpose applied to ``w``.

    Examples
    --------
    >>> import numpy as np
    >>> from bderiv import BDerivative
    >>> bd = BDerivative(np.eye(2), [[1.0, 1.0], [2.0, 1.0], [1.0, 1.0], [2.0, 1.0]])
    >>> MapHost(bd).values(np.array([[-1.0, -2.0]]))
    array([[-2., -2.]])
    """

    def __init__(self, bd):
        self.map = bd

    def _pair(self, u, v, method) -> np.ndarray:
        lead, (U, V) = _rows(self.map.dim, u, v)
        try:
            return method(U, V).reshape(lead + (self.map.dim,))
        except _REFUSALS as exc:
            raise _refused(exc, f"bderiv.jax.bmap of {self.map!r}") from None

    def values(self, u) -> np.ndarray:
        """``M(u)`` for tangents ``(..., d)``."""
        try:
            return self.map(np.asarray(u, dtype=np.float64))
        except _REFUSALS as exc:
            raise _refused(exc, f"bderiv.jax.bmap of {self.map!r}") from None

    def tangents(self, u, du) -> np.ndarray:
        """``M_sigma(u) du``: the piece u selects, applied to du."""
        return self._pair(u, du, self.map.jvp)

    def cotangents(self, u, w) -> np.ndarray:
        """``M_sigma(u)^T w``."""
        return self._pair(u, w, self.map.vjp)
