"""bderiv.jax: flow maps and B-derivatives as JAX functions (skipped without jax).

Oracles: an event-detecting simulation written here with scipy's solve_ivp (region by
region, its own event handling) and its finite differences; the flow's B-derivative,
pieces and adjoints from bderiv's NumPy API (what the JAX functions must hand through
unchanged); tests/reference.py for the saltation map of a table (bmap).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

jax = pytest.importorskip("jax")
jax.config.update("jax_enable_x64", True)
jnp = jax.numpy

from reference import ref_apply, ref_event_times, ref_piece  # noqa: E402

from bderiv import BDerivative, HybridSystem  # noqa: E402
from bderiv.examples import chair, three_event_table  # noqa: E402
from bderiv.jax import _host, bmap, flow  # noqa: E402

E6 = np.eye(6)
#: what JAX raises for a failed callback: JaxRuntimeError, or ValueError once the
#: computation runs on JAX's fast dispatch path (after a successful call)
REFUSED = (jax.errors.JaxRuntimeError, ValueError)
TIGHT = {"rtol": 1e-12, "atol": 1e-13}


@pytest.fixture(scope="module")
def touchdown():
    """The chair landing on both legs at once (t = 0.1), its B-derivative, tangents in
    both pieces (pitch up: leg 0 first; pitch down: leg 1 first)."""
    ex = chair()
    D = ex.system.flow_bderivative(ex.x0, ex.t_final, **TIGHT)
    rng = np.random.default_rng(1)
    T = np.vstack([E6[2], -E6[2], rng.standard_normal((4, 6))])
    assert {tuple(o) for o in D.orders(T)[0]} == {(0, 1), (1, 0)}
    return ex, D, T


def _reference_flow(system, x0, t_final):
    """Phi(t_final, x0) by solve_ivp, one region at a time: each event function is
    watched in the direction that changes its region's bit (up while clear, down while
    set), so a surface just crossed is not found again at the restart."""
    n = system.n_events
    mask = sum(1 << k for k, h in enumerate(system.calls.eval_events(x0)) if h > 0)
    t, x = 0.0, np.array(x0, dtype=float)
    while True:
        events = []
        for k in range(n):
            def ev(_t, y, k=k):
                return system.calls.eval_events(y)[k]
            ev.terminal, ev.direction = True, -1.0 if mask >> k & 1 else 1.0
            events.append(ev)
        sol = solve_ivp(lambda _t, y, m=mask: system.calls.eval_field(y, m), (t, t_final), x,
                        method="DOP853", rtol=1e-12, atol=1e-13, events=events)
        t, x = sol.t[-1], sol.y[:, -1]
        if sol.status == 0:
            return x
        for k in range(n):
            if sol.t_events[k].size:
                mask ^= 1 << k


def test_primal_is_the_simulation(touchdown):
    ex, D, _ = touchdown
    phi = flow(ex.system, ex.t_final, **TIGHT)
    out = phi(ex.x0)
    assert out.dtype == jnp.float64 and out.shape == (6,)
    np.testing.assert_array_equal(out, ex.system.simulate(ex.x0, ex.t_final, **TIGHT).x_final)
    np.testing.assert_allclose(out, _reference_flow(ex.system, ex.x0, ex.t_final),
                               rtol=1e-9, atol=1e-10)
    np.testing.assert_array_equal(jax.jit(phi)(ex.x0), out)


def test_jvp_is_the_bderivative_in_every_piece(touchdown):
    ex, D, T = touchdown
    phi = flow(ex.system, ex.t_final, **TIGHT)
    for t in T:
        y, dy = jax.jvp(phi, (jnp.asarray(ex.x0),), (jnp.asarray(t),))
        expected = D(t)
        assert np.linalg.norm(dy - expected) <= 1e-12 * np.linalg.norm(expected)
    # linearize and jit reach the same host computation
    _, f_lin = jax.linearize(phi, ex.x0)
    np.testing.assert_allclose(f_lin(T[1]), D(T[1]), rtol=1e-12, atol=0)
    jvp = jax.jit(lambda x, t: jax.jvp(phi, (x,), (t,))[1])
    np.testing.assert_allclose(jvp(ex.x0, T[0]), D(T[0]), rtol=1e-12, atol=0)


def test_forward_mode_is_the_limit_of_finite_differences_in_every_piece(touchdown):
    """(Phi(x0 + eps t) - Phi(x0)) / eps, of the JAX function's own values and of the
    independent simulation, converges at O(eps) to jax.jvp, for tangents of both pieces;
    the two pieces differ by far more."""
    ex, _, T = touchdown
    phi = flow(ex.system, ex.t_final, **TIGHT)
    flows = [lambda x: np.asarray(phi(x)),
             lambda x: _reference_flow(ex.system, x, ex.t_final)]
    for values in flows:
        base = values(ex.x0)
        for t in T[:2]:
            dy = np.asarray(jax.jvp(phi, (ex.x0,), (t,))[1])
            errs = []
            for eps in (1e-3, 1e-4, 1e-5):
                fd = (values(ex.x0 + eps * t) - base) / eps
                errs.append(np.linalg.norm(fd - dy) / np.linalg.norm(dy))
            assert errs[2] < 1e-3, errs
            assert errs[1] < 0.2 * errs[0] and errs[2] < 0.2 * errs[1], errs  # O(eps)
    # -t is not the negative of t's tangent: the pieces differ (by a lot, here)
    up, down = (np.asarray(jax.jvp(phi, (ex.x0,), (t,))[1]) for t in T[:2])
    assert np.linalg.norm(up + down) > 0.1 * np.linalg.norm(up)


def test_grad_is_the_transpose_of_the_stated_piece(touchdown):
    ex, D, T = touchdown
    w = np.linspace(-1.0, 1.0, 6)
    for v in T[:2]:
        phi = flow(ex.system, ex.t_final, direction=v, **TIGHT)
        g = jax.grad(lambda x, phi=phi: jnp.dot(w, phi(x)))(ex.x0)
        np.testing.assert_allclose(g, D.vjp(v, w), rtol=1e-12, atol=1e-12)
        (order,) = D.orders(v)
        np.testing.assert_allclose(g, D.piece([order]).T @ w, rtol=1e-10, atol=1e-12)
        # jacrev is that piece; vjp gives the same transpose
        np.testing.assert_allclose(jax.jacrev(phi)(ex.x0), D.piece([order]), rtol=1e-10,
                                   atol=1e-12)
        np.testing.assert_allclose(jax.vjp(phi, ex.x0)[1](w)[0], g, rtol=1e-14, atol=0)
        # the adjoint identity holds for tangents of that piece (v itself), by the
        # forward mode and by finite differences of the independent simulation
        dy = jax.jvp(phi, (ex.x0,), (v,))[1]
        assert abs(np.dot(w, dy) - np.dot(g, v)) < 1e-10 * np.linalg.norm(g)
        eps = 1e-6
        fd = (_reference_flow(ex.system, ex.x0 + eps * v, ex.t_final)
              - _reference_flow(ex.system, ex.x0, ex.t_final)) / eps
        assert abs(np.dot(w, fd) - np.dot(g, v)) < 1e-4 * np.linalg.norm(g)
    # the two stated pieces give different gradients
    g_up, g_down = (jax.grad(lambda x, v=v: jnp.dot(w, flow(
        ex.system, ex.t_final, direction=v, **TIGHT)(x)))(ex.x0) for v in T[:2])
    assert np.linalg.norm(g_up - g_down) > 0.1 * np.linalg.norm(g_up)


def test_reverse_mode_without_direction():
    """Where the flow meets no simultaneous events its derivative is linear and grad needs
    no direction; at the touchdown it is refused, saying why and what to pass."""
    ex = chair()
    x0 = ex.x0 + 0.02 * E6[2]  # tilted: leg 0 lands well before leg 1
    phi = flow(ex.system, ex.t_final, **TIGHT)
    D = ex.system.flow_bderivative(x0, ex.t_final, **TIGHT)
    assert [len(e) for e in D.group_events] == [1, 1]
    w = np.arange(6.0)
    g = jax.grad(lambda x: jnp.dot(w, phi(x)))(x0)
    np.testing.assert_allclose(g, D.piece().T @ w, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(jax.jacrev(phi)(x0), jax.jacfwd(phi)(x0), rtol=1e-10,
                               atol=1e-12)
    with pytest.raises(REFUSED,
                       match=r"reverse mode meets simultaneous events at t = 0\.1\b.*"
                             r"pass direction="):
        jax.grad(lambda x: jnp.dot(w, phi(x)))(ex.x0)


def test_a_refusal_is_not_logged_by_jax_first(touchdown, caplog):
    """The refusal reaches the caller as the exception, and JAX's callback logger says
    nothing (it printed an ERROR with a traceback before the refusal)."""
    import logging

    ex = touchdown[0]
    phi = flow(ex.system, ex.t_final, **TIGHT)
    w = np.arange(6.0)
    with caplog.at_level(logging.DEBUG), pytest.raises(REFUSED, match="pass direction="):
        jax.grad(lambda x: jnp.dot(w, phi(x)))(ex.x0)
    assert not [r for r in caplog.records if r.name.startswith("jax._src.callback")]


def test_a_compiled_model_runs_on_the_compiled_path(touchdown):
    """A model of numba dispatchers (tests/compiled_models.py: the chair's twin) is
    simulated in compiled code through the same callbacks: values and tangents agree with
    the Python model's B-derivative."""
    from compiled_models import chair_pair

    ex, D, T = touchdown
    _, compiled = chair_pair()
    assert compiled.compiled is not None
    phi = flow(compiled, ex.t_final, **TIGHT)
    np.testing.assert_allclose(phi(ex.x0), D.x_final, rtol=1e-9, atol=1e-10)
    dy = jax.vmap(lambda t: jax.jvp(phi, (ex.x0,), (t,))[1])(T)
    assert np.abs(dy - D(T)).max() < 1e-6 * np.abs(D(T)).max()


def _plane():
    """Two events of constant fields in the plane (HybridSystem's docstring example)."""
    F = np.array([[1.0, 1.0], [1.0, 2.0], [2.0, 1.0], [1.5, 1.5]])
    return HybridSystem(lambda x, mask: F[mask], lambda x: x - 1.0, n_events=2, dim=2,
                        event_jacobian=lambda x: np.eye(2),
                        field_jacobian=lambda x, mask: np.zeros((2, 2)))


def _count_calls(monkeypatch, name):
    """Record the leading shapes FlowHost.<name> is called with."""
    calls = []
    original = getattr(_host.FlowHost, name)

    def counted(self, *arrays):
        calls.append(np.broadcast_shapes(*(np.shape(a)[:-1] for a in arrays)))
        return original(self, *arrays)

    monkeypatch.setattr(_host.FlowHost, name, counted)
    return calls


@pytest.mark.parametrize("m", [100, pytest.param(1000, marks=pytest.mark.slow)])
def test_vmap_is_one_host_call_and_equals_a_loop(monkeypatch, m):
    system = _plane()
    X = np.random.default_rng(2).uniform(-0.5, 0.5, (m, 2))
    calls = _count_calls(monkeypatch, "final_states")
    phi = flow(system, 2.0)
    out = jax.vmap(phi)(X)
    assert calls == [(m,)]
    loop = np.array([system.simulate(x, 2.0).x_final for x in X])
    np.testing.assert_array_equal(out, loop)
    # nested vmaps hand the whole (m/4, 4) batch over too
    calls.clear()
    np.testing.assert_array_equal(jax.vmap(jax.vmap(phi))(X.reshape(-1, 4, 2)),
                                  loop.reshape(-1, 4, 2))
    assert calls == [(m // 4, 4)]


def test_vmap_of_jvp_and_grad_is_one_host_call(monkeypatch):
    system = _plane()
    X = np.random.default_rng(3).uniform(-0.5, 0.5, (8, 2))
    T = np.random.default_rng(4).standard_normal((8, 2))
    tangents = _count_calls(monkeypatch, "tangents")
    cotangents = _count_calls(monkeypatch, "cotangents")
    phi = flow(system, 2.0, direction=[1.0, 0.5])
    dy = jax.vmap(lambda x, t: jax.jvp(phi, (x,), (t,))[1])(X, T)
    assert tangents == [(8,)]
    for x, t, row in zip(X, T, dy, strict=True):
        np.testing.assert_allclose(row, system.flow_bderivative(x, 2.0)(t), rtol=1e-12)
    # jacfwd at one start: one host call with the unit vectors, each through D
    tangents.clear()
    J = jax.jacfwd(phi)(X[0])
    assert tangents == [(2,)]
    np.testing.assert_allclose(J, system.flow_bderivative(X[0], 2.0)(np.eye(2)).T,
                               rtol=1e-12)
    g = jax.vmap(jax.grad(lambda x: phi(x).sum()))(X)
    assert cotangents == [(8,)]
    for x, row in zip(X, g, strict=True):
        D = system.flow_bderivative(x, 2.0)
        np.testing.assert_allclose(row, D.vjp([1.0, 0.5], np.ones(2)), rtol=1e-12)


def test_jit_compiles_once():
    system = _plane()
    traces = []

    def loss(x):
        traces.append(1)
        return flow_map(x).sum()

    flow_map = flow(system, 2.0)
    fast = jax.jit(jax.value_and_grad(loss))
    X = np.random.default_rng(5).uniform(-0.5, 0.5, (3, 2))
    for x in X:
        value, grad = fast(x)
        D = system.flow_bderivative(x, 2.0)
        assert value == pytest.approx(system.simulate(x, 2.0).x_final.sum(), rel=1e-14)
        if all(len(e) == 1 for e in D.group_events):
            np.testing.assert_allclose(grad, D.piece().T @ np.ones(2), rtol=1e-12)
    assert len(traces) == 1


def test_float32_and_integer_starts():
    system = _plane()
    phi = flow(system, 2.0)
    x64 = np.array([0.25, -0.125])
    out32 = phi(x64.astype(np.float32))
    assert out32.dtype == jnp.float32
    np.testing.assert_allclose(out32, phi(x64), rtol=1e-6)
    assert phi(np.array([0, 0])).dtype == jnp.float64


def test_bad_arguments_are_refused_when_given():
    ex = chair()
    with pytest.raises(TypeError, match="system must be a HybridSystem, got BDerivative"):
        flow(BDerivative(np.eye(2), np.ones((4, 2))), 1.0)
    with pytest.raises(ValueError, match="t_final must be a finite number > 0, got -1.0"):
        flow(ex.system, -1.0)
    with pytest.raises(ValueError, match=r"direction must have shape \(6,\).*got shape \(2,\)"):
        flow(ex.system, 1.0, direction=[1.0, 0.0])
    with pytest.raises(ValueError, match="direction must be finite and nonzero"):
        flow(ex.system, 1.0, direction=np.zeros(6))
    with pytest.raises(ValueError, match="rtol must be in"):
        flow(ex.system, 1.0, rtol=0.5e-16)
    phi = flow(ex.system, ex.t_final)
    with pytest.raises(ValueError, match=r"x0 must have shape \(\.\.\., 6\).*got shape \(3,\)"):
        phi(np.ones(3))
    with pytest.raises(ValueError, match=r"x0 must have shape .*got shape \(4, 5\)"):
        jax.jit(phi)(np.ones((4, 5)))
    with pytest.raises(TypeError, match="x0 must hold real numbers.*complex128"):
        phi(np.ones(6, dtype=complex))
    with pytest.raises(TypeError, match="x0 must hold real numbers.*bool"):
        phi(np.ones(6, dtype=bool))


@pytest.mark.parametrize("transform", ["eager", "jit", "vmap", "jvp"])
def test_refusals_reach_the_caller_with_bderivs_message(transform):
    ex = chair()
    bad = ex.rho  # both feet on the ground: a start on the event surfaces
    with pytest.raises(ValueError) as info:
        ex.system.simulate(bad, ex.t_final)
    message = str(info.value)
    phi = flow(ex.system, ex.t_final)
    call = {"eager": phi, "jit": jax.jit(phi),
            "vmap": lambda x: jax.vmap(phi)(np.stack([ex.x0, x])),
            "jvp": lambda x: jax.jvp(phi, (x,), (E6[0],))}[transform]
    for _ in range(2):  # before and after a successful call (JAX dispatches differently)
        with pytest.raises(REFUSED) as info:
            call(bad)
        assert f"bderiv.jax.flow at x0 = {bad.tolist()}: {message}" in str(info.value)
        call(ex.x0)
    # a non-finite start: bderiv's refusal, not a NaN result
    with pytest.raises(REFUSED, match="x0 must be finite"):
        call(np.full(6, np.nan))


def test_second_derivatives_are_refused(touchdown):
    ex, _, T = touchdown
    phi = flow(ex.system, ex.t_final, direction=T[0], **TIGHT)
    with pytest.raises(NotImplementedError, match="first derivatives only"):
        jax.hessian(lambda x: phi(x).sum())(ex.x0)
    with pytest.raises(NotImplementedError, match="first derivatives only"):
        jax.jvp(lambda x: jax.jvp(phi, (x,), (T[0],))[1], (ex.x0,), (T[1],))


# -- bmap -------------------------------------------------------------------------------


def test_bmap_of_a_bderivative_against_the_reference():
    Dh, F = three_event_table()
    bd = BDerivative(Dh, F)
    m = bmap(bd)
    U = np.random.default_rng(6).standard_normal((8, 3))
    np.testing.assert_allclose(jax.vmap(m)(U), [ref_apply(Dh, F, u) for u in U],
                               rtol=1e-12, atol=1e-13)
    P = [ref_piece(Dh, F, ref_event_times(Dh, F, u)[1]) for u in U]  # the piece at u
    np.testing.assert_allclose(jax.vmap(jax.jacrev(m))(U), P, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(jax.vmap(jax.jacfwd(m))(U), P, rtol=1e-10, atol=1e-12)
    du, w = np.ones(3), np.arange(3.0)
    np.testing.assert_allclose(jax.jvp(m, (U[0],), (du,))[1], bd.jvp(U[0], du), rtol=1e-14)
    np.testing.assert_allclose(jax.vjp(m, U[0])[1](w)[0], bd.vjp(U[0], w), rtol=1e-14)
    np.testing.assert_allclose(jax.jit(m)(U), bd(U), rtol=1e-14)


def test_transpose_of_a_tangent_shared_by_a_batch():
    """One tangent t pushed through the pieces of a batch of points: the transpose sums
    their transposes (the primitive's cotangent summed over the broadcast axis)."""
    bd = BDerivative(*three_event_table())
    m = bmap(bd)
    U = np.random.default_rng(7).standard_normal((5, 3))
    W = np.random.default_rng(8).standard_normal((5, 3))

    def push(t):
        return jax.vmap(lambda u: jax.jvp(m, (u,), (t,))[1])(U)

    (t_bar,) = jax.linear_transpose(push, np.ones(3))(W)
    np.testing.assert_allclose(t_bar, bd.vjp(U, W).sum(axis=0), rtol=1e-12)


def test_bmap_of_a_flow_bderivative(touchdown):
    ex, D, T = touchdown
    m = bmap(D)
    np.testing.assert_allclose(m(T), D(T), rtol=1e-14)
    for t in T[:2]:
        (order,) = D.orders(t)
        np.testing.assert_allclose(jax.jacrev(m)(t), D.piece([order]), rtol=1e-10,
                                   atol=1e-12)


def test_bmap_errors():
    with pytest.raises(TypeError, match="bd must be a BDerivative or a FlowBDerivative, "
                                        "got ndarray"):
        bmap(np.eye(2))
    m = bmap(BDerivative(*three_event_table()))
    with pytest.raises(ValueError, match=r"u must have shape \(\.\.\., 3\)"):
        m(np.ones(2))
    with pytest.raises(REFUSED, match="V must be finite"):
        m(np.array([1.0, np.inf, 0.0]))
