"""``python -m bderiv compile``: its checks of arguments, and what each family's process is
given (the integrator's optimisation level, the collector's threshold). The integrator's
family itself runs in every suite on an empty cache (the background process that
``tests/conftest.py`` starts, through the same ``--here`` path); the workloads of the
dense, structured and resets families are not run here (their kernels are the tests')."""

from __future__ import annotations

import gc
import subprocess

import pytest

from bderiv.cli import main, warmup
from bderiv.models import readiness


def test_a_family_process_makes_full_collections_rarer(monkeypatch):
    """``bderiv compile FAMILY --here`` (the process of one family) compiles its families
    with full collections rarer (CPython's generational collector: skipped where the third
    threshold is ignored)."""
    compiled = []
    monkeypatch.setattr(warmup, "compile_family", compiled.append)
    before = gc.get_threshold()
    try:
        gc.set_threshold(700, 10, 10)  # CPython's default
        if gc.get_threshold()[2] != 10:
            pytest.skip("this Python's collector has no threshold of full collections")
        assert main(["compile", "dense", "resets", "--here"]) == 0
        assert gc.get_threshold() == (700, 10, warmup.FULL_COLLECTIONS)
    finally:
        gc.set_threshold(*before)
    assert compiled == ["dense", "resets"]


def test_only_the_integrators_process_runs_at_its_optimisation_level(monkeypatch):
    monkeypatch.delenv("NUMBA_OPT", raising=False)
    seen = {}

    class Popen:  # records what the family's process would get, starts nothing
        def __init__(self, command, env, **kwargs):
            seen[command[4]] = env.get("NUMBA_OPT")
            kwargs["stderr"].close()
            kwargs["stdout"].close()

    monkeypatch.setattr(subprocess, "Popen", Popen)
    for name in warmup.FAMILIES:
        warmup._start(name)
    assert seen == {"integrator": readiness.COMPILE_OPT, "dense": None, "structured": None,
                    "resets": None}


def test_bad_families_and_process_counts_are_refused_by_name(capsys):
    with pytest.raises(ValueError, match="families must be among integrator, dense, "
                                         "structured, resets, got 'lanes'"):
        warmup.warm_up(["lanes"])
    with pytest.raises(ValueError, match="families must be among .*, got 'lanes'"):
        warmup.warm_up("lanes")  # one name: a family, not its letters
    with pytest.raises(ValueError, match="processes must be an integer >= 1, got 0"):
        warmup.warm_up(["dense"], processes=0)
    with pytest.raises(ValueError, match="family must be one of"):
        warmup.compile_family("lanes")
    assert main(["compile", "lanes"]) == 2
    err = capsys.readouterr().err
    assert "unknown family 'lanes': the families are integrator, dense, structured, " \
        "resets" in err
    # the internal flags: --here without a family did nothing, --nice alone compiled all
    for argv in (["compile", "--here"], ["compile", "--nice"], ["compile", "dense", "--nice"]):
        assert main(argv) == 2
        assert "--here takes the families to compile" in capsys.readouterr().err


def _stand_in(said):
    """``warmup._start`` replaced: a process that prints what a family's process says
    (``said[name]``, nothing where absent) and compiles nothing."""
    import sys
    import tempfile

    def start(name):
        proc = subprocess.Popen([sys.executable, "-c", f"print({said.get(name, '')!r})"],
                                stdout=(out := tempfile.TemporaryFile()),
                                stderr=(log := tempfile.TemporaryFile()))
        proc.out, proc.log = out, log
        return proc
    return start


def test_a_family_named_twice_is_compiled_once_and_one_that_waited_says_so(monkeypatch):
    """A family given twice starts one process (it started two, counted "1 of 2" twice
    and left one unchecked: a review); an integrator compiled by another process meanwhile
    is said to have been waited for, not compiled (a review)."""
    started, lines = [], []
    start = _stand_in({"integrator": "integrator: compiled by another process, waited for"})
    monkeypatch.setattr(warmup, "_start", lambda name: started.append(name) or start(name))
    monkeypatch.setattr(warmup, "_held_elsewhere", lambda: False)  # (a real one may run)
    seconds = warmup.warm_up(["resets", "integrator", "resets"], processes=2,
                             progress=lines.append)
    assert started == ["resets", "integrator"] and list(seconds) == ["resets", "integrator"]
    assert lines[:2] == ["compiling resets (1 of 2)", "compiling integrator (2 of 2)"]
    done = sorted(line.split(" in ")[0] for line in lines[2:])
    assert done == ["integrator compiled by another process, waited for", "resets compiled"]


def test_a_family_that_compiled_nothing_says_so(monkeypatch, capsys, tmp_path):
    """A family whose kernels all came from the disk cache said "compiled in 1.8 s" (a
    review); its process now says that it found them there. One that compiles a kernel
    of a disk cache says nothing more."""
    (tmp_path / "probe_kernel.py").write_text(
        "import numba\n@numba.njit(cache=True)\ndef twice(x):\n    return 2 * x\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    import probe_kernel

    monkeypatch.setattr(warmup, "compile_family", lambda name: probe_kernel.twice(1.5) and None)
    warmup.compile_here(["dense"])  # compiles twice(float64): a cached dispatcher
    assert capsys.readouterr().out == ""
    warmup.compile_here(["dense"])  # nothing left to compile
    assert capsys.readouterr().out == "dense: in the cache already\n"


def test_a_wait_for_another_compilation_is_said_as_it_starts(monkeypatch):
    """While another process compiles the integrator, ``compile integrator`` said
    "compiling integrator" and then waited silently for it (a review)."""
    lines = []
    monkeypatch.setattr(warmup, "_start", _stand_in(
        {"integrator": "integrator: compiled by another process, waited for"}))
    monkeypatch.setattr(warmup, "_held_elsewhere", lambda: True)
    warmup.warm_up(["integrator"], progress=lines.append)
    assert lines[0] == "waiting for another process that compiles integrator (1 of 1)"
    assert lines[1].startswith("integrator compiled by another process, waited for in ")


def test_the_integrators_family_says_where_it_compiled_nothing(monkeypatch):
    import contextlib

    monkeypatch.setattr(readiness, "compile_lock", lambda wait: contextlib.nullcontext())
    monkeypatch.setattr(readiness, "integrator_cached", lambda: True)
    monkeypatch.setattr(readiness, "held_elsewhere", lambda: True)
    assert warmup.compile_family("integrator") == "compiled by another process, waited for"
    monkeypatch.setattr(readiness, "held_elsewhere", lambda: False)
    assert warmup.compile_family("integrator") == "in the cache already"


def test_ctrl_c_ends_a_command_with_a_line_and_the_shells_status(monkeypatch, capsys):
    from bderiv.cli import parser

    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setitem(parser._COMMANDS, "compile", interrupted)
    assert main(["compile"]) == 130
    assert capsys.readouterr().err.strip() == "bderiv compile: interrupted"
