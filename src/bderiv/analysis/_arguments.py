"""Argument checks of the gait analysis (:mod:`bderiv.analysis.checks`,
:mod:`bderiv.analysis.orbit`, :mod:`bderiv.analysis.stability`,
:mod:`bderiv.analysis.stability_map`): each returns the checked value or raises a
``TypeError``/``ValueError`` naming the argument, what was expected and what came, before
any simulation."""

from __future__ import annotations

import numpy as np

from .._support._validate import check_matrix, check_number
from .._support._validate_ints import check_int

__all__ = ["check_burn_in", "check_directions", "check_iterations", "check_seed",
           "check_settings", "check_steps", "check_system"]


def check_system(system) -> None:
    """Refuse a ``system`` that is not a :class:`~bderiv.analysis.system.HybridSystem`
    (by what the analyses use of it: importing the class would close a loop, as the
    system's module imports them)."""
    if not (hasattr(system, "calls") and hasattr(system, "simulate")):
        raise TypeError(f"system must be a HybridSystem, got {type(system).__name__}")


def check_directions(V, dim: int, what: str, *, nonzero: bool = False) -> np.ndarray:
    """``V`` as a batch of ``what`` (m, dim), m >= 1 (and with ``nonzero`` no row zero):
    a float64 copy."""
    V = check_matrix(V, "V", (None, dim))
    if V.shape[0] == 0:
        raise ValueError(f"V must hold at least one {what} (shape (m, {dim}) with m >= 1), "
                         f"got shape {V.shape}")
    zero = np.flatnonzero(~np.any(V, axis=1)) if nonzero else ()
    if len(zero):
        raise ValueError(f"V must have no zero row (each row is a {what}), but row "
                         f"{int(zero[0])} is zero")
    return V


def check_steps(eps) -> tuple:
    """``eps`` of :func:`~bderiv.analysis.checks.fd_check`: one step or a non-empty 1-d
    sequence of them, each finite and > 0, as a tuple of floats."""
    try:
        steps = np.asarray(eps)
    except ValueError:  # a ragged nest of sequences
        steps = None
    if steps is None or steps.ndim > 1 or steps.size == 0:
        got = f"{eps!r}" if steps is None else f"shape {steps.shape}"
        raise ValueError(f"eps must be a step or a non-empty 1-d sequence of steps, got {got}")
    # a single step is named eps[0], as the sequence of one it stands for
    return tuple(check_number(e, f"eps[{i}]") for i, e in enumerate(steps.reshape(-1).tolist()))


def check_settings(caller: str, given, known) -> None:
    """Refuse keywords of ``given`` not in ``known`` (the settings ``caller`` takes)."""
    unknown = sorted(set(given) - set(known))
    if unknown:
        raise TypeError(f"{caller} got unknown settings {unknown}; it takes "
                        f"{', '.join(known)}")


def check_iterations(iterations) -> int:
    """Iterations of a growth-rate run: an integer >= 2 (the fit needs two)."""
    return check_int(iterations, "iterations", low=2)


def check_burn_in(burn_in, iterations: int) -> int:
    """Iterations not averaged: an integer in ``[0, iterations - 2]``; None gives
    ``iterations // 4``."""
    if burn_in is None:
        return iterations // 4
    return check_int(burn_in, "burn_in", low=0, high=iterations - 2,
                     span=f"in [0, iterations - 2 = {iterations - 2}]",
                     meaning="or None: iterations // 4")


def check_seed(seed):
    """A seed of ``numpy.random.default_rng``: an integer >= 0 (or None: fresh entropy)."""
    return None if seed is None else check_int(seed, "seed", low=0)
