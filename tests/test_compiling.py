"""The notice of a first compilation (:mod:`bderiv._support._compiling`): once per family."""

from __future__ import annotations

import logging

import numba
import numpy as np
from numba.core import event

from bderiv._kernels import dense
from bderiv._support import _compiling


@numba.njit
def _not_ours(x):
    return x + 1.0


def _compile_event(dispatcher, inner=None):
    data = {"dispatcher": dispatcher, "args": (), "return_type": None}
    with event.trigger_event("numba:compile", data=data):
        if inner is not None:
            _compile_event(inner)


def test_each_family_is_announced_once_and_nested_compiles_not(caplog, monkeypatch):
    monkeypatch.setattr(_compiling.NOTICE, "said", set())
    logger = logging.getLogger("bderiv.compiling")
    monkeypatch.setattr(logger, "level", logging.NOTSET)
    with caplog.at_level(logging.WARNING, logger="bderiv"):
        _compile_event(_not_ours)  # not bderiv's: nothing
        _compile_event(_not_ours, inner=dense.widest_rate_spread)  # compiled into another
        assert not caplog.records
        _compile_event(dense.widest_rate_spread)
        _compile_event(dense.widest_rate_spread)
    said = [r.getMessage() for r in caplog.records]
    assert said == ["bderiv: compiling the B-derivative kernels this call needs for this "
                    "machine (their first use here, seconds to a minute; numba keeps them on "
                    "disk for later processes; `python -m bderiv compile` compiles them "
                    "ahead)"]
    assert np.isfinite(_not_ours(1.0))
