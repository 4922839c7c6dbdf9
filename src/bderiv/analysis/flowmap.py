"""FlowBDerivative: the B-derivative of a flow map along a trajectory with event groups.

Along a trajectory that meets event groups at times t_1 < ... < t_m the B-derivative of
``x -> Phi(T, x)`` is the composition (mathematics.md section 2)

    D = L_m . M_m . L_{m-1} . ... . M_1 . L_0

where ``L_i`` (d, d) is the classical derivative of the smooth stretch between groups i and
i + 1 (from the variational equations) and ``M_i`` the :class:`BDerivative` of group i at its
event point. Evaluating a batch is m + 1 matrix products and m kernel calls; no ODE is
solved per vector. Every stage is invertible (the linear ones are fundamental matrices of
the variational equations, the jumps PL homeomorphisms), and so is D:
``D^-1 = L_0^-1 . M_1^-1 . ... . M_m^-1 . L_m^-1``. The passes of a batch through the
stages, and the checks of the stages, are in ``_flowstages``.
"""

from __future__ import annotations

import functools

import numpy as np

from .._limits import MAX_PIECES
from .._support._batch import evaluate, is_dask_array
from .._support._validate import (
    all_finite,
    check_bool,
    check_finite_result,
    check_matrix,
    check_points,
)
from ..engine._linearise import Linearisation
from ..models.events.finaltime import FinalTimeMap
from ._flowstages import (
    backward,
    check_dt,
    check_pass,
    check_stages,
    compose_piece,
    group_orders,
    read_only_copy,
    stage_inputs,
    stage_inverses,
    tangent_rows,
)

__all__ = ["FlowBDerivative"]


class FlowBDerivative(Linearisation):
    """The composed piecewise-linear B-derivative of a flow map.

    Parameters
    ----------
    linear : sequence of array_like, each (d, d)
        Classical derivatives of the smooth stretches, ``len(jumps) + 1`` of them, in time
        order: before the first group, between groups, after the last group.
    jumps : sequence of BDerivative
        One per event group, in time order, each of dimension d; the last may be a
        :class:`~bderiv.models.events.finaltime.FinalTimeMap` (a group at the final time,
        whose local event ``n_g`` is the final time; ``linear[-1]`` then follows it).
    final_field : array_like, shape (d,), optional
        Vector field at the final point: the derivative in the final time (with a group
        at the final time, the field after it: ``dt`` also decides which of its events
        come before the final time).
    group_times : sequence of float, optional
        Time of each group (information only).
    group_events : sequence of tuple of int, optional
        Global event indices of each group (information only; the local event k of
        ``jumps[i]`` is global event ``group_events[i][k]``).
    group_masks : sequence of (int, int), optional
        Region masks before and after each group (information only; after an impact that
        sends the state back, a bounce's bit is the same in both).
    group_spreads : sequence of float, optional
        Time from the first to the last crossing of each group's events (information
        only; default 0). Above 0 where events that crossed measurably apart, within
        ``simultaneity_tol``, were merged into one group: the group's map is then its
        B-derivative at the nearby point where they are simultaneous, met by perturbations
        larger than the spread (:func:`bderiv.analysis.assembly.flow_map_along`); a
        ``simultaneity_tol`` below it gives the map of the separated events.
    group_states : sequence of array_like, shape (d,), optional
        The state at each group's first crossing, before its resets (for a group pending
        at the final time, the final state), one per jump (information only; where the
        offsets of a merged group's surfaces are measured: :func:`bderiv.estimate.group_offsets`).
    x0, x_final : array_like, shape (d,), optional
        Start and final point of the nominal trajectory (information only).
    t_final : float, optional
        Final time (information only).

    Notes
    -----
    Continuous, piecewise linear and positively homogeneous; its pieces are indexed by one
    event order per group (see :meth:`piece`). Pickles with its stages.
    """

    def __init__(
        self,
        linear,
        jumps,
        *,
        final_field=None,
        group_times=None,
        group_events=None,
        group_masks=None,
        group_spreads=None,
        group_states=None,
        x0=None,
        x_final=None,
        t_final=None,
    ):
        self._linear, self._jumps, d = check_stages(linear, jumps)
        self.dim = d
        if final_field is None:
            self.final_field = None
        else:
            ff = check_matrix(np.reshape(final_field, (1, -1)), "final_field", (1, d))[0]
            ff.setflags(write=False)
            self.final_field = ff
        self.group_times = tuple(float(t) for t in (group_times or ()))
        if group_events is None:
            group_events = [tuple(range(bd.n_events)) for bd in jumps]
        self.group_events = tuple(tuple(int(k) for k in g) for g in group_events)
        if len(self.group_events) != len(jumps):
            raise ValueError(
                f"group_events has {len(self.group_events)} groups but there are "
                f"{len(jumps)} jumps"
            )
        self.group_masks = tuple((int(b), int(a)) for b, a in (group_masks or ()))
        self.group_spreads = tuple(float(s) for s in (group_spreads or [0.0] * len(jumps)))
        self.group_states = () if group_states is None else tuple(
            read_only_copy(check_matrix(np.reshape(x, (1, -1)), "group_states", (1, d))[0])
            for x in group_states)
        if self.group_states and len(self.group_states) != len(jumps):
            raise ValueError(f"group_states has {len(self.group_states)} states but there "
                             f"are {len(jumps)} jumps")
        self.x0 = None if x0 is None else read_only_copy(x0)
        self.x_final = None if x_final is None else read_only_copy(x_final)
        self.t_final = None if t_final is None else float(t_final)

    # ------------------------------------------------------------------------------
    @property
    def linear(self):
        """The classical stage derivatives, tuple of read-only (d, d) arrays."""
        return self._linear

    @property
    def jumps(self):
        """The event-group B-derivatives, tuple of BDerivative."""
        return self._jumps

    @property
    def n_groups(self):
        """Number of event groups."""
        return len(self._jumps)

    @property
    def stops_at_group(self):
        """True when the last event group lies at the final time (a
        :class:`~bderiv.models.events.finaltime.FinalTimeMap`: its last local event is the
        final time)."""
        return bool(self._jumps) and isinstance(self._jumps[-1], FinalTimeMap)

    @property
    def is_linear(self):
        """True when no event group lies on the trajectory (a classical derivative)."""
        return not self._jumps

    def __repr__(self):
        sizes = [bd.n_events for bd in self._jumps]
        merged = ""
        if any(s > 0 for s in self.group_spreads):  # groups of events measurably apart
            merged = f", spreads={[float(f'{s:.3g}') for s in self.group_spreads]}"
        last = ""
        if self.stops_at_group:  # its size counts the final time, local event n_g - 1
            last = f" (the last with the final time as its event {sizes[-1] - 1})"
        return (f"FlowBDerivative(dim={self.dim}, groups={sizes}{last}, t_final={self.t_final}"
                f"{merged})")

    def __setstate__(self, state):
        # unpickled arrays come back writeable; keep the stages read-only as built (a map
        # pickled before group_spreads existed: its groups were each at one point)
        state.setdefault("group_spreads", (0.0,) * len(state["_jumps"]))
        state.setdefault("group_states", ())
        self.__dict__.update(state)
        for arr in (*self._linear, *self.group_states, self.final_field, self.x0,
                    self.x_final):
            if arr is not None:
                arr.setflags(write=False)

    # ------------------------------------------------------------------------------
    def _stage_inputs(self, flat, name="V", offset=0, dt=None):
        """The vectors entering each jump, then the final result: a list of (m, d) arrays
        (:func:`~bderiv.analysis._flowstages.stage_inputs`)."""
        return stage_inputs(self._linear, self._jumps, flat, name, offset, dt)

    def apply(self, V, out=None, *, dt=None, chunk_size=None, progress=None):
        """Apply the B-derivative to tangent vectors.

        Parameters
        ----------
        V : array_like, shape (..., d), or a dask array
            Perturbations of the start point.
        out : ndarray, shape (..., d), optional
            Writeable C-contiguous float64 array for the result (may be ``V`` itself).
        dt : array_like, shape (...) or scalar, optional
            Perturbations of the final time, finite; adds ``dt * final_field``. A scalar
            when ``V`` is a dask array.
        chunk_size : int, optional
            Vectors per chunk (results do not depend on it); default: all at once, or
            chunks when ``V`` is a memmap, ``progress`` is given or ``V`` has more than
            2**20 vectors.
        progress : callable ``progress(done, total)``, or True, optional
            Called after each chunk; ``True`` draws a tqdm bar.

        Returns
        -------
        ndarray, shape (..., d)
            (A lazy dask array, computed block-wise, when V is a dask array.)
        """
        if dt is None:
            return evaluate(self._forward, V, self.dim, out=out, chunk_size=chunk_size,
                            progress=progress, desc="FlowBDerivative", method=self.apply)
        if self.final_field is None:
            raise ValueError("this map has no final_field, so dt cannot be used")
        if is_dask_array(V):
            if np.ndim(dt) != 0:
                raise ValueError(f"dt must be a scalar when V is a dask array, got shape "
                                 f"{np.shape(dt)}")
            method = functools.partial(self.apply, dt=check_dt(dt, ()).item())
            return evaluate(None, V, self.dim, out=out, method=method)
        dt = check_dt(dt, np.shape(V)[:-1])
        return evaluate(functools.partial(self._forward, dt=dt), V, self.dim, out=out,
                        chunk_size=chunk_size, progress=progress, desc="FlowBDerivative")

    __call__ = apply

    def _forward(self, rows, res, offset, dt=None):
        """The kernel of :meth:`apply`: ``res = D(rows) (+ dt * final_field)``."""
        if dt is not None:
            dt = dt[offset : offset + len(rows)]
        *_, W = self._stage_inputs(rows, "V", offset, dt)
        if dt is not None:
            with np.errstate(over="ignore", invalid="ignore"):
                W += dt[:, None] * self.final_field
        res[...] = W
        if not all_finite(res):
            check_finite_result(res, "V", offset)

    def inverse(self, W, out=None, *, chunk_size=None, progress=None):
        """The inverse map: final-point perturbations to start-point perturbations.

        Parameters
        ----------
        W : array_like, shape (..., d), or a dask array
        out, chunk_size, progress : optional
            As for :meth:`apply`.

        Returns
        -------
        ndarray, shape (..., d)
            ``V`` with ``self(V) == W`` up to rounding.

        Raises
        ------
        ValueError
            If a linear stage is singular to working precision (naming it).
        """
        return evaluate(self._backward, W, self.dim, name="W", out=out, chunk_size=chunk_size,
                        progress=progress, desc="FlowBDerivative.inverse",
                        method=self.inverse)

    def _backward(self, rows, res, offset):
        """The kernel of :meth:`inverse`: the stages' inverses in reverse order."""
        res[...] = backward(self._stage_inverses, self._jumps, rows, offset)
        if not all_finite(res):
            check_finite_result(res, "W", offset)

    @functools.cached_property
    def _stage_inverses(self):
        """Inverses of the linear stages, (d, d) each, computed once (on the first inverse;
        :func:`~bderiv.analysis._flowstages.stage_inverses`)."""
        return stage_inverses(self._linear)

    def event_times(self, V):
        """Event times and orders of every group for tangent vectors V.

        Parameters
        ----------
        V : array_like, shape (..., d)
            NumPy (a dask array is refused: apply it with ``map_blocks``), sized before
            it is converted (a ValueError if the pass would not fit in memory).

        Returns
        -------
        list of (times, order)
            One pair per group, each as returned by :meth:`BDerivative.event_times` for
            the vectors entering that group: ``times`` (..., n_g) the first-order time
            shifts of the group's events (local index), ``order`` (..., n_g) int64 the
            local event order. An empty list when there is no group.
        """
        V = check_pass(V, self, "event_times", 2)
        flat, lead = check_points(V, self.dim)
        res = []
        for bd, W in zip(self._jumps, self._stage_inputs(flat), strict=False):
            times, order = bd.event_times(W)
            n_g = bd.n_events
            res.append((times.reshape(*lead, n_g), order.reshape(*lead, n_g)))
        return res

    def triangulation(self, max_pieces: int = MAX_PIECES):
        """The map as vertices and simplices: the fan of its one event group's map carried
        by the linear stages (:meth:`Triangulation.composed`), pre-event vertices pulled
        back to x0 (by ``linear[0]``), post-event vertices pushed to t_final (``linear[1]``).

        Raises
        ------
        ValueError
            Unless the trajectory meets exactly one event group (several groups' pieces
            are not one fan; with none the map is linear, ``linear[0]``); as for
            :meth:`BDerivative.triangulation`; or for a singular stage.
        """
        if self.n_groups != 1:
            raise ValueError(
                f"the flow map meets {self.n_groups} event groups; a triangulation (one fan "
                f"of simplices) exists for exactly one group"
            )
        if self.stops_at_group:
            raise ValueError(
                "the flow map's event group lies at the final time (its map is stopped "
                "there); no triangulation is offered for it: choose a final time after the "
                "group"
            )
        (L0, L1), (M,) = self._linear, self._jumps
        return M.triangulation(max_pieces).composed(L0, L1)

    def _tangent_rows(self, V, T, res, transpose: bool, offset: int, name: str) -> None:
        """The kernel of ``jvp``/``vjp``: group i's piece is the one that the vector
        entering it selects (:func:`~bderiv.analysis._flowstages.tangent_rows`)."""
        res[...] = tangent_rows(self._linear, self._jumps, V, T, transpose, offset, name)
        if not all_finite(res):
            check_finite_result(res, name, offset)

    def orders(self, V):
        """Local event order of each group for tangent vectors V: list of (..., n_g) int64.

        The ``order`` halves of :meth:`event_times`, given also where the times themselves
        are beyond float64 (each stage's ``orders``: V of subnormal size). A group at the
        final time (``stops_at_group``) has one more local event, the last: the final time
        itself, so the events after it in an order come after ``t_final`` (not applied).
        """
        V = check_pass(V, self, "orders", 1)
        flat, lead = check_points(V, self.dim)
        return [bd.orders(W).reshape(*lead, bd.n_events)
                for bd, W in zip(self._jumps, self._stage_inputs(flat), strict=False)]

    def apply_orders(self, V):
        """``(self(V), self.orders(V))`` from one pass through the stages (for a (m, d)
        batch): what an iteration of the map that counts its pieces needs
        (:func:`bderiv.analysis.stability.growth_rate`), at the cost of :meth:`orders` alone.

        Parameters
        ----------
        V : array_like, shape (m, d)

        Returns
        -------
        W : ndarray, shape (m, d)
            The images, the same bits as :meth:`apply`.
        orders : list of ndarray, shape (m, n_g), int64
            As :meth:`orders`.
        """
        V = check_pass(V, self, "apply_orders", 1)
        V = check_matrix(V, "V", (None, self.dim), copy=False)  # a copy only to convert
        inputs = self._stage_inputs(np.ascontiguousarray(V, dtype=np.float64))
        return inputs[-1], [bd.orders(X) for bd, X in zip(self._jumps, inputs, strict=False)]

    def piece(self, orders=None, *, with_time=False):
        """The linear piece for one event order per group.

        Parameters
        ----------
        orders : sequence of sequences of int, optional
            ``orders[i]`` is a permutation of ``0..n_g - 1`` (local indices of group i;
            a group at the final time has the final time as one more local event, the
            last). May be omitted when every group has a single event (or there is none).
        with_time : bool
            Append the final-time derivative as column d.

        Returns
        -------
        ndarray, shape (d, d) or (d, d + 1)
        """
        orders = group_orders(self._jumps, orders)
        if check_bool(with_time, "with_time") and self.final_field is None:
            raise ValueError("this map has no final_field, so with_time cannot be used")
        M, shift = compose_piece(self._linear, self._jumps, orders)
        if with_time:
            M = np.column_stack((M, self.final_field + shift))
        return np.array(M)
