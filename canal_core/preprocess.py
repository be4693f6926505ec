"""Clean raw robot logs before alignment.

Polling recorders repeat samples (65-75 % of rows on some arms) and demonstrations start
and end with the arm standing still. Repeats make arc length stall and still ends stretch
time alignment, so both are removed before resampling.
"""

from __future__ import annotations

import numpy as np

from .validation import FloatArray

#: Fraction of a demonstration's path length below which a head/tail sample counts as "still".
STILL_TOLERANCE = 1e-3


def mask_of_new_samples(positions: FloatArray) -> np.ndarray:
    """Return a mask that keeps the first of every run of exactly repeated rows.

    Parameters
    ----------
    positions : array, shape (T, D)

    Returns
    -------
    keep : array of bool, shape (T,)
    """
    keep = np.ones(positions.shape[0], dtype=bool)
    keep[1:] = np.any(positions[1:] != positions[:-1], axis=1)
    return keep


def moving_range(positions: FloatArray, tolerance: float = STILL_TOLERANCE) -> slice:
    """Return the slice of samples between the still head and the still tail.

    A head sample is still while it lies within ``tolerance * path_length`` of the first
    sample; likewise a tail sample of the last one. One still sample is kept at each end
    so the demonstration still starts and ends where the robot stood.

    Parameters
    ----------
    positions : array, shape (T, D)
    tolerance : float
        Fraction of the path length.
    """
    steps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    radius = tolerance * float(steps.sum())
    if radius == 0.0:
        return slice(0, positions.shape[0])
    away_from_start = np.linalg.norm(positions - positions[0], axis=1) > radius
    away_from_end = np.linalg.norm(positions - positions[-1], axis=1) > radius
    first = int(np.argmax(away_from_start))
    last = positions.shape[0] - 1 - int(np.argmax(away_from_end[::-1]))
    return slice(max(first - 1, 0), min(last + 2, positions.shape[0]))


def cleaned_demonstration(
    positions: FloatArray,
    timestamps: FloatArray | None = None,
    tolerance: float = STILL_TOLERANCE,
) -> tuple[FloatArray, FloatArray | None]:
    """Drop exact repeats, then trim still ends.

    Parameters
    ----------
    positions : array, shape (T, D)
    timestamps : array, shape (T,), optional
    tolerance : float
        See :func:`moving_range`.

    Returns
    -------
    positions : array, shape (T', D)
    timestamps : array, shape (T',) or None
    """
    keep = mask_of_new_samples(positions)
    positions = positions[keep]
    if timestamps is not None:
        timestamps = timestamps[keep]
    window = moving_range(positions, tolerance)
    positions = positions[window]
    if timestamps is not None:
        timestamps = timestamps[window]
    return positions, timestamps
