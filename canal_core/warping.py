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


def dtw_distance(a: FloatArray, b: FloatArray, band: int | None = None) -> float:
    """Sum of matched Euclidean distances along the optimal DTW path (unnormalised)."""
    return float(dtw_table(a, b, band)[-1, -1])


def discrete_frechet_distance(a: FloatArray, b: FloatArray) -> float:
    """Discrete Frechet distance between polylines ``a`` (n, D) and ``b`` (m, D) (Eiter-Mannila)."""
    return float(accumulated_cost(pairwise_distances(a, b), np.maximum)[-1, -1])
