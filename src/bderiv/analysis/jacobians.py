"""Check a model's Jacobians at a point (:func:`check_jacobians`), and write one by the
complex step (:func:`complex_step_jacobian`).

For a user writing ``field_jacobian``, ``event_jacobian`` or ``reset_jacobian`` by hand,
in the spirit of :func:`scipy.optimize.check_grad` and ``jax.test_util.check_grads``:
every given Jacobian, for every mask (and event), is compared with a central difference
of its function along a random direction (Richardson-extrapolated, with an error
estimate: :mod:`bderiv._support._numdiff`); a Jacobian not given is computed numerically and its
estimated accuracy reported, so that the report also says where the numerical one would
be refused. :class:`~bderiv.analysis.system.HybridSystem` runs the same comparison once per mask
at the first use of each given Jacobian (``check_jacobians=True``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .._limits import DEFAULT_MASKS
from .._support import _numdiff as numdiff
from .._support._format import format_mask
from .._support._validate import all_finite, check_real_array, check_state
from .._support._validate_ints import check_int, check_masks
from ..models.section import Section
from ..models.user_functions import check_output

__all__ = ["JacobianCheck", "JacobianReport", "check_jacobians", "complex_step_jacobian"]


class JacobianCheck(NamedTuple):
    """One Jacobian of a model at a point.

    Attributes
    ----------
    function : str
        ``"field_jacobian"``, ``"event_jacobian"``, ``"reset_jacobian"`` or
        ``"section_gradient"``.
    mask : int or None
        The region (field and reset), else None.
    event : int or None
        The event k (reset), else None.
    given : bool
        True: the user's Jacobian against a central difference along a random direction;
        False: not given, the numerical Jacobian's own error estimate.
    error : float
        Given: the largest ``|J v - D_v f| / (|J| |v| + |D_v f|)`` over the outputs;
        numerical: the largest estimated error relative to the largest entry of its row
        (of the whole Jacobian for a row of zeros; absolute for a Jacobian of zeros).
    passed : bool
        Given: the mismatch is within ``CHECK_RTOL`` (1e-6) relative plus 8 times the
        difference's error estimate; numerical: every entry reaches the accuracy it needs
        (else the model refuses it: pass the Jacobian).
    detail : str
        Where the worst mismatch is (output component, or entry), with its numbers.
    """

    function: str
    mask: int | None
    event: int | None
    given: bool
    error: float
    passed: bool
    detail: str


class JacobianReport:
    """The checks of :func:`check_jacobians`: ``rows`` (list of :class:`JacobianCheck`),
    ``passed`` (all of them), ``failures``; ``str()`` is a table."""

    def __init__(self, rows, n_events: int):
        self.rows = list(rows)
        self.n_events = n_events

    @property
    def passed(self) -> bool:
        """Whether every Jacobian passed."""
        return all(r.passed for r in self.rows)

    @property
    def failures(self) -> list:
        """The checks that failed."""
        return [r for r in self.rows if not r.passed]

    def _where(self, r) -> str:
        where = "" if r.mask is None else f"mask={format_mask(r.mask, self.n_events)}"
        return where + ("" if r.event is None else f", k={r.event}")

    def __repr__(self):
        bad = self.failures
        if not bad:
            return f"JacobianReport({len(self.rows)} checks, all passed)"
        first = bad[0]
        return (f"JacobianReport({len(self.rows)} checks, {len(bad)} failed; first: "
                f"{first.function}({self._where(first)}))")

    def __str__(self):
        lines = [f"{'function':<17} {'where':<22} {'kind':<9} {'error':>9}  result"]
        for r in self.rows:
            kind = "given" if r.given else "numerical"
            verdict = "ok" if r.passed else f"FAILED: {r.detail}"
            lines.append(f"{r.function:<17} {self._where(r):<22} {kind:<9} "
                         f"{r.error:9.2e}  {verdict}")
        return "\n".join(lines)


def _given(function, mask, event, fun, x, J, seed) -> JacobianCheck:
    c = numdiff.compare(fun, x, J, seed)
    i = c.component
    detail = (f"component {i}: |J v - D_v f| = {c.mismatch[i]:.3g}, tolerance "
              f"{c.tolerance[i]:.3g}")
    return JacobianCheck(function, mask, event, True, c.relative, c.passed, detail)


def _numerical(function, mask, event, fun, x) -> JacobianCheck:
    D = numdiff.jacobian(fun, x)
    size = np.abs(D.value)
    scale = np.maximum(size.max(axis=1, keepdims=True), size.max(initial=0.0))
    ratio = D.error / np.where(scale > 0, scale, 1.0)  # an entry 0 is not infinitely wrong
    with np.errstate(divide="ignore", invalid="ignore"):
        worst = np.where(D.error > 0, D.error / D.needed, 0.0)
    i, j = np.unravel_index(int(np.argmax(worst)), worst.shape)
    detail = (f"entry [{i}, {j}] = {D.value[i, j]:.6g}, estimated error {D.error[i, j]:.3g}"
              f" (needs {D.needed[i, j]:.3g})")
    return JacobianCheck(function, mask, event, False, float(ratio.max(initial=0.0)),
                         bool((D.error <= D.needed).all()), detail)


def check_jacobians(system, x, *, masks=None, section=None, section_gradient=None,
                    seed=0) -> JacobianReport:
    """Check every Jacobian of a model at ``x``, per function and per mask (and event).

    Parameters
    ----------
    system : HybridSystem
    x : array_like, shape (d,)
        The point (any state; the field of every mask is evaluated there, the functions
        are smooth across the surfaces).
    masks : array_like of int, optional
        The regions whose ``field_jacobian`` (and ``reset_jacobian``) are checked;
        default all 2**n (n up to 8; pass them for more events).
    section, section_gradient : callable, optional
        A Poincare section ``section(x) -> float`` and its gradient to check too.
    seed : int
        Seed of the random direction of the comparisons.

    Returns
    -------
    JacobianReport
        One :class:`JacobianCheck` per Jacobian: ``event_jacobian``, ``field_jacobian``
        per mask, ``reset_jacobian`` per mask and event k (a model with resets), the
        section's gradient; ``passed`` says whether all pass, ``str()`` prints a table.

    Raises
    ------
    TypeError, ValueError
        On a bad ``x``, mask or section, named; ValueError also if a function's output
        has the wrong shape or is not finite (as when the model uses it).

    Examples
    --------
    >>> import numpy as np
    >>> from bderiv import HybridSystem, check_jacobians
    >>> field = lambda x, mask: np.array([x[1], -np.sin(x[0]) + (mask & 1)])
    >>> events = lambda x: np.array([x[0] - 0.5])
    >>> good = HybridSystem(field, events, n_events=1, dim=2,
    ...                     event_jacobian=lambda x: np.array([[1.0, 0.0]]),
    ...                     field_jacobian=lambda x, mask: np.array(
    ...                         [[0.0, 1.0], [-np.cos(x[0]), 0.0]]))
    >>> check_jacobians(good, np.array([0.5, 1.0]))
    JacobianReport(3 checks, all passed)
    >>> typo = HybridSystem(field, events, n_events=1, dim=2,
    ...                     field_jacobian=lambda x, mask: np.array(
    ...                         [[0.0, 1.0], [np.cos(x[0]), 0.0]]))  # sign lost
    >>> report = check_jacobians(typo, np.array([0.5, 1.0]))
    >>> report.passed, [(r.function, r.mask, r.given) for r in report.failures]
    (False, [('field_jacobian', 0, True), ('field_jacobian', 1, True)])
    """
    calls = system.calls
    x = check_state(x, calls.dim)
    n, d = calls.n_events, calls.dim
    if masks is None:
        if 1 << n > DEFAULT_MASKS:
            raise ValueError(f"a model with n={n} events has 2**{n} masks: pass masks= "
                             f"(the regions to check), at most {DEFAULT_MASKS} by default")
        masks = range(1 << n)
    masks = check_masks(list(masks), n).tolist()
    check_int(seed, "seed", low=0)
    rows = []

    def add(function, mask, event, jac, fun):
        if jac is None:
            rows.append(_numerical(function, mask, event, fun, x))
        else:
            rows.append(_given(function, mask, event, fun, x, jac(), seed))

    def given(jac, shape, name):  # the checked output of a given Jacobian, or None
        return None if jac is None else lambda *a: check_output(jac(np.array(x), *a), shape,
                                                                name)

    ev = given(calls._event_jac, (n, d), "event_jacobian(x)")
    add("event_jacobian", None, None, ev, calls.eval_events)
    for m in masks:
        fj = given(calls._field_jac, (d, d), f"field_jacobian(x, mask={m})")
        add("field_jacobian", m, None, fj and (lambda m=m, fj=fj: fj(m)),
            lambda y, m=m: calls.eval_field(y, m))
    if calls.has_resets:
        for m in masks:
            for k in range(n):
                rj = given(calls._reset_jac, (d, d), f"reset_jacobian(x, mask={m}, k={k})")
                add("reset_jacobian", m, k, rj and (lambda m=m, k=k, rj=rj: rj(m, k)),
                    lambda y, m=m, k=k: calls.eval_reset(y, m, k))
    if section is not None:
        sec = Section(section, d, section_gradient, check=False)
        sg = given(sec.grad, (d,), "section_gradient(x)")
        add("section_gradient", None, None, sg and (lambda: sg()[None]),
            lambda y: np.array([sec(y)]))
    return JacobianReport(rows, n)


def complex_step_jacobian(fun, x, m=None):
    """The Jacobian of ``fun`` at ``x`` by the complex step: a model's Jacobian in one line.

    Column j is ``Im fun(x + i h e_j) / h`` with ``h = 1e-20 |x_j|`` (at least 1e-200):
    exact to rounding for a complex-analytic function, in d calls, with no step to choose
    (no difference of two values is taken). ``HybridSystem`` uses it by itself for a
    Python model's missing Jacobians where it matches a central difference; write one with
    it where you want it explicitly, or for a function of your own::

        field_jacobian=lambda x, mask: complex_step_jacobian(lambda y: field(y, mask), x)

    (the model then compares it with a central difference at its first use per mask, as it
    does every given Jacobian).

    Parameters
    ----------
    fun : callable
        ``fun(y) -> array_like, shape (m,)``, written so that a complex ``y`` flows through
        it: ``np.sin``, ``**``, arithmetic and ``np.array([...])`` of such terms do;
        ``abs``, ``.real``, ``float(...)``, comparisons of ``y`` and a float array filled
        with complex values (``np.zeros(d)``: use ``np.zeros(d, dtype=y.dtype)``) do not.
    x : array_like, shape (d,)
        A real, finite point.
    m : int, optional
        The size of ``fun``'s output, when known (else one real call finds it).

    Returns
    -------
    ndarray, shape (m, d)

    Raises
    ------
    TypeError
        If ``fun`` does not take complex input (what it raised or returned is said).
    ValueError
        If ``x`` is not a finite 1-d array.

    Examples
    --------
    >>> import numpy as np
    >>> from bderiv import complex_step_jacobian
    >>> complex_step_jacobian(lambda y: np.array([y[0] * np.sin(y[1]), y[0] ** 2]),
    ...                       [2.0, 0.0])
    array([[0., 2.],
           [4., 0.]])
    """
    arr = check_real_array(x, "x")
    if arr.ndim != 1 or not all_finite(arr):
        raise ValueError(f"x must be a finite 1-d array (a state), got {arr!r}")
    arr = np.array(arr, dtype=np.float64)
    if m is None:
        f0 = np.asarray(fun(arr))
        if f0.ndim != 1:
            raise ValueError(f"fun must return a 1-d array, got shape {f0.shape}")
        m = f0.size
    J = numdiff.complex_step(fun, arr, m)
    if J is None:
        probe = arr.astype(np.complex128)
        try:
            out = np.asarray(fun(probe))
            why = (f"it returned {out.dtype} of shape {out.shape}" if out.shape == (m,)
                   else f"it returned shape {out.shape} for a complex state, not ({m},)")
            why = why if np.isfinite(out).all() else "it returned a non-finite value"
        except Exception as exc:  # noqa: BLE001 - named in the message
            why = f"it raised {type(exc).__name__}: {exc}"
        raise TypeError(
            f"fun does not take complex input ({why}); write it so that a complex state "
            f"flows through it (no float(), abs or comparisons of the state; "
            f"np.zeros(d, dtype=y.dtype)), or pass the Jacobian written out"
        )
    return J
