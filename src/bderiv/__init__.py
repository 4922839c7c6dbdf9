"""bderiv: exact, fast Bouligand derivatives of piecewise-differentiable flows at points
where several events happen at once."""

from importlib import metadata as _metadata

from . import examples
from ._kernels._cache import harden_all as _harden_all
from .bderivative import BDerivative, LowRankResets
from .corners import CornerFunction, CornerModel, StructuredCorners
from .flowmap import FlowBDerivative
from .jacobians import check_jacobians, complex_step_jacobian
from .models.integrate.run import SolverOptions
from .models.system import HybridSystem
from .triangulation import Triangulation, load_triangulation

_harden_all()  # every cached kernel: a damaged cache file is compiled again, never raised

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
