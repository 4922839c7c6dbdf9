"""Which engine the tables of a :class:`~bderiv.engine.bderivative.BDerivative` call for,
and that engine built from them.

A dense table ``F`` (2**n, d) is evaluated by the dense engine, with reset Jacobians by
the reset engine; a corner model by the structured engine (``StructuredCorners``) or the
function engine (any other ``CornerModel``). Each engine checks its own tables.
"""

from __future__ import annotations

import numpy as np

from ..geometry.corners import CornerModel, StructuredCorners
from ._engines import DenseEngine, FunctionEngine, StructuredEngine
from ._engines.resets import ResetEngine

#: the types of a table given as an array: the common case, told apart without the
#: typing-Protocol ``isinstance`` (which looks up each member of the protocol by name).
_TABLE_TYPES = (np.ndarray, list, tuple)


def representation(Dh, F, resets) -> str:
    """Which engine ``F`` and ``resets`` call for: ``"dense"``, ``"resets"``,
    ``"structured"`` or ``"function"``; refuses resets with a corner model, half a corner
    model, and a model whose sizes differ from ``Dh``'s."""
    if type(F) in _TABLE_TYPES:  # has none of the protocol's members: no isinstance needed
        return "dense" if resets is None else "resets"
    if resets is not None and hasattr(F, "corner_function"):
        raise TypeError(f"resets need a dense table F (2**n, d), got the model {F!r}")
    if not isinstance(F, CornerModel):
        if hasattr(F, "corners") or hasattr(F, "corner_function"):
            raise TypeError(
                f"F = {F!r} looks like a corner model but lacks part of the protocol: it "
                f"needs n_events, dim, corners(happened) and corner_function() (see "
                f"bderiv.CornerModel)"
            )
        return "dense" if resets is None else "resets"
    n, d = Dh.shape
    want = (n if F.n_events is None else F.n_events, d if F.dim is None else F.dim)
    if want != (n, d):
        raise ValueError(
            f"Dh has shape {Dh.shape} (n={n} events, dimension d={d}) but the corner "
            f"model {F!r} has n={want[0]} events in dimension d={want[1]}"
        )
    return "structured" if isinstance(F, StructuredCorners) else "function"


def build_engine(Dh, F, resets, transversality_tol, memory_limit, fast_paths, reset_tol):
    """``(engine, model)``: the engine of :func:`representation`'s choice, built from the
    checked ``Dh`` (n, d) and the caller's ``F`` and ``resets`` (checked by the engine), and
    the corner model ``F`` (None for a dense table)."""
    kind = representation(Dh, F, resets)
    if kind == "dense":
        engine = DenseEngine.build(Dh, F, transversality_tol, memory_limit, fast_paths)
    elif kind == "resets":
        engine = ResetEngine.build(Dh, F, resets, transversality_tol, reset_tol,
                                   memory_limit)
    elif kind == "structured":
        engine = StructuredEngine(Dh, F, fast_paths)
    else:
        engine = FunctionEngine.from_model(Dh, F)
    return engine, None if kind in ("dense", "resets") else F
