"""Progress reporting: ``progress=`` values become ``callback(done, total)``."""

from __future__ import annotations

import io
import sys

import pytest

from bderiv._progress import TqdmCallback, resolve_progress


def test_none_false_and_callables():
    assert resolve_progress(None) is None
    assert resolve_progress(False) is None
    seen = []
    cb = resolve_progress(lambda done, total: seen.append((done, total)))
    cb(3, 10)
    assert seen == [(3, 10)]
    with pytest.raises(TypeError, match="progress must be None, a bool or a callable"):
        resolve_progress(3)


def test_tqdm_bar_advances_and_closes():
    pytest.importorskip("tqdm")
    out = io.StringIO()
    bar = resolve_progress(True, desc="work", file=out, mininterval=0)
    assert isinstance(bar, TqdmCallback)
    bar(40, 100)
    bar(40, 100)  # no step: nothing to add
    bar(100, 100)  # reaching the total closes the bar
    assert bar.done == 100 and bar._bar is None
    text = out.getvalue()
    assert "work" in text and "100/100" in text
    with TqdmCallback("again", file=io.StringIO()) as other:
        other(1, 5)
    assert other._bar is None


def test_missing_tqdm_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "tqdm.auto", None)  # import tqdm.auto -> ImportError
    with pytest.raises(ImportError, match=r"bderiv\[progress\]"):
        resolve_progress(True)


def test_bderivative_progress_true_draws_a_bar(capsys):
    """``BDerivative.apply(..., progress=True)`` plugs the tqdm bar into the chunked path."""
    pytest.importorskip("tqdm")
    import numpy as np

    from bderiv import BDerivative

    F = np.ones((4, 2))
    F[1] = (2.0, 1.0)
    bd = BDerivative(np.eye(2), F)
    V = np.random.default_rng(0).standard_normal((5000, 2))
    W = bd.apply(V, progress=True, chunk_size=1000)
    np.testing.assert_array_equal(W, bd(V))
    err = capsys.readouterr().err
    assert "5.00k/5.00k" in err or "5000/5000" in err
