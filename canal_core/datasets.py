"""Synthetic demonstration sets from the paper (Section 5), generated in code.

Task I: four demonstrations that start and end in a wide region but pass through a narrow
middle; their mean is a straight line. Task II: the same with one demonstration removed.
"""

from __future__ import annotations

import numpy as np

from .validation import FloatArray

#: Unit offsets of the four Task I demonstrations in the (y, z) plane.
TASK_ONE_CORNERS = np.array([[0.0, 1.0], [1.0, 0.0], [0.0, -1.0], [-1.0, 0.0]])


def task_one(
    n_points: int = 100, length: float = 1.0, wide: float = 0.2, narrow: float = 0.01, noise: float = 0.0,
    seed: int = 0,
) -> list[FloatArray]:
    """Four 3-D demonstrations along x, offset by ``wide`` at the ends and ``narrow`` mid-way.

    Parameters
    ----------
    n_points : int
        Samples per demonstration (each demo gets a slightly different count, as real ones do).
    length, wide, narrow : float
        Extent along x and the offsets at the ends / in the middle.
    noise : float
        Standard deviation of Gaussian noise added to every sample.
    seed : int

    Returns
    -------
    demos : list of 4 arrays, shape (T_j, 3)
    """
    rng = np.random.default_rng(seed)
    demos = []
    for j, corner in enumerate(TASK_ONE_CORNERS):
        x = np.linspace(0.0, length, n_points + 3 * j)
        u = x / length
        offset = narrow + (wide - narrow) * (2.0 * u - 1.0) ** 2
        yz = offset[:, None] * corner[None, :]
        demo = np.column_stack([x, yz])
        demos.append(demo + noise * rng.standard_normal(demo.shape))
    return demos


def task_two(**kwargs: float) -> list[FloatArray]:
    """Task I without its first demonstration (three demos; the directrix tilts away from it)."""
    return task_one(**kwargs)[1:]  # type: ignore[arg-type]


def helix(n_points: int = 200, turns: float = 2.0, radius: float = 1.0, pitch: float = 0.5) -> FloatArray:
    """A helix along z, shape (n_points, 3)."""
    s = np.linspace(0.0, 2.0 * np.pi * turns, n_points)
    return np.column_stack([radius * np.cos(s), radius * np.sin(s), pitch * s / (2.0 * np.pi)])
