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
``TrackerTarget.eta`` always reports the live position's ratio. On the inner side of a turn
tighter than the canal is wide, a target's ratio (not the plan's) is capped by the tube
condition (F1 of :mod:`canal_core.tube`), so that targets never fall behind the ones before.

Progress never goes back: the window starts one section behind the last index reached, so
a curve that comes back close to itself cannot pull the robot to an earlier section, and the
target is aimed from the section reached, never from one behind it. Where the canal turns
tighter than it is wide (or widens fast as it turns), neighbouring planes cross inside it: a
position can lie in front of a plane and behind the one before it. A robot on or in front
of a plane up to ``lookahead`` past the section it is located at has passed it, so a robot
that reached its target is placed at the target's section; otherwise it would stand still on
its target for good. If the
robot is not found in the window (it was pushed far ahead), the sections ahead are searched
once, vectorised, and the bracketing pair whose centre is nearest the robot is taken (the
first plane crossed could be a later turn of a helix). "Done" is only reported at the last
pair of sections, not anywhere in the last plane's half-space.

Plausible steps: one glitch sample (a sensor spike, one pose in the wrong frame) must not
move a robot's plan, and progress never goes back, so a stream with a plan takes a pose as
it takes any only when it is *plausible*: located at most :data:`MAX_ADVANCE` sections past
the section reached, and not far from the canal (its ratio at most :data:`FAR_ETA`, and not
more than :data:`FAR_ETA` local radii before the first plane or beyond the last). A suspect
pose changes nothing: it is answered from the stream's last plausible state (the target
``lookahead`` sections past the section reached, on the kept plan), as outside the canal,
with its own live ratio. :data:`SUSTAIN` consecutive suspect poses that agree (each within
:data:`FAR_ETA` local radii of the one before, or near the canal, ahead of the one
before along its section's tangent, within :data:`FAR_ETA` local radii of the line
through it along that tangent and at most :data:`MAX_ONWARD` sections ahead of it) are a
real displacement (a push, a robot moved by
hand along the canal): the last of them is taken as any pose is, as if it had come first,
and so is every next one that agrees. A stream with no
plan yet (a new stream, a restart) has no plausible state to hold: a pose near the canal is
taken wherever it is located, a far one is answered with the entry the canal gives it (the
located section ahead, at :data:`MAX_PLAN_ETA` in its direction) and leaves the stream
unplaced. The rule counts poses, not seconds: at 1 kHz a robot advances a few hundredths of
a section a pose, so :data:`MAX_ADVANCE` is wide for any stream faster than about 10 Hz;
a slower stream moving faster than that is followed :data:`SUSTAIN` poses late.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .cross_sections import CrossSections, boundary_distance, section_radii
from .tube import TUBE_MARGIN, in_plane_curvature
from .validation import FloatArray, check_point

WINDOW = 16
#: The plan is kept while the live position is within this fraction of the local section's
#: boundary distance from it (see the module docstring).
REPLAN_TOLERANCE = 0.25
#: Largest planned ratio: positions nearer the boundary (or outside) are planned at this
#: eta, leaving a lagging robot a margin. Offline reproduction keeps the exact ratio.
MAX_PLAN_ETA = 0.9
#: Most sections one pose may advance a stream's section reached (see "Plausible steps" in
#: the module docstring); a pose located further ahead is suspect.
MAX_ADVANCE = 8
#: A pose whose ratio exceeds this, or that lies more than this many local radii beyond the
#: first or the last plane, is far from the canal: suspect.
FAR_ETA = 3.0
#: Most sections a suspect pose may run ahead of the one before and still agree with it
#: (measured as the chord of that many sections before the pose's; see "Plausible steps" in
#: the module docstring).
MAX_ONWARD = 4 * MAX_ADVANCE
#: Consecutive suspect poses, each within :data:`FAR_ETA` local radii of the one before,
#: taken as a real displacement: the SUSTAIN-th is followed as any pose is.
SUSTAIN = 4

# On the directrix eta = 0 and any direction gives the same point (as unit_directions does).
DEFAULT_DIRECTIONS = {1: np.array([1.0]), 2: np.array([1.0, 0.0])}


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
    pending : array, shape (D,), or None
        The last suspect pose's position (None: the last pose was plausible).
    strikes : int
        Consecutive suspect poses that agree, up to :data:`SUSTAIN` (see the module
        docstring; 0: the last pose was plausible).
    """

    index: int = 0
    eta: float | None = None
    direction: FloatArray | None = None
    pending: FloatArray | None = None
    strikes: int = 0


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
    # (N, D - 1) b_k of the tube condition (F1); None where no plan can reach it (uncapped)
    curvature: FloatArray | None = None


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
    steps = np.linalg.norm(np.diff(centres, axis=0), axis=1)
    spacing = float(steps.mean()) if len(centres) > 1 else 0.0
    curvature = in_plane_curvature(tangents, basis, np.concatenate([[0.0], np.cumsum(steps)]))
    # A plan never exceeds MAX_PLAN_ETA: a canal whose widest offsets stay clear of every
    # centre of curvature needs no cap, and its steps skip it.
    folds = bool(np.any(MAX_PLAN_ETA * section_radii(sections) * np.linalg.norm(curvature, axis=1) > TUBE_MARGIN))
    return TrackerGeometry(
        centres, tangents, basis, np.einsum("nd,nd->n", centres, tangents), sections, 1e-6 * spacing,
        orientations,
        section_times,
        curvature if folds else None,
    )


def planned_point(g: TrackerGeometry, index: int, eta: float, reach: float, direction: FloatArray) -> FloatArray:
    """The point at ratio ``eta`` along ``direction`` (D - 1,) on section ``index`` (boundary
    distance ``reach`` there), the ratio capped by the tube condition (F1 of
    :mod:`canal_core.tube`): a target on the inner side of a tight turn never falls behind
    the one before it."""
    if g.curvature is not None:
        bend = reach * float(direction @ g.curvature[index])
        if bend > 0.0 and eta * bend > TUBE_MARGIN:
            eta = TUBE_MARGIN / bend
    return np.asarray(g.centres[index] + (eta * reach) * (direction @ g.basis[index]), dtype=np.float64)


def _first_crossing(dist: FloatArray) -> int:
    """Index of the first sign change in ``dist`` (between k and k + 1), or -1."""
    change = (dist[:-1] == 0.0) | ((dist[:-1] > 0.0) != (dist[1:] > 0.0))
    first = int(change.argmax()) if change.size else 0
    return first if change.size and change[first] else -1


def _passed_planes(dist: FloatArray, hit: int, reached: int, lookahead: int, tolerance: float) -> int:
    """The window's first crossing ``hit``, or the furthest plane up to ``lookahead`` past
    ``hit`` or past the section ``reached`` (all window positions) that the position is on or
    in front of (up to ``tolerance``).

    Where the canal turns tighter than it is wide, or widens fast as it turns, neighbouring
    planes cross inside it, and a robot on its target (``lookahead`` planes ahead) can still
    lie behind a plane in between: the first crossing then stays where it was, the target
    with it, and the robot stood still on its target for good (or went back and forth
    between two targets, the further one behind the nearer one's plane). A robot on or in
    front of a plane has passed it. The tolerance is the one "done" allows: a robot
    converging on its target approaches that plane geometrically and would otherwise be on
    it only by rounding.
    """
    last = min(max(hit, reached) + max(lookahead, 1), dist.shape[0] - 1)
    for ahead in range(last, hit, -1):
        if dist[ahead] >= -tolerance:
            return ahead
    return hit


def tracker_step(
    geometry: TrackerGeometry,
    state: TrackerState,
    position: FloatArray,
    lookahead: int = 1,
    replan_tolerance: float = REPLAN_TOLERANCE,
) -> tuple[TrackerTarget, TrackerState]:
    """One reactive step (a suspect pose is held: see "Plausible steps" in the module
    docstring).

    Parameters
    ----------
    geometry : TrackerGeometry
    state : TrackerState
        The stream's state after the previous step (``TrackerState(index)`` to start).
    position : array, shape (D,)
        Live position, finite (not checked here: :meth:`Tracker.step` and the bridge's
        decoding refuse a NaN, which this step would locate on the directrix).
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
    planned = state.direction is not None and state.eta is not None
    lo = max(last_index - 1, 0)
    hi = min(last_index + WINDOW, n - 1)
    dist = g.tangents[lo : hi + 1] @ position - g.offsets[lo : hi + 1]
    hit = _first_crossing(dist)
    if hit >= 0:
        index = lo + _passed_planes(dist, hit, last_index - lo, lookahead, g.done_tolerance)
    elif dist[-1] > 0.0 and hi < n - 1:  # pushed ahead of the window: search forward once
        index = _nearest_crossing_ahead(g, hi, position)
    elif dist[-1] > 0.0:  # past the last plane
        index = n - 2
    else:  # behind the window: hold the last section, never go back (unless a plane is passed)
        index = lo + _passed_planes(dist, 0, last_index - lo, lookahead, g.done_tolerance)
    index = max(min(index, n - 2), 0)
    upper = min(index + 1, n - 1)
    d0 = float(g.tangents[index] @ position - g.offsets[index])
    d1 = float(g.tangents[upper] @ position - g.offsets[upper]) if n > 1 else d0
    alpha = min(max(d0 / (d0 - d1), 0.0), 1.0) if d0 != d1 else 0.0

    pair_q = np.einsum("nkd,nd->nk", g.basis[index : upper + 1], position - g.centres[index : upper + 1])
    q = (1.0 - alpha) * pair_q[0] + alpha * pair_q[-1]
    norm = math.sqrt(float(q @ q))
    direction = q / norm if norm > 0.0 else DEFAULT_DIRECTIONS[q.shape[0]]
    # Aimed from the section reached, not from a pose located one behind it (the window
    # starts there): a target never goes back, or a robot on a canal whose planes cross
    # inside it could go back and forth for good between a target and the one before it.
    target_index = min(max(index, last_index) + max(lookahead, 1), n - 1)
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
    # plausible steps (module docstring): a suspect pose of a stream with a plan is held
    unplaced = False
    pending, strikes = None, 0
    far = is_far(eta, d0, d1, reach)
    if far or (planned and index - last_index > MAX_ADVANCE):
        if not planned:  # nothing plausible to hold: the entry, the stream left unplaced
            unplaced = True
        else:
            onward = not far and state.pending is not None and is_onward(
                g.tangents[index], position - state.pending, reach,
                float(np.linalg.norm(g.centres[index] - g.centres[max(index - MAX_ONWARD, 0)])))
            strikes = suspect_strikes(state.pending, state.strikes, position, reach, onward)
            pending = np.array(position, dtype=np.float64)
            if strikes < SUSTAIN or not math.isfinite(eta):  # an overflow is never followed
                return _held_answer(g, state, eta, lookahead), \
                    TrackerState(last_index, state.eta, state.direction, pending, strikes)

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
    # On the last plane up to the tolerance "done" allows: a robot on its final target is in.
    past_end = index == n - 2 and d1 > g.done_tolerance
    inside = bool(eta <= 1.0 + 1e-9 and not behind_start and not past_end)
    target = planned_point(g, target_index, plan_eta, plan_reach, plan_direction)
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
        state if unplaced else TrackerState(max(last_index, index), plan_eta, plan_direction,
                                            pending, strikes),
    )


def start_section(geometry: TrackerGeometry, position: FloatArray, located: int) -> int:
    """The section a stream with no plan starts from: ``located`` (where the canal locates
    the stream's first ``position``, shape (D,)) when the position is near the canal there,
    else 0 (a first pose far from the canal, perhaps a glitch, must not place the stream:
    :func:`tracker_step` then answers it with the entry and places the stream at its first
    pose near the canal)."""
    n = geometry.centres.shape[0]
    state = TrackerState(min(max(int(located), 0), max(n - 1, 0)))
    with np.errstate(all="ignore"):
        _, after = tracker_step(geometry, state, np.asarray(position, dtype=np.float64))
    # a far pose leaves a stream with no plan as it was (the very same state)
    return state.index if after is not state else 0


def plausible_from(geometry: TrackerGeometry, index: int, position: FloatArray) -> bool:
    """Whether a stream that has reached section ``index`` (with a plan) would take
    ``position``, shape (D,), as a plausible step: near the canal and at most
    :data:`MAX_ADVANCE` sections ahead (see "Plausible steps" in the module docstring)."""
    n, k = geometry.centres.shape[0], geometry.basis.shape[1]
    state = TrackerState(min(max(int(index), 0), max(n - 1, 0)), 0.0, DEFAULT_DIRECTIONS[k])
    with np.errstate(all="ignore"):
        _, after = tracker_step(geometry, state, np.asarray(position, dtype=np.float64))
    return after.strikes == 0


def poses_agree(geometry: TrackerGeometry, position: FloatArray, previous: FloatArray) -> bool:
    """Whether ``position``, shape (D,), lies within :data:`FAR_ETA` radii of the canal's
    widest section of ``previous`` (D,), the pose before it: whether two poses of a robot
    that jumped (a restart to be confirmed) are one place, wherever along the canal that is
    (a canal narrow at its goal must not keep a robot that left it from agreeing with
    itself)."""
    radius = float(np.max(section_radii(geometry.sections)))
    gap = np.asarray(position, dtype=np.float64) - np.asarray(previous, dtype=np.float64)
    return bool(math.sqrt(float(gap @ gap)) <= FAR_ETA * radius)


def located_section(geometry: TrackerGeometry, position: FloatArray) -> int:
    """The section the whole canal places ``position``, shape (D,), at, ignoring where a
    stream has reached: of the plane pairs that bracket it, the one whose centre is nearest
    (the search :func:`tracker_step` makes ahead of a stream, made from the first section)."""
    return _nearest_crossing_ahead(geometry, 0, np.asarray(position, dtype=np.float64))


def direction_in_plane(direction: FloatArray, from_basis: FloatArray,
                       to_basis: FloatArray) -> FloatArray:
    """The unit in-plane direction, shape (D - 1,), on a section of basis ``to_basis``
    (D - 1, D) that points where ``direction`` (D - 1,) points on a section of basis
    ``from_basis`` (D - 1, D): a plan carried from one canal to another (a refit), whose
    sections' frames may turn. The default direction when the two planes are at right angles."""
    projected = to_basis @ (np.asarray(direction, dtype=np.float64) @ from_basis)
    norm = float(np.linalg.norm(projected))
    if not norm > 1e-12:
        return DEFAULT_DIRECTIONS[to_basis.shape[0]].copy()
    return np.asarray(projected / norm, dtype=np.float64)


def is_far(eta: float, d0: float, d1: float, reach: float) -> bool:
    """Whether a pose is far from the canal: its ratio ``eta`` above :data:`FAR_ETA` (or
    not a number), or it lies more than :data:`FAR_ETA` times the local ``reach`` outside
    the pair of planes it was located between (``d0`` < 0: behind the first of them, ``d1``
    > 0: beyond the second; signed plane distances)."""
    return not eta <= FAR_ETA or d0 < -FAR_ETA * reach or d1 > FAR_ETA * reach


def is_onward(tangent: FloatArray, gap: FloatArray, reach: float, most: float) -> bool:
    """Whether a suspect pose near the canal ran on from the suspect pose before it, ``gap``
    (D,) behind it: ahead along the pose's section ``tangent`` (D,) by at most ``most`` (the
    chord of :data:`MAX_ONWARD` sections), and within :data:`FAR_ETA` local ``reach`` of the
    line through the pose before along that tangent (an arm moved along the canal, not a
    glitch on the canal after a pose held beside it or stale poses from behind)."""
    along = float(tangent @ gap)
    across = float(gap @ gap) - along * along
    return 0.0 < along <= most and across <= (FAR_ETA * reach) ** 2


def suspect_strikes(pending: FloatArray | None, strikes: int, position: FloatArray,
                    reach: float, onward: bool = False) -> int:
    """Consecutive agreeing suspect poses once a suspect pose at ``position`` (D,) has come:
    the streak goes on when the previous pose was suspect too (``strikes`` > 0, at
    ``pending``) and either lies within :data:`FAR_ETA` local reaches of it or ``onward``
    holds (the pose is near the canal, suspect only for its advance, and lies ahead of the
    previous one along its section's tangent: an arm moved along the canal faster than a
    slow stream's poses keep up with); else it starts over at 1. At most :data:`SUSTAIN`
    (a followed displacement stays followed while its poses agree)."""
    if strikes > 0 and pending is not None:
        if onward:
            return min(strikes + 1, SUSTAIN)
        gap = position - pending
        if math.sqrt(float(gap @ gap)) <= FAR_ETA * reach:
            return min(strikes + 1, SUSTAIN)
    return 1


def _held_answer(g: TrackerGeometry, state: TrackerState, eta: float,
                 lookahead: int) -> TrackerTarget:
    """The answer to a suspect pose of a stream with a plan: its last plausible state's (the
    target ``lookahead`` sections past the section reached, on the kept plan), outside the
    canal, with the pose's live ratio ``eta``."""
    assert state.eta is not None and state.direction is not None
    n = g.centres.shape[0]
    hold = max(min(state.index, n - 2), 0)
    target_index = min(hold + max(lookahead, 1), n - 1)
    if g.sections.spec.isotropic:
        reach = float(g.sections.params["radius"][target_index])
    else:
        reach = float(boundary_distance(g.sections, np.array([target_index]),
                                        state.direction[None, :])[0])
    target = planned_point(g, target_index, state.eta, reach, state.direction)
    velocity = None
    if g.section_times is not None:
        velocity = _feed_forward(g, target_index, target, state.eta, state.direction)
    return TrackerTarget(
        target, float(hold / max(n - 1, 1)), float(eta), hold, False, False, velocity,
        orientation=None if g.orientations is None else g.orientations[target_index])



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
    ahead = planned_point(g, nxt, eta, reach, direction)
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
        """Next target for the live ``position``, shape (D,), finite (else
        InvalidInputError on ``position``, and the stream is left as it was: a NaN has no
        place to locate, and :func:`tracker_step` would read it as the directrix). A
        finite pose however far, even one whose squares overflow, is the rule's to hold."""
        point = position
        dim = self.geometry.centres.shape[1]
        # at 1 kHz the usual float64 (D,) array is checked at a fifth of check_point's cost
        if not (type(point) is np.ndarray and point.dtype == np.float64 and point.shape == (dim,)
                and all(map(math.isfinite, point.tolist()))):
            point = check_point(position, dim, "position")
        target, self.state = tracker_step(
            self.geometry,
            self.state,
            point,
            self.lookahead,
            self.replan_tolerance,
        )
        return target

    def reset(self, index: int = 0) -> None:
        """Start over from section ``index`` with no plan (a new run, or a new model version)."""
        self.state = TrackerState(index)
