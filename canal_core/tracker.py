"""A reactive one-step tracker: live position in, next ratio-rule target out.

The paper's reproduction is time-independent: the next point depends only on where the
robot is. :func:`tracker_step` makes that reactive. Each call locates the live position in
a small window of sections ahead of the last one reached (amortised O(1)) and answers with
the ratio-rule point ``lookahead`` sections ahead.

The ratio (eta) and in-plane direction the target is built from are the tracker's *plan*.
A real robot lags behind its target and cuts corners; recomputing the plan from the live
position at every step turns that lag into a drift (on a helix whose sections are spaced
about one canal radius apart, a first-order robot started at eta = 0.09 drifted out of the
canal within 25 sections). So the plan is kept while the live position stays within
``replan_tolerance`` (25 % of the local boundary distance) of where the plan puts it, and
the target pulls the robot back onto it; a larger deviation (a push, a new start) replaces
the plan by the live position's eta (at most ``MAX_PLAN_ETA``) and direction at once.
``TrackerTarget.eta`` always reports the live position's ratio.

Progress never goes back: the window starts one section behind the last index reached, so
a curve that comes back close to itself cannot pull the robot to an earlier section. If the
robot is not found in the window (it was pushed far ahead), the sections ahead are searched
once, vectorised, and the bracketing pair whose centre is nearest the robot is taken (the
first plane crossed could be a later turn of a helix). "Done" is only reported at the last
pair of sections, not anywhere in the last plane's half-space.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .cross_sections import CrossSections, boundary_distance
from .tracker_kernel import compiled_step_rows, packed_width
from .validation import FloatArray

WINDOW = 16
#: Batches of at least this many rows take :class:`TrackerBank`'s vectorised pass; a single
#: row the scalar step (one vectorised pass costs about what 2-2.5 scalar steps do, at any
#: batch size up to a few dozen rows: the cost is numpy calls, not rows).
VECTORISE_FROM = 2
#: The plan is kept while the live position is within this fraction of the local section's
#: boundary distance from it (see the module docstring).
REPLAN_TOLERANCE = 0.25
#: Largest planned ratio: positions nearer the boundary (or outside) are planned at this
#: eta, leaving a lagging robot a margin. Offline reproduction keeps the exact ratio.
MAX_PLAN_ETA = 0.9

# On the directrix eta = 0 and any direction gives the same point (as unit_directions does).
_DEFAULT_DIRECTIONS = {1: np.array([1.0]), 2: np.array([1.0, 0.0])}


@dataclass(frozen=True, eq=False)
class TrackerTarget:
    """One answer of the tracker.

    Attributes
    ----------
    target : array, shape (D,)
        Next position to move to.
    progress : float
        Fraction of the canal reached, in [0, 1].
    eta : float
        Ratio of the live position (clamped to 1 for the target when outside).
    section_index : int
        Section the live position was found at.
    inside : bool
        Whether the live position is inside the canal.
    done : bool
        Whether the live position has reached the last cross-section.
    velocity : array, shape (D,), or None
        Feed-forward velocity at the target, when the model knows one.
    orientation : array, shape (4,), or None
        Orientation to hold at the target, unit quaternion [qx, qy, qz, qw]: the mean
        orientation of the target's section when the canal learned orientation.
    """

    target: FloatArray
    progress: float
    eta: float
    section_index: int
    inside: bool
    done: bool
    velocity: FloatArray | None = None
    orientation: FloatArray | None = None


@dataclass(frozen=True, eq=False)
class TrackerState:
    """What a stream's tracker remembers between steps.

    Attributes
    ----------
    index : int
        Section reached so far (never decreases).
    eta : float or None
        Planned ratio; None until the first step (or after a reset).
    direction : array, shape (D - 1,), or None
        Planned unit in-plane direction.
    """

    index: int = 0
    eta: float | None = None
    direction: FloatArray | None = None


@dataclass(frozen=True, eq=False)
class TrackerGeometry:
    """Arrays the tracker reads, precomputed once per model."""

    centres: FloatArray  # (N, D)
    tangents: FloatArray  # (N, D)
    basis: FloatArray  # (N, D - 1, D)
    offsets: FloatArray  # (N,) t_i . c_i
    sections: CrossSections
    done_tolerance: float
    orientations: FloatArray | None = None  # (N, 4) section mean orientations, or None
    section_times: FloatArray | None = None  # (N,) mean seconds to each section

    @cached_property
    def step_tables(self) -> StepTables:
        """The arrays :func:`batched_tracker_step` gathers from (circle sections, N >= 2),
        built on first use."""
        return step_tables(self)


def tracker_geometry(
    centres: FloatArray,
    tangents: FloatArray,
    basis: FloatArray,
    sections: CrossSections,
    orientations: FloatArray | None = None,
    section_times: FloatArray | None = None,
) -> TrackerGeometry:
    """Precompute the plane offsets t_i . c_i used by every step.

    ``orientations`` (N, 4), the canal's section mean orientations, makes every target carry
    the one of its section; ``section_times`` (N,), the demonstrations' mean time to each
    section, gives targets a feed-forward velocity.
    """
    spacing = float(np.linalg.norm(np.diff(centres, axis=0), axis=1).mean()) if len(centres) > 1 else 0.0
    return TrackerGeometry(
        centres, tangents, basis, np.einsum("nd,nd->n", centres, tangents), sections, 1e-6 * spacing,
        orientations,
        section_times,
    )


def _first_crossing(dist: FloatArray) -> int:
    """Index of the first sign change in ``dist`` (between k and k + 1), or -1."""
    change = (dist[:-1] == 0.0) | ((dist[:-1] > 0.0) != (dist[1:] > 0.0))
    first = int(change.argmax()) if change.size else 0
    return first if change.size and change[first] else -1


def tracker_step(
    geometry: TrackerGeometry,
    state: TrackerState,
    position: FloatArray,
    lookahead: int = 1,
    replan_tolerance: float = REPLAN_TOLERANCE,
) -> tuple[TrackerTarget, TrackerState]:
    """One reactive step.

    Parameters
    ----------
    geometry : TrackerGeometry
    state : TrackerState
        The stream's state after the previous step (``TrackerState(index)`` to start).
    position : array, shape (D,)
        Live position.
    lookahead : int
        Sections ahead of the located one to aim at (>= 1).
    replan_tolerance : float
        Largest distance between the live position and the plan, as a fraction of the local
        section's boundary distance, that still keeps the plan (0 = replan every step).

    Returns
    -------
    target : TrackerTarget
    state : TrackerState
        Updated state; its index is never smaller than the one given.

    Notes
    -----
    This runs once per live pose (up to kHz per robot), so it is written for small-array
    overhead rather than elegance: one window product, scalar arithmetic in Python floats,
    and one boundary lookup for every section and direction it needs.
    """
    g = geometry
    n = g.centres.shape[0]
    last_index = state.index
    lo = max(last_index - 1, 0)
    hi = min(last_index + WINDOW, n - 1)
    dist = g.tangents[lo : hi + 1] @ position - g.offsets[lo : hi + 1]
    hit = _first_crossing(dist)
    if hit >= 0:
        index = lo + hit
    elif dist[-1] > 0.0 and hi < n - 1:  # pushed ahead of the window: search forward once
        index = _nearest_crossing_ahead(g, hi, position)
    elif dist[-1] > 0.0:  # past the last plane
        index = n - 2
    else:  # behind the window: hold the last section, never go back
        index = lo
    index = max(min(index, n - 2), 0)
    upper = min(index + 1, n - 1)
    d0 = float(g.tangents[index] @ position - g.offsets[index])
    d1 = float(g.tangents[upper] @ position - g.offsets[upper]) if n > 1 else d0
    alpha = min(max(d0 / (d0 - d1), 0.0), 1.0) if d0 != d1 else 0.0

    pair_q = np.einsum("nkd,nd->nk", g.basis[index : upper + 1], position - g.centres[index : upper + 1])
    q = (1.0 - alpha) * pair_q[0] + alpha * pair_q[-1]
    norm = math.sqrt(float(q @ q))
    direction = q / norm if norm > 0.0 else _DEFAULT_DIRECTIONS[q.shape[0]]
    target_index = min(index + max(lookahead, 1), n - 1)
    planned = state.direction is not None and state.eta is not None
    if g.sections.spec.isotropic:
        # The default kind: the boundary distance does not depend on the direction.
        radius = g.sections.params["radius"]
        r3 = (float(radius[index]), float(radius[upper]), float(radius[target_index]))
        reach6: tuple[float, ...] | FloatArray = r3 + r3
    elif planned:
        # One lookup for the live direction and the planned one at the three sections.
        reach6 = boundary_distance(
            g.sections,
            np.array([index, upper, target_index] * 2),
            np.repeat(np.array([direction, state.direction]), 3, axis=0),
        )
    else:
        reach6 = boundary_distance(
            g.sections, np.array([index, upper, target_index]), direction[None, :].repeat(3, axis=0)
        )
    reach = (1.0 - alpha) * float(reach6[0]) + alpha * float(reach6[1])
    if reach > 0.0:
        eta = norm / reach
    else:
        eta = math.inf if norm > 0.0 else 0.0

    # Plan a margin inside the boundary: a lagging robot asked to ride the boundary itself
    # hovers just outside it (a first-order robot settles about 0.05 in eta off its plan).
    plan_eta, plan_direction, plan_reach = min(eta, MAX_PLAN_ETA), direction, float(reach6[2])
    if planned:
        assert state.eta is not None and state.direction is not None
        ref_reach = (1.0 - alpha) * float(reach6[3]) + alpha * float(reach6[4])
        gap = q - (state.eta * ref_reach) * state.direction
        deviation = math.sqrt(float(gap @ gap))
        if deviation <= replan_tolerance * max(reach, ref_reach):
            plan_eta, plan_direction, plan_reach = state.eta, state.direction, float(reach6[5])

    behind_start = index == 0 and d0 < 0.0
    past_end = index == n - 2 and d1 > 0.0
    inside = bool(eta <= 1.0 + 1e-9 and not behind_start and not past_end)
    target = g.centres[target_index] + (plan_eta * plan_reach) * (plan_direction @ g.basis[target_index])
    last = n - 1
    # "Reached" up to a millionth of the mean section spacing: a robot converging on the
    # last target approaches its plane geometrically and would otherwise never cross it.
    # Only at the last pair of sections: elsewhere the last plane's half-space can hold
    # earlier parts of the canal (a helix, a loop).
    done = bool(
        index >= n - 2
        and float(g.tangents[last] @ position) - float(g.offsets[last]) >= -g.done_tolerance
    )
    progress = 1.0 if done else (index + alpha) / max(n - 1, 1)
    velocity = None
    if g.section_times is not None:
        velocity = _feed_forward(g, target_index, target, plan_eta, plan_direction)
    return (
        TrackerTarget(
            target, float(progress), float(eta), index, inside, done, velocity,
            orientation=None if g.orientations is None else g.orientations[target_index],
        ),
        TrackerState(max(last_index, index), plan_eta, plan_direction),
    )


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
    out, new_index, plan_eta, plan_dir = batched_tracker_step(
        g, index, eta, direction, positions, lookahead, replan_tolerance)
    velocity = out.velocity
    orientation = out.orientation
    targets = [
        TrackerTarget(out.target[r], prog, et, ix, ins, dn,
                      None if velocity is None else velocity[r],
                      None if orientation is None else orientation[r])
        for r, (prog, et, ix, ins, dn) in enumerate(zip(
            out.progress.tolist(), out.eta.tolist(), out.section_index.tolist(),
            out.inside.tolist(), out.done.tolist(), strict=True))]
    new_states = [TrackerState(ni, pe, plan_dir[r])
                  for r, (ni, pe) in enumerate(zip(new_index.tolist(), plan_eta.tolist(),
                                                   strict=True))]
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
    """

    lo: NDArray[np.intp]
    hi: NDArray[np.intp]
    window: FloatArray
    open_pairs: NDArray[np.bool_]
    pair: FloatArray
    radius: FloatArray
    frame: FloatArray
    default_direction: FloatArray


def step_tables(g: TrackerGeometry) -> StepTables:
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
        _DEFAULT_DIRECTIONS[d - 1])


def batched_tracker_step(
    g: TrackerGeometry,
    last_index: NDArray[np.intp],
    old_eta: FloatArray,
    old_dir: FloatArray,
    p: FloatArray,
    lookahead: int,
    replan_tolerance: float = REPLAN_TOLERANCE,
) -> tuple[TrackerBatch, NDArray[np.intp], FloatArray, FloatArray]:
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

    Returns
    -------
    answers : TrackerBatch
    index : array of int, shape (B,)
        Section reached after the step.
    plan_eta : array, shape (B,)
    plan_dir : array, shape (B, D - 1)
        The plan after the step.

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
    t = g.step_tables
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
        index = t.lo[last_index] + first
        # membership tests on short lists cost a tenth of an ndarray.any()
        if WINDOW + 1 in first.tolist():
            lost = np.flatnonzero(first > WINDOW)
            from_index = last_index[lost]
            index[lost] = _unplaced_sections(g, p[lost], t.lo[from_index], t.hi[from_index])
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
        at = index.tolist()
        if 0 in at:  # behind the first plane
            inside &= ~((index == 0) & (d0 < 0.0))
        if n - 2 in at:  # past the last plane; reached it (d1 is its distance)
            end = index == n - 2
            inside &= ~(end & (d1 > 0.0))
            done = end & (d1 >= -g.done_tolerance)
        target_index = index + max(int(lookahead), 1)
        np.minimum(target_index, n - 1, out=target_index)
        target = _planned_points(t, target_index, plan_eta, plan_dir)
        progress = index + alpha
        progress /= max(n - 1, 1)
        if True in done.tolist():
            progress[done] = 1.0
        velocity = None if g.section_times is None else _feed_forwards(
            g, target_index, target, plan_eta, plan_dir)
    orientation = None if g.orientations is None else g.orientations[target_index]
    answers = TrackerBatch(target, progress, eta, index, inside, done, velocity, orientation)
    return answers, np.maximum(last_index, index), plan_eta, plan_dir


def _planned_points(t: StepTables, index: NDArray[np.intp], eta: FloatArray,
                    direction: FloatArray) -> FloatArray:
    """The points at ratio ``eta`` (B,) in ``direction`` (B, D - 1) on sections ``index``
    (B,), shape (B, D): c + eta (direction . r basis), one product of [eta direction, 1]
    with the section's frame."""
    b, k = direction.shape
    scaled = np.empty((b, 1, k + 1))
    np.multiply(direction, eta[:, None], out=scaled[:, 0, :k])
    scaled[:, 0, k] = 1.0
    return (scaled @ t.frame[index])[:, 0]


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


def _feed_forward(
    g: TrackerGeometry, index: int, target: FloatArray, eta: float, direction: FloatArray
) -> FloatArray:
    """Velocity from ``target`` on section ``index`` to the planned point on the next section."""
    assert g.section_times is not None
    nxt = index + 1
    if nxt >= g.centres.shape[0]:
        return np.zeros_like(target)
    dt = float(g.section_times[nxt] - g.section_times[index])
    if dt <= 0.0:
        return np.zeros_like(target)
    if g.sections.spec.isotropic:
        reach = float(g.sections.params["radius"][nxt])
    else:
        reach = float(boundary_distance(g.sections, np.array([nxt]), direction[None, :])[0])
    ahead = g.centres[nxt] + (eta * reach) * (direction @ g.basis[nxt])
    return np.asarray((ahead - target) / dt, dtype=np.float64)


def _nearest_crossing_ahead(g: TrackerGeometry, start: int, position: FloatArray) -> int:
    """Among the plane pairs from ``start`` on that bracket ``position``, the one nearest it."""
    n = g.centres.shape[0]
    ahead = g.tangents[start:] @ position - g.offsets[start:]
    change = (ahead[:-1] == 0.0) | ((ahead[:-1] > 0.0) != (ahead[1:] > 0.0))
    hits = np.flatnonzero(change)
    if hits.size == 0:
        return n - 2
    gaps = np.linalg.norm(g.centres[start + hits] - position, axis=1)
    return int(start + hits[int(np.argmin(gaps))])


class Tracker:
    """Stateful wrapper around :func:`tracker_step` for one live stream."""

    def __init__(
        self, geometry: TrackerGeometry, lookahead: int = 1, replan_tolerance: float = REPLAN_TOLERANCE
    ) -> None:
        self.geometry = geometry
        self.lookahead = lookahead
        self.replan_tolerance = replan_tolerance
        self.state = TrackerState()

    @property
    def index(self) -> int:
        """Section reached so far."""
        return self.state.index

    def step(self, position: FloatArray) -> TrackerTarget:
        """Next target for the live ``position``, shape (D,)."""
        target, self.state = tracker_step(
            self.geometry,
            self.state,
            np.asarray(position, dtype=np.float64),
            self.lookahead,
            self.replan_tolerance,
        )
        return target

    def reset(self, index: int = 0) -> None:
        """Start over from section ``index`` with no plan (a new run, or a new model version)."""
        self.state = TrackerState(index)


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


class TrackerBank:
    """The tracker states of many streams of one model, held as arrays.

    A stream owns a *slot* (:meth:`add`); :meth:`step` steps any set of slots in one
    vectorised pass that reads and writes the state arrays directly, with no per-stream
    Python object on the way in or out. The answers equal :func:`tracker_step` on each
    slot's state (same sections, flags and plan; floats up to the last bits of a reordered
    sum). For circle sections (N >= 3) the pass is the compiled
    :func:`canal_core.tracker_kernel.step_rows` once it is compiled
    (:func:`canal_core.tracker_kernel.compile_step_rows`; about 1 us a call plus a fraction
    of a microsecond a row), else :func:`batched_tracker_step` (numpy, 30-60 us a call);
    non-circular sections, canals of fewer than three sections and numpy batches under
    :data:`VECTORISE_FROM` rows take the scalar step.

    Parameters
    ----------
    geometry : TrackerGeometry
    lookahead : int
        Sections ahead of the located one to aim at (>= 1).
    replan_tolerance : float
        As :func:`tracker_step`.
    capacity : int
        Slots allocated up front (the arrays double when full).
    compiled : bool
        Step with the compiled kernel when it is compiled (False: always numpy).
    """

    def __init__(self, geometry: TrackerGeometry, lookahead: int = 1,
                 replan_tolerance: float = REPLAN_TOLERANCE, capacity: int = 16,
                 compiled: bool = True) -> None:
        self.geometry = geometry
        self.lookahead = max(int(lookahead), 1)
        self.replan_tolerance = float(replan_tolerance)
        k = geometry.basis.shape[1]
        cap = max(int(capacity), 1)
        #: section reached per slot (never decreases while stepped)
        self.index = np.zeros(cap, dtype=np.intp)
        #: planned ratio per slot; NaN: no plan yet
        self.eta = np.full(cap, np.nan)
        #: planned unit in-plane direction per slot, shape (capacity, D - 1)
        self.direction = np.zeros((cap, k))
        self._free = list(range(cap - 1, -1, -1))
        self._isotropic = bool(geometry.sections.spec.isotropic) and geometry.centres.shape[0] >= 3
        self.compiled = bool(compiled)
        self._kernel_arrays: tuple[Any, ...] = ()
        if self._isotropic:
            # built with the bank (where a model is loaded), not by its first step, which
            # runs on a live worker while every other stream waits
            geometry.step_tables  # noqa: B018  # a cached property
            g = geometry
            self._kernel_arrays = tuple(np.ascontiguousarray(a, dtype=np.float64) for a in (
                g.centres, g.tangents, g.offsets, g.basis, g.step_tables.radius,
                np.zeros(0) if g.section_times is None else g.section_times,
                np.zeros((0, 4)) if g.orientations is None else g.orientations,
                g.step_tables.default_direction))

    def __len__(self) -> int:
        """Slots in use."""
        return int(self.index.shape[0]) - len(self._free)

    def add(self, index: int = 0) -> int:
        """A free slot, started at section ``index`` with no plan."""
        if not self._free:
            cap = self.index.shape[0]
            self.index = np.concatenate([self.index, np.zeros(cap, dtype=np.intp)])
            self.eta = np.concatenate([self.eta, np.full(cap, np.nan)])
            self.direction = np.concatenate([self.direction, np.zeros_like(self.direction)])
            self._free = list(range(2 * cap - 1, cap - 1, -1))
        slot = self._free.pop()
        self.reset(slot, index)
        return slot

    def release(self, slot: int) -> None:
        """Give ``slot`` back (its stream is gone)."""
        self.reset(slot, 0)
        self._free.append(int(slot))

    def reset(self, slot: int, index: int = 0) -> None:
        """Start ``slot`` over from section ``index`` (clamped to the canal's sections) with
        no plan."""
        self.index[slot] = min(max(int(index), 0), self.geometry.centres.shape[0] - 1)
        self.eta[slot] = np.nan

    def state(self, slot: int) -> TrackerState:
        """``slot``'s state as a :class:`TrackerState`."""
        eta = float(self.eta[slot])
        if math.isnan(eta):
            return TrackerState(int(self.index[slot]))
        return TrackerState(int(self.index[slot]), eta, self.direction[slot].copy())

    def step(self, slots: Any, positions: FloatArray) -> TrackerBatch:
        """Step the given slots (distinct) with their live positions, shape (B, D)."""
        p = np.asarray(positions, dtype=np.float64)
        kernel = self._kernel()
        if kernel is not None:
            return self._batch_of_rows(self._compiled_rows(kernel, slots, p))
        return self._numpy_step(slots, p)

    def step_packed(self, slots: Any, positions: FloatArray) -> FloatArray:
        """:meth:`step`'s answers packed one row per slot, as the compiled kernel writes
        them (:func:`canal_core.tracker_kernel.step_rows`): target (D), progress, eta,
        section, inside (1.0/0.0), done (1.0/0.0), velocity (D), orientation (4); velocity
        and orientation NaN when the model has none.

        Parameters
        ----------
        slots : sequence of int, length B
            Distinct slots.
        positions : array, shape (B, D)

        Returns
        -------
        rows : array, shape (B, 2 D + 9)
            A caller reads every answer with one ``tolist()`` (the live bridge's path).
        """
        p = np.asarray(positions, dtype=np.float64)
        kernel = self._kernel()
        if kernel is not None:
            return self._compiled_rows(kernel, slots, p)
        return self._rows_of_batch(self._numpy_step(slots, p))

    @property
    def has_velocity(self) -> bool:
        """Whether answers carry a feed-forward velocity (the model knows section times)."""
        return self.geometry.section_times is not None

    @property
    def has_orientation(self) -> bool:
        """Whether answers carry an orientation (the model learned orientations)."""
        return self.geometry.orientations is not None

    def _kernel(self) -> Any:
        """The compiled kernel this bank steps with, or None (numpy): circle sections only,
        once compiled, unless the bank was made with ``compiled=False``."""
        return compiled_step_rows() if self._isotropic and self.compiled else None

    def _numpy_step(self, slots: Any, p: FloatArray) -> TrackerBatch:
        b = p.shape[0]
        if b == 1 and (VECTORISE_FROM > 1 or not self._isotropic):
            return self._one(int(slots[0]), p[0])
        slots = np.asarray(slots, dtype=np.intp)
        if self._isotropic and b >= VECTORISE_FROM:
            return self._vectorised(slots, p)
        with np.errstate(all="ignore"):  # far poses overflow; their rows answer outside
            out = self._empty(b)
            if b:
                self._scalar(np.arange(b), slots, p, out)
        return out

    def _compiled_rows(self, kernel: Any, slots: Any, p: FloatArray) -> FloatArray:
        """Every row through the compiled kernel, state read and written in the slot arrays;
        the answers packed (:meth:`step_packed`). The argument types are exactly the
        kernel's one compiled signature (it is called without numba's type dispatch)."""
        g = self.geometry
        b, d = p.shape
        out = np.empty((b, packed_width(d)))
        kernel(*self._kernel_arrays, np.array(slots, dtype=np.intp),
               np.ascontiguousarray(p), self.index, self.eta, self.direction, self.lookahead,
               WINDOW, self.replan_tolerance, MAX_PLAN_ETA, float(g.done_tolerance), out)
        return out

    def _batch_of_rows(self, rows: FloatArray) -> TrackerBatch:
        d = self.geometry.centres.shape[1]
        return TrackerBatch(
            rows[:, :d].copy(), rows[:, d].copy(), rows[:, d + 1].copy(),
            rows[:, d + 2].astype(np.intp), rows[:, d + 3] != 0.0, rows[:, d + 4] != 0.0,
            rows[:, d + 5:2 * d + 5].copy() if self.has_velocity else None,
            rows[:, 2 * d + 5:].copy() if self.has_orientation else None)

    def _rows_of_batch(self, res: TrackerBatch) -> FloatArray:
        b, d = res.target.shape
        rows = np.full((b, packed_width(d)), np.nan)
        rows[:, :d] = res.target
        rows[:, d] = res.progress
        rows[:, d + 1] = res.eta
        rows[:, d + 2] = res.section_index
        rows[:, d + 3] = res.inside
        rows[:, d + 4] = res.done
        if res.velocity is not None:
            rows[:, d + 5:2 * d + 5] = res.velocity
        if res.orientation is not None:
            rows[:, 2 * d + 5:] = res.orientation
        return rows

    def _one(self, slot: int, position: FloatArray) -> TrackerBatch:
        """One row (a drain of one pose, the common case of a keeping-up bridge): the
        scalar step on the slot's state, its answer as 1-row arrays."""
        with np.errstate(all="ignore"):  # far poses overflow; their rows answer outside
            t, st = tracker_step(self.geometry, self.state(slot), position, self.lookahead,
                                 self.replan_tolerance)
        self._keep(slot, st)
        return TrackerBatch(
            t.target[None, :], np.array([t.progress]), np.array([t.eta]),
            np.array([t.section_index], dtype=np.intp), np.array([t.inside]),
            np.array([t.done]), None if t.velocity is None else t.velocity[None, :],
            None if t.orientation is None else t.orientation[None, :].copy())

    def _keep(self, slot: int, st: TrackerState) -> None:
        """A scalar step's new state, written into ``slot``'s arrays."""
        self.index[slot] = st.index
        if st.eta is None or st.direction is None:
            self.eta[slot] = np.nan
        else:
            self.eta[slot] = st.eta
            self.direction[slot] = st.direction

    def _empty(self, b: int) -> TrackerBatch:
        g = self.geometry
        d = g.centres.shape[1]
        return TrackerBatch(
            np.empty((b, d)), np.empty(b), np.empty(b), np.empty(b, dtype=np.intp),
            np.empty(b, dtype=bool), np.empty(b, dtype=bool),
            None if g.section_times is None else np.empty((b, d)),
            None if g.orientations is None else np.empty((b, 4)))

    def _scalar(self, rows: NDArray[np.intp], slots: NDArray[np.intp], p: FloatArray,
                out: TrackerBatch) -> None:
        for r in rows.tolist():
            slot = int(slots[r])
            t, st = tracker_step(self.geometry, self.state(slot), p[r], self.lookahead,
                                 self.replan_tolerance)
            self._keep(slot, st)
            out.target[r] = t.target
            out.progress[r], out.eta[r], out.section_index[r] = t.progress, t.eta, t.section_index
            out.inside[r], out.done[r] = t.inside, t.done
            if out.velocity is not None and t.velocity is not None:
                out.velocity[r] = t.velocity
            if out.orientation is not None and t.orientation is not None:
                out.orientation[r] = t.orientation

    def _vectorised(self, slots: NDArray[np.intp], p: FloatArray) -> TrackerBatch:
        """Every row in one pass (:func:`batched_tracker_step`), state read and written in
        the slot arrays."""
        out, self.index[slots], self.eta[slots], self.direction[slots] = batched_tracker_step(
            self.geometry, self.index[slots], self.eta[slots], self.direction[slots], p,
            self.lookahead, self.replan_tolerance)
        return out


def _feed_forwards(g: TrackerGeometry, index: NDArray[np.intp], target: FloatArray,
                   eta: FloatArray, direction: FloatArray) -> FloatArray:
    """:func:`_feed_forward` for many rows of circle sections, shapes (B,), (B, D), (B,),
    (B, D - 1)."""
    assert g.section_times is not None
    n = g.centres.shape[0]
    nxt = np.minimum(index + 1, n - 1)
    dt = g.section_times[nxt] - g.section_times[index]
    ahead = _planned_points(g.step_tables, nxt, eta, direction)
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
