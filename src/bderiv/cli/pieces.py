"""The pieces a sample of tangent vectors meets: what ``bderiv demo`` reports about them.

With few events the most visited pieces say it all; with many (n = 12 has 4.8e8 pieces)
almost every vector is in a piece of its own, and what informs is how many distinct
pieces the sample met, the range of their determinants and gains, and the spread of the
event times that decides the order.
"""

from __future__ import annotations

import math

import numpy as np

from .._limits import FULL_TABLE_ENTRIES

#: the most visited pieces listed
SHOWN = 6
#: vectors whose pieces give the determinant and gain ranges (one piece matrix each)
RANGE_VECTORS = 1000
#: a list of the most visited pieces is shown when the first holds at least this share
LIST_SHARE = 0.01


def distinct_pieces(orders, limit=None):
    """Distinct rows of the per-group event orders, the most frequent first.

    Parameters
    ----------
    orders : list of ndarray, each shape (m, n_g)
        The event orders of m vectors in each group g (empty: no event group).
    limit : int, optional
        Keep at most this many.

    Returns
    -------
    list of (list of ndarray, float)
        The orders of a piece, one per group, and the share of the m vectors in it.

    Examples
    --------
    >>> import numpy as np
    >>> orders = [np.array([[1, 0], [0, 1], [1, 0], [1, 0]])]  # one group of 2 events
    >>> [(o[0].tolist(), share) for o, share in distinct_pieces(orders)]
    [([1, 0], 0.75), ([0, 1], 0.25)]
    """
    if not orders:
        return [([], 1.0)]
    sizes = [o.shape[1] for o in orders]
    key = np.concatenate(orders, axis=1)
    uniq, counts = np.unique(key, axis=0, return_counts=True)
    top = np.argsort(-counts, kind="stable")[:limit]
    return [([s.astype(np.int64) for s in np.split(uniq[i], np.cumsum(sizes)[:-1])],
             float(counts[i] / key.shape[0])) for i in top]


def piece_summary(fb, sample, full=False) -> dict:
    """The pieces of the flow map ``fb`` that the vectors ``sample`` (m, d) meet.

    Returns
    -------
    dict
        ``count`` (all pieces: the product of n_g! over the groups), ``sample`` (m),
        ``distinct`` (pieces met), ``most_visited`` (at most :data:`SHOWN` entries of
        :func:`piece_entry`; empty when the first holds less than :data:`LIST_SHARE`),
        ``ranges`` (:func:`piece_ranges`) and ``time_spread`` (per group of several events:
        the 5 %, 50 % and 95 % quantiles of ``t_last - t_first`` over the vectors).
    """
    events = fb.event_times(sample) if fb.n_groups else []
    orders = [order for _, order in events]
    met = distinct_pieces(orders)
    shown = met[:SHOWN] if met[0][1] >= LIST_SHARE else []
    return {
        "count": math.prod(math.factorial(bd.n_events) for bd in fb.jumps),
        "sample": len(sample),
        "distinct": len(met),
        "most_visited": [piece_entry(fb, o, share, full) for o, share in shown],
        "ranges": piece_ranges(fb, [o[:RANGE_VECTORS] for o in orders],
                               min(RANGE_VECTORS, len(sample))),
        "time_spread": [
            {"group": g, "quantiles": [5, 50, 95],
             "values": np.percentile(t.max(axis=1) - t.min(axis=1), [5, 50, 95]).tolist()}
            for g, (t, _) in enumerate(events) if t.shape[1] > 1
        ],
    }


def piece_entry(fb, orders, share=None, full=False) -> dict:
    """One piece: its orders, share, det and 2-norm of D's piece and of each group's M.

    ``orders``: one local event order per group (empty without groups). With ``full`` the
    matrices too: ``matrix`` (D's piece, d x d) and ``event_matrices`` (each group's).
    """
    D = fb.piece([o.tolist() for o in orders]) if orders else fb.piece()
    Ms = [bd.piece(o) for bd, o in zip(fb.jumps, orders, strict=True)]
    entry = {"orders": [o.tolist() for o in orders]}
    if share is not None:
        entry["share"] = share
    entry.update(det=float(np.linalg.det(D)), norm=float(np.linalg.norm(D, 2)),
                 event_dets=[float(np.linalg.det(M)) for M in Ms])
    if full:
        entry.update(matrix=D.tolist(), event_matrices=[M.tolist() for M in Ms])
    return entry


def piece_ranges(fb, orders, vectors: int) -> dict:
    """Ranges of det and 2-norm over the distinct pieces of the given vectors' orders.

    Returns
    -------
    dict
        ``vectors``, ``pieces`` (distinct among them) and ``det``, ``norm``,
        ``event_det`` (the product of the groups' determinants at their event points), each
        ``[min, max]``.
    """
    entries = [piece_entry(fb, o) for o, _ in distinct_pieces(orders)]

    def span(values):
        return [float(min(values)), float(max(values))]

    return {"vectors": vectors, "pieces": len(entries),
            "det": span([e["det"] for e in entries]),
            "norm": span([e["norm"] for e in entries]),
            "event_det": span([math.prod(e["event_dets"]) for e in entries])}


def group_tables(fb, full=False) -> list:
    """Per event group: with ``full`` its Dh and, when small enough, its corner table F."""
    if not full:
        return [{} for _ in fb.jumps]
    tables = []
    for bd in fb.jumps:
        dense = bd.F is not None and (1 << bd.n_events) * bd.dim <= FULL_TABLE_ENTRIES
        tables.append({"Dh": bd.Dh.tolist(), "F": bd.F.tolist() if dense else None})
    return tables
