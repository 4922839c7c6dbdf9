"""bderiv.symbolic: the inputs refused or taken, and what the generated functions check.

Oracles: closed forms (a ball dropped from 1 m meets the floor at sqrt(2 / 9.81) s; a
box hitting a floor and then a wall, its impacts computed by hand from
``v+ = v - (1 + e) w (J v) / (J w)``, ``w = M^-1 J^T``), the numbers a model is built
with, and the words of the errors (what they name).
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

sp = pytest.importorskip("sympy")

from bderiv.symbolic import ModelFunctions, contact_system, from_sympy  # noqa: E402

G = 9.81
x, y, a, b, s0, s1 = sp.symbols("x y a b s0 s1")


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("symbolic-inputs-cache")


def generated(folder) -> list:
    return list(folder.rglob("m_*.py"))


def ball(cache, **change):
    """A unit mass above a floor (gap y), gravity down: contact_system's arguments."""
    return contact_system(**{**dict(q=[x, y], mass_matrix=sp.eye(2), forces=[0, -G],
                                    contacts=[y], impact=0.5, cache_dir=cache), **change})


@pytest.fixture(scope="module")
def param_ball(cache):
    """:func:`ball` with its restitution the parameter a (0.5) and its horizontal mass the
    parameter b (1): the model the tests of values build (compiled once)."""
    return ball(cache, mass_matrix=sp.diag(b, 1), impact=a, params={a: 0.5, b: 1.0})


# --- one symbol, one role ---------------------------------------------------------------
def test_a_symbol_in_two_roles_is_refused_before_anything_is_built(tmp_path, param_ball):
    """Each of these built a model whose state read the wrong entry (velocities=[y, vy]
    made the floor's height the vertical velocity: no impact) or failed later
    (``flags=[y]``: NameError s_0); now refused, naming the symbol and both roles."""
    xd, yd, k = sp.Symbol("x_dot"), sp.Symbol("y_dot"), sp.Symbol("contact_stiffness")
    cases = [
        (dict(velocities=[y, sp.Symbol("vy")]),
         r"y is both a coordinate \(q\[1\]\) and a velocity \(velocities\[0\]\)"),
        (dict(params={y: 5.0}), r"y is both a coordinate \(q\[1\]\) and a parameter "
                                r"\(a key of params\)"),
        (dict(q=[x, xd], contacts=[xd]),
         r"x_dot is both a coordinate \(q\[1\]\) and a velocity \(the velocity of q\[0\], "
         r"named by default"),
        (dict(flags=[y]), r"y is both a coordinate \(q\[1\]\) and a flag \(flags\[0\]\)"),
        (dict(params={yd: 3.0}), r"y_dot is both a velocity \(the velocity of q\[1\], "
                                 r"named by default.*and a parameter \(a key of params\)"),
        (dict(velocities=[k, sp.Symbol("v")]), r"contact_stiffness is both a velocity "
                                               r"\(velocities\[0\]\) and a parameter \(of "
                                               r"the default stance law\)"),
    ]
    for change, message in cases:
        with pytest.raises(ValueError, match=message):
            ball(tmp_path, **change)
    assert not generated(tmp_path)
    # the model as meant: dropped from 1 m, it meets the floor at sqrt(2 / g)
    traj = param_ball.simulate(np.array([0.0, 1.0, 2.0, 0.0]), 0.5)
    assert_allclose(traj.groups[0].time, np.sqrt(2 / G), rtol=1e-10)


# --- the generated functions check the length of x --------------------------------------
def test_generated_functions_refuse_a_state_of_another_length(cache):
    """Given the state without its parameters (or too long) a kernel read past the end of
    the array and returned garbage (``model.events(state)`` gave [0.1, 0.2] for the true
    [-0.4, -1.8])."""
    m = from_sympy([x, y], [s0, s1], [1 + a, 1 + b * s0], [x - a, y - b],
                   resets={0: [x, -y]}, params={a: 0.5, b: 2.0}, cache_dir=cache)
    k = m.source.kernels
    state, full = np.array([0.1, 0.2]), np.array([0.1, 0.2, 0.5, 2.0])
    assert_allclose(m.events(full), [0.1 - 0.5, 0.2 - 2.0], rtol=1e-15)
    assert_allclose(m.field(full, 1), [1.5, 3.0], rtol=1e-15)
    message = (r"x must have 4 entries: the state \(2\) then the 2 parameter values in the "
               r"order of param_names")
    calls = [lambda z: k.field(z, 1), lambda z: k.field_jacobian(z, 1), k.events,
             k.event_jacobian, k.corner_field, lambda z: k.reset(z, 0, 0),
             lambda z: k.reset_jacobian(z, 0, 0)]
    for call in calls:
        for wrong in (state, full[:1], np.append(full, 7.0)):
            with pytest.raises(ValueError, match=message):
                call(np.ascontiguousarray(wrong))
    with pytest.raises(ValueError, match=message):  # the Python code says the same
        k.events.py_func(state)
    with pytest.raises(ValueError, match=message):  # the checked calls reach the kernel
        m.calls.eval_events(np.array([0.1, 0.2, 7.0]))


def test_contact_kernels_refuse_a_state_of_another_length(param_ball):
    model = param_ball
    k = model.source.kernels
    full = np.concatenate((np.array([0.0, 1.0, 2.0, 0.0]), model.params))
    with pytest.raises(ValueError, match=r"x must have 8 entries: the state \(4\) then the "
                                         r"4 parameter values"):
        k.field(full[:4], 0)
    with pytest.raises(ValueError, match="x must have 8 entries"):
        model.source.coupling(full[:2])
    assert_allclose(k.field(full, 0), [2.0, 0.0, 0.0, -G], rtol=1e-15)


# --- simultaneous impacts: by time, not by distance --------------------------------------
M_BOX = np.array([[1.0, 0.3], [0.3, 1.0]])


def _impact(v, J, e=0.8):
    w = np.linalg.solve(M_BOX, J)
    return v - (1 + e) * w * (J @ v) / (J @ w)


@pytest.fixture(scope="module")
def box(cache):
    """A body of mass matrix M_BOX, no forces, a floor (gap y) and a wall (gap x),
    coupled: J_0 M^-1 J_1^T != 0."""
    return contact_system([x, y], sp.Matrix(M_BOX.tolist()), [0, 0], [y, x], impact=0.8,
                          cache_dir=cache)


def test_a_contact_hit_measurably_later_is_not_an_impact_at_the_same_instant(box):
    """The floor is hit at t = 0.5 with the wall 5e-7 away, approached at 1e-4 (5 ms
    away): refused as "hit at the same instant" when any gap below 1e-6 counted.
    Closed form: straight lines, the floor impact (which also throws the body at the
    wall, coupled), then the wall's 4.6e-7 s later."""
    gap, r = 5e-7, 1e-4
    x0 = np.array([gap + 0.5 * r, 1.0, -r, -2.0])
    q1, v1 = x0[:2] + 0.5 * x0[2:], _impact(x0[2:], np.array([0.0, 1.0]))
    t2 = 0.5 + q1[0] / -v1[0]
    q2, v2 = q1 + (t2 - 0.5) * v1, _impact(v1, np.array([1.0, 0.0]))
    assert v2[0] > 0 and v2[1] > 0  # both flown off: no more impact
    traj = box.simulate(x0, 0.6)
    assert [g.events for g in traj.groups] == [(0,), (1,)]
    assert_allclose([g.time for g in traj.groups], [0.5, t2], rtol=1e-12)
    assert_allclose(traj.x_final, [*(q2 + (0.6 - t2) * v2), *v2], rtol=1e-9, atol=1e-12)


def test_the_compiled_model_says_its_stops_are_in_python_for_the_reset_guard(box):
    """The impacts' reset is compiled, the guard that checks each is Python: the compiled
    model's description says the guard, not only a reset of the wrong signature."""
    box.simulate(np.array([1.0, 1.0, -1.0, -2.0]), 0.1)
    words = box.calls.compiled.describe()
    assert "stops: in Python" in words and "reset_guard" in words, words


@pytest.mark.parametrize("gap", [0.0, 1e-8])
def test_coupled_impacts_at_the_same_instant_are_still_refused(box, gap):
    """Hit together (gap 0), or the wall within IMPACT_SIMULTANEITY_TOL = 1e-7 s of the
    floor at its closing speed 1 (1e-8 s): the impacts do not commute."""
    x0 = np.array([gap + 0.5, 1.0, -1.0, -2.0])
    with pytest.raises(ValueError, match=r"contacts 0 \(phi = y\) and 1 \(phi = x\) are "
                                         r"hit at the same instant and are coupled"):
        box.simulate(x0, 0.6, simultaneity_tol=1e-9)


# --- parameter values the model cannot take ---------------------------------------------
def test_the_restitution_is_checked_wherever_its_value_becomes_known(tmp_path, param_ball):
    with pytest.raises(ValueError, match=r"the restitution e must be in \[0, 1\], got 3.0 "
                                         r"\(the parameter a = 3.0\)"):
        param_ball.with_params(a=3.0)
    with pytest.raises(ValueError, match=r"the restitution e must be in \[0, 1\], got -1.0 "
                                         r"\(the parameter a = -1.0\)"):
        ball(tmp_path, impact=a, params={a: -1.0})
    with pytest.raises(ValueError, match=r"got 2.25 \(a\*\*2 at a = 1.5\)"):
        ball(tmp_path, impact=a**2, params={a: 1.5})
    assert not generated(tmp_path)  # refused before the derivation
    elastic = ModelFunctions(param_ball.with_params(a=1.0))
    assert_allclose(elastic.reset([0.3, 0.0, 2.0, -1.0], 0, 0), [0.3, 0.0, 2.0, 1.0],
                    rtol=1e-15)


def test_the_mass_matrix_is_checked_positive_definite(tmp_path, cache, param_ball):
    q1, q2 = sp.symbols("q1 q2")
    with pytest.raises(ValueError, match=r"mass_matrix must be positive definite, and it "
                                         r"is not: \[\[1.0, 0.0\], \[0.0, -1.0\]\], "
                                         r"eigenvalues \[-1.0, 1.0\]"):
        ball(tmp_path, mass_matrix=sp.diag(1, -1))
    assert not generated(tmp_path)
    with pytest.raises(ValueError, match=r"positive definite, and it is not at b = 0.0"):
        param_ball.with_params(b=0.0)
    # M depends on q: checked at each evaluation. q1'' = 0 (no force), q2'' = 0 / q1:
    # M = diag(1, q1) is singular at q1 = 0, reached at t = 0.5 from q1 = 1 at speed -2
    pole = contact_system([q1, q2], sp.diag(1, q1), [0, 0], [q2 + 10], cache_dir=cache)
    f = ModelFunctions(pole)
    assert_allclose(f.field([2.0, 0.0, -2.0, 0.0], 0), [-2.0, 0.0, 0.0, 0.0], atol=1e-15)
    not_definite = r"the mass matrix M\(q\) is not positive definite at this state"
    with pytest.raises(ValueError, match=r"field\(x, mask\) raised ValueError: " + not_definite):
        f.field([-1.0, 0.0, 0.0, 0.0], 0)
    with pytest.raises(ValueError, match=not_definite + r".*at x = \["):
        pole.simulate(np.array([1.0, 0.0, -2.0, 0.0]), 1.0)


# --- messages ----------------------------------------------------------------------------
def test_a_stance_law_that_returns_no_expression_is_named(tmp_path):
    for law, got in [(lambda pen, rate: None, "NoneType None"),
                     (lambda pen, rate: sp.Matrix([pen, rate]), "MutableDenseMatrix"),
                     (lambda pen, rate: "k * pen", "str 'k \\* pen'")]:
        with pytest.raises(TypeError, match=r"the stance law of contact 0 \(.*<lambda>\) must "
                                            r"return one sympy expression \(the normal "
                                            r"force.*got " + got):
            ball(tmp_path, stance=law)


def test_expressions_refused_at_the_build_are_named(tmp_path):
    def refused(match, **change):
        arguments = dict(state=[x, y], flags=[s0, s1], field=[1 + s0, 1 + s1],
                         events=[x, y], cache_dir=tmp_path)
        with pytest.raises(ValueError, match=match):
            from_sympy(**{**arguments, **change})

    # its 401 digits shown to 4 (the message printed them all: 507 characters)
    refused(r"^field\[0\] = 1\.0e\+400\*x \+ 1\.0 does not compile: the coefficient "
            r"1.00E\+400 overflows a double", field=[1 + sp.Integer(10)**400 * x, 1])
    refused(r"^field\[0\] = [^\n]{190,196} \.\.\. does not compile: the coefficient",
            field=[sum(x**i for i in range(80)) + sp.Integer(10)**400 * x, 1])
    # inside a function too (sympy's N leaves sin(10**400*x) as it is), and beyond the
    # 4300 digits Python's str(int) takes (the cache key's text raised its ValueError)
    refused(r"^field\[0\] = sin\(1\.0e\+400\*x\) \+ 1\.0 does not compile",
            field=[sp.sin(sp.Integer(10)**400 * x) + 1, 1])
    refused(r"^field\[0\] = 1\.0e\+5000\*x \+ 1\.0 does not compile: the coefficient "
            r"1.00E\+5000 overflows a double", field=[1 + sp.Integer(10)**5000 * x, 1])
    refused(r"field\[0\] = Piecewise\(\(x \+ 1, x > 0\)\) has a Piecewise without an "
            r"otherwise branch", field=[sp.Piecewise((1 + x, x > 0)), 1])
    refused(r"resets\[0\]\[1\] = Piecewise.* without an otherwise branch",
            resets={0: [x, sp.Piecewise((y, y > 1))]})
    refused(r"field\[0\] = x \+ 1 contains x, which are neither.*; x \(real=True\) is not "
            r"the x of the model \(no assumptions\)", field=[1 + sp.Symbol("x", real=True), 1])
    with pytest.raises(ValueError, match=r"forces\[0\] = Piecewise.* without an otherwise"):
        ball(tmp_path, forces=[sp.Piecewise((-1, x > 0)), -G])
    # a review: these were accepted, and wrong or failing at the first run
    positive = sp.Symbol("xp", positive=True)  # sqrt(xp**2) is xp: wrong at xp = -2
    refused(r"state\[0\] = xp is declared positive=True: sympy has simplified the "
            r"expressions with that .* a state coordinate takes any real value: make it with "
            r"real=True", state=[positive, y], field=[sp.sqrt(positive**2), 1],
            events=[positive, y])
    refused(r"field must be a sequence of one per state symbol, d = 4 sympy expressions, got "
            r"a 2 x 2 Matrix", state=[x, y, a, b], field=sp.Matrix([[y, x], [b, a]]))
    refused(r"field\[1\] = zoo holds a non-finite constant", field=[1, 1 / sp.Integer(0)])
    k = sp.Symbol("k", positive=True)
    refused(r"params\[k\] = -2.0, but k is declared positive=True", field=[k, 1],
            params={k: -2.0})
    refused(r"DiracDelta\(x\) does not compile: .* a switch in the state is an event",
            field=[1 - sp.sign(x), 1])
    # a gap that the coordinates do not move failed at the run ("x0 lies on the surface",
    # or a division by zero in the impact's reset)
    with pytest.raises(ValueError, match=r"contacts\[0\] = a does not depend on the "
                                         r"coordinates q"):
        ball(tmp_path, contacts=[a], params={a: 1.0})
    assert not generated(tmp_path)


def test_a_parameter_value_that_breaks_its_symbols_assumption_is_refused(cache):
    """``k`` made positive: sympy simplified ``sqrt(k**2)`` to ``k`` as the field was
    written, so ``with_params(k=-2)`` gave the field of k = 2 (a review)."""
    k = sp.Symbol("k", positive=True)
    m = from_sympy([x, y], [s0], [y, -sp.sqrt(k**2) * x], [x - 5], params={k: 2.0},
                   cache_dir=cache)
    with pytest.raises(ValueError, match=r"params\[k\] = -2.0, but k is declared "
                                         r"positive=True"):
        m.with_params(k=-2.0)
    assert_allclose(ModelFunctions(m.with_params(k=3.0)).field([1.0, 0.0], 0), [0.0, -3.0])


def test_exact_sympy_numbers_and_0d_arrays_are_parameter_values(cache):
    m = from_sympy([x, y], [s0, s1], [1 + a, b], [x, y],
                   params={a: sp.pi, b: np.array(0.25)}, cache_dir=cache)
    assert m.param_values == {"a": np.pi, "b": 0.25}
    values = ball(cache, mass_matrix=sp.diag(b, 1), impact=a,  # param_ball's equations
                  params={a: sp.sqrt(2) / 2, b: np.array(2.0)}).param_values
    assert (values["a"], values["b"]) == (np.sqrt(2) / 2, 2.0)


def test_model_functions_check_mask_and_k_and_say_what_the_kernel_raised(cache):
    m = from_sympy([x, y], [s0], [1 / x, 1], [y], resets={0: [x, -y]}, cache_dir=cache)
    f = ModelFunctions(m)
    assert_allclose(f.field([0.5, 1.0], 1), [2.0, 1.0])
    for mask, error in [(99, ValueError), (2, ValueError), (-1, ValueError),
                        (2**70, ValueError), (1.0, TypeError), (True, TypeError)]:
        with pytest.raises(error, match=r"^mask must be"):
            f.field([0.5, 1.0], mask)
    with pytest.raises(ValueError,
                       match=r"k must be an integer in \[0, 1\) \(an event\), got 1"):
        f.reset([0.5, 1.0], 0, 1)
    with pytest.raises(TypeError, match="k must be an integer"):
        f.reset([0.5, 1.0], 0, 0.0)
    with pytest.raises(ValueError, match=r"^field\(x, mask\) raised ZeroDivisionError: "
                                         r"division by zero; in region mask 0b1 \(bit k set "
                                         r"= event k happened\) at x = \[0.0, 1.0\]$") as info:
        f.field([0.0, 1.0], 1)
    assert isinstance(info.value.__cause__, ZeroDivisionError)


def test_with_params_takes_exact_sympy_numbers_and_0d_arrays(cache):
    """The values from_sympy takes are those with_params takes (sympy.pi was refused
    there as "must be a real number")."""
    model = from_sympy([x, y], [s0, s1], [1 + a, b], [x, y], params={a: 1.0, b: 2.0},
                       cache_dir=cache)
    for value in (sp.pi, sp.sqrt(2), np.array(0.5)):
        assert model.with_params(a=value).param_values["a"] == float(value)
    for value in (np.array(np.inf), sp.oo, -sp.oo):  # as np.inf is
        with pytest.raises(ValueError, match="must be finite"):
            model.with_params(a=value)
    for value in (sp.I, sp.nan, np.array([0.5])):
        with pytest.raises(TypeError, match="must be a real number"):
            model.with_params(a=value)
