"""The ``models`` families of ``tools/fuzz.py`` (``tools/fuzz_models.py``, compared by
``tools/fuzz_twins.py``): seeded random
hybrid models written once as plain functions, run as Python functions on scipy's
``solve_ivp`` and as ``numba.njit`` of the same functions on the compiled integrator (with
the compiled run of the stops, and with the Python loop deciding them), must give the same
answer or the same refusal. The oracle of each arm is the other arms: the compiled run and
the Python loop on the same compiled stretches to the bit; scipy's DOP853 and the compiled
one within the integration accuracy (``fuzz_twins.STATE_RTOL``, ``FLOW_RTOL``); every
sample of each arm's run on its mask's side of every surface.
"""

from __future__ import annotations

import importlib.util
import pathlib
import sys

import numpy as np
import pytest

TOOLS = pathlib.Path(__file__).resolve().parents[1] / "tools"


@pytest.fixture(scope="module")
def fuzz():
    spec = importlib.util.spec_from_file_location("bderiv_fuzz_tool", TOOLS / "fuzz.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)  # puts tools/ on sys.path: fuzz_models imports
    return module


@pytest.fixture(scope="module")
def fm(fuzz):
    return sys.modules["fuzz_models"]


@pytest.fixture(scope="module")
def twins(fuzz):
    return sys.modules["fuzz_twins"]


#: per family, seeds of models (``fuzz_models.draw`` from ``default_rng(seed)``)
SEEDS = {family: list(range(4)) for family in ("models-plain", "models-sim", "models-near",
                                         "models-graze", "models-resets", "models-final")}
#: seeds of the disagreements the first long run found (fixed since; kept as regression
#: cases): a group with a bounce whose landing was decided in the region with every bit
#: flipped (crossings.landing, both paths: rules.first_sent_back), and a return across a
#: surface within the first step after a stop, lost (excursions._start_dip); a trajectory
#: spiralling into the intersection of two surfaces in finite time, followed past it with
#: a crossing lost (crossings that accumulate: zeno.ImpactWatch); an exact tangency that
#: one integrator locates as a crossing sent back, the other screens as a grazing peak
#: (both refuse: fuzz_twins._graze_seen_apart); a group's member leaving at a small rate
#: and back across within the first step, its dip shallower than its tolerance, lost
#: (excursions._start_dip)
FOUND = {"models-resets": [3397828890274385335, 2092657018377387946, 2838364480737254932,
                           77373933576014767],
         "models-plain": [1091442821039362419],
         "models-sim": [1635481354732627137, 3684918118149487902],
         "models-graze": [2444480689758357945, 149951279942737962,
                          2352292564369576528]}
for _family, _seeds in FOUND.items():
    SEEDS[_family] = [*SEEDS[_family], *_seeds]


def _cases():
    for family, seeds in SEEDS.items():
        for seed in seeds:
            yield pytest.param(family, seed, id=f"{family}-{seed}")


@pytest.mark.parametrize("family, seed", list(_cases()))
def test_the_twins_agree(fuzz, fm, twins, family, seed):
    model = fm.draw(np.random.default_rng(seed), family, 12)
    model.seed = seed
    tally = fuzz.Tally()
    twins.check_model(model, tally)
    assert tally.evaluations[family] >= 4, tally.report()
    assert tally.wrong[family] == 0, tally.report()


def test_a_wrong_twin_is_found(fuzz, fm, twins):
    """The tolerance has teeth: the compiled twin given the constant term b_0 of every
    region's field 1e-5 off (a model that is not the same) is out of it, in the states
    or the flow map."""
    model = fm.draw(np.random.default_rng(0), "models-plain", 12)
    model.seed = 0
    systems = model.systems

    def off():
        python, compiled = systems()
        p = model.p.copy()
        block = model.d * model.d + 2 * model.d  # a region's A, b, c
        p[model.d * model.d:block * 2**model.n:block] += 1e-5  # params start at x[d]
        other = fm.Model(model.family, model.n, model.d, p, model.x0, model.t_final,
                         False, model.gaps, model.window_time, np.random.default_rng(0))
        return python, other.systems()[1]

    model.systems = off
    tally = fuzz.Tally()
    twins.check_model(model, tally)
    assert tally.wrong["models-plain"] > 0, tally.report()
    assert any("apart" in k for k in tally.disagreed["models-plain"]), tally.report()


def test_the_tool_runs_the_models_families(fuzz, capsys):
    assert fuzz.main(["--families", "models", "--evaluations", "200", "--rows", "4",
                      "--seed", "5"]) == 0
    report = capsys.readouterr().out
    for family in SEEDS:
        assert family in report, report
    assert report.rstrip().splitlines()[-1].endswith(" 0 wrong") or " 0 wrong" in report


def test_refusal_kinds(twins):
    assert twins.kind(ValueError("the resets of events [0, 1], simultaneous at t=1, do not "
                              "commute: ...")) == "do not commute"
    assert twins.kind(ValueError("events [0, 1] were grouped at t=1 by simultaneity_tol=1e-07, "
                              "but event 1 is not at that point: ...")) == "not at that point"
    assert twins.kind(RuntimeError("something new\nmore")).startswith("RuntimeError: something")
