"""Refusals of one query are data (``_errors``): every caller that hands rows on (chunks,
flow-map groups, rows repeated per direction) names the caller's own row."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from bderiv import BDerivative, FlowBDerivative, StructuredCorners
from bderiv._support._errors import ChainStop, QueryError, refusal


@pytest.fixture(scope="module")
def weak():
    """Structured corners whose region 0b011 has rate -0.2 for event 2; the query ``BAD``
    visits it, ``GOOD`` does not (the model of test_corners' per-query check)."""
    Dh = np.eye(3)
    A = np.zeros((3, 3))
    A[0, 2], A[1, 2], A[2, 2] = -0.7, -0.6, 1.0
    return BDerivative(Dh, StructuredCorners(np.ones(3), A, [[0, 1]], [[0.0, 0.0, 0.1]]))


BAD = np.array([-1.0, -2.0, -10.0])
GOOD = np.array([-5.0, -1.0, -2.0])


def _batch(shape, bad):
    V = np.tile(GOOD, shape + (1,))
    V[bad] = BAD
    return V


def test_a_refusal_pickles_and_renders_from_its_fields():
    e = refusal(ChainStop("rate", 3, 2, "0b011", -0.2), "W", offset=10, inverse=True)
    assert (e.row, e.name) == (13, "W")
    assert str(e).startswith("transversality violated on the chain of W[13] (inverse map): "
                             "event 2 has rate -0.2 <= 0 in region mask 0b011")
    back = pickle.loads(pickle.dumps(e))
    assert type(back) is QueryError and str(back) == str(e) and back.args == e.args
    assert str(e.at(shape=(4, 5))).startswith("transversality violated on the chain of "
                                              "W[2, 3] (inverse map)")
    with pytest.raises(ValueError, match="unknown kind of chain stop 'nan'"):
        refusal(ChainStop("nan", 0, 0, "", 0.0))


def test_chunks_name_the_row_of_the_whole_batch(weak):
    V = _batch((7,), 5)
    for kwargs in ({}, {"chunk_size": 2}, {"chunk_size": 3}):
        with pytest.raises(ValueError, match=r"on the chain of V\[5\]: event 2 has rate -0.2"):
            weak(V, **kwargs)


def test_flow_map_groups_name_the_callers_row(weak):
    fb = FlowBDerivative([np.eye(3), 2.0 * np.eye(3)], [weak])
    V = _batch((7,), 4)
    for kwargs in ({}, {"chunk_size": 3}):
        with pytest.raises(ValueError, match=r"^in event group 0 of the flow map, for the "
                                             r"vectors entering it: transversality violated "
                                             r"on the chain of V\[4\]: event 2"):
            fb(V, **kwargs)
    with pytest.raises(ValueError, match=r"^in event group 0 .* on the chain of W\[4\] "
                                         r"\(inverse map\)"):
        fb.inverse(2.0 * _batch((7,), 4), chunk_size=2)
    with pytest.raises(ValueError, match=r"^in event group 0 .* on the chain of V\[1, 0\]"):
        fb(_batch((2, 3), (1, 0)))
    with pytest.raises(ValueError, match=r"^in event group 0 .* on the chain of V\[6\]"):
        fb.jvp(_batch((7,), 6), np.ones((7, 3)), chunk_size=4)


def test_piece_matrices_name_the_callers_row(weak):
    """piece_matrices runs each row d times (one per direction): the refusal names the
    caller's vector, not the repeated row."""
    with pytest.raises(ValueError, match=r"on the chain of V\[1, 2\]: event 2 has rate"):
        weak.piece_matrices(_batch((2, 3), (1, 2)))
    with pytest.raises(ValueError, match=r"on the chain of V\[3\]: event 2 has rate"):
        weak.piece_matrices(_batch((5,), 3))


def test_event_times_name_the_full_index():
    """Rates ~2**-1000: the times of a vector ~1e100 are beyond float64 (refused), those
    of a vector ~1 are not."""
    F = np.ldexp(np.array([[1.0, 1.0], [2.0, 1.0], [1.0, 2.0], [2.0, 2.0]]), -1000)
    bd = BDerivative(np.eye(2), F)
    V = np.tile([-1.0, -2.0], (2, 3, 1))
    V[1, 2] *= 1e100
    with pytest.raises(ValueError, match=r"time of event 0 for V\[1, 2\] overflows float64"):
        bd.event_times(V)
    assert np.isfinite(bd.event_times(V[0])[0]).all()
