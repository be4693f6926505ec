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

from collections.abc import Callable

import numpy as np

from .validation import FloatArray

#: Half-width of the cheap first search, in samples.
NEAR_WINDOW = 4
#: Half-width of the second search, in samples; later searches double it up to the window.
MID_WINDOW = 32
#: Most (pair x window sample) entries searched at once: bounds the memory of a fit with
#: many sections (N = 5,000 peaked at 865 MB in one block, now a few tens of MB).
MAX_BLOCK = 1 << 20


def crosses_plane(before: FloatArray, after: FloatArray) -> np.ndarray:
    """Whether a segment whose ends have signed plane distances ``before``/``after`` meets the plane."""
    return np.asarray((before == 0.0) | (np.sign(before) != np.sign(after)))


def _crossings_in_window(
    aligned: FloatArray,
    centres: FloatArray,
    tangents: FloatArray,
    sections: np.ndarray,
    demos: np.ndarray,
    half_width: int,
) -> tuple[FloatArray, np.ndarray, FloatArray]:
    """Crossing points for (section, demo) pairs searched within ``half_width`` samples.

    Returns the points, shape (P, D), a mask, shape (P,), of pairs where a sign change
    was found (unfound pairs hold the window sample nearest the plane, projected onto it),
    and the distance from c_i of that nearest sample, shape (P,).
    """
    n_samples = aligned.shape[1]
    offsets = np.arange(-half_width, half_width + 1)
    cols = np.clip(sections[:, None] + offsets[None, :], 0, n_samples - 1)  # (P, W)
    # t_i . (x_{j,k} - c_i) = t_i . x_{j,k} - t_i . c_i: gather samples only, not frames.
    t = tangents[sections]
    plane = np.einsum("pd,pd->p", centres[sections], t)
    dist = np.einsum("pwd,pd->pw", aligned[demos[:, None], cols], t) - plane[:, None]  # (P, W)

    lo, hi = dist[:, :-1], dist[:, 1:]
    moves = cols[:, 1:] != cols[:, :-1]  # clipped windows repeat the end sample
    crosses = moves & crosses_plane(lo, hi)
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

    nearest = np.argmin(np.abs(dist), axis=1)
    x = aligned[demos, cols[pair, nearest]]
    reference = np.linalg.norm(x - centres[sections], axis=1)
    miss = ~found
    points[miss] = x[miss] - dist[pair, nearest][miss, None] * tangents[sections[miss]]
    return points, found, reference


def in_row_blocks(
    compute: Callable[[slice], tuple[np.ndarray, ...]], n_rows: int, row_cost: int
) -> tuple[np.ndarray, ...]:
    """``compute`` over slices of rows holding at most ``MAX_BLOCK`` entries, concatenated.

    ``compute(rows)`` returns arrays whose first axis follows the rows; ``row_cost`` is the
    number of entries one row makes ``compute`` allocate (its search window).
    """
    block = max(1, MAX_BLOCK // row_cost)
    if n_rows <= block:
        return compute(slice(None))
    parts = [compute(slice(k, k + block)) for k in range(0, n_rows, block)]
    return tuple(np.concatenate(column) for column in zip(*parts, strict=True))


def _blocked_crossings(
    aligned: FloatArray,
    centres: FloatArray,
    tangents: FloatArray,
    sections: np.ndarray,
    demos: np.ndarray,
    half_width: int,
) -> tuple[FloatArray, np.ndarray, FloatArray]:
    """:func:`_crossings_in_window` over blocks of pairs of at most ``MAX_BLOCK`` entries."""
    points, found, reference = in_row_blocks(
        lambda rows: _crossings_in_window(aligned, centres, tangents, sections[rows], demos[rows], half_width),
        sections.size,
        2 * half_width + 1,
    )
    return points, found, reference


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
    wide = max(NEAR_WINDOW + 1, round(window * n_samples))
    # Widen the search only for the pairs that have not found a crossing yet: most pairs
    # cross within a few samples, the ends of the canal need the whole window.
    # Widen the search only for the pairs that have not found a crossing yet: most pairs
    # cross within a few samples, the ends of the canal need the whole window. Doubling the
    # width finds the same (nearest-in-index) crossing as one wide search, at a cost that
    # grows with how far each pair's crossing is rather than with N for every pending pair.
    widths = [min(NEAR_WINDOW, wide), min(MID_WINDOW, wide)]
    while widths[-1] < wide:
        widths.append(min(2 * widths[-1], wide))
    points, found, reference = _blocked_crossings(
        aligned, centres, tangents, sections, demos, widths[0]
    )
    pending = np.flatnonzero(~found)
    for width in sorted(set(widths[1:])):
        if pending.size == 0:
            break
        far_points, far_found, _ = _blocked_crossings(
            aligned, centres, tangents, sections[pending], demos[pending], width
        )
        # A crossing found far away is taken only if it is nearer c_i than the demo's own
        # nearby sample: a demo lagging behind the mean qualifies, the far side of a loop
        # (or of a helix turn) met by a demo that starts ahead of the first plane does not.
        near_enough = np.linalg.norm(far_points - centres[sections[pending]], axis=1) <= reference[pending]
        take = far_found & near_enough
        points[pending[take]] = far_points[take]
        pending = pending[~far_found]
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
