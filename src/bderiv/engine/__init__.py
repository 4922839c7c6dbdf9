"""The engine: :class:`~bderiv.engine.bderivative.BDerivative` (validate, pick an engine,
evaluate batches, pieces), one evaluation engine per corner representation
(``_engines``, the one its tables call for chosen in ``_representation``), linearisation
of any piecewise-linear map (``_linearise``), the corner geometry of a B-derivative
(``_geometry``) and the benchmark baselines (``_baselines``)."""

from .._support import _compiling  # noqa: F401 - a first compilation is announced
