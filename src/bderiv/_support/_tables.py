"""Bitmask-indexed corner tables (NumPy only).

Row ``mask`` of every table belongs to the region where the events whose bits are set in
``mask`` have happened (mathematics.md section 1). Tables are built block by block so that the
temporaries stay a small fraction of the tables themselves; no Python loop runs over the
individual masks.
"""

from __future__ import annotations

import functools
import os

try:
    import resource
except ImportError:  # pragma: no cover - not on Windows
    resource = None

import numpy as np

from .._limits import BLOCK_ROWS, RATE_BLOCK_ROWS, UNDERFLOW_LOG10


def blocks(n_rows: int, block: int = BLOCK_ROWS):
    """Yield ``slice`` objects covering ``range(n_rows)`` in blocks."""
    for start in range(0, n_rows, block):
        yield slice(start, min(start + block, n_rows))


def mask_bits(masks, n: int, dtype=np.float64) -> np.ndarray:
    """Bits of ``masks`` as a (len(masks), n) 0/1 matrix, column k = bit k."""
    return ((np.asarray(masks, dtype=np.int64)[:, None] >> np.arange(n)) & 1).astype(dtype)


#: the most events whose region masks an int64 holds (bit 63 is its sign)
INT64_EVENTS = 63


def mask_dtype(n_events: int):
    """The dtype of an array of region masks of ``n_events`` events: int64, or object
    (Python ints) beyond :data:`INT64_EVENTS`."""
    return np.int64 if n_events <= INT64_EVENTS else object


def block_bits(rows: slice, n: int) -> np.ndarray:
    """:func:`mask_bits` of the masks ``rows.start .. rows.stop - 1`` of a block, (rows, n)
    float 0/1. The whole table of n <= ``SHARED_BITS_N`` events is one block: its bits are
    made once and shared, read-only."""
    if rows.start == 0 and rows.stop == 1 << n and n <= SHARED_BITS_N:
        return _table_bits(n)
    return mask_bits(np.arange(rows.start, rows.stop, dtype=np.int64), n)


#: the largest n whose (2**n, n) table of mask bits is kept (:func:`block_bits`): 80 KiB
SHARED_BITS_N = 10


@functools.cache
def _table_bits(n: int) -> np.ndarray:
    bits = mask_bits(np.arange(1 << n, dtype=np.int64), n)
    bits.flags.writeable = False
    return bits


def happened_rows(masks, n: int) -> np.ndarray:
    """uint8 (len(masks), n) flags of integer masks (the regions of a corner model)."""
    return mask_bits(masks, n, np.uint8)


def tabulate(corners, n: int, d: int) -> np.ndarray:
    """The (2**n, d) table of a model's ``corners(happened)``, built block by block."""
    F = np.empty((1 << n, d))
    for rows in blocks(F.shape[0]):
        F[rows] = corners(happened_rows(np.arange(rows.start, rows.stop), n))
    return F


def chain_regions(order, n: int) -> np.ndarray:
    """uint8 flags of the regions along orders: for ``order`` of shape (..., n), flags of
    shape (..., n + 1, n) whose row j marks the events ``order[..., :j]``."""
    order = np.asarray(order, dtype=np.int64)
    flat = order.reshape(-1, n)
    hap = np.zeros((flat.shape[0], n + 1, n), dtype=np.uint8)
    rows = np.arange(flat.shape[0])
    for j in range(n):
        hap[:, j + 1] = hap[:, j]
        hap[rows, j + 1, flat[:, j]] = 1
    return hap.reshape(order.shape[:-1] + (n + 1, n))


def available_memory() -> int:
    """Bytes of physical memory currently available (a conservative estimate)."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return 8 << 30


def memory_headroom() -> int:
    """Bytes this process may still take: the memory available (:func:`available_memory`)
    and, under an address-space limit (``RLIMIT_AS``, ``ulimit -v``), what the limit leaves
    of the address space in use (``/proc/self/statm``), whichever is less."""
    room = available_memory()
    if resource is None:
        return room
    limit = resource.getrlimit(resource.RLIMIT_AS)[0]
    if limit in (resource.RLIM_INFINITY, -1):
        return room
    try:
        with open("/proc/self/statm") as fh:
            used = int(fh.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return room
    return max(min(room, limit - used), 0)


def record_layout(n: int, d: int) -> tuple[int, int, int]:
    """(nc, dc, stride) of the region records: n and d padded to ``nc``, ``dc`` blocks of 8
    float64, a record of ``stride = 8 (2 nc + dc)`` float64 (see :func:`region_records`)."""
    nc, dc = -(-n // 8), -(-d // 8)
    return nc, dc, 8 * (2 * nc + dc)


def dense_table_bytes(n: int, d: int) -> int:
    """Bytes of the region records a dense ``BDerivative`` keeps (F and G live in them)."""
    return (1 << n) * record_layout(n, d)[2] * 8


def aligned_empty(shape: tuple[int, int]) -> np.ndarray:
    """An uninitialised C-contiguous float64 array whose data starts on a 64-byte boundary
    (a cache line: with rows of a multiple of 8 entries, every 8-wide vector load of a
    kernel reads one line)."""
    size = shape[0] * shape[1]
    buf = np.empty(size + 8)
    start = (-buf.ctypes.data // 8) % 8  # float64 entries up to the next 64-byte boundary
    return buf[start : start + size].reshape(shape)


def padded(X, cols: int, fill: float = 0.0) -> np.ndarray:
    """X (rows, c) in a C-contiguous (rows, cols) float64 array, the extra columns ``fill``
    (the kernels read rows as whole vectors of a multiple of 8 entries)."""
    shape = (X.shape[0], cols)
    out = np.zeros(shape) if fill == 0 else np.full(shape, fill)  # zeros: 1/5 of full's cost
    out[:, : X.shape[1]] = X
    return out


def region_records(F, Dh: np.ndarray, f_exp: int = 0) -> np.ndarray:
    """The table of one record per region, 64-byte aligned, shape (2**n, stride).

    Row ``mask`` holds ``[-1 / G[mask] | G[mask] | F[mask]]``, each part padded with
    (-1 | 0 | 0) to a multiple of 8 entries, so that a kernel reads a region's reciprocal
    rates, rates and corner as whole 8-wide vectors from one aligned record. ``F`` (2**n, d)
    is the caller's checked table (any real dtype and layout: copied block by block, so no
    second table is held), times ``2**f_exp`` (an exact scaling); the rates
    ``G = F @ Dh.T`` are computed into the records (overflow gives inf, reported by the
    caller's checks).
    """
    n, d = Dh.shape
    nc, dc, stride = record_layout(n, d)
    rows_total = F.shape[0]
    R = aligned_empty((rows_total, stride))
    og, of = 8 * nc, 16 * nc
    DhT = Dh.T
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        for rows in blocks(rows_total, RATE_BLOCK_ROWS):
            block = R[rows]
            block[:, of : of + d] = F[rows] if not f_exp else np.ldexp(F[rows], f_exp)
            block[:, of + d :] = 0.0
            G = block[:, of : of + d] @ DhT
            block[:, og : og + n] = G
            block[:, og + n : of] = 0.0
            block[:, :n] = -1.0 / G
            block[:, n:og] = -1.0
    return R


def corner_point_bytes(n: int, d: int) -> int:
    """Bytes of the corner points U and W, each (2**n, d), built on request."""
    return 2 * (1 << n) * d * 8


def human_bytes(nbytes: float) -> str:
    """``1536 -> '1.5 KiB'``, in B, KiB, ..., PiB; from 10,000 PiB on, in PiB with an exponent
    (``'8.9e+10 PiB'``), for any Python int (beyond floats, 2**1024, too).

    Examples
    --------
    >>> human_bytes(1000), human_bytes(1536), human_bytes(1 << 60), human_bytes(10**26)
    ('1000 B', '1.5 KiB', '1024.0 PiB', '8.9e+10 PiB')
    >>> human_bytes((1 << 100_000) * 8)  # 2**100003 B
    '7.1e+30088 PiB'
    """
    if isinstance(nbytes, int) and nbytes >= 1 << 1000:  # no float holds it: from its log
        import math

        exponent = math.log10(nbytes) - 50 * math.log10(2)  # of the size in PiB
        digits = math.floor(exponent)
        mantissa = round(10 ** (exponent - digits), 1)
        if mantissa >= 10:
            mantissa, digits = 1.0, digits + 1
        return f"{mantissa:.1f}e+{digits} PiB"
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if nbytes < 1024 or unit == "PiB":
            break
        nbytes /= 1024
    if unit == "B":
        return f"{int(nbytes)} B"
    return f"{nbytes:.1f} {unit}" if nbytes < 1e4 else f"{nbytes:.1e} {unit}"


def row_norms(A: np.ndarray) -> np.ndarray:
    """Euclidean norms of the rows of A, without overflow or underflow for entries near the
    ends of the float64 range (rows divided by their largest entry first; einsum: no
    temporary of A's size, faster than np.linalg.norm: docs/benchmarks.md, "Kernel design
    choices, measured")."""
    big = np.maximum(np.abs(A).max(axis=1), np.finfo(float).tiny)
    unit = A / big[:, None]
    return big * np.sqrt(np.einsum("ij,ij->i", unit, unit))


#: the smallest normal float64: rates below it are subnormal (fewer than 53 bits)
TINY = np.finfo(np.float64).tiny


def table_maxima(Dh, F) -> tuple[list, float]:
    """(dh_big, f_big): the largest ``|Dh[k]|`` of each row (a list of n floats) and the
    largest ``|F|`` of the table (read block by block)."""
    return (np.abs(Dh).max(axis=1).tolist(),
            max(float(np.abs(F[rows]).max()) for rows in blocks(F.shape[0])))


def find_transversality_violation(G, F, Dh, tol, pending_only=False, maxima=None):
    """First (mask, k, kind, scale) with G[mask, k] <= tol * |F[mask]| |Dh[k]|, or None.

    With ``pending_only`` only the rates of events still pending in the region (bit k of
    mask clear) must be positive: after an impact whose reset sends the state back to the
    side it came from, the event's rate is negative (mathematics.md section 9); every rate
    must still be finite.

    ``kind`` is ``"overflow"`` for a rate beyond float64, ``"zero"`` where ``F[mask]`` or
    ``Dh[k]`` is a row of zeros, ``"underflow"`` for a rate below float64 (``scale`` is then
    log10 |F[mask]| |Dh[k]|), ``"violated"`` for a rate <= 0 and
    ``"grazing"`` for a positive rate that is tiny relative to the scale of the two vectors
    (the surfaces are then nearly tangent to the flow and the event times ill-conditioned).

    A block that :func:`_clearly_transversal` passes is not examined further (the common
    case: no norm of a row is then taken). ``maxima``: :func:`table_maxima` of these F and
    Dh when the caller has it.
    """
    n = G.shape[1]
    dh_big, f_big = table_maxima(Dh, F) if maxima is None else maxima
    dh_norm = None
    for rows in blocks(G.shape[0]):
        happened = block_bits(rows, n) != 0 if pending_only else None
        if _clearly_transversal(G[rows], F.shape[1], f_big, dh_big, tol, happened):
            continue
        if dh_norm is None:
            dh_norm = row_norms(Dh)
        f_norm = row_norms(F[rows])
        with np.errstate(over="ignore"):
            scale = f_norm[:, None] * dh_norm
        # a subnormal rate (below finfo.tiny) has lost digits: never accepted
        bad = (G[rows] <= tol * scale) | (G[rows] < TINY)
        if pending_only:
            bad &= ~happened
        bad |= ~np.isfinite(G[rows])
        if bad.any():
            if not np.isfinite(G[rows]).all():
                i, k = np.argwhere(~np.isfinite(G[rows]))[0]
                return rows.start + int(i), int(k), "overflow", float(scale[i, k])
            # report a sign violation before a grazing rate anywhere in the block
            neg = (G[rows] <= 0) & bad
            i, k = np.argwhere(neg if neg.any() else bad)[0]
            kind = "violated" if neg.any() else "grazing"
            if f_norm[i] == 0.0 or dh_norm[k] == 0.0:  # a row of zeros: no rate at all
                return rows.start + int(i), int(k), "zero", 0.0
            # |F| |Dh| below ~1e-290: the rate is lost to underflow, not known to be <= 0
            log_scale = np.log10(max(f_norm[i], 1e-320)) + np.log10(max(dh_norm[k], 1e-320))
            if abs(G[rows.start + i, k]) < TINY and log_scale < UNDERFLOW_LOG10:
                return rows.start + int(i), int(k), "underflow", float(log_scale)
            return rows.start + int(i), int(k), kind, float(scale[i, k])
    return None


def _clearly_transversal(G, d, f_big, dh_big, tol, happened=None) -> bool:
    """Whether every rate of a block of G (dimension d; every pending rate when
    ``happened``, the (rows, n) flags of the events that happened, is given) passes the
    test of :func:`find_transversality_violation`, decided without the norms of the rows.

    A sufficient test (False sends the block to the full one): ``G[mask, k] > tol * U[k]``
    and ``TINY < G[mask, k] < inf``, with ``U[k] = 2 d b_F b_k``, b_F the largest ``|F|``
    (``f_big``), b_k the largest ``|Dh[k]|`` (``dh_big``), each raised to TINY if below,
    as :func:`row_norms` does. ``row_norms`` gives at most ``b sqrt(d) (1 + eps)**(d/2 +
    2)`` (its unit rows have entries <= 1), so the computed scale is at most ``d b_F b_k (1
    + eps)**(d + 3)``, below the real product ``fl(2 d b_F) b_k``; rounding is monotone, so
    ``fl(tol * U[k])`` is at least the full test's ``tol * scale[mask, k]``. ``U`` in
    Python floats: an overflow there gives inf (no warning) and fails the test; tol = 0 and
    ``U = inf`` give NaN, for which the bound is TINY (the full test then accepts every
    finite rate >= TINY).
    """
    t = float(tol)
    if t != tol:  # a tolerance that is no float (a Fraction): the full test's arithmetic
        return False
    big = max(f_big, TINY) * (2 * d)
    low = []
    for b in dh_big:
        bound = t * (big * max(b, TINY))
        low.append(bound if bound > TINY else TINY)
    ok = G > np.array(low)
    if happened is not None:
        ok |= happened
    ok &= np.abs(G) < np.inf
    return np.count_nonzero(ok) == ok.size


def corner_points(F: np.ndarray, Dh: np.ndarray, G: np.ndarray):
    """Pre- and post-event corner points U, W, each (2**n, d) (mathematics.md section 5).

    x_S solves Dh x_S = 1_S * G[S] (minimum-norm solution); W[S] = x_S and
    U[S] = x_S - F[S] + F[0]. Requires Dh of full row rank.
    """
    n = Dh.shape[0]
    pinv_T = np.linalg.pinv(Dh).T  # (n, d)
    U = np.empty_like(F)
    W = np.empty_like(F)
    for rows in blocks(F.shape[0]):
        masks = np.arange(rows.start, rows.stop, dtype=np.int64)
        np.matmul(mask_bits(masks, n) * G[rows], pinv_T, out=W[rows])
        np.subtract(W[rows], F[rows], out=U[rows])
        U[rows] += F[0]
    return U, W
