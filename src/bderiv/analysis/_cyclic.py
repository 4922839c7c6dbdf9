"""Cyclic coordinates of a gait: coordinates the model does not depend on.

A running or walking gait advances: its forward position (or heading) grows every stride
and is never periodic. When the field, the events, the resets and the section do not
depend on a coordinate ``x_i`` (shifting ``x_i`` by c shifts the whole trajectory's
``x_i`` by c and changes nothing else), the gait is periodic in the other coordinates and
``x_i`` advances by the same amount every stride. The orbit solver leaves such
coordinates out of the fixed-point equation and of the stability analysis (they are
neutral: a shift neither grows nor decays) and reports the advance per period.

A wrong choice gives a wrong gait, not a failure: with a floor ``y = a sin(2 pi x)`` a
hopper's return map was solved in ``(y, vx)`` at x = 0 to a residual of 1e-16, and the
strides that followed from the "orbit" had apex heights 0.506, 0.440, 0.444, 0.498, ...
So the independence is checked twice (:func:`check_independence`, :func:`check_equivariance`):
the return from the start shifted by each of :data:`SHIFTS`, whose ratio is irrational
(a single shift of 1 passed that floor, of period 1: no single shift can tell a dependence
of a period dividing it), and, at every Newton iterate and at the orbit, the return map's
B-derivative along the coordinate, which must map ``e_i`` to ``e_i`` (equivariance:
``P(x + c e_i) = P(x) + c e_i`` for every c), a dependence of any period or of the orbit's
neighbourhood alone.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg

from .._limits import EQUIVARIANCE_RTOL, INDEPENDENCE_RTOL
from .._support._validate_ints import is_integer

#: shifts applied to a cyclic coordinate to check that the model does not depend on it:
#: of both signs, of irrational ratio (sqrt 2 and the golden ratio's inverse), so that no
#: period of a dependence divides both
SHIFTS = (math.sqrt(2.0), -(math.sqrt(5.0) - 1.0) / 2.0)


def check_cyclic(cyclic, dim: int) -> tuple:
    """The cyclic coordinates as a sorted tuple of distinct indices in ``[0, dim)``."""
    try:
        items = list(cyclic)
    except TypeError:
        items = None
    # integers only: int(1.5) would silently be coordinate 1
    bad = None if items is None else [i for i in items if not is_integer(i)]
    if items is None or bad:
        what = (f"{type(cyclic).__name__}, not a sequence" if items is None
                else f"{bad[0]!r} is {type(bad[0]).__name__}")
        raise TypeError(f"cyclic must be a sequence of coordinate indices (integers), got "
                        f"{cyclic!r} ({what})")
    indices = [int(i) for i in items]
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

    ``returned`` is ``P(x)``; ``shifted_returns`` holds ``P(x + c e_i)`` for each cyclic
    index i (in order) and, for each, each shift c of :data:`SHIFTS` (in order): each must
    equal ``P(x) + c e_i``.
    """
    tol = INDEPENDENCE_RTOL * max(1.0, float(np.abs(x).max()))
    shifts = [(i, c) for i in cyclic for c in SHIFTS]
    for (i, c), shifted in zip(shifts, shifted_returns, strict=True):
        moved = shifted.copy()
        moved[i] -= c
        gap = float(np.abs(moved - returned).max())
        if not gap <= tol:
            raise ValueError(
                f"coordinate {i} is not cyclic: shifting it by {c:.6g} at x = {x} changes "
                f"the return to the section by {gap:.3g} beyond the shift (tolerance "
                f"{tol:.3g}); the field, events, resets or section depend on it"
            )


def check_equivariance(R, x, cyclic) -> None:
    """Refuse cyclic coordinates along which the return map's B-derivative ``R`` at ``x``
    (a :class:`~bderiv.analysis.returnmap.ReturnMap`) is not the identity: ``R(e_i) = e_i`` and
    ``R(-e_i) = -e_i`` to within ``EQUIVARIANCE_RTOL`` times ``max(1, |R(+-e_i)|)``.
    The refusal names the coordinate, the measured dependence (how far the return moves
    per unit shift beyond the shift) and the coordinate it moves most."""
    d = x.size
    for i in cyclic:
        E = np.zeros((2, d))
        E[0, i], E[1, i] = 1.0, -1.0
        images = R(E)
        tol = EQUIVARIANCE_RTOL * max(1.0, float(np.abs(images).max()))
        miss = np.abs(images - E)
        gap = float(miss.max())
        if not gap <= tol:
            j = int(np.unravel_index(np.argmax(miss), miss.shape)[1])
            raise ValueError(
                f"coordinate {i} is not cyclic: at x = {x} the return map's derivative along "
                f"it is not the shift itself: a shift of coordinate {i} by c moves the return "
                f"by {gap:.3g} c beyond the shift (coordinate {j} most: the derivative maps "
                f"e_{i} to {images[0]}; tolerance {tol:.3g}), so the field, events, resets "
                f"or section depend on it and the next strides from an orbit found with it "
                f"cyclic would not repeat it"
            )


def undeclared(R, r, tol: float) -> list:
    """The coordinates i that the return moved (``|r_i| > tol``, ``r = P(x) - x``) and along
    which the return map's B-derivative ``R`` is the shift itself (as
    :func:`check_equivariance` tests): a forward position left out of ``cyclic``, which
    Newton's method cannot bring back (the map's column i of ``R - I`` is 0), said when
    the search fails."""
    d = r.size
    E = np.vstack([np.eye(d), -np.eye(d)])
    images = R(E)
    miss = np.abs(images - E).reshape(2, d, d).max(axis=(0, 2))
    scale = np.abs(images).reshape(2, d, d).max(axis=(0, 2))
    return [i for i in range(d) if abs(r[i]) > tol
            and miss[i] <= EQUIVARIANCE_RTOL * max(1.0, scale[i])]


def reduced_basis(normal, cyclic, dim: int) -> np.ndarray:
    """Orthonormal basis (dim, dim - 1 - len(cyclic)) of the section's tangent space with
    the cyclic coordinates held at 0."""
    rows = np.vstack([normal, np.eye(dim)[list(cyclic)]])
    return scipy.linalg.null_space(rows)

def without_cyclic(R, cyclic):
    """``V -> R(V)`` with the cyclic components of the images set to 0, and the same with
    the orders (``R.apply_orders``): the map a stability iterates (a cyclic shift is
    neutral)."""

    def fmap(V):
        W = R(V)
        W[:, cyclic] = 0.0
        return W

    def fmap_orders(V):
        W, orders = R.apply_orders(V)
        W[:, cyclic] = 0.0
        return W, orders

    return fmap, fmap_orders
