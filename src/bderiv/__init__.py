"""bderiv: exact, fast Bouligand derivatives of piecewise-differentiable flows at points
where several events happen at once."""

import importlib as _importlib
from importlib import metadata as _metadata

#: the public names and the modules that hold them, imported at their first use (PEP 562):
#: ``import bderiv`` alone costs a few milliseconds, so that ``python -m bderiv`` says what
#: it does before numba, scipy and the kernels load
_WHERE = {
    "BDerivative": "engine.bderivative", "LowRankResets": "engine.bderivative",
    "CornerFunction": "geometry.corners", "CornerModel": "geometry.corners",
    "StructuredCorners": "geometry.corners",
    "FlowBDerivative": "analysis.flowmap", "check_jacobians": "analysis.jacobians",
    "complex_step_jacobian": "analysis.jacobians", "SolverOptions": "models.integrate.options",
    "HybridSystem": "analysis.system", "Triangulation": "geometry.triangulation",
    "load_triangulation": "geometry.triangulation",
}


def __getattr__(name):
    if name in _WHERE:
        value = getattr(_importlib.import_module(f".{_WHERE[name]}", __name__), name)
    elif name == "examples":
        value = _importlib.import_module(".examples", __name__)
    else:
        raise AttributeError(f"module 'bderiv' has no attribute {name!r}")
    # every cached kernel imported so far: a damaged cache file is compiled again, never
    # raised (kernels imported later are hardened when their drivers are made); and a
    # first compilation is announced (_compiling)
    _importlib.import_module("._kernels._cache", __name__).harden_all()
    _importlib.import_module("._support._compiling", __name__)
    globals()[name] = value
    return value


def __dir__():
    return sorted([*globals(), *_WHERE, "examples"])

try:
    __version__ = _metadata.version("bderiv")
except _metadata.PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0+unknown"

__all__ = [
    "FlowBDerivative",
    "HybridSystem",
    "SolverOptions",
    "examples",
    "BDerivative",
    "CornerFunction",
    "CornerModel",
    "LowRankResets",
    "StructuredCorners",
    "Triangulation",
    "__version__",
    "check_jacobians",
    "complex_step_jacobian",
    "load_triangulation",
]
