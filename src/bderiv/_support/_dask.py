"""Lazy, block-wise evaluation of a map on dask arrays.

Imported by :func:`bderiv._support._batch.evaluate` only when a query is a dask array
(``_batch.is_dask_array`` decides that from the type's module, without importing dask).
Each block of the dask array is evaluated by the ordinary NumPy path of the map, in
whatever process or machine the scheduler runs it. It must pickle (``BDerivative``,
``FlowBDerivative`` and ``Triangulation`` do: they hold only NumPy arrays and plain
values).

How the map travels. Built while a ``dask.distributed`` client is the default one (a
``Client(...)`` made in this process, :func:`distributed.default_client`), the graph
refers to the map scattered to that client's workers once (``client.scatter(...,
broadcast=True)``), kept for the map's lifetime and reused by every later graph of the
same map on the same client: a ``.compute()`` then sends a key, not the map (the map in the
graph went with every compute, 576 MiB at n = d = 20, and the client warned "Sending
large graph"). Such a graph is for that client: compute it there. Without a client the map
is one key of the graph (a ``dask.delayed`` value) on which every block's task depends,
so any scheduler pickles it once per compute, however many blocks there are (in a task
of its own it was pickled with every task).

Also the preload of the worker processes that ``stability_map(client="local")`` starts
(:func:`dask_setup`: they leave Ctrl-C to the caller) and their end after it
(:func:`end_now`).
"""

from __future__ import annotations

import contextlib
import inspect
import logging
import os
import signal
import sys
import threading
import uuid
import weakref

import numpy as np

from ._errors import QueryError
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
        Lazy; nothing is computed until ``.compute()`` (or ``dask.compute``). A row that
        a block refuses is named by its index in the whole of ``V``, as for a NumPy
        query (``V[1003]``, not its row in the block).

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
    # fresh keys: naming them by a hash of the map would pickle all of it to hash it
    token = uuid.uuid4().hex
    what = getattr(fn, "__name__", "map")
    # a bound method travels as its object (the map) and its name: apply and inverse of
    # one map share what is scattered
    owner, method = (fn.__self__, fn.__name__) if inspect.ismethod(fn) else (fn, None)
    shipped = _scattered(owner)
    if shipped is None:
        import dask

        shipped = dask.delayed(owner, pure=True, name=f"bderiv-shipped-{token}")
    return V.map_blocks(_apply, shipped, method, dtype=np.float64,
                        meta=np.empty((0,) * V.ndim), name=f"bderiv-{what}-{token}")


#: (id of the map, client id) -> (weak reference to the map, its scattered future)
_SCATTERED: dict = {}


def _scattered(owner):
    """The future of ``owner`` scattered to the default distributed client (once per map
    and client, while the map lives), or None: no client, or a map that cannot be held
    by a weak reference (it then goes in the graph)."""
    distributed = sys.modules.get("distributed")  # not imported: no client
    if distributed is None:
        return None
    try:
        client = distributed.default_client()
    except ValueError:  # no client
        return None
    key = (id(owner), client.id)
    found = _SCATTERED.get(key)
    if found is not None and found[0]() is owner and found[1].status == "finished":
        return found[1]
    try:
        ref = weakref.ref(owner, lambda _, key=key: _SCATTERED.pop(key, None))
    except TypeError:
        return None
    future = client.scatter(owner, broadcast=True, hash=False)
    _SCATTERED[key] = (ref, future)
    return future


def _apply(block, owner, method, block_info=None):
    """One block's task: the map's ``method`` (or ``owner`` itself when None) on the
    block, as a float64 ndarray.

    A refused row (a :class:`~bderiv._support._errors.QueryError`: a non-finite vector, a
    query the kernels refuse) is named by its index in the whole dask array, not in the
    block: ``block_info`` (given by ``map_blocks``) says where the block sits."""
    fn = owner if method is None else getattr(owner, method)
    block = np.asarray(block)
    lead = block.shape[:-1]
    try:
        return np.asarray(fn(block), dtype=np.float64)
    except QueryError as exc:
        where, whole = _whole_row(exc.row, lead, block_info)
        raise exc.at(row=where, shape=whole) from None


def _whole_row(row, lead, block_info):
    """``(flat index, leading shape)`` in the whole dask array of the block's flat row
    ``row`` (the block of leading shape ``lead``, placed by ``block_info``; None: the
    block is the whole array)."""
    if block_info is None or 0 not in block_info:
        return row, lead
    info = block_info[0]
    starts = [start for start, _ in info["array-location"][:-1]]
    whole = tuple(info["shape"][:-1])
    if not whole:
        return row, whole
    index = [int(i) + s for i, s in zip(np.unravel_index(row, lead), starts, strict=True)]
    return int(np.ravel_multi_index(index, whole)), whole


def dask_setup(worker) -> None:
    """The preload of the worker processes of the LocalCluster that ``stability_map(
    client="local")`` starts for its call (``preload=["bderiv._support._dask"]``; called
    by ``distributed`` in the worker process as it starts): they ignore SIGINT.

    A terminal's Ctrl-C goes to every process of its foreground process group, the
    cluster's worker processes included: each printed the traceback of a KeyboardInterrupt
    in its event loop while the caller's own KeyboardInterrupt closed the cluster. They
    are ended by the caller that started them instead. The worker's event loop runs in its
    process's main thread, where alone a signal's handler can be set.
    """
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def end_now(client, cluster) -> None:
    """Close the LocalCluster that ``stability_map(client="local")`` started, after Ctrl-C:
    its workers end now, not restarted by their nannies (closed as usual, a worker running
    a point was given the nanny's 4 s to finish it before it was killed), and the logs of
    the comms so broken (the scheduler's and the client's, now and then one to three
    lines with a traceback) are not shown: the teardown of this cluster, its loggers
    restored after."""
    quiet = [logging.getLogger(name) for name in ("distributed", "tornado")]
    levels = [logger.level for logger in quiet]
    for logger in quiet:
        logger.setLevel(logging.CRITICAL + 1)
    try:
        client.close()
        for nanny in list(cluster.workers.values()):
            nanny.close_gracefully(reason="bderiv: interrupted")
            if nanny.pid is not None:
                with contextlib.suppress(OSError):
                    os.kill(nanny.pid, signal.SIGTERM)
        cluster.close()
    finally:
        for logger, level in zip(quiet, levels, strict=True):
            logger.setLevel(level)


def start_local(workers: int):
    """``(client, cluster)``: the LocalCluster of ``stability_map(client="local")`` (one
    thread per worker process, the workers ignoring SIGINT: :func:`dask_setup`), started
    in a thread of its own. A Ctrl-C while it starts (a second or two) raises here at
    once, and the cluster is ended as soon as it stands (:func:`end_now`): interrupted
    inside its constructor, it was left half made, and distributed's exit handler printed
    a hundred lines ending in "AssertionError: Status.init". (A worker process still
    starting, before :func:`dask_setup`, prints its own KeyboardInterrupt: the terminal's
    Ctrl-C reaches it, and no setting of the caller's keeps it from a spawned process.)"""
    from distributed import Client, LocalCluster

    lock, made, interrupted = threading.Lock(), [], []

    def start():
        try:
            # its scheduler's HTTP server on a free port: by default it takes 8787, and
            # where that is taken (the user's own cluster) distributed warns and takes another
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                   dashboard_address=None,
                                   scheduler_kwargs={"dashboard_address": ":0"},
                                   preload=["bderiv._support._dask"])
            pair = (Client(cluster), cluster)
        except BaseException as exc:  # noqa: BLE001 - raised in the caller's thread
            made.append(exc)
            return
        with lock:
            made.append(pair)
            ended = bool(interrupted)
        if ended:
            end_now(*pair)

    thread = threading.Thread(target=start, name="bderiv-start-cluster", daemon=False)
    thread.start()
    try:
        while thread.is_alive():
            thread.join(0.1)
    except KeyboardInterrupt:
        with lock:
            interrupted.append(True)
        raise
    if isinstance(made[0], BaseException):
        raise made[0]
    return made[0]

