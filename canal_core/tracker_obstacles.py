"""Live targets around obstacles: the tracker's answers, corrected for a scene in one pass.

The tracker (:mod:`canal_core.tracker_bank`) answers each pose with the ratio rule's point a
few sections ahead. With a scene (:mod:`canal_core.obstacles`) each answer is then checked,
all rows at once, and corrected where needed:

* the robot inside an obstacle (or its clearance): the target backs away along the deepest
  obstacle's outward normal, by at most one step, or, where that leads into another
  obstacle, one step the way with the most room (``in_obstacle``);
* the straight move to the target keeps every clearance (the 1-Lipschitz test of
  :func:`canal_core.obstacles.segments_keep_clearance`, or the segment measured where its
  ends are too near an obstacle for it): the answer is the tracker's (``ok``);
* otherwise the target is the clear point of the target section nearest the tracker's
  (``detour``), among a polar grid of each section (:func:`canal_core.obstacles.section_candidates`,
  free distances precomputed per scene), no further from the robot than the tracker's own
  answer (or one step, when that is further) and at least half a step clear of every
  obstacle (so that the next move has room along the obstacle, not only away from it), or
  as clear as the section's clearest point where the scene leaves less room than that (a
  narrow passage is taken, keeping every obstacle's clearance);
* no such point in the target section (out of reach): one step towards the best of them when
  that step keeps clear (where the section's grid is coarser than a step), else the nearest
  clear point of an earlier section up to the robot's own (``detour``: it swerves before it
  goes on);
* before a section the scene closes (no clear candidate, or none a lane reaches from the
  section before: a plate between two planes), the robot goes on as far as it is free,
  nearest where it is, and holds there (``blocked``); a robot for which no move is found is
  held where it is and told so (``blocked``).

A candidate whose *lane* (the same point relative to each later section) runs into an
obstacle within a horizon of sections is taken only when no clear lane is in reach, and
then the one nearest a clear lane: the robot starts to swerve while there is room, instead
of meeting the obstacle head on.

A step is the demonstrations' largest step into or out of the robot's section
(:func:`canal_core.obstacles.demonstrated_steps`): their pace there, not the one far step a
demonstration may take where it sets off from aside or ends. Every quantity a pose needs is a
gather of the per-scene tables and a few vectorised operations over the rows: no Python
loop over poses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .obstacles import (
    Scene,
    backed_away_points,
    obstacle_free_distances,
    section_candidates,
    segment_free_distances,
    segments_clear,
)
from .tracker import TrackerGeometry
from .validation import FloatArray

#: Obstacle status of a live answer (the wire's status keys are these names).
OK, DETOUR, BLOCKED, IN_OBSTACLE = 0, 1, 2, 3
STATUS_NAMES = ("ok", "detour", "blocked", "in_obstacle")
#: A detour target keeps at least this share of a step of free distance beyond the clearance.
LIVE_MARGIN = 0.5


@dataclass(frozen=True, eq=False)
class SceneTables:
    """A scene measured once against one canal's sections.

    Attributes
    ----------
    scene : Scene
    version : int
        The scene's version (the skill's scene counter; 0 when it has none).
    candidates : array, shape (N, G, D)
        Polar grid of points inside each section.
    free : array, shape (N, G)
        Their free distance to the scene.
    closed : array of bool, shape (N,)
        Sections with no clear candidate.
    steps : array, shape (N,)
        The longest move of one answer around each section.
    margin : array, shape (N,)
        The free distance a detour target keeps in each section: :data:`LIVE_MARGIN` steps,
        or the section's clearest candidate's when that is less (0 where closed).
    lane_clear : array of bool, shape (N, G)
        Whether each candidate's *lane* (the same in-plane point, relative to each section's
        size and frame) keeps the margin over the next ``horizon`` sections, its steps from
        section to section clear too: a lane that is clear now but runs into an obstacle
        soon is left while there is room to.
    horizon : int
    lane_gap : array, shape (N, G)
        Distance from each candidate to the nearest candidate of its section whose lane is
        clear (inf when none is): a detour that cannot reach a clear lane in one answer
        heads for the nearest.
    closed_ahead : array of bool, shape (N,)
        Sections none of whose lanes is clear within the horizon: the scene closes the canal
        ahead of them, and a stream there is ``blocked`` (it moves on to the last free
        section and holds).
    usable : array of bool, shape (N, G)
        Candidates that keep their section's margin.
    closed_before : array of int, shape (N,)
        How many sections up to each are closed, or reached by no lane from the section
        before (a wall between two planes): a stream whose target lies past one more than
        its own section is ``blocked``.
    lane_penalty : array, shape (N, G)
        What a candidate on a blocked lane adds to its cost (0 on a clear lane, or where no
        lane of its section is clear): it is taken only when no clear lane is in reach, the
        one nearest a clear lane first.
    """

    scene: Scene
    version: int
    candidates: FloatArray
    free: FloatArray
    closed: NDArray[np.bool_]
    steps: FloatArray
    margin: FloatArray
    lane_clear: NDArray[np.bool_]
    horizon: int
    lane_gap: FloatArray
    closed_ahead: NDArray[np.bool_]
    usable: NDArray[np.bool_]
    closed_before: NDArray[np.intp]
    lane_penalty: FloatArray


def scene_tables(geometry: TrackerGeometry, scene: Scene, steps: FloatArray | float,
                 version: int = 0) -> SceneTables:
    """Measure ``scene`` against every section of ``geometry`` (one pass; a few ms).

    Parameters
    ----------
    geometry : TrackerGeometry
    scene : Scene
    steps : array, shape (N,), or float
        The longest move of one answer around each section (the demonstrations' largest
        step there, :attr:`canal_core.Canal.section_steps`); a number applies to every section.
    version : int
    """
    n, d = geometry.centres.shape
    step_k = np.broadcast_to(np.asarray(steps, dtype=np.float64), (n,)).copy()
    cand = section_candidates(np.arange(n), geometry.centres, geometry.basis, geometry.sections)
    g = cand.shape[1]
    if len(scene):
        free = obstacle_free_distances(cand.reshape(-1, d), scene).min(axis=1).reshape(n, g)
    else:
        free = np.full((n, g), np.inf)
    clearest = free.max(axis=1)
    closed = ~(clearest >= 0.0)
    # Half a step of room where the section has it (the next move goes along the obstacle,
    # not only away from it); in a narrower passage, the room there is. The step is the
    # demonstrations' usual one at most: one far crossing where they end must not shut
    # the goal off.
    step = float(np.median(step_k))
    margin = np.where(closed, 0.0, np.minimum(LIVE_MARGIN * np.minimum(step_k, step), clearest))
    usable = (free >= margin[:, None]) & ~closed[:, None]
    # The horizon: as many sections as a step's sideways room takes to cross the widest
    # section (as the offline detour's window), at least 3.
    spacing = float(np.median(np.sqrt((np.diff(geometry.centres, axis=0) ** 2).sum(axis=1)))) if n > 1 else 0.0
    sideways = np.sqrt(max(step**2 - spacing**2, 1e-300))
    widest = float(np.sqrt(((cand - geometry.centres[:, None, :]) ** 2).sum(axis=2)).max())
    horizon = int(np.clip(np.ceil(widest / sideways) + 2, 3, max(3, n // 3)))
    # Each lane's step to the next section: a wall between two planes holds no candidate,
    # but the steps across it run into it. Most steps pass the sufficient test of their ends'
    # free distances; the rest are measured.
    onward = usable[:-1] & usable[1:]  # (N - 1, G)
    if len(scene) and n > 1:
        rows, cols = np.nonzero(onward)
        onward[rows, cols] = segments_clear(cand[rows, cols], cand[rows + 1, cols], free[rows, cols],
                                            free[rows + 1, cols], scene)
    passable = np.vstack([onward, usable[-1:]])  # (N, G)
    # A section no lane reaches from the one before is closed to a stream before it.
    shut = closed.copy()
    shut[1:] |= ~onward.any(axis=1)
    clear_lane = passable.copy()
    for h in range(1, horizon + 1):
        clear_lane &= passable[np.minimum(np.arange(n) + h, n - 1)]
    gap = np.full((n, cand.shape[1]), np.inf)
    gap[clear_lane] = 0.0
    # Only sections with a blocked lane need the search (a few, around each obstacle).
    mixed = np.flatnonzero(~clear_lane.all(axis=1) & clear_lane.any(axis=1))
    rel = cand[mixed] - geometry.centres[mixed][:, None, :]  # small numbers: the expansion is exact enough
    sq = (rel**2).sum(axis=2)
    for lo in range(0, mixed.size, 32):  # (32, G, G) at a time, one batched matrix product each
        r = rel[lo : lo + 32]
        d2 = sq[lo : lo + 32, :, None] + sq[lo : lo + 32, None, :] - 2.0 * (r @ r.transpose(0, 2, 1))
        d2 = np.where(clear_lane[mixed[lo : lo + 32], None, :], d2, np.inf)
        gap[mixed[lo : lo + 32]] = np.sqrt(np.maximum(d2.min(axis=2), 0.0))
    closed_ahead: NDArray[np.bool_] = np.asarray(~clear_lane.any(axis=1), dtype=bool)
    scale2 = (step_k**2)[:, None]
    penalty = np.where(~clear_lane & np.isfinite(gap), 1e6 * scale2 + 1e3 * np.where(np.isfinite(gap), gap, 0.0) ** 2, 0.0)
    return SceneTables(scene, int(version), cand, free, closed, step_k, margin, clear_lane, horizon, gap,
                       closed_ahead, usable, np.cumsum(shut), penalty)


def avoided_targets(
    tables: SceneTables,
    positions: FloatArray,
    targets: FloatArray,
    section: NDArray[np.intp],
    target_section: NDArray[np.intp],
) -> tuple[FloatArray, NDArray[np.int8]]:
    """The tracker's targets corrected for the scene, and each row's obstacle status.

    Parameters
    ----------
    tables : SceneTables
    positions : array, shape (B, D)
        Live positions.
    targets : array, shape (B, D)
        The tracker's answers.
    section : array of int, shape (B,)
        Section each robot was located at.
    target_section : array of int, shape (B,)
        Section of each answer (>= ``section``).

    Returns
    -------
    targets : array, shape (B, D)
    status : array of int8, shape (B,)
        :data:`OK`, :data:`DETOUR`, :data:`BLOCKED` or :data:`IN_OBSTACLE`.
    """
    scene = tables.scene
    b = positions.shape[0]
    status = np.zeros(b, dtype=np.int8)
    out = np.array(targets, dtype=np.float64, copy=True)
    if not len(scene) or b == 0:
        return out, status
    each = obstacle_free_distances(np.concatenate([positions, out]), scene)  # (2B, O)
    fp_each = each[:b]
    fp = fp_each.min(axis=1)
    ft = each[b:].min(axis=1)
    clear = segments_clear(positions, out, fp, ft, scene)
    inside = ~(fp >= 0.0)  # NaN (a non-finite pose) counts as inside nothing: left as it is
    inside &= np.isfinite(fp)
    if inside.any():
        rows = np.flatnonzero(inside)
        out[rows] = backed_away_points(scene, positions[rows], fp_each[rows], tables.steps[section[rows]])
        status[rows] = IN_OBSTACLE
    # Anticipation: a clear move whose lane runs into an obstacle within the horizon is
    # detoured too, while there is still room to swerve.
    k = np.minimum(target_section, tables.candidates.shape[0] - 1)
    near = ((tables.candidates[k] - out[:, None, :]) ** 2).sum(axis=2).argmin(axis=1)
    ahead = ~tables.lane_clear[k, near]
    todo = np.flatnonzero((~clear | ahead) & ~inside & np.isfinite(fp))
    if todo.size:
        out[todo], status[todo] = _detoured(tables, positions[todo], out[todo], fp[todo],
                                            section[todo], target_section[todo])
    return out, status


def _detoured(
    tables: SceneTables,
    p: FloatArray,
    t: FloatArray,
    fp: FloatArray,
    section: NDArray[np.intp],
    target_section: NDArray[np.intp],
) -> tuple[FloatArray, NDArray[np.int8]]:
    """Rows whose straight move is not clear: the best clear candidate of the target section,
    or a step towards it, else of an earlier section (``detour``); before a closed section or
    with no move found, as far as it is free or where it is (``blocked``)."""
    r = p.shape[0]
    # A detour moves no further than the tracker's own answer would have, or one step.
    reach = np.maximum(np.sqrt(((t - p) ** 2).sum(axis=1)), tables.steps[section])
    n = tables.candidates.shape[0]
    # Tiers: the target section, then back to the robot's own section.
    depth = int(np.max(target_section - section, initial=0)) + 1
    out = p.copy()
    status = np.full(r, BLOCKED, dtype=np.int8)
    # Before a closed section (or one no lane reaches), the robot goes on as far as it is
    # free and holds nearest where it is, instead of sliding along what closes the canal.
    shut_all = tables.closed_ahead[target_section] | (
        tables.closed_before[target_section] > tables.closed_before[section])
    left = np.arange(r)
    for tier in range(depth):  # a handful of tiers (the lookahead + 1), on the rows left
        ts = target_section[left]
        sec = np.clip(ts - tier, np.minimum(section[left], ts), n - 1)
        cand = tables.candidates[sec]  # (L, G, D)
        pl = p[left]
        dist2 = ((cand - pl[:, None, :]) ** 2).sum(axis=2)
        free = tables.free[sec]
        in_reach = tables.usable[sec] & (dist2 <= reach[left, None] ** 2)
        lipschitz = np.minimum(fp[left, None] + free, reach[left, None])
        ok = in_reach & (dist2 <= lipschitz * lipschitz)
        # Nearest the tracker's target, among lanes clear ahead first.
        cost = ((cand - t[left, None, :]) ** 2).sum(axis=2) + tables.lane_penalty[sec]
        cost = np.where(shut_all[left, None], dist2, cost)
        best, hit = _cheapest(cost, ok)
        # In a passage narrower than a step the sufficient test clears no move: the rows
        # left measure their moves to the candidates in reach.
        unsure = np.flatnonzero(~hit & in_reach.any(axis=1))
        if unsure.size:
            rr, gg = np.nonzero(in_reach[unsure] & ~ok[unsure])
            ok[unsure[rr], gg] = segment_free_distances(pl[unsure[rr]], cand[unsure[rr], gg], tables.scene) >= 0.0
            best, hit = _cheapest(cost, ok)
        chosen = cand[np.arange(left.size), best]
        # None in reach (a section's grid is coarser than a step where the canal is wide): one
        # step towards the section's best clear point, when that step keeps clear.
        far = np.flatnonzero(~hit & tables.usable[sec].any(axis=1) & ~shut_all[left])
        if far.size:
            goal_best, _ = _cheapest(cost[far], tables.usable[sec[far]])
            toward = cand[far, goal_best] - pl[far]
            length = np.sqrt((toward**2).sum(axis=1))
            q = pl[far] + (np.minimum(1.0, reach[left[far]] / np.maximum(length, 1e-300)))[:, None] * toward
            moves = (length > 0.0) & (segment_free_distances(pl[far], q, tables.scene) >= 0.0)
            chosen[far[moves]] = q[moves]
            hit[far[moves]] = True
        rows = left[hit]
        out[rows] = chosen[hit]
        # Holding back in an earlier section is still a detour while the way to the target
        # section is open (the robot swerves first); it is blocked before a closed one.
        status[rows] = np.where(shut_all[rows], BLOCKED, DETOUR)
        left = left[~hit]
        if not left.size:
            break
    # A robot told to stay where it is, is held: it says so (it may stay held for good where
    # only a detour planned ahead, as a reproduction's, would go around).
    held = ((out - p) ** 2).sum(axis=1) <= (1e-9 * reach) ** 2
    status[held] = BLOCKED
    return out, status


def _cheapest(cost: FloatArray, ok: NDArray[np.bool_]) -> tuple[NDArray[np.intp], NDArray[np.bool_]]:
    """Each row's cheapest allowed column, and whether it has one."""
    masked = np.where(ok, cost, np.inf)
    best = masked.argmin(axis=1)
    return best, np.isfinite(masked[np.arange(cost.shape[0]), best])


__all__ = [
    "BLOCKED",
    "DETOUR",
    "IN_OBSTACLE",
    "LIVE_MARGIN",
    "OK",
    "STATUS_NAMES",
    "SceneTables",
    "avoided_targets",
    "scene_tables",
]
