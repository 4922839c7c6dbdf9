"""The systems the commands run on: built-in models and corner tables, by name."""

from __future__ import annotations

import numpy as np

from .. import examples
from .._limits import RANDOM_ROWS
from ..engine.bderivative import BDerivative
from .names import (
    COMPILED_EXAMPLES,
    ORBIT_EXAMPLES,
    check_example_options,  # noqa: F401  (re-exported: the commands' names live in .names)
)
from .usage import UsageError


def load_example(name: str, n: int | None = None, extended: bool = False,
                 compiled: bool = False):
    """The example ``name`` and the B-derivative at its event point.

    Parameters
    ----------
    name : str
        One of :data:`MODEL_EXAMPLES`, :data:`TABLE_EXAMPLES` or :data:`IMPACT_EXAMPLES`.
    n : int, optional
        Number of events of ``network`` (default 3); refused for the other examples.
    extended : bool
        The ``network`` variant with d = 2n; refused for the other examples.
    compiled : bool
        The compiled version of the examples of :data:`COMPILED_EXAMPLES` (the others
        have none: their Python version).

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
    check_example_options(name, n, extended)
    if name == "corners":
        return None, BDerivative(*examples.three_event_table())
    if name == "planar":
        return None, BDerivative(*examples.planar_table())
    compiled = compiled and name in COMPILED_EXAMPLES
    if name == "chair":
        ex = examples.chair(compiled=compiled)
    elif name == "table":
        ex = examples.table()
    elif name == "landing":
        ex = examples.impacts.landing(compiled=compiled)
    elif name == "ball-in-corner":
        ex = examples.ball_in_corner()
    else:
        ex = examples.network(3 if n is None else n, extended=extended, compiled=compiled)
    return ex, ex.system.bderivative(ex.rho)


def refuse_without_triangulation(name: str, bd) -> None:
    """A usage error if the resets of ``bd`` (the example ``name``) make it no
    homeomorphism, so that it has no triangulation (docs/mathematics.md section 9): a
    singular reset, such as an impact that stops a velocity, forgets a direction."""
    if bd.resets is None:
        return
    try:
        bd.inverse(np.zeros((1, bd.dim)))  # builds the inverse resets: refuses singular ones
    except ValueError as exc:
        raise UsageError(f"{name} has no triangulation (nor has its flow map, which "
                         f"contains the same resets): {exc}") from None


def load_orbit(name: str, n: int | None = None, extended: bool = False, model=None):
    """The gait example ``name`` and its periodic orbit, found as ``bderiv demo`` finds it.

    Parameters
    ----------
    name : str
        One of :data:`ORBIT_EXAMPLES`.
    n, extended
        Refused (options of ``network``), as in :func:`load_example`.
    model : Example, optional
        The gait's model from :func:`load_gait` (built here if not given).

    Returns
    -------
    example : Example
    orbit : PeriodicOrbit
        By Newton's method from a perturbed apex state
        (:func:`bderiv.examples.gaits.pronking_orbit`, the demo's orbit).
    """
    ex = load_gait(name, n, extended) if model is None else model
    return ex, examples.gaits.pronking_orbit(ex)


def load_gait(name: str, n: int | None = None, extended: bool = False):
    """The model of the gait example ``name``, without its orbit (found in seconds by
    :func:`load_orbit`): its sizes decide which figures apply before any work.

    Examples
    --------
    >>> ex = load_gait("pronking")
    >>> ex.system.n_events, ex.system.dim
    (2, 4)
    """
    check_example_options(name, n, extended)
    if name not in ORBIT_EXAMPLES:
        raise UsageError(f"{name!r} has no periodic orbit; the gaits are "
                         f"{', '.join(ORBIT_EXAMPLES)}")
    return examples.gaits.pronking()


def random_vectors(rng, rows: int, d: int) -> np.ndarray:
    """``rng.standard_normal((rows, d))`` drawn :data:`RANDOM_ROWS` rows at a time (the
    same numbers): Ctrl-C is seen between the draws (one draw of 30 million rows held it
    for 3-4 s)."""
    out = np.empty((rows, d))
    for start in range(0, rows, RANDOM_ROWS):
        stop = min(start + RANDOM_ROWS, rows)
        out[start:stop] = rng.standard_normal((stop - start, d))
    return out
