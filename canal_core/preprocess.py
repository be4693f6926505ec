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
   and ``SPIKE_FACTOR`` (4) x (m + 1) / 2 local steps (median of the surrounding steps),
   and ``GLITCH_FLOOR`` (1 %) of the demo's robust path length. Real motion cannot pass the
   first two: for monotone sampling that distance is at most half the chord, and at a
   genuine reversal about (m + 1) / 2 steps; slow motion can (a millimetre dip is many
   steps of a tenth of a millimetre), and the floor keeps such small excursions, which the
   canal then encloses. A glitch repeated by the poller is one
   sample after step 3; a resampled glitch (with its ramps) spans a few. The test runs
   again on what is left (up to 3 passes), which catches the partial ramps around a
   removed glitch. Longer excursions are kept. The rule and its constants live in
   :mod:`canal_core.glitches`.
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

from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from .bounds import MAX_COORDINATE
from .errors import InvalidInputError
from .glitches import glitch_masks, robust_path_length, step_lengths
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
#: A repeat run longer than this many median sampling intervals is a pause (see step 3).
PAUSE_INTERVALS = 10.0


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


def size_ratios(positions: Sequence[FloatArray]) -> FloatArray:
    """Return each demonstration's size over the median demonstration's size.

    A demonstration's size is the diagonal of its bounding box. Demonstrations of one skill
    differ in size by a few times at most; a ratio near 1000 or 1/1000 is a log in
    millimetres among logs in metres (or the other way), which the fit cannot tell from a
    way of its own.

    Parameters
    ----------
    positions : sequence of arrays, each shape (T_j, D)

    Returns
    -------
    ratios : array, shape (N,)
        1 for every demonstration when the median size is 0.
    """
    sizes = np.array([float(np.linalg.norm(np.ptp(p, axis=0))) for p in positions])
    median = float(np.median(sizes)) if sizes.size else 0.0
    if not median > 0.0:
        return np.ones(sizes.shape[0])
    return np.asarray(sizes / median, dtype=np.float64)


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


def check_time_order(times: FloatArray, field: str = "timestamps") -> None:
    """Refuse (:class:`InvalidInputError`, naming ``field``) time stamps that a demonstration
    would be refused for: no span, or time going back for more than an isolated sample.

    Parameters
    ----------
    times : array, shape (T,)
        Finite seconds.
    """
    _time_order_rows(times, field)


def _time_order_rows(times: FloatArray, field: str) -> IntArray:
    """Rows whose timestamps, in order, strictly increase (step 2 of the module docstring)."""
    n = times.shape[0]
    span = float(times.max() - times.min())
    if not np.isfinite(span):
        raise InvalidInputError(f"expected {field} with a finite span, got {span}", field=field)
    if span <= 0.0:
        raise InvalidInputError(
            f"expected {field} to advance, got {n} equal values {float(times[0])!r}",
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
                    f"expected increasing {field}, got {float(t[k])!r} after "
                    f"{float(t[k - 1])!r} at sample {int(rows[k])}: time goes back for more "
                    "than one sample (a clock reset or logs joined together)",
                    field=field,
                )
        repaired += len(drop)
        if repaired > budget:
            k = int(back[0])
            raise InvalidInputError(
                f"expected increasing {field}, got {repaired} samples out of order "
                f"(first {float(t[k])!r} after {float(t[k - 1])!r} at sample {int(rows[k])}); "
                f"at most {budget} are repaired by dropping them",
                field=field,
            )
        rows = np.delete(rows, np.unique(drop))
    t = times[rows]
    if np.any(np.diff(t) <= eps):
        k = int(np.argmax(np.diff(t) <= eps)) + 1
        raise InvalidInputError(
            f"expected increasing {field}, got {float(t[k])!r} after "
            f"{float(t[k - 1])!r} at sample {int(rows[k])}",
            field=field,
        )
    return rows


def _repeat_mask(positions: FloatArray, tolerance: float) -> np.ndarray:
    """Keep a sample when it moved ``tolerance`` from its predecessor or the drift since
    the last kept sample reached it (arc length crossed into a new bin of that width)."""
    steps = step_lengths(positions)
    keep = np.ones(positions.shape[0], dtype=bool)
    if tolerance <= 0.0:
        keep[1:] = steps > 0.0
        return keep
    bins = np.floor(np.concatenate([[0.0], np.cumsum(steps)]) / tolerance)
    keep[1:] = (steps >= tolerance) | (bins[1:] > bins[:-1])
    return keep


def _spaced_rows(positions: FloatArray, tolerance: float) -> IntArray:
    """Indices of samples at least ``tolerance`` apart from the previous kept one (the first
    and the last are kept): a strictly increasing arc length by construction."""
    n = positions.shape[0]
    rows = np.arange(n)
    for _ in range(64):
        chord = step_lengths(np.take(positions, rows, axis=0))
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
    """Cumulative arc length over its total, shape (T,) (evenly spaced if it never moves)."""
    steps = step_lengths(positions)
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
    return prepared_samples_many([positions], [timestamps], [field], [time_field or field], still_tolerance)[0]


def prepared_samples_many(
    demos: list[FloatArray],
    timestamps: list[FloatArray | None],
    fields: list[str],
    time_fields: list[str],
    still_tolerance: float = STILL_TOLERANCE,
) -> list[PreparedDemonstration]:
    """Run the preparation stage on several demonstrations, their glitch passes batched.

    The same results and the same error as preparing each alone in turn: the first
    demonstration that fails raises, whichever step it fails in (demos after one failing
    steps 1-3 are not prepared at all). :func:`prepared_samples` is this with one demo.

    Parameters
    ----------
    demos : list of array_like, each shape (T_j, D)
    timestamps : list of (array_like, shape (T_j,)) or None
    fields, time_fields : list of str
        Name each demonstration and its timestamps in errors.
    still_tolerance : float
        See :func:`moving_range`.

    Returns
    -------
    list of PreparedDemonstration
    """
    heads: list[_Head] = []
    failure: InvalidInputError | None = None
    for d, t, f, tf in zip(demos, timestamps, fields, time_fields, strict=True):
        try:
            heads.append(_prepared_head(d, t, f, tf))
        except InvalidInputError as error:
            failure = error
            break
    masks = glitch_masks([h.positions for h in heads])
    prepared = [
        _prepared_tail(h, g, f, still_tolerance) for h, g, f in zip(heads, masks, fields, strict=False)
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


def glitch_rows(positions: FloatArray) -> np.ndarray:
    """The rows steps 3 and 4 drop as glitches from a path taken in the order it came.

    The rule of a demonstration's step 4 on the samples step 3 keeps (exact and
    rounding-level repeats merged into the sample they repeat); a repeat of a glitch is a
    glitch too. A path of fewer than ``MIN_TESTED`` distinct samples keeps every row, as a
    demonstration does. Corrections are cleaned by this before they shape a canal.

    Parameters
    ----------
    positions : array, shape (T, D)
        Finite (checked by the caller).

    Returns
    -------
    glitch : array of bool, shape (T,)
        True for the rows to leave out.
    """
    n = positions.shape[0]
    new = mask_of_new_samples(positions)
    exact = np.flatnonzero(new)
    pts = np.take(positions, exact, axis=0)
    size = robust_path_length(pts)
    if size == 0.0:
        return np.zeros(n, dtype=bool)
    keep = _repeat_mask(pts, NEAR_DUPLICATE_TOLERANCE * size)
    kept = np.flatnonzero(keep)
    flagged = np.zeros(exact.size, dtype=bool)
    flagged[kept[glitch_masks([np.take(pts, kept, axis=0)])[0]]] = True
    # Each exact row stands for the kept sample it merged into, each input row for its
    # exact row.
    representative = np.maximum.accumulate(np.where(keep, np.arange(keep.size), 0))
    exact_flag = flagged[representative]
    row_exact = np.cumsum(new) - 1
    return np.asarray(exact_flag[row_exact], dtype=bool)


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
