"""Progress reporting: ``progress=`` values become ``callback(done, total)``."""

from __future__ import annotations

import io
import sys

import numpy as np
import pytest

from bderiv._support._progress import TqdmCallback, resolve_progress


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


def _raise_at(k, exc):
    """A progress callback that raises ``exc`` at its k-th call."""
    calls = []

    def progress(done, total):
        calls.append((done, total))
        if len(calls) == k:
            raise exc

    return progress, calls


def test_callback_that_raises_mid_batch_says_how_far_the_work_got():
    """The callback's exception stops the batch at that chunk and is chained: a
    ProgressCallbackError (a ValueError) naming the call, its cause the original."""
    import numpy as np

    from bderiv import BDerivative
    from bderiv._support._progress import ProgressCallbackError

    bd = BDerivative(np.eye(2), np.array([[1.0, 1.0], [2.0, 1.0], [1.0, 3.0], [2.0, 2.0]]))
    V = np.random.default_rng(0).standard_normal((10_000, 2))
    boom = ZeroDivisionError("my callback's bug")
    progress, calls = _raise_at(3, boom)
    with pytest.raises(ProgressCallbackError, match=r"the progress callback progress raised "
                       r"ZeroDivisionError\(\"my callback's bug\"\) at progress\(3000, 10000\)"
                       r", after 3000 of 10000 vectors: the work stopped there") as info:
        bd.apply(V, progress=progress, chunk_size=1000)
    assert isinstance(info.value, ValueError) and info.value.__cause__ is boom
    assert calls == [(1000, 10_000), (2000, 10_000), (3000, 10_000)]  # no chunk after it


def test_callback_error_in_nested_progress_is_said_once():
    """fd_check hands forward_differences a callback around the user's: the user's
    exception is wrapped once, with fd_check's counts (all steps of eps)."""
    import numpy as np

    from bderiv import examples
    from bderiv._support._progress import ProgressCallbackError
    from bderiv.analysis.checks import fd_check

    ex = examples.chair()
    V = np.random.default_rng(0).standard_normal((2, ex.system.dim))
    D = ex.system.flow_bderivative(ex.x0, ex.t_final)
    progress, calls = _raise_at(3, KeyError("stop"))
    with pytest.raises(ProgressCallbackError) as info:
        fd_check(ex.system, ex.x0, ex.t_final, V, D(V), eps=(1e-4, 1e-5), progress=progress)
    assert str(info.value).count("the progress callback") == 1
    assert "at progress(3, 4), after 3 of 4 vectors" in str(info.value)
    assert isinstance(info.value.__cause__, KeyError) and calls[-1] == (3, 4)


def test_long_simulation_shows_progress_and_stops_on_ctrl_c(monkeypatch):
    """simulate(max_step=1e-7) would run for hours: its bar of simulated time appears
    after the delay, and a Ctrl-C (SIGINT, delivered as Python delivers it) stops it
    within a second."""
    import _thread
    import signal
    import threading
    import time

    from bderiv import examples
    from bderiv._support import _progress

    pytest.importorskip("tqdm")
    buffer = io.StringIO()
    monkeypatch.setattr(_progress, "BAR_DELAY", 0.2)
    monkeypatch.setattr(_progress, "BAR_OPTIONS",
                        {"file": buffer, "disable": False, "leave": True})
    # a background job may ignore SIGINT: take it as an interactive session does
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    ex = examples.chair()
    sent = []
    timer = threading.Timer(1.0, lambda: (sent.append(time.monotonic()),
                                          _thread.interrupt_main(signal.SIGINT)))
    try:
        timer.start()
        with pytest.raises(KeyboardInterrupt):
            ex.system.simulate(ex.x0, ex.t_final, max_step=1e-7)
        stopped = time.monotonic()
    finally:
        timer.cancel()
        signal.signal(signal.SIGINT, previous)
    assert sent and stopped - sent[0] < 1.0
    text = buffer.getvalue()
    assert "simulate: " in text and f"of {ex.t_final:.4g} [" in text, text
    assert "t = 0 of" not in text.split("\r")[-1]  # it moved


def test_short_simulations_draw_no_bar(monkeypatch):
    """The bar waits for BAR_DELAY: a run shorter than that draws nothing."""
    from bderiv import examples
    from bderiv._support import _progress

    buffer = io.StringIO()
    monkeypatch.setattr(_progress, "BAR_OPTIONS",
                        {"file": buffer, "disable": False, "leave": True})
    ex = examples.chair()
    ex.system.simulate(ex.x0, ex.t_final)
    assert buffer.getvalue() == ""


def test_a_large_batch_goes_in_chunks_and_gives_the_same_numbers(monkeypatch):
    """A batch in one call held Ctrl-C for seconds (5e6 rows of d = 30: up to 2.9 s, a
    review): above IMPLICIT_CHUNK_ROWS rows it goes chunk by chunk, with the same bits
    and the same error index."""
    from bderiv import BDerivative
    from bderiv._support import _batch

    rng = np.random.default_rng(3)
    bd = BDerivative(np.eye(2) + 0.1, np.abs(rng.standard_normal((4, 2))) + 0.5)
    V = rng.standard_normal((1000, 2))
    whole = bd(V)
    calls = []
    real = _batch._run

    def counted(kernel, rows, *args):
        calls.append(rows.shape[0])
        return real(kernel, rows, *args)

    monkeypatch.setattr(_batch, "_run", counted)
    monkeypatch.setattr(_batch, "IMPLICIT_CHUNK_ROWS", 300)
    monkeypatch.setattr(_batch, "DEFAULT_CHUNK_ROWS", 256)
    assert bd(V).tobytes() == whole.tobytes() and calls == [256, 256, 256, 232]
    V[700, 1] = np.nan
    with pytest.raises(ValueError, match=r"vector V\[700\] = "):
        bd(V)


def _last(buffer, label):
    """The last drawing of the bar labelled ``label``."""
    drawings = [d for d in buffer.getvalue().replace("\n", "\r").split("\r")
                if d.startswith(label + ": ")]
    assert drawings, buffer.getvalue()
    return drawings[-1]


def test_a_newton_search_shows_its_iterate_and_residual(bars_drawn):
    drawn = bars_drawn
    """periodic_orbit's bar (drawn once the search lasts, here at once): the iterate and
    the residual of the last map, which falls to the tolerance."""
    from bderiv.examples import gaits

    ex = gaits.pronking(legs=2)
    guess = ex.x0 + np.array([0.02, 0.01, 0.0, -0.05])
    orbit = ex.system.periodic_orbit(guess, gaits.apex_section, period_guess=0.5)
    last = _last(drawn, "periodic_orbit")
    iterate = len(orbit.history) - 1
    assert last.startswith(f"periodic_orbit: Newton iterate {iterate} (of at most "), last
    residuals = [float(d.split("max |P(x) - x| = ")[1].split(" [")[0])
                 for d in drawn.getvalue().split("\r") if "max |P(x) - x| = " in d]
    assert residuals[0] > 1e-3 and residuals[-1] < 1e-9, residuals


def test_a_growth_rate_a_monte_carlo_and_a_triangulation_count_their_steps(bars_drawn):
    drawn = bars_drawn
    from bderiv import BDerivative
    from bderiv.analysis.stability import growth_rate
    from bderiv.estimate.consistency import consistency
    from bderiv.examples import chair

    A = np.array([[2.0, 1.0], [0.0, 0.5]])
    growth = growth_rate(lambda V: V @ A.T, np.eye(2), iterations=40)
    np.testing.assert_allclose(growth.rates[0], 2.0, rtol=1e-6)
    assert " 40 of 40 iterations [" in _last(drawn, "growth rate")
    consistency(chair(), 3, seed=1)
    assert " 3 of 3 runs [" in _last(drawn, "consistency")
    tri = BDerivative(np.eye(3), np.ones((8, 3))).triangulation()
    tri(np.ones((2, 3)))
    cones = len(tri.simplices)
    assert f" {cones} of {cones} cones [" in _last(drawn, "Triangulation")


def test_default_chunks_are_sized_by_their_time(monkeypatch):
    """Without chunk_size the chunks are sized by their time (progress every half second
    or so, however slow the rows: a corner function at n = 128 reported its first 2**16
    rows after 100 s): the first of FIRST_CHUNK_ROWS, then as many as the last one ran in
    CHUNK_SECONDS, at most DEFAULT_CHUNK_ROWS. The same bits whatever the chunks."""
    from bderiv import BDerivative
    from bderiv._support import _batch

    rng = np.random.default_rng(4)
    bd = BDerivative(np.eye(3) + 0.1, np.abs(rng.standard_normal((8, 3))) + 0.5)
    V = rng.standard_normal((20_000, 3))
    whole, seen = bd(V), []
    assert bd(V, progress=lambda done, total: seen.append(done)).tobytes() == whole.tobytes()
    assert seen[0] == _batch.FIRST_CHUNK_ROWS and seen[-1] == V.shape[0]
    monkeypatch.setattr(_batch, "CHUNK_SECONDS", 1e-12)  # as if each row took ages
    seen.clear()
    assert bd(V, progress=lambda done, total: seen.append(done)).tobytes() == whole.tobytes()
    assert seen[:3] == [4096, 4096 + 1024, 4096 + 2048]  # the smallest: a parallel launch
