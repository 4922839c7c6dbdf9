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
    # once: a later operation's kernels compile silently, and the notice says so (a review)
    assert said == ["bderiv: compiling the B-derivative kernels this call needs for this "
                    "machine (their first use here, seconds; each other operation, as "
                    "event_times or jvp, compiles its own at its first call; numba keeps "
                    "them on disk for later processes; `python -m bderiv compile` compiles "
                    "them ahead)"]
    assert np.isfinite(_not_ours(1.0))


def test_a_symbolic_models_generated_functions_are_announced(tmp_path, caplog, monkeypatch):
    """The modules from_sympy generates are named by bderiv.symbolic._cache, not under the
    package: the family matches that name (it once matched ``bderiv.symbolic`` and never
    fired)."""
    from bderiv.symbolic import _cache

    module = _cache.load(tmp_path / "m_probe.py", "probe0notice",
                         "import numba\n\n@numba.njit\ndef field(x):\n    return x + 1.0\n")
    monkeypatch.setattr(_compiling.NOTICE, "said", set())
    monkeypatch.setattr(logging.getLogger("bderiv.compiling"), "level", logging.NOTSET)
    with caplog.at_level(logging.WARNING, logger="bderiv"):
        _compile_event(module.field)
    assert [r.getMessage() for r in caplog.records] == [
        "bderiv: compiling a symbolic model's generated functions for this machine (their "
        "first use here, seconds; numba keeps them on disk for later processes)"]


def test_a_submodule_import_announces_first_compilations():
    """``from bderiv.examples import chair`` (no public name of ``bderiv`` read) registers
    the notice: the packages whose calls compile import it."""
    import subprocess
    import sys

    probe = ("import sys\nfrom bderiv.examples import chair\n"
             "print('bderiv._support._compiling' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "True"
