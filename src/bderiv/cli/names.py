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
