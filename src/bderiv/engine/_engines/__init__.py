"""Evaluation engines behind :class:`~bderiv.BDerivative`: one per corner representation
(``dense``, ``structured``, ``function``), all with the interface of ``base.Engine`` and
the fast paths of ``fastpath``."""

from __future__ import annotations

from .dense import DenseEngine
from .function import FunctionEngine
from .structured import StructuredEngine

__all__ = ["DenseEngine", "FunctionEngine", "StructuredEngine"]
