"""The one call path of every map: ``(..., d)`` in, ``(..., d)`` out.

:func:`evaluate` is what ``BDerivative``, ``FlowBDerivative`` and ``Triangulation`` do
with a batch: validate it, reshape it to C-contiguous float64 ``(m, d)``, hand it to the
map's kernel (which writes into ``(m, d)`` rows of ``out``), and reshape back; or, when
asked, chunk by chunk with progress reports; or, for a dask array, lazily block by block.
"""

from __future__ import annotations

import time

import numpy as np

from .._limits import (
    CHUNK_SECONDS,
    DEFAULT_CHUNK_ROWS,
    FIRST_CHUNK_ROWS,
    IMPLICIT_CHUNK_ROWS,
    PARALLEL_MIN_QUERIES,
    sized_by_time,
)
from ._errors import QueryError
from ._validate import check_memory, check_out, check_points
from ._validate_ints import check_positive_int


def is_dask_array(x) -> bool:
    """True when ``x`` is a ``dask.array.Array`` (checked without importing dask).

    Examples
    --------
    >>> import numpy as np
    >>> is_dask_array(np.zeros(3))
    False
    """
    t = type(x)
    return t.__name__ == "Array" and t.__module__.split(".")[0] == "dask"


def refuse_dask(*arrays, what: str, how: str = "") -> None:
    """Refuse a dask array among ``arrays`` for a method that takes NumPy arrays only
    (``what``: its name and verb; ``how``: a note on the blocks): a TypeError saying how to
    apply it block by block (converted, it would be computed whole in memory)."""
    if any(is_dask_array(a) for a in arrays):
        raise TypeError(f"{what} NumPy arrays, got a dask array; apply it block by block "
                        f"with dask.array.map_blocks{how} (converting it would compute it "
                        f"whole in memory)")


def evaluate(kernel, V, dim: int, *, name: str = "V", out=None, chunk_size=None,
             progress=None, desc: str = "bderiv", method=None):
    """Evaluate a batch map with the common conventions of every public ``__call__``.

    Parameters
    ----------
    kernel : callable ``kernel(rows, res, offset)``
        Writes the map of ``rows`` (C-contiguous float64, shape (m, dim)) into ``res``
        (same shape, C-contiguous float64, never overlapping ``rows``); ``offset`` is the
        index of ``rows[0]`` in the whole batch (for error messages).
    V : array_like, shape (..., dim), or a dask array
    dim : int
    name : str
        The argument's name in error messages.
    out : ndarray, shape (..., dim), optional
        Writeable C-contiguous float64; may be ``V`` itself or overlap it (the input is
        then copied first, as NumPy ufuncs do).
    chunk_size : int, optional
        Rows per kernel call; default: the whole batch at once, or chunks of at most
        ``DEFAULT_CHUNK_ROWS`` rows, each sized to about ``CHUNK_SECONDS`` by the last one's
        time, when ``V`` is a memmap, ``progress`` is given or the batch has more than
        ``IMPLICIT_CHUNK_ROWS`` rows (Ctrl-C is seen between chunks).
    progress : callable ``progress(done, total)``, or bool, optional
        Called after each chunk; ``True`` draws a tqdm bar labelled ``desc``.
    method : callable, optional
        The public method itself (picklable, ``method(block) -> block``), applied block by
        block when ``V`` is a dask array.

    Returns
    -------
    ndarray, shape (..., dim) (a lazy dask array for a dask input)
    """
    if is_dask_array(V):
        from ._dask import map_blocks

        if chunk_size is not None or progress not in (None, False):
            raise ValueError(
                f"chunk_size and progress do not apply to a dask array {name}: its blocks "
                f"are its chunks (rechunk it), and dask shows its own progress "
                f"(dask.diagnostics.ProgressBar, or the distributed dashboard); got "
                f"chunk_size={chunk_size!r}, progress={progress!r}")
        return map_blocks(method, V, dim, name, out)
    large = isinstance(V, np.ndarray) and V.size > IMPLICIT_CHUNK_ROWS * max(dim, 1)
    if chunk_size is None and progress in (None, False) and not isinstance(V, np.memmap) \
            and not large:
        flat, lead = check_points(V, dim, name)
        shape = lead + (dim,)
        result = _result(shape, name) if out is None else check_out(out, shape)
        res = result.reshape(-1, dim)
        if out is not None and np.may_share_memory(flat, res):
            flat = flat.copy()
        _run(kernel, flat, res, 0, name, lead)
        return result
    return _chunked(kernel, V, dim, name, out, chunk_size, progress, desc)


def _chunked(kernel, V, dim, name, out, chunk_size, progress, desc):
    """Chunk by chunk: only one chunk of ``V`` is converted or held at a time (their rows
    as given, else sized by their time: the bits are the same whatever the chunks)."""
    timed = chunk_size is None
    size = min(FIRST_CHUNK_ROWS, DEFAULT_CHUNK_ROWS) if timed else check_positive_int(
        chunk_size, "chunk_size")
    if progress is not None:
        from ._progress import resolve_progress

        progress = resolve_progress(progress, desc=desc)
    if not isinstance(V, np.ndarray):
        V = np.asarray(V)
    if V.ndim == 0 or V.shape[-1] != dim:
        check_points(V, dim, name)  # raises the usual message
    lead = V.shape[:-1]
    rows = V.reshape(-1, dim)  # a view for contiguous (memmap) input
    shape = lead + (dim,)
    result = _result(shape, name) if out is None else check_out(out, shape)
    res = result.reshape(-1, dim)
    if out is not None and np.may_share_memory(rows, res) and not _same_rows(rows, res):
        rows = rows.copy()  # a shifted overlap: later chunks would read what earlier wrote
    total, start = rows.shape[0], 0
    while start < total:
        stop = min(start + size, total)
        began = time.perf_counter()
        flat, _ = check_points(rows[start:stop], dim, name, index_shape=lead, offset=start)
        if out is not None and np.may_share_memory(flat, res):
            flat = flat.copy()
        _run(kernel, flat, res[start:stop], start, name, lead)
        if timed:  # no fewer rows than a parallel launch takes: slow rows keep both threads
            size = sized_by_time(stop - start, time.perf_counter() - began, CHUNK_SECONDS,
                                 PARALLEL_MIN_QUERIES, DEFAULT_CHUNK_ROWS)
        if progress is not None:
            progress(stop, total)
        start = stop
    if progress is not None and total == 0:
        progress(0, 0)
    return result


def _result(shape, name) -> np.ndarray:
    """The result of a batch, refused by name beyond what the process may take (a memmap
    of millions of rows: the result goes to a file of its own through ``out=``)."""
    check_memory(8 * int(np.prod(shape, dtype=object)), None,
                 f"the result for {name} (float64 of shape {shape}) would",
                 "pass out=, a writeable np.memmap of that shape, to write it to a file "
                 "instead")
    return np.empty(shape)


def _run(kernel, rows, res, offset, name, lead) -> None:
    """``kernel(rows, res, offset)``; its refusals of a row (:class:`QueryError`, by flat
    index: ``V[5]``) name it, for a batch with several leading axes, by its full index
    (``V[1, 2]``)."""
    try:
        kernel(rows, res, offset)
    except QueryError as exc:
        raise exc.at(shape=lead) from None


def _same_rows(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether ``a`` and ``b`` are the same rows of the same memory (exact aliasing)."""
    return (a.dtype == b.dtype and a.strides == b.strides
            and a.__array_interface__["data"][0] == b.__array_interface__["data"][0])
