"""``tools/fuzz.py`` (issue 27, item 10): a short seeded run finds no wrong answer on any
family, and the tool does find the wrong answers of a broken build (its checks are not
vacuous). The oracle of the tool is ``tests/reference.py`` and the invariants of the map
(see the tool's docstring)."""

from __future__ import annotations

import importlib.util
import pathlib

import numpy as np
import pytest

TOOL = pathlib.Path(__file__).resolve().parents[1] / "tools" / "fuzz.py"


@pytest.fixture(scope="module")
def fuzz():
    spec = importlib.util.spec_from_file_location("bderiv_fuzz_tool", TOOL)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_short_run_has_no_wrong_answer(fuzz, capsys):
    assert fuzz.main(["--evaluations", "1500", "--rows", "8", "--seed", "27"]) == 0
    report = capsys.readouterr().out
    print(report)
    lines = report.splitlines()
    top = next(i for i, line in enumerate(lines) if line.startswith("family"))
    end = next(i for i, line in enumerate(lines) if line.startswith("total:"))
    rows = {line.split()[0]: line.split() for line in lines[top + 1 : end]}
    # every family ran ("fast-boundary" reports as "own-rates" and "additive")
    assert len(rows) >= len(fuzz.ALL), report
    evaluated = [name for name, cols in rows.items() if int(cols[2]) > 0]
    assert len(evaluated) >= len(rows) - 1, report  # "huge" may be all refused
    assert all(int(cols[3]) == 0 for cols in rows.values()), report
    assert lines[end].endswith(" 0 wrong"), report


def test_the_tool_finds_the_wrong_answers_of_unscaled_results(fuzz, monkeypatch):
    """With the results of the model and reset engines left scaled (the unscaling pass
    disabled), homogeneity and the oracle both fail, and are counted per family."""
    from bderiv._kernels import scaling

    monkeypatch.setattr(scaling, "unscale_rows", lambda out, exps, shift: 0)
    tally = fuzz.Tally()
    rng = np.random.default_rng(5)
    for _ in range(2):
        fuzz.check(fuzz.fam_resets(rng, 12), tally, rng)
        fuzz.check(fuzz.ALL["structured"](rng, 12), tally, rng)
    assert tally.wrong["resets"] > 0 and tally.wrong["structured"] > 0, tally.report()
    assert "off the oracle" in tally.report()


def test_refusal_kinds_are_named(fuzz):
    assert fuzz.kind_of("the time of event 1 for V[3] underflows float64 (about 2**-1100",
                        fuzz.QUERY_KINDS) == "time beyond float64"
    assert fuzz.kind_of("the result for V[0] overflowed (not finite)",
                        fuzz.QUERY_KINDS) == "overflow"
    assert fuzz.kind_of("something else", fuzz.QUERY_KINDS).startswith("unclear")
    # a refusal is justified by the oracle's answer being beyond the normal floats
    assert fuzz.beyond(np.array([[1.0, 2.0**-1000]]), -30)[0]
    assert not fuzz.beyond(np.array([[1.0, 2.0**-1000]]), 20)[0]
    assert fuzz.beyond(np.array([[2.0**1000]]), 30)[0]
