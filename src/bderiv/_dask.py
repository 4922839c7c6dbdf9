"""Lazy, block-wise evaluation of a map on dask arrays.

Imported by :func:`bderiv._batch.evaluate` only when a query is a dask array
(``_batch.is_dask_array`` decides that from the type's module, without importing dask).
Each block of the dask array is evaluated by the ordinary NumPy path of the map, in
whatever process or machine the scheduler runs it. The map is one key of the graph (a
``dask.delayed`` value) on which every block's task depends, so a distributed scheduler
pickles it once and moves it to each worker once, however many blocks there are (in a
task of its own it was pickled with every task: 600 MB a task for n = d = 20). It must
pickle (``BDerivative``, ``FlowBDerivative`` and ``Triangulation`` do: they hold only
NumPy arrays and plain values).

Point it at a cluster with ``dask.distributed.Client("tcp://scheduler:8786")`` before
calling ``.compute()``; nothing here depends on the scheduler.
"""

from __future__ import annotations

import uuid

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
    import dask

    # fresh keys: naming them by a hash of the map would pickle all of it to hash it
    token = uuid.uuid4().hex
    what = getattr(fn, "__name__", "map")
    shipped = dask.delayed(fn, pure=True, name=f"bderiv-shipped-{token}")  # not the array's key
    return V.map_blocks(_apply, shipped, dtype=np.float64, meta=np.empty((0,) * V.ndim),
                        name=f"bderiv-{what}-{token}")


def _apply(block, fn):
    """One block's task: ``fn`` (the map's method, computed once per worker) on the block,
    as a float64 ndarray."""
    return np.asarray(fn(np.asarray(block)), dtype=np.float64)
