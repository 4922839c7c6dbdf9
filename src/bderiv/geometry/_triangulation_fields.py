"""The arrays of a triangulation checked before they are trusted, from a file
(:mod:`bderiv.geometry._triangulation_io`) or from ``Triangulation(pre, post, simplices,
kernel, kernel_post)``: dtypes, shapes, finiteness, index ranges, every vertex used,
non-degenerate cones (:func:`check_fields`)."""

from __future__ import annotations

import numpy as np

#: the arrays of a triangulation; version 1 files lack ``kernel_post`` (it is ``kernel``)
FIELDS = ("pre", "post", "simplices", "kernel", "kernel_post")


class DegenerateCones(ValueError):
    """A triangulation's cone spans less than R^d (in floating point)."""


def check_fields(fields: dict, source: str, type_error: type = TypeError) -> dict:
    """Validate the four arrays of a triangulation completely.

    Parameters
    ----------
    fields : dict
        ``pre``, ``post`` (n_vertices, d), ``simplices`` (n_simplices, n + 1), ``kernel``
        (d, d - n) and optionally ``kernel_post`` (d, d - n; absent or None: ``kernel``),
        as array_likes.
    source : str
        What they came from (``"Triangulation"`` or a file), named in every message.
    type_error : type
        Raised for a wrong dtype (``TypeError``; ``ValueError`` for file contents).

    Returns
    -------
    dict
        The five arrays of :data:`FIELDS` as fresh C-contiguous arrays: float64, and int64
        simplices.
    """
    if fields.get("kernel_post") is None:
        fields = {**fields, "kernel_post": fields["kernel"]}
    out = {name: _matrix(fields[name], name, source, type_error) for name in FIELDS}
    pre, post, simplices, kernel, kernel_post = (out[name] for name in FIELDS)
    (n_vertices, d), n = pre.shape, simplices.shape[1] - 1

    def require(ok, name, want, got):
        if not ok:
            raise ValueError(f"{source}: field {name!r} must have {want}, got {got}")

    require(n_vertices >= 2 and d >= 1, "pre", "shape (n_vertices >= 2, d >= 1)", pre.shape)
    require(post.shape == pre.shape, "post", f"shape {pre.shape} (that of pre)", post.shape)
    require(simplices.shape[0] >= 1 and 1 <= n <= d, "simplices",
            f"shape (n_simplices >= 1, n + 1) with 1 <= n <= d = {d}", simplices.shape)
    for name, basis in (("kernel", kernel), ("kernel_post", kernel_post)):
        require(basis.shape == (d, d - n), name, f"shape (d, d - n) = ({d}, {d - n})",
                basis.shape)
    lo, hi = simplices.min(), simplices.max()
    require(lo >= 0 and hi < n_vertices, "simplices", f"vertex indices 0..{n_vertices - 1}",
            f"indices {lo}..{hi}")
    out["simplices"] = simplices = np.array(simplices, dtype=np.int64)
    require(not simplices[:, 0].any(), "simplices", "column 0 (the apex) all 0",
            f"{np.unique(simplices[:, 0]).tolist()}")
    require(not pre[0].any(), "pre", "vertex 0 (the apex) at the origin", pre[0])
    require(not post[0].any(), "post", "vertex 0 (the apex) at the origin", post[0])
    unused = np.setdiff1d(np.arange(n_vertices), simplices)
    if unused.size:
        raise ValueError(
            f"{source}: field 'simplices' must use every vertex of pre/post, but vertices "
            f"{unused[:10].tolist()} are in no simplex"
        )
    for name, points, basis in (("pre", pre, kernel), ("post", post, kernel_post)):
        bad = _first_degenerate(points, simplices, basis)
        if bad >= 0:
            raise DegenerateCones(
                f"{source}: field 'simplices' must give non-degenerate cones, but simplex "
                f"{bad} {simplices[bad].tolist()} spans less than R^{d} with the {name} "
                f"vertices (and the kernel basis {'kernel' if name == 'pre' else 'kernel_post'})"
            )
    return out


def _matrix(value, name: str, source: str, type_error: type) -> np.ndarray:
    """One field as a 2-D finite array: float64, or int64 for ``simplices``."""
    try:
        arr = np.asarray(value)
    except (ValueError, TypeError, OverflowError, RecursionError) as exc:
        raise ValueError(f"{source}: field {name!r} is not a rectangular array: {exc}") from None
    kinds, want = ("iu", "integers (vertex indices)") if name == "simplices" else (
        "fiu", "real numbers")
    if arr.dtype.kind not in kinds:
        raise type_error(f"{source}: field {name!r} must hold {want}, got dtype {arr.dtype}")
    if arr.ndim != 2:
        raise ValueError(
            f"{source}: field {name!r} must be a 2-D array, got {arr.ndim}-D with shape "
            f"{arr.shape}"
        )
    if name == "simplices":
        return arr  # converted to int64 by check_fields after its range check
    arr = np.array(arr, dtype=np.float64)
    if not np.isfinite(arr).all():
        i, j = np.argwhere(~np.isfinite(arr))[0]
        raise ValueError(f"{source}: field {name!r} must be finite, got {name}[{i}, {j}] = "
                         f"{arr[i, j]}")
    return arr


def _first_degenerate(points, simplices, kernel) -> int:
    """Index of the first simplex whose cone does not span R^d (-1 when none).

    The cone's d generators (its n vertices, the kernel basis) are scaled to unit length,
    since a cone does not depend on their lengths, and the smallest singular value is
    compared with numpy's rank tolerance.
    """
    d = points.shape[1]
    unit, kunit = _unit(points, axis=1), _unit(kernel, axis=0)
    block = max(1, (1 << 22) // (d * d))  # 32 MiB of matrices at a time
    for start in range(0, simplices.shape[0], block):
        cols = unit[simplices[start:start + block, 1:]].transpose(0, 2, 1)  # (b, d, n)
        P = np.concatenate([cols, np.broadcast_to(kunit, (cols.shape[0],) + kunit.shape)],
                           axis=2)
        s = np.linalg.svd(P, compute_uv=False)  # (b, d), descending
        bad = np.flatnonzero(s[:, -1] <= s[:, 0] * d * np.finfo(np.float64).eps)
        if bad.size:
            return start + int(bad[0])
    return -1


def _unit(a: np.ndarray, axis: int) -> np.ndarray:
    """``a`` with its vectors along ``axis`` scaled to length 1 (zero vectors stay 0).

    Divided by the largest entry first, so that no square overflows near 1e300.
    """
    big = np.abs(a).max(axis=axis, keepdims=True, initial=0.0)
    a = np.divide(a, big, out=np.zeros_like(a), where=big > 0)
    norms = np.linalg.norm(a, axis=axis, keepdims=True)
    return np.divide(a, norms, out=np.zeros_like(a), where=norms > 0)
