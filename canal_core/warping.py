"""Dynamic-programming distances between sampled curves: DTW and discrete Frechet.

Both fill an accumulated-cost table whose cell (i, j) depends on (i-1, j), (i, j-1) and
(i-1, j-1). Cells on one anti-diagonal are independent, so the table is filled one
anti-diagonal at a time with vectorised numpy (O(n + m) Python steps, not O(n m)). One
kernel serves both, with an optional Sakoe-Chiba band for DTW; no compiled dependency.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .validation import FloatArray, IntArray


def pairwise_distances(a: FloatArray, b: FloatArray) -> FloatArray:
    """Euclidean distances between every row of ``a`` and of ``b``.

    Parameters
    ----------
    a : array, shape (n, D)
    b : array, shape (m, D)

    Returns
    -------
    distances : array, shape (n, m)
    """
    diff = a[:, None, :] - b[None, :, :]
    return np.sqrt(np.einsum("ijk,ijk->ij", diff, diff))


def band_mask(n: int, m: int, band: int | None) -> np.ndarray:
    """Cells within ``band`` samples of the (rescaled) diagonal, shape (n, m); all if None."""
    if band is None:
        return np.ones((n, m), dtype=bool)
    i = np.arange(n)[:, None] * (m - 1) / max(n - 1, 1)
    j = np.arange(m)[None, :]
    return np.abs(i - j) <= band


def accumulated_cost(
    cost: FloatArray,
    combine: Callable[[FloatArray, FloatArray], FloatArray],
) -> FloatArray:
    """Fill the padded DP table P, shape (n + 1, m + 1), anti-diagonal by anti-diagonal.

    ``P[i + 1, j + 1] = combine(cost[i, j], min(P[i, j], P[i, j + 1], P[i + 1, j]))``;
    ``np.add`` gives DTW, ``np.maximum`` gives the discrete Frechet distance.
    """
    n, m = cost.shape
    table = np.full((n + 1, m + 1), np.inf)
    table[0, 0] = 0.0
    for k in range(n + m - 1):
        i = np.arange(max(0, k - m + 1), min(n - 1, k) + 1)
        j = k - i
        best = np.minimum(np.minimum(table[i, j], table[i, j + 1]), table[i + 1, j])
        table[i + 1, j + 1] = combine(cost[i, j], best)
    return table


def dtw_table(a: FloatArray, b: FloatArray, band: int | None = None) -> FloatArray:
    """Accumulated DTW cost table between curves ``a`` (n, D) and ``b`` (m, D), shape (n+1, m+1)."""
    cost = pairwise_distances(a, b)
    cost[~band_mask(cost.shape[0], cost.shape[1], band)] = np.inf
    return accumulated_cost(cost, np.add)


def dtw_path(a: FloatArray, b: FloatArray, band: int | None = None) -> tuple[IntArray, IntArray]:
    """Optimal DTW alignment of ``a`` (n, D) and ``b`` (m, D).

    Parameters
    ----------
    a : array, shape (n, D)
    b : array, shape (m, D)
    band : int, optional
        Sakoe-Chiba half-width in samples of ``b``; None for no band.

    Returns
    -------
    ia, ib : arrays of int, shape (L,)
        Matched index pairs, monotone, from (0, 0) to (n - 1, m - 1).
    """
    table = dtw_table(a, b, band)
    i, j = a.shape[0], b.shape[0]
    path = [(i - 1, j - 1)]
    # Backtracking is inherently sequential, but only O(n + m) steps of scalar work.
    while (i, j) != (1, 1):
        steps = ((i - 1, j - 1), (i - 1, j), (i, j - 1))
        i, j = min(steps, key=lambda s: table[s])
        path.append((i - 1, j - 1))
    pairs = np.asarray(path[::-1], dtype=np.int64)
    return pairs[:, 0], pairs[:, 1]


def band_cells(n: int, m: int, band: int) -> tuple[IntArray, IntArray]:
    """The cells of a band around the diagonal of an (n, m) table, row by row.

    Row i holds j in [ceil(i r - band), floor(i r + band)] within [0, m - 1], r = (m - 1) / (n - 1).

    Returns
    -------
    ii, jj : arrays of int, shape (L,)
        Row and column of each cell, rows ascending and columns ascending within a row.
    """
    ratio = (m - 1) / (n - 1)
    rows = np.arange(n)
    j_lo = np.clip(np.ceil(rows * ratio - band - 1e-9).astype(np.int64), 0, m - 1)
    j_hi = np.clip(np.floor(rows * ratio + band + 1e-9).astype(np.int64), 0, m - 1)
    ii = np.repeat(rows, j_hi - j_lo + 1)
    jj = np.concatenate([np.arange(lo, hi + 1) for lo, hi in zip(j_lo.tolist(), j_hi.tolist(), strict=True)])
    return ii, jj


def mean_matched_index(ia: IntArray, ib: IntArray, n: int) -> FloatArray:
    """For each row 0 .. n - 1 of the first curve, the mean index of the second curve's
    samples a DTW path (``ia``, ``ib``) matches to it, shape (n,)."""
    return np.asarray(np.bincount(ia, weights=ib, minlength=n) / np.bincount(ia, minlength=n),
                      dtype=np.float64)


def banded_mean_matches(a: FloatArray, curves: FloatArray, band: int) -> FloatArray:
    """For every row of ``a``, the mean index of the samples of each curve matched to it on
    the curve's :func:`dtw_path` with ``a`` within a Sakoe-Chiba band, all curves at once.

    The tables cover the band's cells only: a cell (i, j) is in the band when
    |i (m - 1) / (n - 1) - j| <= ``band``, as in :func:`band_mask`. They are stored by
    anti-diagonal (k = i + j), so each step of the fill reads and writes contiguous slices of
    diagonals k - 1 and k - 2, for every curve at once: one numpy step per anti-diagonal,
    whatever the number of curves, and a cost that follows the band's width, not the whole
    table's. The backtrack breaks ties in :func:`dtw_path`'s order, so the paths are its
    paths.

    Parameters
    ----------
    a : array, shape (n, D)
    curves : array, shape (c, m, D)
    band : int
        Half-width in samples of the curves (at least 1).

    Returns
    -------
    mean_index : array, shape (c, n)
    """
    n, m, count = a.shape[0], curves.shape[1], curves.shape[0]
    if n == 1 or m == 1:
        out = np.empty((count, n))
        for c in range(count):
            out[c] = mean_matched_index(*dtw_path(a, curves[c], band), n)
        return out
    ii, jj = band_cells(n, m, band)
    n_diag = n + m - 1
    cost = np.full((count, n_diag, n + 1), np.inf)
    diff = a[ii][None, :, :] - curves[:, jj, :]
    cost[:, ii + jj, ii + 1] = np.sqrt(np.einsum("cpd,cpd->cp", diff, diff))
    table = np.full((count, n_diag, n + 1), np.inf)
    k_cells = ii + jj
    i_lo = np.full(n_diag, n, dtype=np.int64)
    i_hi = np.full(n_diag, -1, dtype=np.int64)
    np.minimum.at(i_lo, k_cells, ii)
    np.maximum.at(i_hi, k_cells, ii)
    table[:, 0, 1] = cost[:, 0, 1]
    lows, highs = i_lo.tolist(), i_hi.tolist()
    for k in range(1, n_diag):
        lo, hi = lows[k], highs[k] + 1
        if hi <= lo:
            continue
        best = np.minimum(table[:, k - 1, lo:hi], table[:, k - 1, lo + 1 : hi + 1])
        if k >= 2:
            np.minimum(best, table[:, k - 2, lo:hi], out=best)
        table[:, k, lo + 1 : hi + 1] = cost[:, k, lo + 1 : hi + 1] + best
    # Backtrack each curve on plain lists (scalar reads of numpy arrays cost several times more).
    out = np.empty((count, n))
    for c in range(count):
        rows_ = table[c].tolist()
        i, k = n - 1, n_diag - 1
        sums = [0.0] * n
        counts = [0] * n
        sums[i] += k - i
        counts[i] += 1
        while k > 0:
            # In dtw_path's order on ties: (i - 1, j - 1), (i - 1, j), (i, j - 1).
            low: float = float("inf")
            nk, ni = 0, 0
            if k >= 2 and i >= 1:
                low, nk, ni = rows_[k - 2][i], k - 2, i - 1
            if i >= 1 and rows_[k - 1][i] < low:
                low, nk, ni = rows_[k - 1][i], k - 1, i - 1
            if k - 1 - i >= 0 and rows_[k - 1][i + 1] < low:
                low, nk, ni = rows_[k - 1][i + 1], k - 1, i
            k, i = nk, ni
            sums[i] += k - i
            counts[i] += 1
        out[c] = np.asarray(sums) / np.asarray(counts)
    return out


def dtw_distance(a: FloatArray, b: FloatArray, band: int | None = None) -> float:
    """Sum of matched Euclidean distances along the optimal DTW path (unnormalised)."""
    return float(dtw_table(a, b, band)[-1, -1])


def discrete_frechet_distance(a: FloatArray, b: FloatArray) -> float:
    """Discrete Frechet distance between polylines ``a`` (n, D) and ``b`` (m, D) (Eiter-Mannila)."""
    return float(accumulated_cost(pairwise_distances(a, b), np.maximum)[-1, -1])
