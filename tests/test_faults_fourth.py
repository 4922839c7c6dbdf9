"""Faults, fourth round (issue 27 items 9-12): every cache file bderiv loads is checked or
named when damaged, ``export --format both`` is one unit, a garbled ``.npz`` header is the
documented error, a killed save's temporary is removed by the next save, and Dask sends a
map once per client."""

from __future__ import annotations

import importlib
import logging
import os
import pathlib
import re
import subprocess
import sys
import textwrap

import numpy as np
import pytest

# -- 9: damaged cache files: compiled again, or named -----------------------------------------


def run_python(code, cache=None, timeout=600):
    """``code`` in a fresh interpreter (``NUMBA_CACHE_DIR=cache`` if given); its result."""
    env = dict(os.environ, **({} if cache is None else {"NUMBA_CACHE_DIR": str(cache)}))
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True,
                          text=True, env=env, timeout=timeout)


def flip_middle_bytes(files):
    """Flip one bit in the middle of each of ``files``."""
    for path in files:
        data = bytearray(path.read_bytes())
        data[len(data) // 2] ^= 0x10
        path.write_bytes(bytes(data))


_EAGER_MODULE = """
from numba import types
from bderiv.models.compiled._cached import eager


@eager(types.float64[::1](types.float64[::1]))
def double(x):
    return 2.0 * x
"""

_EAGER_PROBE = """
import sys
import numpy as np
sys.path.insert(0, {folder!r})
import eagermod
print(eagermod.double(np.arange(3.0)).tolist(), eagermod.double.stats.cache_path)
"""


def test_damaged_cache_of_an_eager_kernel_is_compiled_again(tmp_path):
    """The kernels compiled at import (``models/compiled/_cached.eager``) read numba's plain
    ``.nbc`` files: a flipped bit in their machine code aborted every later ``import
    bderiv`` (SIGABRT, SIGSEGV, SIGILL). Now, a kernel made by ``eager`` in a fresh
    process (bderiv's own kernels loaded from the warm cache, this one's cached beside
    it) with a bit flipped in its index and in its data file: the process lives,
    computes, names the folder and rewrites the entry."""
    (tmp_path / "eagermod.py").write_text(_EAGER_MODULE)
    probe = _EAGER_PROBE.format(folder=str(tmp_path))
    out = run_python(probe)
    assert out.returncode == 0, out.stderr[-2000:]
    result, folder = out.stdout.rsplit(maxsplit=1)
    assert result == "[0.0, 2.0, 4.0]"
    files = sorted(p for p in pathlib.Path(folder).iterdir() if "eagermod.double" in p.name)
    assert len(files) == 2  # an index and a data file
    flip_middle_bytes(files)  # its index and data file (.bdi, .bdc; numba's .nbi, .nbc)
    damaged = [path.read_bytes() for path in files]
    out = run_python(probe)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.rsplit(maxsplit=1)[0] == "[0.0, 2.0, 4.0]"
    assert f"the compiled-kernel cache in {folder} is damaged" in out.stderr
    assert "Traceback" not in out.stderr
    assert damaged != [path.read_bytes() for path in files]  # written again


_USER_MODULE = """
import numba
import numpy as np


@numba.njit(cache=True)
def field(x, mask):
    out = np.empty_like(x)
    out[0] = 1.0 + 0.0 * x[0]
    out[1] = -1.0 if mask & 1 else 0.5
    return out


@numba.njit(cache=True)
def events(x):
    return np.array([x[0] - 1.0])
"""


def import_fresh(folder, name):
    """Import ``folder/name.py`` anew (new dispatchers: numba reads its cache again)."""
    sys.modules.pop(name, None)
    sys.path.insert(0, str(folder))
    try:
        return importlib.import_module(name)
    finally:
        sys.path.remove(str(folder))
        sys.modules.pop(name, None)


def test_an_entry_whose_data_file_another_save_took_is_a_miss(tmp_path, caplog):
    """Two processes saving two keys of one kernel at once both take the first free data
    file name; the index written last can name the data file the other wrote. That entry
    is a miss (compiled again, then saved right), never the other key's code: a float
    signature ran an int one's machine code, and another CPU's code could run too."""
    from numba.core.caching import IndexDataCacheFile

    from bderiv._kernels._cache import CheckedCacheFile

    caplog.set_level(logging.WARNING, logger="bderiv")
    plain = IndexDataCacheFile(str(tmp_path), "probe-1.py311", ("stamp", 1))
    cache = CheckedCacheFile(plain, "probe", parallel=False)
    ints, floats = (("int64",), "cpu-a", "code"), (("float64",), "cpu-a", "code")
    cache.save(ints, "the int64 entry")
    assert cache.load(ints) == "the int64 entry"
    # the race's outcome: the other process's index, naming this one's data file
    cache._save_index({floats: cache._data_name(1)})
    assert cache.load(floats) is None
    assert cache.load(ints) is None  # not in that index: compiled again too
    cache.save(floats, "the float64 entry")
    cache.save(ints, "the int64 entry")
    assert cache.load(floats) == "the float64 entry"
    assert cache.load(ints) == "the int64 entry"
    # a data file without its key (an earlier bderiv's, beside a current index): a miss
    cache._save_data(cache._data_name(1), ("a", "tuple", "of", "numba's"))  # floats' file
    assert cache.load(floats) is None
    assert cache.load(ints) == "the int64 entry"
    # an earlier source's entry under the same key (read between a save's index and data)
    cache._save_data(cache._data_name(2), (("stamp", 0), ints, "an earlier source's"))
    assert cache.load(ints) is None
    assert caplog.records == []  # not taken for damage


def test_numba_debug_cache_shows_the_checked_files(tmp_path, capsys, monkeypatch):
    """``NUMBA_DEBUG_CACHE=1`` shows where each kernel's cache is read and written; the
    package's kernels printed nothing (their checked file replaces the methods of numba's
    that print), so a user checking that a process loads rather than compiles saw no
    line for them."""
    import numba
    from numba.core.caching import IndexDataCacheFile

    from bderiv._kernels._cache import CheckedCacheFile

    cache = CheckedCacheFile(IndexDataCacheFile(str(tmp_path), "probe-1.py311", ("s", 1)),
                             "probe", parallel=False)
    key = (("float64",), "cpu-a", "code")
    monkeypatch.setattr(numba.core.config, "DEBUG_CACHE", 0)
    cache.save(key, "an entry")
    assert capsys.readouterr().out == ""
    monkeypatch.setattr(numba.core.config, "DEBUG_CACHE", 1)
    cache.save(key, "an entry")
    assert cache.load(key) == "an entry"
    index, data = str(tmp_path / "probe-1.py311.bdi"), str(tmp_path / "probe-1.py311.1.bdc")
    assert capsys.readouterr().out.splitlines() == [
        f"[cache] index loaded from {index!r}", f"[cache] data saved to {data!r}",
        f"[cache] index loaded from {index!r}", f"[cache] data loaded from {data!r}"]


def test_numba_disable_jit_is_refused_by_name():
    """``NUMBA_DISABLE_JIT=1`` makes ``njit`` return plain functions: bderiv's kernels and
    compiled integrator cannot run, and said so by an AttributeError on a dispatcher."""
    out = subprocess.run([sys.executable, "-c", "import bderiv; bderiv.examples.chair()"],
                         capture_output=True, text=True, timeout=300,
                         env=dict(os.environ, NUMBA_DISABLE_JIT="1"))
    assert out.returncode != 0
    assert "ImportError: bderiv needs numba's compiler, and NUMBA_DISABLE_JIT is set" in \
        out.stderr, out.stderr[-2000:]
    assert "undecorated" in out.stderr


def test_damaged_cache_of_a_users_function_is_named(tmp_path):
    """A user's ``cache=True`` field whose numba cache is truncated: every later process
    raised ``UnpicklingError`` (or "field was compiled for [] only") from the first
    compilation, naming nothing. Now a RuntimeError names the function, the folder and
    the files, on both integrators' first use of it, and deleting those files (as it
    says) is enough."""
    from bderiv import HybridSystem

    name = f"usermodel_{tmp_path.name.replace('-', '_')}"
    (tmp_path / f"{name}.py").write_text(_USER_MODULE)
    mod = import_fresh(tmp_path, name)
    system = HybridSystem(mod.field, mod.events, n_events=1, dim=2)
    system.compiled.describe()
    assert system.calls.eval_field(np.array([0.5, 0.0]), 1)[1] == -1.0
    folder = pathlib.Path(mod.field.stats.cache_path)
    data = sorted(folder.glob(f"{name}.field-*.nbc"))
    index, = folder.glob(f"{name}.field-*.nbi")
    assert data
    for path in data:
        path.write_bytes(path.read_bytes()[:40])  # truncated
    expected = (re.escape("field (field): its numba disk cache (cache=True) cannot be "
                          "loaded (UnpicklingError: ") + ".*"
                + re.escape(f"): its files in {folder} ({index.name} and ") + ".*"
                + re.escape(") are damaged; delete them"))
    mod = import_fresh(tmp_path, name)
    system = HybridSystem(mod.field, mod.events, n_events=1, dim=2)
    with pytest.raises(RuntimeError, match=expected):
        system.compiled  # noqa: B018 - the compiled path's first use of the field
    with pytest.raises(RuntimeError, match=expected):
        system.calls.eval_field(np.array([0.5, 0.0]), 1)  # the Python path's
    for path in [index, *data]:
        path.unlink()
    mod = import_fresh(tmp_path, name)
    system = HybridSystem(mod.field, mod.events, n_events=1, dim=2)
    system.compiled.describe()
    assert system.calls.eval_field(np.array([0.5, 0.0]), 1)[1] == -1.0


def test_damaged_symbolic_module_is_refused(tmp_path, caplog):
    """A generated model module with one changed digit still parses and computes another
    model; its digest line now refuses it (removed, warned, generated again), and a file
    without the line is generated again too."""
    from bderiv.symbolic import _cache

    path = _cache.module_path(_cache.cache_folder(tmp_path), "k")
    _cache.store(path, "VALUE = 0.25\n")
    assert path.read_text().splitlines()[1:] == ["VALUE = 0.25"]
    assert _cache.read(path) == "VALUE = 0.25\n"
    path.write_bytes(path.read_bytes().replace(b"0.25", b"0.35"))
    with caplog.at_level("WARNING", logger="bderiv"):
        assert _cache.read(path) is None
    assert f"the generated model module {path} is damaged" in caplog.text
    assert not path.exists()
    path.write_text("VALUE = 0.25\n")  # no digest line (an older bderiv's file)
    assert _cache.read(path) is None and not path.exists()


@pytest.mark.slow
def test_damaged_symbolic_module_is_generated_again(tmp_path):
    """End to end: a digit of a cached model's module changed (and its time moved, so that
    Python and numba read it again) in a fresh process: the field is still the model's."""
    code = f"""
        import sympy as sp, numpy as np
        from bderiv.symbolic import ModelFunctions, from_sympy
        x, v, s = sp.symbols("x v s")
        m = from_sympy([x, v], [s], [v, -0.75 * x + 2.5 * s], [x - 0.5],
                       cache_dir={str(tmp_path)!r})
        print(m.source.build.cached, ModelFunctions(m).field(np.array([2.0, 0.0]), 1)[1])
    """
    out = run_python(code, tmp_path / "numba")
    assert out.stdout.split() == ["False", "1.0"], out.stderr[-2000:]  # -0.75 * 2 + 2.5
    path, = (tmp_path / "symbolic").glob("m_*.py")
    text = path.read_text()
    assert text.count("- 0.75*x_0") == 1  # the field's
    path.write_text(text.replace("- 0.75*x_0", "- 0.25*x_0"))
    os.utime(path, (path.stat().st_atime + 10, path.stat().st_mtime + 10))
    out = run_python(code, tmp_path / "numba")
    assert out.stdout.split() == ["False", "1.0"], out.stdout + out.stderr[-2000:]
    assert "is damaged" in out.stderr


# -- 10: export --format both: a kill between the two renames ----------------------------------

class Killed(BaseException):
    """The process killed at this point (nothing after it runs; not an Exception)."""


def rename_then_die(monkeypatch, renames=1):
    """``os.replace`` that does ``renames`` renames, then 'kills' the process."""
    real, done = os.replace, []

    def replace(src, dst):
        if len(done) == renames:
            raise Killed
        done.append(dst)
        real(src, dst)

    monkeypatch.setattr(os, "replace", replace)
    return done


@pytest.mark.parametrize("earlier", ["export", "single saves"])
def test_export_killed_between_its_renames(tmp_path, monkeypatch, earlier):
    """``bderiv export --format both`` killed after its first rename: the new .npz sits
    beside the earlier .json. The .npz is refused (naming both files), the earlier .json
    loads the earlier map; the next export makes a pair that loads."""
    from bderiv import load_triangulation
    from bderiv.cli.export import run_export

    base = tmp_path / "tri"
    npz, js = f"{base}.npz", f"{base}.json"
    if earlier == "export":
        run_export("corners", out=str(base), fmt="both")
    else:
        from bderiv.cli.systems import load_example

        tri = load_example("corners", None, False)[1].triangulation()
        tri.save(npz)
        tri.save(js)
    before = load_triangulation(js)
    assert_same(load_triangulation(npz), before)
    with monkeypatch.context() as m:
        done = rename_then_die(m)
        with pytest.raises(Killed):
            run_export("planar", out=str(base), fmt="both")
    assert done == [npz]  # the .npz renamed, the .json not
    assert sorted(os.listdir(tmp_path)) == ["tri.json", "tri.npz"]
    holds = "the token" if earlier == "export" else "no pair token"
    with pytest.raises(ValueError, match=f"{re.escape(repr(npz))} was exported together with "
                                         f"{re.escape(repr(js))} .* holds {holds}"):
        load_triangulation(npz)
    assert_same(load_triangulation(js), before)  # the earlier export, whole
    run_export("planar", out=str(base), fmt="both")
    after = load_triangulation(npz)
    assert_same(load_triangulation(js), after)
    assert not np.array_equal(after.pre, before.pre)


def assert_same(a, b):
    for name in ("pre", "post", "simplices", "kernel", "kernel_post"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


# -- 11: a garbled .npy header, a killed save's temporary --------------------------------------

def garble_header(path, member):
    """Rewrite the .npz at ``path`` with the ``}`` closing ``member``'s .npy header made a
    space: ast cannot parse it, and numpy's Python-2 fallback tokenizes it (TokenError)."""
    import zipfile

    with zipfile.ZipFile(path) as zf:
        members = {info.filename: zf.read(info) for info in zf.infolist()}
    data = bytearray(members[f"{member}.npy"])
    assert data[6:8] == b"\x01\x00"  # format 1.0: a 2-byte header length at 8
    end = 10 + int.from_bytes(data[8:10], "little")
    close = data.rindex(b"}", 10, end)
    data[close] = ord(" ")
    members[f"{member}.npy"] = bytes(data)
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, content in members.items():
            zf.writestr(name, content)


@pytest.mark.parametrize("member", ["meta", "pre", "simplices"])
def test_npz_header_that_does_not_parse_is_the_documented_error(tmp_path, member):
    """A .npy header without its closing brace: numpy's header parser raised
    tokenize.TokenError (before any CRC is checked); now the ValueError naming the file
    and the member."""
    import tokenize

    from bderiv import BDerivative, load_triangulation

    F = np.array([[1.0, 1.0], [2.0, 1.0], [1.0, 1.0], [2.0, 1.0]])
    path = BDerivative(np.eye(2), F).triangulation().save(tmp_path / "tri.npz")
    garble_header(path, member)
    with pytest.raises(tokenize.TokenError):  # what numpy itself raises on it
        np.load(path)[member]
    with pytest.raises(ValueError, match=f"{re.escape(repr(path))}: field {member!r} cannot "
                                         f"be read"):
        load_triangulation(path)


_KILLED_SAVE = """
import os, signal
from bderiv._support._safefiles import write_all

def dying(fh):
    fh.write(b"half a file")
    fh.flush()
    os.kill(os.getpid(), signal.SIGKILL)

print(os.getpid(), flush=True)
write_all({{{path!r}: (True, dying)}})
"""


def test_next_save_removes_a_killed_saves_temporary_only(tmp_path):
    """A save killed midway leaves its hidden temporary; the next save of the same target
    removes it, and only stale temporaries of that target: not a live writer's (this
    process's), not another target's, not another host's younger than a day."""
    import signal
    import socket

    from bderiv import BDerivative, load_triangulation
    from bderiv._support._safefiles import create_temp

    path = str(tmp_path / "tri.npz")
    out = run_python(_KILLED_SAVE.format(path=path))
    assert out.returncode == -signal.SIGKILL, out.stderr[-2000:]
    dead = int(out.stdout.split()[0])
    left, = os.listdir(tmp_path)
    assert left.startswith(".tri.npz.") and left.endswith(".tmp")
    host = re.sub(r"[^A-Za-z0-9-]", "-", socket.gethostname())[:40]
    live, fd = create_temp(path)  # a concurrent writer in this process
    os.close(fd)
    keep = [os.path.basename(live),
            f".tri.json.{dead}-{host}.0123456789abcdef.tmp",  # another target's
            f".tri.npz.bak.{dead}-{host}.0123456789abcdef.tmp",  # another target's
            f".tri.npz.{dead}-otherhost.0123456789abcdef.tmp"]  # another host's, young
    old = [f".tri.npz.{dead}-otherhost.fedcba9876543210.tmp",  # another host's, 2 days
           ".tri.npz.00112233445566aa.tmp"]  # an earlier bderiv's name, 2 days old
    for name in keep[1:] + old:
        (tmp_path / name).write_bytes(b"")
    for name in old:
        os.utime(tmp_path / name, (os.path.getmtime(tmp_path / name) - 2 * 86400,) * 2)
    F = np.array([[1.0, 1.0], [2.0, 1.0], [1.0, 1.0], [2.0, 1.0]])
    tri = BDerivative(np.eye(2), F).triangulation()
    tri.save(path)
    assert sorted(os.listdir(tmp_path)) == sorted(["tri.npz", *keep])
    assert_same(load_triangulation(path), tri)


# -- 12: Dask: the map sent once per client -----------------------------------------------------

class CountedMap:
    """A map (``apply``, ``inverse``) counting how often it is pickled; ``payload`` sets its
    size (a stand-in for a large map's tables)."""

    pickles = 0

    def __init__(self, payload):
        self.payload = np.ones(payload) if np.isscalar(payload) else payload

    def apply(self, V):
        return 2.0 * V

    def inverse(self, W):
        return 0.5 * W

    def __reduce__(self):
        type(self).pickles += 1
        return (type(self), (self.payload,))


def test_dask_sends_the_map_once_per_client():
    """On a distributed client, the graph refers to the map scattered once: its pickled
    size does not grow with the map (it grew by the whole map, every compute sent it
    again: 576 MiB at n = d = 20), and three computes of three graphs (apply, inverse)
    pickle the map at most once, not twice per compute."""
    distributed = pytest.importorskip("distributed")
    da = pytest.importorskip("dask.array")
    import pickle

    from bderiv._support._dask import map_blocks

    X = np.random.default_rng(1).standard_normal((400, 3))
    V = da.from_array(X, chunks=(100, 3))
    with (distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                   dashboard_address=None,
            scheduler_kwargs={"dashboard_address": ":0"}) as cluster,
          distributed.Client(cluster)):
        small, large = CountedMap(10), CountedMap(200_000)  # 1.6 MB of payload
        sizes = [len(pickle.dumps(dict(map_blocks(m.apply, V, 3).__dask_graph__())))
                 for m in (small, large)]
        assert abs(sizes[1] - sizes[0]) < 1000, sizes
        CountedMap.pickles = 0
        for _ in range(3):
            lazy = map_blocks(large.apply, V, 3)
            np.testing.assert_array_equal(lazy.compute(), 2.0 * X)
            back = map_blocks(large.inverse, lazy, 3)
            np.testing.assert_array_equal(back.compute(), X)
        assert CountedMap.pickles <= 1
