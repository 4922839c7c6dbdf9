"""``bderiv demo``: a model's B-derivative, its pieces, a timed batch and the check.

The computation returns one JSON-ready dict and reports it section by section through a
callback ``report(section, res)`` as it goes (a model: ``"model"``, ``"trajectory"``,
``"pieces"``, ``"check"``; a corner table: ``"corner_table"``; both end with ``"total"``),
so that the text can stream while the finite differences run; :mod:`bderiv.cli.render`
turns each section into text.
"""

from __future__ import annotations

import math
import time

import numpy as np

from ..checks import fd_check
from .systems import load_example
from .usage import require_memory

#: tangent vectors of the batch whose event orders are counted (pieces met, shares)
PIECE_SAMPLE = 100_000
#: vectors of the untimed first call (compiling, or loading the cached kernels)
FIRST_CALL = 2048
#: the vectors of the corner-table demo, one per row (its first d columns are used)
TABLE_VECTORS = ((-1.0, -2.0, -3.0), (-3.0, -1.0, -2.0), (0.5, -0.2, 0.1))


def run_demo(example="chair", n=None, extended=False, batch=1_000_000, check=8,
             eps=(1e-4, 1e-5, 1e-6), seed=0, progress=None, report=None) -> dict:
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
    progress : callable ``progress(done, total)``, optional
        Called after each step of the finite-difference check.
    report : callable ``report(section, res)``, optional
        Called with the results so far after each section.

    Returns
    -------
    dict
    """
    report = report or (lambda section, res: None)
    t_start = time.perf_counter()
    rng = np.random.default_rng(seed)
    ex, bd = load_example(example, n, extended)
    dim = bd.dim if ex is None else ex.system.dim
    # the batch, its image and one temporary of the flow's stages, before anything runs
    require_memory(3 * batch * dim * 8, f"--batch {batch} (d = {dim})")
    require_memory(3 * check * dim * 8, f"--check {check} (d = {dim})")
    res = {"example": example}
    if ex is None:
        _table_demo(bd, res, batch, rng, report)
    else:
        _model_demo(ex, res, batch, check, eps, rng, progress, report)
    res["total_seconds"] = time.perf_counter() - t_start
    report("total", res)
    return res


def _model_demo(ex, res, batch, check, eps, rng, progress, report):
    """The demo of a model: trajectory, pieces, timed batch, finite-difference check."""
    system = ex.system
    res.update(name=ex.name, description=ex.description, dim=system.dim,
               n_events=system.n_events, x0=ex.x0.tolist(), t_final=ex.t_final)
    report("model", res)
    t0 = time.perf_counter()
    fb = system.flow_bderivative(ex.x0, ex.t_final)
    res["build_seconds"] = time.perf_counter() - t0
    res["groups"] = _groups(fb, system.start_mask(ex.x0))
    report("trajectory", res)
    V = rng.standard_normal((batch, system.dim))
    res["batch"] = _time_batch(fb, V)
    sample = V[:PIECE_SAMPLE]
    res["pieces_sample"] = len(sample)
    orders = fb.orders(sample) if fb.n_groups else []
    res["pieces"] = [_piece(fb.piece(o) if o else fb.piece(), o, share)
                     for o, share in distinct_pieces(orders, limit=6)]
    res["n_pieces"] = math.prod(math.factorial(len(g["events"])) for g in res["groups"])
    res["n_pieces_visited"] = len(distinct_pieces(orders))
    report("pieces", res)
    if check > 0:
        res["check"] = _check(ex, fb, rng, check, eps, progress,
                              res["batch"]["seconds"] / batch)
        report("check", res)


def _groups(fb, mask):
    """The event groups of the trajectory with the region masks before and after each."""
    groups = []
    for t, events in zip(fb.group_times, fb.group_events, strict=True):
        after = mask | sum(1 << k for k in events)
        groups.append({"time": t, "events": list(events), "mask_before": mask,
                       "mask_after": after})
        mask = after
    return groups


def _time_batch(fmap, V):
    """Time ``fmap(V)`` after an untimed first call on a slice of it."""
    t0 = time.perf_counter()
    fmap(V[:FIRST_CALL])
    t_first = time.perf_counter() - t0
    t0 = time.perf_counter()
    out = fmap(V)
    seconds = time.perf_counter() - t0
    return {"size": len(V), "seconds": seconds, "ns_per_vector": seconds / len(V) * 1e9,
            "first_call_seconds": t_first, "max_abs_output": float(np.abs(out).max())}


def _piece(P, orders, share=None):
    """A piece's JSON entry: its event orders (one per group), share, det and 2-norm."""
    entry = {"orders": [o.tolist() for o in orders]}
    if share is not None:
        entry["share"] = share
    entry.update(det=float(np.linalg.det(P)), norm=float(np.linalg.norm(P, 2)))
    return entry


def distinct_pieces(orders, limit=None):
    """Distinct rows of the per-group event orders, the most frequent first.

    Parameters
    ----------
    orders : list of ndarray, each shape (m, n_g)
        The event orders of m vectors in each group g (empty: no event group).
    limit : int, optional
        Keep at most this many.

    Returns
    -------
    list of (list of ndarray, float)
        The orders of a piece, one per group, and the share of the m vectors in it.

    Examples
    --------
    >>> import numpy as np
    >>> orders = [np.array([[1, 0], [0, 1], [1, 0], [1, 0]])]  # one group of 2 events
    >>> [(o[0].tolist(), share) for o, share in distinct_pieces(orders)]
    [([1, 0], 0.75), ([0, 1], 0.25)]
    """
    if not orders:
        return [([], 1.0)]
    sizes = [o.shape[1] for o in orders]
    key = np.concatenate(orders, axis=1)
    uniq, counts = np.unique(key, axis=0, return_counts=True)
    top = np.argsort(-counts, kind="stable")[:limit]
    return [([s.astype(np.int64) for s in np.split(uniq[i], np.cumsum(sizes)[:-1])],
             float(counts[i] / key.shape[0])) for i in top]


def _check(ex, fb, rng, k, eps, progress, per_batch):
    """Finite differences of the simulation against the B-derivative on k unit vectors."""
    V = rng.standard_normal((k, ex.system.dim))
    V /= np.linalg.norm(V, axis=1, keepdims=True)
    fd = fd_check(ex.system, ex.x0, ex.t_final, V, fb(V), eps, progress=progress)
    t0 = time.perf_counter()
    for _ in range(10):
        fb(V)
    per_bd = (time.perf_counter() - t0) / (10 * k)
    errors = list(fd.max_errors)
    # how much the error shrinks from one step to the next (10x per decade when O(eps))
    shrink = [a / b if b > 0 else math.inf for a, b in zip(errors[:-1], errors[1:], strict=True)]
    covered = len(distinct_pieces(fb.orders(V) if fb.n_groups else []))
    per_fd = fd.seconds_per_vector
    return {"vectors": k, "pieces_covered": covered, "eps": list(fd.eps),
            "max_rel_error": errors, "error_ratios": shrink,
            "fd_seconds_per_vector": per_fd, "bd_seconds_per_vector": per_bd,
            "bd_seconds_per_vector_batch": per_batch, "speedup": per_fd / per_batch}


def _table_demo(bd, res, batch, rng, report):
    """The demo of a corner table: a few vectors, every piece, the inverse, a timed batch."""
    res.update(name=f"corner table ({bd.n_events} events in R^{bd.dim})", dim=bd.dim,
               n_events=bd.n_events)
    V = np.array(TABLE_VECTORS)[:, : bd.dim]
    times, order = bd.event_times(V)
    W = bd(V)
    res["vectors"] = [{"u": u.tolist(), "order": o.tolist(), "times": t.tolist(),
                       "Mu": w.tolist()} for u, o, t, w in zip(V, order, times, W, strict=True)]
    res["pieces"] = [_piece(P, [o]) for o, P in bd.pieces(max_pieces=720)]
    res["n_pieces"] = len(res["pieces"])
    err = float(np.abs(bd.inverse(W) - V).max())
    res["batch"] = _time_batch(bd, rng.standard_normal((batch, bd.dim)))
    res["check"] = {"inverse_round_trip": err}
    report("corner_table", res)
