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
) -> tuple[FloatArray, np.ndarray, FloatArray, FloatArray]:
    """Crossing points for (section, demo) pairs searched within ``half_width`` samples.

    Returns the points, shape (P, D), a mask, shape (P,), of pairs where a sign change
    was found (unfound pairs hold the window sample nearest the plane, projected onto it),
    the distance from c_i of that nearest sample, shape (P,), and the fractional sample
    index of the crossing in the demo, shape (P,) (NaN where none was found).
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
    index = cols[pair, seg] + np.clip(alpha, 0.0, 1.0)

    nearest = np.argmin(np.abs(dist), axis=1)
    x = aligned[demos, cols[pair, nearest]]
    reference = np.linalg.norm(x - centres[sections], axis=1)
    miss = ~found
    points[miss] = x[miss] - dist[pair, nearest][miss, None] * tangents[sections[miss]]
    index[miss] = np.nan
    return points, found, reference, index


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
) -> tuple[FloatArray, np.ndarray, FloatArray, FloatArray]:
    """:func:`_crossings_in_window` over blocks of pairs of at most ``MAX_BLOCK`` entries."""
    points, found, reference, index = in_row_blocks(
        lambda rows: _crossings_in_window(aligned, centres, tangents, sections[rows], demos[rows], half_width),
        sections.size,
        2 * half_width + 1,
    )
    return points, found, reference, index


#: Samples per block of the far search: each block is bounded by a ball, so a plane that
#: misses the ball is crossed nowhere in the block.
BLOCK = 16
#: Rings of blocks visited one at a time around a pair's own block (most crossings lie
#: within two blocks); after that every remaining block is tested at once.
RING_ROUNDS = 3


def _block_balls(aligned: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Centres (n, nb, D) and radii (n, nb) of balls around samples bB..(b+1)B of each demo.

    Block b holds the segments bB .. bB + B - 1 (both ends of each), ``nb = ceil((N-1)/B)``.
    """
    n_samples = aligned.shape[1]
    n_blocks = max(1, -(-(n_samples - 1) // BLOCK))
    idx = np.minimum(np.arange(n_blocks)[:, None] * BLOCK + np.arange(BLOCK + 1)[None, :], n_samples - 1)
    pts = aligned[:, idx]  # (n, nb, B + 1, D)
    lo, hi = pts.min(axis=2), pts.max(axis=2)
    return 0.5 * (lo + hi), 0.5 * np.linalg.norm(hi - lo, axis=2)


def _far_crossings(
    aligned: FloatArray,
    centres: FloatArray,
    tangents: FloatArray,
    sections: np.ndarray,
    demos: np.ndarray,
    half_width: int,
    balls: tuple[FloatArray, FloatArray],
) -> tuple[FloatArray, np.ndarray, FloatArray]:
    """Nearest-in-index crossing within ``half_width`` samples for each (section, demo) pair.

    Same answer as :func:`_crossings_in_window` with that width (the lexicographic minimum
    of (|s + 0.5 - i|, s) over the crossing segments s), at a cost that does not depend on
    the window: the blocks of ``BLOCK`` segments are visited in rings around section i's
    block (ring r: blocks b_i - r and b_i + r). A block whose ball the plane misses holds no
    crossing and costs one dot product; only cut blocks are searched sample by sample. A
    pair stops once its best score is below 16 r + 0.5, the least score any unvisited
    segment can have. Pairs still open after ``RING_ROUNDS`` rings test every remaining
    block's ball at once and search all the cut ones, so no pair keeps the loop going
    across the whole window.

    Returns the points, shape (P, D), whether a crossing was found, shape (P,), and its
    fractional sample index in the demo, shape (P,) (NaN where none was found).
    """
    n_samples, dim = aligned.shape[1], aligned.shape[2]
    n_pairs = sections.size
    t = tangents[sections]
    plane = np.einsum("pd,pd->p", centres[sections], t)
    seg_lo = np.maximum(0, sections - half_width)
    seg_hi = np.minimum(n_samples - 2, sections + half_width - 1)
    # Rounding slack: d is computed per sample, the test per ball; |t.c_i| and |t.m| are
    # bounded by the largest norms of the directrix and of the ball centres.
    bound = float(np.linalg.norm(centres, axis=1).max() + np.linalg.norm(balls[0], axis=2).max())
    reach = balls[1] * (1.0 + 1e-9) + 1e-12 * (balls[1] + bound)
    home = sections // BLOCK
    block_lo, block_hi = seg_lo // BLOCK, seg_hi // BLOCK
    best_score = np.full(n_pairs, np.inf)
    best_seg = np.full(n_pairs, -1, dtype=np.int64)
    q = np.arange(BLOCK)
    samples_of_block = np.arange(BLOCK + 1)

    def searched(rows: np.ndarray, b: np.ndarray) -> None:
        """Search blocks ``b`` of pairs ``rows`` sample by sample and keep each pair's best."""
        for start in range(0, rows.size, MAX_BLOCK // (BLOCK + 1)):
            r, bb = rows[start : start + MAX_BLOCK // (BLOCK + 1)], b[start : start + MAX_BLOCK // (BLOCK + 1)]
            cols = np.minimum(bb[:, None] * BLOCK + samples_of_block[None, :], n_samples - 1)
            dist = np.einsum("pwd,pd->pw", aligned[demos[r, None], cols], t[r]) - plane[r, None]
            seg = bb[:, None] * BLOCK + q[None, :]
            inside = (seg >= seg_lo[r, None]) & (seg <= seg_hi[r, None])
            crosses = inside & crosses_plane(dist[:, :-1], dist[:, 1:])
            score = np.where(crosses, np.abs(seg + 0.5 - sections[r, None]), np.inf)
            j = np.argmin(score, axis=1)
            pick = np.arange(r.size)
            s_score, s_seg = score[pick, j], seg[pick, j]
            # A pair may appear more than once: its lexicographic (score, segment) minimum.
            order = np.lexsort((s_seg, s_score, r))
            r, s_score, s_seg = r[order], s_score[order], s_seg[order]
            first = np.flatnonzero(np.concatenate([[True], r[1:] != r[:-1]]))
            r, s_score, s_seg = r[first], s_score[first], s_seg[first]
            better = (s_score < best_score[r]) | ((s_score == best_score[r]) & (s_seg < best_seg[r]))
            best_score[r[better]] = s_score[better]
            best_seg[r[better]] = s_seg[better]

    active = np.flatnonzero(seg_lo <= seg_hi)
    ring = 0
    while active.size and ring < RING_ROUNDS:
        b = np.concatenate([home[active] - ring, home[active] + ring]) if ring else home[active]
        rows = np.concatenate([active, active]) if ring else active
        ok = (b >= block_lo[rows]) & (b <= block_hi[rows])
        rows, b = rows[ok], b[ok]
        cut = np.abs(np.einsum("pd,pd->p", t[rows], balls[0][demos[rows], b]) - plane[rows]) <= reach[demos[rows], b]
        searched(rows[cut], b[cut])
        ring += 1
        # Unvisited segments after ring r - 1 score at least BLOCK (r - 1) + 0.5 (ties go
        # to the left one, which may be unvisited: hence strictly below).
        active = active[(best_score[active] >= BLOCK * (ring - 1) + 0.5)
                        & ((home[active] - ring >= block_lo[active]) | (home[active] + ring <= block_hi[active]))]
    if active.size:
        # Every remaining block of the window at once: its ball test, then the cut ones.
        blocks = np.arange(balls[1].shape[1])
        for start in range(0, active.size, MAX_BLOCK // blocks.size):
            rows = active[start : start + MAX_BLOCK // blocks.size]
            offset = np.einsum("pd,pbd->pb", t[rows], balls[0][demos[rows]]) - plane[rows, None]
            open_block = (
                (np.abs(blocks[None, :] - home[rows, None]) >= ring)
                & (blocks[None, :] >= block_lo[rows, None])
                & (blocks[None, :] <= block_hi[rows, None])
            )
            pr, bk = np.nonzero(open_block & (np.abs(offset) <= reach[demos[rows]]))
            searched(rows[pr], bk)
    found = np.isfinite(best_score)
    points = np.zeros((n_pairs, dim))
    index = np.full(n_pairs, np.nan)
    if found.any():
        f = np.flatnonzero(found)
        cols = np.stack([best_seg[f], best_seg[f] + 1], axis=1)
        x = aligned[demos[f, None], cols]  # (F, 2, D)
        d = np.einsum("pwd,pd->pw", x, t[f]) - plane[f, None]
        d0, d1 = d[:, 0], d[:, 1]
        denom = d0 - d1
        alpha = np.divide(d0, denom, out=np.zeros_like(d0), where=denom != 0.0)
        points[f] = x[:, 0] + np.clip(alpha, 0.0, 1.0)[:, None] * (x[:, 1] - x[:, 0])
        index[f] = best_seg[f] + np.clip(alpha, 0.0, 1.0)
    return points, found, index


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
    return located_crossings(aligned, centres, tangents, window)[0]


def located_crossings(
    aligned: FloatArray, centres: FloatArray, tangents: FloatArray, window: float = 1.0 / 3.0
) -> tuple[FloatArray, FloatArray]:
    """:func:`plane_crossings` and where along each demo they lie.

    Returns
    -------
    crossings : array, shape (N, n, D)
    index : array, shape (N, n)
        Fractional sample index in demo j of its crossing with plane i; NaN where the demo
        contributes its nearest sample instead (no crossing taken).
    """
    n_demos, n_samples, _ = aligned.shape
    sections = np.repeat(np.arange(n_samples), n_demos)
    demos = np.tile(np.arange(n_demos), n_samples)
    wide = max(NEAR_WINDOW + 1, round(window * n_samples))
    # Most pairs cross within a few samples of their own index: a dense search there.
    points, found, reference, index = _blocked_crossings(
        aligned, centres, tangents, sections, demos, min(NEAR_WINDOW, wide)
    )
    pending = np.flatnonzero(~found)
    if pending.size:
        # The rest (demos ahead of or behind the mean's phase, common in raw logs) by the
        # block search: its cost does not grow with how far the crossing lies.
        balls = _block_balls(aligned)
        far_points, far_found, far_index = in_row_blocks(
            lambda rows: _far_crossings(
                aligned, centres, tangents, sections[pending[rows]], demos[pending[rows]], wide, balls
            ),
            pending.size,
            4 * (BLOCK + 1),
        )
        # A crossing found far away is taken only if it is nearer c_i than the demo's own
        # nearby sample: a demo lagging behind the mean qualifies, the far side of a loop
        # (or of a helix turn) met by a demo that starts ahead of the first plane does not.
        near_enough = np.linalg.norm(far_points - centres[sections[pending]], axis=1) <= reference[pending]
        take = far_found & near_enough
        points[pending[take]] = far_points[take]
        index[pending[take]] = far_index[take]
    return points.reshape(n_samples, n_demos, -1), index.reshape(n_samples, n_demos)


def sections_of_samples(index: FloatArray, demo: int, sample_index: FloatArray) -> FloatArray:
    """Section index, shape (M,), at fractional aligned sample indices of one demo.

    Inverts the demo's crossings (section i is met at sample ``index[i, demo]``) by linear
    interpolation, with unit slope beyond the first and last plane met; where the demo
    met fewer than two planes, the sample index itself.
    A demo ahead of or behind the mean's phase is thus placed at the sections it crosses,
    not at its own index.

    Parameters
    ----------
    index : array, shape (N, n)
        From :func:`located_crossings`.
    demo : int
    sample_index : array, shape (M,)
    """
    met = np.flatnonzero(np.isfinite(index[:, demo]))
    if met.size < 2:
        return np.asarray(sample_index, dtype=np.float64)
    at = index[met, demo]
    order = np.argsort(at, kind="stable")
    at, met = at[order], met[order].astype(np.float64)
    k = np.asarray(sample_index, dtype=np.float64)
    section = np.interp(k, at, met)
    # Beyond the first / last plane it meets, the demo keeps its offset from there: a demo
    # that met no plane near its start still sits at the first sections, not at the first met.
    before, after = k < at[0], k > at[-1]
    section[before] = met[0] - (at[0] - k[before])
    section[after] = met[-1] + (k[after] - at[-1])
    return np.asarray(np.clip(section, 0.0, index.shape[0] - 1.0))


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
