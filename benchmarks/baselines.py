"""The per-query oracle of ``tests/reference.py`` as a benchmark baseline.

The other baselines (batched NumPy, the BLAS yardstick), the flop count, the timer and the
test systems are shared with ``bderiv bench`` and ``tools/`` in ``bderiv.engine._baselines``;
this one stays here because it runs the test suite's oracle, which is not part of the
package.

:func:`reference_apply` loops over the queries in Python. ``ref_apply`` rebuilds the whole
rate table ``G = F Dh^T`` on every call, O(2**n n d) work that belongs to construction; to
time only the evaluation we hand it the prebuilt table (``reference.rates`` answers with
it while the baseline runs). It is timed on a subset of the queries and reported per query.
"""

from __future__ import annotations

import contextlib
import os
import sys

import numpy as np

_TESTS = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "tests")
if _TESTS not in sys.path:
    sys.path.insert(0, _TESTS)

import reference  # noqa: E402  (tests/reference.py, the per-query oracle)


@contextlib.contextmanager
def _prebuilt_rates(G):
    """Let ``reference.rates`` return the prebuilt table (evaluation only, no rebuild)."""
    original = reference.rates
    reference.rates = lambda Dh, F: G
    try:
        yield
    finally:
        reference.rates = original


def reference_apply(Dh, F, G, V, inverse=False):
    """The per-query oracle on every row of V (m, d): a Python loop over the queries.

    Parameters
    ----------
    Dh : ndarray, shape (n, d)
    F : ndarray, shape (2**n, d)
    G : ndarray, shape (2**n, n)
        The event rates ``F @ Dh.T``, handed to the oracle instead of rebuilt per query.
    V : ndarray, shape (m, d)
    inverse : bool
        Apply M^-1 (``reference.ref_inverse``) instead of M.

    Returns
    -------
    ndarray, shape (m, d)
    """
    fn = reference.ref_inverse if inverse else reference.ref_apply
    out = np.empty_like(V, dtype=np.float64)
    with _prebuilt_rates(G):
        for i in range(V.shape[0]):
            out[i] = fn(Dh, F, V[i])
    return out
