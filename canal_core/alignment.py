"""Temporal alignment of demonstrations (paper Section 4.1).

Demonstrations of one skill have different lengths and speeds. The paper fits a cubic
spline to each and resamples all of them to N samples, which gives sample-to-sample
correspondence; it names Dynamic Time Warping as the alternative. Both are here.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import CubicSpline

from .validation import FloatArray
from .warping import dtw_path

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


def demonstration_spline(positions: FloatArray, timestamps: FloatArray | None) -> CubicSpline:
    """Cubic spline through a demonstration over its parameter in [0, 1] (Section 4.1).

    The parameter is strictly increasing by construction (:func:`increasing_rows`).
    """
    u = spline_parameter(positions, timestamps)
    keep = increasing_rows(u)
    if not keep[-1]:  # end exactly at 1: keep the last sample, drop the one it repeats
        keep[np.flatnonzero(keep)[-1]] = False
        keep[-1] = True
    return CubicSpline(u[keep], positions[keep], axis=0)


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
    return np.stack(
        [demonstration_spline(d, t)(u) for d, t in zip(demos, timestamps, strict=True)]
    )


def dtw_parameters(
    demos: list[FloatArray],
    timestamps: list[FloatArray | None],
    n_samples: int,
    band: float = 0.1,
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
        Sakoe-Chiba half-width as a fraction of ``n_samples``.

    Returns
    -------
    parameters : array, shape (n, N)
        Values in [0, 1], non-decreasing along each row, 0 first and 1 last.
    """
    u = np.linspace(0.0, 1.0, n_samples)
    resampled = np.stack([demonstration_spline(d, t)(u) for d, t in zip(demos, timestamps, strict=True)])
    reference = resampled.mean(axis=0)
    width = max(1, round(band * n_samples))
    parameters = np.empty((len(demos), n_samples))
    for j in range(len(demos)):
        i_ref, i_demo = dtw_path(reference, resampled[j], band=width)
        counts = np.bincount(i_ref, minlength=n_samples)
        mean_index = np.bincount(i_ref, weights=i_demo, minlength=n_samples) / counts
        # Averaging keeps the map monotone; pin the ends so every demo spans its whole path.
        mean_index[0], mean_index[-1] = 0.0, n_samples - 1.0
        parameters[j] = strictly_increasing_warp(mean_index, n_samples - 1.0) / (n_samples - 1)
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
    parameters = dtw_parameters(demos, timestamps, n_samples, band)
    return np.stack(
        [
            demonstration_spline(d, t)(p)
            for d, t, p in zip(demos, timestamps, parameters, strict=True)
        ]
    )
