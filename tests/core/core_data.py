"""Demonstration sets shared by the canal_core tests (a module of its own: every test folder
has a conftest.py, so ``from conftest import`` would be ambiguous)."""

from __future__ import annotations

import numpy as np

from canal_core import Canal, datasets, fit


def tube_demos(radius: float = 0.5, n_demos: int = 6, n_points: int = 80) -> list[np.ndarray]:
    """Straight lines along x on a circle of ``radius`` around the x axis."""
    angles = np.linspace(0.0, 2.0 * np.pi, n_demos, endpoint=False)
    x = np.linspace(0.0, 4.0, n_points)
    return [np.column_stack([x, radius * np.cos(a) * np.ones_like(x), radius * np.sin(a) * np.ones_like(x)]) for a in angles]


def helix_demos(offset: float = 0.05, n_demos: int = 5) -> list[np.ndarray]:
    """Helices shifted radially and vertically around one helix."""
    base = datasets.helix(300, turns=2.0, radius=1.0, pitch=0.8)
    angles = np.linspace(0.0, 2.0 * np.pi, n_demos, endpoint=False)
    return [base + offset * np.array([np.cos(a), np.sin(a), np.sin(a)]) for a in angles]


def sleeve_demos(radius: float = 0.05, n_demos: int = 6) -> list[np.ndarray]:
    """Helices spread evenly around one helix in its own normal planes (a true tube)."""
    from canal_core.frames import rotation_minimizing_frames

    base = datasets.helix(300, turns=2.0, radius=1.0, pitch=0.8)
    _, n, b = rotation_minimizing_frames(base)
    angles = np.linspace(0.0, 2.0 * np.pi, n_demos, endpoint=False) + 0.3
    return [base + radius * (np.cos(a) * n + np.sin(a) * b) for a in angles]


def ring_demos() -> list[np.ndarray]:
    """Five straight 1 m strokes around a 6 cm ring, each wavering by about a centimetre; with
    times 0..2 s they move at 0.5 m/s (:func:`ring_canal`)."""
    x = np.linspace(0.0, 1.0, 80)
    demos = []
    for j in range(5):
        a = 2.0 * np.pi * j / 5
        demos.append(np.column_stack([x, 0.06 * np.cos(a) + 0.012 * np.sin(7 * x + j),
                                      0.06 * np.sin(a) + 0.012 * np.cos(9 * x + 2 * j)]))
    return demos


def ring_canal() -> Canal:
    """The canal of :func:`ring_demos`, timed, 100 sections."""
    return fit(ring_demos(), [np.linspace(0.0, 2.0, 80)] * 5, n_samples=100)


def tracker_starts(canal: Canal, n: int, rng: np.random.Generator) -> np.ndarray:
    """Starts spread along the first third of the canal, some inside, some outside (off the
    section planes: a point exactly on a plane is a tie that rounding may break either way)."""
    idx = rng.integers(0, max(canal.n_sections // 3, 1), n)
    scale = rng.choice([0.2, 0.8, 1.5, 4.0], n)[:, None] * canal.radii.max()
    along = rng.uniform(0.1, 0.9, n)[:, None] * (canal.directrix[idx + 1] - canal.directrix[idx])
    return canal.directrix[idx] + along + scale * canal.normals[idx]


def sine_curve(rng: np.random.Generator, dim: int, n: int, freq_high: float, amp_high: float,
               drift: float) -> tuple[np.ndarray, np.ndarray]:
    """A random smooth curve: the sum of three sines per axis (frequencies in [0.3,
    ``freq_high``) half-turns, amplitudes in [0.1, ``amp_high``)), drifting ``drift`` along x.

    Returns
    -------
    s : array, shape (n,)
        Its parameter, 0 to 1.
    base : array, shape (n, dim)
    """
    s = np.linspace(0.0, 1.0, n)
    freq = rng.uniform(0.3, freq_high, size=(3, dim))
    amp = rng.uniform(0.1, amp_high, size=(3, dim))
    base = np.sum(amp[:, None, :] * np.sin(np.pi * freq[:, None, :] * s[None, :, None]), axis=0)
    base[:, 0] += drift * s
    return s, base


def bent_copy(rng: np.random.Generator, s: np.ndarray, base: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """One demonstration of ``base`` (:func:`sine_curve`): 40-79 samples, shifted and bent
    by smooth random deviations (scale 0.05).

    Returns
    -------
    u : array, shape (M,)
        Its samples' parameter, 0 to 1.
    demo : array, shape (M, dim)
    """
    dim = base.shape[1]
    dev = rng.normal(scale=0.05, size=(2, dim))
    u = np.linspace(0.0, 1.0, int(rng.integers(40, 80)))
    curve = np.array([np.interp(u, s, base[:, d]) for d in range(dim)]).T
    return u, curve + dev[0] + np.outer(np.sin(np.pi * u), dev[1])
