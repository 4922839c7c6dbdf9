"""``bderiv.jax.flow``: the flow map of a hybrid system as a differentiable JAX function."""

from __future__ import annotations

import numpy as np

from .._support._validate import check_number, check_state
from .._support._validate_ints import check_positive_int
from ..analysis.system import HybridSystem
from ..models.integrate.options import DERIVATIVE_OPTIONS, SolverOptions
from ._host import FlowHost
from ._primitive import pl_function


def flow(system, t_final, *, direction=None, simultaneity_tol=None,
         options=None, rtol=None, atol=None, method=None, max_step=None, cache_size=256):
    """The flow map ``x0 -> Phi(t_final, x0)`` of a :class:`~bderiv.HybridSystem` as a
    JAX function, with the exact B-derivative as its forward mode.

    Parameters
    ----------
    system : HybridSystem
    t_final : float
        Final time, > 0.
    direction : array_like, shape (d,), optional
        A tangent at the start point: reverse mode (``grad``, ``vjp``, ``jacrev``) uses
        the transpose of the linear piece it selects (the same one for every start
        point). Needed only where the B-derivative has several pieces (simultaneous
        events, or an event group at the final time); without it reverse mode refuses
        them.
    simultaneity_tol : float, optional
        Events within this time of each other form one group of the B-derivative (as for
        :meth:`~bderiv.HybridSystem.flow_bderivative`, default 1e-7). The value itself is
        :meth:`~bderiv.HybridSystem.simulate`'s, with its own (1e-12).
    options, rtol, atol, method, max_step : optional
        Integrator settings of the simulations (:class:`~bderiv.SolverOptions`).
    cache_size : int
        B-derivatives kept, one per distinct start point (default 256): forward and
        reverse passes at one point build it once.

    Returns
    -------
    callable
        ``phi(x0)``: ``x0`` of shape ``(..., d)`` (a float or integer JAX or NumPy array),
        the final states ``(..., d)`` in x0's float dtype (enable ``jax_enable_x64`` for
        float64: bderiv computes in float64 and casts). Works under ``jax.jit``,
        ``jax.vmap`` (one host call for the whole batch), ``jax.jvp`` / ``jax.linearize``
        / ``jax.jacfwd`` (the B-derivative applied to each tangent, exact at simultaneous
        events whichever piece the tangent lies in) and ``jax.grad`` / ``jax.vjp`` /
        ``jax.jacrev`` (the transpose of the piece ``direction`` selects). Not twice
        differentiable (NotImplementedError).

    Raises
    ------
    TypeError, ValueError
        At once, for a bad argument (named); when ``phi`` is traced, for an ``x0`` of
        the wrong dtype or shape. A refusal of bderiv while it computes (a start on an
        event surface, a grazing crossing, a non-finite start, ...) reaches the caller
        as the exception JAX raises for a failed callback, whose message ends with
        bderiv's, the start point named first: ``jax.errors.JaxRuntimeError`` (a
        ValueError once JAX runs the computation on its fast dispatch path, after a
        successful call); JAX also logs the callback's traceback.

    Notes
    -----
    At a point where events happen together the flow is piecewise differentiable: its
    B-derivative ``D(x0)`` is continuous and piecewise linear, one linear piece per event
    order (docs/mathematics.md, section 2). Forward mode returns ``D(x0)(t)``, the exact
    directional derivative in every direction t. A gradient is one matrix: reverse mode
    returns ``J^T w`` with ``J`` the piece that ``direction`` selects (the limit of the
    classical Jacobians at ``x0 + s * direction`` as ``s -> 0+``, an element of the
    Bouligand and so of Clarke's generalized Jacobian). ``<w, D(x0)(t)> = <J^T w, t>``
    holds for the tangents t of that piece only. ``jax.jacfwd`` stacks ``D(x0)(e_i)``,
    each unit vector through its own piece, which is in general no piece.

    Examples
    --------
    >>> import jax
    >>> from bderiv.examples import chair
    >>> from bderiv.jax import flow
    >>> jax.config.update("jax_enable_x64", True)
    >>> ex = chair()                    # two legs touch the ground together at t = 0.1
    >>> phi = flow(ex.system, ex.t_final)
    >>> x_final, dx = jax.jvp(phi, (ex.x0,), (jax.numpy.eye(6)[2],))  # a pitch perturbation
    >>> bool(abs(dx - ex.system.flow_bderivative(ex.x0, ex.t_final)(np.eye(6)[2])).max()
    ...      < 1e-12)
    True
    """
    if not isinstance(system, HybridSystem):
        raise TypeError(f"system must be a HybridSystem, got {type(system).__name__}")
    d = system.dim
    t_final = check_number(t_final, "t_final")
    options = SolverOptions.resolve(options, DERIVATIVE_OPTIONS, rtol=rtol, atol=atol,
                                    method=method, max_step=max_step,
                                    simultaneity_tol=simultaneity_tol)
    cache_size = check_positive_int(cache_size, "cache_size")
    if direction is not None:
        direction = _check_direction(direction, d)
    host = FlowHost(system, t_final, options=options, direction=direction,
                    cache_size=cache_size)
    phi = pl_function(host.final_states, host, d, "x0")
    phi.__name__ = phi.__qualname__ = "flow_map"
    phi.__doc__ = f"x0 (..., {d}) -> Phi({t_final:g}, x0) of {system!r} (bderiv.jax.flow)"
    return phi


def _check_direction(direction, d: int) -> np.ndarray:
    arr = check_state(direction, d, "direction", meaning="a tangent at the start point")
    if not arr.any():
        raise ValueError(f"direction must be finite and nonzero (it selects a piece), got "
                         f"{arr.tolist()}")
    arr.setflags(write=False)
    return arr
