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


def normalised_arc_length(positions: FloatArray) -> FloatArray:
    """Cumulative arc length scaled to [0, 1].

    Parameters
    ----------
    positions : array, shape (T, D)
        Consecutive rows must differ (see :func:`canal_core.preprocess.cleaned_demonstration`).

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


def demonstration_spline(positions: FloatArray, timestamps: FloatArray | None) -> CubicSpline:
    """Cubic spline through a demonstration over its parameter in [0, 1] (Section 4.1)."""
    return CubicSpline(spline_parameter(positions, timestamps), positions, axis=0)


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
        parameters[j] = mean_index / (n_samples - 1)
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
