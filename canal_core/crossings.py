"""Where each demonstration crosses each cross-section plane.

The paper measures the radius "from each point on the directrix to the corresponding points
on the demonstrated trajectories", i.e. to the aligned sample of the same index. That sample
is generally not in the cross-section plane, and its 3-D distance inflates the radius. Here
each demonstration's polyline is intersected with the plane through c_i normal to t_i: the
sign change of t_i . (x - c_i) is found and the crossing interpolated linearly, and the
distance is then measured inside the plane.

To keep a curve that loops back from being caught twice, the crossing is searched only
within +-N/3 samples of i (as both published implementations do) and, among the crossings
found there, the one nearest in index to i wins. A demonstration that never crosses the
plane in that window (typically at the two ends, where demonstrations start ahead of or
stop short of the mean) contributes its sample nearest the plane, projected onto it.
"""

from __future__ import annotations

import numpy as np

from .validation import FloatArray

#: Half-width of the cheap first search, in samples.
NEAR_WINDOW = 4


def _signed_distances(
    aligned: FloatArray, centres: FloatArray, tangents: FloatArray, rows: np.ndarray,
    demos: np.ndarray, cols: np.ndarray,
) -> FloatArray:
    """t_i . (x_{j,k} - c_i) for index arrays of matching shape (sections i, demos j, samples k)."""
    diff = aligned[demos, cols] - centres[rows]
    return np.einsum("...d,...d->...", diff, tangents[rows])


def _crossings_in_window(
    aligned: FloatArray,
    centres: FloatArray,
    tangents: FloatArray,
    sections: np.ndarray,
    demos: np.ndarray,
    half_width: int,
) -> tuple[FloatArray, np.ndarray]:
    """Crossing points for (section, demo) pairs searched within ``half_width`` samples.

    Returns the points, shape (P, D), and a mask, shape (P,), of pairs where a sign change
    was found; unfound pairs hold the window sample nearest the plane, projected onto it.
    """
    n_samples = aligned.shape[1]
    offsets = np.arange(-half_width, half_width + 1)
    cols = np.clip(sections[:, None] + offsets[None, :], 0, n_samples - 1)  # (P, W)
    rows = np.broadcast_to(sections[:, None], cols.shape)
    dems = np.broadcast_to(demos[:, None], cols.shape)
    dist = _signed_distances(aligned, centres, tangents, rows, dems, cols)  # (P, W)

    lo, hi = dist[:, :-1], dist[:, 1:]
    moves = cols[:, 1:] != cols[:, :-1]  # clipped windows repeat the end sample
    crosses = moves & ((lo == 0.0) | (np.sign(lo) != np.sign(hi)))
    # Prefer the crossing segment whose centre is nearest the section's own index.
    distance_to_centre = np.abs(offsets[:-1] + 0.5)
    score = np.where(crosses, distance_to_centre[None, :], np.inf)
    seg = np.argmin(score, axis=1)
    found = np.isfinite(score[np.arange(seg.size), seg])

    pair = np.arange(seg.size)
    d0, d1 = lo[pair, seg], hi[pair, seg]
    denom = d0 - d1
    alpha = np.divide(d0, denom, out=np.zeros_like(d0), where=denom != 0.0)
    x0 = aligned[demos, cols[pair, seg]]
    x1 = aligned[demos, cols[pair, seg + 1]]
    points = x0 + np.clip(alpha, 0.0, 1.0)[:, None] * (x1 - x0)

    if not found.all():
        miss = ~found
        nearest = np.argmin(np.abs(dist[miss]), axis=1)
        x = aligned[demos[miss], cols[miss][np.arange(nearest.size), nearest]]
        t = tangents[sections[miss]]
        offset = dist[miss][np.arange(nearest.size), nearest]
        points[miss] = x - offset[:, None] * t
    return points, found


def plane_crossings(
    aligned: FloatArray, centres: FloatArray, tangents: FloatArray, window: float = 1.0 / 3.0
) -> FloatArray:
    """Points where every demonstration meets every cross-section plane.

    Parameters
    ----------
    aligned : array, shape (n, N, D)
        Aligned demonstrations.
    centres : array, shape (N, D)
        Directrix points c_i.
    tangents : array, shape (N, D)
        Unit tangents t_i (plane normals).
    window : float
        Search half-width as a fraction of N (+-N/3 by default).

    Returns
    -------
    crossings : array, shape (N, n, D)
        Points in the planes (t_i . (x - c_i) = 0 up to rounding).
    """
    n_demos, n_samples, _ = aligned.shape
    sections = np.repeat(np.arange(n_samples), n_demos)
    demos = np.tile(np.arange(n_demos), n_samples)
    points, found = _crossings_in_window(
        aligned, centres, tangents, sections, demos, min(NEAR_WINDOW, n_samples)
    )
    wide = max(NEAR_WINDOW + 1, round(window * n_samples))
    if not found.all() and wide > NEAR_WINDOW:
        # Only pairs without a nearby crossing pay for the wide search.
        miss = np.flatnonzero(~found)
        points[miss], _ = _crossings_in_window(
            aligned, centres, tangents, sections[miss], demos[miss], wide
        )
    return points.reshape(n_samples, n_demos, -1)


def in_plane_coordinates(
    points: FloatArray, centres: FloatArray, basis: FloatArray
) -> FloatArray:
    """Coordinates of points relative to c_i in each section's in-plane basis.

    Parameters
    ----------
    points : array, shape (N, n, D)
    centres : array, shape (N, D)
    basis : array, shape (N, D - 1, D)
        In-plane unit vectors: (n_i, b_i) in 3-D, (n_i,) in 2-D.

    Returns
    -------
    coords : array, shape (N, n, D - 1)
    """
    return np.einsum("ijd,ikd->ijk", points - centres[:, None, :], basis)
