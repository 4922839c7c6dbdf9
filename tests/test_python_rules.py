"""The stop rules' Python twins (``bderiv.models.events._python_rules``) against the
compiled rules: the same bits on the same arrays, rule by rule (the two integrators decide
their stops by them), and the choice between the two."""

from __future__ import annotations

import numpy as np
import pytest

from bderiv.models.compiled import rules as compiled
from bderiv.models.events import _python_rules
from bderiv.models.events._python_rules import TWIN


def _same(a, b) -> bool:
    """Equal values, bit for bit (arrays: dtype and every entry; NaN only as NaN)."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a), np.asarray(b)
        return a.shape == b.shape and a.tobytes() == b.tobytes()
    if a is None or b is None:
        return a is None and b is None
    return np.float64(a).tobytes() == np.float64(b).tobytes()  # numbers and flags


def _draws(rng, n, d):
    """Arguments of each rule: random values, exact zeros and ties mixed in (the branches
    that compare), by rule name."""
    h = rng.standard_normal(n) * rng.choice([1e-9, 1e-3, 1.0], n)
    h[rng.random(n) < 0.2] = 0.0
    rate = rng.standard_normal(n)
    rate[rng.random(n) < 0.2] = 0.0
    window = np.abs(rng.standard_normal(n)) * 1e-3
    fired = rng.random(n) < 0.4
    J = rng.standard_normal((n, d))
    F = rng.standard_normal(d)
    F1 = F + rng.choice([0.0, 1e-14, 1e-3]) * rng.standard_normal(d)
    Jd = rng.standard_normal((d, d))
    mask, skip, kept = (int(rng.integers(0, 2**n)) for _ in range(3))
    m = int(rng.integers(2, 12))
    samples = rng.standard_normal((2 * m + 1, n)) * 1e-3
    samples[0] = np.abs(samples[0])  # across at the start: start_dip_steps's case
    samples[rng.random(samples.shape) < 0.1] = 0.0
    tol = np.abs(rng.standard_normal(n)) * 1e-4
    ends = np.sort(rng.uniform(0.0, 1.0, m))
    sign = rng.choice([-1.0, 1.0], n)
    return {
        "state_error": (1e-12, 1e-10, np.abs(F), np.abs(F1) * 1e-11, np.empty(d)),
        "local_rates": (sign, J, F, np.empty((n, d)), np.empty(n)),
        "tolerances": (J, np.abs(F) * 1e-9, np.empty(n)),
        "windows": (J, rate, np.abs(F) * 1e-9, fired, np.empty(n)),
        "classify": (h, rate, window, fired, 1e-6, np.empty(n, dtype=np.int64)),
        "clearly_positive": (J[0], F),
        "same_flow": (F, F1, Jd, Jd + (F1 - F)[:, None]),
        "_close": (F, F1),
        "first_grazing": (fired, J, F),
        "wrong_side": (h, mask, window),
        "reads_across": (h, mask, window, skip),
        "carried_across": (h, mask, window, skip, J, F),
        "first_sent_back": (fired, h, window, kept, J, F),
        "return_sample": (samples, tol),
        "start_dip_steps": (samples,),
        "sample_times": (ends, np.empty(2 * m - 1)),
        "linspace": (float(ends[0]), float(ends[-1]), np.empty(m)),
        "peak_rows": (samples, tol, bool(rng.random() < 0.5), 0.5),
    }


def test_every_rule_has_a_case_here():
    names = {name for name in dir(compiled) if hasattr(getattr(compiled, name), "py_func")}
    assert names == set(_draws(np.random.default_rng(0), 3, 4))


@pytest.mark.parametrize("seed", range(40))
def test_each_twin_gives_the_compiled_rules_bits(seed):
    rng = np.random.default_rng(seed)
    n, d = int(rng.integers(1, 7)), int(rng.integers(1, 9))
    for name, args in _draws(rng, n, d).items():
        twin_args = [a.copy() if isinstance(a, np.ndarray) else a for a in args]
        got = getattr(TWIN, name)(*twin_args)
        want = getattr(compiled, name)(*args)
        assert _same(want, got), (name, want, got)
        for a, b in zip(args, twin_args, strict=True):  # what they wrote into ``out``
            if isinstance(a, np.ndarray):
                assert _same(a, b), (name, a, b)


def test_a_rule_runs_compiled_where_the_machine_has_it_else_as_python(monkeypatch):
    chosen = _python_rules._Rules()
    monkeypatch.setattr(_python_rules, "machine_has", lambda dispatcher: False)
    assert chosen.windows.__wrapped__ is TWIN.windows  # (its warnings off)
    assert chosen.GROUP == compiled.GROUP  # constants as they are
    monkeypatch.setattr(_python_rules, "machine_has", lambda dispatcher: True)
    assert chosen.windows.__wrapped__ is TWIN.windows  # looked again after POLL_SECONDS
    monkeypatch.setattr(_python_rules, "POLL_SECONDS", 0.0)
    assert chosen.windows is compiled.windows
    monkeypatch.setattr(_python_rules, "machine_has", lambda dispatcher: False)
    assert chosen.windows is compiled.windows  # compiled once found: kept


@pytest.mark.parametrize("on_machine", [False, True], ids=["twins", "compiled"])
def test_a_python_model_of_seventy_events_crosses_them_all_either_way(on_machine,
                                                                      monkeypatch):
    """Compiled, a mask is an int64: bit k >= 64 read bit k - 64, and a model of 70 events
    was refused ("event 64 is on the wrong side ... an internal error") once the machine
    had the compiled rules, not before (a review). The rules that read masks go to their
    twins for such a model."""
    from bderiv import HybridSystem

    monkeypatch.setattr(_python_rules, "machine_has", lambda dispatcher: on_machine)
    monkeypatch.setattr(_python_rules, "rules", _python_rules._Rules())
    for module in ("crossings", "excursions", "locate", "peaks", "sides", "stopcalls"):
        monkeypatch.setattr(f"bderiv.models.events.{module}.rules", _python_rules.rules)
    n = 70
    levels = 0.5 * np.arange(1, n + 1)
    model = HybridSystem(lambda x, mask: np.array([1.0]), lambda x: x[0] - levels,
                         n_events=n, dim=1, event_jacobian=lambda x: np.ones((n, 1)),
                         field_jacobian=lambda x, mask: np.zeros((1, 1)))
    run = model.simulate(np.array([0.0]), 2.0)  # events 0, 1 and 2 cross (at 0.5, 1, 1.5)
    assert run.x_final == pytest.approx([2.0])
    assert run.mask_final == 0b111


def test_the_twins_are_as_quiet_as_the_compiled_rules(monkeypatch):
    """An overflow to inf in a twin's NumPy scalars warned, where the compiled rule is
    silent: under warnings as errors (this suite's setting) the twin raised (a review)."""
    monkeypatch.setattr(_python_rules, "machine_has", lambda dispatcher: False)
    chosen = _python_rules._Rules()
    dh, F = np.array([1e160, 0.0]), np.array([1.0, 1.0])
    assert chosen.clearly_positive(dh, F) == compiled.clearly_positive(dh, F)
