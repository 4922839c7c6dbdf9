"""``from_sympy``: a :class:`~bderiv.analysis.system.HybridSystem` from sympy expressions.

The compiled kernels (:mod:`bderiv.symbolic._codegen` lists them) live in a generated
module in the cache folder (:mod:`bderiv.symbolic._cache`); :class:`Kernels` holds them,
and the model is the plain ``HybridSystem`` whose functions they are, with its parameter
values and a :class:`SymbolicSource` saying where it came from (:func:`symbolic_system`);
:class:`ModelFunctions` calls a model's functions on the state alone.
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass

import numpy as np

from .._support._format import format_region, format_state, note_call
from .._support._validate_ints import check_int, check_mask
from ..analysis.system import HybridSystem
from ..models.compiled import is_compiled
from . import _cache, _codegen
from ._inputs import assumed_params, check_model, require_sympy


@dataclass(frozen=True)
class Kernels:
    """The numba kernels of a symbolic model (the njit dispatchers; no validation but the
    length of ``x``: another is refused with a ValueError).

    Attributes
    ----------
    field, field_jacobian, events, event_jacobian, corner_field : numba dispatcher
        ``field(x, mask) -> (d,)`` ... as in :mod:`bderiv.symbolic._codegen`: ``x``
        (d + n_params,) C-contiguous float64, the state then the parameter values;
        ``mask`` and ``k`` int64. Each returns a new array.
    reset, reset_jacobian : numba dispatcher or None
        None for a model without resets.
    dim, n_events, n_params : int
    param_names : tuple of str
        The parameters in the order they follow the state in ``x``.
    source : pathlib.Path
        The generated module.
    """

    field: object
    field_jacobian: object
    events: object
    event_jacobian: object
    corner_field: object
    reset: object
    reset_jacobian: object
    dim: int
    n_events: int
    n_params: int
    param_names: tuple
    source: object


@dataclass(frozen=True)
class BuildInfo:
    """How :func:`from_sympy` got the kernels.

    Attributes
    ----------
    key : str
        The hash of the model's expressions (the cache file's name).
    cached : bool
        True when the generated module was found in bderiv's cache (no derivation); not
        numba's cache of its kernels (where that is gone, ``load_seconds`` shows them compiled).
    check_seconds : float
        Time of the argument checks and the cache key (the expressions' canonical text).
    derive_seconds : float
        Time of the symbolic derivation, cse and printing (0 when cached).
    load_seconds : float
        Time of importing the generated module: numba compilation, or loading the
        compiled kernels from numba's cache.
    """

    key: str
    cached: bool
    check_seconds: float
    derive_seconds: float
    load_seconds: float


@dataclass(frozen=True)
class SymbolicSource:
    """Where a model of :mod:`bderiv.symbolic` came from: its ``source``
    (:class:`~bderiv.analysis.system.HybridSystem`), shared by the models
    :meth:`~bderiv.analysis.system.HybridSystem.with_params` makes from it.

    Attributes
    ----------
    builder : str
        ``"from_sympy"`` or ``"contact_system"``.
    kernels : Kernels
        The njit functions (the model's functions are these: ``model.field is
        kernels.field``); ``kernels.source`` is the generated module.
    build : BuildInfo
        Whether the cache was hit and what the derivation and compilation took.
    coupling : OnFirstCall or None
        ``J M^-1 J^T`` from ``(q, 0, params)`` (:func:`bderiv.symbolic.coupling`), a
        kernel compiled at its first call; None but for
        :func:`~bderiv.symbolic.contact_system`.
    contacts : tuple of str
        The gap functions as given (in the messages); ``()`` but for
        :func:`~bderiv.symbolic.contact_system`.
    param_check : callable or None
        ``param_check(values)`` raises a ValueError for parameter values the model cannot
        take (:func:`~bderiv.symbolic.contact_system`: a restitution outside [0, 1], a
        mass matrix independent of q that is not positive definite); None: any finite
        values.
    """

    builder: str
    kernels: Kernels
    build: BuildInfo
    coupling: object = None
    contacts: tuple = ()
    param_check: object = None

    @property
    def param_names(self) -> tuple:
        """The parameters' names, in the order their values follow the state in ``x``."""
        return self.kernels.param_names

    def check_params(self, values) -> None:
        """Refuse parameter values (the array, in the order of :attr:`param_names`) that
        the model cannot take (``param_check``); called by ``with_params``."""
        if self.param_check is not None:
            self.param_check(np.asarray(values, dtype=np.float64))


class ModelFunctions:
    """A model's functions with the Python signatures of
    :class:`~bderiv.analysis.system.HybridSystem` on the state alone: ``ModelFunctions(model)``.

    Each method checks its arguments (the state converted to float64, shapes other than
    (d,) refused; ``mask`` an integer in [0, 2**n), ``k`` one in [0, n): TypeError or
    ValueError naming them) and calls the model's function (for a model of
    :mod:`bderiv.symbolic`, its kernel; no output check) on the state followed by the
    model's parameter values ``params``. What the function raises is said as a run says
    it: a numba function's exception (a division by zero, a mass matrix that is not
    positive definite) becomes a ValueError naming the call, the region and the state
    (its cause the exception); a Python function's is raised as it is, with a note naming
    the call and its arguments (Python 3.11+).
    """

    def __init__(self, model):
        self.model = model
        self.p = np.zeros(0) if model.params is None else model.params
        self.d, self.n = model.dim, model.n_events

    def _x(self, x):
        x = np.asarray(x, dtype=np.float64)
        if x.shape != (self.d,):
            raise ValueError(f"x must have shape ({self.d},), got shape {x.shape}")
        return x

    def _call(self, call, x, *ints):
        """``call`` (``"field(x, mask)"``) of the model at the state ``x`` and ``ints``
        (mask, k: checked here), the exception of the function said as a run says it."""
        name = call[:call.index("(")]
        fun = getattr(self.model, name)
        if fun is None:
            raise TypeError(f"the model has no {name}")
        x = self._x(x)
        if ints:
            ints = (check_mask(ints[0], self.n), *ints[1:])
        if len(ints) == 2:
            ints = (ints[0], check_int(ints[1], "k", low=0, high=self.n - 1,
                                       span=f"in [0, {self.n})", meaning="an event"))
        try:
            return fun(np.concatenate((x, self.p)), *ints)
        except Exception as exc:
            if not is_compiled(fun):  # a Python function's own exception: noted, kept
                note_call(exc, call, x, ints, self.n)
                raise
            region = f" in {format_region(ints[0], max(self.n, 1))}" if ints else ""
            event = f", k = {ints[1]}" if len(ints) == 2 else ""
            raise ValueError(f"{call} raised {type(exc).__name__}: {exc};{region} at x = "
                             f"{format_state(x)}{event}") from exc

    def field(self, x, mask):
        """``field(x, mask) -> (d,)``."""
        return self._call("field(x, mask)", x, mask)

    def field_jacobian(self, x, mask):
        """``field_jacobian(x, mask) -> (d, d)``."""
        return self._call("field_jacobian(x, mask)", x, mask)

    def events(self, x):
        """``events(x) -> (n,)``."""
        return self._call("events(x)", x)

    def event_jacobian(self, x):
        """``event_jacobian(x) -> (n, d)``."""
        return self._call("event_jacobian(x)", x)

    def corner_field(self, x):
        """``corner_field(x) -> (2**n, d)``: row ``mask`` is ``field(x, mask)``."""
        return self._call("corner_field(x)", x)

    def reset(self, x, mask, k):
        """``reset(x, mask, k) -> (d,)``."""
        return self._call("reset(x, mask, k)", x, mask, k)

    def reset_jacobian(self, x, mask, k):
        """``reset_jacobian(x, mask, k) -> (d, d)``."""
        return self._call("reset_jacobian(x, mask, k)", x, mask, k)


def symbolic_system(kernels: Kernels, values, build: BuildInfo, builder="from_sympy", *,
                    coupling=None, contacts=(), reset_guard=None,
                    param_check=None) -> HybridSystem:
    """The model of ``kernels`` with the parameter values ``values``: a
    :class:`~bderiv.analysis.system.HybridSystem` whose functions are the kernels
    themselves, its ``source`` a :class:`SymbolicSource`."""
    k = kernels
    resets = k.reset is not None
    source = SymbolicSource(builder, k, build, coupling, tuple(contacts), param_check)
    # the Jacobians are derived, not written by hand: no difference check at first use
    return HybridSystem(k.field, k.events, n_events=k.n_events, dim=k.dim,
                        event_jacobian=k.event_jacobian, field_jacobian=k.field_jacobian,
                        corner_field=k.corner_field, reset=k.reset if resets else None,
                        reset_jacobian=k.reset_jacobian if resets else None,
                        check_jacobians=False, params=np.array(values, dtype=np.float64),
                        reset_guard=reset_guard, source=source)


def _locate_compile_error(model, exc):
    """The ValueError naming the first user expression numba refuses alone (else the
    module's error)."""
    import numba

    namespace = {}
    exec(compile(_codegen.probe_source(model), "<bderiv.symbolic probe>", "exec"), namespace)
    sig = "float64(float64[::1], int64)"
    for i, (label, e) in enumerate(model.labelled()):
        try:
            numba.njit(sig)(namespace[f"probe_{i}"])
        except Exception as probe_exc:  # numba's TypingError and its relatives
            return ValueError(f"{label} = {model.show(e)} does not compile with numba: "
                              f"{_numba_reason(probe_exc)}")
    return ValueError(f"the generated kernels do not compile with numba: "
                      f"{_numba_reason(exc)}")


def _numba_reason(exc) -> str:
    """The informative line of a numba error: the second line (the first says which
    pipeline failed), without the terminal's colour codes."""
    lines = [ln.strip() for ln in re.sub(r"\x1b\[[0-9;]*m", "", str(exc)).splitlines()]
    lines = [ln for ln in lines if ln]
    return lines[1] if len(lines) > 1 and lines[0].startswith("Failed in") else (
        lines[0] if lines else type(exc).__name__)


def _compile_closed(dispatcher, signature):
    """``dispatcher`` compiled for ``signature`` only, through bderiv's checked cache."""
    from .._kernels._cache import harden

    if not dispatcher.signatures:
        harden(dispatcher).compile(signature)
        dispatcher.disable_compile()
    return dispatcher


class OnFirstCall:
    """A kernel of a generated module compiled (as :func:`_compile_closed` does) at its
    first call, not at the build: a contact model's ``coupling`` is called only where
    two contacts are hit at once, or by :func:`bderiv.symbolic.coupling`, and compiling
    it took 0.4-0.8 s of a model's 4-5 s. Its expressions are the reset's (``J``, ``M``),
    which the build compiled, so numba does not refuse it later."""

    def __init__(self, dispatcher, signature: str):
        self.dispatcher, self.signature = dispatcher, signature

    def __call__(self, *args):
        return _compile_closed(self.dispatcher, self.signature)(*args)


def compile_kernels(model, module, path) -> Kernels:
    """The kernels of the generated ``module``, each compiled for its signature only.

    Each is given bderiv's checked numba cache first (:func:`bderiv._kernels._cache.harden`:
    a damaged cache entry is compiled again, never run), so a second process loads the
    machine code instead of compiling; then its compilation is closed (other argument
    types are refused, not compiled). Compiled once per process.
    """
    names = _codegen.KERNELS + (_codegen.RESET_KERNELS if module.HAS_RESETS else ())
    found = {}
    for name in names:
        found[name] = _compile_closed(getattr(module, name), _codegen.SIGNATURES[name])
    return Kernels(**found, **{name: None for name in _codegen.RESET_KERNELS
                               if name not in found},
                   dim=model.dim, n_events=model.n_events, n_params=len(model.p),
                   param_names=model.param_names, source=path)


def from_sympy(state, flags, field, events, resets=None, params=None, *, cache_dir=None):
    """A :class:`~bderiv.analysis.system.HybridSystem` from sympy expressions, compiled with numba.

    One expression covers all 2**n regions through the flags: flag k is 1 where event k
    has happened (bit k of the region's mask), 0 before. The Jacobians are derived
    symbolically (exact), common subexpressions shared, and the kernels generated as
    numba source cached on disk (a second process loads them: no derivation, no
    compilation).

    Parameters
    ----------
    state : sequence of sympy.Symbol, length d
        The state variables.
    flags : sequence of sympy.Symbol, length n
        One per event.
    field : sequence of sympy.Expr, length d
        The vector field, in state, flags and parameters.
    events : sequence of sympy.Expr, length n
        The event functions h_k (event k happens where h_k crosses 0; region bit k set
        where h_k > 0), in state and parameters (no flags).
    resets : mapping int -> sequence of sympy.Expr (length d), optional
        The state right after crossing event k, in state, flags and parameters; the flags
        are those before the crossing (flag k = 0: an upward crossing, 1: downward; write
        ``s_k * v + (1 - s_k) * v_after`` for a jump at touchdown only). Events without an
        entry do not move the state. Simultaneous resets must commute (HybridSystem).
    params : mapping sympy.Symbol -> float, optional
        Parameter values (exact sympy numbers and 0-d arrays by ``float()``), changed by
        :meth:`~bderiv.analysis.system.HybridSystem.with_params` without re-deriving or
        recompiling (the kernels take them as an array).
    cache_dir : str or os.PathLike, optional
        Root of the cache folder (default ``$BDERIV_CACHE_DIR``, else
        ``~/.cache/bderiv``; :mod:`bderiv.symbolic._cache`).

    Returns
    -------
    HybridSystem
        With all its functions and Jacobians given (the kernels), on the compiled path;
        its ``source`` (:class:`SymbolicSource`) holds the kernels and ``build``, which
        says whether the cache was hit and what the derivation and compilation took.

    Raises
    ------
    TypeError
        Symbols that are not sympy Symbols, expressions that are not sympy expressions,
        parameter values that are not real numbers.
    ValueError
        Wrong lengths, flags in the events, free symbols that are neither state, flags
        nor parameters (named), non-finite parameter values, an expression that does not
        compile (named: printing as Python or numba typing fails, a number overflows a
        double) or has a Piecewise without an otherwise branch.
    ImportError
        Without sympy (``pip install 'bderiv[symbolic]'``).
    OSError
        If the cache folder cannot be created or written (named).
    """
    started = time.perf_counter()
    sympy = require_sympy()
    model = check_model(state, flags, field, events, resets, params)
    _, kernels, build = load_model(
        model, [f"bderiv.symbolic codegen {_codegen.CODEGEN_VERSION}",
                f"sympy {sympy.__version__}", *model.canonical_text()],
        _codegen.generate, cache_dir, started=started)
    return symbolic_system(kernels, model.values, build, param_check=assumed_params(
        [model.original[p] for p in model.p]))


def load_model(model, key_parts, generate, cache_dir, *, started):
    """The generated module of ``model``, its kernels and how they were got.

    ``key_parts`` (strings) identify the model and its generator; ``generate(model, key)``
    returns the module's source, written to the cache unless it is there already;
    ``started`` is when the caller began checking its arguments
    (:func:`time.perf_counter`).

    Returns
    -------
    module, Kernels, BuildInfo
    """
    key = _cache.model_key(key_parts)
    path = _cache.module_path(_cache.cache_folder(cache_dir), key)
    source = _cache.read(path)  # None: missing, or damaged (removed)
    cached = source is not None
    start = time.perf_counter()
    if not cached:
        source = generate(model, key)
        try:
            _cache.store(path, source)
        except OSError as exc:
            raise OSError(f"cannot write the generated kernels to {path}: {exc}; set "
                          f"{_cache.CACHE_ENV} or pass cache_dir= a writable folder") from None
    derived = time.perf_counter()
    try:
        module = _cache.load(path, key, source)
        kernels = compile_kernels(model, module, path)
    except Exception as exc:  # numba refused the generated source: name the expression
        path.unlink(missing_ok=True)
        raise _locate_compile_error(model, exc) from None
    build = BuildInfo(key=key, cached=cached, check_seconds=start - started,
                      derive_seconds=derived - start, load_seconds=time.perf_counter() - derived)
    return module, kernels, build
