"""The machine a timing was measured on: CPU, threads, BLAS and the environment's settings.

Timings of ``bderiv demo`` and ``bderiv bench`` carry this record, so that a number read
later says where it came from and which thread settings were in effect (the kernels run on
numba's threads; the flow map's linear stages are BLAS products, whose threads compete
with other work on a busy machine).
"""

from __future__ import annotations

import os
import platform

#: environment variables that set the threads of numba and of the BLAS libraries
THREAD_VARIABLES = ("NUMBA_NUM_THREADS", "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS",
                    "MKL_NUM_THREADS")


def machine_info() -> dict:
    """The CPU, its logical cores, numba's threads, the BLAS and the thread variables.

    Returns
    -------
    dict
        ``cpu`` (str), ``cpus`` (int), ``numba_threads`` (int), ``blas`` (str) and
        ``thread_variables`` (each of :data:`THREAD_VARIABLES` to its value, or None when
        unset).

    Examples
    --------
    >>> info = machine_info()
    >>> sorted(info)
    ['blas', 'cpu', 'cpus', 'numba_threads', 'thread_variables']
    """
    import numba

    return {
        "cpu": _cpu_name(),
        "cpus": os.cpu_count() or 1,
        "numba_threads": numba.get_num_threads(),
        "blas": _blas_name(),
        "thread_variables": {name: os.environ.get(name) for name in THREAD_VARIABLES},
    }


def describe(info: dict) -> str:
    """One line for people: ``AMD EPYC (2 CPUs), numba threads 2, BLAS ..., ...``.

    Examples
    --------
    >>> describe({"cpu": "X", "cpus": 2, "numba_threads": 2, "blas": "openblas 0.3",
    ...           "thread_variables": {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": None}})
    'X (2 CPUs), numba threads 2, BLAS openblas 0.3; OPENBLAS_NUM_THREADS=1, OMP_NUM_THREADS unset'
    """
    settings = ", ".join(f"{k}={v}" if v is not None else f"{k} unset"
                         for k, v in info["thread_variables"].items())
    return (f"{info['cpu']} ({info['cpus']} CPUs), numba threads {info['numba_threads']}, "
            f"BLAS {info['blas']}; {settings}")


def _cpu_name() -> str:
    """The CPU's model name (``/proc/cpuinfo`` on Linux, else the platform's answer)."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown CPU"


def _blas_name() -> str:
    """NumPy's BLAS as built (name and version), or ``"unknown"``."""
    import numpy as np

    try:
        blas = np.__config__.CONFIG["Build Dependencies"]["blas"]
        return f"{blas['name']} {blas.get('version', '')}".strip()
    except (AttributeError, KeyError, TypeError):  # NumPy < 1.26 has no CONFIG
        return "unknown"
