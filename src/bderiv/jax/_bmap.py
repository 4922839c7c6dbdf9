"""``bderiv.jax.bmap``: a B-derivative (a piecewise-linear map) as a JAX function."""

from __future__ import annotations

from ..analysis.flowmap import FlowBDerivative
from ..engine.bderivative import BDerivative
from ._host import MapHost
from ._primitive import pl_function


def bmap(bd):
    """A :class:`~bderiv.BDerivative` or :class:`~bderiv.FlowBDerivative` ``M`` as the JAX
    function ``u -> M(u)``.

    Parameters
    ----------
    bd : BDerivative or FlowBDerivative
        Of dimension d.

    Returns
    -------
    callable
        ``m(u)``: tangents ``u`` of shape ``(..., d)`` to ``M(u)`` ``(..., d)``, in u's
        float dtype. Under ``jax.jvp`` its derivative at u is the piece that u selects,
        ``M_sigma(u)`` (``bd.jvp(u, du)``); under ``jax.grad`` / ``jax.vjp`` its
        transpose (``bd.vjp(u, w)``): M is linear on the piece around u, so both are
        exact there. On a boundary between pieces (a tie between event times) the
        piece is the one ``bd.orders(u)`` names. Works under ``jax.jit`` and
        ``jax.vmap`` (one host call per batch); not twice differentiable.

    Raises
    ------
    TypeError
        If ``bd`` is neither; when ``m`` is traced, for a non-real dtype of u.
    ValueError
        When ``m`` is traced, for a shape other than ``(..., d)``; bderiv's refusals
        while it computes reach the caller as JAX's error for a failed callback
        (``jax.errors.JaxRuntimeError``, or ValueError on JAX's fast dispatch path) with
        bderiv's message.

    Examples
    --------
    >>> import jax
    >>> import numpy as np
    >>> from bderiv import BDerivative
    >>> from bderiv.jax import bmap
    >>> jax.config.update("jax_enable_x64", True)
    >>> bd = BDerivative(np.eye(2), [[1.0, 1.0], [2.0, 1.0], [1.0, 1.0], [2.0, 1.0]])
    >>> m = bmap(bd)
    >>> m(jax.numpy.array([-1.0, -2.0]))
    Array([-2., -2.], dtype=float64)
    >>> jax.jacrev(m)(jax.numpy.array([-1.0, -2.0]))   # the piece at u, d x d
    Array([[2., 0.],
           [0., 1.]], dtype=float64)
    """
    if not isinstance(bd, BDerivative | FlowBDerivative):
        raise TypeError(f"bd must be a BDerivative or a FlowBDerivative, got "
                        f"{type(bd).__name__}")
    host = MapHost(bd)
    m = pl_function(host.values, host, bd.dim, "u")
    m.__name__ = m.__qualname__ = "bmap"
    m.__doc__ = f"u (..., {bd.dim}) -> M(u) of {bd!r} (bderiv.jax.bmap)"
    return m
