"""A reactive one-step tracker: live position in, next ratio-rule target out.

The paper's reproduction is time-independent: the next point depends only on where the
robot is. :func:`tracker_step` makes that reactive. Each call locates the live position in
a small window of sections ahead of the last one reached (amortised O(1)), recomputes eta and
the direction from the live position (so a push changes the plan at once), and answers with
the ratio-rule point ``lookahead`` sections ahead.

Progress never goes back: the window starts one section behind the last index reached, so
a curve that comes back close to itself cannot pull the robot to an earlier section. If the
robot is not found in the window (it was pushed far ahead), the sections ahead are searched
once, vectorised, from the last index to the end.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .cross_sections import CrossSections, boundary_distance
from .validation import FloatArray

WINDOW = 16

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
    """

    target: FloatArray
    progress: float
    eta: float
    section_index: int
    inside: bool
    done: bool


@dataclass(frozen=True, eq=False)
class TrackerGeometry:
    """Arrays the tracker reads, precomputed once per model."""

    centres: FloatArray  # (N, D)
    tangents: FloatArray  # (N, D)
    basis: FloatArray  # (N, D - 1, D)
    offsets: FloatArray  # (N,) t_i . c_i
    sections: CrossSections
    done_tolerance: float


def tracker_geometry(
    centres: FloatArray, tangents: FloatArray, basis: FloatArray, sections: CrossSections
) -> TrackerGeometry:
    """Precompute the plane offsets t_i . c_i used by every step."""
    spacing = float(np.linalg.norm(np.diff(centres, axis=0), axis=1).mean()) if len(centres) > 1 else 0.0
    return TrackerGeometry(
        centres, tangents, basis, np.einsum("nd,nd->n", centres, tangents), sections, 1e-6 * spacing
    )


def _first_crossing(dist: FloatArray) -> int:
    """Index of the first sign change in ``dist`` (between k and k + 1), or -1."""
    change = (dist[:-1] == 0.0) | ((dist[:-1] > 0.0) != (dist[1:] > 0.0))
    first = int(change.argmax()) if change.size else 0
    return first if change.size and change[first] else -1


def tracker_step(
    geometry: TrackerGeometry, last_index: int, position: FloatArray, lookahead: int = 1
) -> tuple[TrackerTarget, int]:
    """One reactive step.

    Parameters
    ----------
    geometry : TrackerGeometry
    last_index : int
        Section reached so far (the tracker's state).
    position : array, shape (D,)
        Live position.
    lookahead : int
        Sections ahead of the located one to aim at (>= 1).

    Returns
    -------
    target : TrackerTarget
    last_index : int
        Updated state, never smaller than the one given.

    Notes
    -----
    This runs once per live pose (up to kHz per robot), so it is written for small-array
    overhead rather than elegance: one window product, scalar arithmetic in Python floats,
    and one boundary lookup for the two located sections and the target section together.
    """
    g = geometry
    n = g.centres.shape[0]
    lo = max(last_index - 1, 0)
    hi = min(last_index + WINDOW, n - 1)
    dist = g.tangents[lo : hi + 1] @ position - g.offsets[lo : hi + 1]
    hit = _first_crossing(dist)
    if hit >= 0:
        index = lo + hit
    elif dist[-1] > 0.0 and hi < n - 1:  # pushed ahead of the window: search forward once
        ahead = g.tangents[hi:] @ position - g.offsets[hi:]
        hit = _first_crossing(ahead)
        index = hi + hit if hit >= 0 else n - 2
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
    reach3 = boundary_distance(
        g.sections, np.array([index, upper, target_index]), direction[None, :].repeat(3, axis=0)
    )
    reach = (1.0 - alpha) * float(reach3[0]) + alpha * float(reach3[1])
    if reach > 0.0:
        eta = norm / reach
    else:
        eta = math.inf if norm > 0.0 else 0.0
    behind_start = index == 0 and d0 < 0.0
    past_end = index == n - 2 and d1 > 0.0
    inside = bool(eta <= 1.0 + 1e-9 and not behind_start and not past_end)

    target = g.centres[target_index] + (min(eta, 1.0) * float(reach3[2])) * (direction @ g.basis[target_index])
    last = n - 1
    # "Reached" up to a millionth of the mean section spacing: a robot converging on the
    # last target approaches its plane geometrically and would otherwise never cross it.
    done = bool(float(g.tangents[last] @ position) - float(g.offsets[last]) >= -g.done_tolerance)
    progress = 1.0 if done else (index + alpha) / max(n - 1, 1)
    return (
        TrackerTarget(target, float(progress), float(eta), index, inside, done),
        max(last_index, index),
    )


class Tracker:
    """Stateful wrapper around :func:`tracker_step` for one live stream."""

    def __init__(self, geometry: TrackerGeometry, lookahead: int = 1) -> None:
        self.geometry = geometry
        self.lookahead = lookahead
        self.index = 0

    def step(self, position: FloatArray) -> TrackerTarget:
        """Next target for the live ``position``, shape (D,)."""
        target, self.index = tracker_step(
            self.geometry, self.index, np.asarray(position, dtype=np.float64), self.lookahead
        )
        return target

    def reset(self, index: int = 0) -> None:
        """Start over (e.g. a new run, or a new model version)."""
        self.index = index
