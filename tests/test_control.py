"""bderiv.control: shooting against hybrid-tools, parameter derivatives against finite
differences of an independent simulation, iLQR through the chair's simultaneous touchdown."""

from __future__ import annotations

import numba
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from bderiv import HybridSystem, examples
from bderiv.control import (
    ParametricFlow,
    ShootingConfig,
    StepEndsAtImpact,
    augment,
    ball_1d,
    ball_2d,
    controlled_chair,
    cost_gradient,
    ilqr,
    rollout,
    shoot,
)

#: hybrid-tools' example settings (its shooting script: error_tol 0.005, input_state_tol
#: 1e-5, the rest its defaults), for both optimisers
TOLS = {"max_iters": 50, "error_tol": 0.005, "input_state_tol": 1e-5}


def _theirs(system, params, T, x0, controls, guess, target, outputs):
    ht = pytest.importorskip("hybrid_tools.shooting_method_optimizer")
    for mode in system.noises:  # its simulator draws process noise on the inputs: none
        system.noises[mode].W *= 0
    opt = ht.ShootingMethodOptimizer(system, "I", np.array(params), dt=0.005, T=T)
    return opt.optimize(np.array(x0, float), controls, np.array(guess, float),
                        np.array(target, float), outputs, np.zeros(len(x0) // 2),
                        ht.ShootingMethodOptimizerConfig(verbose=False, **TOLS))


@pytest.mark.parametrize("guess", [8.0, 10.0])
def test_shooting_2d_ball_against_hybrid_tools(guess):
    """Its own 2-D example: from (0, 1) at rest, the start velocity that puts the ball at
    (4, 1) at T = 5 s (several bounces, e = 0.8). Same start, cost, rules: we need no
    more iterations and reach the same optimum."""
    boxes = pytest.importorskip("hybrid_tools.basic_hybrid_systems")
    x0, target = [0.0, 1.0, 0.0, 0.0], [4.0, 1.0]
    theirs = _theirs(boxes.bouncing_ball_2d(), [0.8, 9.81, 0.0], 5.0, x0, [2, 3],
                     [0.8, guess], target, [0, 1])
    flow = ball_2d()
    ours = shoot(flow, x0, flow.defaults, 5.0, target, output_indices=[0, 1],
                 state_indices=[2, 3], initial_guess=[0.8, guess],
                 config=ShootingConfig(**TOLS))
    assert theirs.converged and ours.converged
    assert ours.iterations <= theirs.iterations
    assert np.allclose(ours.decision, theirs.optimal_controls, rtol=0, atol=2e-3)
    assert np.abs(ours.x_final - target).max() < TOLS["error_tol"]


def test_shooting_1d_ball_against_hybrid_tools():
    """The 1-D ball from q = 1: the start velocity that puts it at q = 0.5 at T = 2 s
    (two bounces)."""
    boxes = pytest.importorskip("hybrid_tools.basic_hybrid_systems")
    theirs = _theirs(boxes.bouncing_ball(), [0.8, 9.81], 2.0, [1.0, 0.0], [1], [3.0],
                     [0.5], [0])
    flow = ball_1d()
    ours = shoot(flow, [1.0, 0.0], flow.defaults, 2.0, [0.5], output_indices=[0],
                 state_indices=[1], initial_guess=[3.0], config=ShootingConfig(**TOLS))
    assert theirs.converged and ours.converged
    assert ours.iterations <= theirs.iterations
    assert abs(ours.decision[0] - theirs.optimal_controls[0]) < 2e-3


def _ball_scipy(x, p, T):
    """The 1-D ball by solve_ivp with its own event logic: q'' = -g + u, bounce at q = 0
    falling, q' -> -e q'."""
    u, e, g = p
    t, y = 0.0, np.array(x, float)

    def hit(_t, s):
        return s[0]

    hit.terminal, hit.direction = True, -1
    while t < T:
        sol = solve_ivp(lambda _t, s: [s[1], -g + u], (t, T), y, events=hit,
                        rtol=1e-12, atol=1e-13)
        t, y = sol.t[-1], sol.y[:, -1].copy()
        if sol.status == 1:
            y = np.array([0.0, -e * y[1]])
    return y


def test_parameter_derivatives_against_finite_differences():
    """B = dx(T)/dp (input, restitution, gravity) through two bounces, against one-sided
    differences of an independent simulation (scipy, events in the test)."""
    flow = ball_1d()
    x, p, T = np.array([1.0, 0.5]), np.array([0.7, 0.8, 9.81]), 1.6
    step = flow.step(x, p, T)
    assert len(step.groups) == 2
    eps = 1e-6
    base = _ball_scipy(x, p, T)
    assert np.allclose(step.x_next, base, atol=1e-8)
    for j in range(3):
        fd = (_ball_scipy(x, p + eps * np.eye(3)[j], T) - base) / eps
        assert np.allclose(step.B[:, j], fd, rtol=1e-4, atol=1e-4 * np.abs(fd).max())
    fd_x = np.column_stack([(_ball_scipy(x + eps * np.eye(2)[i], p, T) - base) / eps
                            for i in range(2)])
    assert np.allclose(step.A, fd_x, rtol=1e-4, atol=1e-5)


@pytest.fixture(scope="module")
def chair_flow():
    return controlled_chair(mode_damping=60.0, simultaneity_tol=5e-3)


def test_cost_gradient_against_finite_differences():
    """dJ/dU by the adjoint on the pieces, against one-sided differences of the cost,
    with the touchdowns apart (the cost differentiable there)."""
    flow = controlled_chair(mode_damping=60.0)  # window 1e-7: each touchdown its own
    N, dt = 5, 0.03
    U = np.zeros((N, 2))
    target = rollout(flow, flow.x0, U, dt)[-1] + 0.01
    U[:, 1] = 2.0
    Qf, R = np.eye(6), 1e-2 * np.eye(2)
    G = cost_gradient(flow, flow.x0, U, dt, target, Qf, R)

    def cost(V):
        e = rollout(flow, flow.x0, V, dt)[-1] - target
        return 0.5 * np.sum(V * (V @ R)) + 0.5 * e @ Qf @ e

    eps, c0 = 1e-6, cost(U)
    fd = np.array([[(cost(U + eps * np.eye(N * 2)[2 * k + j].reshape(N, 2)) - c0) / eps
                    for j in range(2)] for k in range(N)])
    assert np.allclose(G, fd, rtol=1e-3, atol=1e-4 * np.abs(fd).max())


def _chair_runs(flow, torque=4.0):
    N, dt = 5, 0.03
    U0 = np.zeros((N, 2))
    target = rollout(flow, flow.x0, U0, dt)[-1]  # reached by landing flat: both feet at once
    U0[:, 1] = torque
    out = {}
    for lin in ("nominal", (0, 1), (1, 0)):
        res = ilqr(flow, flow.x0, U0, dt, target, Qf=np.eye(6), R=1e-6 * np.eye(2),
                   linearisation=lin, max_iters=12, tol=0.0)
        costs = np.array(res.costs)
        hit = np.flatnonzero(costs < 1e-14 * costs[0])
        out[lin] = (int(hit[0]) if hit.size else None, res)
    return out


@pytest.mark.parametrize("torque", [4.0, -4.0])
def test_ilqr_through_the_simultaneous_touchdown(chair_flow, torque):
    """The chair driven to the state it reaches by landing on both feet at once, from a
    torque that lands one foot first (either foot, by its sign): our iLQR (the nominal's
    piece) gets the cost below 1e-14 of its start in at most 5 iterations, through any
    switch of order. No single-order linearisation does better, and the fixed order that
    is wrong on the nominal's side (opposite to the order in which the first nominal
    that merges the touchdowns crosses them) needs at least twice as many iterations
    (torque 4: 12 against 4; -4: 11 against 4); the other can match ours (-4: 4).
    Neither stalls."""
    runs = _chair_runs(chair_flow, torque)
    ours, res = runs["nominal"]
    assert ours is not None and ours <= 5
    assert all(s[1] == (0, 1) for it in res.history for s in it.switches)
    side = next(g for it in res.history for step in it.orders for g in step if len(g) == 2)
    for lin in ((0, 1), (1, 0)):
        theirs, fixed = runs[lin]
        assert not fixed.stalled
        assert theirs is None or theirs >= ours, (lin, theirs, ours)
        if lin != side:
            assert theirs is None or theirs >= 2 * ours, (lin, theirs, ours)


def test_a_long_ilqr_shows_its_iteration_and_cost(chair_flow, bars_drawn):
    """The bar of a search (drawn once it lasts, here at once): each accepted iteration
    with the nominal's cost, as the result's history has them."""
    N, dt = 5, 0.03
    U0 = np.zeros((N, 2))
    target = rollout(chair_flow, chair_flow.x0, U0, dt)[-1]
    U0[:, 1] = 4.0
    res = ilqr(chair_flow, chair_flow.x0, U0, dt, target, Qf=np.eye(6), R=1e-6 * np.eye(2),
               max_iters=2, tol=0.0)
    drawn = [d for d in bars_drawn.getvalue().replace("\n", "\r").split("\r")
             if d.startswith("ilqr: ")]
    assert drawn[0].startswith("ilqr: iteration 1 (of at most 2), cost "), drawn
    assert drawn[-1].startswith(f"ilqr: iteration 2 (of at most 2), cost {res.cost:.4g} ")


def test_ilqr_started_at_the_target_has_converged(chair_flow):
    """Cost 0 at the start (the target is the nominal's own end): converged at once, not
    "stalled" after line searches that cannot lower a cost of 0 (about 170 forward passes
    up to mu_max before)."""
    N, dt = 5, 0.03
    U0 = np.zeros((N, 2))
    target = rollout(chair_flow, chair_flow.x0, U0, dt)[-1]
    res = ilqr(chair_flow, chair_flow.x0, U0, dt, target, Qf=np.eye(6), R=1e-6 * np.eye(2))
    assert res.cost == 0.0 and res.converged and not res.stalled
    assert len(res.history) == 1 and np.array_equal(res.U, U0)


@numba.njit(cache=True)
def _thrust_field(z, mask):  # docs/control.md's first block: z = (q, q', u)
    out = np.zeros_like(z)
    out[0], out[1] = z[1], -9.81 + z[2]
    return out


@numba.njit(cache=True)
def _thrust_events(z):
    return np.array([-z[0]])


@numba.njit(cache=True)
def _thrust_reset(z, mask, k):
    out = z.copy()
    out[1] = -0.8 * z[1]
    return out


@pytest.fixture(scope="module")
def thrust_ball():
    return ParametricFlow(HybridSystem(_thrust_field, _thrust_events, n_events=1, dim=3,
                                       reset=_thrust_reset), 1)


THRUST = {"Qf": np.diag([100.0, 10.0]), "R": np.array([[1e-3]])}


@pytest.mark.parametrize("height", [-0.1, -1.0])
def test_ilqr_towards_a_target_below_the_ground_stops_at_its_best_iterate(thrust_ball,
                                                                          height):
    """The thrust ball (docs/control.md) sent below the ground, which it cannot reach: the
    iterates press a bounce onto a step's end, where the step's flow map jumps. Those
    trials are failed trials (as shoot's refused ones): ilqr returns its best iterate,
    not converged, stalled, a reason naming the impact, and never bderiv's words about a
    final time the caller did not pass. Its cost is at least the bound the ground sets
    (q_N >= 0), and its states are the scipy simulation of its inputs."""
    res = ilqr(thrust_ball, [1.0, 0.0], np.zeros((4, 1)), 0.25, [height, 0.0], **THRUST,
               max_iters=50)
    assert not res.converged and res.stalled
    assert "reached a step ending at an impact" in res.reason
    assert "t_final" not in res.reason and "final time" not in res.reason
    assert any("ends at an impact" in r for r in res.refusals)
    assert res.cost >= 0.5 * 100.0 * height**2
    assert res.costs == sorted(res.costs, reverse=True) and res.cost == res.costs[-1]
    x = np.array([1.0, 0.0])
    for k, u in enumerate(res.U):
        x = _ball_scipy(x, [u[0], 0.8, 9.81], 0.25)
        assert np.allclose(res.X[k + 1], x, rtol=0, atol=1e-6)


def test_ilqr_refuses_a_first_nominal_with_a_step_ending_at_an_impact(thrust_ball):
    """Steps of length sqrt(2 / g), the ball's fall from q = 1 without thrust: the first
    step ends at its bounce. Refused naming the step, its time and what to change."""
    tb = float(np.sqrt(2.0 / 9.81))
    with pytest.raises(StepEndsAtImpact, match=r"step 0 \(t = 0 to 0\.451524 from x0\).*"
                       r"event 0 \(with a reset\).*Change dt or N") as info:
        ilqr(thrust_ball, [1.0, 0.0], np.zeros((2, 1)), tb, [0.5, 0.0], **THRUST)
    assert "t_final" not in str(info.value) and "final time" not in str(info.value)
    assert abs(info.value.time - tb) < 1e-7


def test_ilqr_restarted_at_its_solution_has_converged(thrust_ball):
    """Restarted at its own converged inputs (three times over), ilqr returns them at
    once, converged and not stalled: the predicted decrease there is at rounding level
    (before: mu raised to mu_max and "stalled", the gradient about 1e-15). The solution
    is a minimum by one-sided differences of the scipy simulation's cost."""
    x0, target = np.array([1.0, 0.0]), np.array([0.4, 0.5])
    first = ilqr(thrust_ball, x0, np.zeros((4, 1)), 0.25, target, **THRUST)
    assert first.converged
    U = first.U
    for _ in range(3):
        res = ilqr(thrust_ball, x0, U, 0.25, target, **THRUST)
        assert res.converged and not res.stalled, res.reason
        assert res.cost <= first.cost * (1 + 1e-12)
        U = res.U
    assert "rounding" in res.reason and len(res.history) == 1

    def cost(V):
        x = x0
        for u in V[:, 0]:
            x = _ball_scipy(x, [u, 0.8, 9.81], 0.25)
        e = x - target
        return 0.5 * float(np.sum(V * (V @ THRUST["R"]))) + 0.5 * e @ THRUST["Qf"] @ e

    eps, c0 = 1e-5, cost(U)
    grad = [(cost(U + eps * np.eye(4)[k][:, None]) - c0) / eps for k in range(4)]
    assert abs(c0 - res.cost) < 1e-8 and np.abs(grad).max() < 1e-3


def test_augment_is_the_params_model():
    """augment() of a params model's functions: the same trajectory as
    HybridSystem(..., params=p), and parameters that do not move."""

    def field(z, mask):
        a = z[2] if mask & 0b10 else 1.0
        b = z[3] if mask & 0b01 else 1.0
        return np.array([a * (1 + 0.1 * z[1] ** 2), b * (1 + 0.2 * np.sin(z[0]))])

    def events(z):
        return np.array([z[0] + 0.1 * z[1] ** 2, z[1]])

    p = np.array([0.4, 0.3])
    plain = HybridSystem(field, events, n_events=2, dim=2, params=p)
    flow = ParametricFlow(augment(field, events, n_events=2, dim=2, n_params=2), 2)
    x0 = np.array([-0.9, -0.8])
    flow.rate_check(x0, p)
    assert np.allclose(flow.final(x0, p, 1.5), plain.simulate(x0, 1.5).x_final,
                       rtol=0, atol=1e-9)


@numba.njit(cache=True)
def _nb_field(z, mask):
    """A ball under gravity and a thrust z[2] (the parameter), numba."""
    return np.array([z[1], -9.81 + z[2]])


@numba.njit(cache=True)
def _nb_events(z):
    return np.array([-z[0]])


@numba.njit(cache=True)
def _nb_reset(z, mask, k):
    return np.array([z[0], -0.8 * z[1]])


def _nb_flow():
    return ParametricFlow(augment(_nb_field, _nb_events, n_events=1, dim=2, n_params=1,
                                  reset=_nb_reset), 1)


def test_augment_of_numba_functions_gives_a_compiled_model():
    """augment() of numba functions: numba wrappers (run here as Python: their compiled
    run is the slow case below, a compile of seconds in every process) that hold the
    parameter still, and refuse a state function of the wrong size by name."""
    from bderiv.control.parametric import _compiled_augmented

    field, events, reset = _compiled_augmented(_nb_field, _nb_events, _nb_reset, 2, 1)
    assert all(isinstance(f, numba.core.registry.CPUDispatcher) for f in (field, reset))
    z = np.array([0.3, -1.0, 0.5])
    assert np.array_equal(field.py_func(z, 0), [-1.0, -9.81 + 0.5, 0.0])
    assert np.array_equal(reset.py_func(z, 1, 0), [0.3, 0.8, 0.5])
    wide, _, _ = _compiled_augmented(_nb_field, _nb_events, None, 1, 2)
    with pytest.raises(ValueError, match="field"):
        wide.py_func(np.zeros(3), 0)


@pytest.mark.slow
def test_augment_of_numba_functions_is_compiled_and_exact():
    """augment() of numba functions run compiled (its wrappers compile in each process,
    about 7 s: docs/control.md), the bounce and the parameter derivative equal the ball's
    closed form: from q = 1 at rest under g - u, the bounce at t1 = sqrt(2 / (g - u))."""
    flow = _nb_flow()
    u, T = 0.5, 0.6
    a = 9.81 - u
    t1 = np.sqrt(2 / a)
    v1 = 0.8 * a * t1
    s = T - t1
    assert np.allclose(flow.final([1.0, 0.0], [u], T), [v1 * s - 0.5 * a * s * s, v1 - a * s],
                       rtol=0, atol=1e-9)
    step = flow.step([1.0, 0.0], [u], T)
    eps = 1e-6
    fd = (flow.final([1.0, 0.0], [u + eps], T) - flow.final([1.0, 0.0], [u - eps], T)) / (2 * eps)
    assert np.allclose(step.B[:, 0], fd, rtol=1e-6, atol=1e-8)


def test_a_parameter_must_stand_still():
    """A model whose last coordinate moves is not a parametric flow: step and final
    refuse it, naming the field's entries (the 1-D ball's velocity taken as a
    "parameter")."""
    flow = ParametricFlow(examples.bouncing_ball().system, 1)
    for call in (lambda: flow.step([1.0], [0.0], 0.3), lambda: flow.final([1.0], [0.0], 0.3)):
        with pytest.raises(ValueError, match=r"parameters must not move.*field\(z, mask\)\[1:\]"):
            call()


def test_step_simulates_no_more_than_its_flow_map():
    """A step whose events cross one at a time is read off its flow map's run: no second
    simulation, its end the independent simulation's."""
    flow = ball_1d()
    x, p, T = np.array([1.0, 0.5]), np.array([0.7, 0.8, 9.81]), 1.6
    calls = []
    model_type = type(flow.system)  # a model is frozen: its type's method counted
    simulate = model_type.simulate
    with pytest.MonkeyPatch.context() as m:
        m.setattr(model_type, "simulate",
                  lambda *a, **k: calls.append(1) or simulate(*a, **k))
        step = flow.step(x, p, T)
    assert not calls and len(step.groups) == 2
    assert np.allclose(step.x_next, _ball_scipy(x, p, T), rtol=0, atol=1e-8)


def test_shooting_returns_the_state_of_its_decision():
    """Stopped by input_state_tol (error_tol out of reach), the result's final state and
    its convergence flag are those of the decision it returns (checked by the independent
    simulation)."""
    flow = ball_1d()
    res = shoot(flow, [1.0, 0.0], flow.defaults, 2.0, [0.5], output_indices=[0],
                state_indices=[1], initial_guess=[3.0],
                config=ShootingConfig(error_tol=1e-14, input_state_tol=1e-2))
    assert not res.converged and res.iterations < 50
    q = _ball_scipy([1.0, res.decision[0]], flow.defaults, 2.0)[0]
    assert abs(res.x_final[0] - q) < 1e-8
    assert abs(res.x_final[0] - 0.5) < res.errors[-1]  # the accepted step lowered |r|


def test_refusals():
    flow = ball_1d()
    with pytest.raises(TypeError, match="ParametricFlow"):
        shoot(object(), [1, 0], [0, 0.8, 9.81], 1.0, [0.5], output_indices=[0],
              state_indices=[1])
    with pytest.raises(ValueError, match="state_indices"):
        shoot(flow, [1, 0], flow.defaults, 1.0, [0.5], output_indices=[0],
              state_indices=[2])
    with pytest.raises(TypeError, match=r"output_indices must be a 1-D sequence of "
                       r"integers \(indices in \[0, 2\)\), got int 0"):
        shoot(flow, [1, 0], flow.defaults, 1.0, [0.5], output_indices=0, state_indices=[1])
    with pytest.raises(ValueError, match="target"):
        shoot(flow, [1, 0], flow.defaults, 1.0, [0.5, 1.0], output_indices=[0],
              state_indices=[1])
    with pytest.raises(ValueError, match="x must have shape"):
        flow.step([1.0], flow.defaults, 1.0)
    with pytest.raises(ValueError, match=r"U must have shape \(N, 3\)"):
        ilqr(flow, [1, 0], np.zeros((4, 2)), 0.1, [0, 0], Qf=np.eye(2), R=np.eye(3))
    U = np.zeros((4, 3))
    U[2, 1] = np.nan  # its shape was said wrong (a review)
    with pytest.raises(ValueError, match=r"U must be finite, got U\[2, 1\] = nan"):
        ilqr(flow, [1, 0], U, 0.1, [0, 0], Qf=np.eye(2), R=np.eye(3))
    with pytest.raises(ValueError, match="R must be symmetric"):
        ilqr(flow, [1, 0], np.zeros((4, 3)), 0.1, [0, 0], Qf=np.eye(2), R=-np.eye(3))
    with pytest.raises(ValueError, match="linearisation"):
        ilqr(flow, [1, 0], np.zeros((4, 3)), 0.1, [0, 0], Qf=np.eye(2), R=np.eye(3),
             linearisation="average")
    with pytest.raises(TypeError, match="HybridSystem"):
        ParametricFlow(object(), 1)
    with pytest.raises(ValueError, match="n_params"):
        ParametricFlow(flow.system, 5)
    args = (flow, [1, 0], np.zeros((3, 3)), 0.3, [0, 0])
    with pytest.raises(TypeError, match="linearisation must be"):
        ilqr(*args, Qf=np.eye(2), R=np.eye(3), linearisation=5)
    with pytest.raises(ValueError, match=r"linearisation, a fixed order.*\(0 \.\. 0\)"):
        ilqr(*args, Qf=np.eye(2), R=np.eye(3), linearisation=(7,))
    with pytest.raises(ValueError, match=r"Qf must be finite, but Qf\[0, 0\] = nan"):
        ilqr(*args, Qf=np.full((2, 2), np.nan), R=np.eye(3))
    with pytest.raises(ValueError, match="line_search must be an integer >= 1, got 0"):
        ilqr(*args, Qf=np.eye(2), R=np.eye(3), line_search=0)
    wide = augment(lambda z, m: z[:2], lambda z: z[:1] - 5, n_events=1, dim=1, n_params=1)
    with pytest.raises(ValueError, match=r"field\(z, mask\) must return shape \(1,\)"):
        ParametricFlow(wide, 1).final([1.0], [0.0], 1.0)


# -- settings out of range: refused by name, before any simulation --------------------------


@pytest.mark.parametrize(("field", "value", "error", "message"), [
    ("max_iters", 0, ValueError, "max_iters must be an integer >= 1, got 0"),
    ("max_iters", 2.5, TypeError, "max_iters must be an integer >= 1, got float 2.5"),
    ("max_iters", True, TypeError, "max_iters must be an integer >= 1, got bool True"),
    ("error_tol", 0.0, ValueError, "error_tol must be a finite number > 0, got 0.0"),
    ("error_tol", np.nan, ValueError, "error_tol must be a finite number > 0, got nan"),
    ("error_tol", -0.1, ValueError, "error_tol must be a finite number > 0, got -0.1"),
    ("error_tol", "0.1", TypeError, "error_tol must be a real number, got str '0.1'"),
    ("input_state_tol", -1e-3, ValueError, "input_state_tol must be a finite number >= 0"),
    ("input_state_tol", np.inf, ValueError, "input_state_tol must be a finite number >= 0"),
    ("initial_lambda", 0.0, ValueError, "initial_lambda must be a finite number > 0"),
    ("initial_lambda", 1e7, ValueError,
     r"initial_lambda must lie in \[min_lambda, max_lambda\] = \[1e-10, 1000000.0\], got "
     r"10000000.0"),
    ("lambda_increase", 0.5, ValueError, "lambda_increase must be a finite number >= 1"),
    ("lambda_increase", np.nan, ValueError, "lambda_increase must be a finite number >= 1"),
    ("lambda_decrease", 0.0, ValueError, "lambda_decrease must be a finite number > 0"),
    ("lambda_decrease", 10.0, ValueError,
     r"lambda_decrease must be a finite number in \(0, 1\], got 10.0"),
    ("min_lambda", 0.0, ValueError, "min_lambda must be a finite number > 0, got 0.0"),
    ("min_lambda", 1e7, ValueError,
     "min_lambda must be <= max_lambda, got min_lambda=10000000.0 > max_lambda=1000000.0"),
    ("max_lambda", np.inf, ValueError, "max_lambda must be a finite number > 0, got inf"),
    ("line_search_max_iters", -1, ValueError,
     "line_search_max_iters must be an integer >= 0, got -1"),
    ("line_search_max_iters", 1.0, TypeError,
     "line_search_max_iters must be an integer >= 0, got float 1.0"),
    ("line_search_backoff", 1.0, ValueError,
     r"line_search_backoff must be a finite number in \(0, 1\), got 1.0"),
    ("line_search_backoff", 0.0, ValueError, "line_search_backoff must be a finite number > 0"),
    ("line_search_backoff", np.nan, ValueError, "line_search_backoff must be a finite number"),
])
def test_shooting_config_refuses_out_of_range(field, value, error, message):
    """Each setting is checked when the config is built (not met as a silent wrong run: a
    NaN tolerance never stops, a backoff of 1 never shortens the step)."""
    with pytest.raises(error, match=message):
        ShootingConfig(**{field: value})


def test_shooting_config_keeps_meaningful_edges():
    """0 stays allowed where it means something: no stop for a small step, no halved
    steps; NumPy scalars are stored as plain Python numbers."""
    config = ShootingConfig(input_state_tol=0, line_search_max_iters=np.int64(0),
                            lambda_increase=1, lambda_decrease=1, error_tol=np.float32(0.5))
    assert config.input_state_tol == 0.0 and type(config.input_state_tol) is float
    assert config.line_search_max_iters == 0 and type(config.line_search_max_iters) is int
    assert type(config.error_tol) is float and type(config.lambda_increase) is float


@pytest.mark.parametrize(("keyword", "value", "error", "message"), [
    ("tol", np.nan, ValueError, "tol must be a finite number >= 0, got nan"),
    ("tol", -1e-9, ValueError, "tol must be a finite number >= 0, got -1e-09"),
    ("tol", 1.0, ValueError, r"tol must be a finite number in \[0, 1\) \(a relative "
                             r"decrease of the cost; max_iters bounds the iterations\), got 1.0"),
    ("tol", "1e-6", TypeError, "tol must be a real number, got str '1e-6'"),
    ("cost_tol", -1.0, ValueError, "cost_tol must be a finite number >= 0, got -1.0"),
    ("cost_tol", np.nan, ValueError, "cost_tol must be a finite number >= 0, got nan"),
    ("cost_tol", np.inf, ValueError, "cost_tol must be a finite number >= 0, got inf"),
    ("mu0", 0.0, ValueError, "mu0 must be a finite number > 0, got 0.0"),
    ("mu_max", np.nan, ValueError, "mu_max must be a finite number > 0, got nan"),
    ("mu_max", np.inf, ValueError, "mu_max must be a finite number > 0, got inf"),
    ("mu_max", 0.0, ValueError, "mu_max must be a finite number > 0, got 0.0"),
    ("mu_max", 1e-8, ValueError,
     r"mu_max must be >= mu0 \(the regularisation grows from mu0 up to mu_max\), got "
     r"mu_max=1e-08 < mu0=1e-06"),
    ("max_iters", 0, ValueError, "max_iters must be an integer >= 1, got 0"),
    ("max_iters", 10.0, TypeError, "max_iters must be an integer >= 1, got float 10.0"),
    ("line_search", 2.5, TypeError, "line_search must be an integer >= 1, got float 2.5"),
])
def test_ilqr_refuses_settings_before_simulating(monkeypatch, keyword, value, error,
                                                  message):
    """Each numeric keyword of ilqr is checked at the call's start: no simulation runs
    (a NaN tolerance or mu_max < mu0 would otherwise run and return a wrong result)."""
    flow = ball_1d()
    monkeypatch.setattr(type(flow), "final", lambda *a, **k: pytest.fail("simulated"))
    monkeypatch.setattr(type(flow), "step", lambda *a, **k: pytest.fail("simulated"))
    with pytest.raises(error, match=message):
        ilqr(flow, [1, 0], np.zeros((3, 3)), 0.3, [0, 0], Qf=np.eye(2), R=np.eye(3),
             **{keyword: value})


def test_ilqr_holds_the_parameters_that_are_not_inputs(thrust_ball):
    """ball_1d's parameters are (thrust, restitution, gravity): ilqr moved all three (a
    review: e about 8e-10 and g = -2.67 at its "optimum"). With ``inputs=[0]`` the other
    two keep their values in U0, and the result is the thrust-only model's, whose
    restitution and gravity are constants of its equations (0.8 and 9.81)."""
    from bderiv.control import models

    x0, target = np.array([1.0, 0.0]), np.array([0.4, 0.5])
    alone = ilqr(thrust_ball, x0, np.zeros((4, 1)), 0.25, target, **THRUST)
    U0 = np.tile([0.0, 0.8, 9.81], (4, 1))
    held = ilqr(models.ball_1d(), x0, U0, 0.25, target, Qf=THRUST["Qf"],
                R=np.diag([1e-3, 1.0, 1.0]), inputs=[0])
    assert held.converged and alone.converged
    np.testing.assert_array_equal(held.U[:, 1:], U0[:, 1:])
    np.testing.assert_allclose(held.U[:, 0], alone.U[:, 0], rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(held.X, alone.X, rtol=1e-6, atol=1e-8)
    for bad, kind, words in (([3], ValueError, r"inputs must be distinct indices in "
                                               r"\[0, 3\), got \[3\]"),
                             ((), ValueError, "inputs must name at least one"),
                             (0, TypeError, "inputs must be a 1-D sequence of integers")):
        with pytest.raises(kind, match=words):
            ilqr(models.ball_1d(), x0, U0, 0.25, target, Qf=THRUST["Qf"],
                 R=np.eye(3), inputs=bad)
