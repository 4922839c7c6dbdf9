"""Using bderiv from JAX: flow maps and B-derivatives as differentiable JAX functions.

- :func:`flow`: ``x0 -> Phi(t_final, x0)`` of a :class:`~bderiv.HybridSystem`; forward
  mode is the exact B-derivative (every tangent through its own piece at simultaneous
  events), reverse mode the transpose of the one piece a stated direction selects;
- :func:`bmap`: a :class:`~bderiv.BDerivative` or :class:`~bderiv.FlowBDerivative` as
  ``u -> M(u)``, differentiated by the piece at u.

Both run bderiv on the host through :func:`jax.pure_callback` and work under ``jit``,
``vmap`` (one host call per batch), ``jvp`` and ``grad``. Needs the optional extra
``jax``; this package imports jax only when one of them is called (``import bderiv``
never does). docs/jax.md compares the derivatives with diffrax's at a simultaneous
touchdown.

Layout
------
- ``_host``: the NumPy side (simulations, B-derivatives per start point, pieces);
- ``_primitive``: the JAX side (the host callbacks, the tangent-map primitive that gives
  a function an exact forward mode and a stated reverse mode, input checks);
- ``_flow``, ``_bmap``: the two public functions.
"""

from ._bmap import bmap
from ._flow import flow

__all__ = ["bmap", "flow"]
