"""``from_sympy``: a :class:`~bderiv.analysis.system.HybridSystem` from sympy expressions.

The compiled kernels (:mod:`bderiv.symbolic._codegen` lists them) live in a generated
module in the cache folder (:mod:`bderiv.symbolic._cache`); :class:`Kernels` holds them,
:class:`ModelFunctions` wraps them in Python signatures on the state alone, and
:class:`SymbolicSystem` is the ``HybridSystem`` whose functions they are, with its
parameter values (:func:`symbolic_system`).
"""

from __future__ import annotations

import dataclasses
import re
import time
from dataclasses import KW_ONLY, dataclass

import numpy as np

from ..analysis.system import HybridSystem
from . import _cache, _codegen
from ._inputs import check_model, check_value, require_sympy


@dataclass(frozen=True)
class Kernels:
    """The numba kernels of a symbolic model (the njit dispatchers; no validation).

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
        True when the generated source was found in the cache (no derivation).
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


class ModelFunctions:
    """The kernels with the Python signatures of :class:`~bderiv.analysis.system.HybridSystem`.

    Each method checks the state (converted to float64; shapes other than (d,) are
    refused: the kernels do not check bounds) and calls its kernel on the state followed
    by the parameter values ``params``.
    """

    def __init__(self, kernels: Kernels, params: np.ndarray):
        self.k, self.p = kernels, params
        self.d, self.n = kernels.dim, kernels.n_events

    def _x(self, x):
        x = np.asarray(x, dtype=np.float64)
        if x.shape != (self.d,):
            raise ValueError(f"x must have shape ({self.d},), got shape {x.shape}")
        return np.concatenate((x, self.p))

    def field(self, x, mask):
        """``field(x, mask) -> (d,)``."""
        return self.k.field(self._x(x), mask)

    def field_jacobian(self, x, mask):
        """``field_jacobian(x, mask) -> (d, d)``."""
        return self.k.field_jacobian(self._x(x), mask)

    def events(self, x):
        """``events(x) -> (n,)``."""
        return self.k.events(self._x(x))

    def event_jacobian(self, x):
        """``event_jacobian(x) -> (n, d)``."""
        return self.k.event_jacobian(self._x(x))

    def corner_field(self, x):
        """``corner_field(x) -> (2**n, d)``: row ``mask`` is ``field(x, mask)``."""
        return self.k.corner_field(self._x(x))

    def reset(self, x, mask, k):
        """``reset(x, mask, k) -> (d,)``."""
        return self.k.reset(self._x(x), mask, k)

    def reset_jacobian(self, x, mask, k):
        """``reset_jacobian(x, mask, k) -> (d, d)``."""
        return self.k.reset_jacobian(self._x(x), mask, k)


@dataclasses.dataclass(frozen=True, eq=False, repr=False)
class SymbolicSystem(HybridSystem):
    """A :class:`~bderiv.analysis.system.HybridSystem` built by :func:`from_sympy`.

    Every method of ``HybridSystem`` applies: it is one, its functions the compiled
    :attr:`kernels` (:class:`Kernels`, the njit functions) with the parameter values
    ``params``, its Jacobians given (derived, not checked against differences), on the
    compiled path (every stop included: the kernels' event Jacobian and resets are
    compiled; a section must then be a numba dispatcher) unless it is on the scipy path
    (:meth:`scipy_path`). It adds no hook: what it adds is data (the kernels, how they
    were built) and the ways to another model over the same kernels.

    Attributes
    ----------
    kernels : Kernels
    functions : ModelFunctions
        The kernels with the Python signatures, on the state alone.
    params : ndarray, shape (n_params,)
        The parameter values (read-only), in the order of ``kernels.param_names``.
    build : BuildInfo
    """

    _: KW_ONLY
    kernels: Kernels = None
    build: BuildInfo = None
    functions: ModelFunctions = dataclasses.field(init=False, compare=False)

    def __post_init__(self):
        super().__post_init__()
        object.__setattr__(self, "functions", ModelFunctions(self.kernels, self.params))

    def scipy_path(self) -> SymbolicSystem:
        """The same model integrated by :func:`scipy.integrate.solve_ivp` through the
        Python calls of its kernels: for a Python section, another method than DOP853,
        or to compare the two integrators."""
        return dataclasses.replace(self, use_compiled=False)

    @property
    def param_values(self) -> dict:
        """``{name: value}`` of the parameters."""
        return dict(zip(self.kernels.param_names, self.params.tolist(), strict=True))

    def with_params(self, values=None, /, **by_name) -> SymbolicSystem:
        """The same model with other parameter values: no derivation, no compilation.

        Parameters
        ----------
        values : mapping, optional
            ``{symbol or name: value}``.
        **by_name
            ``name=value``.

        Returns
        -------
        SymbolicSystem
            A new system sharing this one's kernels (on the same path); unnamed
            parameters keep their value.

        Raises
        ------
        TypeError
            If a value is not a real number, or ``values`` not a mapping.
        ValueError
            If a name is not a parameter of the model (the parameters are listed), or a
            value is not finite.
        """
        if values is not None and not hasattr(values, "items"):
            raise TypeError(f"values must be a mapping parameter -> value, got "
                            f"{type(values).__name__}")
        new = self.params.copy()
        index = {name: j for j, name in enumerate(self.kernels.param_names)}
        for name, value in [*(values or {}).items(), *by_name.items()]:
            if str(name) not in index:
                known = ", ".join(self.kernels.param_names) or "none"
                raise ValueError(f"{name} is not a parameter of this model (its parameters: "
                                 f"{known})")
            new[index[str(name)]] = check_value(value, f"the value of {name}")
        return dataclasses.replace(self, params=new)

    def __repr__(self):
        params = ", ".join(f"{k}={v:g}" for k, v in self.param_values.items())
        return (f"{type(self).__name__}(n_events={self.n_events}, dim={self.dim}"
                f"{', resets' if self.reset is not None else ''}"
                f"{', params: ' + params if params else ''})")


def symbolic_system(kernels: Kernels, values, build: BuildInfo, *, kind=SymbolicSystem,
                    **more) -> SymbolicSystem:
    """The model of ``kernels`` with the parameter values ``values``: a ``kind`` (a
    :class:`SymbolicSystem`) whose functions are the kernels themselves (``more``: the
    fields ``kind`` adds)."""
    k = kernels
    resets = k.reset is not None
    # the Jacobians are derived, not written by hand: no difference check at first use
    return kind(k.field, k.events, n_events=k.n_events, dim=k.dim,
                event_jacobian=k.event_jacobian, field_jacobian=k.field_jacobian,
                corner_field=k.corner_field, reset=k.reset if resets else None,
                reset_jacobian=k.reset_jacobian if resets else None, check_jacobians=False,
                params=np.array(values, dtype=np.float64), kernels=k, build=build, **more)


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
        Parameter values, changed later by :meth:`SymbolicSystem.with_params` without
        re-deriving or recompiling (the kernels take them as an array).
    cache_dir : str or os.PathLike, optional
        Root of the cache folder (default ``$BDERIV_CACHE_DIR``, else
        ``~/.cache/bderiv``; :mod:`bderiv.symbolic._cache`).

    Returns
    -------
    SymbolicSystem
        A ``HybridSystem`` with all its functions and Jacobians given; ``build`` says
        whether the cache was hit and what the derivation and compilation took.

    Raises
    ------
    TypeError
        Symbols that are not sympy Symbols, expressions that are not sympy expressions,
        parameter values that are not real numbers.
    ValueError
        Wrong lengths, flags in the events, free symbols that are neither state, flags
        nor parameters (named), non-finite parameter values, an expression that does not
        compile (named: printing as Python or numba typing fails).
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
    return symbolic_system(kernels, model.values, build)


def load_model(model, key_parts, generate, cache_dir, extra=None, *, started):
    """The generated module of ``model``, its kernels and how they were got.

    ``key_parts`` (strings) identify the model and its generator; ``generate(model, key)``
    returns the module's source, written to the cache unless it is there already;
    ``extra`` ``{name: signature}`` are further kernels of the module compiled likewise
    (``module.<name>``); ``started`` is when the caller began checking its arguments
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
        for name, signature in (extra or {}).items():
            _compile_closed(getattr(module, name), signature)
    except Exception as exc:  # numba refused the generated source: name the expression
        path.unlink(missing_ok=True)
        raise _locate_compile_error(model, exc) from None
    build = BuildInfo(key=key, cached=cached, check_seconds=start - started,
                      derive_seconds=derived - start, load_seconds=time.perf_counter() - derived)
    return module, kernels, build
