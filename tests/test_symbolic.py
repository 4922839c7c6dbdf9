"""bderiv.symbolic.from_sympy: generated kernels against independent oracles.

Oracles: closed forms of a small model written out by hand (field, events, resets and
every Jacobian, for every mask); central differences of the generated functions; the
bundled chair and landing examples, written by hand in Python (their fields, events,
complex-step and hand-written Jacobians, resets, and their flow maps' B-derivatives);
a second process that cannot call sympy's derivation (the cache).
"""

from __future__ import annotations

import os
import pathlib
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from numpy.testing import assert_allclose

sp = pytest.importorskip("sympy")

from bderiv.analysis.system import HybridSystem  # noqa: E402
from bderiv.examples.chair import chair  # noqa: E402
from bderiv.examples.impacts import landing  # noqa: E402
from bderiv.symbolic import ModelFunctions, SymbolicSource, from_sympy  # noqa: E402

PARAMS = {"a": 1.3, "b": 0.7, "c": 2.1}


def small_model(b_factor=1):
    """A d = 3, n = 2 model with flags in the field and the resets, and parameters:
    the keyword arguments of from_sympy (``b_factor`` changes one expression)."""
    q, v, w, s0, s1, a, b, c = sp.symbols("q v w s0 s1 a b c")
    field = [v,
             -a * sp.sin(q) + s0 * b * w**2 - s1 * c * v,
             s0 * s1 * sp.exp(-q) * v - b_factor * b * w + c * sp.cos(q) * s1]
    events = [q - c * w, v**2 / 2 + a * q - b]
    resets = {0: [q, (1 - s0) * (-b * v) + s0 * v, w + (1 - s0) * a * q * v],
              1: [q + s1 * c * w, v, w * sp.exp(a * q)]}
    params = {a: PARAMS["a"], b: PARAMS["b"], c: PARAMS["c"]}
    return dict(state=[q, v, w], flags=[s0, s1], field=field, events=events, resets=resets,
                params=params)


def closed_form(x, mask, a, b, c):
    """The small model's functions and Jacobians, written out by hand."""
    q, v, w = x
    s0, s1 = mask & 1, mask >> 1 & 1
    F = np.array([v, -a * np.sin(q) + s0 * b * w**2 - s1 * c * v,
                  s0 * s1 * np.exp(-q) * v - b * w + c * np.cos(q) * s1])
    JF = np.array([[0.0, 1.0, 0.0],
                   [-a * np.cos(q), -s1 * c, 2 * s0 * b * w],
                   [-s0 * s1 * np.exp(-q) * v - c * np.sin(q) * s1, s0 * s1 * np.exp(-q), -b]])
    h = np.array([q - c * w, v**2 / 2 + a * q - b])
    Dh = np.array([[1.0, 0.0, -c], [a, v, 0.0]])
    R = [np.array([q, (1 - s0) * (-b * v) + s0 * v, w + (1 - s0) * a * q * v]),
         np.array([q + s1 * c * w, v, w * np.exp(a * q)])]
    DR = [np.array([[1.0, 0.0, 0.0], [0.0, -(1 - s0) * b + s0, 0.0],
                    [(1 - s0) * a * v, (1 - s0) * a * q, 1.0]]),
          np.array([[1.0, 0.0, s1 * c], [0.0, 1.0, 0.0],
                    [a * w * np.exp(a * q), 0.0, np.exp(a * q)]])]
    return F, JF, h, Dh, R, DR


def central(f, x, step=1e-6):
    """Central differences of ``f`` at ``x``: columns are the partial derivatives."""
    cols = []
    for j in range(x.size):
        e = np.zeros(x.size)
        e[j] = step
        cols.append((f(x + e) - f(x - e)) / (2 * step))
    return np.stack(cols, axis=-1)


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("symbolic-cache")


@pytest.fixture(scope="module")
def small(cache):
    return from_sympy(**small_model(), cache_dir=cache)


POINTS = np.array([[0.3, -1.2, 0.8], [-0.7, 0.4, -1.5], [1.9, 2.2, 0.1]])


# ------------------------------------------------------------------------------
# the generated functions against the closed forms and central differences
# ------------------------------------------------------------------------------
@pytest.mark.parametrize("mask", range(4))
def test_small_model_against_closed_forms(small, mask):
    f = ModelFunctions(small)
    for x in POINTS:
        F, JF, h, Dh, R, DR = closed_form(x, mask, **PARAMS)
        assert_allclose(f.field(x, mask), F, rtol=1e-14, atol=1e-14)
        assert_allclose(f.field_jacobian(x, mask), JF, rtol=1e-14, atol=1e-14)
        assert_allclose(f.events(x), h, rtol=1e-14, atol=1e-14)
        assert_allclose(f.event_jacobian(x), Dh, rtol=1e-14, atol=1e-14)
        assert_allclose(f.corner_field(x)[mask], F, rtol=1e-14, atol=1e-14)
        for k in range(2):
            assert_allclose(f.reset(x, mask, k), R[k], rtol=1e-14, atol=1e-14)
            assert_allclose(f.reset_jacobian(x, mask, k), DR[k], rtol=1e-14, atol=1e-14)


@pytest.mark.parametrize("mask", range(4))
def test_small_model_jacobians_against_central_differences(small, mask):
    f = ModelFunctions(small)
    for x in POINTS:
        assert_allclose(f.field_jacobian(x, mask), central(lambda y: f.field(y, mask), x),
                        rtol=1e-7, atol=1e-7)
        assert_allclose(f.event_jacobian(x), central(f.events, x), rtol=1e-7, atol=1e-7)
        for k in range(2):
            assert_allclose(f.reset_jacobian(x, mask, k),
                            central(lambda y, k=k: f.reset(y, mask, k), x),
                            rtol=1e-7, atol=1e-7)


def test_system_is_a_hybrid_system_with_exact_jacobians(small):
    assert isinstance(small, HybridSystem)
    assert (small.dim, small.n_events, small.calls.has_resets) == (3, 2, True)
    assert type(small) is HybridSystem and type(small.source) is SymbolicSource
    assert small.source.builder == "from_sympy" and small.field is small.source.kernels.field
    assert repr(small.scipy_path()) == ("HybridSystem(n_events=2, dim=3, params: a=1.3, b=0.7, "
                                        "c=2.1)")
    x = POINTS[0]
    assert_allclose(small.calls.sample_corners(x),
                    [closed_form(x, m, **PARAMS)[0] for m in range(4)],
                    rtol=1e-14, atol=1e-14)
    small.calls.eval_field_jacobian(x, 3)
    assert small.numerical_jacobian_cost == {}  # every Jacobian given
    with pytest.raises(ValueError, match=r"x must have shape \(3,\), got shape \(2,\)"):
        ModelFunctions(small).field(np.zeros(2), 0)


def test_with_params_changes_the_answer_as_the_closed_form_says(small):
    other = small.with_params(b=0.2, c=-1.0)
    assert type(other) is HybridSystem and other.source is small.source
    assert other.source.kernels is small.source.kernels  # neither re-derived nor recompiled
    assert other.param_values == {"a": 1.3, "b": 0.2, "c": -1.0}
    assert small.param_values == PARAMS  # the original keeps its values
    by_symbol = small.with_params({sp.Symbol("b"): 0.2}, c=-1.0)
    for x in POINTS:
        for mask in range(4):
            F, JF, h, Dh, R, DR = closed_form(x, mask, a=1.3, b=0.2, c=-1.0)
            for sys_ in (other, by_symbol):
                assert_allclose(ModelFunctions(sys_).field(x, mask), F, rtol=1e-14, atol=1e-14)
                assert_allclose(ModelFunctions(sys_).field_jacobian(x, mask), JF, rtol=1e-14,
                                atol=1e-14)
                assert_allclose(ModelFunctions(sys_).events(x), h, rtol=1e-14, atol=1e-14)
                assert_allclose(ModelFunctions(sys_).reset_jacobian(x, mask, 0), DR[0],
                                rtol=1e-14, atol=1e-14)
    with pytest.raises(ValueError, match=r"d is not a parameter of this model \(its "
                                         r"parameters: a, b, c\)"):
        small.with_params(d=1.0)
    with pytest.raises(TypeError, match="the value of b must be a real number, got str"):
        small.with_params(b="1")
    with pytest.raises(ValueError, match="the value of b must be finite, got nan"):
        small.with_params(b=np.nan)
    assert not small.params.flags.writeable


def test_the_generic_operations_on_a_hand_written_model(small):
    """``with_params``, ``param_values``, ``scipy_path`` and :class:`ModelFunctions` are
    HybridSystem's, for any model: a hand-written one has no named parameters; a model
    not built by contact_system has no coupling."""
    from bderiv.symbolic import coupling

    p = np.array([2.0])
    plain = HybridSystem(lambda x, mask: x[:1] * x[1], lambda x: x[:1] - 1.0, n_events=1,
                         dim=1, params=p)
    assert plain.source is None and plain.param_values == {}
    assert repr(plain) == "HybridSystem(n_events=1, dim=1, numerical: event_jacobian, " \
                          "field_jacobian)"
    assert plain.with_params() is plain
    with pytest.raises(ValueError, match=r"a is not a parameter of this model \(its "
                                         r"parameters: none\)"):
        plain.with_params(a=1.0)
    with pytest.raises(TypeError, match="values must be a mapping parameter -> value, "
                                        "got list"):
        plain.with_params([1.0])
    assert plain.scipy_path().use_compiled is False
    assert ModelFunctions(plain).field(np.array([3.0]), 0) == [6.0]  # x then params
    with pytest.raises(TypeError, match="the model has no reset"):
        ModelFunctions(plain).reset(np.array([3.0]), 0, 0)
    with pytest.raises(TypeError, match="coupling needs a model built by contact_system, "
                                        "got HybridSystem with source SymbolicSource"):
        coupling(small, np.zeros(3))


def test_kernels_are_njit_functions_callable_from_compiled_code(small):
    """The layout the compiled integrator uses: the kernels called from an njit function,
    their ``x`` the state followed by the parameter values; they are closed to other
    argument types."""
    import numba

    K = small.source.kernels
    field, events = K.field, K.events

    @numba.njit
    def euler(x, mask, p, dt, steps):  # explicit Euler steps through the field kernel
        d = x.size
        xp = np.concatenate((x, p))
        for _ in range(steps):
            xp[:d] = xp[:d] + dt * field(xp, mask)
        return xp[:d], events(xp)

    x0, p = POINTS[0].copy(), np.array([1.3, 0.7, 2.1])
    x, h = euler(x0, 3, p, 1e-3, 5)
    expected = x0.copy()
    for _ in range(5):
        expected = expected + 1e-3 * closed_form(expected, 3, **PARAMS)[0]
    assert_allclose(x, expected, rtol=1e-14)
    assert_allclose(h, closed_form(expected, 3, **PARAMS)[2], rtol=1e-14)
    assert_allclose(K.corner_field(np.concatenate((x0, p))),
                    [closed_form(x0, m, **PARAMS)[0] for m in range(4)], rtol=1e-14)
    assert (K.dim, K.n_events, K.n_params, K.param_names) == (3, 2, 3, ("a", "b", "c"))
    with pytest.raises(TypeError, match="No matching definition"):
        K.field(x0.astype(np.float32), 0)


def test_a_symbolic_model_runs_every_stop_compiled(small, monkeypatch):
    """A symbolic model is on the compiled path, its stops included (the kernels' event
    Jacobian and resets are compiled): a run is one call of the compiled run, no stretch
    of the Python loop and no call of its checked Python functions, where solve_ivp on
    its scipy path calls them at every step; both give the same trajectory and flow
    map."""
    from bderiv.models.compiled import model as compiled_model
    from bderiv.models.integrate import run as run_module

    python = small.scipy_path()
    assert small.compiled is not None and python.compiled is None
    assert small.compiled.describe().endswith("stops: compiled")
    assert python.source is small.source and python.param_values == small.param_values
    calls = {"compiled run": 0, "python stretch": 0, "python calls": 0}

    def counted(name, fn):
        def call(*args, **kwargs):
            calls[name] += 1
            return fn(*args, **kwargs)
        return call

    x0, T, counted_runs = np.array([0.66, 0.08, -0.57]), 2.0, {}
    with monkeypatch.context() as m:
        m.setattr(compiled_model.CompiledModel, "run_stretches",
                  counted("compiled run", compiled_model.CompiledModel.run_stretches))
        m.setattr(run_module, "_python_stretch",
                  counted("python stretch", run_module._python_stretch))
        for system in (small, python):
            for name in ("eval_field", "eval_events", "eval_event_jacobian", "eval_reset"):
                m.setattr(system.calls, name, counted("python calls",
                                                      getattr(system.calls, name)))
        counted_runs["compiled"] = (small.simulate(x0, T), dict(calls))
        assert counted_runs["compiled"][1] == {"compiled run": 1, "python stretch": 0,
                                               "python calls": 0}
        counted_runs["scipy"] = (python.simulate(x0, T), calls["python calls"])
    compiled, scipy_ = counted_runs["compiled"][0], counted_runs["scipy"][0]
    assert counted_runs["scipy"][1] > 100
    assert [g.events for g in compiled.groups] == [g.events for g in scipy_.groups] == [
        (0,), (1,), (0,)]
    assert_allclose([g.time for g in compiled.groups], [g.time for g in scipy_.groups],
                    rtol=1e-12)
    assert_allclose(compiled.x_final, scipy_.x_final, rtol=1e-12, atol=1e-12)
    V = np.random.default_rng(4).standard_normal((20, 3))
    D_compiled, D_scipy = small.flow_bderivative(x0, T)(V), python.flow_bderivative(x0, T)(V)
    assert_allclose(D_compiled, D_scipy, rtol=0, atol=1e-10 * np.abs(D_scipy).max())


def test_a_python_section_is_refused_on_the_compiled_path(small):
    """The compiled integrator watches the section at every step: a Python one is
    refused, naming the way out; the scipy path takes it."""
    x0 = np.array([0.5, -0.2, 0.3])  # q falls through 0 before t = 2

    def section(x):
        return -x[0]

    with pytest.raises(TypeError, match=r"so section must be too .*scipy_path\(\)"):
        small.simulate(x0, 2.0, section=section)
    traj = small.scipy_path().simulate(x0, 2.0, section=section)
    assert traj.x_final[0] == pytest.approx(0.0, abs=1e-9)


def test_numbers_print_exactly(cache):
    """Floats keep every bit, rationals are correctly rounded, integers beyond int64 work."""
    x, s = sp.symbols("x s")
    big = 10**30
    sys_ = from_sympy([x], [s], [0.1 * x + sp.Rational(1, 3) + big * s + sp.Integer(3) * x**2],
                      [x - sp.Rational(2, 7)], cache_dir=cache)
    f = ModelFunctions(sys_)
    assert f.field(np.array([2.0]), 0)[0] == 0.1 * 2.0 + 1 / 3 + 3 * 2.0**2
    assert f.field(np.array([0.0]), 1)[0] == 1 / 3 + 1e30
    assert f.events(np.array([1.0]))[0] == 1.0 - 2 / 7
    assert f.field_jacobian(np.array([2.0]), 0)[0, 0] == 0.1 + 12.0


def test_store_keeps_the_first_file(tmp_path):
    from bderiv.symbolic import _cache

    path = _cache.module_path(_cache.cache_folder(tmp_path), "k")
    _cache.store(path, "first = 1\n")
    _cache.store(path, "second = 2\n")  # another process's write of the same key
    assert _cache.read(path) == "first = 1\n"
    assert [p.name for p in path.parent.iterdir()] == [path.name]  # no temporary left


# ------------------------------------------------------------------------------
# the bundled examples written as equations, against their hand-written versions
# ------------------------------------------------------------------------------
def chair_equations(legs):
    """The chair (bderiv.examples.chair) as sympy expressions, leg geometry as params."""
    X, Z, th, vx, vz, om = sp.symbols("X Z theta v_x v_z omega")
    flags = sp.symbols("s0 s1")
    K, C, kappa, Ct, inertia = sp.symbols("K C kappa C_t I")
    leg = sp.symbols("a0 b0 a1 b1")
    rx = [leg[2 * k] * sp.cos(th) - leg[2 * k + 1] * sp.sin(th) for k in range(2)]
    rz = [leg[2 * k] * sp.sin(th) + leg[2 * k + 1] * sp.cos(th) for k in range(2)]
    c_leg = C * (1 + kappa * flags[0] * flags[1])  # more damping while both legs touch
    fz = [flags[k] * (-K * (Z + rz[k]) - c_leg * (vz + om * rx[k])) for k in range(2)]
    fx = [flags[k] * (-Ct * (vx - om * rz[k])) for k in range(2)]
    field = [vx, vz, om, fx[0] + fx[1], -9.81 + fz[0] + fz[1],
             sum(rx[k] * fz[k] - rz[k] * fx[k] for k in range(2)) / inertia]
    params = {K: 400.0, C: 4.0, kappa: 1.0, Ct: 1.0, inertia: 0.1,
              **dict(zip(leg, np.ravel(legs).tolist(), strict=True))}
    return dict(state=[X, Z, th, vx, vz, om], flags=flags, field=field,
                events=[-(Z + rz[0]), -(Z + rz[1])], params=params)


@pytest.fixture(scope="module")
def chair_pair(cache):
    import inspect

    ex = chair()
    # the example's leg geometry (a_k, b_k), a constant of its field's closure
    legs = inspect.getclosurevars(ex.system.field).nonlocals["legs"]
    return ex, from_sympy(**chair_equations(legs), cache_dir=cache)


def test_chair_functions_match_the_hand_written_model(chair_pair):
    ex, sym = chair_pair
    hand = ex.system
    rng = np.random.default_rng(1)
    for x in (ex.rho, ex.x0, *(ex.rho + 0.3 * rng.standard_normal((2, 6)))):
        assert_allclose(sym.calls.eval_events(x), hand.calls.eval_events(x), rtol=1e-13,
                        atol=1e-14)
        assert_allclose(sym.calls.eval_event_jacobian(x), hand.calls.eval_event_jacobian(x),
                        rtol=1e-13, atol=1e-14)
        assert_allclose(sym.calls.sample_corners(x), hand.calls.sample_corners(x), rtol=1e-13,
                        atol=1e-12)
        for mask in range(4):
            # the example's field_jacobian is a complex-step Jacobian of its field
            assert_allclose(sym.calls.eval_field_jacobian(x, mask),
                            hand.calls.eval_field_jacobian(x, mask),
                            rtol=1e-12, atol=1e-11)
            assert_allclose(ModelFunctions(sym).field_jacobian(x, mask),
                            central(lambda y, mask=mask: ModelFunctions(sym).field(y, mask), x),
                            rtol=1e-6, atol=1e-6)


def test_chair_flow_bderivative_matches_the_hand_written_model(chair_pair):
    ex, sym = chair_pair
    V = np.random.default_rng(2).standard_normal((40, 6))
    D_sym = sym.flow_bderivative(ex.x0, ex.t_final)  # on the compiled integrator
    D_py = sym.scipy_path().flow_bderivative(ex.x0, ex.t_final)  # solve_ivp, Python calls
    D_hand = ex.system.flow_bderivative(ex.x0, ex.t_final)
    assert sym.compiled is not None and ex.system.compiled is None
    assert list(D_sym.group_events) == list(D_py.group_events) == list(D_hand.group_events) \
        == [(0, 1)]
    orders = {tuple(o) for o in D_hand.orders(V)[0]}
    assert orders == {(0, 1), (1, 0)}  # both pieces are compared
    for D in (D_sym, D_py):
        assert_allclose(D(V), D_hand(V), rtol=0, atol=1e-10 * np.abs(D_hand(V)).max())


def landing_equations():
    """The landing (bderiv.examples.impacts) as sympy expressions: plastic stop of each
    foot's sliding at touchdown as a reset, the coupling of the impulses a parameter."""
    Y, vY = sp.symbols("Y v_Y")
    feet = [sp.symbols(f"s{i} p{i} u{i} w{i}") for i in range(2)]
    flags = sp.symbols("f0 f1")
    m, k, c, kg, cg, hip, mu, thrust, coupling = sp.symbols(
        "m k c k_g c_g k_hip mu thrust coupling")
    g = 9.81
    push = thrust * flags[0] * flags[1]
    leg = [k * (1 - (Y - p)) - c * (vY - w) + push for (_, p, _, w) in feet]
    field = [vY, -g + leg[0] + leg[1]]
    for i, (s, p, u, w) in enumerate(feet):
        field += [u, w, -hip / m * s - flags[i] * mu / m * u,
                  -leg[i] / m - g - flags[i] * (kg / m * p + cg / m * w)]
    state = [Y, vY, *feet[0], *feet[1]]
    resets = {}
    for i in range(2):
        after = dict(zip(state, state, strict=True))
        u, u_other = feet[i][2], feet[1 - i][2]
        after[u] = flags[i] * u  # touchdown (flag 0): stopped; lift-off: unchanged
        after[u_other] = u_other - coupling * (1 - flags[i]) * u
        resets[i] = [after[x] for x in state]
    params = {m: 0.4, k: 200.0, c: 4.0, kg: 2000.0, cg: 20.0, hip: 30.0, mu: 40.0,
              thrust: 6.0, coupling: 0.0}
    return dict(state=state, flags=flags, field=field, events=[-feet[0][1], -feet[1][1]],
                resets=resets, params=params)


def test_landing_with_resets_matches_the_hand_written_model(cache):
    ex = landing()
    sym = from_sympy(**landing_equations(), cache_dir=cache)
    hand = ex.system
    for mask in range(4):
        for k in range(2):
            assert_allclose(sym.calls.eval_reset(ex.rho, mask, k),
                            hand.calls.eval_reset(ex.rho, mask, k),
                            rtol=1e-15, atol=0)
            assert_allclose(sym.calls.eval_reset_jacobian(ex.rho, mask, k),
                            hand.calls.eval_reset_jacobian(ex.rho, mask, k), rtol=0, atol=0)
    V = np.random.default_rng(3).standard_normal((40, 10))
    D_sym = sym.flow_bderivative(ex.x0, ex.t_final)
    D_hand = hand.flow_bderivative(ex.x0, ex.t_final)
    assert list(D_sym.group_events) == list(D_hand.group_events) == [(0, 1)]
    assert {tuple(o) for o in D_hand.orders(V)[0]} == {(0, 1), (1, 0)}
    assert_allclose(D_sym(V), D_hand(V), rtol=0, atol=1e-10 * np.abs(D_hand(V)).max())
    # coupled impulses: refused by both at the double touchdown (the resets do not commute)
    with pytest.raises(ValueError) as by_hand:
        landing(coupling=0.5).system.bderivative(ex.rho)
    with pytest.raises(ValueError) as by_sym:
        sym.with_params(coupling=0.5).bderivative(ex.rho)
    assert str(by_sym.value) == str(by_hand.value)


# ------------------------------------------------------------------------------
# the cache
# ------------------------------------------------------------------------------
def _no_derivation(monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("sympy derivation called")

    monkeypatch.setattr(sp, "diff", refuse)
    monkeypatch.setattr(sp, "cse", refuse)


def test_cache_hit_in_process_and_in_a_second_process(tmp_path, monkeypatch):
    first = from_sympy(**small_model(), cache_dir=tmp_path)
    assert not first.source.build.cached and first.source.build.derive_seconds > 0
    assert list((tmp_path / "symbolic").glob("m_*.py")) == [first.source.kernels.source]
    with monkeypatch.context() as m:
        _no_derivation(m)
        again = from_sympy(**small_model(), cache_dir=tmp_path)
        with pytest.raises(AssertionError, match="derivation called"):
            from_sympy(**small_model(b_factor=2), cache_dir=tmp_path)  # other expressions
    assert again.source.build.cached and again.source.build.key == first.source.build.key
    # a second process with sympy's derivation disabled loads the same kernels
    code = textwrap.dedent(f"""
        import sys
        import numpy as np
        import sympy
        sys.path.insert(0, {str(pathlib.Path(__file__).parent)!r})
        from test_symbolic import small_model
        def refuse(*args, **kwargs):
            raise AssertionError("sympy derivation called")
        sympy.diff = sympy.cse = refuse
        from bderiv.symbolic import ModelFunctions, from_sympy
        s = from_sympy(**small_model(), cache_dir={str(tmp_path)!r})
        b = s.source.build
        print(b.cached, b.key, *ModelFunctions(s).field(np.array([0.3, -1.2, 0.8]), 3))
    """)
    env = {k: v for k, v in os.environ.items() if k != "BDERIV_CACHE_DIR"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=env, timeout=300)
    assert out.returncode == 0, out.stderr
    cached, key, *F = out.stdout.split()
    assert (cached, key) == ("True", first.source.build.key)
    assert_allclose(np.array(F, dtype=float),
                    closed_form(np.array([0.3, -1.2, 0.8]), 3, **PARAMS)[0], rtol=1e-15)
    other = from_sympy(**small_model(b_factor=2), cache_dir=tmp_path)  # a miss: derived
    assert not other.source.build.cached and other.source.build.key != first.source.build.key
    assert len(list((tmp_path / "symbolic").glob("m_*.py"))) == 2
    x = POINTS[0]
    assert ModelFunctions(other).field(x, 0)[2] == pytest.approx(-2 * PARAMS["b"] * x[2],
                                                                 rel=1e-15)


def test_cache_dir_from_the_environment(tmp_path, monkeypatch):
    monkeypatch.setenv("BDERIV_CACHE_DIR", str(tmp_path))
    x, s = sp.symbols("x s")
    sys_ = from_sympy([x], [s], [1 + s * x], [x - 1])
    assert sys_.source.kernels.source.parent == tmp_path / "symbolic"
    assert sys_.params.shape == (0,)
    assert_allclose(ModelFunctions(sys_).corner_field(np.array([2.0])), [[1.0], [3.0]])


# ------------------------------------------------------------------------------
# refusals
# ------------------------------------------------------------------------------
def test_refusals(cache):
    x, y, s, t, a, z = sp.symbols("x y s t a z")
    ok = dict(state=[x, y], flags=[s], field=[y, -a * x + s], events=[x],
              params={a: 1.0}, cache_dir=cache)

    def refused(exc, match, **change):
        with pytest.raises(exc, match=match):
            from_sympy(**{**ok, **change})

    refused(ValueError, r"field must have 2 expressions \(one per state symbol, d = 2\), "
                        r"got 3", field=[y, x, x])
    refused(ValueError, r"events must have 2 expressions \(one per flag, n = 2\), got 1",
            flags=[s, t])
    refused(ValueError, r"events\[0\] = s \+ x contains s, which are flags", events=[x + s])
    refused(ValueError, r"field\[1\] = -a\*x \+ z contains z, which are neither state, "
                        r"flags nor parameters", field=[y, -a * x + z])
    refused(ValueError, r"field\[1\] = -a\*x \+ s contains a, which are neither", params={})
    refused(TypeError, r"params\[a\] must be a real number, got NoneType",
            params={a: None})
    refused(ValueError, r"params\[a\] must be finite, got inf", params={a: np.inf})
    refused(TypeError, r"state\[1\] must be a sympy Symbol, got str 'y'", state=[x, "y"])
    refused(ValueError, r"state\[1\] = x repeats state\[0\]", state=[x, x])
    refused(ValueError, "x is both a state symbol and a flag", flags=[x])
    refused(TypeError, r"field\[0\] must be a sympy expression or a number, got str",
            field=["y", x])
    refused(ValueError, r"resets key 1 is not an event index in \[0, 1\)",
            resets={1: [x, y]})
    refused(ValueError, r"resets\[0\] must have 2 expressions", resets={0: [x]})
    refused(ValueError, r"resets\[0\]\[1\] = z contains z, which are neither",
            resets={0: [x, z]})
    refused(ValueError, r"field\[1\] = f\(x\) does not compile: sympy cannot print it as "
                        r"Python \(PrintMethodNotImplementedError: f\)",
            field=[y, sp.Function("f")(x)])
    refused(ValueError, r"field\[0\] = I\*x does not compile with numba: No conversion from "
                        r"complex128 to float64", field=[sp.I * x, y])
    refused(ValueError, r"the derivative of field\[0\] by x = 2\*DiracDelta\(x\) "
                        r"does not compile: sympy cannot print it", field=[sp.sign(x), y])
    assert not [p for p in (cache / "symbolic").glob("m_*.py")
                if "I*x" in p.read_text() or "1j" in p.read_text()]  # not left in the cache
