"""Bitmask-indexed corner tables (NumPy only).

Row ``mask`` of every table belongs to the region where the events whose bits are set in
``mask`` have happened (MATH.md section 1). Tables are built block by block so that the
temporaries stay a small fraction of the tables themselves; no Python loop runs over the
individual masks.
"""

from __future__ import annotations

import os

import numpy as np

#: rows per block when a table is built or scanned; 2**15 rows of 20 float64 are 5 MiB.
BLOCK_ROWS = 1 << 15


def blocks(n_rows: int, block: int = BLOCK_ROWS):
    """Yield ``slice`` objects covering ``range(n_rows)`` in blocks."""
    for start in range(0, n_rows, block):
        yield slice(start, min(start + block, n_rows))


def mask_bits(masks: np.ndarray, n: int) -> np.ndarray:
    """Bits of ``masks`` as a float64 (len(masks), n) 0/1 matrix, column k = bit k."""
    return ((masks[:, None] >> np.arange(n)) & 1).astype(np.float64)


def format_mask(mask: int, n: int) -> str:
    """``0b...`` string of ``n`` bits; the rightmost bit is event 0."""
    return "0b" + format(int(mask), f"0{n}b")


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


def dense_table_bytes(n: int, d: int) -> int:
    """Bytes of the tables a dense ``BDerivative`` keeps: F (2**n, d) and G (2**n, n)."""
    return (1 << n) * (d + n) * 8


def corner_point_bytes(n: int, d: int) -> int:
    """Bytes of the corner points U and W, each (2**n, d), built on request."""
    return 2 * (1 << n) * d * 8


def human_bytes(nbytes: float) -> str:
    """``1536 -> '1.5 KiB'``."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if nbytes < 1024 or unit == "PiB":
            return f"{nbytes:.1f} {unit}" if unit != "B" else f"{int(nbytes)} B"
        nbytes /= 1024
    raise AssertionError("unreachable")


#: rows per BLAS call when the rate table is built. Products this small run on one BLAS
#: thread; one big call spreads over BLAS threads, which on a shared 2-core machine was
#: measured 5x to 50x slower (n = d = 20: 0.09 s in blocks of 512 rows, 0.5 s to 5 s in
#: one call or in blocks of 2**11..2**15 rows, depending on the other load).
RATE_BLOCK_ROWS = 512


def event_rates(F: np.ndarray, Dh: np.ndarray) -> np.ndarray:
    """G = F @ Dh.T, shape (2**n, n): G[mask, k] is how fast h_k grows in region mask."""
    G = np.empty((F.shape[0], Dh.shape[0]))
    DhT = Dh.T
    for rows in blocks(F.shape[0], RATE_BLOCK_ROWS):
        np.matmul(F[rows], DhT, out=G[rows])
    return G


def find_transversality_violation(G, F, Dh, tol):
    """First (mask, k, kind, scale) with G[mask, k] <= tol * |F[mask]| |Dh[k]|, or None.

    ``kind`` is ``"violated"`` for a rate <= 0 and ``"grazing"`` for a positive rate that is
    tiny relative to the scale of the two vectors (the surfaces are then nearly tangent to
    the flow and the event times are ill-conditioned).
    """
    dh_norm = np.linalg.norm(Dh, axis=1)
    for rows in blocks(G.shape[0]):
        # row norms by einsum: no (rows, d) temporary, 6x faster than np.linalg.norm
        f_norm = np.sqrt(np.einsum("ij,ij->i", F[rows], F[rows]))
        scale = f_norm[:, None] * dh_norm
        bad = G[rows] <= tol * scale
        if bad.any():
            # report a sign violation before a grazing rate anywhere in the block
            neg = G[rows] <= 0
            i, k = np.argwhere(neg if neg.any() else bad)[0]
            kind = "violated" if neg.any() else "grazing"
            return rows.start + int(i), int(k), kind, float(scale[i, k])
    return None


def corner_points(F: np.ndarray, Dh: np.ndarray, G: np.ndarray):
    """Pre- and post-event corner points U, W, each (2**n, d) (MATH.md section 5).

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
