"""The bundled examples' compiled versions against their Python versions.

Each example writes its equations once; ``compiled=True`` compiles them with numba and the
model runs on the compiled integrator, the Python version on scipy's solve_ivp. Two
integrators and two evaluations of the same equations must give the same simulations
(end states to 1e-10, event times to 1e-10) and the same flow maps (1e-8 relative on
random directions, the same event orders). The compiled functions are made once per
module (the first compilation of each takes seconds; numba keeps it on disk).
"""

from __future__ import annotations

import numba
import numpy as np
import pytest

from bderiv import examples
from bderiv.analysis.system import HybridSystem
from bderiv.examples import gaits, runner

#: (name, factory of the example given compiled=...)
CASES = {
    "chair": lambda compiled: examples.chair(compiled=compiled),
    "network": lambda compiled: examples.network(4, compiled=compiled),
    "network-extended": lambda compiled: examples.network(3, extended=True, seed=1,
                                                          compiled=compiled),
    "landing": lambda compiled: examples.landing(compiled=compiled),
    "pronking": lambda compiled: gaits.pronking(compiled=compiled),
    "pronking-4": lambda compiled: gaits.pronking(legs=4, compiled=compiled),
    "running": lambda compiled: runner.running(compiled=compiled),
}


@pytest.fixture(scope="module", params=sorted(CASES))
def pair(request):
    """``(Python example, compiled example)`` of one case."""
    make = CASES[request.param]
    return make(False), make(True)


def test_the_pair_is_one_model_on_two_paths(pair):
    py, cc = pair
    assert not py.compiled and cc.compiled
    assert py.system.compiled is None and cc.system.compiled is not None
    for attr in ("rho", "x0"):
        np.testing.assert_array_equal(getattr(py, attr), getattr(cc, attr))
    assert (py.t_event, py.t_final, py.name) == (cc.t_event, cc.t_final, cc.name)
    x = py.x0 + 0.01
    for mask in range(1 << py.system.n_events):
        np.testing.assert_allclose(cc.system.calls.eval_field(x, mask),
                                   py.system.calls.eval_field(x, mask),
                                   rtol=1e-15, atol=1e-15)
    np.testing.assert_allclose(cc.system.calls.eval_events(x), py.system.calls.eval_events(x),
                               rtol=1e-15, atol=1e-15)


def test_simulations_agree(pair):
    py, cc = pair
    T = 3.0 * py.t_final  # beyond the first stance: several event groups
    a, b = py.system.simulate(py.x0, T), cc.system.simulate(cc.x0, T)
    assert [g.events for g in a.groups] == [g.events for g in b.groups]
    assert [g.directions for g in a.groups] == [g.directions for g in b.groups]
    np.testing.assert_allclose([g.time for g in b.groups], [g.time for g in a.groups],
                               rtol=0, atol=1e-10)
    np.testing.assert_allclose(b.x_final, a.x_final, rtol=0, atol=1e-10)


def test_flow_maps_agree(pair):
    py, cc = pair
    Dp = py.system.flow_bderivative(py.x0, py.t_final)
    Dc = cc.system.flow_bderivative(cc.x0, cc.t_final)
    V = np.random.default_rng(0).standard_normal((200, py.system.dim))
    for op, oc in zip(Dp.orders(V), Dc.orders(V), strict=True):
        np.testing.assert_array_equal(op, oc)
    P, C = Dp(V), Dc(V)
    assert np.abs(C - P).max() <= 1e-8 * np.abs(P).max()


def test_compiled_pronking_orbit_is_the_python_one():
    py, cc = gaits.pronking(), gaits.pronking(compiled=True)
    op, oc = gaits.pronking_orbit(py), gaits.pronking_orbit(cc)
    np.testing.assert_allclose(oc.x0, op.x0, rtol=0, atol=1e-9)
    assert abs(oc.period - op.period) <= 1e-9
    V = np.random.default_rng(1).standard_normal((50, 4)) @ op.return_map.tangent_basis
    V = V @ op.return_map.tangent_basis.T
    P, C = op.return_map(V), oc.return_map(V)
    assert np.abs(C - P).max() <= 1e-6 * np.abs(P).max()


def test_compiled_section_is_needed_and_given():
    cc = gaits.pronking(compiled=True)
    with pytest.raises(TypeError, match="section must be too"):
        cc.system.return_map(cc.x0, gaits.apex_section)
    assert gaits.compiled_apex_section(np.array([0.6, 0.0, 0.25, 0.0])) == -0.25
    assert examples.pronking(compiled=True).description.endswith(", numba-compiled")


@pytest.mark.parametrize("make", [examples.chair, examples.landing, gaits.pronking,
                                  runner.running, lambda **kw: examples.network(2, **kw)])
def test_compiled_must_be_a_flag(make):
    with pytest.raises(TypeError, match="compiled must be True or False, got str 'yes'"):
        make(compiled="yes")


@pytest.mark.parametrize("legs, error, message", [
    (1, ValueError, "legs must be an integer >= 2, got 1"),
    (2.5, TypeError, "legs must be an integer >= 2, got float 2.5"),
    ("4", TypeError, "legs must be an integer >= 2, got str '4'"),
])
def test_pronking_legs_are_checked(legs, error, message):
    with pytest.raises(error, match=message):
        gaits.pronking(legs=legs, compiled=True)


def test_another_body_reuses_the_compiled_functions_bit_for_bit():
    """The compiled gaits take their constants at run time (the system's ``params``):
    another body compiles nothing, and simulates bit for bit as a fresh compilation of the
    same functions with its constants."""
    from numba.core import event

    first = gaits.pronking(compiled=True)
    first.system.simulate(first.x0, first.t_final)  # what a first model compiles
    values = {"stiffness": 300.0, "damping": 3.0, "inertia": 0.2, "half_base": 0.35}
    start = np.array([0.02, 0.03, 0.0, 0.2])  # pitched: the feet land apart
    with event.install_recorder("numba:compile") as compiled:
        ex = gaits.pronking(compiled=True, **values)
        reused = ex.system.simulate(ex.x0 + start, 3.0 * ex.t_final)
    assert compiled.buffer == []
    assert ex.system.compiled.named["field"] is first.system.compiled.named["field"]
    fresh = HybridSystem(numba.njit(gaits.field), numba.njit(gaits.events), n_events=2,
                         dim=4, event_jacobian=gaits.event_jacobian,
                         params=gaits.body(**values).values())
    new = fresh.simulate(ex.x0 + start, 3.0 * ex.t_final)
    assert len(new.groups) >= 4 and [g.events for g in new.groups] == [
        g.events for g in reused.groups]
    for a, b in ((new.t, reused.t), (new.x, reused.x), (new.x_final, reused.x_final),
                 ([g.time for g in new.groups], [g.time for g in reused.groups])):
        np.testing.assert_array_equal(a, b)


def test_the_compiled_running_gait_takes_its_speed_at_run_time():
    a, b = runner.running(compiled=True), runner.running(compiled=True, v_target=1.5)
    assert a.system.compiled.named["field"] is b.system.compiled.named["field"]
    x = b.x0 + 0.01
    np.testing.assert_array_equal(b.system.calls.eval_field(x, 3)[3],
                                  2 * 8.0 * (1.5 - x[3]))  # traction 8 shared by 2 legs


def test_the_integrator_compiles_each_kernel_once():
    """The chair's first flow map compiles every kernel of the integrator and the compiled
    run for one set of argument types (a second, for a literal or another array type, is a
    second compilation: seconds of a cold start; this bites where the kernels compile in
    this process, an empty cache: a cached caller is loaded whole, its callees not asked),
    and the driver is compiled for the types the compiled run calls it with through its
    address (the model's struct) and Python calls it with: once."""
    import sys

    from numba.core.dispatcher import Dispatcher

    from bderiv.models.compiled import _integrate, _model

    ex = examples.chair(compiled=True)
    ex.system.flow_bderivative(ex.x0, ex.t_final)
    prefix = "bderiv.models.compiled._"  # the private kernels (rules: Python's too)
    kernels = {f"{name}.{key}": len(value.signatures)
               for name, module in list(sys.modules.items()) if name.startswith(prefix)
               for key, value in vars(module).items()
               if isinstance(value, Dispatcher) and value.py_func.__module__ == name}
    assert kernels["bderiv.models.compiled._run.run_stretches"] == 1
    assert {k: n for k, n in kernels.items() if n > 1} == {}
    assert _integrate.drive_stretch.signatures == [_model.DRIVER_ARGS]
