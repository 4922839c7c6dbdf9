"""Cyclic coordinates of a gait: coordinates the model does not depend on.

A running or walking gait advances: its forward position (or heading) grows every stride
and is never periodic. When the field, the events, the resets and the section do not
depend on a coordinate ``x_i`` (shifting ``x_i`` by c shifts the whole trajectory's
``x_i`` by c and changes nothing else), the gait is periodic in the other coordinates and
``x_i`` advances by the same amount every stride. The orbit solver leaves such
coordinates out of the fixed-point equation and of the stability analysis (they are
neutral: a shift neither grows nor decays) and reports the advance per period.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

from ._limits import INDEPENDENCE_RTOL

#: shift applied to a cyclic coordinate to check that the model does not depend on it
SHIFT = 1.0


def check_cyclic(cyclic, dim: int) -> tuple:
    """The cyclic coordinates as a sorted tuple of distinct indices in ``[0, dim)``."""
    try:
        indices = [int(i) for i in cyclic]
    except (TypeError, ValueError):
        raise TypeError(f"cyclic must be a sequence of coordinate indices, got "
                        f"{cyclic!r}") from None
    if len(set(indices)) != len(indices) or not all(0 <= i < dim for i in indices):
        raise ValueError(f"cyclic must hold distinct coordinate indices in [0, {dim}), got "
                         f"{list(cyclic)}")
    if len(indices) >= dim - 1:
        raise ValueError(f"cyclic leaves {dim - len(indices)} coordinate(s) of {dim}: the "
                         f"section and the orbit need at least two that are not cyclic")
    return tuple(sorted(indices))


def kept(cyclic, dim: int) -> np.ndarray:
    """The indices of the coordinates that are not cyclic."""
    return np.setdiff1d(np.arange(dim), np.asarray(cyclic, dtype=np.int64))


def check_section_normal(normal, cyclic, x) -> None:
    """Refuse a section whose gradient at x depends on a cyclic coordinate."""
    scale = float(np.abs(normal).max())
    for i in cyclic:
        if abs(normal[i]) > INDEPENDENCE_RTOL * scale:
            raise ValueError(f"coordinate {i} cannot be cyclic: the section depends on it "
                             f"(its gradient at x = {x} has component {normal[i]:.3g} there)")


def check_independence(returned, x, shifted_returns, cyclic) -> None:
    """Refuse cyclic coordinates the return depends on.

    ``returned`` is ``P(x)``; ``shifted_returns[j]`` is ``P(x + SHIFT e_i)`` for the j-th
    cyclic index i, which must equal ``P(x) + SHIFT e_i``.
    """
    tol = INDEPENDENCE_RTOL * max(1.0, float(np.abs(x).max()))
    for i, shifted in zip(cyclic, shifted_returns, strict=True):
        moved = shifted.copy()
        moved[i] -= SHIFT
        gap = float(np.abs(moved - returned).max())
        if not gap <= tol:
            raise ValueError(
                f"coordinate {i} is not cyclic: shifting it by {SHIFT:g} at x = {x} changes "
                f"the return to the section by {gap:.3g} beyond the shift (tolerance "
                f"{tol:.3g}); the field, events, resets or section depend on it"
            )


def reduced_basis(normal, cyclic, dim: int) -> np.ndarray:
    """Orthonormal basis (dim, dim - 1 - len(cyclic)) of the section's tangent space with
    the cyclic coordinates held at 0."""
    rows = np.vstack([normal, np.eye(dim)[list(cyclic)]])
    return scipy.linalg.null_space(rows)
