"""Sizes are refused before any copy (issue 27 item 8): big requests and big or endless
files give a ValueError naming the size and the limit, and allocate nothing first."""

from __future__ import annotations

import json
import os
import tracemalloc
import zipfile

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from bderiv import BDerivative, load_triangulation
from bderiv.analysis.stability import check_growth_memory, growth_rate
from bderiv.geometry._triangulation_io import json_parse_bytes

MEMORY = r"take [\d.]+ [KMGTP]?i?B, more than the memory limit of"


@pytest.fixture(scope="module")
def bd():
    F = np.array([[1.0, 1.0, 0.5], [2.0, 1.0, 0.5], [1.0, 1.0, 0.5], [2.0, 1.0, 0.5]])
    return BDerivative(np.eye(3)[:2], F)


def peak_bytes(fn):
    """Peak bytes traced (Python and NumPy allocations) while ``fn()`` runs."""
    tracemalloc.start()
    try:
        fn()
    finally:
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    return peak


def refused_cheaply(fn, match):
    """``fn()`` raises the memory ValueError matching ``match`` and allocates < 1 MiB first."""
    def run():
        with pytest.raises(ValueError, match=match):
            fn()
    assert peak_bytes(run) < 1 << 20


# -- requests -----------------------------------------------------------------------------

def test_piece_matrices_sized_before_the_copy(bd):
    """A broadcast batch of 10**9 rows (no memory of its own) is refused, not copied."""
    V = np.broadcast_to(np.array([-1.0, -2.0, 0.5]), (10**9, 3))
    refused_cheaply(lambda: bd.piece_matrices(V), "the piece matrices of 1000000000 vectors "
                    "in dimension 3 " + MEMORY)
    refused_cheaply(lambda: bd.piece_matrices(V[:1000], memory_limit=1000),
                    MEMORY + " 1000 B")
    # within the limit it works: P[q] = diag(2, 1, 1) for v with v0 event first (closed form:
    # v = (-1, -2, 0.5) reaches event 0 at t = 1, then its rate in x0 doubles)
    P = bd.piece_matrices(V[:3], memory_limit=1 << 20)
    assert_array_equal(P, np.broadcast_to(np.diag([2.0, 1.0, 1.0]), (3, 3, 3)))
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 3\)"):  # the shape first
        bd.piece_matrices(np.broadcast_to(np.ones(4), (10**9, 4)))


def test_event_times_orders_jvp_vjp_sized_before_the_copy(bd):
    """A broadcast batch of 10**10 rows (no memory of its own) is refused by the size of
    what it needs, its float64 copy counted, before it is copied: it was copied first and
    numpy's MemoryError came out (or at 4e8 rows, 9 GiB held for 20 s before the refusal)."""
    V = np.broadcast_to(np.array([-1.0, -2.0, 0.5]), (10**10, 3))
    for call in (bd.event_times, bd.orders):
        refused_cheaply(lambda call=call: call(V), "the event times and orders of 10000000000 "
                        "vectors \\(2 events\\) and the vectors' float64 copy " + MEMORY +
                        r".*: pass fewer vectors at a time")
    refused_cheaply(lambda: bd.jvp(V, V), r"the jvp of 10000000000 vectors \(its result and "
                    r"T's float64 copy\) would " + MEMORY + r".*: pass out=")
    refused_cheaply(lambda: bd.vjp(V, V, out=np.empty((3, 3))),  # out given: T's copy alone
                    r"the vjp of 10000000000 vectors \(W's float64 copy\) would " + MEMORY)
    # a C-contiguous float64 batch is not copied: its size is the results' alone
    times, order = bd.event_times(V[:4].copy())
    assert times.shape == order.shape == (4, 2)
    np.testing.assert_allclose(bd.jvp(V[:4], V[:4]), bd(V[:4]), rtol=1e-15)


def flow_map():
    """A flow map of d = 4 through two groups (3 and 2 events), its stages by hand."""
    from bderiv.analysis.flowmap import FlowBDerivative

    rng = np.random.default_rng(0)
    jumps = []
    for n in (3, 2):
        Dh = np.eye(n, 4) + 0.1 * rng.random((n, 4))
        jumps.append(BDerivative(Dh, 1.0 + 0.3 * rng.random((1 << n, 4))))
    return FlowBDerivative([np.eye(4) + 0.1 * rng.random((4, 4)) for _ in range(3)], jumps)


def test_flow_map_passes_sized_before_the_copy(monkeypatch):
    """The flow map's orders, event_times and apply_orders are sized before the batch is
    converted (a broadcast batch of 10**10 rows: numpy's MemoryError came out), and by
    all the pass holds: the vectors entering each of its three stages and the results
    (the vectors were copied and passed through every stage before any check, and each
    group's own check saw only its part)."""
    from bderiv._support import _validate

    fb = flow_map()
    V = np.broadcast_to(-np.ones(4), (10**10, 4))
    groups = "vectors through 2 event groups \\(5 events: "
    for name in ("orders", "event_times", "apply_orders"):
        refused_cheaply(lambda name=name: getattr(fb, name)(V),
                        f"the {name} of 10000000000 {groups}.* copy\\) would " + MEMORY)
    monkeypatch.setattr(_validate, "memory_headroom", lambda: 2 << 20)  # 2 MiB left
    W = -np.ones((20_000, 4))  # 8 B x 20000 x (3 stages x 4 + 5 or 10 results): 2.6, 3.4 MiB
    for name in ("orders", "event_times", "apply_orders"):
        with pytest.raises(ValueError, match=f"the {name} of 20000 {groups}the vectors "
                                             f"entering each stage and the results\\) would "
                                             f"take [23].\\d MiB, more than the memory limit "
                                             f"of 2.0 MiB: pass fewer vectors at a time"):
            getattr(fb, name)(W)
    W = W[:1000]  # 130 KiB: done
    assert [o.shape for o in fb.orders(W)] == [(1000, 3), (1000, 2)]
    image, orders = fb.apply_orders(W)
    assert_array_equal(image, fb(W))
    assert all(np.array_equal(a, b) for a, b in zip(orders, fb.orders(W), strict=True))


def test_growth_rate_sized_before_its_tables():
    refused_cheaply(lambda: check_growth_memory(10**10, 3, 1000),
                    "the growth rate of 10000000000 directions in dimension 3 over 1000 "
                    "iterations")
    refused_cheaply(lambda: check_growth_memory(10, 3, 10**12), MEMORY)
    # growth_rate checks before its log table: 2 directions, 10**12 iterations
    refused_cheaply(lambda: growth_rate(lambda V: V, np.eye(2), iterations=10**12), MEMORY)
    # the bound: 8 bytes x n_directions x (8 d + iterations)
    check_growth_memory(100, 3, 1000, memory_limit=8 * 100 * (24 + 1000))
    with pytest.raises(ValueError, match="take 800.0 KiB, more than the memory limit of 800"):
        check_growth_memory(100, 3, 1000, memory_limit=8 * 100 * (24 + 1000) - 1)


# -- files ------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def tri(bd):
    return bd.triangulation()


@pytest.mark.parametrize("fmt", ["json", "npz"])
def test_devices_pipes_and_folders_are_refused(tmp_path, fmt):
    refused_cheaply(lambda: load_triangulation("/dev/zero", fmt),
                    "'/dev/zero' must be a regular file, got a device")
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)  # opened without blocking: no writer is waited for
    with pytest.raises(ValueError, match="must be a regular file, got a pipe"):
        load_triangulation(fifo, fmt)
    with pytest.raises(ValueError, match="must be a regular file, got a directory"):
        load_triangulation(tmp_path, fmt)


def sparse(path, size):
    """A file of ``size`` bytes that takes no disk (a hole), or skip where impossible."""
    with open(path, "wb"):
        pass
    try:
        os.truncate(path, size)
    except OSError as exc:
        pytest.skip(f"no sparse file of {size} bytes here: {exc}")
    return path


@pytest.mark.parametrize("fmt", ["json", "npz"])
def test_huge_files_are_refused_before_reading(tmp_path, fmt):
    path = sparse(tmp_path / f"huge.{fmt}", 6 << 30)  # the 6 GiB
    if fmt == "json":
        refused_cheaply(lambda: load_triangulation(path, memory_limit=1 << 30),
                        r"reading triangulation file .* \(6442450944 bytes parsed as JSON: 5 "
                        r"bytes a byte at least\) " + MEMORY)
        # within the limit as a file, not once parsed: refused before it is read too
        refused_cheaply(lambda: load_triangulation(path, memory_limit=12 << 30), MEMORY)
    else:  # an .npz is read by its directory (at the end): a hole is no archive
        with pytest.raises(ValueError, match="cannot be read as .npz"):
            load_triangulation(path)
    path = sparse(tmp_path / "endless.json", 1 << 40)  # 1 TiB: above any machine's memory
    refused_cheaply(lambda: load_triangulation(path), MEMORY)


def test_json_parse_bound_holds_and_is_checked(tmp_path, tri):
    """json_parse_bytes bounds what the parser takes (tracemalloc, an independent count),
    from numbers to a text of empty containers; the bound is what load checks."""
    texts = [json.dumps(tri.to_dict()), "[" + ",".join(["[]"] * 50_000) + "]",
             "[" + ",".join(["{}"] * 50_000) + "]", "[" + ",".join(["0.5"] * 50_000) + "]",
             '{' + ",".join(f'"{i}":1' for i in range(50_000)) + "}",
             '"' + "x" * 200_000 + '"', "[" + ",".join(['"\\ud83d\\ude00"'] * 50_000) + "]",
             "[" + ",".join(["[[[[]]]]"] * 20_000) + "]"]
    for text in texts:
        data = text.encode()
        assert peak_bytes(lambda data=data: json.loads(data)) <= json_parse_bytes(data)
    path = tmp_path / "tri.json"
    tri.save(path)
    need = json_parse_bytes(path.read_bytes())
    assert_array_equal(load_triangulation(path, memory_limit=need).pre, tri.pre)
    with pytest.raises(ValueError, match=r"reading triangulation file .* \(JSON\) " + MEMORY):
        load_triangulation(path, memory_limit=need - 1)


def test_npz_headers_are_checked_against_their_members(tmp_path, tri):
    path = tri.save(tmp_path / "tri.npz")
    with pytest.raises(ValueError, match=r"\(its arrays\) " + MEMORY + " 10 B"):
        load_triangulation(path, memory_limit=10)
    # a header promising 8 GB in a member of a few bytes: refused before numpy allocates
    with np.load(path) as npz:
        members = {k: npz[k] for k in npz.files}
    with zipfile.ZipFile(path, "w") as zf:
        for name, arr in members.items():
            with zf.open(f"{name}.npy", "w") as fh:
                header = np.lib.format.header_data_from_array_1_0(arr)
                if name == "pre":
                    header["shape"] = (10**9, 1)
                np.lib.format.write_array_header_1_0(fh, header)
                fh.write(arr.tobytes())
    refused_cheaply(lambda: load_triangulation(path),
                    r"field 'pre' cannot be read: its header promises 8000000000 bytes")


def test_memory_limit_of_load_is_validated(tmp_path, tri):
    path = tri.save(tmp_path / "tri.json")
    with pytest.raises(TypeError, match="memory_limit must be a number of bytes"):
        load_triangulation(path, memory_limit="1 GB")
    with pytest.raises(ValueError, match="memory_limit must be a positive whole number"):
        load_triangulation(path, memory_limit=-5)
    with pytest.raises(ValueError, match=r"\(\d+ bytes parsed as JSON.*\) " + MEMORY + " 100 B"):
        load_triangulation(path, memory_limit=100)  # the file itself is larger


def test_orbit_stability_sized_before_its_directions(pronking_gait):
    """The issue's ``orbit.stability(n_directions=10**10)`` (224 GiB of directions): refused
    before one is drawn."""
    _, orbit = pronking_gait
    assert orbit.return_map.dim == 4  # built first: its own memory is not the point here
    refused_cheaply(lambda: orbit.stability(n_directions=10**10),
                    "the growth rate of 10000000000 directions in dimension 4 over 1000 "
                    "iterations")


def test_default_memory_limit_read_only_for_tables_above_the_small_size(monkeypatch):
    from bderiv import _limits
    from bderiv._support import _tables

    reads = []

    def none_left():
        reads.append(1)
        return 0  # no memory at all: whatever is measured against it is refused

    monkeypatch.setattr(_tables, "available_memory", none_left)  # memory_headroom reads it
    # n = 2, d = 8: 768 bytes of records, under SMALL_NEED_BYTES: the limit is not read
    assert _tables.dense_table_bytes(2, 8) <= _limits.SMALL_NEED_BYTES
    BDerivative(np.eye(2, 8), np.ones((4, 8)))
    assert reads == []
    # n = 12, d = 8: 1.25 MiB, above it: read, and refused against the 0 bytes left
    n = 12
    assert _tables.dense_table_bytes(n, 8) > _limits.SMALL_NEED_BYTES
    with pytest.raises(ValueError, match="more than the memory limit of 0 B"):
        BDerivative(np.ones((n, 8)), np.ones((1 << n, 8)))
    assert reads == [1]
    # an explicit limit is checked at any size, the default not read
    with pytest.raises(ValueError, match="more than the memory limit of 100 B"):
        BDerivative(np.eye(2, 8), np.ones((4, 8)), memory_limit=100)
    assert reads == [1]


def test_the_default_limit_is_what_the_process_may_take(monkeypatch):
    """Under ``ulimit -v`` the process may take less than the memory available: the
    default limit of every size check is ``memory_headroom`` (available memory and the
    address-space limit), as for a run's records. It was the available memory alone, so
    that under a limit a table, a batch's result or the piece matrices ended in numpy's
    MemoryError. Also the sizes that had no check: a corner model's table and corners,
    a batch's result, and the event times and orders."""
    from bderiv import StructuredCorners
    from bderiv._support import _validate

    monkeypatch.setattr(_validate, "memory_headroom", lambda: 2 << 20)  # 2 MiB left
    n, d = 12, 100
    model = StructuredCorners(np.ones(d), np.zeros((n, d)))
    model.n_events, model.dim = n, d
    Dh = np.zeros((n, d))
    Dh[:, :n] = np.eye(n)
    bd = BDerivative(Dh, model)
    limit = "more than the memory limit of 2.0 MiB"
    with pytest.raises(ValueError, match=rf"the dense table of a corner model \(12 events "
                                         rf"in R\^100: 2\*\*12 rows of 100 float64\) take "
                                         rf"3.1 MiB, {limit}"):
        model.table()
    with pytest.raises(ValueError, match=rf"the corners of 4096 regions in R\^100 .*{limit}"):
        model.corners(np.zeros((4096, n), np.uint8))
    with pytest.raises(ValueError, match=rf"the piece matrices of 30 vectors .*{limit}"):
        bd.piece_matrices(-np.ones((30, d)))
    with pytest.raises(ValueError, match=rf"the result for V \(float64 of shape \(3000, 100\)\) "
                                         rf"would take 2.3 MiB, {limit}: pass out="):
        bd(-np.ones((3000, d)))
    with pytest.raises(ValueError, match=rf"the event times and orders of 11000 vectors .*"
                                         rf"{limit}"):
        bd.event_times(-np.ones((11000, d)))
    out = np.empty((3000, d))  # the result's own room: no limit to it
    np.testing.assert_array_equal(bd(-np.ones((3000, d)), out=out), -np.ones((3000, d)))
