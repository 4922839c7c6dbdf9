"""The systems the commands run on: built-in models and corner tables, by name."""

from __future__ import annotations

from .. import examples
from ..bderivative import BDerivative
from .usage import UsageError

#: examples that need no model (corner tables only)
TABLE_EXAMPLES = ("corners", "planar")
#: examples from :mod:`bderiv.examples` (nonlinear models)
MODEL_EXAMPLES = ("chair", "network", "table")
#: examples whose demo is a summary of their own (``demo`` only): a gait's periodic orbit
#: and stability verdict, an impact with resets checked against simulation
GAIT_EXAMPLES = ("pronking", "landing")
#: gait examples with a periodic orbit (``plot``'s figures orbit and growth), with the
#: names of their state components
ORBIT_EXAMPLES = {"pronking": ("z", "theta", "vz", "omega")}
#: largest n of the scalable network family the CLI accepts
NETWORK_MAX_N = 20


def _network_options_only(name: str, n: int | None, extended: bool) -> None:
    """Refuse ``--n`` and ``--extended`` for an example other than ``network``."""
    if n is not None and name != "network":
        raise UsageError(f"--n applies to --example network only, not to {name!r}")
    if extended and name != "network":
        raise UsageError(f"--extended applies to --example network only, not to {name!r}")


def load_example(name: str, n: int | None = None, extended: bool = False):
    """The example ``name`` and the B-derivative at its event point.

    Parameters
    ----------
    name : str
        One of :data:`MODEL_EXAMPLES` or :data:`TABLE_EXAMPLES`.
    n : int, optional
        Number of events of ``network`` (default 3); refused for the other examples.
    extended : bool
        The ``network`` variant with d = 2n; refused for the other examples.

    Returns
    -------
    example : Example or None
        None for the corner tables ``corners`` and ``planar``, which have no model.
    bd : BDerivative

    Examples
    --------
    >>> ex, bd = load_example("corners")
    >>> ex is None, bd.n_events, bd.dim
    (True, 3, 3)
    """
    _network_options_only(name, n, extended)
    if name == "corners":
        return None, BDerivative(*examples.three_event_table())
    if name == "planar":
        return None, BDerivative(*examples.planar_table())
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


def load_orbit(name: str, n: int | None = None, extended: bool = False):
    """The gait example ``name`` and its periodic orbit, found as ``bderiv demo`` finds it.

    Parameters
    ----------
    name : str
        One of :data:`ORBIT_EXAMPLES`.
    n, extended
        Refused (options of ``network``), as in :func:`load_example`.

    Returns
    -------
    example : Example
    orbit : PeriodicOrbit
        By Newton's method from a perturbed apex state
        (:func:`bderiv.examples.gaits.pronking_orbit`, the demo's orbit).
    """
    _network_options_only(name, n, extended)
    if name not in ORBIT_EXAMPLES:
        raise UsageError(f"{name!r} has no periodic orbit; the gaits are "
                         f"{', '.join(ORBIT_EXAMPLES)}")
    ex = examples.gaits.pronking()
    return ex, examples.gaits.pronking_orbit(ex)
