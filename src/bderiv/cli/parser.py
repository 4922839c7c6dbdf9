"""The argument parser of ``bderiv`` and the dispatch of each command.

Each command runs its computation (:mod:`.demo`, :mod:`.bench`, :mod:`.figures`,
:mod:`.export`), which returns data, and prints the data's rendering (:mod:`.render`) as
text or JSON. Bad arguments, found by argparse or by the computations
(:class:`~bderiv.cli.usage.UsageError`), give one line on stderr and exit status 2; any
other exception is a bug or a failure of the machine and propagates with its traceback.
"""

from __future__ import annotations

import argparse
import os
import sys

from .._limits import (
    BENCH_BATCH,
    BENCH_NS,
    BENCH_REPEAT,
    DEMO_BATCH,
    DEMO_CHECK,
    EPS_RANGE,
    FD_EPS,
    NETWORK_MAX_N,
)
from .._support._policy import policy
from . import render
from ._types import dpi, eps_step, nonneg_int, positive_int
from .names import (
    COMPILED_EXAMPLES,
    DECAY_STRIDES,
    DEFAULT_OUT,
    FIGURES,
    GAIT_EXAMPLES,
    GAIT_FIGURES,
    GAIT_HELP,
    GAIT_WORK,
    IMPACT_EXAMPLES,
    MIN_DPI,
    MODEL_EXAMPLES,
    ORBIT_EXAMPLES,
    TABLE_EXAMPLES,
    check_demo_options,
    check_example_options,
    demo_dim,
)
from .usage import UsageError, require_demo_memory, require_robot_files
from .warmup import FAMILIES

# the commands' computations (numba, scipy, the kernels) are imported by the command that
# runs, so that the parser, --help and the demo's first line come before them


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors, ``bderiv demo: error: ...`` (the command's name, as
    for the errors found after parsing), and exit status 2."""

    def error(self, message):  # noqa: D401 - argparse API
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _add_example_args(p, default_help, gaits=()):
    p.add_argument("--example", choices=MODEL_EXAMPLES + TABLE_EXAMPLES + tuple(gaits),
                   help=f"the system (default: {default_help}): the models "
                   f"{', '.join(MODEL_EXAMPLES)} or the corner tables "
                   f"{' and '.join(TABLE_EXAMPLES)} (no model, so no flow map; planar: 2 "
                   f"events in the plane)"
                   + "".join(f"; {GAIT_HELP[g]}" for g in gaits))
    p.add_argument("--n", type=positive_int, default=None,
                   help=f"number of events of --example network (1..{NETWORK_MAX_N}, "
                   f"default 3); --n alone means --example network")
    p.add_argument("--extended", action="store_true",
                   help="network variant with d = 2n instead of d = n")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``bderiv`` (one-line errors, exit status 2).

    Function of ~70 lines: one block of ``add_argument`` calls per command, read as the
    command line's reference.

    Examples
    --------
    >>> args = build_parser().parse_args(["demo", "--example", "network", "--n", "4"])
    >>> args.command, args.example, args.n, args.batch  # None: the option left out
    ('demo', 'network', 4, None)
    """
    from .. import __version__

    parser = _Parser(
        prog="bderiv",
        description="Exact, fast Bouligand derivatives of piecewise-differentiable flows at "
        "points where several events happen at once. With no command: demo. Also "
        "`python -m bderiv`.",
    )
    parser.add_argument("--version", action="version", version=f"bderiv {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="{demo,bench,plot,export,compile}")

    p = sub.add_parser("demo", help="the B-derivative of a built-in model, checked against "
                       "simulation (default command)")
    _add_example_args(p, "chair", GAIT_EXAMPLES)
    # --batch, --check, --eps: None when left out (an example that ignores one refuses it)
    p.add_argument("--batch", type=positive_int,
                   help=f"tangent vectors in the timed batch (default {DEMO_BATCH})")
    p.add_argument("--check", type=nonneg_int,
                   help=f"vectors checked against finite differences (default {DEMO_CHECK}, "
                   f"0 = none)")
    p.add_argument("--eps", type=eps_step, nargs="+",
                   help=f"finite-difference steps, largest first, each between "
                   f"{EPS_RANGE[0]:g} and {EPS_RANGE[1]:g} (default "
                   f"{' '.join(f'{e:.0e}' for e in FD_EPS)})")
    p.add_argument("--seed", type=nonneg_int, default=0, help="random seed (default 0)")
    p.add_argument("--full", action="store_true",
                   help="also print the matrices: the pieces listed, each group's Dh and "
                   "corner table F, the flow map's linear stages")
    p.add_argument("--json", action="store_true", help="print one JSON document")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.add_argument("--python", action="store_true",
                   help=f"the example's Python functions on scipy's solve_ivp instead of its "
                   f"numba-compiled ones on the compiled integrator (the default for "
                   f"{', '.join(COMPILED_EXAMPLES)}; the same equations)")

    p = sub.add_parser("bench", help="dimension sweep against the baselines")
    p.add_argument("--n", type=positive_int, nargs="+", default=list(BENCH_NS),
                   help=f"numbers of events (default {' '.join(map(str, BENCH_NS))})")
    p.add_argument("--d-factor", type=int, choices=(1, 2), default=1,
                   help="dimension d = d_factor * n (default 1)")
    p.add_argument("--batch", type=positive_int, default=BENCH_BATCH,
                   help=f"queries per batch (default {BENCH_BATCH})")
    p.add_argument("--repeat", type=positive_int, default=BENCH_REPEAT,
                   help="timed runs, best kept")
    p.add_argument("--plot", metavar="FILE",
                   help="also save the log-log plot (.png, .pdf or .svg; its directory is "
                   "made if missing)")
    p.add_argument("--json", action="store_true", help="print the rows as JSON")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")

    p = sub.add_parser("plot", help="figures to PNG, PDF or SVG files")
    _add_example_args(p, "planar", (*ORBIT_EXAMPLES, *IMPACT_EXAMPLES))
    p.add_argument("--figure", nargs="+", choices=(*FIGURES, "all"), metavar="NAME",
                   help=f"which figures, among {', '.join(FIGURES)}, all (default: all that "
                   "apply to the system; scaling only with --bench-json). note: the "
                   "triangulation carried through the corner-limit flow, in state and "
                   f"impact-time coordinates. {' and '.join(GAIT_FIGURES)} (--example "
                   f"{', '.join(ORBIT_EXAMPLES)} only): the gait's periodic orbit with its "
                   "event groups, and the growth of perturbations through the return map "
                   "against simulated strides (a few seconds, as long as `bderiv demo --example "
                   f"pronking`: the orbit is found by Newton's method and {DECAY_STRIDES} "
                   "strides simulated)")
    p.add_argument("--out", default=None,
                   help=f"output directory, made if missing (default ./{DEFAULT_OUT}/EXAMPLE:"
                   f" one folder per example); files of the same name are replaced, and "
                   f"the output says which")
    p.add_argument("--format", choices=("png", "pdf", "svg"), default="png",
                   help="file format (default png)")
    p.add_argument("--dpi", type=dpi, default=120,
                   help=f"resolution of png files (default 120, at least {MIN_DPI})")
    p.add_argument("--bench-json", metavar="FILE",
                   help="rows of `bderiv bench --json` (a file) for the scaling figure")
    p.add_argument("--json", action="store_true", help="print the files written as JSON")

    p = sub.add_parser("export", help="the triangulation to .npz and .json")
    _add_example_args(p, "chair", IMPACT_EXAMPLES)
    p.add_argument("--map", choices=("event", "flow"), default="event",
                   help="event (default): the B-derivative at the event point; flow: the "
                   "B-derivative of the flow from x0 over [0, t_final] (models with one "
                   "event group)")
    p.add_argument("--out", default="triangulation",
                   help="output path without suffix (default ./triangulation); its directory "
                   "is made if missing, and the output says which files it replaced")
    p.add_argument("--format", choices=("npz", "json", "both"), default="both",
                   help="file format (default both)")
    p.add_argument("--max-pieces", type=positive_int, default=40320,
                   help="refuse more than this many event orders (default 8! = 40320)")
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    p = sub.add_parser("compile", help="compile the kernels into numba's disk cache ahead "
                       "of their first use (a Docker image, CI, a new Dask worker)")
    p.add_argument("families", nargs="*", default=[], metavar="FAMILY",
                   help=f"some of {', '.join(FAMILIES)} (default: all)")
    p.add_argument("--processes", type=positive_int, default=None,
                   help="families compiled at once (default: the cores this process may use)")
    p.add_argument("--no-progress", action="store_true", help="no progress lines")
    p.add_argument("--here", action="store_true", help=argparse.SUPPRESS)  # one family, here
    p.add_argument("--nice", action="store_true", help=argparse.SUPPRESS)  # in the background

    parser.commands = sub.choices  # each command's parser, for its own error messages
    return parser


def _demo(args) -> str | None:
    example = args.example
    if example is None:
        example = "network" if args.n is not None or args.extended else "chair"
    check_demo_options(example, {"--batch": args.batch, "--check": args.check,
                                 "--eps": args.eps, "--full": args.full or None,
                                 "--python": args.python or None})
    if example in GAIT_EXAMPLES:
        return _gait_demo(args)

    def show(section, res):  # the text streams while the demo runs
        print(render.demo_section(section, res), end="", flush=True)

    check_example_options(example, args.n, args.extended)
    batch = DEMO_BATCH if args.batch is None else args.batch
    check = DEMO_CHECK if args.check is None else args.check
    require_demo_memory(batch, check, demo_dim(example, args.n, args.extended))
    if example in MODEL_EXAMPLES and not args.json:  # before the computations load
        print(f"bderiv demo: {example}", flush=True)
    progress = None if args.no_progress else render.progress_bar("finite differences")
    from .demo import run_demo

    res = run_demo(example, args.n, args.extended, batch, check, tuple(args.eps or FD_EPS),
                   args.seed, args.full, progress=progress,
                   report=show if not args.json else None, compiled=not args.python)
    return render.to_json(res, indent=1) if args.json else None


def _gait_demo(args) -> str:
    """``demo --example pronking``: from the model to a stability verdict, checked against
    simulation (:func:`bderiv.examples.gaits.pronking_summary`); ``--example landing``: a
    simultaneous impact with resets (:func:`bderiv.examples.impacts.landing_summary`);
    ``--example rimless-wheel`` or ``compass-gait``: a walker's gait through leg swaps
    (:func:`bderiv.examples.walker_report.walker_summary`); ``--example quadruped``: a model from
    equations to its stability verdict (:func:`bderiv.examples.quadruped.quadruped_summary`);
    ``--example solo12``: a robot from its URDF (:func:`bderiv.robots.demo.solo12_summary`)."""
    if args.n is not None or args.extended:
        raise UsageError(f"--n and --extended are options of --example network, not "
                         f"{args.example}")
    if args.example == "solo12":
        require_robot_files("--example solo12")
    print(f"bderiv demo: {args.example}: {GAIT_WORK[args.example]} (the summary prints "
          f"when it is done)", file=sys.stderr, flush=True)
    from ..examples import gaits, impacts, walker_report

    if args.example == "solo12":
        from ..robots import demo

        res = demo.solo12_summary(seed=args.seed, **_steps(args))
        return render.to_json(res, indent=1) if args.json else demo.summary_text(res)
    if args.example == "quadruped":
        from ..examples import quadruped

        res = quadruped.quadruped_summary(seed=args.seed)
        return render.to_json(res, indent=1) if args.json else quadruped.summary_text(res)
    if args.example in ("rimless-wheel", "compass-gait"):
        res = walker_report.walker_summary(args.example, seed=args.seed)
        return render.to_json(res, indent=1) if args.json else walker_report.summary_text(res)
    module, run = ((impacts, impacts.landing_summary) if args.example == "landing"
                   else (gaits, gaits.pronking_summary))
    res = run(seed=args.seed, compiled=not args.python, **_steps(args))
    return render.to_json(res, indent=1) if args.json else module.summary_text(res)


def _steps(args) -> dict:
    """``--eps`` as a summary's keyword: the steps of its check against finite
    differences (none given: the summary's own)."""
    return {} if args.eps is None else {"eps": tuple(args.eps)}


def _bench(args) -> str:
    progress = None if args.no_progress else render.progress_bar("bench", unit="size")
    from .bench import run_bench

    result = run_bench(args.n, d_factor=args.d_factor, batch=args.batch, repeat=args.repeat,
                       plot=args.plot, progress=progress)
    if args.json:
        return render.to_json(result, indent=1)
    return render.bench_text(result)


def _plot(args) -> str:
    def say(text):  # on stderr: stdout is the summary (or its JSON)
        print(f"bderiv plot: {text}", file=sys.stderr, flush=True)

    from .figures import run_figures

    summary = run_figures(args.example, args.n, args.extended, args.figure, args.out,
                          args.format, args.dpi, args.bench_json, report=say)
    return render.to_json(summary) if args.json else render.figures_text(summary)


def _export(args) -> str:
    from .export import run_export

    summary = run_export(args.example, args.n, args.extended, args.out, args.format,
                         args.max_pieces, args.map)
    return render.to_json(summary) if args.json else render.export_text(summary)


def _compile(args) -> str | None:
    unknown = [name for name in args.families if name not in FAMILIES]
    if unknown:
        raise UsageError(f"unknown family {unknown[0]!r}: the families are "
                         f"{', '.join(FAMILIES)}")
    if args.here and not args.families or args.nice and not args.here:  # internal flags
        raise UsageError("--here takes the families to compile in this process, and "
                         "--nice goes with --here")
    from .warmup import compile_here, warm_up

    if args.here:  # the process of one family (warm_up starts it; --nice: in the background)
        compile_here(args.families, nice=args.nice)
        return None  # its lines printed as it went

    def say(text):  # on stderr: stdout is the summary
        print(f"bderiv compile: {text}", file=sys.stderr, flush=True)

    seconds = warm_up(args.families or FAMILIES, args.processes,
                      None if args.no_progress else say)
    return "".join(f"{name:<12} {t:7.1f} s\n" for name, t in seconds.items())


#: each command: ``args -> text to print`` (None when the text was streamed already)
_COMMANDS = {"demo": _demo, "bench": _bench, "plot": _plot, "export": _export,
             "compile": _compile}


def _refuse_negative_eps(argv, parser) -> None:
    """argparse reads ``--eps -1e-4`` as an option named ``-1e-4`` and says "expected at
    least one argument"; say what is wrong instead."""
    for i, arg in enumerate(argv[1:], 1):
        if argv[i - 1] == "--eps" and arg[:1] == "-" and arg[1:2].isdigit():
            parser.commands[argv[0] if argv[0] in parser.commands else "demo"].error(
                f"argument --eps: the steps must be positive, got {arg!r}")


def _check_environment() -> None:
    """A bad ``BDERIV_INTEGRATOR`` is every command's usage error, said before it runs (it
    came as a traceback from a compiled model's first run, or not at all where the
    integrator was in the cache)."""
    try:
        policy()
    except ValueError as exc:
        raise UsageError(str(exc)) from None


def main(argv=None) -> int:
    """Entry point of ``bderiv`` and ``python -m bderiv``; returns the exit status.

    Parameters
    ----------
    argv : list of str, optional
        The arguments (default: ``sys.argv[1:]``); no command means ``demo``.

    Returns
    -------
    int
        0 on success, 2 on a bad argument (after a one-line message on stderr), 130 after
        Ctrl-C (a line saying so). Any other error propagates (a traceback, exit status
        1).

    Examples
    --------
    >>> main(["export", "--example", "corners", "--out", "/proc/dir/tri"])  # not writable
    2
    >>> main(["demo", "--example", "corners", "--batch", "100"])  # doctest: +ELLIPSIS
    bderiv demo: corners, corner table without a model, 3 events in R^3
    ...
    vector u -> event order, event times (in that order), M(u):
      u = [-1, -2, -3]  order (0,2,1)  times [1, 3, 3.8]  M(u) = [-2.9, -3.8, -6.8]
    ...
    0
    """
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0].startswith("-") and argv[0] not in ("-h", "--help", "--version"):
        argv.insert(0, "demo")  # options without a command are the demo's
    _refuse_negative_eps(argv, parser)
    args, extra = parser.parse_known_args(argv)
    if args.command is None:
        args, extra = parser.parse_known_args(["demo", *extra])
    if extra:  # reported by the command's parser, with the command's name
        parser.commands[args.command].error(f"unrecognized arguments: {' '.join(extra)}")
    try:
        _check_environment()
        text = _COMMANDS[args.command](args)
        if text is not None:
            print(text, end="" if text.endswith("\n") else "\n", flush=True)
    except UsageError as exc:
        print(f"bderiv {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # the reader went away (`bderiv demo | head`): stop quietly
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1
    except KeyboardInterrupt:  # Ctrl-C: a line, not a traceback; the shell's status
        print(f"\nbderiv {args.command}: interrupted", file=sys.stderr, flush=True)
        return 130
    return 0
