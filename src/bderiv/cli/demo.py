"""``bderiv demo``: a model's B-derivatives, their pieces, a timed batch and the check.

Two maps are reported and named apart: ``M``, the B-derivative at an event point (one per
event group, a :class:`~bderiv.BDerivative`), and ``D``, the B-derivative of the flow from
``x0`` over ``[0, t_final]`` (a :class:`~bderiv.FlowBDerivative`, ``D = L_m M_m ... M_1 L_0``).
A corner table without a model has only ``M``.

The computation returns one JSON-ready dict and reports it section by section through a
callback ``report(section, res)`` as it goes (a model: ``"model"``, ``"trajectory"``,
``"pieces"``, ``"batch"``, ``"check"``; a corner table: ``"corner_table"``; both end with
``"total"``), so that the text can stream while the finite differences run;
:mod:`bderiv.cli.render` turns each section into text. Each phase is timed apart, with
the part of it spent compiling (or loading the cached kernels: the first run on a machine)
in ``res["phases"]``; the timings reported (the build, the batch) leave compilation out.
"""

from __future__ import annotations

import time

import numpy as np

from .._limits import DEMO_BATCH, DEMO_CHECK, FD_EPS
from ..analysis.checks import fd_check
from .machine import machine_info
from .pieces import distinct_pieces, group_tables, piece_summary
from .systems import load_example, random_vectors
from .timing import Phases
from .usage import require_demo_memory

#: tangent vectors of the batch whose event orders are counted (pieces met, shares)
PIECE_SAMPLE = 100_000
#: vectors of the untimed first call (the kernels compiled or loaded, the caches warm)
FIRST_CALL = 2048
#: timed runs of the batch (the best and the slowest are reported)
TIMED_RUNS = 3
#: the vectors of the corner-table demo, one per row (its first d columns are used)
TABLE_VECTORS = ((-1.0, -2.0, -3.0), (-3.0, -1.0, -2.0), (0.5, -0.2, 0.1))


def run_demo(example="chair", n=None, extended=False, batch=DEMO_BATCH, check=DEMO_CHECK,
             eps=FD_EPS, seed=0, full=False, progress=None, report=None,
             compiled=True) -> dict:
    """Run the demo and return its results as a JSON-ready dict.

    Parameters
    ----------
    example, n, extended
        The system, as for :func:`bderiv.cli.systems.load_example`.
    batch : int
        Tangent vectors in the timed batch.
    check : int
        Unit vectors compared with finite differences of the simulation (0: none).
    eps : tuple of float
        Finite-difference steps.
    seed : int
    full : bool
        Also the matrices: the pieces listed, the event Jacobians and corner tables, and
        a model's linear stages.
    progress : callable ``progress(done, total)``, optional
        Called after each step of the finite-difference check.
    report : callable ``report(section, res)``, optional
        Called with the results so far after each section.
    compiled : bool
        The example's compiled version where it has one
        (:data:`~bderiv.cli.systems.COMPILED_EXAMPLES`), else its Python functions.

    Returns
    -------
    dict
        A model's ``check`` holds ``error_ratios``, how much the error shrinks from each
        step to the next: None (JSON null) where the smaller step's error is exactly 0.
    """
    report = report or (lambda section, res: None)
    t_start, phases = time.perf_counter(), Phases()
    rng = np.random.default_rng(seed)
    with phases("loading the example"):
        ex, bd = load_example(example, n, extended, compiled)
    dim = bd.dim if ex is None else ex.system.dim
    require_demo_memory(batch, check, dim)  # before anything runs
    res = {"example": example}
    if ex is None:
        with phases("corner table"):
            _table_demo(bd, res, batch, rng, full, report)
    else:
        _model_demo(ex, res, batch, check, eps, rng, full, progress, report, phases)
    res["total_seconds"] = time.perf_counter() - t_start
    res["phases"] = {name: {"seconds": sec, "compiling_seconds": phases.compiling[name]}
                     for name, sec in phases.seconds.items()}
    report("total", res)
    return res


def _model_demo(ex, res, batch, check, eps, rng, full, progress, report, phases):
    """The demo of a model: trajectory, pieces, timed batch, finite-difference check."""
    system = ex.system
    res.update(description=ex.description, dim=system.dim, n_events=system.n_events,
               x0=ex.x0.tolist(), t_final=ex.t_final, compiled=ex.compiled)
    report("model", res)
    with phases("flow map"):
        fb = system.flow_bderivative(ex.x0, ex.t_final)
    res["integrator"] = _running_on(system)
    res["build_seconds"] = phases.without_compiling("flow map")
    res["groups"] = _groups(fb, full)
    if full:
        res["linear"] = [L.tolist() for L in fb.linear]
    report("trajectory", res)
    V = random_vectors(rng, batch, system.dim)
    with phases("pieces"):
        res["pieces"] = piece_summary(fb, V[:PIECE_SAMPLE], full)
    report("pieces", res)
    with phases("batch"):
        res["batch"] = _time_batch(fb, V)
    report("batch", res)
    if check > 0:
        before = _running_on(system)
        with phases("check"):
            res["check"] = _check(ex, fb, rng, check, eps, progress,
                                  res["batch"]["ns_per_vector"] * 1e-9)
        after = _running_on(system)  # the speed-up's reference: where its runs went
        res["check"]["simulations_on"] = before if before == after else f"{before}-{after}"
        report("check", res)


def _running_on(system) -> str:
    """Where ``system``'s runs go now: ``"python"`` (a compiled model's functions on their
    Python code, before they are compiled on this machine), ``"scipy"`` (a Python model,
    or a compiled one while the integrator compiles elsewhere) or ``"compiled"``."""
    return "python" if system.calls.python_first else \
        "scipy" if system.compiled is None else "compiled"


def _groups(fb, full):
    """The event groups with the region masks before and after each (and their tables)."""
    return [{"time": t, "events": list(events), "mask_before": before, "mask_after": after,
             **table}
            for t, events, (before, after), table in zip(
                fb.group_times, fb.group_events, fb.group_masks, group_tables(fb, full),
                strict=True)]


def _time_batch(fmap, V):
    """Time ``fmap(V)`` :data:`TIMED_RUNS` times after an untimed first call on a slice."""
    t0 = time.perf_counter()
    fmap(V[:FIRST_CALL])
    t_first = time.perf_counter() - t0
    out = np.empty_like(V)
    runs = []
    for _ in range(TIMED_RUNS):
        t0 = time.perf_counter()
        fmap(V, out=out)
        runs.append(time.perf_counter() - t0)
    best = min(runs)
    return {"size": len(V), "runs_seconds": runs, "ns_per_vector": best / len(V) * 1e9,
            "first_call_seconds": t_first, "max_abs_output": float(np.abs(out).max()),
            "machine": machine_info()}


def _check(ex, fb, rng, k, eps, progress, per_batch):
    """Finite differences of the simulation against the B-derivative on k unit vectors."""
    V = rng.standard_normal((k, ex.system.dim))
    V /= np.linalg.norm(V, axis=1, keepdims=True)
    # untimed: the simulations' first calls (a compiled model's functions and integrator
    # compiled or loaded from the disk cache), so that the time per vector is the run's
    ex.system.flow_fd(ex.x0, ex.t_final, V[:1], eps[0])
    fd = fd_check(ex.system, ex.x0, ex.t_final, V, fb(V), eps, progress=progress)
    t0 = time.perf_counter()
    for _ in range(10):
        fb(V)
    per_call = (time.perf_counter() - t0) / (10 * k)  # D in calls of k vectors
    errors = list(fd.max_errors)
    # how much the error shrinks from one step to the next (10x per decade when O(eps));
    # None (JSON null) where the smaller step's error is exactly 0: no ratio
    shrink = [a / b if b > 0 else None for a, b in zip(errors[:-1], errors[1:], strict=True)]
    covered = len(distinct_pieces(fb.orders(V) if fb.n_groups else []))
    per_fd = fd.seconds_per_vector
    return {"vectors": k, "pieces_covered": covered, "eps": list(fd.eps),
            "max_rel_error": errors, "error_ratios": shrink,
            "fd_seconds_per_vector": per_fd, "map_seconds_per_vector": per_call,
            "speedup": per_fd / per_batch}


def _table_demo(bd, res, batch, rng, full, report):
    """The demo of a corner table: its tables, a few vectors, every piece, the inverse, a
    timed batch."""
    res.update(description=f"corner table without a model, {bd.n_events} events in "
               f"R^{bd.dim}", dim=bd.dim, n_events=bd.n_events, Dh=bd.Dh.tolist(),
               F=bd.F.tolist())
    V = np.array(TABLE_VECTORS)[:, : bd.dim]
    times, order = bd.event_times(V)
    W = bd(V)
    res["vectors"] = [{"u": u.tolist(), "order": o.tolist(), "times": t.tolist(),
                       "Mu": w.tolist()} for u, o, t, w in zip(V, order, times, W, strict=True)]
    res["pieces"] = []
    for o, P in bd.pieces(max_pieces=720):
        entry = {"order": o.tolist(), "det": float(np.linalg.det(P)),
                 "norm": float(np.linalg.norm(P, 2))}
        res["pieces"].append(entry | ({"matrix": P.tolist()} if full else {}))
    err = float(np.abs(bd.inverse(W) - V).max())
    res["batch"] = _time_batch(bd, random_vectors(rng, batch, bd.dim))
    res["check"] = {"inverse_round_trip": err}
    report("corner_table", res)
