"""Metrics for trajectories and canals.

All take sampled curves as arrays of shape (T, D). Distances between curves with different
sample counts are well defined for DTW and Frechet; RMSE resamples both by arc length first.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .alignment import normalised_arc_length
from .validation import FloatArray
from .warping import discrete_frechet_distance, dtw_distance

if TYPE_CHECKING:
    from .model import Canal

__all__ = [
    "containment",
    "discrete_frechet_distance",
    "dtw_distance",
    "jerk",
    "path_length",
    "resampled_by_arc_length",
    "rmse",
]


def containment(canal: Canal, points: FloatArray) -> float:
    """Fraction of ``points`` (M, D) inside the canal."""
    return float(np.mean(canal.contains(points)))


def path_length(positions: FloatArray) -> float:
    """Length of the polyline ``positions`` (T, D)."""
    return float(np.linalg.norm(np.diff(positions, axis=0), axis=1).sum())


def resampled_by_arc_length(positions: FloatArray, n_samples: int) -> FloatArray:
    """Linear resampling of a polyline (T, D) at ``n_samples`` evenly spaced arc lengths."""
    from scipy.interpolate import interp1d

    keep = np.ones(positions.shape[0], dtype=bool)
    keep[1:] = np.any(np.diff(positions, axis=0) != 0.0, axis=1)
    pts = positions[keep]
    if pts.shape[0] == 1:
        return np.repeat(pts, n_samples, axis=0)
    s = normalised_arc_length(pts)
    return np.asarray(interp1d(s, pts, axis=0)(np.linspace(0.0, 1.0, n_samples)), dtype=np.float64)


def rmse(a: FloatArray, b: FloatArray, n_samples: int = 200) -> float:
    """Root-mean-square distance after resampling both curves by arc length to ``n_samples``."""
    ra, rb = resampled_by_arc_length(a, n_samples), resampled_by_arc_length(b, n_samples)
    return float(np.sqrt(np.mean(np.sum((ra - rb) ** 2, axis=1))))


def jerk(positions: FloatArray, dt: float = 1.0) -> float:
    """Mean squared jerk magnitude, sum |d^3 x / dt^3|^2 / (T - 3), for samples ``dt`` apart."""
    if positions.shape[0] < 4:
        return 0.0
    third = np.diff(positions, n=3, axis=0) / dt**3
    return float(np.mean(np.sum(third**2, axis=1)))
