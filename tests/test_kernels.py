"""The kernel core: its on-disk cache is found again by a new process, and long batches are
cut into launches without changing a bit of the result."""

from __future__ import annotations

import json
import subprocess
import sys
from typing import NamedTuple

import numba
import numpy as np
import pytest
from reference import random_system

from bderiv import BDerivative
from bderiv._kernels import _core, _drivers, steps

_PROBE = """
import json, numpy as np
from bderiv import BDerivative
from bderiv._kernels import _core, _drivers, dense, lanes
F = np.array([[1.0, 1.0, 0.5], [2.0, 1.0, 0.0], [1.0, 3.0, 1.0], [2.0, 2.0, 0.0]])
bd = BDerivative(np.array([[1.0, 0.2, 0.0], [0.1, 1.0, 0.3]]), F, fast_paths=False)
V = np.random.default_rng(0).standard_normal((5000, 3))
bd(V[:3]); bd(V)
drivers = dense.apply if _core.PLAIN else bd._engine._lane_kernels[0]
(trampoline, _), = _drivers.TRAMPOLINES.values()
stats = [d.stats for d in (drivers.serial, _drivers._TASKS, _drivers._LAUNCH, trampoline)]
print(json.dumps([[sum(s.cache_hits.values()), sum(s.cache_misses.values())] for s in stats]))
"""


def test_drivers_load_from_the_disk_cache_in_a_new_process():
    runs = []
    for _ in range(2):  # the first run may compile; the second must load what it saved
        out = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True)
        assert out.returncode == 0, out.stderr
        runs.append(json.loads(out.stdout))
    # (hits, misses) of the serial driver, the parallel one, its launcher and trampoline
    assert runs[1] == [[1, 0]] * 4, runs


def _kernel_modules():
    import importlib
    import pkgutil

    import bderiv._kernels as package

    return [importlib.import_module(f"bderiv._kernels.{m.name}")
            for m in pkgutil.iter_modules(package.__path__)]


def test_every_cached_kernel_is_named_by_the_sources_and_checked():
    """Numba watches a cached function's own file only: every kernel of ``_kernels`` that
    is cached carries the digest of all the package's sources in its name (an edit of a
    callee in another file names new cache files), and reads checked files (a damaged
    entry is compiled again). Everything else is compiled uncached, into them."""
    from numba.core.dispatcher import Dispatcher

    from bderiv._kernels._cache import hardened

    found = []
    for module in _kernel_modules():
        for value in vars(module).values():
            if isinstance(value, _drivers.Batch):
                value = value.serial
            if not isinstance(value, Dispatcher) or value.stats.cache_path is None:
                continue
            found.append(value.py_func.__qualname__)
            assert value.py_func.__qualname__.endswith(f".k{_core.SOURCES}"), found[-1]
            assert hardened(value), found[-1]
    assert len(found) >= 10, found  # the drivers and the kernels called from Python


def test_the_sources_digest_follows_every_file(tmp_path):
    from bderiv._kernels._cache import KEY_DIGITS, sources_digest

    (tmp_path / "a.py").write_text("x = 1\n")
    (tmp_path / "b.py").write_text("y = 2\n")
    first = sources_digest(tmp_path)
    assert len(first) == KEY_DIGITS and first == sources_digest(tmp_path)
    (tmp_path / "b.py").write_text("y = 3\n")
    assert sources_digest(tmp_path) != first
    (tmp_path / "b.py").write_text("y = 2\n")
    (tmp_path / "c.py").write_text("")
    assert sources_digest(tmp_path) != first  # a new file counts too


def test_the_kernels_digest_covers_the_numbers_compiled_in(tmp_path):
    """The kernels compile values of ``bderiv._numerics`` in (``QUERY_BAND``,
    ``TASK_QUERIES``): its file is part of the digest that names their cache files."""
    import pathlib

    from bderiv import _numerics
    from bderiv._kernels._cache import sources_digest

    folder = pathlib.Path(_core.__file__).parent
    assert _core.SOURCES == sources_digest(folder, _numerics.__file__) != sources_digest(folder)
    (tmp_path / "a.py").write_text("x = 1\n")
    numbers = tmp_path / "numbers.py"
    numbers.write_text("BAND = 256\n")
    first = sources_digest(tmp_path / "none", numbers)
    numbers.write_text("BAND = 128\n")
    assert sources_digest(tmp_path / "none", numbers) != first


def test_launches_do_not_change_the_result(monkeypatch):
    rng = np.random.default_rng(5)
    Dh, F = random_system(rng, 5, 6)
    bd = BDerivative(Dh, F)
    V = rng.standard_normal((5000, 6))
    whole = bd(V)
    assert bd.inverse(whole).shape == V.shape
    monkeypatch.setattr(_core, "launch_queries", lambda n, d: 1024)  # 5 launches, one short
    cut = BDerivative(Dh, F)
    np.testing.assert_array_equal(cut(V), whole)
    times, order = bd.event_times(V)
    t2, o2 = cut.event_times(V)
    np.testing.assert_array_equal(t2, times)
    np.testing.assert_array_equal(o2, order)


def test_one_parallel_driver_serves_every_block_and_matches_the_serial_one():
    """The parallel driver calls each block's serial driver through its address: two
    systems whose apply kernels differ (h in 8 lanes and in 16) share it, its launcher and
    its trampoline (their tables and outputs have one type), and each gives the bits of
    its serial driver. The parallel driver has one signature, whatever the types. (d = 16:
    the width pairs 8 x 16 and 16 x 16, which test_lanes compiles too.)"""
    rng = np.random.default_rng(11)
    V = rng.standard_normal((3000, 16))
    batches = []
    for n in (3, 12):
        bd = BDerivative(*random_system(rng, n, 16), fast_paths=False)
        whole = bd(V)  # the parallel driver (3000 rows)
        rows = np.concatenate([bd(V[i:i + 500]) for i in range(0, 3000, 500)])  # serial
        np.testing.assert_array_equal(whole, rows)
        batches.append(bd._engine._lane_kernels[0] if not _core.PLAIN else None)
    assert _drivers._TASKS.signatures == [_drivers._TASKS_ARGS]
    if not _core.PLAIN:
        a, b = batches
        assert a.serial is not b.serial  # two blocks ...
        (kinds, (_, trampoline)), = a._addresses.items()  # ... of one type: one trampoline
        assert b._addresses[kinds][1] == trampoline
        assert [address for _, address in _drivers.TRAMPOLINES.values()].count(trampoline) == 1


class _Named(NamedTuple):
    a: np.ndarray
    name: str


@numba.njit
def _copy_block(tables, V, outs, start, stop, inverse):
    for q in range(start, stop):
        outs[0][q, 0] = V[q, 0] + tables.a[0]


def test_tables_the_threads_cannot_share_are_refused_by_name():
    """The parallel driver hands its threads arrays, numbers and tuples of them (without
    an owner): tables holding anything else are refused before anything compiles for
    them, naming the block, where the serial driver runs them."""
    copy = _drivers.batch(_copy_block)
    tables, out = _Named(np.ones(1), "x"), np.empty((5000, 1))
    assert copy(tables, np.zeros((10, 1)), (out[:10],)) == 0  # serial: fine
    with pytest.raises(TypeError, match="_copy_block: .* got a unicode_type"):
        copy(tables, np.zeros((5000, 1)), (out,))


def test_launch_sizes():
    assert _core.launch_queries(8, 8) == 1 << 18
    assert _core.launch_queries(128, 128) == 1 << 14  # floor
    assert _core.launch_queries(1, 1) == 1 << 20  # ceiling


@pytest.mark.parametrize("n", [0, 1, 2, 23, 24, 25, 40, 47, 48, 49, 97, 128, 1000])
def test_the_orders_are_numpys_stable_argsort(n):
    """The own-rates fast paths' orders: insertion sort (dense tables, n <= 40, and any
    table up to 24 events), merged insertion runs above (oracle: NumPy's stable
    argsort), with ties broken by the smaller event."""
    rng = np.random.default_rng(n)
    order = np.empty(n, dtype=np.int64)
    sorts = [steps.merge_order] + ([steps.insertion_order] if n <= 40 else [])
    for t in (rng.standard_normal(n), rng.integers(0, max(n // 4, 1), n).astype(float),
              np.zeros(n), np.arange(n, 0, -1.0)):
        for sort in sorts:
            sort(t, order)
            np.testing.assert_array_equal(order, np.argsort(t, kind="stable"))


@pytest.mark.parametrize("n", [1, 2, 3, 6])
def test_the_rate_spread_of_small_tables_is_the_kernels(n):
    """A table of one block gets its rate spread from NumPy, larger ones from the kernel:
    both the spread of a plain scan (the first slowest and fastest pending region of each
    event, the first event of the largest ratio), ties and the rates of events that
    happened (negative with resets: never read) included."""
    from bderiv._kernels.dense import widest_rate_spread
    from bderiv.engine._engines.dense import rate_spread

    rng = np.random.default_rng(n)
    for G in (rng.uniform(0.5, 2.0, (2**n, n)), rng.integers(1, 4, (2**n, n)).astype(float)):
        masks = np.arange(2**n)
        G[(masks[:, None] >> np.arange(n)) & 1 == 1] *= -1.0
        best = (0.0, 0, 0, 0)
        for k in range(n):
            rows = [B for B in range(2**n) if not (B >> k) & 1]
            slow = min(rows, key=lambda B: (G[B, k], B))
            fast = min(rows, key=lambda B: (-G[B, k], B))
            if G[fast, k] / G[slow, k] > best[0]:
                best = (G[fast, k] / G[slow, k], k, slow, fast)
        assert rate_spread(G, n) == best
        # a slice of the region records, as the engine passes it (one compilation)
        records = np.hstack([G, np.zeros((2**n, 1))])
        assert tuple(widest_rate_spread(records[:, :n])) == best


#: the tests of the plain kernels' files that reach another engine (corner functions,
#: structured models, simulations of the flow), left out of the default run's subprocess
NOT_DENSE = ("not function and not structured and not terminal_cost and not flow_jvp")


@pytest.mark.parametrize("select", [
    pytest.param(["-k", NOT_DENSE], id="dense-engine-tests"),
    pytest.param([], id="whole-files", marks=pytest.mark.slow)])
def test_the_plain_kernels_pass_the_same_tests(select):
    """``BDERIV_KERNELS=plain`` (the scalar kernels any numba target compiles) runs the dense
    tests against the oracle in a subprocess, so both paths are tested on every run: by
    default the tests of the three files that reach the dense engine (those of the other
    engines run the same kernels as in this process), with ``-m slow`` the whole files."""
    import os

    tests = os.path.dirname(os.path.abspath(__file__))
    env = dict(os.environ, BDERIV_KERNELS="plain")
    out = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider", "-n", "0",
         *select, os.path.join(tests, "test_bderivative.py"),
         os.path.join(tests, "test_adjoints.py"), os.path.join(tests, "test_fuzz.py")],
        capture_output=True, text=True, env=env, cwd=os.path.dirname(tests))
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    probe = subprocess.run([sys.executable, "-c", "from bderiv._kernels import _core; "
                            "print(_core.PLAIN)"], capture_output=True, text=True, env=env)
    assert probe.stdout.strip() == "True"


@pytest.mark.slow
def test_the_lane_kernels_compile_for_a_generic_target(tmp_path):
    """The explicit vectors of the lane kernels (dense and structured) are legal on any
    LLVM target (LLVM splits them): compiled for a generic CPU (on x86-64: SSE2 only, no
    AVX, no FMA unit) into a fresh cache, they pass their tests against the oracle.

    Slow (about 200 s on 2 cores since the kernels scale their queries): run with
    ``pytest -m slow`` after a change to the kernels."""
    import os

    tests = os.path.dirname(os.path.abspath(__file__))
    env = dict(os.environ, NUMBA_CPU_NAME="generic", NUMBA_CACHE_DIR=str(tmp_path))
    env.pop("BDERIV_KERNELS", None)
    out = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider", "-n", "0",
         os.path.join(tests, "test_lanes.py"), os.path.join(tests, "test_structured_lanes.py")],
        capture_output=True, text=True, env=env, cwd=os.path.dirname(tests))
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    assert "passed" in out.stdout and "skipped" not in out.stdout, out.stdout[-500:]
