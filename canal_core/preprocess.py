"""Turn what robots record into what the method needs (one stage, before alignment).

Raw kinesthetic logs are not curves: polling recorders repeat samples (65-75 % of rows on
some arms), filters and resamplers leave steps at rounding level (1e-17 .. 1e-7), the arm
stands still for seconds at both ends, clocks stamp two samples alike or step back, a
glitch throws one sample far off, and demonstrations of one skill differ in length and rate.
:func:`prepared_demonstration` is the one stage that handles all of it; :func:`canal_core.fit`
and the service's upload validation both call it, so a demonstration that cannot be fitted
is refused when it arrives, naming it.

The stage only *selects* rows, it never invents values: every output row is an input row
(:func:`prepared_rows` gives their indices, e.g. to carry orientations along). In order:

1. **Scale.** Every coordinate must satisfy ``|x| <= MAX_COORDINATE`` (1e15): beyond that,
   squares and products in the fit overflow (1e306 used to end in an HTTP 500). Units from
   nanometres to kilometres fit comfortably; larger values are refused naming the sample.
2. **Time** (when timestamps are given). Timestamps closer than ``TIME_TOLERANCE`` (1e-9) of
   the demo's duration to the previous kept one are duplicates: the first is kept. A sample
   whose timestamp steps back is dropped when removing it (or its predecessor, when that one
   jumped ahead) leaves the neighbours in order; at most ``MAX_TIME_REPAIRS`` (1 %) of the
   samples are repaired so. Anything else (a clock reset, logs glued together) is an
   :class:`InvalidInputError` naming the demo and the sample.
3. **Repeats.** A sample within ``NEAR_DUPLICATE_TOLERANCE`` (1e-6) of the demo's size (its
   robust path length) from the previous sample is a repeat and dropped, unless the slow
   drift since the last kept sample has itself reached that distance (so creeping motion is
   kept at that resolution). With timestamps, the last sample of a repeat run that lasts
   longer than ``PAUSE_INTERVALS`` sampling intervals is kept too: the arm really paused,
   and a time spline must not overshoot across the pause.
4. **Spikes.** An excursion of m = 1..6 samples that leaves the path and comes back is a
   glitch: its interior sample k is dropped when its distance from the midpoint of the
   samples a and b around the excursion exceeds both ``CHORD_FACTOR`` (2) x |x_b - x_a|
   and ``SPIKE_FACTOR`` (4) x (m + 1) / 2 local steps (median of the surrounding steps).
   Real motion cannot: for monotone sampling that distance is at most half the chord, and
   at a genuine reversal about (m + 1) / 2 steps. A glitch repeated by the poller is one
   sample after step 3; a resampled glitch (with its ramps) spans a few. The test runs
   again on what is left (up to 3 passes), which catches the partial ramps around a
   removed glitch. Longer excursions are kept.
5. **Still ends.** Head samples within ``STILL_TOLERANCE`` (1e-3) of the path length from the
   first sample are trimmed, likewise at the tail; one still sample is kept at each end.
6. **Arc-length parameter** (no timestamps). Consecutive kept samples are made at least
   ``NEAR_DUPLICATE_TOLERANCE / 2`` of the path length apart, so the cumulative arc length
   is strictly increasing by construction and its normalisation cannot round two samples
   together (the scipy "x must be strictly increasing" crash).

Then at least ``MIN_POINTS`` samples must remain, else an :class:`InvalidInputError` says
whether the demo never moves (identical points) or only stands still. The demo must also
move by more than ``MIN_RELATIVE_MOTION`` (1e-9) of its coordinates' magnitude: a demo that
only moves at rounding level is refused, not fitted.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.lib.stride_tricks import as_strided

from .bounds import MAX_COORDINATE
from .errors import InvalidInputError
from .validation import MIN_POINTS, FloatArray, IntArray, check_positions

#: Fraction of a demonstration's path length below which a head/tail sample counts as "still".
STILL_TOLERANCE = 1e-3
#: Fraction of the path length below which two consecutive samples are the same sample.
NEAR_DUPLICATE_TOLERANCE = 1e-6
#: Smallest motion accepted, as a fraction of the largest absolute coordinate.
MIN_RELATIVE_MOTION = 1e-9
#: Fraction of the duration below which two timestamps are the same instant.
TIME_TOLERANCE = 1e-9
#: Most out-of-order samples repaired by dropping them, as a fraction of the samples (>= 1).
MAX_TIME_REPAIRS = 0.01
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
#: A repeat run longer than this many median sampling intervals is a pause (see step 3).
PAUSE_INTERVALS = 10.0
#: Chords of the robust path length: at most this many, so jitter does not inflate it.
PATH_CHORDS = 256


@dataclass(frozen=True, eq=False)
class PreparedDemonstration:
    """The result of the preparation stage for one demonstration.

    Attributes
    ----------
    rows : array of int, shape (T',)
        Input rows kept for alignment, increasing.
    positions : array, shape (T', D)
    timestamps : array, shape (T',) or None
        Strictly increasing when given.
    sample_rows : array of int, shape (S,)
        Every input row that is a genuine sample (not a glitch, an out-of-order stamp or an
        exact repeat), still ends included: what the canal must contain.
    sample_phase : array, shape (S,)
        The alignment parameter in [0, 1] of each of those samples (0 before the moving
        part, 1 after it).
    """

    rows: IntArray
    positions: FloatArray
    timestamps: FloatArray | None
    sample_rows: IntArray
    sample_phase: FloatArray


def _step_lengths(positions: FloatArray) -> FloatArray:
    """|x_{k+1} - x_k|, shape (T - 1,) (einsum: one pass, no temporaries of squares)."""
    diffs = positions[1:] - positions[:-1]
    return np.asarray(np.sqrt(np.einsum("ij,ij->i", diffs, diffs)), dtype=np.float64)


def _distances_from(positions: FloatArray, point: FloatArray) -> FloatArray:
    """|x_k - point|, shape (T,)."""
    offsets = positions - point
    return np.asarray(np.sqrt(np.einsum("ij,ij->i", offsets, offsets)), dtype=np.float64)


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
    # Column by column: a reduction over the short last axis costs several times more.
    changed = positions[1:, 0] != positions[:-1, 0]
    for axis in range(1, positions.shape[1]):
        changed |= positions[1:, axis] != positions[:-1, axis]
    keep[1:] = changed
    return keep


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
    return float(_step_lengths(coarse).sum())


def moving_range(positions: FloatArray, tolerance: float = STILL_TOLERANCE) -> slice:
    """Return the slice of samples between the still head and the still tail.

    A head sample is still while it lies within ``tolerance * path_length`` of the first
    sample; likewise a tail sample of the last one. One still sample is kept at each end
    so the demonstration still starts and ends where the robot stood.

    Parameters
    ----------
    positions : array, shape (T, D)
    tolerance : float
        Fraction of the (robust) path length.
    """
    radius = tolerance * robust_path_length(positions)
    if radius == 0.0:
        return slice(0, positions.shape[0])
    away_from_start = _distances_from(positions, positions[0]) > radius
    away_from_end = _distances_from(positions, positions[-1]) > radius
    if not away_from_start.any():
        return slice(0, positions.shape[0])
    first = int(np.argmax(away_from_start))
    last = positions.shape[0] - 1 - int(np.argmax(away_from_end[::-1]))
    return slice(max(first - 1, 0), min(last + 2, positions.shape[0]))


def _time_order_rows(times: FloatArray, field: str) -> IntArray:
    """Rows whose timestamps, in order, strictly increase (step 2 of the module docstring)."""
    n = times.shape[0]
    span = float(times.max() - times.min())
    if not np.isfinite(span):
        raise InvalidInputError(f"expected timestamps of {field} with a finite span, got {span}", field=field)
    if span <= 0.0:
        raise InvalidInputError(
            f"expected timestamps of {field} to advance, got {n} equal values {float(times[0])!r}",
            field=field,
        )
    rows = np.arange(n)
    eps = TIME_TOLERANCE * span
    budget = max(1, int(MAX_TIME_REPAIRS * n))
    repaired = 0
    # Each pass removes equal stamps and isolated out-of-order samples; a second pass only
    # runs for what the first revealed.
    for _ in range(4):
        t = times[rows]
        step = np.diff(t)
        equal = np.flatnonzero(np.abs(step) <= eps) + 1
        if equal.size:
            rows = np.delete(rows, equal)
            continue
        back = np.flatnonzero(step < 0.0) + 1  # sample k steps back from k - 1
        if back.size == 0:
            return rows
        drop = []
        for k in back.tolist():
            before = t[k - 2] if k >= 2 else -np.inf
            after = t[k + 1] if k + 1 < t.size else np.inf
            if t[k - 1] < after:
                drop.append(k)  # k fell behind (a late sample)
            elif before < t[k]:
                drop.append(k - 1)  # k - 1 jumped ahead
            else:
                raise InvalidInputError(
                    f"expected increasing timestamps in {field}, got {float(t[k])!r} after "
                    f"{float(t[k - 1])!r} at sample {int(rows[k])}: time goes back for more "
                    "than one sample (a clock reset or logs joined together)",
                    field=field,
                )
        repaired += len(drop)
        if repaired > budget:
            k = int(back[0])
            raise InvalidInputError(
                f"expected increasing timestamps in {field}, got {repaired} samples out of order "
                f"(first {float(t[k])!r} after {float(t[k - 1])!r} at sample {int(rows[k])}); "
                f"at most {budget} are repaired by dropping them",
                field=field,
            )
        rows = np.delete(rows, np.unique(drop))
    t = times[rows]
    if np.any(np.diff(t) <= eps):
        k = int(np.argmax(np.diff(t) <= eps)) + 1
        raise InvalidInputError(
            f"expected increasing timestamps in {field}, got {float(t[k])!r} after "
            f"{float(t[k - 1])!r} at sample {int(rows[k])}",
            field=field,
        )
    return rows


def _repeat_mask(positions: FloatArray, tolerance: float) -> np.ndarray:
    """Keep a sample when it moved ``tolerance`` from its predecessor or the drift since
    the last kept sample reached it (arc length crossed into a new bin of that width)."""
    steps = _step_lengths(positions)
    keep = np.ones(positions.shape[0], dtype=bool)
    if tolerance <= 0.0:
        keep[1:] = steps > 0.0
        return keep
    bins = np.floor(np.concatenate([[0.0], np.cumsum(steps)]) / tolerance)
    keep[1:] = (steps >= tolerance) | (bins[1:] > bins[:-1])
    return keep


def _local_medians(steps: FloatArray, width: int, at: IntArray) -> FloatArray:
    """Median of the ``width`` steps centred on each sample in ``at`` (clipped at the ends)."""
    start = np.clip(at - width // 2, 0, steps.size - width)
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


def _excursion_glitches(positions: FloatArray, hit: IntArray, chords: FloatArray,
                        spans: FloatArray, width: int, wide: int,
                        medians: Callable[[int, IntArray], FloatArray]) -> IntArray:
    """Rows of the glitch samples inside the excursions that passed the window bounds
    (step 4 of the module docstring).

    Parameters
    ----------
    positions : array, shape (n, D)
    hit : array of int, shape (E,)
        Flat indices (m - 1) x (n - 2) + a of the excursions of m interior samples from
        sample a to sample b = a + m + 1 left to test.
    chords, spans : array, shape (MAX_GLITCH_RUN x (n - 2),)
        Straight distance and path length from a to b of every (m, a).
    width, wide : int
        Median windows of the local step around a single sample, around a longer excursion.
    medians : callable (window, rows) -> array
        Median of the ``window`` steps around each of ``rows`` (clipped to its demonstration).

    Returns
    -------
    rows : array of int
        Interior samples a + k (k = 1..m) farther than both ``CHORD_FACTOR`` x chord and
        ``SPIKE_FACTOR`` x (m + 1) / 2 x the local step from the chord's midpoint.
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
            median_at[at] = medians(window, at)
            step[rows] = median_at[centre[rows]]
    limit = SPIKE_FACTOR * 0.5 * (m + 1) * step
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


def _spike_mask(positions: FloatArray) -> np.ndarray:
    """True for glitch samples (step 4 of the module docstring).

    An excursion of m = 1..``MAX_GLITCH_RUN`` samples between samples a and b = a + m + 1:
    interior sample k is a glitch when |x_k - (x_a + x_b) / 2| exceeds both ``CHORD_FACTOR``
    x |x_b - x_a| and ``SPIKE_FACTOR`` x (m + 1) / 2 x the local step. The local step is the median of the
    5 steps around a single sample, of the 17 steps around a longer excursion (a resampled
    glitch brings its own ramps). Two necessary conditions on the whole window come first,
    both from |x_k - (x_a + x_b) / 2| <= (path length from a to b) / 2: that half length
    must exceed ``CHORD_FACTOR`` x |x_b - x_a| (tested on every window) and then the
    window's limit (tested where the first one held: jitter of a standing arm passes the
    first, rarely the second). Only the windows left are tested sample by sample.
    """
    n = positions.shape[0]
    spike = np.zeros(n, dtype=bool)
    if n < 5:
        return spike
    steps = _step_lengths(positions)
    arc = np.concatenate([[0.0], np.cumsum(steps)])
    chords, spans = _chords_and_spans(positions, arc, min(MAX_GLITCH_RUN, n - 2))
    hit = np.flatnonzero(spans > 2.0 * CHORD_FACTOR * chords)
    width = min(2 * SPIKE_WINDOW + 1, steps.size)
    if hit.size:
        wide = min(2 * GLITCH_SCALE_WINDOW + MAX_GLITCH_RUN + 1, steps.size)
        spike[_excursion_glitches(positions, hit, chords, spans, width, wide,
                                  lambda window, at: _local_medians(steps, window, at))] = True
    # An end sample is a glitch when its step dwarfs the next one and the local steps.
    end_scale = _local_medians(steps, width, np.array([1, n - 2]))
    spike[0] |= steps[0] > SPIKE_FACTOR * max(steps[1], end_scale[0]) * 2.0
    spike[-1] |= steps[-1] > SPIKE_FACTOR * max(steps[-2], end_scale[1]) * 2.0
    return spike


#: Samples on each side of a removed glitch whose verdict the next pass can change: a
#: window reaches 6 samples, a local median 8 steps beyond the window's centre.
GLITCH_REACH = 16


def _glitch_mask(positions: FloatArray) -> np.ndarray:
    """:func:`_spike_mask` repeated on what is left (at most ``GLITCH_PASSES`` times): once a
    glitch's core is gone, the partial ramps a resampler left around it stand out in turn.

    A sample's verdict depends only on the samples within ``GLITCH_REACH`` of it (and on
    whether an end of the demo lies there), so a later pass re-tests only the stretches
    around what the previous pass removed, each with that much context: the same answer
    as a whole pass, at the cost of a few short ones.
    """
    n = positions.shape[0]
    glitch = np.zeros(n, dtype=bool)
    left = np.arange(n)
    found = _spike_mask(positions)
    for _ in range(GLITCH_PASSES - 1):
        if not found.any():
            return glitch
        glitch[left[found]] = True
        removed = left[found]
        left = np.flatnonzero(~glitch)
        m = left.size
        if m <= 4 * GLITCH_REACH:
            found = _spike_mask(np.take(positions, left, axis=0))
            continue
        # Where each removed sample was, in the new numbering; the stretches it can affect.
        at = np.searchsorted(left, removed)
        lo = np.maximum(at - GLITCH_REACH, 0)
        hi = np.minimum(at + GLITCH_REACH, m - 1)
        # Merge overlapping stretches (they are sorted by their start).
        start = np.flatnonzero(np.concatenate([[True], lo[1:] > np.maximum.accumulate(hi)[:-1]]))
        ends = np.maximum.accumulate(hi)[np.concatenate([start[1:] - 1, [hi.size - 1]])]
        found = np.zeros(m, dtype=bool)
        for first, last in zip(lo[start].tolist(), ends.tolist(), strict=True):
            s0, s1 = max(0, first - GLITCH_REACH), min(m, last + GLITCH_REACH + 1)
            verdict = _spike_mask(np.take(positions, left[s0:s1], axis=0))
            found[first : last + 1] = verdict[first - s0 : last + 1 - s0]
    if found.any():
        glitch[left[found]] = True
    return glitch


#: Shortest demonstration :func:`_spike_masks` tests together with others: from here on
#: every window has its full length (shorter ones clip theirs and go one at a time).
BATCHED_SPIKE_MIN = 2 * GLITCH_SCALE_WINDOW + MAX_GLITCH_RUN + 2
#: Most rows tested in one batch: its (runs x rows) temporaries stay below glibc's mmap
#: threshold (128 kB), so they come from reused heap memory; larger ones were mapped fresh
#: and page-faulted on every fit, which cost more than the calls the batch saves.
SPIKE_BATCH_ROWS = 2048


def _segment_medians(steps: FloatArray, width: int, at: IntArray, first: IntArray, last: IntArray) -> FloatArray:
    """:func:`_local_medians` of concatenated demonstrations: the window around step ``at``
    clipped to its own demonstration's rows ``first`` .. ``last`` (its steps first .. last - 1)."""
    start = np.minimum(np.maximum(at - width // 2, first), last - width)
    windows = steps[start[:, None] + np.arange(width)[None, :]]
    return np.asarray(np.partition(windows, width // 2, axis=1)[:, width // 2], dtype=np.float64)


def _spike_masks(parts: list[FloatArray]) -> list[np.ndarray]:
    """:func:`_spike_mask` of several demonstrations (or stretches) in one vectorised pass.

    The parts are concatenated; a window (a, m) counts only when it ends inside a's own
    part, arc lengths restart at each part and local medians are clipped to it, so every
    verdict is the one :func:`_spike_mask` gives the part alone, bit for bit. Parts shorter
    than ``BATCHED_SPIKE_MIN`` (narrower windows) go one at a time.
    """
    out: list[np.ndarray] = [np.zeros(0, dtype=bool)] * len(parts)
    group: list[int] = []
    rows = 0
    for k, p in enumerate(parts):
        if p.shape[0] < BATCHED_SPIKE_MIN:
            out[k] = _spike_mask(p)
            continue
        if group and rows + p.shape[0] > SPIKE_BATCH_ROWS:
            _spike_masks_into(parts, group, out)
            group, rows = [], 0
        group.append(k)
        rows += p.shape[0]
    if group:
        _spike_masks_into(parts, group, out)
    return out


def _spike_masks_into(parts: list[FloatArray], batched: list[int], out: list[np.ndarray]) -> None:
    """:func:`_spike_masks` of the parts listed in ``batched``, written to ``out``."""
    sizes = np.array([parts[k].shape[0] for k in batched])
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    ends = starts + sizes - 1  # last row of each part
    positions = np.concatenate([parts[k] for k in batched])
    total = positions.shape[0]
    steps = _step_lengths(positions)  # the steps across two parts are never read
    arc = np.empty(total)
    for first, last in zip(starts.tolist(), ends.tolist(), strict=True):
        arc[first] = 0.0
        np.cumsum(steps[first:last], out=arc[first + 1 : last + 1])
    longest = MAX_GLITCH_RUN
    chords, spans = _chords_and_spans(positions, arc, longest)
    part_first = np.repeat(starts, sizes)
    part_last = np.repeat(ends, sizes)
    # Window (a, m) ends at b = a + m + 1, which must lie in a's part.
    inside = (np.arange(2, longest + 2)[:, None] + np.arange(total - 2)[None, :]) <= part_last[None, : total - 2]
    hit = np.flatnonzero((spans > 2.0 * CHORD_FACTOR * chords) & inside.reshape(-1))
    width = 2 * SPIKE_WINDOW + 1
    spike = np.zeros(total, dtype=bool)
    if hit.size:
        wide = 2 * GLITCH_SCALE_WINDOW + MAX_GLITCH_RUN + 1
        spike[_excursion_glitches(
            positions, hit, chords, spans, width, wide,
            lambda window, at: _segment_medians(steps, window, at, part_first[at],
                                                part_last[at]))] = True
    # End samples, as in _spike_mask, part by part.
    head_scale = _segment_medians(steps, width, starts + 1, starts, ends)
    tail_scale = _segment_medians(steps, width, ends - 1, starts, ends)
    spike[starts] |= steps[starts] > SPIKE_FACTOR * np.maximum(steps[starts + 1], head_scale) * 2.0
    spike[ends] |= steps[ends - 1] > SPIKE_FACTOR * np.maximum(steps[ends - 2], tail_scale) * 2.0
    for k, first, last in zip(batched, starts.tolist(), ends.tolist(), strict=True):
        out[k] = spike[first : last + 1]


def _glitch_masks(parts: list[FloatArray]) -> list[np.ndarray]:
    """:func:`_glitch_mask` of several demonstrations, each pass of all of them (and of all
    the stretches their previous pass left to re-test) in one :func:`_spike_masks` call."""
    glitch = [np.zeros(p.shape[0], dtype=bool) for p in parts]
    left = [np.arange(p.shape[0]) for p in parts]
    found = _spike_masks(parts)
    active = list(range(len(parts)))
    for _ in range(GLITCH_PASSES - 1):
        still: list[int] = []
        jobs: list[tuple[int, int, int, int]] = []  # (part, first, last, s0); first < 0: whole
        pieces: list[FloatArray] = []
        for j in active:
            if not found[j].any():
                continue  # final: nothing was removed
            still.append(j)
            removed = left[j][found[j]]
            glitch[j][removed] = True
            left[j] = np.flatnonzero(~glitch[j])
            m = left[j].size
            if m <= 4 * GLITCH_REACH:
                jobs.append((j, -1, -1, 0))
                pieces.append(np.take(parts[j], left[j], axis=0))
                continue
            at = np.searchsorted(left[j], removed)
            lo = np.maximum(at - GLITCH_REACH, 0)
            hi = np.minimum(at + GLITCH_REACH, m - 1)
            start = np.flatnonzero(np.concatenate([[True], lo[1:] > np.maximum.accumulate(hi)[:-1]]))
            stretch_ends = np.maximum.accumulate(hi)[np.concatenate([start[1:] - 1, [hi.size - 1]])]
            found[j] = np.zeros(m, dtype=bool)
            for first, last in zip(lo[start].tolist(), stretch_ends.tolist(), strict=True):
                s0, s1 = max(0, first - GLITCH_REACH), min(m, last + GLITCH_REACH + 1)
                jobs.append((j, first, last, s0))
                pieces.append(np.take(parts[j], left[j][s0:s1], axis=0))
        for (j, first, last, s0), verdict in zip(jobs, _spike_masks(pieces), strict=True):
            if first < 0:
                found[j] = verdict
            else:
                found[j][first : last + 1] = verdict[first - s0 : last + 1 - s0]
        active = still
    for j in active:
        if found[j].any():
            glitch[j][left[j][found[j]]] = True
    return glitch


def _spaced_rows(positions: FloatArray, tolerance: float) -> IntArray:
    """Indices of samples at least ``tolerance`` apart from the previous kept one (the first
    and the last are kept): a strictly increasing arc length by construction."""
    n = positions.shape[0]
    rows = np.arange(n)
    for _ in range(64):
        chord = _step_lengths(np.take(positions, rows, axis=0))
        short = chord < tolerance
        if not short.any():
            return rows
        # Drop the later sample of a short chord, unless the previous chord was short too
        # (dropping both ends of a run at once could open a gap): one per run per pass.
        later = np.flatnonzero(short & ~np.concatenate([[False], short[:-1]])) + 1
        later[later == rows.size - 1] -= 1  # keep the last sample, drop its neighbour
        later = later[later > 0]
        rows = np.delete(rows, np.unique(later))
        if rows.size < 2:
            return rows
    # Long runs of short chords (jitter at standstill): finish greedily, rarely reached.
    kept = [0]
    for k in range(1, rows.size):
        if np.linalg.norm(positions[rows[k]] - positions[rows[kept[-1]]]) >= tolerance:
            kept.append(k)
    if kept[-1] != rows.size - 1:
        kept[-1] = rows.size - 1
    return rows[np.asarray(kept)]


def _arc_parameter(positions: FloatArray) -> FloatArray:
    steps = _step_lengths(positions)
    s = np.concatenate([[0.0], np.cumsum(steps)])
    return s / s[-1] if s[-1] > 0 else np.linspace(0.0, 1.0, positions.shape[0])


def prepared_samples(
    positions: FloatArray,
    timestamps: FloatArray | None = None,
    *,
    field: str,
    time_field: str | None = None,
    still_tolerance: float = STILL_TOLERANCE,
) -> PreparedDemonstration:
    """Run the preparation stage (see the module docstring) and keep its bookkeeping.

    Parameters
    ----------
    positions : array_like, shape (T, D)
    timestamps : array_like, shape (T,), optional
        Any order problems are repaired or refused here.
    field : str
        Names the demonstration in errors (e.g. ``"demos[2]"``).
    time_field : str, optional
        Names its timestamps in errors; defaults to ``field``.
    still_tolerance : float
        See :func:`moving_range`.

    Returns
    -------
    PreparedDemonstration

    Raises
    ------
    InvalidInputError
        With ``field`` (or ``time_field``) set, saying what was expected and what came.
    """
    head = _prepared_head(positions, timestamps, field, time_field)
    return _prepared_tail(head, _glitch_mask(head.positions), field, still_tolerance)


def prepared_samples_many(
    demos: list[FloatArray],
    timestamps: list[FloatArray | None],
    fields: list[str],
    time_fields: list[str],
    still_tolerance: float = STILL_TOLERANCE,
) -> list[PreparedDemonstration]:
    """:func:`prepared_samples` of several demonstrations, their glitch passes batched.

    The same results and the same error as calling :func:`prepared_samples` on each in
    turn: the first demonstration that fails raises, whichever step it fails in (demos
    after a failing first stage are not prepared at all).
    """
    heads: list[_Head] = []
    failure: InvalidInputError | None = None
    for d, t, f, tf in zip(demos, timestamps, fields, time_fields, strict=True):
        try:
            heads.append(_prepared_head(d, t, f, tf))
        except InvalidInputError as error:
            failure = error
            break
    glitches = _glitch_masks([h.positions for h in heads])
    prepared = [
        _prepared_tail(h, g, f, still_tolerance) for h, g, f in zip(heads, glitches, fields, strict=False)
    ]
    if failure is not None:
        raise failure
    return prepared


class _Head(NamedTuple):
    """Steps 1-3 of the preparation stage, what step 4 (glitches) and the rest need."""

    times: FloatArray | None
    rows: IntArray
    positions: FloatArray
    keep: np.ndarray
    kept: IntArray
    exact_rows: IntArray


def _prepared_head(
    positions: FloatArray, timestamps: FloatArray | None, field: str, time_field: str | None
) -> _Head:
    """Steps 1-3 of :func:`prepared_samples` (scale, time, repeats)."""
    points = check_positions(positions, field)
    n = points.shape[0]
    reach = float(np.abs(points).max())
    if reach > MAX_COORDINATE:
        magnitude = np.abs(points).max(axis=1)
        row = int(np.argmax(magnitude > MAX_COORDINATE))
        raise InvalidInputError(
            f"expected coordinates of {field} within +-{MAX_COORDINATE:g} (metres to nanometres "
            f"all fit), got {float(magnitude[row]):.6g} at sample {row}; rescale the units",
            field=field,
        )
    rows = np.arange(n)
    times: FloatArray | None = None
    if timestamps is not None:
        tfield = time_field or field
        times = np.asarray(timestamps, dtype=np.float64)
        if times.shape != (n,):
            raise InvalidInputError(f"expected {tfield} of shape ({n},), got {times.shape}", field=tfield)
        if not np.isfinite(times).all():
            row = int(np.argmax(~np.isfinite(times)))
            raise InvalidInputError(f"expected finite {tfield}, got NaN or Inf at row {row}", field=tfield)
        rows = _time_order_rows(times, tfield)

    # Step 3: repeats (exact and rounding-level), then step 4: glitches. Rows are gathered
    # with np.take: several times cheaper than fancy or boolean indexing of (T, D) arrays.
    pts = points if times is None else np.take(points, rows, axis=0)
    exact = np.flatnonzero(mask_of_new_samples(pts))
    rows, pts = rows[exact], np.take(pts, exact, axis=0)
    size = robust_path_length(pts)
    if size <= MIN_RELATIVE_MOTION * reach or size == 0.0:
        what = (
            f"all {n} samples are identical" if rows.size == 1
            else f"it moves only {size:.3g}, at rounding level for coordinates of {reach:.3g}"
        )
        raise InvalidInputError(
            f"expected at least {MIN_POINTS} distinct moving samples in {field}, got none: {what}",
            field=field,
        )
    keep = _repeat_mask(pts, NEAR_DUPLICATE_TOLERANCE * size)
    if times is not None:
        # A long run of repeats is a real pause: keep its last sample as well.
        run_end = np.flatnonzero(~keep[1:] & np.concatenate([keep[2:], [True]])) + 1
        if run_end.size:
            kept_t = times[rows[keep]]
            interval = float(np.median(np.diff(kept_t))) if kept_t.size > 1 else 0.0
            run_start = np.maximum.accumulate(np.where(keep, np.arange(keep.size), 0))[run_end]
            long = times[rows[run_end]] - times[rows[run_start]] > PAUSE_INTERVALS * interval
            keep[run_end[long]] = True
    exact_rows = rows
    kept = np.flatnonzero(keep)
    rows, pts = rows[kept], np.take(pts, kept, axis=0)
    return _Head(times, rows, pts, keep, kept, exact_rows)


def _prepared_tail(head: _Head, glitch: np.ndarray, field: str, still_tolerance: float) -> PreparedDemonstration:
    """Steps 4 (given the glitch mask of ``head.positions``) to 6 of :func:`prepared_samples`."""
    times, rows, pts, keep, kept, exact_rows = head
    # Every exact-deduplicated row stands for the kept sample it merged into; rows merged
    # into a glitch are glitches too (a poller repeating one at rounding level).
    flagged = np.zeros(keep.size, dtype=bool)
    flagged[kept[glitch]] = True
    representative = np.maximum.accumulate(np.where(keep, np.arange(keep.size), 0))
    samples = exact_rows[~flagged[representative]]
    if glitch.any():
        genuine = np.flatnonzero(~glitch)
        rows, pts = rows[genuine], np.take(pts, genuine, axis=0)

    # Step 5: still ends, then step 6: arc-length spacing.
    window = moving_range(pts, still_tolerance)
    rows, pts = rows[window], pts[window]
    if times is None and rows.size >= 2:
        spaced = _spaced_rows(pts, 0.5 * NEAR_DUPLICATE_TOLERANCE * robust_path_length(pts))
        rows, pts = rows[spaced], pts[spaced]
    if rows.size < MIN_POINTS:
        raise InvalidInputError(
            f"expected at least {MIN_POINTS} distinct moving samples in {field}, got {rows.size} "
            "after dropping repeats, glitches and still ends",
            field=field,
        )

    if times is None:
        phase_kept = _arc_parameter(pts)
        sample_phase = np.interp(samples, rows, phase_kept)
        kept_times = None
    else:
        kept_times = times[rows]
        sample_phase = np.clip((times[samples] - kept_times[0]) / (kept_times[-1] - kept_times[0]), 0.0, 1.0)
    return PreparedDemonstration(
        rows=rows,
        positions=pts,
        timestamps=kept_times,
        sample_rows=samples,
        sample_phase=np.asarray(sample_phase, dtype=np.float64),
    )


def prepared_rows(
    positions: FloatArray,
    timestamps: FloatArray | None = None,
    *,
    field: str,
    still_tolerance: float = STILL_TOLERANCE,
) -> IntArray:
    """Input rows kept by :func:`prepared_demonstration`, increasing, shape (T',)."""
    return prepared_samples(positions, timestamps, field=field, still_tolerance=still_tolerance).rows


def prepared_demonstration(
    positions: FloatArray,
    timestamps: FloatArray | None = None,
    *,
    field: str,
    time_field: str | None = None,
    still_tolerance: float = STILL_TOLERANCE,
) -> tuple[FloatArray, FloatArray | None]:
    """Turn a raw log into a demonstration ready for alignment (see the module docstring).

    Parameters
    ----------
    positions : array_like, shape (T, D)
        Raw samples, D in {2, 3}, T >= 4, finite.
    timestamps : array_like, shape (T,), optional
        Seconds (any origin); equal, near-equal and isolated out-of-order stamps are repaired.
    field : str
        Names the demonstration in errors (e.g. ``"demos[2]"``).
    time_field : str, optional
        Names its timestamps in errors; defaults to ``field``.
    still_tolerance : float
        Fraction of the path length within which head and tail samples count as still.

    Returns
    -------
    positions : array, shape (T', D)
        Rows of the input: no repeats, glitches or still ends; without timestamps,
        consecutive rows at least 5e-7 of the path length apart (strictly increasing arc length).
    timestamps : array, shape (T',) or None
        Strictly increasing, steps at least 1e-9 of the duration.

    Raises
    ------
    InvalidInputError
        Coordinates beyond +-1e15, a demo that does not move (identical points) or stands
        still, timestamps that cannot be put in order; ``field`` names the demo.
    """
    prepared = prepared_samples(
        positions, timestamps, field=field, time_field=time_field, still_tolerance=still_tolerance
    )
    return prepared.positions, prepared.timestamps


def cleaned_demonstration(
    positions: FloatArray,
    timestamps: FloatArray | None = None,
    tolerance: float = STILL_TOLERANCE,
) -> tuple[FloatArray, FloatArray | None]:
    """Former name of :func:`prepared_demonstration` (field ``"positions"`` in errors)."""
    return prepared_demonstration(positions, timestamps, field="positions", still_tolerance=tolerance)
