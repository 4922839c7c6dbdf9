"""The demo's JSON is standard JSON, and the summaries of ``pronking`` and ``landing`` take
``--eps`` (a review: an error of exactly 0 made the JSON hold ``Infinity``, which
``json.loads`` of other languages refuses; ``--eps`` was refused where the summaries run a
check against finite differences).

Oracles: ratios worked out by hand from errors forced by a monkeypatch (1e-3 / 1e-4 = 10,
anything / 0: no number, null); the ratio of two steps, which a first-order error follows
(1e-5 / 1e-3 = 0.01).
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from bderiv.cli import main, render


def _strict(text):
    """``json.loads`` refusing the non-standard constants Infinity, -Infinity and NaN."""

    def refuse(name):
        raise ValueError(f"not standard JSON: {name}")

    return json.loads(text, parse_constant=refuse)


def _forced(real, max_errors, ratios=None):
    """``fd_check`` as ``real``, its max errors replaced (a check whose error is 0)."""

    def fd_check(*args, **kwargs):
        fd = real(*args, **kwargs)
        return dataclasses.replace(fd, max_errors=max_errors,
                                   ratios=fd.ratios if ratios is None else ratios)

    return fd_check


def test_to_json_writes_a_number_that_is_not_finite_as_null():
    data = {"a": [1.5, float("inf"), (np.float64(-np.inf), float("nan"))], "b": {"c": 0.0},
            "d": "Infinity", "e": None, "f": 3}
    text = render.to_json(data)
    assert _strict(text) == {"a": [1.5, None, [None, None]], "b": {"c": 0.0},
                             "d": "Infinity", "e": None, "f": 3}


def test_the_demos_json_has_null_where_a_steps_error_is_zero(capsys, monkeypatch):
    from bderiv.cli import demo

    # the third step's error exactly 0: the shrink from the second to it has no number
    monkeypatch.setattr(demo, "fd_check", _forced(demo.fd_check, (1e-3, 1e-4, 0.0)))
    argv = ["demo", "--batch", "500", "--check", "1", "--no-progress"]
    assert main([*argv, "--json"]) == 0
    text = capsys.readouterr().out
    res = _strict(text)  # Infinity was written here
    ratios = res["check"]["error_ratios"]
    assert ratios[0] == pytest.approx(10.0, rel=1e-12) and ratios[1] is None, ratios
    json.dumps(res, allow_nan=False)
    assert main(argv) == 0  # the text says so too
    assert "error shrinks with eps by 10.0x, - (to 0) per step" in capsys.readouterr().out


def test_the_landing_summary_has_null_for_a_ratio_to_zero(capsys, monkeypatch):
    from bderiv.analysis import checks

    # errors 1e-3, 0, 0: ratios (smaller / larger step's) 0 / 1e-3 = 0, and 0 / 0: none
    monkeypatch.setattr(checks, "fd_check", _forced(checks.fd_check, (1e-3, 0.0, 0.0),
                                                    (0.0, float("nan"))))
    assert main(["demo", "--example", "landing", "--json"]) == 0
    res = _strict(capsys.readouterr().out)
    assert res["fd"]["ratios"] == [0.0, None]
    assert main(["demo", "--example", "landing"]) == 0  # 1 / 0 raised ZeroDivisionError
    assert "error shrinks with eps by - (to 0), - per step" in capsys.readouterr().out


@pytest.mark.parametrize("example", ["landing", "pronking"])
def test_the_summaries_take_eps_as_their_checks_steps(capsys, example):
    assert main(["demo", "--example", example, "--eps", "1e-3", "1e-5", "--json",
                 "--no-progress"]) == 0
    fd = _strict(capsys.readouterr().out)["fd"]
    assert fd["eps"] == [1e-3, 1e-5]
    # first order: the error follows the step, 1e-5 / 1e-3 = 0.01
    (ratio,) = fd["ratios"]
    assert 0.005 < ratio < 0.02, fd
    assert main(["demo", "--example", example, "--eps", "1e-4", "1e-4"]) == 2
    assert "--eps: the steps must decrease" in capsys.readouterr().err


@pytest.mark.parametrize("example, more", [("chair", ["--batch", "1000", "--check", "1"]),
                                           ("landing", [])])
def test_the_steps_are_printed_as_given(capsys, example, more):
    """``{e:.0e}`` printed 1.5e-4 as 2e-04 and 2.5e-5 as 3e-05, steps the check did not
    take, beside a ratio that fitted the real ones (a review). (The gaits' summaries
    print them with the same ``_format.format_steps``.)"""
    assert main(["demo", "--example", example, "--eps", "1.5e-4", "2.5e-5",
                 "--no-progress", *more]) == 0
    out = capsys.readouterr().out
    assert "  eps = 1.5e-04: " in out and "  eps = 2.5e-05: " in out, out


def test_a_commands_random_batch_is_drawn_in_pieces_with_the_same_numbers(monkeypatch):
    """demo and bench draw their batch RANDOM_ROWS rows at a time, so that Ctrl-C is seen
    between the draws (one draw of 30 million rows held it for 3-4 s: a review); the
    numbers are those of one draw (the demo's output does not change)."""
    from bderiv.cli import systems

    monkeypatch.setattr(systems, "RANDOM_ROWS", 7)
    got = systems.random_vectors(np.random.default_rng(4), 50, 3)
    np.testing.assert_array_equal(got, np.random.default_rng(4).standard_normal((50, 3)))
