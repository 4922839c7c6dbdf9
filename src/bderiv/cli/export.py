"""``bderiv export``: the triangulation of an example's B-derivative, saved and re-read.

``--map event`` (the default) saves the map at the event point, ``--map flow`` the flow map
from ``x0`` over ``[0, t_final]``: the same fan with its vertices carried by the flow's
linear stages.

What a save guarantees. Each file is written to a temporary file beside it, synced and read
back; only then are the earlier files replaced, by one rename each (``os.replace``,
atomic). A failure before the renames (an error, a full disk, Ctrl-C, a file that does not
read back) leaves the earlier files as they were. With ``--format both`` the two renames
are two steps, the ``.npz`` first: a process killed between them leaves the new ``.npz``
beside the earlier ``.json``, each file whole. The two files of one export carry one
random token (header field ``pair``): loading an ``.npz`` whose ``.json`` (same name) does
not share its token is a ValueError naming both, so after such a kill the new ``.npz`` is
refused and the earlier ``.json`` loads (the earlier map), until the export is run again.
"""

from __future__ import annotations

import math
import os

import numpy as np

from .._limits import CHECK_VECTORS, MAX_PIECES
from .._support._tables import corner_point_bytes
from ..geometry._triangulation_files import save_files
from ..geometry.triangulation import load_triangulation
from .names import check_example_options
from .systems import load_example, refuse_without_triangulation
from .usage import (
    UsageError,
    check_output_directory,
    check_output_file,
    make_output_directory,
    not_writable,
    require_memory,
)


def triangulation_bytes(n: int, d: int) -> int:
    """Peak bytes of building and saving a triangulation of n events in R^d.

    The corner points and the vertex tables (four arrays (2**n, d)), the orders, chains and
    simplices (about (6n + 4) n! int64) and, for JSON, the simplices as Python lists (about
    40 bytes an entry).

    Examples
    --------
    >>> round(triangulation_bytes(12, 12) / 2**30, 1)  # GiB
    735.2
    """
    f = math.factorial(n)
    return 2 * corner_point_bytes(n, d) + (6 * n + 4) * f * 8 + 2 * f * (n + 1) * 40


def run_export(example=None, n=None, extended=False, out="triangulation", fmt="both",
               max_pieces=MAX_PIECES, which="event") -> dict:
    """Save the triangulation of ``example`` (default chair) and check the files read back.

    Parameters
    ----------
    example, n, extended
        The system, as for :func:`bderiv.cli.systems.load_example`.
    out : str
        Path without suffix (a ``.npz`` or ``.json`` suffix is dropped); its directory is
        made if missing, with its missing parents.
    fmt : {"npz", "json", "both"}
    max_pieces : int
        Refuse more than this many event orders.
    which : {"event", "flow"}
        The map: the B-derivative at the event point, or that of the flow from ``x0`` over
        ``[0, t_final]`` (a model whose trajectory meets one event group).

    Returns
    -------
    dict
        ``example``, ``map`` (``which``), ``map_description``, ``n_events``, ``dim``,
        ``vertices``, ``simplices``, ``files`` (each ``path``, ``format``, ``bytes``,
        ``max_error_reloaded``, ``replaced``: whether it replaced an earlier file),
        ``check_vectors``, ``created`` (the topmost directory made for ``out``, or None).

    Notes
    -----
    All or none as the module docstring says: a failure before the renames keeps the
    earlier files; a kill between the two renames of ``fmt="both"`` leaves the new
    ``.npz``, which loading refuses (the pair token), beside the earlier ``.json``.
    """
    base = _output_base(out)
    suffixes = ("npz", "json") if fmt == "both" else (fmt,)
    for suffix in suffixes:  # each replaced by a rename: a directory in the way refused
        check_output_file(f"{base}.{suffix}", "--out", in_place=False)
    if example is None:
        example = "network" if n is not None or extended else "chair"
    check_example_options(example, n, extended)  # --n in its range before its n! below
    if n is not None:  # the pieces known before the example's tables are built
        _refuse_pieces(n, max_pieces)
    ex, bd = load_example(example, n, extended)
    n, d = bd.n_events, bd.dim
    if not bd.full_rank:
        raise UsageError(
            f"{example} has {n} events on surfaces of rank {np.linalg.matrix_rank(bd.Dh)} "
            f"< n: its B-derivative has no triangulation (it is still evaluated exactly by "
            f"BDerivative)"
        )
    refuse_without_triangulation(example, bd)  # resets that forget a direction
    _refuse_pieces(n, max_pieces)
    require_memory(triangulation_bytes(n, d), f"the triangulation of {n} events in R^{d}")
    if which == "event":
        fmap, described = bd, "the B-derivative at the event point"
        tri = bd.triangulation(max_pieces=max_pieces)
    else:
        if ex is None:
            raise UsageError(f"--map flow needs a model, but {example} is a corner table "
                             f"without one (it has only the map at the event point)")
        fmap = ex.system.flow_bderivative(ex.x0, ex.t_final)
        described = (f"the B-derivative of the flow from x0 over [0, {ex.t_final:g}] "
                     f"(its pre-event vertices pulled back to x0, post-event vertices "
                     f"pushed to t_final)")
        tri = flow_triangulation(fmap, max_pieces)
    V = np.random.default_rng(0).standard_normal((CHECK_VECTORS, d))
    expected = fmap(V)
    paths = {f"{base}.{f}": f for f in suffixes}
    errors = {}

    def read_back(temps):  # every file read back before any replaces its target
        for path, temp in temps.items():
            errors[path] = float(np.abs(load_triangulation(temp, paths[path])(V)
                                        - expected).max())

    replaced = {path: os.path.exists(path) for path in paths}
    created = make_output_directory(os.path.dirname(base) or ".", "--out")
    try:
        save_files(tri, paths, check=read_back)
    except OSError as exc:
        raise UsageError(not_writable("--out", " and ".join(paths), exc)) from None
    files = [{"path": path, "format": f, "bytes": os.path.getsize(path),
              "max_error_reloaded": errors[path], "replaced": replaced[path]}
             for path, f in paths.items()]
    return {"example": example, "map": which, "map_description": described, "n_events": n,
            "dim": d, "vertices": tri.pre.shape[0], "simplices": tri.simplices.shape[0],
            "files": files, "check_vectors": CHECK_VECTORS, "created": created}


def flow_triangulation(fb, max_pieces):
    """The triangulation of a flow map with one event group: ``L_1 . M . L_0``.

    The fan of the group's map ``M`` carried by the linear stages
    (:meth:`Triangulation.composed`); several groups do not make one fan, and none make a
    linear map: both are usage errors.
    """
    if fb.n_groups != 1:
        raise UsageError(
            f"--map flow: the flow map meets {fb.n_groups} event groups; a triangulation "
            f"(one fan of simplices) exists for exactly one group (with several, the pieces "
            f"are intersections of the groups' cones, not one fan; with none, the map is "
            f"linear)"
        )
    return fb.triangulation(max_pieces)


def _output_base(out: str) -> str:
    """``--out`` without a ``.npz`` / ``.json`` suffix, checked to name a file that can be
    written (in a directory that exists or can be made)."""
    base = out
    for ext in (".npz", ".json"):
        if base.endswith(ext):
            base = base[: -len(ext)]
    if os.path.basename(base) in ("", ".", ".."):
        raise UsageError(
            f"--out must be a file path such as results/tri (the suffixes .npz and .json "
            f"are added), got {out!r}"
        )
    check_output_directory(os.path.dirname(os.path.abspath(base)), "--out")
    return base


def _refuse_pieces(n, max_pieces):
    """Refuse ``n`` events whose ``n!`` event orders exceed ``max_pieces``."""
    if math.factorial(n) > max_pieces:
        raise UsageError(
            f"{n} events give 2 * {n}! simplices, more than 2 * --max-pieces={max_pieces}"
        )
