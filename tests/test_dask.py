"""Dask: ``bd(x)`` with a dask array is lazy and block-wise; maps pickle; a real cluster.

The in-process tests use dask's synchronous and threaded schedulers; one test runs a
``distributed.LocalCluster`` with two worker processes.
"""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from numpy.testing import assert_array_equal

import bderiv._support._dask
from bderiv import BDerivative
from bderiv._support._batch import is_dask_array

da = pytest.importorskip("dask.array")
dask = pytest.importorskip("dask")


def three_events():
    F = np.ones((8, 3))
    F[0b001] = (1.0, 0.1, 1.0)
    F[0b011] = (1.0, 0.5, 2.0)
    F[0b111] = (1.5, 1.0, 2.0)
    return BDerivative(np.eye(3), F)


@pytest.fixture(scope="module")
def bd():
    return three_events()


@pytest.fixture(scope="module")
def X():
    return np.random.default_rng(0).standard_normal((5000, 3))


def test_detection_without_importing_dask(X):
    assert not is_dask_array(X)
    assert not is_dask_array([1.0, 2.0])
    assert is_dask_array(da.from_array(X))
    assert not hasattr(bderiv._support._dask, "is_dask_array")  # one check, in _batch


def test_lazy_and_identical(bd, X):
    D = da.from_array(X, chunks=(1500, 3))
    W = bd(D)
    assert is_dask_array(W)  # nothing computed yet
    assert W.shape == X.shape and W.dtype == np.float64
    assert W.chunks == D.chunks
    with dask.config.set(scheduler="synchronous"):
        assert_array_equal(W.compute(), bd(X))
        assert_array_equal(bd.inverse(W).compute(), bd.inverse(bd(X)))
    assert_array_equal(bd.apply(D).compute(scheduler="threads"), bd(X))


def test_last_axis_split_and_leading_axes(bd, X):
    V = X[:600].reshape(20, 30, 3)
    D = da.from_array(V, chunks=(7, 11, 2))  # vectors split across blocks: rechunked
    W = bd(D)
    assert W.shape == (20, 30, 3)
    assert_array_equal(W.compute(scheduler="synchronous"), bd(V))


def test_integer_dask_input(bd):
    V = np.array([[-1, -2, -3], [3, 1, 2]])
    assert_array_equal(bd(da.from_array(V)).compute(), bd(V.astype(float)))


def test_bad_dask_input(bd, X):
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 3\)"):
        bd(da.from_array(X[:, :2]))
    with pytest.raises(ValueError, match="out cannot be used"):
        bd(da.from_array(X), out=np.empty_like(X))
    for options in ({"chunk_size": 0}, {"chunk_size": 10}, {"progress": True},
                    {"progress": lambda done, total: None}):  # they were ignored silently
        with pytest.raises(ValueError, match=r"chunk_size and progress do not apply to a "
                                             r"dask array V: its blocks are its chunks"):
            bd(da.from_array(X), **options)
    with pytest.raises(TypeError, match="real numbers"):
        bd(da.from_array(np.ones((4, 3), dtype=complex)))
    for bad in (X[:, :2], np.ones((4, 3), dtype=complex), np.ones((4, 3), dtype=bool)):
        with pytest.raises((ValueError, TypeError)) as lazy:
            bd(da.from_array(bad))
        with pytest.raises(type(lazy.value)) as eager:
            bd(bad)
        assert str(lazy.value) == str(eager.value)  # the messages of a NumPy query


def test_bderivative_pickles(bd, X):
    clone = pickle.loads(pickle.dumps(bd))
    assert_array_equal(clone(X), bd(X))
    assert_array_equal(clone.inverse(X), bd.inverse(X))
    assert not clone.F.flags.writeable and not clone.Dh.flags.writeable
    assert not clone.rates.flags.writeable


def test_flow_map_pickles():
    examples = pytest.importorskip("bderiv.examples")
    ex = examples.network(3)
    fb = ex.system.flow_bderivative(ex.x0, ex.t_final)
    V = np.random.default_rng(1).standard_normal((100, 3))
    clone = pickle.loads(pickle.dumps(fb))
    assert_array_equal(clone(V), fb(V))
    lazy = fb(da.from_array(V, chunks=(30, 3)))  # the flow map is lazy on dask too
    assert is_dask_array(lazy)
    assert_array_equal(lazy.compute(scheduler="processes"), fb(V))
    for (t1, o1), (t2, o2) in zip(clone.event_times(V), fb.event_times(V), strict=True):
        assert_array_equal(t1, t2)
        assert_array_equal(o1, o2)


def test_local_cluster(bd):
    """Two worker processes: the map travels by pickle and the results are identical.

    About 15 s on two busy cores (worker start-up and loading the cached kernels), so it
    stays in CI, under the 20 s line above which it would be marked slow.
    """
    distributed = pytest.importorskip("distributed")
    X = np.random.default_rng(2).standard_normal((200_000, 3))
    with (
        distributed.LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
            scheduler_kwargs={"dashboard_address": ":0"}
        ) as cluster,
        distributed.Client(cluster) as client,
    ):
        D = da.from_array(X, chunks=(25_000, 3))
        W = bd(D).compute()
        back = bd.inverse(bd(D)).compute()
        workers = client.run(lambda: __import__("os").getpid())
    assert len(set(workers.values())) == 2
    assert_array_equal(W, bd(X))
    assert_array_equal(back, bd.inverse(bd(X)))


def test_corner_model_pickles_and_runs_lazily():
    """A BDerivative built on a corner model (no 2**n table) travels to workers too."""
    from bderiv import StructuredCorners

    model = StructuredCorners(F0=[1.0, 1.0, 1.0], A=[[0.5, 0.0, 0.0], [0.0, 0.2, 0.0],
                                                     [0.0, 0.0, 0.3]])
    bd = BDerivative(np.eye(3), model)
    V = np.random.default_rng(4).standard_normal((3000, 3))
    clone = pickle.loads(pickle.dumps(bd))
    assert_array_equal(clone(V), bd(V))
    lazy = bd(da.from_array(V, chunks=(1000, 3)))
    assert_array_equal(lazy.compute(scheduler="processes"), bd(V))


def test_triangulation_lazy_in_processes(bd, X):
    """A Triangulation (and its inverse) on dask: lazy, pickled to worker processes."""
    tri = bd.triangulation()
    V = X[:3000]
    D = da.from_array(V, chunks=(1000, 3))
    W = tri(D)
    assert is_dask_array(W) and W.chunks == D.chunks
    back = tri.inverse(W)
    assert is_dask_array(back)
    w, v = dask.compute(W, back, scheduler="processes")
    assert_array_equal(w, tri(V))
    assert_array_equal(v, tri.inverse(tri(V)))
    with pytest.raises(ValueError, match="out cannot be used"):
        tri(D, out=np.empty_like(V))


# -- a refused row is named by its index in the whole dask array, not in its block ---------


_MAPS = {
    "apply": lambda bd: bd,
    "inverse": lambda bd: bd.inverse,
    "triangulation": lambda bd: bd.triangulation(),
    "triangulation inverse": lambda bd: bd.triangulation().inverse,
}


def _refusals(fn, V, chunks):
    """The error of ``fn`` on ``V`` as a dask array of ``chunks`` (computed), and on ``V``
    itself."""
    with pytest.raises(ValueError) as lazy:
        fn(da.from_array(V, chunks=chunks)).compute(scheduler="synchronous")
    with pytest.raises(ValueError) as eager:
        fn(V)
    return lazy.value, eager.value


@pytest.mark.parametrize("which", list(_MAPS))
def test_a_nan_row_of_the_second_block_is_named_by_its_global_index(bd, X, which):
    """Two blocks of 1000 rows, a NaN in row 1003 (row 3 of the second block): the error
    names V[1003] (W[1003] for an inverse), as for the NumPy array, not V[3]."""
    V = X[:2000].copy()
    V[1003] = np.nan
    lazy, eager = _refusals(_MAPS[which](bd), V, (1000, 3))
    assert "[1003] = [nan nan nan] is not" in str(lazy)
    assert str(lazy) == str(eager)


def test_a_refused_query_of_the_second_block_is_named_by_its_global_index(bd, X):
    """A refusal by the map itself (a QueryError: the result overflows float64) is
    renumbered too."""
    V = X[:2000].copy()
    V[1003] = 1e308
    lazy, eager = _refusals(bd, V, (1000, 3))
    assert type(lazy).__name__ == "QueryError"
    assert str(lazy).startswith("the result for V[1003] overflowed")
    assert str(lazy) == str(eager)


@pytest.mark.parametrize("bad", [np.nan, 1e308], ids=["nan", "overflow"])
def test_several_leading_axes_chunked_name_the_full_index(bd, X, bad):
    """Leading axes (40, 50) in blocks of (20, 20): row (25, 37) sits at (5, 17) of its
    block; the error names V[25, 37]."""
    V = np.resize(X, (40, 50, 3)).copy()
    V[25, 37] = bad
    lazy, eager = _refusals(bd, V, (20, 20, 3))
    assert "V[25, 37]" in str(lazy)
    assert str(lazy) == str(eager)


def test_methods_without_dask_blocks_refuse_a_dask_array_without_computing_it(bd):
    """event_times, orders and piece_matrices take NumPy arrays: a dask array is refused
    (as jvp and vjp refuse it), never converted (it was computed whole in memory)."""

    def never(block):
        raise AssertionError("the dask array was computed")

    V = da.ones((40, bd.dim), chunks=(10, bd.dim)).map_blocks(never, dtype=float)
    for call in (bd.event_times, bd.orders, bd.piece_matrices):
        with pytest.raises(TypeError, match=r"take[s]? NumPy arrays, got a dask array; apply "
                                            r"it block by block with dask.array.map_blocks"):
            call(V)


def test_flow_map_methods_without_dask_blocks_refuse_a_dask_array_as_bderivative_does(bd):
    """The flow map's orders, event_times and apply_orders refuse a dask array in the words
    of BDerivative's, never converting it (np.asarray computed it whole in memory)."""
    from bderiv.analysis.flowmap import FlowBDerivative

    def never(block):
        raise AssertionError("the dask array was computed")

    fb = FlowBDerivative([np.eye(3), 2.0 * np.eye(3)], [bd])
    V = da.ones((40, 3), chunks=(10, 3)).map_blocks(never, dtype=float)
    words = (r" NumPy arrays, got a dask array; apply it block by block with "
             r"dask.array.map_blocks \(converting it would compute it whole in memory\)")
    for call in (fb.event_times, fb.orders):
        with pytest.raises(TypeError, match="^event_times and orders take" + words):
            call(V)
    with pytest.raises(TypeError, match="^apply_orders takes" + words):
        fb.apply_orders(V)
    with pytest.raises(TypeError, match="^event_times and orders take" + words):
        bd.orders(V)  # the same words
