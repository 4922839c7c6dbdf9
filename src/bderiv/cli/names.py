"""The names the command line offers: examples, figures and their defaults.

Kept apart from the commands' computations so that the argument parser, and ``--help``,
load none of them (``python -m bderiv`` answers before numba and the kernels load).
"""

from __future__ import annotations

from .._limits import NETWORK_MAX_N
from .usage import UsageError

#: examples that need no model (corner tables only)
TABLE_EXAMPLES = ("corners", "planar")
#: examples from :mod:`bderiv.examples` (nonlinear models)
MODEL_EXAMPLES = ("chair", "network", "table")
#: examples whose demo is a summary of their own (``demo`` only): a gait's periodic orbit
#: and stability verdict, an impact with resets checked against simulation, a passive
#: walker's gait through leg swaps beside its reference numbers
GAIT_EXAMPLES = ("pronking", "landing", "rimless-wheel", "compass-gait", "quadruped",
                 "solo12")
#: gait examples with a periodic orbit (``plot``'s figures orbit and growth), with what
#: the orbit figure names: the state components and time with their units, the phases
#: (regions by mask)
ORBIT_EXAMPLES = {"pronking": {
    "labels": ("height $z$ (m)", "pitch $\\theta$ (rad)", "vertical velocity $v_z$ (m/s)",
               "pitch rate $\\omega$ (rad/s)"),
    "time_label": "time (s)",
    "phases": {3: "stance: both feet on the ground"},
}}
#: the examples beyond the models and the corner tables, in the help of ``--example``
GAIT_HELP = {"pronking": "the gait pronking (a periodic orbit and its stability)",
             "landing": "the impact landing (resets at a simultaneous touchdown)",
             "rimless-wheel": "the rimless wheel's gait (a leg swap every step, against "
                              "its closed forms)",
             "compass-gait": "the compass gait (leg swaps; against Garcia et al. 1998)",
             "ball-in-corner": "a ball bouncing off two walls at once (resets that send "
                               "the state back)",
             "quadruped": "a planar quadruped pronking, built from its equations "
                          "(bderiv.symbolic.contact_system; sympy)",
             "solo12": "Solo12's four-foot touchdown from its URDF (bderiv.robots; "
                       "Pinocchio)"}
#: what the demo of each of :data:`GAIT_EXAMPLES` computes, said on stderr as it starts
#: (its summary prints at the end: seconds, more where a machine compiles it first)
GAIT_WORK = {"pronking": "the orbit by Newton's method, the return map's pieces and growth "
                         "rate, and their checks against simulated strides",
             "landing": "the double touchdown with its resets, its B-derivative and the "
                        "check against simulation",
             "rimless-wheel": "the walker's gait by Newton's method and its stability",
             "compass-gait": "the walker's gait by Newton's method and its stability",
             "quadruped": "the model from its equations, its orbit and stability",
             "solo12": "the robot from its URDF, its four-foot touchdown and the "
                       "B-derivative there"}
#: impact examples (models with resets) whose B-derivative at the event point ``plot`` and
#: ``export`` take as they take the models'
IMPACT_EXAMPLES = ("landing", "ball-in-corner")
#: examples with a compiled version (``compiled=True``: numba functions on the compiled
#: integrator, the same equations as the Python version)
COMPILED_EXAMPLES = ("chair", "network", "pronking", "landing")

#: figures that draw the plane (need d = 2); ``note`` also needs n = 2
FIGURES_2D = ("field", "triangulation", "circle", "note")
#: figures of a gait's periodic orbit (the examples of :data:`ORBIT_EXAMPLES`)
GAIT_FIGURES = ("orbit", "growth")
#: every figure, by its file name
FIGURES = (*FIGURES_2D, "pieces", "scaling", *GAIT_FIGURES)
#: the smallest ``--dpi`` of ``plot``: at 6 dpi and below matplotlib's Agg fails on the
#: figures' smallest text (7 pt, under 0.6 pixel: FreeType's "invalid ppem value"), at 7 it
#: draws them all (measured, matplotlib 3.11); 10, a margin: that text about a pixel high
MIN_DPI = 10
#: the smallest height in pixels of a figure's text (its size in points times dpi / 72)
#: ``plot`` accepts: the smallest text of the figures at :data:`MIN_DPI` (0.97), with
#: room above the failures measured (0.58 and below)
MIN_TEXT_PIXELS = 0.9
#: the default output directory: one folder per example inside it, so that the figures of
#: one example do not replace another's
DEFAULT_OUT = "bderiv-figures"
#: simulated strides of the growth figure's decay check (the iterations it shows), and the
#: directions and size of its perturbations
DECAY_STRIDES, DECAY_DIRECTIONS, DECAY_EPS = 40, 4, 1e-3


def check_example_options(name: str, n: int | None, extended: bool) -> None:
    """Refuse ``--n`` and ``--extended`` for an example other than ``network``, and an
    ``--n`` out of its range (before anything is loaded)."""
    if n is not None and name != "network":
        raise UsageError(f"--n applies to --example network only, not to {name!r}")
    if extended and name != "network":
        raise UsageError(f"--extended applies to --example network only, not to {name!r}")
    if n is not None and not 1 <= n <= NETWORK_MAX_N:
        raise UsageError(f"--n must be between 1 and {NETWORK_MAX_N}, got {n}")


#: summaries whose check against finite differences takes its steps from ``--eps`` (the
#: walkers' and the quadruped's summaries have no such check)
FD_SUMMARIES = ("pronking", "landing", "solo12")
#: the dimension d of the examples whose demo times a batch (``network``: n, 2n extended),
#: known before they load, so that a batch too large is refused before the demo's first line
DEMO_DIMS = {"chair": 6, "table": 12, "corners": 3, "planar": 2}
#: the demo's options that only some examples use, with those examples (--seed, --json and
#: --no-progress apply to all: without a progress bar, --no-progress asks for nothing)
DEMO_OPTIONS = {"--batch": (*MODEL_EXAMPLES, *TABLE_EXAMPLES), "--check": MODEL_EXAMPLES,
                "--eps": (*MODEL_EXAMPLES, *FD_SUMMARIES),
                "--full": (*MODEL_EXAMPLES, *TABLE_EXAMPLES), "--python": COMPILED_EXAMPLES}


def demo_dim(name: str, n: int | None, extended: bool) -> int:
    """The dimension d of ``name``'s batch (:data:`DEMO_DIMS`), without loading it."""
    if name == "network":
        return (3 if n is None else n) * (2 if extended else 1)
    return DEMO_DIMS[name]


def check_demo_options(name: str, given: dict) -> None:
    """Refuse, before anything is loaded, the options of ``demo`` that the example ``name``
    ignores (:data:`DEMO_OPTIONS`; ``given``: each option to its value, None when left
    out), ``--eps`` with ``--check 0``, and steps that do not decrease.

    Examples
    --------
    >>> check_demo_options("corners", {"--check": 5, "--eps": [1e-3]})  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    bderiv.cli.usage.UsageError: --check and --eps mean nothing for --example corners, ...
    """
    if given.get("--python") is not None and name not in COMPILED_EXAMPLES:
        raise UsageError(f"--python chooses the Python functions of an example that has "
                         f"numba-compiled ones ({', '.join(COMPILED_EXAMPLES)}); {name} "
                         f"has no compiled version, so it means nothing there")
    ignored = [opt for opt, users in DEMO_OPTIONS.items()
               if given.get(opt) is not None and name not in users]
    if ignored:
        takes = [opt for opt, users in DEMO_OPTIONS.items() if name in users]
        kind = (", a corner table without a model (nothing simulated, so no check against "
                "finite differences)" if name in TABLE_EXAMPLES else
                ", whose demo is a summary of its own" if name in GAIT_EXAMPLES else "")
        listed = " and ".join(filter(None, (", ".join(ignored[:-1]), ignored[-1])))
        raise UsageError(f"{listed} mean{'s' * (len(ignored) == 1)} nothing for --example "
                         f"{name}{kind}; it takes {', '.join([*takes, '--seed'])} and "
                         f"--json")
    eps = given.get("--eps") or []
    if eps and given.get("--check") == 0:
        raise UsageError("--eps sets the steps of the check against finite differences, "
                         "which --check 0 leaves out, so it means nothing there")
    for i in range(1, len(eps)):
        if not eps[i] < eps[i - 1]:
            raise UsageError(f"--eps: the steps must decrease, largest first (the check says "
                             f"how much the error shrinks from each step to the next), got "
                             f"{eps[i]:g} after {eps[i - 1]:g}")
