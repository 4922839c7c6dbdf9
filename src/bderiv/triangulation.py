"""``Triangulation``: the B-derivative as a PL homeomorphism given by vertices and simplices.

This is the representation of the source note (MATH.md section 5): pre-event vertices,
their post-event images, and the simplicial cones of the fan around F[0]. It holds
everything needed to rebuild the map elsewhere, without the event machinery.
"""

from __future__ import annotations

import json
import math
import os
from itertools import permutations

import numpy as np
import scipy.linalg

from ._validate import check_points, check_positive_int

#: tag written into every saved file, checked on load
FILE_FORMAT = "bderiv.triangulation"
FILE_VERSION = 1
_FIELDS = ("pre", "post", "simplices", "kernel")


class Triangulation:
    """A continuous piecewise-linear map given by a fan of simplicial cones.

    Parameters
    ----------
    pre : array_like, shape (n_vertices, d)
        Pre-event vertices. Vertex 0 is the origin (the apex of every cone).
    post : array_like, shape (n_vertices, d)
        Their images under the map.
    simplices : array_like of int, shape (n_simplices, n + 1)
        Vertex indices; column 0 is the apex. The cone of a simplex is spanned by its other
        n vertices (non-negative weights) plus the kernel basis (any weights).
    kernel : array_like, shape (d, d - n)
        Orthonormal basis of ker Dh, on which the map is the identity (empty when d = n).

    Notes
    -----
    Built by :meth:`BDerivative.triangulation`: vertices ``0 .. 2**n - 1`` are the corner
    points ``U[mask] -> W[mask]`` and vertex ``2**n`` is ``-F[0] -> -F[full]``. The order
    sigma with chain ``B_0 = 0, ..., B_n = full`` owns two simplices,
    ``[0, B_1, ..., B_{n-1}, full]`` and ``[0, B_1, ..., B_{n-1}, 2**n]``, the halves of
    its cone before and after the flow direction.

    Save it with :meth:`save` (``.npz`` or ``.json``) and read it back with :meth:`load`
    (or :func:`bderiv.load_triangulation`): the file holds the whole map.

    Examples
    --------
    >>> import numpy as np
    >>> from bderiv import BDerivative
    >>> F = np.array([[1.0, 1.0], [2.0, 1.0], [1.0, 1.0], [2.0, 1.0]])
    >>> tri = BDerivative(np.eye(2), F).triangulation()
    >>> tri
    Triangulation(n_events=2, dim=2, vertices=5, simplices=4)
    >>> tri([-1.0, -2.0])
    array([-2., -2.])
    """

    def __init__(self, pre, post, simplices, kernel):
        self.pre = np.ascontiguousarray(pre, dtype=np.float64)
        self.post = np.ascontiguousarray(post, dtype=np.float64)
        self.simplices = np.ascontiguousarray(simplices, dtype=np.int64)
        self.kernel = np.ascontiguousarray(kernel, dtype=np.float64)
        if self.pre.shape != self.post.shape or self.pre.ndim != 2:
            raise ValueError(
                f"pre and post must be (n_vertices, d) arrays of one shape, got "
                f"{self.pre.shape} and {self.post.shape}"
            )
        d = self.pre.shape[1]
        n = self.simplices.shape[1] - 1
        if self.kernel.shape != (d, d - n):
            raise ValueError(f"kernel must have shape ({d}, {d - n}), got {self.kernel.shape}")
        if self.simplices.min() < 0 or self.simplices.max() >= self.pre.shape[0]:
            raise ValueError(
                f"simplices must index vertices 0..{self.pre.shape[0] - 1}, got indices "
                f"{self.simplices.min()}..{self.simplices.max()}"
            )
        self.dim = d
        self.n_events = n

    @classmethod
    def from_bderivative(cls, bd, max_pieces: int) -> Triangulation:
        """Build the fan of ``bd`` (2 n! simplices); refuses when n! > ``max_pieces``."""
        check_positive_int(max_pieces, "max_pieces")
        n = bd.n_events
        if math.factorial(n) > max_pieces:
            raise ValueError(
                f"the triangulation of {n} events has 2 * {n}! = {2 * math.factorial(n)} "
                f"simplices, more than 2 * max_pieces={max_pieces}; pass a larger max_pieces"
            )
        U, W = bd.corner_points()
        full = (1 << n) - 1
        pre = np.vstack([U, -bd.F[0]])
        post = np.vstack([W, -bd.F[full]])
        orders = np.array(list(permutations(range(n))), dtype=np.int64).reshape(-1, n)
        # chain[:, j] = mask after j events; cumulative OR of the order's bits
        chain = np.cumsum(1 << orders, axis=1)
        inner = chain[:, :-1]
        apex = np.zeros((len(orders), 1), dtype=np.int64)
        plus = np.hstack([apex, inner, np.full((len(orders), 1), full)])
        minus = np.hstack([apex, inner, np.full((len(orders), 1), full + 1)])
        simplices = np.stack([plus, minus], axis=1).reshape(-1, n + 1)
        kernel = scipy.linalg.null_space(bd.Dh).reshape(bd.dim, bd.dim - n)
        return cls(pre, post, simplices, kernel)

    def __repr__(self) -> str:
        return (
            f"Triangulation(n_events={self.n_events}, dim={self.dim}, "
            f"vertices={self.pre.shape[0]}, simplices={self.simplices.shape[0]})"
        )

    def __call__(self, V) -> np.ndarray:
        """Evaluate the map by locating each vector in its cone (barycentric weights).

        Brute force over all simplices: meant for checking and for small n.

        Parameters
        ----------
        V : array_like, shape (..., d)

        Returns
        -------
        ndarray, shape (..., d)
        """
        flat, lead = check_points(V, self.dim)
        n = self.n_events
        best_weight = np.full(flat.shape[0], -np.inf)
        out = np.empty_like(flat)
        for simplex in self.simplices:
            P = np.hstack([self.pre[simplex[1:]].T, self.kernel])
            Q = np.hstack([self.post[simplex[1:]].T, self.kernel])
            weights = np.linalg.solve(P, flat.T)  # (d, m)
            # the cone needs non-negative weights on its n vertices; keep the simplex
            # whose smallest weight is largest (robust on shared faces)
            min_weight = weights[:n].min(axis=0) / (np.abs(weights[:n]).max(axis=0) + 1e-300)
            better = min_weight > best_weight
            best_weight[better] = min_weight[better]
            out[better] = (Q @ weights[:, better]).T
        return out.reshape(lead + (self.dim,))

    # -- files ----------------------------------------------------------------------------

    def to_dict(self) -> dict:
        """Plain-Python description (lists of floats and ints), as written to JSON.

        Returns
        -------
        dict
            Keys ``format``, ``version``, ``n_events``, ``dim`` and the arrays ``pre``
            (n_vertices, d), ``post`` (n_vertices, d), ``simplices`` (n_simplices, n + 1)
            and ``kernel`` (d, d - n) as nested lists.
        """
        return {
            "format": FILE_FORMAT,
            "version": FILE_VERSION,
            "n_events": self.n_events,
            "dim": self.dim,
            **{name: getattr(self, name).tolist() for name in _FIELDS},
        }

    @classmethod
    def from_dict(cls, data: dict) -> Triangulation:
        """Rebuild from :meth:`to_dict` output; checks the format tag and the shapes."""
        if not isinstance(data, dict) or data.get("format") != FILE_FORMAT:
            raise ValueError(
                f"not a bderiv triangulation: expected a mapping with format={FILE_FORMAT!r}"
            )
        version = data.get("version")
        if version != FILE_VERSION:
            raise ValueError(
                f"triangulation file version {version!r} is not supported (this bderiv "
                f"reads version {FILE_VERSION})"
            )
        missing = [name for name in _FIELDS if name not in data]
        if missing:
            raise ValueError(f"triangulation data lacks the field(s) {missing}")
        n, d = int(data["n_events"]), int(data["dim"])
        pre = np.asarray(data["pre"], dtype=np.float64).reshape(-1, d)
        post = np.asarray(data["post"], dtype=np.float64).reshape(-1, d)
        simplices = np.asarray(data["simplices"], dtype=np.int64).reshape(-1, n + 1)
        kernel = np.asarray(data["kernel"], dtype=np.float64).reshape(d, d - n)
        return cls(pre, post, simplices, kernel)

    def save(self, path, format: str | None = None) -> str:
        """Write the triangulation to ``path`` as ``.npz`` (binary) or ``.json`` (text).

        Parameters
        ----------
        path : str or os.PathLike
            Destination; its suffix picks the format unless ``format`` is given.
        format : {"npz", "json"}, optional

        Returns
        -------
        str
            The path written.

        Notes
        -----
        Both formats round-trip exactly (JSON writes floats with all their digits). The
        ``.npz`` holds the arrays ``pre``, ``post``, ``simplices``, ``kernel`` and a JSON
        header ``meta``; it loads with ``numpy.load(path)`` alone.
        """
        path = os.fspath(path)
        fmt = _file_format(path, format)
        if fmt == "json":
            with open(path, "w", encoding="utf-8") as fh:
                json.dump(self.to_dict(), fh)
                fh.write("\n")
        else:
            meta = {k: v for k, v in self.to_dict().items() if k not in _FIELDS}
            with open(path, "wb") as fh:  # a file object: numpy must not append ".npz"
                np.savez_compressed(
                    fh, meta=np.array(json.dumps(meta)), **{k: getattr(self, k) for k in _FIELDS}
                )
        return path

    @classmethod
    def load(cls, path, format: str | None = None) -> Triangulation:
        """Read a triangulation written by :meth:`save`.

        Parameters
        ----------
        path : str or os.PathLike
            A ``.npz`` or ``.json`` file; its suffix picks the format unless ``format``
            is given.
        format : {"npz", "json"}, optional

        Returns
        -------
        Triangulation

        Raises
        ------
        ValueError
            If the file is not a bderiv triangulation or its version is unknown.

        Examples
        --------
        >>> import os, tempfile
        >>> import numpy as np
        >>> from bderiv import BDerivative, Triangulation
        >>> F = np.array([[1.0, 1.0], [2.0, 1.0], [1.0, 1.0], [2.0, 1.0]])
        >>> tri = BDerivative(np.eye(2), F).triangulation()
        >>> path = tri.save(os.path.join(tempfile.mkdtemp(), "tri.json"))
        >>> Triangulation.load(path)([-1.0, -2.0])
        array([-2., -2.])
        """
        path = os.fspath(path)
        fmt = _file_format(path, format)
        if fmt == "json":
            with open(path, encoding="utf-8") as fh:
                try:
                    data = json.load(fh)
                except json.JSONDecodeError as exc:
                    raise ValueError(f"{path} is not valid JSON: {exc}") from None
            return cls.from_dict(data)
        try:
            with np.load(path, allow_pickle=False) as npz:
                if "meta" not in npz.files:
                    raise ValueError(f"{path} is not a bderiv triangulation (no 'meta' entry)")
                data = json.loads(str(npz["meta"]))
                if isinstance(data, dict):
                    data.update({k: npz[k] for k in _FIELDS if k in npz.files})
        except (OSError, EOFError) as exc:
            raise ValueError(f"cannot read {path} as .npz: {exc}") from None
        return cls.from_dict(data)


def _file_format(path: str, format: str | None) -> str:
    if format is None:
        format = os.path.splitext(path)[1].lstrip(".").lower()
    if format not in ("npz", "json"):
        raise ValueError(
            f"unknown triangulation file format {format!r} for {path!r}: use a .npz or "
            f".json file name, or format='npz' / 'json'"
        )
    return format


def load_triangulation(path, format: str | None = None) -> Triangulation:
    """Read a triangulation saved by :meth:`Triangulation.save` or ``bderiv export``.

    Same as :meth:`Triangulation.load`; the result is callable, ``tri(V)`` with V of
    shape ``(..., d)``.
    """
    return Triangulation.load(path, format)
