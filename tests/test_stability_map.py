"""Stability maps over parameter grids (issue 20 item 5).

Oracle: a planar limit cycle whose growth rate is known in closed form at every grid
point (``cycle``), serially and through a Dask client; the pronking gait on a
two-worker LocalCluster (slow).
"""

from __future__ import annotations

import functools
import time

import numpy as np
import pytest

from bderiv import complex_step_jacobian
from bderiv._support._progress import ProgressCallbackError
from bderiv.analysis.stability_map import StabilityMap, stability_map
from bderiv.analysis.system import HybridSystem


def cycle(multiplier, turns):
    """The cycle r = 1 turning ``turns`` times per unit time; r' = mu (r - 1) (1 - 4 (r -
    1)^2) with mu = log(multiplier), so the return map to y = 0, x > 0 has the period
    1 / turns and the growth rate multiplier ** (1 / turns)."""
    mu, omega = np.log(multiplier), 2 * np.pi * turns

    def field(x, mask):
        r = np.sqrt(x[0] ** 2 + x[1] ** 2)  # complex-safe: Jacobian by the complex step
        g = mu * (r - 1) * (1 - 4 * (r - 1) ** 2) / r
        return np.array([-omega * x[1] + g * x[0], omega * x[0] + g * x[1]])

    return HybridSystem(field, lambda x: np.array([x[0] - 10.0]), n_events=1, dim=2,
                        field_jacobian=lambda x, m: complex_step_jacobian(
                            lambda y: field(y, m), x, 2),
                        event_jacobian=lambda x: np.array([[1.0, 0.0]]))


def section(x):
    return x[1]


GRID = {"multiplier": [0.5, 0.9, 1.5], "turns": [1.0, 2.0]}


def check_closed_form(smap):
    assert isinstance(smap, StabilityMap) and smap.names == ("multiplier", "turns")
    m, turns = np.meshgrid(*smap.values, indexing="ij")
    np.testing.assert_allclose(smap.growth_rate, m ** (1 / turns), rtol=2e-3)
    np.testing.assert_allclose(smap.period, 1 / turns, rtol=1e-8)
    np.testing.assert_allclose(smap.x0[..., 0], 1.0, atol=1e-8)
    assert smap.stable.tolist() == [[True, True], [True, True], [False, False]]
    assert smap.failures == {}


def test_closed_form_growth_rates_serially():
    """Each point's model is built once: the first point's, built to check x_guess, is
    the one its orbit is found on (it was built twice: a robot's URDF loaded again)."""
    calls, built = [], []

    def counted(**params):
        built.append(params)
        return cycle(**params)

    smap = stability_map(counted, GRID, [1.05, 0.0], section, period_guess=1.0,
                         progress=lambda done, total: calls.append((done, total)))
    check_closed_form(smap)
    assert calls[-1] == (6, 6) and len(calls) == 6
    assert len(built) == 6 and built[0] == {"multiplier": 0.5, "turns": 1.0}
    assert "4 stable, 2 unstable, 0 without an orbit" in smap.summary()


def test_through_a_dask_client_the_same_map():
    distributed = pytest.importorskip("distributed")
    with (distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                                   dashboard_address=None,
            scheduler_kwargs={"dashboard_address": ":0"}) as cluster,
          distributed.Client(cluster) as client):
        smap = stability_map(cycle, GRID, [1.05, 0.0], section, period_guess=1.0,
                             client=client)
    check_closed_form(smap)


def test_a_point_without_orbit_is_recorded_not_raised():
    # no return to the section within 3 * period_guess when the cycle turns too slowly
    smap = stability_map(cycle, {"multiplier": [0.5], "turns": [1.0, 0.05]}, [1.05, 0.0],
                         section, period_guess=1.0, max_iter=3)
    assert np.isfinite(smap.growth_rate[0, 0]) and np.isnan(smap.growth_rate[0, 1])
    assert list(smap.failures) == [(0, 1)] and "section" in smap.failures[(0, 1)]
    assert "no orbit at multiplier=0.5, turns=0.05" in smap.summary()


def test_orbits_not_accepted_are_solved_again_from_the_guess():
    # accept only periods below 0.75: turns = 1 (period 1) is refused, and its neighbour
    # turns = 2 then starts from x_guess and is accepted
    smap = stability_map(cycle, {"multiplier": [0.5], "turns": [1.0, 2.0]}, [1.05, 0.0],
                         section, period_guess=1.0, accept=lambda orbit: orbit.period < 0.75)
    assert np.isnan(smap.growth_rate[0, 0]) and "is not accepted" in smap.failures[(0, 0)]
    assert smap.growth_rate[0, 1] == pytest.approx(0.5 ** 0.5, rel=2e-3)


def test_bad_grids_and_clients():
    with pytest.raises(TypeError, match="grid must be a dict of one or two parameters"):
        stability_map(cycle, [0.5], [1.0, 0.0], section)
    with pytest.raises(ValueError, match=r"grid\['turns'\] must be a non-empty 1-d"):
        stability_map(cycle, {"multiplier": [0.5], "turns": []}, [1.0, 0.0], section)
    with pytest.raises(ValueError, match='client must be None, "local" or a distributed'):
        stability_map(cycle, {"multiplier": [0.5], "turns": [1.0]}, [1.0, 0.0], section,
                      client="cluster")
    # refused at once, not recorded as "no orbit" at every point (a review)
    grid = {"multiplier": [0.5], "turns": [1.0]}
    with pytest.raises(ValueError,
                       match=r"x_guess must be finite, but x_guess\[1\] = nan; got \[1.0, nan\]"):
        stability_map(cycle, grid, [1.0, np.nan], section)
    with pytest.raises(ValueError, match=r"period_guess must be a finite number > 0, got -1"):
        stability_map(cycle, grid, [1.0, 0.0], section, period_guess=-1)


def test_a_guess_of_the_wrong_size_is_refused_before_the_grid_runs(monkeypatch):
    # a review: every point ran and failed with "x_guess must have shape (2,)", the map all
    # NaN; now the model of the first point is built once, and nothing is solved
    built, solved = [], []
    real = HybridSystem.periodic_orbit
    monkeypatch.setattr(HybridSystem, "periodic_orbit",
                        lambda *a, **k: solved.append(1) or real(*a, **k))

    def make(**params):
        built.append(params)
        return cycle(**params)

    grid = {"multiplier": [0.5, 0.9, 1.5], "turns": [1.0, 2.0]}
    for guess, got in (([1.05], r"shape \(1,\)"), ([1.05, 0.0, 0.0], r"shape \(3,\)"),
                       ([[1.05, 0.0]], r"shape \(1, 2\)"),
                       ([1.0, [0.0]], r"a ragged nest \[1.0, \[0.0\]\]")):
        with pytest.raises(ValueError, match=r"x_guess must have shape \(2,\) \(a state of "
                           r"the model that make_system\(multiplier=0.5, turns=1\) builds\), "
                           r"got " + got):
            stability_map(make, grid, guess, section, period_guess=1.0)
    with pytest.raises(TypeError, match=r"x_guess must hold real numbers"):
        stability_map(make, grid, ["a", "b"], section, period_guess=1.0)
    assert built == [{"multiplier": 0.5, "turns": 1.0}] * 5 and solved == []
    # the same with the pronking example (an Example: its system is read)
    from bderiv.examples import gaits

    with pytest.raises(ValueError, match=r"x_guess must have shape \(4,\) \(a state of the "
                       r"model that make_system\(gain=3\) builds\), got shape \(3,\)"):
        stability_map(gaits.pronking, {"gain": [3, 4, 5]}, gaits.pronking().x0[:3],
                      gaits.apex_section, period_guess=0.5)
    assert solved == []


def test_bad_make_system_grid_values_and_iterations_are_named():
    grid, guess = {"multiplier": [0.5], "turns": [1.0]}, [1.05, 0.0]
    with pytest.raises(TypeError, match=r"make_system must be callable \(make_system\(\*\*params"
                       r"\) -> HybridSystem\), got int"):
        stability_map(3, grid, guess, section)
    with pytest.raises(TypeError, match=r"make_system must return a HybridSystem \(or an object "
                       r"with a system attribute, such as an Example\), got float"):
        stability_map(lambda **p: 3.0, grid, guess, section)
    # "could not convert string to float: 'abc'" named no argument
    with pytest.raises(TypeError, match=r"grid\['turns'\] must hold real numbers \(float or "
                       r"integer dtype\), got dtype <U3 \(string\)"):
        stability_map(cycle, {"multiplier": [0.5], "turns": "abc"}, guess, section)
    with pytest.raises(ValueError, match=r"grid\['turns'\] must be a non-empty 1-d sequence of "
                       r"finite numbers, got \[1, \[2, 3\]\]"):
        stability_map(cycle, {"multiplier": [0.5], "turns": [1, [2, 3]]}, guess, section)
    with pytest.raises(ValueError, match=r"grid\['turns'\] must be a non-empty 1-d sequence of "
                       r"finite numbers, got \[1.0, inf\]"):
        stability_map(cycle, {"multiplier": [0.5], "turns": [1.0, np.inf]}, guess, section)
    with pytest.raises(TypeError, match=r"grid's keys must be parameter names \(str, keywords "
                       r"of make_system\), got int 1"):
        stability_map(cycle, {"multiplier": [0.5], 1: [1.0]}, guess, section)
    # refused at once, not after the first orbit (iterations=1 passed the first check)
    for bad in (0, 1):
        with pytest.raises(ValueError, match=rf"iterations must be an integer >= 2, got {bad}$"):
            stability_map(cycle, grid, guess, section, iterations=bad)


def test_figure_marks_the_unstable_region(tmp_path):
    pytest.importorskip("matplotlib")
    from bderiv.plot import stability_map as figure

    smap = stability_map(cycle, GRID, [1.05, 0.0], section, period_guess=1.0,
                         n_directions=10, iterations=20)
    fig = figure(smap)
    ax = fig.axes[0]
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("multiplier", "turns")
    assert "4 of 6 orbits" in ax.get_title()
    # the colour scale is centred at growth rate 1 and spans the map's rates
    mesh = ax.collections[0]
    assert mesh.norm.vcenter == 1.0 and mesh.norm.vmax >= 1.5 ** 1.0 - 1e-9
    assert any("//" in (getattr(c, "hatches", None) or ()) for c in ax.collections)
    # the colour bar is labelled on both sides of 1 (the stable values too)
    ticks = fig.axes[1].get_yticks()
    assert 1.0 in ticks and ticks.min() < 0.75 and ticks.max() > 1.25
    assert all(0.5 <= t <= 1.5 ** 1.0 + 1e-9 for t in ticks)
    fig.savefig(tmp_path / "map.png")
    with pytest.raises(ValueError, match="needs a map over two parameters, got 1"):
        figure(stability_map(functools.partial(cycle, turns=1.0), {"multiplier": [0.5]},
                             [1.05, 0.0], section, period_guess=1.0))


@pytest.mark.slow
def test_pronking_on_a_local_cluster_equals_the_serial_map():
    pytest.importorskip("distributed")
    from bderiv.examples import gaits

    grid = {"gain": [3.5, 4.0], "coupling": [0.3, 0.5]}
    args = (gaits.pronking, grid, gaits.pronking().x0, gaits.apex_section)
    serial = stability_map(*args, period_guess=0.5)
    local = stability_map(*args, period_guess=0.5, client="local")
    np.testing.assert_allclose(local.growth_rate, serial.growth_rate, rtol=1e-10)
    assert serial.failures == {} and serial.stable.all()


@pytest.mark.slow
def test_ctrl_c_on_a_local_cluster_returns_within_a_second():
    """The cluster made for the call closes after Ctrl-C has returned (its processes take
    a second or more to end; it had taken 1.2 to 1.5 s): the interrupt is not held up by
    it. A real SIGINT to the main thread, as a terminal sends it (``interrupt_main`` sets
    Python's flag only, which a wait for the cluster's results does not see)."""
    pytest.importorskip("distributed")
    import signal
    import threading

    from bderiv.examples import gaits

    grid = {"gain": np.linspace(3.0, 4.5, 40), "coupling": np.linspace(0.2, 0.6, 40)}
    args = (gaits.pronking, grid, gaits.pronking().x0, gaits.apex_section)
    sent = 8.0  # the cluster started and the first wave going
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    timer = threading.Timer(sent, signal.pthread_kill,
                            args=(threading.main_thread().ident, signal.SIGINT))
    try:
        start = time.perf_counter()
        timer.start()
        with pytest.raises(KeyboardInterrupt):
            stability_map(*args, period_guess=0.5, client="local")
        assert time.perf_counter() - start < sent + 1.0
    finally:
        timer.cancel()
        signal.signal(signal.SIGINT, previous)
    closing = [t for t in threading.enumerate() if t.name == "bderiv-close-cluster"]
    for thread in closing:  # the cluster closed before the next test
        thread.join(30)
    assert not any(t.is_alive() for t in closing)


def _cheap_point(self, params, start):
    """A point's work stubbed: its start as the fixed point (no orbit is solved)."""
    return start, 1.0, 0.5


class _FirstReport(Exception):
    pass


def _stop_at_first_report(done, total):
    raise _FirstReport


def test_the_grid_is_not_listed_before_its_first_point(monkeypatch):
    """A review: the waves of the whole grid were listed first (about 180 B a point: 4.6 GB
    and 45 s at 5000 x 5000 before the first report). Only the map's arrays are the size
    of the grid now: a 1000 x 1000 grid takes them (32 MB) and a few KB more until the
    first point is reported."""
    import tracemalloc

    from bderiv.analysis import stability_map as module

    monkeypatch.setattr(module._Task, "__call__", _cheap_point)
    grid = {"multiplier": np.linspace(0.5, 1.5, 1000), "turns": np.linspace(1, 2, 1000)}
    arrays = 1000 * 1000 * (2 + 2) * 8
    tracemalloc.start()
    try:
        with pytest.raises(ProgressCallbackError) as stopped:
            stability_map(cycle, grid, [1.05, 0.0], section, progress=_stop_at_first_report)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert isinstance(stopped.value.__cause__, _FirstReport)
    assert arrays <= peak < arrays + (2 << 20)


def test_waves_are_the_anti_diagonals_in_order():
    """The waves made one at a time are those of the grid listed whole (the order of the
    points, hence each point's start and the map's bits, is unchanged)."""
    from bderiv.analysis.stability_map import _waves

    def listed(shape):  # the earlier definition
        waves = {}
        for index in sorted(np.ndindex(*shape), key=lambda index: (sum(index), index)):
            waves.setdefault(sum(index), []).append(index)
        return list(waves.values())

    for shape in ((1,), (6,), (1, 1), (1, 5), (5, 1), (3, 4), (4, 3), (5, 5)):
        assert list(_waves(shape)) == listed(shape)


def test_a_map_too_large_for_the_memory_is_refused_before_it_runs(monkeypatch):
    """Its arrays (growth rate, period, x0: (2 + d) floats a point) are checked against
    what the process may take, before any point (the waves of 10^12 points were listed
    until the memory ran out)."""
    from bderiv.analysis import stability_map as module

    monkeypatch.setattr(module._Task, "__call__", _cheap_point)
    grid = {"multiplier": np.linspace(0.5, 1.5, 10**6), "turns": np.linspace(1, 2, 10**6)}
    with pytest.raises(ValueError, match=r"the map's arrays over a 1000000 x 1000000 grid "
                       r"\(growth rate, period and the fixed point x0 of size 2 at each "
                       r"point\) take 29.1 TiB, more than the memory limit of .*: map a "
                       r"coarser grid, or the grid in parts \(one call each\)"):
        stability_map(cycle, grid, [1.05, 0.0], section, progress=_stop_at_first_report)
