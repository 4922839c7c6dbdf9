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
    assert chosen.windows is TWIN.windows
    assert chosen.GROUP == compiled.GROUP  # constants as they are
    monkeypatch.setattr(_python_rules, "machine_has", lambda dispatcher: True)
    assert chosen.windows is TWIN.windows  # looked again only after POLL_SECONDS
    monkeypatch.setattr(_python_rules, "POLL_SECONDS", 0.0)
    assert chosen.windows is compiled.windows
    monkeypatch.setattr(_python_rules, "machine_has", lambda dispatcher: False)
    assert chosen.windows is compiled.windows  # compiled once found: kept
