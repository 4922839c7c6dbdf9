"""Rigid bodies with point contacts: a hybrid system from the equations of motion.

:func:`contact_system` takes generalized coordinates ``q`` (m), the mass matrix ``M(q)``,
the generalized forces and the contacts' gap functions ``phi_k(q)`` (>= 0 apart) and
builds the :class:`~bderiv.analysis.system.HybridSystem` of state ``x = (q, q')`` (d = 2m) with
one event per contact, the penetration ``h_k = -phi_k(q)`` (touchdown: an upward crossing;
lift-off: downward):

- in stance contact k pushes along its normal ``J_k = d phi_k / dq`` with the force
  ``lambda_k = law(-phi_k, -J_k q')`` of its penetration and penetration rate (a
  compliant law; default a spring-damper ``contact_stiffness * pen + contact_damping *
  rate``, parameters changeable with ``with_params``), so the field is

      M(q) q'' = forces - C(q, q') q' + sum_k s_k J_k^T lambda_k,

  ``s_k`` the contact's flag (1 in stance) and ``C(q, q') q'`` the Coriolis and centrifugal
  terms derived from ``M`` (Christoffel symbols; ``coriolis=False`` leaves them out);
- at touchdown an impact resets the velocity, ``q'+ = q'- - (1 + e) w (J q'-) / (J w)``
  with ``w = M^-1 J^T``: plastic (``e = 0``) zeroes the contact's normal velocity ``J q'``
  (the state stays on the surface and the stance begins: docs/mathematics.md section 9,
  "Where a reset lands"), restitution ``e > 0`` reverses and scales it (a bounce: the
  contact's bit is kept, the body flies on). ``impact=None``: no impulse, the compliant
  law alone.

How the mass matrix is handled: never inverted symbolically (the solution's expressions
grow about 7-fold per coordinate: 216118 operations for 6 of the quadruped's 7); the
kernels fill ``M`` and the right-hand side from cse'd expressions and solve in compiled
code, and every Jacobian is exact through the implicit-function rule
(:mod:`bderiv.symbolic._mechanics`, which gives the measurements). For m = 7 the solve is
a few hundred flops, below the cost of the expressions themselves.

Simultaneous impacts (docs/mathematics.md section 9, "When the B-derivative exists", which
derives the condition): two plastic or restitution impacts at once commute, so that the
state after them and the B-derivative exist, exactly when the contacts are orthogonal in
the inverse-mass metric, ``J_i M^-1 J_j^T = 0`` (the impulse at one does not change the
other's normal velocity). :class:`ImpactCheck` (the model's ``reset_guard``) checks it
wherever an impact resets the state while another contact is hit at the same instant
(approaching, not yet in stance, and reached within ``IMPACT_SIMULTANEITY_TOL`` seconds at
its closing speed, ``|phi| <= speed * IMPACT_SIMULTANEITY_TOL``: the time the library's runs
group events by; one reached measurably later is hit on its own, after): in the
simulation, the B-derivative at a point and along trajectories; coupled contacts are
refused with their names, the coupling and what to do (a compliant contact,
``impact=None``, or the impacts one after the other). The check is local: a quadruped's
feet on spring legs are orthogonal at a pronking touchdown, where the legs are vertical,
and coupled where the body is pitched.
:func:`coupling` gives the matrix at any state.
"""

from __future__ import annotations

import time

import numpy as np

from .._limits import COUPLING_TOL, IMPACT_SIMULTANEITY_TOL
from .._support._validate import check_value
from ..analysis.system import HybridSystem
from . import _contact_checks as checks
from ._contact_checks import DEFAULT_STANCE
from ._contact_model import ContactModel
from ._inputs import (
    _check_free,
    _expressions,
    _sequence,
    _symbols,
    assumed_params,
    refuse_partial_piecewise,
    require_sympy,
)
from ._mechanics import COUPLING_SIGNATURE, MECHANICS_VERSION, generate
from ._model import OnFirstCall, load_model, symbolic_system
from ._solve import SOLVE_DIGEST

__all__ = ["COUPLING_TOL", "DEFAULT_STANCE", "IMPACT_SIMULTANEITY_TOL", "ImpactCheck",
           "contact_system", "coupling"]


def coupling(model, x) -> np.ndarray:
    """``J M^-1 J^T`` (n, n) of a model of :func:`contact_system` at the state ``x`` (d,)
    or the coordinates ``q`` (m,), with the model's parameter values: entry (i, j) is the
    change of contact i's normal velocity per unit impulse at contact j; zero off the
    diagonal where the contacts are mass-orthogonal.

    Raises
    ------
    TypeError
        If ``model`` was not built by :func:`contact_system`.
    ValueError
        If ``x`` has neither shape.

    Examples
    --------
    A ball on a floor and a wall at angle beta to the vertical: orthogonal impulses at
    beta = 0, coupled by sin(beta) otherwise.

    >>> import sympy as sp
    >>> from bderiv.symbolic import contact_system, coupling
    >>> x, y, beta = sp.symbols("x y beta")
    >>> corner = contact_system([x, y], sp.eye(2), [0, -9.81],
    ...                         [y, sp.cos(beta) * x + sp.sin(beta) * y], impact=0.8,
    ...                         params={beta: 0.0})
    >>> coupling(corner, [0.0, 0.0])
    array([[1., 0.],
           [0., 1.]])
    >>> coupling(corner.with_params(beta=0.5), [0.0, 0.0]).round(6)
    array([[1.      , 0.479426],
           [0.479426, 1.      ]])
    """
    kernel = getattr(getattr(model, "source", None), "coupling", None)
    if kernel is None:
        raise TypeError(f"coupling needs a model built by contact_system, got "
                        f"{type(model).__name__} with source "
                        f"{type(getattr(model, 'source', None)).__name__}")
    x = np.asarray(x, dtype=np.float64)
    m = model.dim // 2
    if x.shape not in ((m,), (2 * m,)):
        raise ValueError(f"x must be a state of shape ({2 * m},) or coordinates of shape "
                         f"({m},), got shape {x.shape}")
    return kernel(np.concatenate((x[:m], np.zeros(m), model.params)))


class ImpactCheck:
    """A contact model's ``reset_guard``: before the impact of contact k (a touchdown),
    refuse it (ValueError naming the contacts, the coupling and the remedies) when another
    contact is hit at the same instant and coupled to k through the inverse mass matrix.

    "At the same instant": contact j approaches (its closing speed ``r_j = d(-phi_j)/dt``
    > 0), is not in stance, and its gap is closed within the time the library's runs
    group events by, ``|phi_j| <= r_j * IMPACT_SIMULTANEITY_TOL`` (a first-order time to
    contact of 1e-7 s at most, whatever the gap's size): a contact reached measurably
    later is hit on its own (a wall 5e-7 m away approached at 1e-4 m/s is hit 5 ms later).

    Called as the model's functions are, on ``x`` (d + n_params,): the state followed by
    the parameter values.
    """

    def __init__(self, kernels, coupling_kernel, contacts):
        self.kernels, self.coupling_kernel, self.contacts = kernels, coupling_kernel, contacts

    def __call__(self, x, mask, k) -> None:
        mask, k = int(mask), int(k)
        if mask >> k & 1:  # a lift-off: no impact
            return
        x = np.ascontiguousarray(x, dtype=np.float64)
        d = self.kernels.dim
        m = d // 2
        h = self.kernels.events(x)
        rate = self.kernels.event_jacobian(x)[:, :m] @ x[m:d]  # d(-phi)/dt
        now = np.abs(h) <= rate * IMPACT_SIMULTANEITY_TOL  # hit within the tolerance
        hit = [j for j in range(self.kernels.n_events)
               if j != k and now[j] and rate[j] > 0.0 and not mask >> j & 1]
        if not hit:
            return
        C = self.coupling_kernel(np.concatenate((x[:m], np.zeros(m), x[d:])))
        for j in hit:
            rel = abs(C[k, j]) / np.sqrt(abs(C[k, k] * C[j, j]))
            if not rel <= COUPLING_TOL:
                a, b = sorted((k, j))
                raise ValueError(
                    f"contacts {a} (phi = {self.contacts[a]}) and {b} (phi = "
                    f"{self.contacts[b]}) are hit at the same instant and are coupled "
                    f"through the inverse mass matrix: J_{a} M^-1 J_{b}^T = {C[a, b]:.6g} "
                    f"({rel:.3g} relative to J_{a} M^-1 J_{a}^T = {C[a, a]:.6g} and J_{b} "
                    f"M^-1 J_{b}^T = {C[b, b]:.6g}), so the impulse at one changes the "
                    f"other's normal velocity: the impacts do not commute, the state after "
                    f"them depends on their order and the flow has no B-derivative there. "
                    f"Make the contacts compliant (impact=None, the stance law alone), or "
                    f"treat the impacts one after the other (a state where they are not "
                    f"simultaneous)"
                )


def contact_system(q, mass_matrix, forces, contacts, stance=None, impact="plastic",
                   params=None, *, velocities=None, flags=None, coriolis=True,
                   cache_dir=None) -> HybridSystem:
    """A body with point contacts as a compiled hybrid system (module docstring).

    Parameters
    ----------
    q : sequence of sympy.Symbol, length m
        The generalized coordinates; the state is ``(q, q')``, d = 2m.
    mass_matrix : sympy.Matrix or nested sequence, (m, m)
        ``M(q)``, symmetric positive definite, in q and the parameters. Symmetry is
        checked symbolically; positive definiteness numerically: where ``M`` does not
        depend on q, at the parameter values (here and by ``with_params``: a Cholesky
        factorization), and wherever the kernels evaluate it (every field, Jacobian,
        reset and coupling solves with its factorization ``L D L^T``, so a state where
        ``M`` is singular or indefinite raises a ValueError naming the mass matrix).
    forces : sequence of sympy.Expr, length m
        The generalized forces other than the inertial and contact ones (gravity, springs,
        dampers, actuators), in q, the velocities, the flags and the parameters.
    contacts : sequence of sympy.Expr, length n
        The gaps ``phi_k(q)``, >= 0 apart, in q and the parameters: event k is
        ``-phi_k``.
    stance : callable or list of n callables, optional
        ``law(penetration, rate) -> normal force`` (sympy expressions in, one out; it may
        use the state and the parameters too). Default: ``contact_stiffness * pen +
        contact_damping * rate``, parameters with the values of :data:`DEFAULT_STANCE`
        unless ``params`` names them.
    impact : "plastic", ("restitution", e), float e in [0, 1], sympy expression or None
        The velocity reset at touchdown (e = 0 plastic; a number becomes the parameter
        ``restitution``, changeable with ``with_params``); None: no impulse. An
        expression in the parameters must be in [0, 1] at their values (checked here and
        by ``with_params``, as a number is).
    params : mapping sympy.Symbol -> float, optional
        Parameter values (``with_params`` changes them without re-deriving): real numbers,
        exact sympy ones (``sympy.pi``) and 0-d arrays converted by ``float()``.
    velocities : sequence of sympy.Symbol, length m, optional
        The symbols of q' (default ``<name>_dot`` for each coordinate). A symbol takes
        one role: coordinates, velocities, flags and parameters are distinct symbols.
    flags : sequence of sympy.Symbol, length n, optional
        Symbols the forces may use for "contact k in stance" (1) or not (0): friction,
        thrust. Default: new ones (the forces then cannot name them).
    coriolis : bool
        Add the Coriolis and centrifugal terms derived from ``M(q)`` (default True).
    cache_dir : optional
        As for :func:`~bderiv.symbolic.from_sympy`.

    Returns
    -------
    HybridSystem
        Its functions the compiled kernels (as :func:`~bderiv.symbolic.from_sympy`'s), its
        ``reset_guard`` an :class:`ImpactCheck` when there are impacts, its ``source`` a
        :class:`~bderiv.symbolic.SymbolicSource` with the contacts and the coupling kernel
        (:func:`coupling`).

    Raises
    ------
    TypeError, ValueError
        Wrong lengths or types (named), a symbol in two roles (named, with both), a
        non-symmetric mass matrix, one that does not depend on q and is not positive
        definite at the parameter values, contacts depending on velocities or flags, free
        symbols that are not coordinates, velocities, flags or parameters, a stance law
        that does not return one expression (named), a restitution outside [0, 1] (at the
        parameter values), a Piecewise without an otherwise branch; as
        :func:`~bderiv.symbolic.from_sympy`.

    Examples
    --------
    A ball of unit mass in a corner: a floor and a wall at angle ``beta`` to the
    vertical, restitution 0.8; its impact on the floor at 3 m/s:

    >>> import numpy as np, sympy as sp
    >>> from bderiv.symbolic import ModelFunctions, contact_system
    >>> x, y, beta = sp.symbols("x y beta")
    >>> corner = contact_system([x, y], sp.eye(2), [0, -9.81],
    ...                         [y, sp.cos(beta) * x + sp.sin(beta) * y], impact=0.8,
    ...                         params={beta: 0.0})
    >>> ModelFunctions(corner).reset(np.array([1.0, 0.0, 0.5, -3.0]), 0, 0)
    array([1. , 0. , 0.5, 2.4])
    """
    started = time.perf_counter()
    sp = require_sympy()
    q = _symbols(q, "q")
    m = len(q)
    if not m:
        raise ValueError("q must have at least one coordinate, got none")
    v = (_symbols(velocities, "velocities") if velocities is not None
         else [sp.Symbol(f"{s.name}_dot") for s in q])
    if len(v) != m:
        raise ValueError(f"velocities must have one symbol per coordinate ({m}), got {len(v)}")
    n = len(_sequence(contacts, "contacts", "gap functions"))
    phis = _expressions(contacts, "contacts", n, "one gap per contact")
    if not n:
        raise ValueError("contacts must have at least one gap function, got none")
    s = (_symbols(flags, "flags") if flags is not None
         else [sp.Dummy(f"contact_{k}") for k in range(n)])
    if len(s) != n:
        raise ValueError(f"flags must have one symbol per contact ({n}), got {len(s)}")
    if not isinstance(coriolis, bool | np.bool_):
        raise TypeError(f"coriolis must be True or False, got {type(coriolis).__name__}")
    if params is not None and not hasattr(params, "items"):
        raise TypeError(f"params must be a mapping symbol -> value, got "
                        f"{type(params).__name__}")
    params = dict(params or {})
    for sym in params:
        if not isinstance(sym, sp.Symbol):
            raise TypeError(f"params keys must be sympy Symbols, got {type(sym).__name__} "
                            f"{sym!r}")
    laws, added_law = checks.laws(stance, n, params)
    e, added_e = checks.restitution(impact, params)
    checks.refuse_shared(_roles(q, v, velocities is None, s, params, added_law, added_e))
    params = {sym: check_value(value, f"params[{sym}]")
              for sym, value in {**params, **added_law, **added_e}.items()}
    M = checks.matrix(mass_matrix, m)
    forces = _expressions(forces, "forces", m, f"one per coordinate, m = {m}")
    names = set(params)
    where = "are not coordinates or parameters"
    for i, row in enumerate(M):
        for j, entry in enumerate(row):
            _check_free(f"mass_matrix[{i}][{j}]", entry, set(q) | names, where)
    for k, phi in enumerate(phis):
        _check_free(f"contacts[{k}]", phi, set(q) | names, where + " (a gap depends on the "
                    "coordinates only)")
        if not phi.free_symbols & set(q):  # (it failed at the run: on the surface, or 1/0)
            raise ValueError(f"contacts[{k}] = {phi} does not depend on the coordinates q: "
                             f"its gap never changes, so the contact is never made or "
                             f"broken")
    allowed = set(q) | set(v) | set(s) | names
    unknown = "are neither coordinates, velocities, flags nor parameters"
    for i, f in enumerate(forces):
        _check_free(f"forces[{i}]", f, allowed, unknown)
    if e is not None:
        _check_free("the restitution", e, names, "are not parameters")
    pen = [sp.Dummy(f"pen_{k}") for k in range(n)]
    rate = [sp.Dummy(f"rate_{k}") for k in range(n)]
    lams = []
    for k, law in enumerate(laws):
        lam = checks.stance_force(law, k, pen[k], rate[k])
        _check_free(f"the stance force of contact {k}", lam, allowed | {pen[k], rate[k]},
                    unknown)
        lams.append(lam)
    for label, expr in [*((f"mass_matrix[{i}][{j}]", M[i][j]) for i in range(m)
                          for j in range(m)),
                        *((f"forces[{i}]", f) for i, f in enumerate(forces)),
                        *((f"contacts[{k}]", phi) for k, phi in enumerate(phis)),
                        *((f"the stance force of contact {k}", lam)
                          for k, lam in enumerate(lams)),
                        *([("the restitution", e)] if e is not None else [])]:
        refuse_partial_piecewise(label, expr, expr)

    # canonical symbols: x_i (q then q'), s_k, p_j
    pnames = list(params)
    if len({str(p) for p in pnames}) != len(pnames):
        raise ValueError("params has two symbols of the same name; with_params could not "
                         "tell them apart: rename one")
    x = tuple(sp.Symbol(f"x_{i}", real=True) for i in range(2 * m))
    sc = tuple(sp.Symbol(f"s_{k}", real=True) for k in range(n))
    pc = tuple(sp.Symbol(f"p_{j}", real=True) for j in range(len(pnames)))
    pens = tuple(sp.Symbol(f"pen_{k}", real=True) for k in range(n))
    rates = tuple(sp.Symbol(f"rate_{k}", real=True) for k in range(n))
    to = {**dict(zip([*q, *v], x, strict=True)), **dict(zip(s, sc, strict=True)),
          **dict(zip(pnames, pc, strict=True)), **dict(zip(pen, pens, strict=True)),
          **dict(zip(rate, rates, strict=True))}

    def canon(exprs):
        return tuple(sp.sympify(e).xreplace(to) for e in exprs)

    model = ContactModel(
        M=tuple(map(canon, M)), forces=canon(forces), contacts=canon(phis), laws=canon(lams),
        restitution=None if e is None else canon([e])[0], coriolis=bool(coriolis), x=x,
        s=sc, p=pc, pen=pens, rate=rates, param_names=tuple(map(str, pnames)),
        values=np.array([params[p] for p in pnames], dtype=np.float64),
        original={c: u for u, c in to.items()}, names=tuple(map(str, phis)))
    constant = not any(entry.free_symbols & set(x) for row in model.M for entry in row)
    param_check = checks.ParamCheck(
        pc, model.param_names, model.restitution if e is not None and e.free_symbols else None,
        str(e), M=model.M if constant else None, assumed=assumed_params(pnames))
    param_check(model.values)  # before the derivation and the compilation
    module, kernels, build = load_model(
        model, [f"bderiv.symbolic.contacts {MECHANICS_VERSION}", f"solve {SOLVE_DIGEST}",
                f"sympy {sp.__version__}", *model.canonical_text()], generate, cache_dir,
        started=started)
    coupled = OnFirstCall(module.coupling, COUPLING_SIGNATURE)
    guard = None if kernels.reset is None else ImpactCheck(kernels, coupled,
                                                            model.names)
    return symbolic_system(kernels, model.values, build, "contact_system",
                           coupling=coupled, contacts=model.names, reset_guard=guard,
                           param_check=param_check)


def _roles(q, v, default_v: bool, s, params, added_law, added_e) -> list:
    """The roles of contact_system's symbols for :func:`._contact_checks.refuse_shared`."""
    return [
        ("a coordinate", {c: f"q[{i}]" for i, c in enumerate(q)}),
        ("a velocity", {c: f"the velocity of q[{i}], named by default: pass velocities="
                        if default_v else f"velocities[{i}]" for i, c in enumerate(v)}),
        ("a flag", {c: f"flags[{k}]" for k, c in enumerate(s)}),
        ("a parameter", {**{p: "a key of params" for p in params},
                         **{p: "of the default stance law" for p in added_law},
                         **{p: "impact's restitution" for p in added_e}}),
    ]
