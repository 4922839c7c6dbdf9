"""Command line: ``bderiv demo | bench | plot | export`` (also ``python -m bderiv``).

- ``demo``: a built-in model (the chair by default): its trajectory's event groups, the
  B-derivative of its flow, the pieces (event orders, determinant, norm), a batch of
  tangent vectors with the time per vector, and the check against finite differences of
  the simulation. ``--json`` prints one JSON document instead.
- ``bench``: a dimension sweep of bderiv against the batched-NumPy baseline and a BLAS
  yardstick; a table, optionally a log-log plot.
- ``plot``: the figures of :mod:`bderiv.plot` to PNG or PDF files.
- ``export``: the triangulation of an example's B-derivative to ``.npz`` and ``.json``
  (read back with :func:`bderiv.load_triangulation`).

Bad arguments give a one-line error on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

import numpy as np

from .bderivative import BDerivative

#: examples that need no model (corner tables only)
TABLE_EXAMPLES = ("corners", "planar")
#: examples from :mod:`bderiv.examples` (nonlinear models)
MODEL_EXAMPLES = ("chair", "network", "table")
#: largest n of the scalable network family the CLI accepts
NETWORK_MAX_N = 20


class UsageError(Exception):
    """A bad argument found after parsing; reported in one line, exit status 2."""


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors: ``bderiv: error: ...`` and exit status 2."""

    def error(self, message):  # noqa: D401 - argparse API
        self.exit(2, f"{self.prog.split()[0]}: error: {message} (see {self.prog} --help)\n")


# -- examples -------------------------------------------------------------------------------


def three_event_table():
    """A 3-event system in R^3 whose event order can be overtaken (MATH.md section 3).

    Returns
    -------
    Dh : ndarray, shape (3, 3)
    F : ndarray, shape (8, 3)
    """
    F = np.ones((8, 3))
    F[0b001] = (1.0, 0.1, 1.0)  # after event 0 alone, h_1 grows ten times slower
    F[0b011] = (1.0, 0.5, 2.0)
    F[0b111] = (1.5, 1.0, 2.0)
    return np.eye(3), F


def planar_table():
    """A 2-event system in the plane (d = n = 2) for the 2-D figures.

    Returns
    -------
    Dh : ndarray, shape (2, 2)
    F : ndarray, shape (4, 2)
    """
    Dh = np.array([[1.0, 0.3], [0.2, 1.0]])
    F = np.array([[1.0, 1.0], [0.4, 1.6], [1.5, 0.5], [0.8, 0.9]])
    return Dh, F


def have_models() -> bool:
    """Whether :mod:`bderiv.examples` (the nonlinear models) is available."""
    try:
        import bderiv.examples  # noqa: F401
    except ImportError:
        return False
    return True


def load_example(name: str, n: int | None = None, extended: bool = False):
    """The example ``name``: ``(Example or None, BDerivative at its event point)``.

    ``corners`` and ``planar`` are corner tables without a model (Example is None).
    """
    if n is not None and name != "network":
        raise UsageError(f"--n applies to --example network only, not to {name!r}")
    if extended and name != "network":
        raise UsageError(f"--extended applies to --example network only, not to {name!r}")
    if name == "corners":
        return None, BDerivative(*three_event_table())
    if name == "planar":
        return None, BDerivative(*planar_table())
    try:
        from . import examples
    except ImportError as exc:  # the models are not in this installation
        raise UsageError(
            f"example {name!r} needs bderiv.examples, which cannot be imported here ({exc}); "
            f"use --example corners"
        ) from None
    if name == "chair":
        ex = examples.chair()
    elif name == "table":
        ex = examples.table()
    else:
        n = 3 if n is None else n
        if not 1 <= n <= NETWORK_MAX_N:
            raise UsageError(f"--n must be between 1 and {NETWORK_MAX_N}, got {n}")
        ex = examples.network(n, extended=extended)
    return ex, ex.system.bderivative(ex.rho)


def _progress(enabled: bool, desc: str):
    """A tqdm callback on stderr, shown only on a terminal; None when disabled."""
    if not enabled:
        return None
    try:
        from ._progress import TqdmCallback

        return TqdmCallback(desc, leave=False, disable=None, file=sys.stderr)
    except ImportError:
        return None  # the bar is a nicety in the CLI; without tqdm run silently


def _fmt_order(order) -> str:
    return "(" + ",".join(str(int(k)) for k in order) + ")"


def _fmt_mask(mask: int, n: int) -> str:
    return format(int(mask), f"0{n}b")


# -- demo -------------------------------------------------------------------------------------


def _distinct_pieces(orders, limit):
    """Distinct rows of the per-group orders: list of (orders per group, share), by share."""
    if not orders:
        return [([], 1.0)]
    sizes = [o.shape[1] for o in orders]
    key = np.concatenate(orders, axis=1)
    uniq, counts = np.unique(key, axis=0, return_counts=True)
    top = np.argsort(-counts, kind="stable")[:limit]
    out = []
    for i in top:
        split = np.split(uniq[i], np.cumsum(sizes)[:-1])
        out.append(([s.astype(np.int64) for s in split], counts[i] / key.shape[0]))
    return out


def run_demo(example="chair", n=None, extended=False, batch=1_000_000, check=8,
             eps=(1e-4, 1e-5, 1e-6), seed=0, progress=True, emit=None):
    """Run the demo and return its results as a JSON-ready dict.

    ``emit(text)`` (optional) receives the report section by section as it is computed.
    """
    emit = emit or (lambda text: None)
    t_start = time.perf_counter()
    rng = np.random.default_rng(seed)
    ex, bd_point = load_example(example, n, extended)
    res = {"example": example}
    if ex is None:
        return _run_table_demo(bd_point, res, batch, rng, emit, t_start)
    system = ex.system
    d, n_ev = system.dim, system.n_events
    res.update(name=ex.name, description=ex.description, dim=d, n_events=n_ev,
               x0=ex.x0.tolist(), t_final=ex.t_final)
    emit(f"bderiv demo: {ex.name}\n  {ex.description}\n")

    t0 = time.perf_counter()
    fb = system.flow_bderivative(ex.x0, ex.t_final)
    t_build = time.perf_counter() - t0
    groups, mask = [], system.start_mask(ex.x0)
    for t, events in zip(fb.group_times, fb.group_events, strict=True):
        after = mask | sum(1 << k for k in events)
        groups.append({"time": t, "events": list(events), "mask_before": mask,
                       "mask_after": after})
        mask = after
    res["groups"] = groups
    lines = [f"trajectory from x0 to t_final = {ex.t_final:g}: {len(groups)} event group(s)"]
    for i, g in enumerate(groups):
        kind = "simultaneous" if len(g["events"]) > 1 else "single"
        lines.append(
            f"  group {i}: t = {g['time']:.6f}, events {tuple(g['events'])} {kind}, mask "
            f"{_fmt_mask(g['mask_before'], n_ev)} -> {_fmt_mask(g['mask_after'], n_ev)}"
        )
    lines.append(
        f"B-derivative of x -> Phi({ex.t_final:g}, x) at x0: D = L_m M_m ... L_1 M_1 L_0 "
        f"(L: variational equations of the smooth stretches, M: one BDerivative per "
        f"group), built in {t_build:.2f} s"
    )
    emit("\n".join(lines) + "\n")

    # batch evaluation (first call compiles the kernels, or loads them from the cache)
    V = rng.standard_normal((batch, d))
    t0 = time.perf_counter()
    fb(V[: min(batch, 2048)])
    t_first = time.perf_counter() - t0
    t0 = time.perf_counter()
    out = fb(V)
    t_batch = time.perf_counter() - t0
    res["batch"] = {"size": batch, "seconds": t_batch, "ns_per_vector": t_batch / batch * 1e9,
                    "first_call_seconds": t_first}

    # pieces met by the batch (a sample of it), with determinant and norm
    sample = V[: min(batch, 100_000)]
    orders = fb.orders(sample) if fb.n_groups else []
    n_total = math.prod(math.factorial(len(g["events"])) for g in groups)
    pieces = []
    for per_group, share in _distinct_pieces(orders, limit=6):
        P = fb.piece(per_group) if per_group else fb.piece()
        pieces.append({"orders": [o.tolist() for o in per_group], "share": share,
                       "det": float(np.linalg.det(P)), "norm": float(np.linalg.norm(P, 2))})
    res["pieces"] = pieces
    res["n_pieces"] = n_total
    n_seen = len(_distinct_pieces(orders, limit=10**9)) if orders else 1
    res["n_pieces_visited"] = n_seen
    lines = [f"pieces: {n_total:,} in all (one event order per group), {n_seen:,} met by "
             f"{len(sample):,} random tangent vectors; the most visited:"]
    labels = [" ".join(f"g{i}={_fmt_order(o)}" for i, o in enumerate(p["orders"])) or "-"
              for p in pieces]
    width = max(map(len, labels), default=1)
    for label, p in zip(labels, pieces, strict=True):
        lines.append(f"  order {label:<{width}}  share {100 * p['share']:6.3g} %   det = "
                     f"{p['det']:<10.6g} |D|_2 = {p['norm']:.6g}")
    lines.append(
        f"batch: {batch:,} tangent vectors in {t_batch:.3f} s = "
        f"{res['batch']['ns_per_vector']:.0f} ns per vector (first call, compiling or "
        f"loading the cached kernels: {t_first:.2f} s); |D V| max = {np.abs(out).max():.4g}"
    )
    emit("\n".join(lines) + "\n")

    if check > 0:
        res["check"] = _fd_check(system, ex, fb, rng, check, eps, progress, emit,
                                 t_batch / batch)
    res["total_seconds"] = time.perf_counter() - t_start
    emit(f"total {res['total_seconds']:.1f} s\n")
    return res


def _fd_check(system, ex, fb, rng, k, eps, progress, emit, per_batch):
    """Finite differences of the simulation against the B-derivative on k vectors."""
    d = system.dim
    V = rng.standard_normal((k, d))
    V /= np.linalg.norm(V, axis=1, keepdims=True)
    D = fb(V)
    scale = np.abs(D).max()
    errors, fd_seconds = [], 0.0
    bar = _progress(progress, "finite differences")
    for i, e in enumerate(eps):
        t0 = time.perf_counter()
        FD = system.flow_fd(ex.x0, ex.t_final, V, e)
        fd_seconds += time.perf_counter() - t0
        errors.append(float(np.abs(FD - D).max() / scale))
        if bar is not None:
            bar(i + 1, len(eps))
    per_fd = fd_seconds / (len(eps) * (k + 1))
    t0 = time.perf_counter()
    for _ in range(10):
        fb(V)
    per_bd = (time.perf_counter() - t0) / (10 * k)
    ratios = [errors[i] / errors[i + 1] for i in range(len(errors) - 1)]
    orders = fb.orders(V) if fb.n_groups else []
    n_pieces = len(_distinct_pieces(orders, limit=10**9)) if orders else 1
    result = {"vectors": k, "pieces_covered": n_pieces, "eps": list(eps),
              "max_rel_error": errors, "error_ratios": ratios,
              "fd_seconds_per_vector": per_fd, "bd_seconds_per_vector": per_bd,
              "bd_seconds_per_vector_batch": per_batch, "speedup": per_fd / per_batch}
    lines = [f"check against finite differences of the simulation ({k} unit vectors, "
             f"{n_pieces} distinct pieces): max |FD - D V| / max |D V|"]
    for e, err in zip(eps, errors, strict=True):
        lines.append(f"  eps = {e:.0e}: {err:.3e}")
    if ratios:
        lines.append("  error shrinks with eps by " + ", ".join(f"{r:.1f}x" for r in ratios)
                     + " per step (O(eps) expected)")
    lines.append(f"  one simulation per vector: {per_fd * 1e3:.1f} ms; B-derivative: "
                 f"{per_batch * 1e9:.0f} ns per vector in the batch ({per_fd / per_batch:,.0f}x "
                 f"faster; {per_bd * 1e6:.1f} us per vector in a call of {k})")
    emit("\n".join(lines) + "\n")
    return result


def _run_table_demo(bd, res, batch, rng, emit, t_start):
    """The demo on a corner table without a model (no simulation to compare with)."""
    res.update(name=f"corner table ({bd.n_events} events in R^{bd.dim})", dim=bd.dim,
               n_events=bd.n_events)
    emit(f"bderiv demo: {res['name']}, Dh = event Jacobian, F = corner table\n")
    V = np.array([[-1.0, -2.0, -3.0], [-3.0, -1.0, -2.0], [0.5, -0.2, 0.1]])[:, : bd.dim]
    times, order = bd.event_times(V)
    W = bd(V)
    rows = []
    lines = ["vector u -> event order, event times, M(u):"]
    for u, o, t, w in zip(V, order, times, W, strict=True):
        rows.append({"u": u.tolist(), "order": o.tolist(), "times": t.tolist(),
                     "Mu": w.tolist()})
        lines.append(f"  u={u}  order={o.tolist()}  times={np.round(t[o], 4)}  M(u)={w}")
    res["vectors"] = rows
    pieces = []
    for o, P in bd.pieces(max_pieces=720):
        pieces.append({"orders": [o.tolist()], "det": float(np.linalg.det(P)),
                       "norm": float(np.linalg.norm(P, 2))})
    res["pieces"] = pieces
    res["n_pieces"] = len(pieces)
    lines.append(f"pieces: {len(pieces)}")
    for p in pieces:
        lines.append(f"  order {_fmt_order(p['orders'][0]):<10} det = {p['det']:<8.4g} "
                     f"|M|_2 = {p['norm']:.4g}")
    err = float(np.abs(bd.inverse(W) - V).max())
    lines.append(f"inverse round trip max |M^-1(M(u)) - u| = {err:.2e}")
    B = rng.standard_normal((batch, bd.dim))
    t0 = time.perf_counter()
    bd(B[:2048])
    t_first = time.perf_counter() - t0
    t0 = time.perf_counter()
    bd(B)
    dt = time.perf_counter() - t0
    res["batch"] = {"size": batch, "seconds": dt, "ns_per_vector": dt / batch * 1e9,
                    "first_call_seconds": t_first}
    res["check"] = {"inverse_round_trip": err}
    lines.append(f"batch: {batch:,} vectors in {dt:.3f} s = {dt / batch * 1e9:.0f} ns per "
                 f"vector (first call: {t_first:.2f} s)")
    res["total_seconds"] = time.perf_counter() - t_start
    emit("\n".join(lines) + "\n")
    return res


def _cmd_demo(args) -> int:
    example = args.example
    if example is None:
        if args.n is not None or args.extended:
            example = "network"
        else:
            example = "chair" if have_models() else "corners"
    emit = None if args.json else (lambda text: print(text, end="", flush=True))
    res = run_demo(example, args.n, args.extended, args.batch, args.check, tuple(args.eps),
                   args.seed, progress=not args.no_progress, emit=emit)
    if args.json:
        print(json.dumps(res, indent=1))
    return 0


# -- bench ------------------------------------------------------------------------------------


def _cmd_bench(args) -> int:
    from . import _bench

    if args.plot:
        _check_figure_path(args.plot)
    bar = _progress(not args.no_progress, "bench")
    rows = _bench.sweep(tuple(args.n), d_factor=args.d_factor, batch=args.batch,
                        repeat=args.repeat, progress=bar)
    if args.plot:
        from . import plot

        plot.scaling(rows).savefig(args.plot, dpi=120)
    if args.json:
        print(json.dumps(rows, indent=1))
    else:
        print(f"bderiv bench: d = {args.d_factor} n, batch m = {args.batch:,}, best of "
              f"{args.repeat}; ns/q = nanoseconds per query (tangent vector)")
        print(_bench.format_table(rows))
        print("speed-up = numpy / bderiv; % of BLAS = useful work rate (n^2 + 2 n d flops "
              "per query) over a matrix product of the same flop count")
        if args.plot:
            print(f"plot written to {args.plot}")
    return 0


# -- plot -------------------------------------------------------------------------------------

FIGURES_2D = ("field", "triangulation", "circle")
FIGURES = (*FIGURES_2D, "pieces", "scaling")


def _check_figure_path(path):
    """Refuse a figure path before any work is done (suffix, existing directory)."""
    ext = os.path.splitext(path)[1].lower()
    if ext not in (".png", ".pdf", ".svg"):
        raise UsageError(f"figure file {path!r} must end in .png, .pdf or .svg")
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        raise UsageError(f"directory {parent!r} of the figure file does not exist")


def _cmd_plot(args) -> int:
    from . import plot

    example = args.example
    if example is None:
        example = "network" if have_models() else "planar"
        n = 2 if args.n is None and example == "network" else args.n
    else:
        n = args.n
    wanted = list(dict.fromkeys(args.figure or ["all"]))
    if "all" in wanted:
        wanted = [f for f in FIGURES if f != "scaling" or args.bench_json]
    _, bd = load_example(example, n, args.extended)
    if bd.dim != 2:
        asked_2d = [f for f in wanted if f in FIGURES_2D]
        if args.figure and "all" not in args.figure and asked_2d:
            raise UsageError(
                f"figures {asked_2d} need a 2-D system but {example} has d = {bd.dim}; use "
                f"--example planar or --example network --n 2"
            )
        wanted = [f for f in wanted if f not in FIGURES_2D]
    os.makedirs(args.out, exist_ok=True)
    written = []
    for name in wanted:
        if name == "field":
            fig = plot.corner_field(bd)
        elif name == "triangulation":
            fig = plot.triangulation(bd)
        elif name == "circle":
            fig = plot.tangent_circle(bd)
        elif name == "pieces":
            fig = plot.pieces(bd)
        else:
            fig = plot.scaling(_bench_rows(args.bench_json))
        path = os.path.join(args.out, f"{name}.{args.format}")
        fig.savefig(path, dpi=args.dpi)
        written.append(path)
    if args.json:
        print(json.dumps({"example": example, "dim": bd.dim, "files": written}))
    else:
        print(f"bderiv plot: {example} (n = {bd.n_events}, d = {bd.dim})")
        for path in written:
            print(f"  wrote {path}")
        if bd.dim != 2:
            print("  (field, triangulation and circle need a 2-D system: --example planar or "
                  "--example network --n 2)")
    return 0


def _bench_rows(path):
    if path is None:
        from . import _bench

        return _bench.sweep((2, 4, 8), batch=20_000, repeat=1)
    try:
        with open(path, encoding="utf-8") as fh:
            rows = json.load(fh)
    except (OSError, json.JSONDecodeError) as exc:
        raise UsageError(f"cannot read benchmark rows from {path!r}: {exc}") from None
    if not isinstance(rows, list) or not all(
        isinstance(r, dict) and {"n", "method", "seconds_per_query"} <= r.keys() for r in rows
    ):
        raise UsageError(f"{path!r} is not the output of `bderiv bench --json`")
    return rows


# -- export -----------------------------------------------------------------------------------


def _cmd_export(args) -> int:
    from .triangulation import load_triangulation

    example = args.example or ("chair" if have_models() else "corners")
    _, bd = load_example(example, args.n, args.extended)
    if not bd.full_rank:
        raise UsageError(
            f"{example} has {bd.n_events} events on surfaces of rank "
            f"{np.linalg.matrix_rank(bd.Dh)} < n: its B-derivative has no triangulation "
            f"(it is still evaluated exactly by BDerivative)"
        )
    if math.factorial(bd.n_events) > args.max_pieces:
        raise UsageError(
            f"{bd.n_events} events give 2 * {bd.n_events}! simplices, more than 2 * "
            f"--max-pieces={args.max_pieces}"
        )
    tri = bd.triangulation(max_pieces=args.max_pieces)
    base = args.out
    for ext in (".npz", ".json"):
        if base.endswith(ext):
            base = base[: -len(ext)]
    formats = ("npz", "json") if args.format == "both" else (args.format,)
    parent = os.path.dirname(os.path.abspath(base))
    if not os.path.isdir(parent):
        raise UsageError(f"output directory {parent!r} does not exist")
    rng = np.random.default_rng(0)
    V = rng.standard_normal((200, bd.dim))
    expected = bd(V)
    files = []
    for fmt in formats:
        path = tri.save(f"{base}.{fmt}")
        err = float(np.abs(load_triangulation(path)(V) - expected).max())
        files.append({"path": path, "format": fmt, "bytes": os.path.getsize(path),
                      "max_error_reloaded": err})
    summary = {"example": example, "n_events": tri.n_events, "dim": tri.dim,
               "vertices": tri.pre.shape[0], "simplices": tri.simplices.shape[0],
               "files": files}
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"bderiv export: {example}: {tri!r}")
        print("  pre-event vertices (n_vertices, d), post-event images, simplices "
              "(n_simplices, n + 1; column 0 the apex), kernel basis of Dh")
        for f in files:
            print(f"  wrote {f['path']} ({f['bytes']:,} bytes); reloaded with "
                  f"bderiv.load_triangulation: max |tri(V) - bd(V)| = "
                  f"{f['max_error_reloaded']:.2e} on 200 vectors")
    return 0


# -- parser -----------------------------------------------------------------------------------


def _positive_int(text):
    try:
        value = int(text.replace("_", ""))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return value


def _nonneg_int(text):
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}")
    return value


def _positive_float(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return value


def _add_example_args(p, default_help):
    p.add_argument("--example", choices=MODEL_EXAMPLES + TABLE_EXAMPLES,
                   help=f"the system (default: {default_help})")
    p.add_argument("--n", type=_positive_int, default=None,
                   help=f"number of events of --example network (1..{NETWORK_MAX_N}, "
                   f"default 3)")
    p.add_argument("--extended", action="store_true",
                   help="network variant with d = 2n instead of d = n")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``bderiv`` (one-line errors, exit status 2).

    Examples
    --------
    >>> args = build_parser().parse_args(["demo", "--example", "network", "--n", "4"])
    >>> args.command, args.example, args.n, args.batch
    ('demo', 'network', 4, 1000000)
    """
    parser = _Parser(
        prog="bderiv",
        description="Exact, fast Bouligand derivatives of piecewise-differentiable flows at "
        "points where several events happen at once. With no command: demo. Also "
        "`python -m bderiv`.",
    )
    from . import __version__

    parser.add_argument("--version", action="version", version=f"bderiv {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="{demo,bench,plot,export}")

    p = sub.add_parser("demo", help="the B-derivative of a built-in model, checked against "
                       "simulation (default command)")
    _add_example_args(p, "chair; corners without the models")
    p.add_argument("--batch", type=_positive_int, default=1_000_000,
                   help="tangent vectors in the timed batch (default 1000000)")
    p.add_argument("--check", type=_nonneg_int, default=8,
                   help="vectors checked against finite differences (default 8, 0 = none)")
    p.add_argument("--eps", type=_positive_float, nargs="+", default=[1e-4, 1e-5, 1e-6],
                   help="finite-difference steps (default 1e-4 1e-5 1e-6)")
    p.add_argument("--seed", type=_nonneg_int, default=0, help="random seed (default 0)")
    p.add_argument("--json", action="store_true", help="print one JSON document")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")

    p = sub.add_parser("bench", help="dimension sweep against the baselines")
    p.add_argument("--n", type=_positive_int, nargs="+", default=[2, 4, 8, 12, 16],
                   help="numbers of events (default 2 4 8 12 16)")
    p.add_argument("--d-factor", type=int, choices=(1, 2), default=1,
                   help="dimension d = d_factor * n (default 1)")
    p.add_argument("--batch", type=_positive_int, default=100_000,
                   help="queries per batch (default 100000)")
    p.add_argument("--repeat", type=_positive_int, default=3, help="timed runs, best kept")
    p.add_argument("--plot", metavar="FILE", help="also save the log-log plot (.png/.pdf)")
    p.add_argument("--json", action="store_true", help="print the rows as JSON")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")

    p = sub.add_parser("plot", help="figures to PNG/PDF files")
    _add_example_args(p, "network --n 2; planar without the models")
    p.add_argument("--figure", nargs="+", choices=(*FIGURES, "all"),
                   help="which figures (default all that apply)")
    p.add_argument("--out", default="bderiv-figures", help="output directory")
    p.add_argument("--format", choices=("png", "pdf", "svg"), default="png")
    p.add_argument("--dpi", type=_positive_int, default=120)
    p.add_argument("--bench-json", metavar="FILE",
                   help="rows of `bderiv bench --json` for the scaling figure")
    p.add_argument("--json", action="store_true", help="print the files written as JSON")

    p = sub.add_parser("export", help="the triangulation to .npz and .json")
    _add_example_args(p, "chair; corners without the models")
    p.add_argument("--out", default="triangulation",
                   help="output path without suffix (default ./triangulation)")
    p.add_argument("--format", choices=("npz", "json", "both"), default="both")
    p.add_argument("--max-pieces", type=_positive_int, default=40320,
                   help="refuse more than this many event orders (default 8! = 40320)")
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    return parser


_COMMANDS = {"demo": _cmd_demo, "bench": _cmd_bench, "plot": _cmd_plot, "export": _cmd_export}


def main(argv=None) -> int:
    """Entry point of ``bderiv`` and ``python -m bderiv``; returns the exit status.

    Parameters
    ----------
    argv : list of str, optional
        The arguments (default: ``sys.argv[1:]``); no command means ``demo``.

    Returns
    -------
    int
        0 on success, 2 on a bad argument (after a one-line message on stderr).

    Examples
    --------
    >>> main(["export", "--example", "corners", "--out", "/nonexistent/dir/tri"])
    2
    >>> main(["demo", "--example", "corners", "--batch", "100"])  # doctest: +ELLIPSIS
    bderiv demo: corner table (3 events in R^3), Dh = event Jacobian, F = corner table
    vector u -> event order, event times, M(u):
      u=[-1. -2. -3.]  order=[0, 2, 1]  times=[1.  3.  3.8]  M(u)=[-2.9 -3.8 -6.8]
    ...
    0
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        args = parser.parse_args(["demo"])
    try:
        return _COMMANDS[args.command](args)
    except (UsageError, ImportError) as exc:
        print(f"bderiv {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except (ValueError, TypeError, OSError) as exc:
        if os.environ.get("BDERIV_DEBUG"):
            raise
        msg = " ".join(str(exc).split())
        print(f"bderiv {args.command}: error: {type(exc).__name__}: {msg} (set "
              f"BDERIV_DEBUG=1 for the traceback)", file=sys.stderr)
        return 2
