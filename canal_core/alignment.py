"""Temporal alignment of demonstrations (paper Section 4.1).

Demonstrations of one skill have different lengths and speeds. The paper fits a cubic
spline to each and resamples all of them to N samples, which gives sample-to-sample
correspondence; it names Dynamic Time Warping as the alternative. Both are here.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .validation import FloatArray
from .warping import banded_mean_matches, dtw_path, mean_matched_index

if TYPE_CHECKING:
    from scipy.interpolate import CubicSpline

#: Samples the "warp" alignment matches the demonstrations on (:func:`dtw_parameters`):
#: measured leave-one-out on RAIL, 64 aligned as well as 200 and as all N.
DTW_SAMPLES = 64
#: Most samples matched by :func:`canal_core.warping.banded_mean_matches` (its tables are
#: 2m x m per demo); longer matches go through :func:`canal_core.warping.dtw_path`.
BANDED_LIMIT = 1000
#: Table entries :func:`dtw_parameters` gives the banded kernel at once (a few tens of MB).
BANDED_ENTRIES = 1 << 21
#: Smallest step of a warp, in reference samples (keeps every warp strictly increasing).
MIN_WARP_STEP = 1e-6


def normalised_arc_length(positions: FloatArray) -> FloatArray:
    """Cumulative arc length scaled to [0, 1].

    Parameters
    ----------
    positions : array, shape (T, D)
        Consecutive rows must differ by more than rounding (see
        :func:`canal_core.preprocess.prepared_demonstration`).

    Returns
    -------
    s : array, shape (T,)
    """
    steps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(steps)])
    return s / s[-1] if s[-1] > 0 else np.linspace(0.0, 1.0, positions.shape[0])


def spline_parameter(positions: FloatArray, timestamps: FloatArray | None) -> FloatArray:
    """Curve parameter in [0, 1]: normalised time when timestamps exist, else normalised arc length."""
    if timestamps is None:
        return normalised_arc_length(positions)
    return (timestamps - timestamps[0]) / (timestamps[-1] - timestamps[0])


def increasing_rows(parameter: FloatArray) -> np.ndarray:
    """Mask keeping the rows where ``parameter`` rises above every earlier value, shape (T,).

    Prepared demonstrations never lose a row here; this is the guarantee at the spline
    itself, so no caller can hand scipy a stalled parameter (the rows dropped are
    rounding-level repeats that :mod:`canal_core.preprocess` would have dropped).
    """
    keep = np.ones(parameter.shape[0], dtype=bool)
    keep[1:] = parameter[1:] > np.maximum.accumulate(parameter)[:-1]
    return keep


def spline_knots(positions: FloatArray, timestamps: FloatArray | None) -> tuple[FloatArray, FloatArray]:
    """Knots and values of a demonstration's spline: parameter in [0, 1] and positions.

    The parameter is strictly increasing by construction (:func:`increasing_rows`).

    Returns
    -------
    knots : array, shape (K,)
    values : array, shape (K, D)
    """
    u = spline_parameter(positions, timestamps)
    keep = increasing_rows(u)
    if not keep[-1]:  # end exactly at 1: keep the last sample, drop the one it repeats
        keep[np.flatnonzero(keep)[-1]] = False
        keep[-1] = True
    return u[keep], positions[keep]


def demonstration_spline(positions: FloatArray, timestamps: FloatArray | None) -> CubicSpline:
    """Cubic spline through a demonstration over its parameter in [0, 1] (Section 4.1).

    The parameter is strictly increasing by construction (:func:`increasing_rows`).
    """
    from scipy.interpolate import CubicSpline

    knots, values = spline_knots(positions, timestamps)
    return CubicSpline(knots, values, axis=0)


def stacked_spline_values(knots: list[FloatArray], values: list[FloatArray], at: FloatArray) -> FloatArray:
    """Not-a-knot cubic splines through several demonstrations, evaluated at ``at``.

    The same numbers as ``CubicSpline(knots[j], values[j], axis=0)(at)`` (scipy) for every j,
    with every demonstration's tridiagonal system for the slopes s_k solved in one call:
    the systems are stacked into one block-diagonal system whose coupling entries are zero,
    so elimination never mixes two demonstrations. scipy's per-spline set-up cost
    (validation, one LAPACK call and one polynomial object per demonstration) dominated the
    alignment of raw logs.

    Parameters
    ----------
    knots : list of arrays, each shape (K_j,)
        Strictly increasing.
    values : list of arrays, each shape (K_j, D)
    at : array, shape (M,) or (n, M)
        Where to evaluate: the same parameters for every demonstration, or one row each.

    Returns
    -------
    array, shape (n, M, D)
    """
    from scipy.interpolate import CubicSpline
    from scipy.linalg import solve_banded

    sizes = np.array([k.size for k in knots])
    if sizes.min() < 4:  # scipy's special cases (a line, a parabola)
        rows = np.broadcast_to(at, (len(knots), at.shape[-1]))
        return np.stack([CubicSpline(k, v, axis=0)(a) for k, v, a in zip(knots, values, rows, strict=True)])
    x = np.concatenate(knots)
    y = np.concatenate(values)
    first = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    last = first + sizes - 1
    # Differences across two demonstrations are computed too (finite: parameters run from
    # 0 to 1) and never used: the rows and columns they would fill are overwritten below.
    dx = np.diff(x)
    dxr = dx[:, None]
    slope = np.diff(y, axis=0) / dxr
    # The banded matrix and right-hand side of scipy's CubicSpline, rows of all demos.
    ab = np.zeros((3, x.size))
    ab[1, 1:-1] = 2 * (dx[:-1] + dx[1:])  # diagonal
    ab[0, 2:] = dx[:-1]  # upper diagonal
    ab[-1, :-2] = dx[1:]  # lower diagonal
    b = np.empty(y.shape)
    b[1:-1] = 3 * (dxr[1:] * slope[:-1] + dxr[:-1] * slope[1:])
    # Not-a-knot at both ends of every demonstration.
    f, g = first, last
    ab[1, f] = dx[f + 1]
    ab[0, f + 1] = x[f + 2] - x[f]
    d = (x[f + 2] - x[f])[:, None]
    b[f] = ((dxr[f] + 2 * d) * dxr[f + 1] * slope[f] + dxr[f] ** 2 * slope[f + 1]) / d
    ab[1, g] = dx[g - 2]
    ab[-1, g - 1] = x[g] - x[g - 2]
    d = (x[g] - x[g - 2])[:, None]
    b[g] = (dxr[g - 1] ** 2 * slope[g - 2] + (2 * d + dxr[g - 1]) * dxr[g - 2] * slope[g - 1]) / d
    # No coupling between one demonstration's last row and the next one's first.
    ab[0, f] = 0.0
    ab[-1, g] = 0.0
    s = solve_banded((1, 1), ab, b, overwrite_ab=True, overwrite_b=True, check_finite=False)
    # Hermite coefficients per interval, evaluated as scipy's PPoly does (powers of the
    # offset from the interval's left knot, summed from the constant term up).
    t = (s[:-1] + s[1:] - 2 * slope) / dxr
    c0 = t / dxr
    c1 = (slope - s[:-1]) / dxr - t
    per_demo = np.broadcast_to(at, (len(knots), at.shape[-1]))
    interval = np.concatenate([
        f0 + np.clip(np.searchsorted(k, a, side="right") - 1, 0, k.size - 2)
        for f0, k, a in zip(first.tolist(), knots, per_demo, strict=True)
    ])
    z = (per_demo.ravel() - x[interval])[:, None]
    z2 = z * z
    out = np.take(y, interval, axis=0) + np.take(s, interval, axis=0) * z
    out += np.take(c1, interval, axis=0) * z2
    out += np.take(c0, interval, axis=0) * (z2 * z)
    return out.reshape(len(knots), at.shape[-1], y.shape[1])


def strictly_increasing_warp(index: FloatArray, last: float) -> FloatArray:
    """A non-decreasing warp from ``0`` to ``last`` made strictly increasing.

    Each step is raised to at least ``MIN_WARP_STEP`` (a running maximum of
    ``index - k * step``, plus ``k * step``), then the whole warp is scaled back into [0, last].
    """
    k = np.arange(index.size) * MIN_WARP_STEP
    warp = np.maximum.accumulate(index - k) + k
    warp -= warp[0]
    return np.asarray(warp * (last / warp[-1]) if warp[-1] > 0 else np.linspace(0.0, last, index.size))


def resampled_demonstrations(
    demos: list[FloatArray], timestamps: list[FloatArray | None], n_samples: int
) -> FloatArray:
    """Resample every demonstration at ``n_samples`` evenly spaced parameter values.

    Parameters
    ----------
    demos : list of arrays, each shape (T_j, D)
    timestamps : list of (array, shape (T_j,)) or None
    n_samples : int

    Returns
    -------
    aligned : array, shape (n, N, D)
    """
    u = np.linspace(0.0, 1.0, n_samples)
    knots = [spline_knots(d, t) for d, t in zip(demos, timestamps, strict=True)]
    return stacked_spline_values([k[0] for k in knots], [k[1] for k in knots], u)


def dtw_parameters(
    demos: list[FloatArray],
    timestamps: list[FloatArray | None],
    n_samples: int,
    band: float = 0.1,
    resolution: int | None = None,
) -> FloatArray:
    """Each demonstration's spline parameter matched to every reference sample by DTW.

    Each demonstration is first resampled to ``n_samples`` (so DTW sees evenly spaced
    samples), then warped onto the reference (the mean of the resampled set). For every
    reference sample, the demonstration's matched indices are averaged into one fractional
    index, a monotone map from the reference to the demonstration's parameter.

    Parameters
    ----------
    demos : list of arrays, each shape (T_j, D)
    timestamps : list of (array, shape (T_j,)) or None
    n_samples : int
    band : float
        Sakoe-Chiba half-width as a fraction of the samples matched.
    resolution : int, optional
        Match on at most this many samples and interpolate the warps to ``n_samples``
        (None: match on all ``n_samples``).

    Returns
    -------
    parameters : array, shape (n, N)
        Values in [0, 1], non-decreasing along each row, 0 first and 1 last.
    """
    # The warps are smooth: matched on ``resolution`` samples and interpolated to N, they
    # cost the same at any N (a table of N^2 cells at N = 1,000 cost ~0.1 s per demo).
    m = n_samples if resolution is None else min(n_samples, resolution)
    resampled = resampled_demonstrations(demos, timestamps, m)
    reference = resampled.mean(axis=0)
    width = max(1, round(band * m))
    parameters = np.empty((len(demos), n_samples))
    grid = np.linspace(0.0, 1.0, n_samples)
    coarse = np.linspace(0.0, 1.0, m)
    if m <= BANDED_LIMIT:
        # The banded kernel's diagonal-major tables hold (2m) x m entries per demo: a few
        # demos at a time at fine resolution, all of them at the warp's coarse one.
        step = max(1, BANDED_ENTRIES // (2 * m * m))
        matched = np.concatenate([banded_mean_matches(reference, resampled[j : j + step], width)
                                  for j in range(0, len(demos), step)])
    else:
        matched = np.empty((len(demos), m))
        for j in range(len(demos)):
            matched[j] = mean_matched_index(*dtw_path(reference, resampled[j], band=width), m)
    for j in range(len(demos)):
        mean_index = matched[j]
        # Averaging keeps the map monotone; pin the ends so every demo spans its whole path.
        mean_index[0], mean_index[-1] = 0.0, m - 1.0
        warp = strictly_increasing_warp(mean_index, m - 1.0) / (m - 1)
        parameters[j] = warp if m == n_samples else np.interp(grid, coarse, warp)
    return parameters


def dtw_aligned_demonstrations(
    demos: list[FloatArray],
    timestamps: list[FloatArray | None],
    n_samples: int,
    band: float = 0.1,
) -> FloatArray:
    """Align demonstrations by DTW against their spline-aligned mean.

    Each demonstration's spline is resampled at the parameters :func:`dtw_parameters` matched
    to the reference samples.

    Parameters
    ----------
    demos : list of arrays, each shape (T_j, D)
    timestamps : list of (array, shape (T_j,)) or None
    n_samples : int
    band : float
        Sakoe-Chiba half-width as a fraction of ``n_samples``.

    Returns
    -------
    aligned : array, shape (n, N, D)
    """
    return splines_at(demos, timestamps, dtw_parameters(demos, timestamps, n_samples, band))


def splines_at(demos: list[FloatArray], timestamps: list[FloatArray | None], parameters: FloatArray) -> FloatArray:
    """Every demonstration's spline at its own parameters (n, N), shape (n, N, D)."""
    knots = [spline_knots(d, t) for d, t in zip(demos, timestamps, strict=True)]
    return stacked_spline_values([k[0] for k in knots], [k[1] for k in knots], parameters)
