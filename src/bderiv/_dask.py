"""Lazy, block-wise evaluation of a map on dask arrays.

Imported by :func:`bderiv._batch.evaluate` only when a query is a dask array
(``_batch.is_dask_array`` decides that from the type's module, without importing dask).
Each block of the dask array is evaluated by the ordinary NumPy path of the map, in
whatever process or machine the scheduler runs it; the map is shipped to the workers by
pickling, so it must pickle (``BDerivative``, ``FlowBDerivative`` and ``Triangulation``
do: they hold only NumPy arrays and plain values).

Point it at a cluster with ``dask.distributed.Client("tcp://scheduler:8786")`` before
calling ``.compute()``; nothing here depends on the scheduler.
"""

from __future__ import annotations

import numpy as np

from ._validate import check_real_array


def map_blocks(fn, V, dim: int, name: str = "V", out=None):
    """Apply ``fn`` ((m, dim) ndarray -> (m, dim) ndarray) lazily to a dask array.

    Parameters
    ----------
    fn : callable
        Picklable function of one ndarray block of shape ``(..., dim)``, returning an array
        of the same shape, for example a bound ``BDerivative.apply``.
    V : dask.array.Array, shape (..., dim)
        The queries. Any chunking of the leading axes; the last axis is merged into one
        chunk (each vector must sit whole in one block).
    dim : int
        Vector dimension d.
    name : str
        Name of the argument, for error messages.
    out : None
        Must be None: a lazy result has no output buffer.

    Returns
    -------
    dask.array.Array, shape (..., dim), float64
        Lazy; nothing is computed until ``.compute()`` (or ``dask.compute``).

    Examples
    --------
    >>> import numpy as np
    >>> import dask.array as da
    >>> from bderiv import BDerivative
    >>> F = np.array([[1.0, 1.0], [2.0, 1.0], [1.0, 1.0], [2.0, 1.0]])
    >>> bd = BDerivative(np.eye(2), F)
    >>> V = da.from_array(np.array([[-1.0, -2.0], [-3.0, -1.0]]), chunks=(1, 2))
    >>> W = bd(V)                # lazy dask array
    >>> W.compute()
    array([[-2., -2.],
           [-6., -1.]])
    """
    if out is not None:
        raise ValueError(
            f"out cannot be used when {name} is a dask array (the result is lazy); call "
            f".compute() on the result, or da.store it"
        )
    if V.ndim == 0 or V.shape[-1] != dim:
        got = "a scalar" if V.ndim == 0 else f"shape {V.shape}"
        raise ValueError(
            f"{name} must have shape (..., {dim}) (vectors of dimension {dim}, the dimension "
            f"of this map), got {got}"
        )
    check_real_array(np.empty(0, V.dtype), name)  # the message of a NumPy query
    if len(V.chunks[-1]) != 1:
        V = V.rechunk({V.ndim - 1: dim})
    return V.map_blocks(_BlockApply(fn), dtype=np.float64, meta=np.empty((0,) * V.ndim))


class _BlockApply:
    """Picklable wrapper: evaluate ``fn`` on one block, as a float64 ndarray."""

    def __init__(self, fn):
        self.fn = fn

    def __call__(self, block):
        return np.asarray(self.fn(np.asarray(block)), dtype=np.float64)

    def __repr__(self):  # names the dask tasks readably ("bderiv-apply-...")
        return f"bderiv-{getattr(self.fn, '__name__', 'map')}"
