"""The load average at the start and end of a benchmark session, in pytest-benchmark's
``machine_info`` (``--benchmark-json``), for ``tools/bench_table.py --record``.

At the repository's root, not in benchmarks/: two ``conftest.py`` of folders that are not
packages, both collected by ``--doctest-modules``, collide as one module name."""

from __future__ import annotations

import os

import pytest

_LOAD_AT_START = list(os.getloadavg())


@pytest.hookimpl(optionalhook=True)
def pytest_benchmark_update_machine_info(config, machine_info):
    machine_info["load"] = {"start": _LOAD_AT_START, "end": list(os.getloadavg())}
