"""Shared test set-up: hypothesis settings, a session fixture that warms the JIT, and the
session fixtures of objects that take seconds to make (each made once per process).

Rules for new tests (docs/setup.md, "The tests"): a case that takes more than a few seconds
on a warm cache is marked ``slow`` and keeps a smaller case of the same check in the default
run; an object that takes seconds and several files need is a session fixture here, never a
module-level computation (collection runs in every pytest-xdist worker); a nested pytest
run passes ``-n 0``; timings live in benchmarks/ and run with ``-n 0``; a test that looks for
objects with ``gc.get_objects()`` thaws them first (``gc.unfreeze()``: each file's end
freezes what is alive, see :func:`pytest_runtest_protocol`).

The default run (README's ``python -m pytest``, CI) and ``python -m pytest -m slow``.
On a fresh numba cache most of the default run is compilation (about 85 % of the CPU of
the kernel files), so what is left out is what compiles kernels no other test needs, or
repeats a check at a size that only costs time; each keeps a smaller case in the run:

- the plain kernels (``BDERIV_KERNELS=plain``) on the whole files test_bderivative,
  test_adjoints and test_fuzz; by default on their dense-engine tests (test_kernels);
- the lane kernels compiled for a generic CPU (test_kernels); the native ones are tested
  by test_lanes and test_structured_lanes;
- the lane width 16 x 16 (test_lanes); h in 16 lanes and x in 16 lanes stay, apart;
- the benchmark smoke cases from n = 12 and batches of 10**6 (benchmarks/); n <= 8 stay;
- the fuzz run of 10**6 evaluations (test_fuzz, tools/fuzz.py); the fast run stays;
- more examples against finite differences and network(20) (test_examples), the
  quadruped (test_contacts), the pronking map on a local Dask cluster of processes
  (test_stability_map), jax's vmap at m = 1000: the chair, the table and smaller
  networks, the pronking gaits, the map through a threaded in-process cluster and
  m = 100 stay;
- the n = 20 build timing (benchmarks/test_bench_dense.py), a timing: its memory check
  stays.

CI runs the default run only (the slow set holds a timing that fails on a loaded machine
and a compile of every lane kernel for another CPU); ``-m slow`` is for a change of the
kernels or before a release (docs/setup.md, "The tests").
"""

from __future__ import annotations

import atexit
import contextlib
import gc
import getpass
import logging
import os
import tempfile

import numpy as np
import pytest
from hypothesis import HealthCheck, settings

from bderiv.cli.warmup import rarer_full_collections

try:
    import fcntl
except ImportError:  # Windows: the workers may then compile a task twice at once
    fcntl = None

# deadline=None: the first call of each njit kernel compiles (seconds); the warm-up fixture
# below takes most of that out of the examples, but the cache can still be cold on CI.
# max_examples keeps the whole suite within a few minutes on two cores.
settings.register_profile(
    "bderiv",
    deadline=None,
    max_examples=60,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.register_profile("thorough", parent=settings.get_profile("bderiv"), max_examples=500)
settings.load_profile("bderiv")

# numba's compiler keeps a large graph of objects alive, and every full collection walks all
# of it: test_lanes and test_adjoints on an empty cache spent 13.2 s of CPU in 55 full
# collections; with full collections as rare as in bderiv's own compiling processes,
# 4.4 s in 9 (docs/design.md, "The collector")
rarer_full_collections()


def pytest_configure(config):
    # the generated modules of symbolic models go to a temporary folder of the test runs
    # (kept between runs, so that they are not derived and compiled again each time), not
    # to the user's cache; a BDERIV_CACHE_DIR set by the caller is kept
    os.environ.setdefault("BDERIV_CACHE_DIR", os.path.join(
        tempfile.gettempdir(), f"bderiv-tests-{getpass.getuser()}"))
    # two pytest-xdist workers share two cores: after each parallel launch OpenMP's threads
    # (numba's parallel driver) would spin for milliseconds on the core the other worker
    # needs; passive, they sleep at once (the same results: only the waiting differs)
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    # the tests of compiled models run on the compiled integrator from their first call
    # (waiting for its compilation, once for all workers); test_readiness tests the rest
    os.environ.setdefault("BDERIV_INTEGRATOR", "compiled")
    # the notices of first compilations (bderiv._support._compiling) depend on which test runs
    # first on a fresh cache: kept out of the tests' logs (test_compiling turns them on)
    logging.getLogger("bderiv.compiling").setLevel(logging.ERROR)
    # pytest collects garbage five times at its end, to report exceptions raised in the
    # finalizers of what the session leaves (_pytest.unraisableexception): each walks a
    # worker's million objects (4.8 s at the end of the last worker, the other core idle).
    # Once finds what the session left (the fixtures torn down, even after -x); the four
    # more find only garbage that a finalizer makes in a cycle (a stash key meant to be
    # set; another pytest without it collects its own number of times)
    try:
        from _pytest.unraisableexception import gc_collect_iterations_key
    except ImportError:  # pragma: no cover - another pytest
        pass
    else:
        config.stash[gc_collect_iterations_key] = 1
    if not hasattr(config, "workerinput"):  # the main process: the integrator compiles
        from bderiv.models import readiness  # meanwhile, while the workers start

        if not readiness.integrator_cached():
            readiness.start_background(nice=False)
    # pyproject turns warnings into errors; hypothesis' pytest plugin imports
    # mypy_extensions.TypedDict at report time on some installs, a DeprecationWarning that is
    # not ours and would abort the run with an INTERNALERROR
    config.addinivalue_line(
        "filterwarnings", "ignore:mypy_extensions.TypedDict is deprecated:DeprecationWarning"
    )


def _warm_ups():
    """The kernel families nearly every test file runs, one task per family, on a tiny
    system (one size class of the lane kernels): each task runs a small batch (the serial
    driver) and a large one (the parallel driver), so that the two drivers are compiled in
    one process, where the family's block is compiled once for both."""
    from bderiv import BDerivative

    Dh = np.array([[1.0, 0.2, 0.0], [0.1, 1.0, 0.3]])
    F = np.array([[1.0, 1.0, 0.5], [2.0, 1.0, 0.0], [1.0, 3.0, 1.0], [2.0, 2.0, 0.0]])
    bd = BDerivative(Dh, F)
    rng = np.random.default_rng(0)
    small, large = rng.standard_normal((3, 3)), rng.standard_normal((5000, 3))
    # ordered for two workers (the tasks 0, 2 and 1, 3): about 11 and 15 s on a cold cache;
    # then the stop rules. Not the compiled integrator: it compiles in the main process's
    # background process meanwhile (a minute or more on a cold cache), and a worker that
    # waited for it here would leave its core idle; a test that needs it waits for it, and
    # the files that do not run first (pytest_collection_modifyitems)
    return [
        lambda: (bd(small), bd(large), bd.inverse(small), bd.inverse(large)),
        lambda: (bd.event_times(small), bd.event_times(large)),
        lambda: (bd.triangulation()(small), list(bd.pieces())),
        lambda: (bd.jvp(small, small), bd.vjp(small, small), bd.jvp(large, large),
                 bd.vjp(large, large)),
        _python_model_run,
    ]


def _python_model_run():
    """A Python model's run and flow map (scipy's integrator): the stop rules, which both
    integrators call."""
    from bderiv import HybridSystem

    def field(x, mask):
        return np.array([1.0, 0.5 + 0.5 * mask])

    def events(x):
        return np.array([x[0] - 1.0])

    system = HybridSystem(field, events, n_events=1, dim=2,
                          event_jacobian=lambda x: np.array([[1.0, 0.0]]))
    system.simulate(np.zeros(2), 2.0)
    system.flow_bderivative(np.zeros(2), 2.0)


#: files that compile many kernels and never run the compiled integrator: each pytest-xdist
#: worker runs those of its share first, while the integrator compiles in the background
KERNEL_FILES = {"test_adjoints.py", "test_bderivative.py", "test_corners.py",
                "test_fastpaths.py", "test_build_shortcuts.py", "test_kernels.py",
                "test_lanes.py", "test_variants.py", "test_resets.py", "test_scaling.py",
                "test_structured_lanes.py", "test_selection.py", "test_sizes.py",
                "test_triangulation.py", "test_bench_corners.py", "test_bench_dense.py"}


#: tests of :data:`KERNEL_FILES` that run the kernels in a subprocess on the same disk
#: cache: they run after the kernel files of their share, so that the subprocess loads what
#: both workers' kernel files have compiled by then instead of compiling it again
AFTER_KERNELS = {"test_the_plain_kernels_pass_the_same_tests"}


#: files with tests that run compiled models (measured: the tests that ask whether the
#: compiled integrator is ready) or call its driver: each worker runs them last in its
#: share, so that the files before them fill the minute the integrator compiles in, where
#: a test of these waited for it (both workers at once for 15 s on an empty cache, a core
#: left idle) or compiled the driver itself
INTEGRATOR_FILES = {
    "src/bderiv/examples/gaits.py", "src/bderiv/models/compiled/stretch.py",
    "tests/test_bounces.py", "tests/test_cli.py",
    "tests/test_cli_summaries.py", "tests/test_cli_usage.py", "tests/test_compiled_examples.py",
    "tests/test_compiled_integrator.py", "tests/test_compiled_params.py",
    "tests/test_compiled_path.py", "tests/test_compiled_stops.py", "tests/test_complex_step.py",
    "tests/test_contacts.py", "tests/test_control.py", "tests/test_docs.py",
    "tests/test_estimate.py", "tests/test_faults_fourth.py", "tests/test_final_time.py",
    "tests/test_fuzz_models.py", "tests/test_gaits.py", "tests/test_hybrid.py",
    "tests/test_jax.py", "tests/test_lost_crossings.py", "tests/test_near_simultaneous.py",
    "tests/test_overflow_messages.py", "tests/test_python_first.py", "tests/test_readiness.py",
    "tests/test_run_memory.py", "tests/test_shallow_return.py", "tests/test_short_excursion.py",
    "tests/test_simulate_many.py", "tests/test_spirals.py", "tests/test_symbolic.py",
    "tests/test_symbolic_inputs.py", "tests/test_zeno.py"}


#: files whose tests build a model that a test file builds too, and the file they run
#: beside (right after it, in its worker): the symbolic contact model of the doctests
#: compiled in both workers at once, about 4 s each
BESIDE = {"src/bderiv/symbolic/contacts.py": "tests/test_contacts.py"}


def _file(item) -> str:
    return item.nodeid.split("::")[0]


def _beside(items) -> list:
    """``items`` with those of each :data:`BESIDE` file moved right after the last test
    of its partner file (where the partner is not collected, at the end)."""
    moved = {name: [it for it in items if _file(it) == name] for name in BESIDE}
    out = [it for it in items if _file(it) not in BESIDE]
    for name, group in moved.items():
        ends = [i for i, it in enumerate(out) if _file(it) == BESIDE[name]]
        at = ends[-1] + 1 if ends else len(out)
        out[at:at] = group
    return out


def _place(item) -> int:
    """0: a kernel file's test; 1: one of :data:`AFTER_KERNELS`; 3: a test of
    :data:`INTEGRATOR_FILES` (a :data:`BESIDE` file's tests: those of its partner); 2: the
    rest."""
    if item.path.name in KERNEL_FILES:
        return 1 if item.originalname in AFTER_KERNELS else 0
    file = BESIDE.get(_file(item), _file(item))
    return 3 if file in INTEGRATOR_FILES else 2


@pytest.hookimpl(trylast=True)  # after -m and -k deselected: the shares of what runs
def pytest_collection_modifyitems(session, config, items):
    """Within each worker's first share of the tests (pytest-xdist's worksteal gives worker
    i of K the next ``len(rest) // (K - i)`` of the collection), the tests of
    :data:`KERNEL_FILES` first, in their order, then those of :data:`AFTER_KERNELS`, then
    the other files but :data:`INTEGRATOR_FILES`, then those; the tests of a
    :data:`BESIDE` file join its partner's share, after it. The set of tests stays the
    same. Without workers the order is that of the collection."""
    count = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    if count < 2:
        return
    items[:] = _beside(items)
    start, ordered = 0, []
    for i in range(count):
        stop = start + (len(items) - start) // (count - i)
        ordered += sorted(items[start:stop], key=_place)
        start = stop
    items[:] = ordered


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """After a file's last test, collect its garbage and freeze what is left alive (numba's
    dispatchers and types, the modules, the session's fixtures) out of the collector's
    reach: every full collection walked all of it again (docs/design.md, "The
    collector"). Frozen objects are not in ``gc.get_objects()``: a test that looks for
    objects there thaws them first (``gc.unfreeze()``; the next file's end freezes again).
    :func:`pytest_sessionfinish` thaws them for pytest's last collection."""
    yield
    if nextitem is None or nextitem.path != item.path:
        gc.collect()
        gc.freeze()


def pytest_sessionfinish(session, exitstatus):
    """Thaw the objects :func:`pytest_runtest_protocol` froze (pytest's own collection at
    the end, which reports exceptions raised in finalizers, sees every object: one,
    :func:`pytest_configure`); then, with ``BDERIV_SPECIALIZATIONS=<folder>`` set, write
    this process's table of compiled signatures of bderiv's dispatchers there
    (``tools/specializations.py``, issue 36: one file per pytest-xdist worker, merged by
    the tool)."""
    gc.unfreeze()  # first: the table's dispatchers are found by gc.get_objects()
    folder = os.environ.get("BDERIV_SPECIALIZATIONS")
    if not folder:
        return
    import importlib.util
    import pathlib

    tool = pathlib.Path(__file__).resolve().parents[1] / "tools" / "specializations.py"
    spec = importlib.util.spec_from_file_location("bderiv_specializations", tool)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    try:
        module.write(folder)
    except Exception as exc:  # noqa: BLE001 - said in the folder, not lost in a worker
        os.makedirs(folder, exist_ok=True)
        with open(os.path.join(folder, f"error-{os.getpid()}.txt"), "w") as fh:
            fh.write(f"{type(exc).__name__}: {exc}\n")


def pytest_unconfigure(config):
    """Freeze every object again when the interpreter exits (the first exit function to
    run, after pytest's own collection at the end has seen them thawed): its finalization
    then collects garbage over a few objects, not over a worker's million. Each of those
    collections walked all of them, and the other worker's core idled meanwhile: pytest
    waited 4.3-6.2 s after the last worker's last test for the workers to exit, 1.5 s
    frozen (docs/design.md, "The workers' exit")."""
    atexit.register(gc.freeze)


@contextlib.contextmanager
def _held(path):
    """An exclusive lock on the file ``path`` for the duration (none without fcntl)."""
    if fcntl is None:
        yield
        return
    with open(path, "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


@pytest.fixture(scope="session", autouse=True)
def warm_jit(tmp_path_factory):
    """Compile (or load from numba's disk cache) the kernels of :func:`_warm_ups`.

    Under pytest-xdist, worker k of K runs the tasks k, k + K, ... and then the others,
    each under a lock shared by the workers: a task that the other worker is compiling is
    waited for and then loaded from the disk cache, never compiled twice at once (the
    lock's folder: the parent of the workers' base temporary folders, shared by them)."""
    tasks = _warm_ups()
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0")
    k, count = int(worker[2:]), int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    order = list(range(k, len(tasks), count)) + [i for i in range(len(tasks)) if i % count != k]
    for i in order:
        if count == 1:
            tasks[i]()
            continue
        with _held(tmp_path_factory.getbasetemp().parent / f"warm_jit_{i}.lock"):
            tasks[i]()


@pytest.fixture
def bars_drawn(monkeypatch):
    """Every delayed bar of long work (``_progress.DelayedBar``) drawn at once and at each
    report, into the buffer returned (they wait for seconds, on a terminal only)."""
    import io

    from bderiv._support import _progress

    pytest.importorskip("tqdm")
    buffer = io.StringIO()
    monkeypatch.setattr(_progress, "BAR_DELAY", 0.0)
    monkeypatch.setattr(_progress, "BAR_REFRESH", 0.0)
    monkeypatch.setattr(_progress, "BAR_OPTIONS",
                        {"file": buffer, "disable": False, "leave": True})
    return buffer


@pytest.fixture(scope="session")
def pronking_gait():
    """``(example, orbit)``: the two-legged pronking gait's periodic orbit, found once per
    process from a perturbed apex (Newton's method and a few strides: seconds)."""
    from bderiv.examples import gaits

    ex = gaits.pronking()
    return ex, gaits.pronking_orbit(ex, perturbation=(0.02, 0.01, 0.03, -0.05))
