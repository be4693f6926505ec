"""The glitch test of the preparation stage (step 4 of :mod:`canal_core.preprocess`).

A glitch is a reading far off the path: an IK or TF glitch, a dropout to zeros. A polling
logger repeats it (one sample once repeats are gone), a resampler spreads it over ramps (a
few samples). The rule: an excursion of m = 1..``MAX_GLITCH_RUN`` samples between samples a
and b = a + m + 1 holds a glitch at interior sample k when

    |x_k - (x_a + x_b) / 2| > CHORD_FACTOR x |x_b - x_a|  and
    |x_k - (x_a + x_b) / 2| > SPIKE_FACTOR x (m + 1) / 2 x (local step),

the local step being the median of the 5 steps around a single sample, of the 17 steps around
a longer excursion (a resampled glitch brings its own ramps), and

    |x_k - (x_a + x_b) / 2| > GLITCH_FLOOR x (robust path length of the demonstration).

Smooth motion cannot pass the first two: for monotone sampling of a curve that distance is
at most half the chord, and at a genuine reversal (out and back along a line) about one step
per sample of the excursion. Where the arm moves a fraction of a millimetre per sample,
though, a genuine dip of a millimetre is many steps deep and off its chord; the floor keeps
every excursion too small to matter (see ``GLITCH_FLOOR``), so the canal encloses it rather
than leaving it out. An end sample has no sample beyond it; it is a glitch when its step
dwarfs both the next step and the local step, and exceeds the floor. The test runs again on
what is left (``GLITCH_PASSES`` passes), which catches the partial ramps around a removed
glitch; every pass keeps the floor of the whole demonstration.

The rule is written once, over *parts*: demonstrations (or stretches of one) concatenated,
each window and each local median kept inside its own part, so a fit tests all its demos in
one vectorised pass and each verdict is the one the part gets alone, bit for bit. One
demonstration is one part: :func:`glitch_mask` is :func:`glitch_masks` of a single part, and
a lone part skips the bookkeeping that only several parts need (a 20,000-sample demo pays
nothing for the batching).
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import as_strided

from .validation import FloatArray, IntArray

#: A sample is a glitch when it deviates from its neighbours' midpoint by this many steps...
SPIKE_FACTOR = 4.0
#: ... and by this many times its neighbours' distance (monotone sampling: at most 1/2).
CHORD_FACTOR = 2.0
#: Half-width, in samples, of the window whose median step is the local step size.
SPIKE_WINDOW = 2
#: Longest excursion (in samples) caught as a glitch: resampling spreads one glitch reading
#: over its ramps.
MAX_GLITCH_RUN = 6
#: Glitch detection passes (each on what the previous left).
GLITCH_PASSES = 3
#: Steps on each side of a longer excursion whose median is the local step there.
GLITCH_SCALE_WINDOW = 5
#: Samples on each side of a removed glitch whose verdict the next pass can change: a
#: window reaches 6 samples, a local median 8 steps beyond the window's centre.
GLITCH_REACH = 16
#: Smallest deviation dropped, as a fraction of the demonstration's robust path length: an
#: excursion nearer the path than this is kept whatever its steps. Kept, it widens the canal
#: by at most its deviation and moves the demo's arc-length phase by at most twice this
#: fraction; dropped, it may lie outside the canal fitted without it. Slow kinesthetic motion (a fraction of a millimetre per sample) has
#: genuine dips of 1-2 mm, 0.2 % of a 0.5 m path; an IK/TF glitch or a dropout is a sizeable
#: share of the path.
GLITCH_FLOOR = 0.01
#: Chords of the robust path length: at most this many, so jitter does not inflate it.
PATH_CHORDS = 256
#: Fewest samples a part needs for the test: fewer are never flagged.
MIN_TESTED = 5
#: Shortest part :func:`spike_masks` tests together with others: from here on every window
#: has its full length (shorter parts clip theirs and go one at a time).
BATCHED_SPIKE_MIN = 2 * GLITCH_SCALE_WINDOW + MAX_GLITCH_RUN + 2
#: Most rows tested in one batch: its (runs x rows) temporaries stay below glibc's mmap
#: threshold (128 kB), so they come from reused heap memory; larger ones were mapped fresh
#: and page-faulted on every fit, which cost more than the calls the batch saves.
SPIKE_BATCH_ROWS = 2048


def step_lengths(positions: FloatArray) -> FloatArray:
    """Distances between consecutive samples.

    Parameters
    ----------
    positions : array, shape (T, D)

    Returns
    -------
    steps : array, shape (T - 1,)
        ``|x_{k+1} - x_k|`` (einsum: one pass, no temporaries of squares).
    """
    diffs = positions[1:] - positions[:-1]
    return np.asarray(np.sqrt(np.einsum("ij,ij->i", diffs, diffs)), dtype=np.float64)


def robust_path_length(positions: FloatArray) -> float:
    """Path length measured on at most ``PATH_CHORDS`` chords (jitter does not add up).

    Parameters
    ----------
    positions : array, shape (T, D)
    """
    stride = max(1, -(-(positions.shape[0] - 1) // PATH_CHORDS))
    coarse = positions[::stride]
    if (positions.shape[0] - 1) % stride:
        coarse = np.vstack([coarse, positions[-1:]])
    return float(step_lengths(coarse).sum())


def glitch_floor(positions: FloatArray) -> float:
    """Smallest deviation the glitch rule drops in this demonstration.

    Parameters
    ----------
    positions : array, shape (T, D)
        The whole demonstration (its stretches re-tested later keep this floor).

    Returns
    -------
    floor : float
        ``GLITCH_FLOOR`` x its robust path length.
    """
    return GLITCH_FLOOR * robust_path_length(positions)


def _local_medians(steps: FloatArray, width: int, at: IntArray, first: IntArray, last: IntArray) -> FloatArray:
    """Median of the ``width`` steps centred on step ``at``, the window shifted (not cut)
    to stay inside its own part.

    Parameters
    ----------
    steps : array, shape (n - 1,)
        Steps of the concatenated parts (those across two parts are never read).
    width : int
        At most the steps of the shortest part.
    at : array of int, shape (A,)
        Centre of each window (a row index).
    first, last : array of int, shape (A,)
        First and last row of the part of each ``at``.

    Returns
    -------
    medians : array, shape (A,)
        The upper median when ``width`` is even.
    """
    # A part's steps are first .. last - 1: the window starts in [first, last - width].
    start = np.minimum(np.maximum(at - width // 2, first), last - width)
    windows = steps[start[:, None] + np.arange(width)[None, :]]
    return np.asarray(np.partition(windows, width // 2, axis=1)[:, width // 2], dtype=np.float64)


def _chords_and_spans(positions: FloatArray, arc: FloatArray,
                      longest: int) -> tuple[FloatArray, FloatArray]:
    """Straight distance and path length from a to b = a + m + 1 of every excursion.

    Parameters
    ----------
    positions : array, shape (n, D)
    arc : array, shape (n,)
        Arc length at each sample.
    longest : int
        Most interior samples m of an excursion.

    Returns
    -------
    chords, spans : array, shape (longest x (n - 2),)
        At flat index (m - 1) x (n - 2) + a; NaN where b lies past the end (a NaN never
        passes a test).
    """
    n, dim = positions.shape
    coords = np.ascontiguousarray(positions.T)  # (D, n): one contiguous row per axis
    # Every excursion length m at once: row m - 1 pairs each a with b = a + m + 1, read
    # through a strided view of copies padded with NaN past the end; the long axis last
    # keeps numpy's inner loops long, and one axis at a time needs no (D, runs, n) temporary.
    padded = np.full((dim, n + longest), np.nan)
    padded[:, :n] = coords
    arc_padded = np.full(n + longest, np.nan)
    arc_padded[:n] = arc
    step_bytes = padded.strides[1]
    window_ends = as_strided(padded[:, 2:], shape=(dim, longest, n - 2),
                             strides=(padded.strides[0], step_bytes, step_bytes), writeable=False)
    chord_axis = window_ends[0] - coords[0, None, : n - 2]
    square = chord_axis * chord_axis
    for axis in range(1, dim):
        np.subtract(window_ends[axis], coords[axis, None, : n - 2], out=chord_axis)
        square += chord_axis * chord_axis
    chords = np.sqrt(square, out=square).reshape(-1)
    arc_ends = as_strided(arc_padded[2:], shape=(longest, n - 2), strides=(step_bytes, step_bytes),
                          writeable=False)
    spans = (arc_ends - arc[None, : n - 2]).reshape(-1)
    return chords, spans


def _excursion_glitches(positions: FloatArray, steps: FloatArray, row_first: IntArray, row_last: IntArray,
                        row_floor: FloatArray, hit: IntArray, chords: FloatArray, spans: FloatArray,
                        width: int, wide: int) -> IntArray:
    """Rows of the glitch samples inside the excursions left by the window-level test.

    Parameters
    ----------
    positions : array, shape (n, D)
        The parts concatenated.
    steps : array, shape (n - 1,)
    row_first, row_last : array of int, shape (n,)
        First and last row of each row's part.
    row_floor : array, shape (n,)
        The glitch floor of each row's part.
    hit : array of int, shape (E,)
        Flat indices (m - 1) x (n - 2) + a of the excursions of m interior samples from
        sample a to sample b = a + m + 1 left to test, b inside a's part.
    chords, spans : array, shape (runs x (n - 2),)
        Straight distance and path length from a to b of every (m, a).
    width, wide : int
        Median windows of the local step around a single sample, around a longer excursion.

    Returns
    -------
    rows : array of int
        Interior samples a + k (k = 1..m) farther than ``CHORD_FACTOR`` x chord,
        ``SPIKE_FACTOR`` x (m + 1) / 2 x the local step and the part's floor from the
        chord's midpoint.
    """
    n = positions.shape[0]
    run_index, a = np.divmod(hit, n - 2)
    m = run_index + 1
    chord, span = chords[hit], spans[hit]
    b = a + m + 1
    single = m == 1
    centre = np.where(single, a + 1, (a + b) // 2)
    # Windows share centres (a + 1, a + 2, ... for several m): one median per centre.
    step = np.empty(a.size)
    for rows, window in ((single, width), (~single, wide)):
        if rows.any():
            needed = np.zeros(n, dtype=bool)
            needed[centre[rows]] = True
            at = np.flatnonzero(needed)
            median_at = np.empty(n)
            median_at[at] = _local_medians(steps, window, at, row_first[at], row_last[at])
            step[rows] = median_at[centre[rows]]
    limit = np.maximum(SPIKE_FACTOR * 0.5 * (m + 1) * step, row_floor[a])
    # Half the path (with rounding slack) bounds every interior sample's deviation.
    can = np.flatnonzero(0.5 * (1.0 + 1e-9) * span > limit)
    if not can.size:
        return np.zeros(0, dtype=np.intp)
    a, m, b, chord, limit = a[can], m[can], b[can], chord[can], limit[can]
    # Each interior sample a + k (k = 1..m) on its own.
    owner = np.repeat(np.arange(a.size), m)
    k = np.arange(owner.size) - np.repeat(np.cumsum(m) - m, m) + 1
    mid = 0.5 * (np.take(positions, a, axis=0) + np.take(positions, b, axis=0))
    off = np.take(positions, a[owner] + k, axis=0) - np.take(mid, owner, axis=0)
    dev = np.sqrt(np.einsum("ij,ij->i", off, off))
    glitch = (dev > CHORD_FACTOR * chord[owner]) & (dev > limit[owner])
    return np.asarray((a[owner] + k)[glitch], dtype=np.intp)


def _spikes(positions: FloatArray, starts: IntArray, ends: IntArray, floors: FloatArray) -> np.ndarray:
    """One pass of the glitch rule (see the module docstring) over concatenated parts.

    The whole-window tests come first, both from |x_k - (x_a + x_b) / 2| <= (path length
    from a to b) / 2: that half length must exceed ``CHORD_FACTOR`` x |x_b - x_a| (tested on
    every window) and then the window's step limit (tested where the first one held: jitter
    of a standing arm passes the first, rarely the second). Only the windows left are tested
    sample by sample.

    Parameters
    ----------
    positions : array, shape (n, D)
        The parts concatenated.
    starts, ends : array of int, shape (P,)
        First and last row of each part; every part has at least ``MIN_TESTED`` rows, and
        all of them ``BATCHED_SPIKE_MIN`` when there are several (windows share one width).
    floors : array, shape (P,)
        The glitch floor of each part (:func:`glitch_floor` of its whole demonstration).

    Returns
    -------
    spike : array of bool, shape (n,)
        For each part, the verdicts it gets alone.
    """
    total = positions.shape[0]
    steps = step_lengths(positions)  # the steps across two parts are never read
    arc = np.empty(total)
    for first, last in zip(starts.tolist(), ends.tolist(), strict=True):
        arc[first] = 0.0
        np.cumsum(steps[first:last], out=arc[first + 1 : last + 1])
    lone = starts.size == 1
    # Several parts all have BATCHED_SPIKE_MIN rows; a lone part may have fewer, and then
    # clips the excursions and the median windows to what it has.
    fewest_steps = int(ends[0] - starts[0]) if lone else BATCHED_SPIKE_MIN - 1
    longest = min(MAX_GLITCH_RUN, fewest_steps - 1)
    width = min(2 * SPIKE_WINDOW + 1, fewest_steps)
    wide = min(2 * GLITCH_SCALE_WINDOW + MAX_GLITCH_RUN + 1, fewest_steps)
    chords, spans = _chords_and_spans(positions, arc, longest)
    candidate = spans > 2.0 * CHORD_FACTOR * chords
    if lone:
        # A lone part: windows past its end read the NaN padding and fail the test anyway,
        # and its bounds need not be copied for every row.
        row_first, row_last = np.broadcast_to(starts, (total,)), np.broadcast_to(ends, (total,))
        row_floor = np.broadcast_to(floors, (total,))
    else:
        sizes = ends - starts + 1
        row_first, row_last = np.repeat(starts, sizes), np.repeat(ends, sizes)
        row_floor = np.repeat(floors, sizes)
        # Window (a, m) ends at b = a + m + 1, which must lie in a's part.
        b = np.arange(2, longest + 2)[:, None] + np.arange(total - 2)[None, :]
        candidate &= (b <= row_last[None, : total - 2]).reshape(-1)
    hit = np.flatnonzero(candidate)
    spike = np.zeros(total, dtype=bool)
    if hit.size:
        spike[_excursion_glitches(positions, steps, row_first, row_last, row_floor, hit, chords, spans,
                                    width, wide)] = True
    # An end sample is a glitch when its step dwarfs the next one and the local steps, and
    # exceeds the floor.
    head_scale = _local_medians(steps, width, starts + 1, starts, ends)
    tail_scale = _local_medians(steps, width, ends - 1, starts, ends)
    head, tail = steps[starts], steps[ends - 1]
    spike[starts] |= (head > SPIKE_FACTOR * np.maximum(steps[starts + 1], head_scale) * 2.0) & (head > floors)
    spike[ends] |= (tail > SPIKE_FACTOR * np.maximum(steps[ends - 2], tail_scale) * 2.0) & (tail > floors)
    return spike


def spike_mask(positions: FloatArray, floor: float | None = None) -> np.ndarray:
    """One pass of the glitch rule over one demonstration.

    Parameters
    ----------
    positions : array, shape (T, D)
    floor : float, optional
        Smallest deviation dropped; :func:`glitch_floor` of ``positions`` when None (a
        stretch of a longer demonstration passes that demonstration's).

    Returns
    -------
    spike : array of bool, shape (T,)
        True for glitch samples; none when T < ``MIN_TESTED``.
    """
    n = positions.shape[0]
    if n < MIN_TESTED:
        return np.zeros(n, dtype=bool)
    if floor is None:
        floor = glitch_floor(positions)
    return _spikes(positions, np.array([0]), np.array([n - 1]), np.array([floor]))


def spike_masks(parts: list[FloatArray], floors: list[float] | None = None) -> list[np.ndarray]:
    """:func:`spike_mask` of several demonstrations (or stretches), batched.

    Parts are grouped in order into batches of at most ``SPIKE_BATCH_ROWS`` rows (a longer
    part makes a batch of its own) and each batch is one :func:`_spikes` pass. Parts shorter
    than ``BATCHED_SPIKE_MIN`` clip their windows, so they go one at a time.

    Parameters
    ----------
    parts : list of array, each shape (T_j, D)
    floors : list of float, optional
        Smallest deviation dropped in each part; :func:`glitch_floor` of each when None.

    Returns
    -------
    spikes : list of array of bool, each shape (T_j,)
    """
    if floors is None:
        floors = [glitch_floor(p) for p in parts]
    out: list[np.ndarray] = [np.zeros(0, dtype=bool)] * len(parts)
    group: list[int] = []
    rows = 0
    for k, p in enumerate(parts):
        if p.shape[0] < BATCHED_SPIKE_MIN:
            out[k] = spike_mask(p, floors[k])
            continue
        if group and rows + p.shape[0] > SPIKE_BATCH_ROWS:
            _batch_into(parts, floors, group, out)
            group, rows = [], 0
        group.append(k)
        rows += p.shape[0]
    if group:
        _batch_into(parts, floors, group, out)
    return out


def _batch_into(parts: list[FloatArray], floors: list[float], group: list[int], out: list[np.ndarray]) -> None:
    """One :func:`_spikes` pass over the parts listed in ``group``, written to ``out``."""
    sizes = np.array([parts[k].shape[0] for k in group])
    starts = np.cumsum(sizes) - sizes
    # A lone part (a long demonstration) is tested in place, not copied.
    positions = parts[group[0]] if len(group) == 1 else np.concatenate([parts[k] for k in group])
    spike = _spikes(positions, starts, starts + sizes - 1, np.array([floors[k] for k in group]))
    for k, first, size in zip(group, starts.tolist(), sizes.tolist(), strict=True):
        out[k] = spike[first : first + size]


def _stretches_to_retest(left: IntArray, removed: IntArray) -> list[tuple[int, int, int, int]]:
    """Where the next pass can change a verdict, after ``removed`` rows were dropped.

    A sample's verdict depends only on the samples within ``GLITCH_REACH`` of it (and on
    whether an end of the part lies there), so only the stretches around what was removed
    are re-tested, each with that much context on both sides: the same answer as a whole
    pass, at the cost of a few short ones.

    Parameters
    ----------
    left : array of int, shape (M,)
        Rows still in, increasing.
    removed : array of int, shape (R,)
        Rows just dropped, increasing.

    Returns
    -------
    stretches : list of (first, last, s0, s1)
        Positions ``first .. last`` of ``left`` to re-test, on ``left[s0:s1]``.
    """
    m = left.size
    if m <= 4 * GLITCH_REACH:
        return [(0, m - 1, 0, m)]  # short: one whole pass costs no more
    # Where each removed sample was, in the new numbering; the stretches it can affect.
    at = np.searchsorted(left, removed)
    lo = np.maximum(at - GLITCH_REACH, 0)
    hi = np.minimum(at + GLITCH_REACH, m - 1)
    # Merge overlapping stretches (they are sorted by their start).
    reach = np.maximum.accumulate(hi)
    start = np.flatnonzero(np.concatenate([[True], lo[1:] > reach[:-1]]))
    last = reach[np.concatenate([start[1:] - 1, [hi.size - 1]])]
    return [(f, la, max(0, f - GLITCH_REACH), min(m, la + GLITCH_REACH + 1))
            for f, la in zip(lo[start].tolist(), last.tolist(), strict=True)]


def glitch_masks(parts: list[FloatArray]) -> list[np.ndarray]:
    """The glitch test of several demonstrations: :func:`spike_masks` repeated on what is left.

    At most ``GLITCH_PASSES`` passes: once a glitch's core is gone, the partial ramps a
    resampler left around it stand out in turn. Each pass tests all the demonstrations (and
    all the stretches the previous pass left to re-test) in one :func:`spike_masks` call.

    Parameters
    ----------
    parts : list of array, each shape (T_j, D)

    Returns
    -------
    glitches : list of array of bool, each shape (T_j,)
        True for the samples to drop.
    """
    glitch = [np.zeros(p.shape[0], dtype=bool) for p in parts]
    left = [np.arange(p.shape[0]) for p in parts]
    # Each demonstration's floor, kept for every pass and every stretch re-tested.
    floors = [glitch_floor(p) for p in parts]
    found = spike_masks(parts, floors)
    active = list(range(len(parts)))
    for _ in range(GLITCH_PASSES - 1):
        still: list[int] = []
        jobs: list[tuple[int, int, int, int]] = []  # (part, first, last, s0)
        pieces: list[FloatArray] = []
        piece_floors: list[float] = []
        for j in active:
            if not found[j].any():
                continue  # final: nothing was removed
            still.append(j)
            removed = left[j][found[j]]
            glitch[j][removed] = True
            left[j] = np.flatnonzero(~glitch[j])
            found[j] = np.zeros(left[j].size, dtype=bool)
            for first, last, s0, s1 in _stretches_to_retest(left[j], removed):
                jobs.append((j, first, last, s0))
                pieces.append(np.take(parts[j], left[j][s0:s1], axis=0))
                piece_floors.append(floors[j])
        for (j, first, last, s0), verdict in zip(jobs, spike_masks(pieces, piece_floors), strict=True):
            found[j][first : last + 1] = verdict[first - s0 : last + 1 - s0]
        active = still
    for j in active:
        if found[j].any():
            glitch[j][left[j][found[j]]] = True
    return glitch


def glitch_mask(positions: FloatArray) -> np.ndarray:
    """The glitch test of one demonstration (:func:`glitch_masks` of one part).

    Parameters
    ----------
    positions : array, shape (T, D)

    Returns
    -------
    glitch : array of bool, shape (T,)
        True for the samples to drop.
    """
    return glitch_masks([positions])[0]
