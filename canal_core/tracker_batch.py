"""The tracker step for many streams of one model in one vectorised numpy pass.

:func:`batched_tracker_step` applies :func:`canal_core.tracker.tracker_step`'s rules to B
rows at once, reading per-model lookup tables (:class:`StepTables`, built once per geometry);
:func:`tracker_steps` and :func:`step_trackers` wrap it for states held as objects.
The answers equal the scalar step's (same sections, flags and plan; floats up to the last
bits of a reordered sum).
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .tracker import (
    DEFAULT_DIRECTIONS,
    FAR_ETA,
    MAX_ADVANCE,
    MAX_ONWARD,
    MAX_PLAN_ETA,
    REPLAN_TOLERANCE,
    SUSTAIN,
    WINDOW,
    Tracker,
    TrackerGeometry,
    TrackerState,
    TrackerTarget,
    tracker_step,
)
from .tube import tube_ratio_caps
from .validation import FloatArray


@dataclass(frozen=True, eq=False)
class TrackerBatch:
    """Answers of one :meth:`TrackerBank.step` call, row b for the b-th slot stepped.

    Attributes
    ----------
    target : array, shape (B, D)
    progress, eta : array, shape (B,)
    section_index : array of int, shape (B,)
    inside, done : array of bool, shape (B,)
    velocity : array, shape (B, D), or None
        When the model knows section times.
    orientation : array, shape (B, 4), or None
        When the model learned orientations.
    """

    target: FloatArray
    progress: FloatArray
    eta: FloatArray
    section_index: NDArray[np.intp]
    inside: NDArray[np.bool_]
    done: NDArray[np.bool_]
    velocity: FloatArray | None = None
    orientation: FloatArray | None = None

def tracker_steps(
    geometry: TrackerGeometry,
    states: list[TrackerState],
    positions: FloatArray,
    lookahead: int = 1,
    replan_tolerance: float = REPLAN_TOLERANCE,
) -> tuple[list[TrackerTarget], list[TrackerState]]:
    """:func:`tracker_step` for many streams of one model in one vectorised pass.

    Parameters
    ----------
    geometry : TrackerGeometry
    states : list of TrackerState, length B
        Each stream's state after its previous step.
    positions : array, shape (B, D)
        Live position of each stream.
    lookahead, replan_tolerance
        As :func:`tracker_step`.

    Returns
    -------
    targets : list of TrackerTarget, length B
    states : list of TrackerState, length B

    Notes
    -----
    The answers equal B calls of :func:`tracker_step` (same sections, flags and plan; floats
    up to the last bits of a reordered sum). A live bridge receives the poses of many robots
    at once; one numpy pass costs about what 2-3 scalar steps cost whatever the batch size,
    so per-pose work drops with it. The pass is :func:`batched_tracker_step` (rows the window search
    cannot place follow the scalar step's rules there); non-circular sections, canals of
    fewer than three sections and a single stream take the scalar path.
    """
    b = len(states)
    g = geometry
    n = g.centres.shape[0]
    positions = np.asarray(positions, dtype=np.float64)
    if b == 0:
        return [], []
    if not g.sections.spec.isotropic or n < 3 or b == 1:
        pairs = [tracker_step(g, states[i], positions[i], lookahead, replan_tolerance)
                 for i in range(b)]
        return [t for t, _ in pairs], [st for _, st in pairs]
    k = g.basis.shape[1]
    index = np.fromiter([min(max(st.index, 0), n - 1) for st in states], dtype=np.intp, count=b)
    eta = np.fromiter([math.nan if st.eta is None or st.direction is None else st.eta
                       for st in states], dtype=np.float64, count=b)
    direction = np.array([np.zeros(k) if st.direction is None else st.direction
                          for st in states], dtype=np.float64).reshape(b, k)
    pending = np.array([np.zeros(k + 1) if st.pending is None else st.pending
                        for st in states], dtype=np.float64).reshape(b, k + 1)
    strikes = np.fromiter([st.strikes for st in states], dtype=np.intp, count=b)
    out, new_index, plan_eta, plan_dir, pending, strikes = batched_tracker_step(
        g, index, eta, direction, positions, lookahead, replan_tolerance, pending, strikes)
    velocity = out.velocity
    orientation = out.orientation
    targets = [
        TrackerTarget(out.target[r], prog, et, ix, ins, dn,
                      None if velocity is None else velocity[r],
                      None if orientation is None else orientation[r])
        for r, (prog, et, ix, ins, dn) in enumerate(zip(
            out.progress.tolist(), out.eta.tolist(), out.section_index.tolist(),
            out.inside.tolist(), out.done.tolist(), strict=True))]
    new_states = [TrackerState(ni, None if math.isnan(pe) else pe,
                               None if math.isnan(pe) else plan_dir[r],
                               pending[r].copy() if sk else None, sk)
                  for r, (ni, pe, sk) in enumerate(zip(
                      new_index.tolist(), plan_eta.tolist(), strikes.tolist(), strict=True))]
    return targets, new_states


@dataclass(frozen=True, eq=False)
class StepTables:
    """Per-geometry arrays :func:`batched_tracker_step` gathers from, built once per model.

    Each table is indexed by what a step already knows (the section reached, the located
    section, the target section), so one fancy index fetches every row a step reads and one
    small matrix product per stage turns them into distances and in-plane coordinates.
    Points are taken in homogeneous coordinates ``[x, 1]`` so that plane offsets ride in the
    same product.

    Attributes
    ----------
    lo, hi : array of int, shape (N,)
        First and last section of the window searched from each section reached.
    window : array, shape (N, WINDOW + 2, D + 1)
        Rows ``[t_c, -t_c . c_c]`` of the window's sections (clamped at N - 1).
    open_pairs : array of bool, shape (N, WINDOW + 2)
        Whether each pair of consecutive window sections may place the robot (inside
        ``[lo, hi]``); the last column is always True, a sentinel meaning "not placed".
    pair : array, shape (N - 1, 2 + 2 D, D + 1)
        For the pair (i, i + 1): both planes, then for each section its basis rows with
        offsets ``-b . c`` and a row ``[0, r]``: one product with ``[x, 1]`` gives
        ``[d0, d1, q0, r0, q1, r1]``.
    radius : array, shape (N,)
    frame : array, shape (N, D, D)
        Each section's basis rows scaled by its radius, then its centre: what a target
        is built from.
    default_direction : array, shape (D - 1,)
    curvature : array, shape (N, D - 1)
        b_k of the tube condition (F1 of :mod:`canal_core.tube`); zero when no plan can
        reach it.
    folds : bool
        Whether some plan can reach the condition (else ``curvature`` is not read).
    """

    lo: NDArray[np.intp]
    hi: NDArray[np.intp]
    window: FloatArray
    open_pairs: NDArray[np.bool_]
    pair: FloatArray
    radius: FloatArray
    frame: FloatArray
    default_direction: FloatArray
    curvature: FloatArray
    folds: bool


# Built on first use per geometry and dropped with it: every bank and batch of one model
# reads the same tables.
_TABLES: weakref.WeakKeyDictionary[TrackerGeometry, StepTables] = weakref.WeakKeyDictionary()


def step_tables(g: TrackerGeometry) -> StepTables:
    """The :class:`StepTables` of a circle-section geometry with N >= 2 sections, built on
    first use and kept while the geometry lives."""
    tables = _TABLES.get(g)
    if tables is None:
        tables = _TABLES[g] = built_step_tables(g)
    return tables


def built_step_tables(g: TrackerGeometry) -> StepTables:
    """Build the :class:`StepTables` of a circle-section geometry with N >= 2 sections."""
    n, d = g.centres.shape
    reached = np.arange(n)
    lo = np.maximum(reached - 1, 0)
    hi = np.minimum(reached + WINDOW, n - 1)
    columns = np.arange(WINDOW + 2)
    planes = np.concatenate([g.tangents, -g.offsets[:, None]], axis=1)
    window = planes[np.minimum(lo[:, None] + columns, n - 1)]
    open_pairs = np.ones((n, WINDOW + 2), dtype=bool)
    open_pairs[:, :-1] = lo[:, None] + columns[1:] <= hi[:, None]
    radius = np.ascontiguousarray(g.sections.params["radius"], dtype=np.float64)
    # per section: its basis rows [b, -b . c], then [0, r] (the product with [x, 1] is r)
    rows = np.concatenate([
        np.concatenate([g.basis, -np.einsum("nkd,nd->nk", g.basis, g.centres)[:, :, None]],
                       axis=2),
        np.concatenate([np.zeros((n, 1, d)), radius[:, None, None]], axis=2)], axis=1)
    pair = np.concatenate([planes[:-1, None], planes[1:, None], rows[:-1], rows[1:]], axis=1)
    return StepTables(
        lo, hi, np.ascontiguousarray(window), open_pairs, np.ascontiguousarray(pair), radius,
        np.ascontiguousarray(np.concatenate(
            [radius[:, None, None] * g.basis, g.centres[:, None, :]], axis=1)),
        DEFAULT_DIRECTIONS[d - 1],
        np.zeros((n, d - 1)) if g.curvature is None else np.ascontiguousarray(g.curvature),
        g.curvature is not None)


def batched_tracker_step(
    g: TrackerGeometry,
    last_index: NDArray[np.intp],
    old_eta: FloatArray,
    old_dir: FloatArray,
    p: FloatArray,
    lookahead: int,
    replan_tolerance: float = REPLAN_TOLERANCE,
    pending: FloatArray | None = None,
    strikes: NDArray[np.intp] | None = None,
) -> tuple[TrackerBatch, NDArray[np.intp], FloatArray, FloatArray, FloatArray,
           NDArray[np.intp]]:
    """:func:`tracker_step` for B streams of one circle-section canal (N >= 3) in one pass.

    The window search for every row, and for the rows it cannot place the same rules as
    :func:`tracker_step` (pushed ahead: the bracketing pair ahead nearest the robot; past the
    last plane: the last pair; behind: hold). Used by :class:`TrackerBank` (state held as
    arrays) and :func:`tracker_steps` (state as objects).

    Parameters
    ----------
    g : TrackerGeometry
    last_index : array of int, shape (B,)
        Section each stream had reached, in [0, N - 1].
    old_eta : array, shape (B,)
        Each stream's planned ratio; NaN: no plan yet.
    old_dir : array, shape (B, D - 1)
        Each stream's planned unit in-plane direction (any finite value where there is no
        plan).
    p : array, shape (B, D)
        Live positions.
    lookahead, replan_tolerance
        As :func:`tracker_step` (lookahead >= 1).
    pending : array, shape (B, D), optional
    strikes : array of int, shape (B,), optional
        Each stream's :class:`TrackerState` ``pending`` (any value where ``strikes`` is 0)
        and ``strikes`` (None: no stream has a streak).

    Returns
    -------
    answers : TrackerBatch
    index : array of int, shape (B,)
        Section reached after the step.
    plan_eta : array, shape (B,)
    plan_dir : array, shape (B, D - 1)
        The plan after the step.
    pending : array, shape (B, D)
    strikes : array of int, shape (B,)
        The suspect-pose streak after the step.

    Notes
    -----
    A live bridge steps a handful of rows per call, so the cost is the number of numpy
    calls, not the rows: every geometric quantity comes from one gather of
    :class:`StepTables` and one small product (the window's plane distances; both planes
    and both bases of the located pair), the rules for rare rows (not placed by the window,
    at either end of the canal, no in-plane offset) run only when such a row is present,
    and the arithmetic follows :func:`tracker_step`'s order so the answers agree to the
    last bits. Far poses may overflow: their rows answer outside, as the scalar step's do.
    """
    t = step_tables(g)
    n = t.radius.shape[0]
    b, d = p.shape
    k = d - 1
    ph = np.empty((b, d + 1, 1))
    ph[:, :d, 0] = p
    ph[:, d, 0] = 1.0
    with np.errstate(all="ignore"):
        # the window search: the first pair of planes the position lies between (as
        # _first_crossing), else the sentinel column WINDOW + 1
        dist = (t.window[last_index] @ ph)[:, :, 0]
        above = dist > 0.0
        crossing = above[:, :-1] != above[:, 1:]
        crossing |= dist[:, :-1] == 0.0
        change = t.open_pairs[last_index]
        change[:, :-1] &= crossing
        first = change.argmax(axis=1)
        lo = t.lo[last_index]
        index = lo + first
        placed = first <= WINDOW
        # membership tests on short lists cost a tenth of an ndarray.any()
        if WINDOW + 1 in first.tolist():
            lost = np.flatnonzero(first > WINDOW)
            from_index = last_index[lost]
            index[lost] = _unplaced_sections(g, p[lost], t.lo[from_index], t.hi[from_index])
            first = np.where(placed, first, 0)
            placed |= index == lo  # behind the window: held at its first section
        # as tracker._passed_planes: the furthest plane up to lookahead past the first
        # crossing or the section reached that the position is on or in front of
        furthest = np.minimum(np.maximum(first, last_index - lo) + max(lookahead, 1),
                              t.hi[last_index] - lo)
        rows = np.arange(b)
        for ahead in range(1, max(lookahead, 1) + 2):  # the reached section is 0 or 1 past lo
            column = first + ahead
            passed = placed & (column <= furthest)
            passed &= dist[rows, np.minimum(column, WINDOW + 1)] >= -g.done_tolerance
            if passed.any():
                index[passed] = lo[passed] + column[passed]
        np.minimum(index, n - 2, out=index)  # the last plane passed is the last pair's
        # the located pair: [d0, d1, q0, r0, q1, r1] from one product
        v = (t.pair[index] @ ph)[:, :, 0]
        d0 = v[:, 0]
        d1 = v[:, 1]
        alpha = d0 / (d0 - d1)
        np.maximum(alpha, 0.0, out=alpha)
        np.minimum(alpha, 1.0, out=alpha)
        level = d0 == d1
        if True in level.tolist():
            alpha[level] = 0.0
        # q and the reach interpolated together: (1 - alpha) [q0, r0] + alpha [q1, r1]
        qr = (1.0 - alpha)[:, None] * v[:, 2 : 3 + k]
        qr += alpha[:, None] * v[:, 3 + k :]
        q = qr[:, :k]
        reach = qr[:, k]
        norm = _row_norms(q)
        direction = q / norm[:, None]
        flat = norm > 0.0
        if False in flat.tolist():
            direction[~flat] = t.default_direction
        eta = norm / reach
        sound = reach > 0.0
        if False in sound.tolist():
            odd = ~sound
            eta[odd] = np.where(norm[odd] > 0.0, np.inf, 0.0)
        # keep the plan while the live position is near it (circle sections: the reference
        # reach is the live one); NaN old_eta (no plan) compares False
        gap = (old_eta * reach)[:, None] * old_dir
        np.subtract(q, gap, out=gap)
        keep = _row_norms(gap) <= replan_tolerance * reach
        plan_eta = np.minimum(eta, MAX_PLAN_ETA)
        np.copyto(plan_eta, old_eta, where=keep)
        plan_dir = direction
        np.copyto(plan_dir, old_dir, where=keep[:, None])
        inside = eta <= 1.0 + 1e-9
        done = np.zeros(b, dtype=bool)
        # plausible steps (tracker_step's rule): far from the canal, or too far ahead
        planned = old_eta == old_eta  # NaN: no plan
        far = eta > FAR_ETA
        far |= eta != eta
        far |= d0 < -FAR_ETA * reach
        far |= d1 > FAR_ETA * reach
        suspect = far | (planned & (index - last_index > MAX_ADVANCE))
        at = index.tolist()
        if 0 in at:  # behind the first plane
            inside &= ~((index == 0) & (d0 < 0.0))
        if n - 2 in at:  # past the last plane; reached it (d1 is its distance)
            end = index == n - 2
            inside &= ~(end & (d1 > g.done_tolerance))
            done = end & (d1 >= -g.done_tolerance)
        new_index = np.maximum(last_index, index)
        new_pending = p
        new_strikes = np.zeros(b, dtype=np.intp)
        unplaced = None
        if True in suspect.tolist():
            new_pending = p.copy()
            unplaced, index = _suspect_rows(
                suspect, planned, far, last_index, index, eta, alpha, inside, done, plan_eta,
                plan_dir, old_eta, old_dir, new_index, new_pending, new_strikes,
                p if pending is None else pending,
                np.zeros(b, dtype=np.intp) if strikes is None else strikes, p, reach, n,
                g.tangents, g.centres)
        # aimed from the section reached (as tracker_step)
        target_index = np.maximum(index, last_index) + max(int(lookahead), 1)
        np.minimum(target_index, n - 1, out=target_index)
        target = _planned_points(t, target_index, plan_eta, plan_dir)
        progress = index + alpha
        progress /= max(n - 1, 1)
        if True in done.tolist():
            progress[done] = 1.0
        velocity = None if g.section_times is None else _feed_forwards(
            g, target_index, target, plan_eta, plan_dir)
        if unplaced is not None:  # answered with the entry, their state left as it was
            plan_eta[unplaced] = old_eta[unplaced]
            plan_dir[unplaced] = old_dir[unplaced]
    orientation = None if g.orientations is None else g.orientations[target_index]
    answers = TrackerBatch(target, progress, eta, index, inside, done, velocity, orientation)
    return answers, new_index, plan_eta, plan_dir, new_pending, new_strikes


def _suspect_rows(suspect: NDArray[np.bool_], planned: NDArray[np.bool_],
                  far: NDArray[np.bool_],
                  last_index: NDArray[np.intp], index: NDArray[np.intp], eta: FloatArray,
                  alpha: FloatArray, inside: NDArray[np.bool_], done: NDArray[np.bool_],
                  plan_eta: FloatArray, plan_dir: FloatArray, old_eta: FloatArray,
                  old_dir: FloatArray, new_index: NDArray[np.intp],
                  new_pending: FloatArray, new_strikes: NDArray[np.intp],
                  pending: FloatArray, strikes: NDArray[np.intp], p: FloatArray,
                  reach: FloatArray, n: int, tangents: FloatArray,
                  centres: FloatArray) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """:func:`batched_tracker_step`'s suspect rows by :func:`tracker_step`'s rules, written
    into its arrays in place: a held row answers from its last plausible state (section,
    plan) and keeps its state but the streak; a row with no plan is answered as located
    and its state is left as it was. Returns the unplaced rows (whose returned plan the
    caller restores once the answers are built) and the answers' sections."""
    unplaced = np.flatnonzero(suspect & ~planned)
    new_index[unplaced] = last_index[unplaced]
    new_pending[unplaced] = pending[unplaced]
    new_strikes[unplaced] = strikes[unplaced]
    rows = np.flatnonzero(suspect & planned)
    if rows.size:
        moved = p[rows] - pending[rows]
        agree = _row_norms(moved) <= FAR_ETA * reach[rows]
        # near the canal and ahead of the last suspect pose: an arm moved along it
        along = _row_dots(moved, tangents[index[rows]])
        across = _row_dots(moved, moved) - along * along
        at = index[rows]
        most = _row_norms(centres[at] - centres[np.maximum(at - MAX_ONWARD, 0)])
        agree |= (~far[rows] & (along > 0.0) & (along <= most)
                  & (across <= (FAR_ETA * reach[rows]) ** 2))
        agree &= strikes[rows] > 0
        streak = np.where(agree, np.minimum(strikes[rows] + 1, SUSTAIN), 1)
        new_strikes[rows] = streak
        hold = (streak < SUSTAIN) | ~np.isfinite(eta[rows])
        held = rows[hold]
        index = index.copy()
        index[held] = np.minimum(np.maximum(last_index[held], 0), n - 2)
        alpha[held] = 0.0
        inside[held] = False
        done[held] = False
        plan_eta[held] = old_eta[held]
        plan_dir[held] = old_dir[held]
        new_index[held] = last_index[held]
    return unplaced, index


def _planned_points(t: StepTables, index: NDArray[np.intp], eta: FloatArray,
                    direction: FloatArray) -> FloatArray:
    """The points at ratio ``eta`` (B,) in ``direction`` (B, D - 1) on sections ``index``
    (B,), shape (B, D): c + eta (direction . r basis), one product of [eta direction, 1]
    with the section's frame, the ratio capped by the tube condition (F1)."""
    b, k = direction.shape
    if t.folds:
        eta = np.minimum(eta, tube_ratio_caps(t.radius[index], direction, t.curvature[index]))
    scaled = np.empty((b, 1, k + 1))
    np.multiply(direction, eta[:, None], out=scaled[:, 0, :k])
    scaled[:, 0, k] = 1.0
    return (scaled @ t.frame[index])[:, 0]


def _row_dots(x: FloatArray, y: FloatArray) -> FloatArray:
    """Dot product of each row of ``x`` and ``y`` (B, K), summed in column order."""
    out = x[:, 0] * y[:, 0]
    for j in range(1, x.shape[1]):
        out += x[:, j] * y[:, j]
    return out


def _row_norms(x: FloatArray) -> FloatArray:
    """Euclidean norm of each row of ``x`` (B, K), summed in column order as ``x @ x`` is."""
    sq = x[:, 0] * x[:, 0]
    for j in range(1, x.shape[1]):
        sq += x[:, j] * x[:, j]
    return np.sqrt(sq)


def _unplaced_sections(g: TrackerGeometry, p: FloatArray, lo: NDArray[np.intp],
                       hi: NDArray[np.intp]) -> NDArray[np.intp]:
    """Sections of rows the window did not place, by :func:`tracker_step`'s rules."""
    n = g.centres.shape[0]
    dist_all = p @ g.tangents.T
    dist_all -= g.offsets
    ar = np.arange(p.shape[0])
    end = dist_all[ar, hi]
    ahead = (end > 0.0) & (hi < n - 1)
    index = np.where(end > 0.0, n - 2, lo)  # past the last plane / behind: hold
    if ahead.any():
        rows = np.flatnonzero(ahead)
        d = dist_all[rows]
        # as _nearest_crossing_ahead: among the bracketing pairs from the window's end
        # on, the one whose first centre is nearest the robot (none: the last pair)
        change = (d[:, :-1] == 0.0) | ((d[:, :-1] > 0.0) != (d[:, 1:] > 0.0))
        change &= np.arange(n - 1)[None, :] >= hi[rows][:, None]
        gaps = np.linalg.norm(g.centres[None, :-1, :] - p[rows][:, None, :], axis=2)
        gaps[~change] = np.inf
        nearest = gaps.argmin(axis=1)
        # every bracketing pair infinitely far (an overflowing pose): the first of them, as
        # argmin over the scalar step's list of pairs gives
        nearest = np.where(change[np.arange(rows.size), nearest], nearest, change.argmax(axis=1))
        index[rows] = np.where(change.any(axis=1), nearest, n - 2)
    return np.minimum(np.maximum(index, 0), n - 2)


def _feed_forwards(g: TrackerGeometry, index: NDArray[np.intp], target: FloatArray,
                   eta: FloatArray, direction: FloatArray) -> FloatArray:
    """:func:`_feed_forward` for many rows of circle sections, shapes (B,), (B, D), (B,),
    (B, D - 1)."""
    assert g.section_times is not None
    n = g.centres.shape[0]
    nxt = np.minimum(index + 1, n - 1)
    dt = g.section_times[nxt] - g.section_times[index]
    ahead = _planned_points(step_tables(g), nxt, eta, direction)
    ahead -= target
    moving = (index + 1 < n) & (dt > 0.0)
    ahead /= np.where(moving, dt, 1.0)[:, None]
    ahead[~moving] = 0.0
    return ahead


def step_trackers(trackers: list[Tracker], positions: FloatArray) -> list[TrackerTarget]:
    """Step several :class:`Tracker` objects of one geometry at once (see :func:`tracker_steps`).

    Parameters
    ----------
    trackers : list of Tracker, length B
        Trackers sharing one geometry, lookahead and replan tolerance.
    positions : array, shape (B, D)
        Live position of each tracker's stream.

    Returns
    -------
    list of TrackerTarget, length B
    """
    if not trackers:
        return []
    first = trackers[0]
    targets, states = tracker_steps(first.geometry, [t.state for t in trackers], positions,
                                    first.lookahead, first.replan_tolerance)
    for tracker, state in zip(trackers, states, strict=True):
        tracker.state = state
    return targets
