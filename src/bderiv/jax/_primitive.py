"""The JAX side of :mod:`bderiv.jax`: host callbacks and the tangent-map primitive.

:func:`host_call` runs a NumPy function of :mod:`bderiv.jax._host` through
:func:`jax.pure_callback` with ``vmap_method="expand_dims"``: under ``vmap`` the whole
batch reaches the function in one call (arguments that are not batched come with axes of
size 1 in front), never one call per element.

:func:`tangent_map` binds ``bderiv_tangent_map``, a primitive of two arguments ``(a, b)``
that JAX treats as linear in ``b``: its value is ``forward(a, b)``, its transpose
``b_bar = transpose(a, ct)``, each a host function. That is how one function gets an
exact forward mode and a stated reverse mode: a ``custom_jvp`` rule returns
``tangent_map(x0, t)`` as its tangent, which JAX evaluates (``jvp``, ``jacfwd``) or
transposes (``grad``, ``vjp``, ``jacrev``); JAX has no public ``custom_transpose``, and a
``custom_vjp`` function cannot be differentiated forwards. For the flow, ``forward`` is
the B-derivative, which is piecewise linear, not linear: JAX only ever applies it to
tangents (it never adds or scales the results of two applications), so its value is what
``jvp`` returns, while ``grad`` uses the transpose of the one piece ``transpose`` gives.
Derivatives of the primitive itself (second derivatives) are refused.
"""

from __future__ import annotations

import functools
import logging

import numpy as np

#: what a second derivative through bderiv.jax says
SECOND_ORDER = (
    "bderiv.jax gives first derivatives only: the B-derivative's own derivative (hessian, "
    "jvp of jvp, grad of grad) is not available"
)


def require_jax():
    """The ``jax`` module (64-bit floats not required), or an ImportError saying how to
    install it."""
    try:
        import jax
    except ImportError:
        raise ImportError("bderiv.jax needs jax: pip install 'bderiv[jax]' (or pip install "
                          "'jax[cpu]')") from None
    return jax


class _OwnRefusals(logging.Filter):
    """Drops JAX's log of a failed callback when the failure is bderiv's own refusal (marked
    by :func:`bderiv.jax._host._refused`): the refusal reaches the caller as the exception
    JAX re-raises; logged too, it printed first as an ERROR with a traceback."""

    def filter(self, record):
        exc = record.exc_info[1] if record.exc_info else None
        return not getattr(exc, "bderiv_refusal", False)


logging.getLogger("jax._src.callback").addFilter(_OwnRefusals())


def host_call(fn, dtype, *args):
    """``fn(*args)`` on the host, through :func:`jax.pure_callback`.

    Parameters
    ----------
    fn : bound method of a host object (:mod:`bderiv.jax._host`)
        Takes NumPy arrays ``(..., d)`` whose leading shapes broadcast, returns float64
        ``(..., d)`` of the broadcast shape.
    dtype : dtype
        Of the result (the callback's float64 is cast to it).
    *args : jax arrays, shape (..., d)
    """
    jax = require_jax()
    shape = np.broadcast_shapes(*(a.shape for a in args))
    return jax.pure_callback(_on_host(fn, np.dtype(dtype)), jax.ShapeDtypeStruct(shape, dtype),
                             *args, vmap_method="expand_dims")


def _on_host(fn, dtype):
    """``fn`` on NumPy arrays, its result cast to ``dtype``: one function object per
    (method, dtype), kept on the host object that ``fn`` is a method of, so that JAX's
    caches, keyed by the callback, hit (a new closure per call compiled the callback
    again: 0.12 s per eager call) and the wrappers go with their host."""
    wrappers = vars(fn.__self__).setdefault("_jax_callbacks", {})
    key = (fn.__func__, dtype)
    if key not in wrappers:
        def call(*arrays):
            return np.asarray(fn(*(np.asarray(a) for a in arrays)), dtype=dtype)

        wrappers[key] = call
    return wrappers[key]


def tangent_map(a, b, forward, transpose):
    """``forward(a, b)`` as a JAX value linear in ``b``, transposed by ``transpose(a, ct)``.

    Parameters
    ----------
    a, b : jax arrays, shape (..., d) (leading shapes broadcast)
        The point (a start point, or the tangent that selects the piece) and the tangent.
    forward, transpose : callable
        Host functions as for :func:`host_call`.

    Returns
    -------
    jax array, shape (broadcast leading shape, d), of b's dtype
    """
    return _primitive().bind(a, b, forward=forward, transpose=transpose)


@functools.cache
def _primitive():
    """Build and register ``bderiv_tangent_map`` (once, on first use: jax is imported
    only then)."""
    require_jax()
    import jax.numpy as jnp
    from jax.core import ShapedArray
    from jax.extend.core import Primitive
    from jax.interpreters import ad, batching, mlir

    prim = Primitive("bderiv_tangent_map")

    def impl(a, b, *, forward, transpose):
        return host_call(forward, b.dtype, a, b)

    def abstract(a, b, **_):
        return ShapedArray(np.broadcast_shapes(a.shape, b.shape), b.dtype)

    def transpose_rule(ct, a, b, *, forward, transpose):
        if ad.is_undefined_primal(a):
            raise NotImplementedError(SECOND_ORDER)
        if type(ct) is ad.Zero:
            return [None, ad.Zero(b.aval)]
        out = prim.bind(a, ct, forward=transpose, transpose=forward)
        # b was broadcast against a: its cotangent sums over the axes it was broadcast on
        shape = b.aval.shape
        out = out.sum(axis=tuple(range(out.ndim - len(shape))))
        axes = tuple(i for i, (n, m) in enumerate(zip(out.shape, shape, strict=True)) if n != m)
        return [None, out.sum(axis=axes, keepdims=True) if axes else out]

    def batch_rule(args, dims, **params):
        # batch axes in front (size 1 where not batched), ranks padded to match
        args = [jnp.expand_dims(x, 0) if dim is None else jnp.moveaxis(x, dim, 0)
                for x, dim in zip(args, dims, strict=True)]
        ndim = max(x.ndim for x in args)
        args = [x.reshape(x.shape[:1] + (1,) * (ndim - x.ndim) + x.shape[1:]) for x in args]
        return prim.bind(*args, **params), 0

    def jvp_rule(primals, tangents, **params):
        raise NotImplementedError(SECOND_ORDER)

    prim.def_impl(impl)
    prim.def_abstract_eval(abstract)
    mlir.register_lowering(prim, mlir.lower_fun(impl, multiple_results=False))
    ad.primitive_transposes[prim] = transpose_rule
    ad.primitive_jvps[prim] = jvp_rule
    batching.primitive_batchers[prim] = batch_rule
    return prim


def as_vectors(x, d: int, name: str):
    """``x`` as a JAX array of real floats with shape ``(..., d)`` (integers become the
    default float type), at trace time.

    Raises
    ------
    TypeError
        For a bool, complex or other non-real dtype.
    ValueError
        For a shape other than ``(..., d)``.
    """
    require_jax()
    import jax.numpy as jnp

    arr = jnp.asarray(x)
    floating = jnp.issubdtype(arr.dtype, jnp.floating)
    if not (floating or jnp.issubdtype(arr.dtype, jnp.integer)):  # bool is no integer here
        raise TypeError(f"{name} must hold real numbers (a float or integer dtype), got "
                        f"dtype {arr.dtype}")
    if not floating:
        arr = arr.astype(jnp.result_type(float))
    if arr.ndim == 0 or arr.shape[-1] != d:
        got = "a scalar" if arr.ndim == 0 else f"shape {arr.shape}"
        raise ValueError(f"{name} must have shape (..., {d}) (vectors of dimension {d}), "
                         f"got {got}")
    return arr


def pl_function(values, host, d: int, name: str):
    """The JAX function ``x (..., d) -> values(x)`` of a host's piecewise-linear map: its
    value by :func:`host_call`, its JVP by :func:`tangent_map` (exact forward mode, the
    host's stated piece in reverse mode); ``name`` is the argument's name in errors."""
    jax = require_jax()

    @jax.custom_jvp
    def value(x):
        return host_call(values, x.dtype, x)

    @value.defjvp
    def value_jvp(primals, tangents):
        (x,), (t,) = primals, tangents
        return value(x), tangent_map(x, t, host.tangents, host.cotangents)

    def function(x):
        return value(as_vectors(x, d, name))

    return function
