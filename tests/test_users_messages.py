"""Messages that point at the right thing (users' fourth pass, items 3 and 6)."""

from __future__ import annotations

import io

import numpy as np
import pytest

from bderiv._support._progress import TqdmCallback
from bderiv.cli import main
from bderiv.cli.render import bench_text


@pytest.mark.parametrize("example", ["corners", "quadruped", "rimless-wheel"])
def test_python_is_refused_where_it_means_nothing(example, capsys):
    assert main(["demo", "--example", example, "--python"]) == 2
    err = capsys.readouterr().err
    assert f"{example} has no compiled version, so it means nothing there" in err
    assert "chair, network, pronking, landing" in err


def _rows(bderiv_gflops, blas_gflops):
    common = {"n": 4, "d": 4, "m": 1000, "seconds": 1e-3, "seconds_per_query": 1e-6}
    return [dict(common, method="bderiv", gflops=bderiv_gflops, build_seconds=1e-4,
                 speedup=3.0),
            dict(common, method="blas", gflops=blas_gflops)]


@pytest.mark.parametrize("bderiv_gflops, noted", [(2.0, True), (0.5, False)])
def test_bench_says_why_it_can_exceed_blas(bderiv_gflops, noted):
    result = {"d_factor": 1, "batch": 1000, "repeat": 3, "rows": _rows(bderiv_gflops, 1.0),
              "machine": {"cpu": "X", "cpus": 2, "numba_threads": 2, "blas": "b",
                          "thread_variables": {}}}
    text = bench_text(result)
    assert ("200.0%" in text) is noted
    assert ("above 100 % of BLAS, the yardstick product ran slower" in text) is noted


def test_progress_counts_small_totals_plainly():
    out = io.StringIO()
    bar = TqdmCallback("bench", unit="size", file=out)
    for done in range(1, 6):
        bar(done, 5)
    assert "5/5" in out.getvalue() and "5.00" not in out.getvalue()
    out = io.StringIO()
    bar = TqdmCallback("demo", file=out)
    bar(20_000, 20_000)
    assert "20.0k/20.0k" in out.getvalue()


# -- periodic_orbit names the iterate that failed and the argument to change (item 4) ------


def test_periodic_orbit_names_period_guess_when_the_return_is_not_awaited_long_enough(
        monkeypatch):
    """Said after one attempt: the guess's map is built with the caller's settings first,
    and a run that does not return is not tried again with the iterates' (the tolerance
    does not change where it goes)."""
    from bderiv.analysis import orbit
    from bderiv.examples import gaits

    real, built = orbit.return_map, []

    def counted(*args, **kwargs):
        built.append(kwargs["options"].simultaneity_tol)
        return real(*args, **kwargs)

    monkeypatch.setattr(orbit, "return_map", counted)
    with pytest.raises(ValueError, match=r"periodic_orbit at the guess, x = \[.*\]: the "
                                         r"trajectory did not return to the section .* waits 3 "
                                         r"times period_guess for the return, 0.03 here: pass "
                                         r"a larger period_guess"):
        gaits.pronking_orbit(period_guess=0.01)
    assert built == [orbit.ORBIT_OPTIONS.simultaneity_tol]


def test_periodic_orbit_names_the_newton_iterate_that_failed(monkeypatch):
    """A failure of the return map at a later iterate is said there, with its state (the
    message before named only 'x0 (t=0)', which users read as their guess)."""
    from bderiv.analysis import orbit
    from bderiv.examples import gaits

    real, calls = orbit.return_map, []

    def failing_later(system, x, *args, **kwargs):
        calls.append(x.copy())
        if len(calls) == 2:
            raise ValueError("at x0 (t=0) the rate of section(x) is -0.233")
        return real(system, x, *args, **kwargs)

    monkeypatch.setattr(orbit, "return_map", failing_later)
    with pytest.raises(ValueError, match=r"periodic_orbit at Newton iterate 1, x = \[.*\]: at "
                                         r"x0 \(t=0\) the rate of section\(x\) is -0.233") as info:
        gaits.pronking_orbit()
    assert np.array2string(calls[1], precision=6) in str(info.value)


def test_a_group_at_the_final_time_says_what_its_extra_event_is():
    from bderiv import examples

    ex = examples.chair()
    D = ex.system.flow_bderivative(ex.x0, ex.t_event)  # t_final on the touchdown
    assert "groups=[3] (the last with the final time as its event 2)" in repr(D)


def test_symbolic_models_follow_the_cache_variables(monkeypatch, tmp_path):
    import os
    import tempfile

    from bderiv.symbolic._cache import cache_folder

    # the test runs write to a temporary folder, never to the user's ~/.cache
    assert os.environ["BDERIV_CACHE_DIR"].startswith(tempfile.gettempdir())
    monkeypatch.delenv("BDERIV_CACHE_DIR")
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "numba"))
    assert cache_folder() == tmp_path / "numba" / "bderiv" / "symbolic"
    monkeypatch.setenv("BDERIV_CACHE_DIR", str(tmp_path / "ours"))
    assert cache_folder() == tmp_path / "ours" / "symbolic"


def test_the_compass_gait_demo_says_why_its_eigenvalues_differ_from_the_published_ones():
    from bderiv.examples.walker_report import summary_text, walker_summary

    text = summary_text(walker_summary("compass-gait"))
    assert "note: the eigenvalues differ from the published ones by 1.7e-3" in text


def test_export_refuses_too_many_pieces_before_building_the_example(monkeypatch, capsys):
    from bderiv.cli import export

    def never(*args):
        raise AssertionError("the example was built before the refusal")

    monkeypatch.setattr(export, "load_example", never)
    assert main(["export", "--example", "network", "--n", "20"]) == 2
    assert "20 events give 2 * 20! simplices, more than 2 * --max-pieces=40320" in \
        capsys.readouterr().err


def test_a_trajectory_says_its_start_region_and_groups():
    """(item 5) events written with the other sign start the model in another region: the
    repr says which, and the groups met, instead of every sample."""
    from bderiv import examples

    ex = examples.chair()
    traj = ex.system.simulate(ex.x0, ex.t_final)
    text = repr(traj)
    assert text.startswith("Trajectory(t 0 to 0.15, ") and len(text) < 300
    assert "start region 0b0, 1 event groups [t=0.1: [0, 1] 0b0 -> 0b11], final region 0b11" \
        in text
    assert traj.mask_start == 0


def test_the_first_run_says_its_start_region(caplog):
    """(item 5) events written as heights (the other sign) start the chair in region 0b11,
    'both feet touching', in the air: the first run of the model says so at INFO."""
    import logging

    from bderiv import HybridSystem, examples

    ex = examples.chair()
    s = ex.system
    flipped = HybridSystem(s.field, lambda x: -s.events(x), n_events=2, dim=6)
    with caplog.at_level(logging.INFO, logger="bderiv"):
        traj = flipped.simulate(ex.x0, 0.05)
        flipped.simulate(ex.x0, 0.05)
    told = [r.getMessage() for r in caplog.records if "the run starts in region" in
            r.getMessage()]
    assert told == ["the run starts in region 0b11: events [0, 1] counted as happened "
                    "(h_k(x0) > 0); events written with the other sign start it elsewhere "
                    "than meant"]  # once per model
    assert "start region 0b11" in repr(traj)


def test_a_trajectory_without_sensitivities_has_no_flow_map_along_it():
    from bderiv.examples import bouncing_ball

    system = bouncing_ball().system
    traj = system.simulate(np.array([1.0, 0.0]), 0.55)
    with pytest.raises(ValueError, match=r"traj holds no sensitivities .* call "
                                         r"flow_bderivative\(x0, t_final\)"):
        system.flow_map_along(traj)


def _two_event_model(**extra):
    from bderiv import HybridSystem

    return HybridSystem(lambda x, mask: np.array([1.0, 0.5 + mask]),
                        lambda x: np.array([x[0] - 1.0, x[0] - 1.0]), n_events=2, dim=2,
                        event_jacobian=lambda x: np.array([[1.0, 0.0], [1.0, 0.0]]),
                        field_jacobian=lambda x, mask: np.zeros((2, 2)), **extra)


def test_a_corner_field_that_is_not_the_field_is_refused_by_mask():
    """corner_field was used as it came: a table of 5s gave a flow map of [1.09, -0.79]
    where the field's is [1, 2] (a review), silently."""
    right = _two_event_model(corner_field=lambda x: np.array([[1.0, 0.5 + m]
                                                               for m in range(4)]))
    assert right.flow_bderivative(np.zeros(2), 2.0)(np.array([1.0, -1.0])) == pytest.approx(
        [1.0, 2.0])
    wrong = _two_event_model(corner_field=lambda x: np.full((4, 2), 5.0))
    with pytest.raises(ValueError, match=r"corner_field\(x\) row 0 = \[5\. 5\.\] is not "
                                         r"field\(x, mask=0b00\)"):
        wrong.flow_bderivative(np.zeros(2), 2.0)


def test_a_step_below_the_resolution_of_x0_is_refused():
    """x0 + eps v rounded to x0: flow_fd gave zeros and fd_check an error of 1, silently
    (a review)."""
    model = _two_event_model()
    x0, V = np.array([0.0, 1.0]), np.array([[0.0, 0.0], [0.0, 1.0]])  # a zero row is fine
    with pytest.raises(ValueError, match=r"eps=1e-17 is below the resolution of x0 along "
                                         r"V\[1\]"):
        model.flow_fd(x0, 2.0, V, 1e-17)
    assert model.flow_fd(x0, 2.0, V, 1e-6) == pytest.approx(np.array([[0.0, 0.0], [0.0, 1.0]]))


def test_a_max_step_that_forces_too_many_steps_is_refused_before_the_run():
    """max_step=1e-300 ran without end on scipy (a review)."""
    with pytest.raises(ValueError, match=r"max_step=1e-300 would take at least 2e\+300 "
                                         r"steps to t_final=2"):
        _two_event_model().simulate(np.zeros(2), 2.0, max_step=1e-300)


def test_a_corner_functions_table_is_checked_as_the_engine_checks_it():
    """table() and corners() returned NaN for an entry left unwritten or written NaN, and
    numba's raw TypingError for a function that does not compile (a review); a
    BDerivative refused the same functions by name."""
    import numba

    from bderiv import CornerFunction

    @numba.njit
    def half(happened, out):
        out[0] = 1.0 + happened[0]  # out[1] never written

    @numba.njit
    def nan(happened, out):
        out[0] = 1.0
        out[1] = np.nan if happened[1] else 1.0

    with pytest.raises(ValueError, match=r"write all 2 entries of out with finite values; "
                                         r"on the region happened = \[0, 0\] it gave"):
        CornerFunction(half, n_events=2, dim=2).table()
    with pytest.raises(ValueError, match=r"happened = \[0, 1\]"):
        CornerFunction(nan, n_events=2, dim=2).corners([[1, 0], [0, 1]])

    def typo(happened, out):
        out[0] = undefined_name  # noqa: F821

    with pytest.raises(TypeError, match=r"(?s)func could not be called as func\(happened, out\)"
                                        r".*TypingError: .*undefined_name") as err:
        CornerFunction(typo, n_events=2, dim=2).table()
    assert "\x1b[" not in str(err.value)


def test_example_builders_refuse_nonsense_parameters_by_name():
    """chair(inertia=-0.1) and pronking(stiffness=-400) built models all the same, and
    chair(inertia=0) failed later as a non-finite field (a review)."""
    from bderiv.examples import chair, gaits

    for build, kw, match in ((chair, {"inertia": -0.1}, "inertia must be a finite number > 0"),
                             (chair, {"inertia": 0}, "inertia must be a finite number > 0"),
                             (chair, {"damping": -4}, "damping must be a finite number >= 0"),
                             (gaits.pronking, {"stiffness": -400}, "stiffness must be"),
                             (gaits.pronking, {"leg": 0}, "leg must be a finite number > 0"),
                             (gaits.pronking, {"gain": np.nan}, "gain must be a finite")):
        with pytest.raises(ValueError, match=match):
            build(**kw)
    with pytest.raises(TypeError, match="stiffness must be a real number, got str"):
        chair(stiffness="a")
    from bderiv.examples import landing, network

    with pytest.raises(ValueError, match="foot_mass must be a finite number > 0, got 0"):
        landing(foot_mass=0)  # a ZeroDivisionError before
    with pytest.raises(TypeError, match=r"n must be an integer in \[1, 24\], got float 2.5"):
        network(2.5)  # silently n = 2 before
    with pytest.raises(ValueError, match="coupling must be a finite number, got nan"):
        network(3, coupling=np.nan)
