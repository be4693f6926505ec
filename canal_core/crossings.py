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

Where a demonstration folds back over itself (pressing: down, up and down again; a wipe back
and forth) the nearest crossing in index of one plane can lie on a later pass than the next
plane's: the sections would mix its passes. Such a demonstration's crossings are chosen again
in its own order (:func:`ordered_crossings`), so the sections follow the directrix's
parameter, not the nearest plane.
"""

from __future__ import annotations

from bisect import bisect_right
from collections.abc import Callable
from itertools import pairwise

import numpy as np
from numpy.lib.stride_tricks import as_strided, sliding_window_view

from .validation import BoolArray, FloatArray, IntArray

#: A demo's crossing more than this many samples before an earlier section's is a fold:
#: its crossings are chosen again in its own order (:func:`ordered_crossings`).
FOLD_TOLERANCE = 1.0
#: Half-width of the dense first search, in samples.
NEAR_WINDOW = 4
#: Most (pair x window sample) entries searched at once: bounds the memory of a fit with
#: many sections (N = 5,000 peaked at 865 MB in one block, now a few tens of MB).
MAX_BLOCK = 1 << 20
#: Samples per block of the far search: each block is bounded by a ball, so a plane that
#: misses the ball is crossed nowhere in the block.
BLOCK = 16


def crosses_plane(before: FloatArray, after: FloatArray) -> np.ndarray:
    """Whether a segment whose ends have signed plane distances ``before``/``after`` meets the plane."""
    return np.asarray((before == 0.0) | (np.sign(before) != np.sign(after)))


def sign_changes(dist: FloatArray) -> np.ndarray:
    """:func:`crosses_plane` of consecutive entries along the last axis, shape (..., W - 1).

    One comparison per entry instead of two signs per segment: a segment meets the plane
    when one end is on it or the ends lie on different sides.
    """
    above = dist > 0.0
    changes = above[..., 1:] != above[..., :-1]
    on = dist == 0.0
    if on.any():
        changes |= on[..., :-1] | on[..., 1:]
    return changes


def in_row_blocks(
    compute: Callable[[slice], tuple[np.ndarray, ...]], n_rows: int, row_cost: int, budget: int = MAX_BLOCK
) -> tuple[np.ndarray, ...]:
    """``compute`` over slices of rows holding at most ``budget`` entries, concatenated.

    ``compute(rows)`` returns arrays whose first axis follows the rows; ``row_cost`` is the
    number of entries one row makes ``compute`` allocate (its search window).
    """
    block = max(1, budget // max(row_cost, 1))
    if n_rows <= block:
        return compute(slice(None))
    parts = [compute(slice(k, k + block)) for k in range(0, n_rows, block)]
    return tuple(np.concatenate(column) for column in zip(*parts, strict=True))


def _near_crossings(
    aligned: FloatArray, centres: FloatArray, tangents: FloatArray, plane: FloatArray, half_width: int
) -> tuple[FloatArray, BoolArray, FloatArray, FloatArray]:
    """Crossing nearest in index within ``half_width`` samples of i, for every (demo, section).

    Every demo's samples i - h .. i + h (the ends repeated, repeats never count as a
    segment) are read through one strided view, not gathered pair by pair.

    Parameters
    ----------
    aligned : array, shape (n, N, D)
    centres, tangents : arrays, shape (N, D)
    plane : array, shape (N,)
        t_i . c_i.
    half_width : int

    Returns
    -------
    points : array, shape (n, N, D)
        The crossing, or where none was found, the window sample nearest the plane
        projected onto it.
    found : array of bool, shape (n, N)
    reference : array, shape (n, N)
        Distance from c_i of that nearest sample where no crossing was found (0 elsewhere).
    index : array, shape (n, N)
        Fractional sample index of the crossing in the demo (NaN where none was found).
    """
    n_demos, n_samples, dim = aligned.shape
    h = half_width
    offsets = np.arange(-h, h + 1)
    cols = np.clip(np.arange(n_samples)[:, None] + offsets[None, :], 0, n_samples - 1)  # (N, W)
    padded = np.concatenate(
        [np.repeat(aligned[:, :1], h, axis=1), aligned, np.repeat(aligned[:, -1:], h, axis=1)], axis=1
    )
    windows = sliding_window_view(padded, 2 * h + 1, axis=1)  # (n, N, D, W), a view
    # t_i . (x_{j,k} - c_i) = t_i . x_{j,k} - t_i . c_i, one in-plane axis at a time.
    dist = windows[:, :, 0, :] * tangents[None, :, 0, None]
    for axis in range(1, dim):
        dist += windows[:, :, axis, :] * tangents[None, :, axis, None]
    dist -= plane[None, :, None]  # (n, N, W)
    moves = cols[:, 1:] != cols[:, :-1]  # clipped windows repeat the end sample
    crosses = sign_changes(dist) & moves[None]
    # Segments in order of preference: nearest the section's own index, the earlier on a tie.
    preference = np.argsort(np.abs(offsets[:-1] + 0.5), kind="stable")
    ranked = crosses[..., preference]
    first = np.argmax(ranked, axis=-1)  # (n, N); 0 where none (then ranked there is False)
    seg = preference[first]
    # Entries of each pair's own row by flat index (one np.take each, no index grids).
    width = 2 * h + 1
    pair_row = np.arange(n_demos * n_samples).reshape(n_demos, n_samples)
    found = np.take(ranked, pair_row * (width - 1) + first)
    at = pair_row * width + seg
    d0 = np.take(dist, at)
    d1 = np.take(dist, at + 1)
    denom = d0 - d1
    alpha = np.clip(np.divide(d0, denom, out=np.zeros_like(d0), where=denom != 0.0), 0.0, 1.0)
    start = np.take(cols, np.arange(n_samples)[None, :] * width + seg)  # (n, N)
    # Rows of the flattened demos, gathered with np.take (fancy indexing of (n, N, D) by
    # two index arrays costs several times more).
    flat = aligned.reshape(-1, dim)
    row = np.arange(n_demos)[:, None] * n_samples
    x0 = np.take(flat, (row + start).ravel(), axis=0).reshape(n_demos, n_samples, dim)
    x1 = np.take(flat, (row + np.minimum(start + 1, n_samples - 1)).ravel(), axis=0).reshape(n_demos, n_samples, dim)
    points = x0 + alpha[..., None] * (x1 - x0)
    index = np.where(found, start + alpha, np.nan)

    # Pairs without a crossing: the window sample nearest the plane, projected onto it.
    reference = np.zeros((n_demos, n_samples))
    missing = np.flatnonzero(~found)  # flat (demo, section) rows
    if missing.size:
        mi = missing % n_samples
        missed = np.take(dist.reshape(-1, width), missing, axis=0)  # (P, W)
        nearest = np.argmin(np.abs(missed), axis=1)
        x = np.take(flat, missing - mi + np.take(cols, mi * width + nearest), axis=0)
        offset = x - np.take(centres, mi, axis=0)
        reference.reshape(-1)[missing] = np.sqrt(np.einsum("pd,pd->p", offset, offset))
        points.reshape(-1, dim)[missing] = (
            x - np.take(missed, np.arange(missing.size) * width + nearest)[:, None] * np.take(tangents, mi, axis=0)
        )
    return points, found, reference, index


def block_views(aligned: FloatArray) -> FloatArray:
    """Each demo's samples bB .. (b + 1)B as a strided view, shape (n, nb, B + 1, D).

    Block b holds the segments bB .. bB + B - 1 (both ends of each), ``nb = ceil((N-1)/B)``;
    the last block repeats the last sample where the demo ends early. A block is one
    contiguous run of memory, so gathering blocks copies runs instead of single samples.
    Every demo takes ``(nb + 1) B`` rows of one buffer (one spare block, plus one spare row
    at the very end), so block b of demo j is also item ``j (nb + 1) + b`` of the flat view
    :func:`block_items` and sample k is row ``j (nb + 1) B + k`` of :func:`block_rows`.
    """
    n_demos, n_samples, dim = aligned.shape
    n_blocks = max(1, -(-(n_samples - 1) // BLOCK))
    span = (n_blocks + 1) * BLOCK
    buffer = np.empty((n_demos * span + 1, dim))
    rows = buffer[:-1].reshape(n_demos, span, dim)
    rows[:, :n_samples] = aligned
    rows[:, n_samples:] = aligned[:, -1:]
    buffer[-1] = aligned[-1, -1]
    row_stride, axis_stride = buffer.strides
    return np.asarray(as_strided(
        buffer,
        shape=(n_demos, n_blocks, BLOCK + 1, dim),
        strides=(span * row_stride, BLOCK * row_stride, row_stride, axis_stride),
        writeable=False,
    ))


def block_items(blocks: FloatArray) -> FloatArray:
    """The blocks of :func:`block_views` as one flat axis, shape (n (nb + 1), B + 1, D).

    Item ``j (nb + 1) + b`` is block b of demo j: one ``np.take`` gathers blocks (a
    fancy index by two arrays costs several times more).
    """
    n_demos, _, width, dim = blocks.shape
    per_demo = blocks.strides[0] // blocks.strides[1]
    return np.asarray(as_strided(
        blocks, shape=(n_demos * per_demo, width, dim), strides=blocks.strides[1:], writeable=False
    ))


def block_rows(blocks: FloatArray) -> FloatArray:
    """The samples under :func:`block_views`, shape (n (nb + 1) B + 1, D): sample k of demo j
    is row ``j (nb + 1) B + k``."""
    n_demos, _, _, dim = blocks.shape
    per_demo = blocks.strides[0] // blocks.strides[2]
    return np.asarray(as_strided(
        blocks, shape=(n_demos * per_demo + 1, dim), strides=blocks.strides[2:], writeable=False
    ))


#: Most (block x sample x axis) entries of the cut blocks searched at once. Small chunks
#: reuse the same memory from one to the next; one large gather of every cut block cost
#: more in fresh pages (page faults) than in arithmetic.
SEARCH_CHUNK = 1 << 15
#: Entries per chunk of the plane-crossing searches (demos for the dense one, pairs for
#: the block one): a few hundred kB of temporaries, reused from chunk to chunk, where one
#: pass over everything made the allocator fetch (and fault in) fresh pages on every fit.
WORK_CHUNK = 1 << 17
#: Entries per chunk of the far search: its per-pair rows are mostly booleans (which groups
#: and blocks a plane cuts), so a chunk this size still holds a few MB at most, and the
#: 6 x 1,000 pairs of a raw-log fit are searched in one pass instead of paying the pass's
#: fixed cost twice.
FAR_CHUNK = 1 << 19
#: Blocks per group of the first ball test: a plane is tested against every group's ball,
#: and against the balls of the blocks of the groups it cuts only.
GROUP = 4


def block_boxes(blocks: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Lower and upper corners (n, nb, D) of the bounding boxes of the blocks of
    :func:`block_views`.

    Reduced over runs of the padded samples (``reduceat``) plus each block's last sample
    (the first of the next): a reduction over the view's short block axis costs more.
    """
    n_demos, n_blocks, _, dim = blocks.shape
    padded = np.lib.stride_tricks.as_strided(
        blocks, shape=(n_demos, n_blocks * BLOCK + 1, dim),
        strides=(blocks.strides[0], blocks.strides[2], blocks.strides[3]), writeable=False,
    )
    starts = np.arange(n_blocks) * BLOCK
    last = padded[:, starts + BLOCK]
    lo = np.minimum(np.minimum.reduceat(padded, starts, axis=1), last)
    hi = np.maximum(np.maximum.reduceat(padded, starts, axis=1), last)
    return lo, hi


def grouped_boxes(lo: FloatArray, hi: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Boxes (n, ceil(nb / GROUP), D) around every ``GROUP`` consecutive block boxes."""
    n_demos, n_blocks, dim = lo.shape
    extra = -n_blocks % GROUP  # the last group repeats the last block
    if extra:
        lo = np.concatenate([lo, np.repeat(lo[:, -1:], extra, axis=1)], axis=1)
        hi = np.concatenate([hi, np.repeat(hi[:, -1:], extra, axis=1)], axis=1)
    shape = (n_demos, -1, GROUP, dim)
    return lo.reshape(shape).min(axis=2), hi.reshape(shape).max(axis=2)


def box_balls(lo: FloatArray, hi: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Centres (..., D) and radii (...) of the balls circumscribing boxes."""
    return 0.5 * (lo + hi), 0.5 * np.sqrt(np.einsum("...d,...d->...", hi - lo, hi - lo))


def _segment_key(seg: IntArray, section: IntArray) -> IntArray:
    """Integer preference of segment s for section i: the lexicographic order of
    (|s + 0.5 - i|, s) as one number, 2 |2s + 1 - 2i| + [s >= i]."""
    return 2 * np.abs(2 * seg + 1 - 2 * section) + (seg >= section)


def _segment_of_key(key: IntArray, section: IntArray) -> IntArray:
    """Inverse of :func:`_segment_key`."""
    u = key // 2
    return np.where(key % 2 == 1, section + (u - 1) // 2, section - (u + 1) // 2)


def _far_crossings(
    blocks: FloatArray,
    tangents: FloatArray,
    plane: FloatArray,
    sections: IntArray,
    demos: IntArray,
    half_width: int,
    balls: tuple[FloatArray, FloatArray],
    groups: tuple[FloatArray, FloatArray],
) -> tuple[FloatArray, BoolArray, FloatArray]:
    """Nearest-in-index crossing within ``half_width`` samples for each (section, demo) pair.

    The same answer as a dense search of the window (the lexicographic minimum of
    (|s + 0.5 - i|, s) over the crossing segments s) in one pass whose cost does not grow
    with how far the crossing lies: every group of ``GROUP`` blocks of ``BLOCK`` segments
    costs one dot product (a plane that misses the group's ball crosses nowhere in it), the
    blocks of the groups it cuts one more each, and only the blocks the plane cuts inside the
    window are searched sample by sample. Pairs must be sorted by demo.

    Parameters
    ----------
    blocks : array, shape (n, nb, B + 1, D)
        From :func:`block_views`.
    tangents : array, shape (N, D)
    plane : array, shape (N,)
        t_i . c_i.
    sections, demos : arrays of int, shape (P,)
    half_width : int
    balls : (array, shape (n, nb, D), array, shape (n, nb))
        Ball centres and radii (with rounding slack) of the blocks.
    groups : (array, shape (n, ng, D), array, shape (n, ng))
        The same for the groups of blocks (:func:`grouped_boxes`).

    Returns
    -------
    points : array, shape (P, D)
        The crossing (zero where none was found).
    found : array of bool, shape (P,)
    index : array, shape (P,)
        Fractional sample index of the crossing (NaN where none was found).
    """
    n_demos, n_blocks, dim = blocks.shape[0], blocks.shape[1], blocks.shape[3]
    n_samples = tangents.shape[0]
    n_pairs = sections.size
    t = np.take(tangents, sections, axis=0)
    level = plane[sections]
    seg_lo = np.maximum(0, sections - half_width)
    seg_hi = np.minimum(n_samples - 2, sections + half_width - 1)
    # First the balls of groups of GROUP blocks, then the balls of the blocks in the
    # groups the plane cuts: a plane that misses a ball crosses nowhere inside it.
    group_centre, group_reach = groups
    n_groups = group_centre.shape[1]
    bounds = np.searchsorted(demos, np.arange(n_demos + 1))
    cut = np.empty((n_pairs, n_groups), dtype=bool)
    for j in range(n_demos):
        rows = slice(bounds[j], bounds[j + 1])
        if bounds[j] == bounds[j + 1]:
            continue
        # Elementwise, one axis at a time: tiny matrix products would pay BLAS's
        # threading on every call.
        centre = group_centre[j]  # (ng, D)
        offset = t[rows, 0, None] * centre[None, :, 0]
        for axis in range(1, dim):
            offset += t[rows, axis, None] * centre[None, :, axis]
        offset -= level[rows, None]
        np.less_equal(np.abs(offset, out=offset), group_reach[j][None, :], out=cut[rows])
    pair, group = np.divmod(np.flatnonzero(cut), n_groups)  # sorted by pair
    first_block, last_block = seg_lo // BLOCK, np.minimum(seg_hi // BLOCK, n_blocks - 1)
    overlaps = (group * GROUP <= last_block[pair]) & ((group + 1) * GROUP > first_block[pair])
    pair, group = pair[overlaps], group[overlaps]
    # Every block of a cut group that lies in the pair's window.
    pair = np.repeat(pair, GROUP)
    block = (group[:, None] * GROUP + np.arange(GROUP)[None, :]).ravel()
    inside = (block >= first_block[pair]) & (block <= last_block[pair])
    pair, block = pair[inside], block[inside]
    key = demos[pair] * n_blocks + block
    # Per axis from contiguous columns: no (entries, D) gathers, no strided reads.
    centre_columns = np.ascontiguousarray(balls[0].reshape(-1, dim).T)
    normal_columns = np.ascontiguousarray(t.T)
    ball_offset = np.take(normal_columns[0], pair) * np.take(centre_columns[0], key)
    for axis in range(1, dim):
        ball_offset += np.take(normal_columns[axis], pair) * np.take(centre_columns[axis], key)
    ball_offset -= np.take(level, pair)
    hit = np.abs(ball_offset) <= np.take(balls[1].ravel(), key)
    pair, block = pair[hit], block[hit]

    items = block_items(blocks)
    per_demo = items.shape[0] // n_demos
    none = np.iinfo(np.int64).max
    best = np.full(n_pairs, none, dtype=np.int64)
    step = max(1, SEARCH_CHUNK // ((BLOCK + 1) * dim))
    for first in range(0, pair.size, step):
        p, b = pair[first : first + step], block[first : first + step]
        x = np.take(items, demos[p] * per_demo + b, axis=0)  # (C, B + 1, D): copies of the cut blocks
        tp = t[p]
        dist = x[:, :, 0] * tp[:, 0, None]
        for axis in range(1, dim):
            dist += x[:, :, axis] * tp[:, axis, None]
        dist -= level[p, None]
        # Sign changes are rare: each one's key, then each pair's least (a pair's blocks
        # are consecutive rows, so its crossings are a consecutive run).
        row, w = np.divmod(np.flatnonzero(sign_changes(dist)), BLOCK)
        seg = b[row] * BLOCK + w
        owner = p[row]
        inside = (seg >= seg_lo[owner]) & (seg <= seg_hi[owner])  # past N - 2 is outside
        seg, owner = seg[inside], owner[inside]
        if owner.size:
            starts = np.flatnonzero(np.concatenate([[True], owner[1:] != owner[:-1]]))
            key = np.minimum.reduceat(_segment_key(seg, sections[owner]), starts)
            owner = owner[starts]
            best[owner] = np.minimum(best[owner], key)
    found = best != none
    points = np.zeros((n_pairs, dim))
    index = np.full(n_pairs, np.nan)
    if found.any():
        f = np.flatnonzero(found)
        s = _segment_of_key(best[f], sections[f])
        row = demos[f] * (per_demo * BLOCK) + s
        samples = block_rows(blocks)
        x0 = np.take(samples, row, axis=0)
        x1 = np.take(samples, row + 1, axis=0)
        d0 = np.einsum("pd,pd->p", x0, t[f]) - level[f]
        d1 = np.einsum("pd,pd->p", x1, t[f]) - level[f]
        denom = d0 - d1
        alpha = np.clip(np.divide(d0, denom, out=np.zeros_like(d0), where=denom != 0.0), 0.0, 1.0)
        points[f] = x0 + alpha[:, None] * (x1 - x0)
        index[f] = s + alpha
    return points, found, index


def plane_crossings(
    aligned: FloatArray, centres: FloatArray, tangents: FloatArray, window: float = 1.0 / 3.0,
    monotone: bool = True,
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
    monotone : bool
        Choose a folding demo's crossings again in its own order (:func:`located_crossings`).

    Returns
    -------
    crossings : array, shape (N, n, D)
        Points in the planes (t_i . (x - c_i) = 0 up to rounding).
    """
    return located_crossings(aligned, centres, tangents, window, monotone)[0]


def located_crossings(
    aligned: FloatArray,
    centres: FloatArray,
    tangents: FloatArray,
    window: float = 1.0 / 3.0,
    monotone: bool = True,
) -> tuple[FloatArray, FloatArray]:
    """:func:`plane_crossings` and where along each demo they lie.

    ``monotone``: a demo whose nearest-in-index crossings step back along it (a path that
    folds back over itself) has them chosen again in its own order
    (:func:`ordered_crossings`); False keeps the nearest-in-index rule alone.

    Returns
    -------
    crossings : array, shape (N, n, D)
    index : array, shape (N, n)
        Fractional sample index in demo j of its crossing with plane i; NaN where the demo
        contributes its nearest sample instead (no crossing taken).
    """
    n_demos, n_samples, _ = aligned.shape
    wide = max(NEAR_WINDOW + 1, round(window * n_samples))
    plane = np.einsum("nd,nd->n", centres, tangents)
    # Most pairs cross within a few samples of their own index: a dense search there,
    # a few demos at a time so memory stays bounded for large N.
    points, found, reference, index = in_row_blocks(
        lambda rows: _near_crossings(aligned[rows], centres, tangents, plane, min(NEAR_WINDOW, wide)),
        n_demos,
        n_samples * (2 * NEAR_WINDOW + 1),
        WORK_CHUNK,
    )
    demos, sections = np.nonzero(~found)  # sorted by demo
    if demos.size:
        # The rest (demos ahead of or behind the mean's phase, common in raw logs) by the
        # block search: its cost does not grow with how far the crossing lies.
        blocks = block_views(aligned)
        lo, hi = block_boxes(blocks)
        centre, radius = box_balls(lo, hi)
        group_centre, group_radius = box_balls(*grouped_boxes(lo, hi))
        # Rounding slack: d is computed per sample, the test per ball; |t.c_i| and |t.m| are
        # bounded by the largest norms of the directrix and of the ball centres.
        bound = float(np.linalg.norm(centres, axis=1).max() + np.abs(blocks).max() * np.sqrt(blocks.shape[3]))
        balls = (centre, radius * (1.0 + 1e-9) + 1e-12 * (radius + bound))
        groups = (group_centre, group_radius * (1.0 + 1e-9) + 1e-12 * (group_radius + bound))
        far_points, far_found, far_index = in_row_blocks(
            lambda rows: _far_crossings(
                blocks, tangents, plane, sections[rows], demos[rows], wide, balls, groups
            ),
            demos.size,
            2 * group_centre.shape[1] + 4 * GROUP,
            FAR_CHUNK,
        )
        # A crossing found far away is taken only if it is nearer c_i than the demo's own
        # nearby sample: a demo lagging behind the mean qualifies, the far side of a loop
        # (or of a helix turn) met by a demo that starts ahead of the first plane does not.
        # Flat (demo, section) rows: one gather or scatter each instead of a 2-D fancy index.
        flat = demos * n_samples + sections
        offset = far_points - np.take(centres, sections, axis=0)
        near_enough = np.linalg.norm(offset, axis=1) <= np.take(reference, flat)
        take = np.flatnonzero(far_found & near_enough)
        rows = np.take(flat, take)
        points.reshape(-1, points.shape[2])[rows] = np.take(far_points, take, axis=0)
        index.reshape(-1)[rows] = np.take(far_index, take)
    if monotone:
        for j in np.flatnonzero(steps_back(index)):
            points[j], index[j] = ordered_crossings(aligned[j], tangents, plane, wide, points[j], index[j])
    return points.transpose(1, 0, 2).copy(), index.T.copy()


def steps_back(index: FloatArray, tolerance: float = FOLD_TOLERANCE) -> BoolArray:
    """Whether each demo's crossings (n, N: fractional sample index per section, NaN where
    none was taken) ever lie more than ``tolerance`` samples before an earlier section's."""
    reached = np.fmax.accumulate(np.where(np.isfinite(index), index, -np.inf), axis=1)
    behind = index[:, 1:] < reached[:, :-1] - tolerance
    return np.asarray(behind.any(axis=1))


def ordered_crossings(
    demo: FloatArray, tangents: FloatArray, plane: FloatArray, half_width: int,
    points: FloatArray, index: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """One demo's crossings of every plane, in the demo's own order.

    Where the path folds back over itself (pressing: down, up and down again; a wipe back
    and forth) a plane is met on several passes, and the pass nearest in index to one
    section can lie after the pass chosen for the next: the sections would then mix the
    demo's passes. The longest run of the nearest-in-index crossings that is in order (on
    non-decreasing segments of the demo) is kept; the sections between two kept ones are
    chosen again among their crossings between those two (:func:`monotone_crossings`).

    Parameters
    ----------
    demo : array, shape (N, D)
        The aligned demonstration.
    tangents : array, shape (N, D)
    plane : array, shape (N,)
        t_i . c_i.
    half_width : int
        h: crossings farther than h samples from their section are not candidates.
    points : array, shape (N, D)
        The nearest-in-index crossings (or nearest samples, projected).
    index : array, shape (N,)
        Their fractional sample indices (NaN for a nearest sample).

    Returns
    -------
    points, index : arrays, shapes (N, D) and (N,)
    """
    n = demo.shape[0]
    met = np.flatnonzero(np.isfinite(index))
    kept = met[_longest_in_order(np.floor(index[met]).astype(np.int64))]
    points, index = points.copy(), index.copy()
    good = np.zeros(n, dtype=bool)
    good[kept] = True
    bad = np.isfinite(index) & ~good
    # Runs of sections between consecutive kept ones (and before the first / after the
    # last) that hold a crossing out of order.
    edges = np.concatenate([[-1], kept, [n]])
    for k0, k1 in pairwise(edges.tolist()):
        if k1 - k0 < 2 or not bad[k0 + 1 : k1].any():
            continue
        lo = int(np.floor(index[k0])) if k0 >= 0 else max(0, k0 + 1 - half_width)
        hi = int(np.ceil(index[k1])) if k1 < n else min(n - 1, k1 - 1 + half_width + 1)
        rows = slice(k0 + 1, k1)
        points[rows], index[rows] = monotone_crossings(demo, tangents, plane, half_width, rows, lo, hi)
    return points, index


def _longest_in_order(keys: IntArray) -> IntArray:
    """Positions of a longest non-decreasing subsequence of ``keys`` (patience sorting)."""
    tails: list[int] = []  # smallest tail key of a run of each length
    tail_at: list[int] = []  # its position
    parent = [-1] * keys.size
    for position, key in enumerate(keys.tolist()):
        length = bisect_right(tails, key)
        parent[position] = tail_at[length - 1] if length else -1
        if length == len(tails):
            tails.append(key)
            tail_at.append(position)
        else:
            tails[length], tail_at[length] = key, position
    out = []
    c = tail_at[-1] if tail_at else -1
    while c >= 0:
        out.append(c)
        c = parent[c]
    return np.asarray(out[::-1], dtype=np.int64)


def monotone_crossings(
    demo: FloatArray, tangents: FloatArray, plane: FloatArray, half_width: int,
    sections: slice, lo: int, hi: int,
) -> tuple[FloatArray, FloatArray]:
    """Crossings of the planes of ``sections`` by the demo's samples lo .. hi, in order.

    Every crossing within ``half_width`` samples of its section is a candidate with weight
    ``w = 1 - |k - i| / (2 (h + 1))`` (k its fractional sample index, i the section's), and
    the chain of candidates with increasing sections on non-decreasing segments of the demo
    (crossings within one segment may come in either order: neighbouring planes fan out
    where the directrix bends) of largest total weight is taken: as many sections as
    possible met in order, each as near its own index as the order allows. A section left
    out contributes the demo's sample nearest its plane between the crossings of the
    sections before and after it (within its window), projected onto the plane.

    Returns
    -------
    points : array, shape (S, D)
    index : array, shape (S,)
        Fractional sample index of each crossing, NaN where the nearest sample was taken.
    """
    h = half_width
    first, last = int(sections.start), int(sections.stop)
    m = last - first
    dist = tangents[first:last] @ demo[lo : hi + 1].T - plane[first:last, None]  # (S, C)
    changes = sign_changes(dist)  # segment lo + w: samples lo + w, lo + w + 1
    ids = np.arange(first, last)
    changes &= np.abs(np.arange(lo, hi)[None, :] + 0.5 - ids[:, None]) <= h
    r, w = np.nonzero(changes)
    sec, seg = r, lo + w
    d0, d1 = dist[r, w], dist[r, w + 1]
    denom = d0 - d1
    alpha = np.clip(np.divide(d0, denom, out=np.zeros_like(d0), where=denom != 0.0), 0.0, 1.0)
    at = seg + alpha
    weight = 1.0 - np.abs(at - ids[sec]) / (2.0 * (h + 1))
    chosen = _heaviest_chain(sec, seg - lo, weight, hi - lo + 1)
    index = np.full(m, np.nan)
    points = np.empty((m, demo.shape[1]))
    index[sec[chosen]] = at[chosen]
    points[sec[chosen]] = demo[seg[chosen]] + alpha[chosen, None] * (demo[seg[chosen] + 1] - demo[seg[chosen]])
    # Sections left out: the sample nearest the plane between the crossings of the sections
    # met before and after (the range's ends beyond them), within the section's window.
    left = np.flatnonzero(~np.isfinite(index))
    if left.size:
        met = np.flatnonzero(np.isfinite(index))
        k = np.searchsorted(met, left)
        before = np.full(left.size, float(lo))
        after = np.full(left.size, float(hi))
        if met.size:
            before = np.where(k > 0, np.floor(index[met[np.maximum(k - 1, 0)]]), before)
            after = np.where(k < met.size, np.ceil(index[met[np.minimum(k, met.size - 1)]]), after)
        sample = np.arange(lo, hi + 1)[None, :]
        allowed = (sample >= before[:, None]) & (sample <= after[:, None])
        allowed &= np.abs(sample - ids[left, None]) <= h
        allowed[~allowed.any(axis=1)] = True
        pick = np.argmin(np.where(allowed, np.abs(dist[left]), np.inf), axis=1)
        x = demo[lo + pick]
        points[left] = x - dist[left, pick][:, None] * tangents[first + left]
    return points, index


def _heaviest_chain(sec: IntArray, seg: IntArray, weight: FloatArray, n: int) -> IntArray:
    """Candidates (sorted by section) of the heaviest chain with increasing section and
    non-decreasing segment ``seg`` (< n); a Fenwick tree of the best chain weight by segment.

    Plain lists: the loop touches one entry at a time, where numpy scalars cost several times
    more.
    """
    if sec.size == 0:
        return np.zeros(0, dtype=np.int64)
    size = n + 1
    tree = [0.0] * (size + 1)
    arg = [-1] * (size + 1)
    slots = [int(v) + 1 for v in seg.tolist()]
    weights = weight.tolist()
    best = [0.0] * len(slots)
    parent = [-1] * len(slots)
    bounds = np.flatnonzero(np.concatenate([[True], sec[1:] != sec[:-1], [True]])).tolist()
    for a, b in pairwise(bounds):
        for c in range(a, b):  # query the sections before this one
            q, value, who = slots[c], 0.0, -1
            while q > 0:
                if tree[q] > value:
                    value, who = tree[q], arg[q]
                q -= q & -q
            best[c], parent[c] = value + weights[c], who
        for c in range(a, b):  # then add this section's candidates
            q, value = slots[c], best[c]
            while q <= size:
                if value > tree[q]:
                    tree[q], arg[q] = value, c
                q += q & -q
    chain = []
    c = int(np.argmax(best)) if best else -1
    while c >= 0:
        chain.append(c)
        c = parent[c]
    return np.asarray(chain[::-1], dtype=np.int64)


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
    # One product per coordinate axis: a batched contraction over D = 2, 3 costs more.
    offsets = points - centres[:, None, :]
    coords = offsets[:, :, None, 0] * basis[:, None, :, 0]
    for axis in range(1, points.shape[2]):
        coords += offsets[:, :, None, axis] * basis[:, None, :, axis]
    return coords
