"""The Jacobians a model does not give: how each is computed, and what they cost.

A missing Jacobian is had by complex step (exact to rounding, d calls) where that matched a
central difference the first time for its function, mask and event, at that state and
beside it (:func:`trusted`), else by central differences (10 to 100 calls per variable);
where the complex step fails at a later state, by central differences from then on. The
decision is kept per key, and forgotten
when the model's evaluations switch to other code (Python first: the Python code and the
compiled functions may differ in what they make of complex input). The cost is counted
per missing parameter, and a build that spent most of its time on them says so
(:class:`~bderiv.models.calls.ModelCalls` holds one :class:`NumericalJacobians`).
"""

from __future__ import annotations

import contextlib
import logging
import time

import numpy as np

from .._limits import SLOW_BUILD_SECONDS
from .._support import _numdiff as numdiff
from .._support._validate import all_finite
from .user_functions import numerical_jacobian

_log = logging.getLogger("bderiv")

#: how a Jacobian not given is computed (the first use of each function and mask decides)
_COMPLEX, _CENTRAL = "complex step", "central differences"

#: the end of the slow build's warning for a model of Python functions
_COMPILED_HINT = ("; or write its functions with numba (@numba.njit): the compiled "
                  "integrator built flow maps of such models 62-100x faster "
                  "(docs/tutorial.md, section 12)")


#: the second point where a complex step is held to central differences: this fraction of
#: each variable's scale away from the first, along a fixed direction
NEAR = 1e-3


def _matches(fun, x, J, scales=None) -> bool:
    """Whether ``J`` matches a central difference of ``fun`` at ``x`` along a random
    direction, the test of a given Jacobian (``scales``: that of ``numdiff.compare``)."""
    try:
        with np.errstate(all="ignore"):  # a scale beyond float64's square root: not trusted
            return numdiff.compare(fun, x, J, scales=scales).passed
    except ValueError:
        return False


def matches_near(fun, complex_jacobian, x) -> bool:
    """Whether the complex step ``complex_jacobian(y)`` matches a central difference of
    ``fun`` at a point ``y`` near ``x`` too (:data:`NEAR` of each variable's scale, along
    a fixed direction whose entries are 1/2 to 1 in size; the difference along the scales
    of ``x``): a function that is not complex-analytic can match at one point and not
    beside it (``abs(v) * v`` at v = 0, where both are 0). True where ``fun`` has no value
    at ``y``, the complex step none (a later refusal goes to central differences then) or
    central differences none: the first point's match decides."""
    rng = np.random.default_rng(1)
    direction = rng.uniform(0.5, 1.0, x.size) * rng.choice((-1.0, 1.0), x.size)
    scales = numdiff.variable_scales(x)
    y = x + NEAR * scales * direction
    try:
        with np.errstate(all="ignore"):
            if not all_finite(np.asarray(fun(y), dtype=np.float64)):
                return True
        J = complex_jacobian(y)
        return J is None or _matches(fun, y, J, scales)
    except Exception:  # noqa: BLE001 - no value, complex step or difference beside x
        return True


def trusted(fun, complex_jacobian, x, J) -> bool:
    """Whether a complex-step Jacobian is trusted for a function and mask: ``J`` at ``x``
    matches a central difference of ``fun`` there, and :func:`matches_near`."""
    return _matches(fun, x, J) and matches_near(fun, complex_jacobian, x)


class _Counted:
    """``fun`` with its calls counted (those of the checks that decide how a Jacobian is
    computed count in its cost)."""

    def __init__(self, fun):
        self.fun, self.calls = fun, 0

    def __call__(self, *args):
        self.calls += 1
        return self.fun(*args)


class NumericalJacobians:
    """A model's numerical Jacobians: ``how`` (key -> complex step or central differences),
    ``generation`` (of the functions they are taken of: one more at each :meth:`forget`),
    their cost per name, and the builds warned about."""

    def __init__(self):
        self.how = {}
        self.generation = 0
        self._cost = {}  # name -> [Jacobians, calls, seconds]
        self._warned = set()

    def forget(self) -> None:
        """The decisions were made on other code (the model's evaluations switched)."""
        self.how = {}
        self.generation += 1

    def jacobian(self, key, fun, raw, x, shape, what, jac_name):
        """The Jacobian of ``fun`` at ``x`` (``shape``, cost counted): the complex step of
        ``raw`` (the user's function, unchecked) where it matched a central difference of
        ``fun`` the first time for ``key``, else central differences; one computed across a
        :meth:`forget` is computed again. ``what`` gives the call's name for a message
        (formatted only then)."""
        start, generation = time.perf_counter(), self.generation
        table = self.how  # the decisions of these functions: a switch to the compiled ones
        how = table.get(key)  # meanwhile (another thread, a probe) starts a new table
        # NumPy's discarded imaginary parts refused (a branch of the function may cast)
        stepped = _Counted(raw)  # (a refusal of complex input ends the step early)
        J = None if how == _CENTRAL else numdiff.complex_step(stepped, x, shape[0])
        calls = stepped.calls
        if how == _COMPLEX and J is None:  # it took complex input once, not here
            _log.info("the complex step of %s failed at x = %s (the function does not take "
                      "complex input there): central differences from now on", what(), x)
            how = table[key] = _CENTRAL
        if how is None:  # the first time for this key: held to central differences twice
            counted, counted_raw = _Counted(fun), _Counted(raw)
            how = _COMPLEX if J is not None and trusted(
                counted, lambda y: numdiff.complex_step(counted_raw, y, shape[0]), x,
                J) else _CENTRAL
            calls += counted.calls + counted_raw.calls
            table[key] = how
            if jac_name not in self._cost:
                _log.info("%s not given: computing it by %s (%s); pass %s to save that time",
                          jac_name, how, "d calls of the function per Jacobian"
                          if how == _COMPLEX else "the function does not take complex input "
                          "or is not complex-analytic: 10 to 100 calls per variable",
                          jac_name)
        if how == _CENTRAL:
            D = numerical_jacobian(fun, x, what(), jac_name)
            J, calls = D.value, calls + D.calls
        if self.generation != generation:  # the functions switched under it: again, on
            return self.jacobian(key, fun, raw, x, shape, what, jac_name)  # theirs
        cost = self._cost.setdefault(jac_name, [0, 0, 0.0])
        cost[0] += 1
        cost[1] += calls
        cost[2] += time.perf_counter() - start
        return J

    @contextlib.contextmanager
    def watch(self, what, python=False):
        """Around a build (``what``: the method's name): when it took over
        ``SLOW_BUILD_SECONDS``, most of it in numerical Jacobians, say so at WARNING (logger
        ``"bderiv"``) with their count, calls and time, once per model and method; a model
        of Python functions (``python``) is also told of the compiled path."""
        before = {name: tuple(c) for name, c in self._cost.items()}
        start = time.perf_counter()
        yield
        took = time.perf_counter() - start
        spent = {name: (c[0] - before.get(name, (0, 0, 0.0))[0],
                        c[1] - before.get(name, (0, 0, 0.0))[1],
                        c[2] - before.get(name, (0, 0, 0.0))[2])
                 for name, c in self._cost.items()}
        seconds = sum(s[2] for s in spent.values())
        if took < SLOW_BUILD_SECONDS or seconds < 0.5 * took or what in self._warned:
            return
        self._warned.add(what)
        parts = ", ".join(f"{name}: {n:,} Jacobians, {calls:,} calls, {sec:.2f} s "
                          f"({self._how_of(name)})" for name, (n, calls, sec) in spent.items()
                          if n)
        _log.warning("%s took %.2f s, %.2f s of it (%.0f %%) in numerical Jacobians (%s): "
                     "pass them to the model (HybridSystem's field_jacobian, event_jacobian, "
                     "reset_jacobian; bderiv.complex_step_jacobian writes one from a "
                     "function that takes complex input)%s", what, took, seconds,
                     100 * seconds / took, parts, _COMPILED_HINT if python else "")

    def _how_of(self, jac_name) -> str:
        """How the numerical ``jac_name`` was computed: by which of the two, or both."""
        hows = {how for key, how in self.how.items() if key[0] == jac_name}
        return " and ".join(sorted(hows))

    @property
    def cost(self) -> dict:
        """``{name: (Jacobians, calls, seconds)}`` so far."""
        return {name: (c[0], c[1], c[2]) for name, c in self._cost.items()}
