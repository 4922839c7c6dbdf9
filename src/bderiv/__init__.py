"""bderiv: exact, fast Bouligand derivatives of piecewise-differentiable flows at points
where several events happen at once."""

from importlib.metadata import PackageNotFoundError, version

from .bderivative import BDerivative
from .triangulation import Triangulation

try:
    __version__ = version("bderiv")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0+unknown"

__all__ = ["BDerivative", "Triangulation", "__version__"]
