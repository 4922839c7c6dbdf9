"""The stages of a flow map's B-derivative and the passes of a batch through them.

``D = L_m . M_m . L_{m-1} . ... . M_1 . L_0``
(:class:`~bderiv.analysis.flowmap.FlowBDerivative`): the linear stages ``L_i`` (d, d) are
applied to the rows of a batch by a numba kernel, the event groups' maps ``M_i`` (each a
:class:`~bderiv.engine.bderivative.BDerivative`, the last possibly a
:class:`~bderiv.models.events.finaltime.FinalTimeMap`) by their own evaluation. Forwards
(:func:`stage_inputs`), backwards through the inverses (:func:`backward`), the tangent
maps of one piece per row (:func:`tangent_rows`) and the piece of given event orders
(:func:`compose_piece`); the checks of the stages (:func:`check_stages`), of the
final-time perturbations (:func:`check_dt`), of the orders (:func:`group_orders`) and of
a batch's size before it is converted (:func:`check_pass`); a group's refusal said of the
flow map's batch (:func:`in_group`).
"""

from __future__ import annotations

import numpy as np

from .._kernels import _core
from .._kernels import linear as _linear
from .._support._batch import refuse_dask
from .._support._errors import QueryError
from .._support._validate import (
    AS_ROWS,
    FEWER_ROWS,
    all_finite,
    batch_size,
    check_finite_result,
    check_matrix,
    check_memory,
    check_real_array,
    singular_condition,
)
from ..engine.bderivative import BDerivative
from ..models.events.finaltime import FinalTimeMap


def check_stages(linear, jumps) -> tuple[tuple, tuple, int]:
    """The checked stages: ``(linear, jumps, d)``, ``linear`` a tuple of ``len(jumps) + 1``
    read-only float64 (d, d) arrays, ``jumps`` a tuple of maps of dimension d (a
    :class:`~bderiv.models.events.finaltime.FinalTimeMap` only last)."""
    jumps = list(jumps)
    for i, bd in enumerate(jumps):
        last = i == len(jumps) - 1
        if not isinstance(bd, BDerivative) and not (last and isinstance(bd, FinalTimeMap)):
            where = " (only the last jump may be one)" if isinstance(bd, FinalTimeMap) else ""
            raise TypeError(
                f"jumps[{i}] must be a BDerivative, got {type(bd).__name__}{where}"
            )
    linear = list(linear)
    if len(linear) != len(jumps) + 1:
        raise ValueError(
            f"need len(jumps) + 1 = {len(jumps) + 1} linear stages, got {len(linear)}"
        )
    first = np.asarray(linear[0])
    if first.ndim != 2:
        raise ValueError(f"linear[0] must be a (d, d) matrix, got shape {first.shape}")
    d = first.shape[0]
    linear = tuple(check_matrix(L, f"linear[{i}]", (d, d)) for i, L in enumerate(linear))
    for L in linear:
        L.setflags(write=False)
    for i, bd in enumerate(jumps):
        if bd.dim != d:
            raise ValueError(f"jumps[{i}] has dimension {bd.dim} but the stages have {d}")
    return linear, tuple(jumps), d


def check_pass(V, fb, method: str, results: int):
    """``V`` for a pass of the flow map ``fb``'s ``method`` through its stages (``V``
    itself, or as an array: :func:`~bderiv._support._validate.batch_size`), refused before
    it is converted if it is a dask array (in :func:`~bderiv._support._batch.refuse_dask`'s
    words, as ``BDerivative``'s ``event_times`` and ``orders`` refuse it) or if the pass
    would take more than the process may: the vectors entering each stage
    (:func:`stage_inputs`), ``results`` int64 or float64 per event of each group per
    vector, and the float64 copy of ``V`` where one is made."""
    refuse_dask(V, what="apply_orders takes" if method == "apply_orders" else
                "event_times and orders take")
    d, jumps = fb.dim, fb.jumps
    V, m, copy = batch_size(V, d)
    events = sum(bd.n_events for bd in jumps)
    groups = f"{len(jumps)} event group" + ("" if len(jumps) == 1 else "s")
    check_memory(copy + 8 * m * ((len(jumps) + 1) * d + results * events), None,
                 f"the {method} of {m} vectors through {groups} ({events} events: the vectors "
                 f"entering each stage{',' if copy else ' and'} the results"
                 f"{AS_ROWS if copy else ''}) would",
                 FEWER_ROWS)
    return V


def stage(L, X, transpose: bool = False) -> np.ndarray:
    """Rows of X through a linear stage: ``X @ L.T`` (``X @ L`` when ``transpose``).

    A numba kernel of the package (parallel over rows, in tasks) rather than BLAS: these
    products are thin, (m, d) x (d, d), and BLAS's own threads, on a machine whose cores
    are busy, made their time swing 5x and more (docs/concepts.md, "Gotchas"; issue 10);
    overflow gives inf.
    """
    M = np.ascontiguousarray(L if transpose else L.T)  # the kernel combines rows of M
    out = np.empty((X.shape[0], M.shape[1]))
    _linear.linear(_linear.LinearTables(M, M), np.ascontiguousarray(X), (out,), False,
                   launch=_core.launch_queries(1, X.shape[1]))
    return out


def stage_inputs(linear, jumps, flat, name="V", offset=0, dt=None) -> list:
    """The vectors entering each jump, then the final result: a list of (m, d) arrays.

    Errors name the row of the caller's batch (``offset`` is the first row's index) and
    the group; a stage whose result overflows is refused, not passed on. ``dt`` (m,):
    the final-time perturbations of the rows, for a group at the final time.
    """
    out = []
    W = flat
    for i, L in enumerate(linear):
        W = stage(L, W)
        if not all_finite(W):
            check_finite_result(W, name, offset, f"result of linear stage linear[{i}]")
        out.append(W)
        if i < len(jumps):
            jump = jumps[i]
            try:
                W = jump(W, dt) if isinstance(jump, FinalTimeMap) else jump(W)
            except ValueError as exc:
                raise in_group(exc, i, offset, name) from None
    return out


def stage_inverses(linear) -> tuple:
    """Inverses of the linear stages, (d, d) each, read-only.

    Explicit inverses (NumPy's LU-based ``inv``) applied as thin products like the
    forward stages, rather than ``scipy.linalg.lu_solve`` per batch: SciPy's LAPACK
    calls corrupted memory when threads (dask's default scheduler) shared the factors.
    """
    inverses = []
    for i, L in enumerate(linear):
        cond = singular_condition(L)
        if cond is not None:
            raise ValueError(
                f"the flow map is not invertible: its linear stage linear[{i}] is "
                f"singular to working precision (condition number {cond:.3g}); inverse "
                f"needs every linear stage invertible"
            )
        inv = np.linalg.inv(L)
        inv.setflags(write=False)
        inverses.append(inv)
    return tuple(inverses)


def backward(inverses, jumps, rows, offset) -> np.ndarray:
    """Rows (m, d) of final-point perturbations through the stages' inverses in reverse
    order (``inverses``: :func:`stage_inverses`): the start-point perturbations."""
    V = stage(inverses[-1], rows)
    for i in reversed(range(len(jumps))):
        try:
            V = jumps[i].inverse(V)
        except ValueError as exc:
            raise in_group(exc, i, offset, "W") from None
        V = stage(inverses[i], V)
    return V


def tangent_rows(linear, jumps, V, T, transpose: bool, offset: int, name: str) -> np.ndarray:
    """The tangent maps of ``jvp``/``vjp``: group i's piece is the one that the vector
    entering it (row v of ``V`` through the earlier stages) selects. Forwards
    ``L_m J_m ... J_1 L_0 t``; the transpose ``L_0^T J_1^T ... J_m^T L_m^T w``."""
    m = len(jumps)
    inputs = stage_inputs(linear, jumps, V, "V", offset)
    Y = T
    Y = stage(linear[m], Y, transpose) if transpose else stage(linear[0], Y)
    for i in reversed(range(m)) if transpose else range(m):
        Z = np.empty_like(Y)
        try:
            jumps[i]._tangent_rows(inputs[i], Y, Z, transpose, 0, name)
        except ValueError as exc:
            raise in_group(exc, i, offset) from None
        Y = stage(linear[i], Z, True) if transpose else stage(linear[i + 1], Z)
    return Y


def check_dt(dt, lead) -> np.ndarray:
    """The final-time perturbations ``dt`` as a flat float64 array of the batch's rows
    (broadcast to ``lead``, the batch's leading shape)."""
    arr = check_real_array(dt, "dt")
    try:
        arr = np.broadcast_to(arr, lead)
    except ValueError:
        raise ValueError(
            f"dt must be a scalar or have a shape that broadcasts to the leading shape "
            f"{lead} of V, got shape {arr.shape}"
        ) from None
    arr = arr.astype(np.float64).reshape(-1)
    if not np.isfinite(arr).all():
        raise ValueError(f"dt must be finite, got {arr[~np.isfinite(arr)][0]}")
    return arr


def group_orders(jumps, orders) -> list:
    """The checked count of ``orders``, one event order per group: ``list(orders)``, or
    ``[[0], ...]`` for ``None`` when every group has a single event."""
    if orders is None:
        if any(bd.n_events > 1 for bd in jumps):
            raise ValueError(
                "orders must be given: groups "
                f"{[i for i, bd in enumerate(jumps) if bd.n_events > 1]} have "
                "several events"
            )
        orders = [[0]] * len(jumps)
    orders = list(orders)
    if len(orders) != len(jumps):
        raise ValueError(
            f"need one event order per group ({len(jumps)} groups), got {len(orders)}"
        )
    return orders


def compose_piece(linear, jumps, orders) -> tuple[np.ndarray, np.ndarray | float]:
    """The piece of one event order per group: ``(M, shift)``, M (d, d) and ``shift`` the
    final-time column a group at the final time adds ((d,), else 0.0)."""
    M, shift = linear[0], 0.0
    for i, (bd, order) in enumerate(zip(jumps, orders, strict=True)):
        if isinstance(bd, FinalTimeMap):  # the final time is one of its events
            P = bd.piece(order, with_time=True)
            M, shift = P[:, :-1] @ M, linear[i + 1] @ P[:, -1]
        else:
            M = bd.piece(order) @ M
        M = linear[i + 1] @ M
    return M, shift


def in_group(exc: ValueError, group: int, offset: int, name: str | None = None
             ) -> ValueError:
    """An error of event group ``group``'s map, said of the flow map's batch: a refusal of
    one row (:class:`~bderiv._support._errors.QueryError`) numbered as the caller's row
    ``offset + row`` (of the batch ``name``, else the name it had)."""
    where = f"in event group {group} of the flow map, for the vectors entering it: "
    if isinstance(exc, QueryError):
        return exc.at(row=exc.row + offset, name=name, shape=(), prefix=where)
    return ValueError(where + str(exc))


def read_only_copy(a) -> np.ndarray:
    """A read-only float64 copy."""
    arr = np.array(a, dtype=np.float64)
    arr.setflags(write=False)
    return arr
