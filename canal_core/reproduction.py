"""A reproduction (Alg. 1 lines 7-15) on a fitted canal: :func:`reproduce` composes the step
functions of :mod:`canal_core.reproduce`, :mod:`canal_core.timing` and
:mod:`canal_core.orientation`; :meth:`canal_core.model.Canal.reproduce_detailed` calls it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from .bounds import check_duration, check_reach
from .entry import approach_shares, entry_fraction, paced_approach_shares
from .errors import OutsideCanalError
from .lone import lone_path
from .obstacles import (
    Blocked,
    avoided_path,
    backed_out_path,
    demonstrated_largest_step,
    scene_from_list,
)
from .options import OUTSIDE_RULES, PERSISTENCES
from .orientation import hemisphere_continuous, slerped
from .reproduce import (
    CONTAINS_TOLERANCE,
    END_DECAY,
    ENTRY_FRACTION,
    PERSISTENCE_PRIOR_WEIGHT,
    end_faded,
    learned_persistence,
    located_inside,
    path_ratios,
    ratio_rule_positions,
    reach_along,
    section_ratios,
    start_and_located_points,
)
from .timing import (
    arc_length_times,
    finite_velocities,
    reproduction_times,
    rescaled_times,
    speed_limited_times,
    strictly_increasing,
    top_speed,
)
from .tube import paced_offsets, tube_ratio_caps, wall_slope_shares
from .validation import (
    BoolArray,
    FloatArray,
    check_choice,
    check_fraction,
    check_point,
    check_quaternion,
)

if TYPE_CHECKING:
    from .model import Canal


@dataclass(frozen=True, eq=False)
class Reproduction:
    """A trajectory reproduced by the ratio rule.

    Attributes
    ----------
    positions : array, shape (N', D)
        The start, then one point per remaining cross-section, ending on the last one. A
        start behind the first plane first approaches the first of them along a straight
        line, in ``approach`` points (:func:`canal_core.entry.approach_shares`, (E4)); so
        does a start outside whose first point lies farther than a demonstration stepped
        there, one demonstrated step at a time (E5).
    start : array, shape (D,)
    inside : bool
        Whether the start lies inside the canal.
    eta : float
        Ratio the trajectory follows after the start (the start's, at most 1); it fades to 0
        into the last sections (see :func:`canal_core.reproduce.path_ratios`).
    section_index : int
        Section the start was located at.
    projected : bool
        True when the start's ratio exceeded 1: the path enters the canal over the entry
        blend and then follows the boundary's ratio 1.
    times : array, shape (N',), or None
        Seconds from the start, following the demonstrations' mean speed profile (None
        when they carried no time stamps and no duration was asked for).
    velocities : array, shape (N', D), or None
        Finite differences of ``positions`` over ``times`` (zero at the end).
    orientations : array, shape (N', 4), or None
        One unit quaternion [qx, qy, qz, qw] per position when the canal learned orientation
        (see :mod:`canal_core.orientation`): the start orientation (or its section's mean),
        then the rotational ratio rule. Hemisphere-continuous.
    orientation_eta : float or None
        The start orientation's angle from its section mean over the section's spread,
        before clamping to 1 (None without a start orientation or orientation model).
    goal : array, shape (D,), or None
        The goal the canal was deformed to, when one was given.
    blocked : Blocked or None
        When obstacles close the canal: the section the reproduction cannot enter and why;
        ``positions`` (and times, orientations) then end at the section before it.
    detoured : array of bool, shape (N' - 1,), or None
        With obstacles: which points left the ratio rule's path to go around them.
    start_clearance : float or None
        With obstacles: the start's distance to the nearest one minus its clearance
        (negative: the start is inside it; the path leaves it first).
    entry_index : int
        Index in ``positions`` of the first point inside the canal: every later point of
        the ratio rule's path is inside too (0 for a start inside; for a start outside,
        where the learned entry or the entry blend brought the path in).
    approach : int
        Points between the start and the ratio rule's first point, on the straight line
        from a start behind the first plane (E4) or from a start outside farther from that
        point than a demonstration stepped there (E5); 0 for any other start.
    ratios : array, shape (N',), or None
        How far out each position is, as a share of the canal's reach in its direction: the
        start's own ratio (above 1 outside the canal), the approach's points read in the
        first plane (E4) or in the start's own plane (E5), then each point in the plane of
        its section. Where the path follows the ratio rule this is its schedule (entry, learned persistence, end decay); a detour
        around an obstacle shows its own. It is what says how much of the start's offset the
        reproduction keeps, section by section.
    """

    positions: FloatArray
    start: FloatArray
    inside: bool
    eta: float
    section_index: int
    projected: bool
    times: FloatArray | None = None
    velocities: FloatArray | None = None
    orientations: FloatArray | None = None
    orientation_eta: float | None = None
    goal: FloatArray | None = None
    blocked: Blocked | None = None
    detoured: BoolArray | None = None
    start_clearance: float | None = None
    entry_index: int = 0
    approach: int = 0
    ratios: FloatArray | None = None

    @property
    def section_path(self) -> FloatArray:
        """The ratio rule's points, one per section from ``section_index + 1`` on, shape (K, D):
        ``positions`` without the start and its approach."""
        return self.positions[1 + self.approach :]


def ratio_rule_path(
    canal: Canal, index: int, first: int, alpha: float, start_arclength: float, direction: FloatArray,
    eta: float, entry: float | None, end_decay: float, persistence: str, has_goal: bool,
) -> tuple[FloatArray, FloatArray]:
    """The ratio rule's path on sections first .. N - 1, shape (K, D), and its ratios (K,):
    the learned persistence, the entry (E1)-(E3), the tube caps (F1) and the wall's slope (F2) on the schedule of
    :func:`canal_core.reproduce.path_ratios` (the arguments as :func:`reproduce` has them)."""
    s0, u = start_arclength, direction
    reach = reach_along(canal.sections, index, canal.n_sections, u)  # sections index .. N-1
    share: FloatArray | None = None
    if persistence in ("learned", "learned+end"):
        # "learned+end", for a start inside: the end decay is the prior the demonstrations'
        # own persistence is shrunk towards, not a second fade on top of it: where they kept
        # their offsets to the end (goals that follow the start), the reproduction keeps its
        # offset too. A start outside keeps both (the end decay is what brings it in by
        # mid-motion when the demonstrations' offsets barely fade), and so does a goal asked
        # for (it is reached exactly).
        to_end = persistence == "learned+end" and eta <= 1.0 and not has_goal
        prior = end_faded(canal.arclength[index + 1:], s0, end_decay) if to_end else 1.0
        kept = learned_persistence(
            canal.section_points[index:], reach, u, alpha, prior=prior, weight=PERSISTENCE_PRIOR_WEIGHT
        )
        if kept is not None:
            # At most the start's own ratio: an inside start stays inside by construction.
            share = np.clip(kept[first - index - 1 :], 0.0, 1.0)
            if to_end:
                end_decay = 0.0
    if entry is None:
        entry = entry_fraction(canal.arclength[first:], s0, share,
                               np.concatenate([reach[:1], reach[first - index:]]), ENTRY_FRACTION)
    wall = reach[first - index :]
    caps = tube_ratio_caps(wall, u, canal.curvature[first:])  # (F1)
    ratios = path_ratios(eta, canal.arclength[first:], s0, entry, end_decay, share, caps)
    slope = wall_slope_shares(wall, canal.arclength[first:])
    ratios = ratios * slope  # (F2)
    if ratios.size:
        # The offset changes from section to section no faster than a demonstration stepped
        # there, from the start's own on: a persistence regressed on crossings of the first
        # planes could fade a start's offset in two sections, or in the first step, a jump of
        # centimetres.
        steps = canal.section_steps[index:]
        here = (1.0 - alpha) * reach[0] + alpha * reach[first - index]
        walls = np.concatenate([[here], wall])
        offsets = np.concatenate([[eta * here], ratios * wall])
        scheduled = None
        if eta > 1.0:
            planned = path_ratios(eta, canal.arclength[first:], s0, entry, end_decay, share) * slope * wall
            scheduled = np.concatenate([offsets[:1], planned])
        allowed = np.minimum(steps[:-1], steps[1:])[first - index - 1 :]
        paced = paced_offsets(offsets, allowed, walls, scheduled)[1:]  # (F3)
        ratios = np.divide(paced, wall, out=np.zeros_like(paced), where=wall > 0.0)
    path = ratio_rule_positions(first, ratios, u, canal.directrix, canal.basis, canal.sections, wall)
    return path, ratios


def reproduce(
    canal: Canal,
    start: Any,
    outside: str = "project",
    start_orientation: Any = None,
    goal: Any = None,
    duration: Any = None,
    *,
    entry: float | None = None,
    end_decay: float = END_DECAY,
    persistence: str = "learned",
    obstacles: Any = None,
    deadline: float | None = None,
) -> Reproduction:
    """Reproduce from ``start`` (D,) on ``canal`` by the ratio rule (Alg. 1 lines 7-15).

    The start is located on the earliest section that holds it
    (:func:`canal_core.reproduce.start_locations`); its ratio eta is carried along the
    canal on the schedule of :func:`canal_core.reproduce.path_ratios` (entry blend for a
    start outside, end decay onto the demonstrations' end).

    Parameters
    ----------
    canal : Canal
    start : array_like, shape (D,)
    outside : {"project", "raise"}
        For a start outside the canal: enter the canal over the entry blend and say so
        in ``projected``, or raise :class:`OutsideCanalError`.
    start_orientation : array_like, shape (4,), optional
        Unit quaternion [qx, qy, qz, qw] of the start pose. Its offset from the start
        section's mean orientation is carried by the rotational ratio rule
        (:mod:`canal_core.orientation`). Checked always, used only when the canal has an
        orientation model; without it the orientations are the section means.
    goal : array_like, shape (D,), optional
        End the reproduction here: the canal is deformed first (:meth:`Canal.with_goal`).
    duration : float, optional
        Seconds; the times are stretched to end there (without time stamps, paced by
        ``section_pace`` when the logger was steady, else at constant speed along the path).
    entry : float or None
        None (default): a start outside enters the canal over the length in which the
        demonstrations' own start offsets half faded (:mod:`canal_core.entry`; on a canal of
        one demonstration the offset is a translation that fades over the motion instead,
        (L2) of :mod:`canal_core.lone`); a fraction
        of the canal's length: the entry blend over that length (0 clamps the ratio to 1 at
        once).
    end_decay : float
        Fraction of the canal's length over which the offset fades onto the directrix's end
        (``entry=0, end_decay=0`` with ``persistence="constant"``: the paper's constant,
        clamped ratio). Not used by (L2), whose offset fades over all that is left.
    persistence : {"learned", "constant", "learned+end"}
        How much of the start's ratio is kept along the canal before the end decay:
        what the demonstrations themselves kept of their start offsets, section by
        section (:func:`canal_core.reproduce.learned_persistence`, shrunk towards the
        paper's constant ratio by one pseudo-demonstration), or all of it (the paper).
        "learned+end": for a start inside and no goal, what the demonstrations kept up to
        their ends, shrunk towards the end decay instead of faded by it: the reproduction
        ends where their regression on the start puts it, not on the directrix's end.
    obstacles : Scene or list of obstacle dicts, optional
        What stands in the canal (:mod:`canal_core.obstacles`): the path goes through the
        free part of each section, keeps every clearance, steps no further than the
        demonstrations' largest step, and stops short, saying ``blocked``, where the
        obstacles close the canal.
    deadline : float, optional
        ``time.monotonic()`` by which a detour around ``obstacles`` must be found, else
        :class:`~canal_core.errors.TooSlowError` (a server's bound on one request).
    """
    point = check_reach(check_point(start, canal.dim, "start"), *canal.extent, "start")
    scene = None if obstacles is None else scene_from_list(obstacles, canal.dim)
    check_choice(outside, OUTSIDE_RULES, "outside")
    quat = None if start_orientation is None else check_quaternion(start_orientation)
    entry = None if entry is None else check_fraction(entry, "entry", maximum=1.0)
    end_decay = check_fraction(end_decay, "end_decay", maximum=1.0)
    check_choice(persistence, PERSISTENCES, "persistence")
    seconds = None if duration is None else check_duration(duration)
    target = None if goal is None else check_point(goal, canal.dim, "goal")
    if target is not None:  # with_goal holds it within the canal's reach
        canal = canal.with_goal(target)
    loc, held = start_and_located_points(
        point[None, :], canal.directrix, canal.tangents, canal.basis, canal.sections, canal.plane_offsets,
        canal.end_depths, canal.radii[[0, -1]],
    )
    eta = float(loc.eta[0])
    index, alpha = int(loc.index[0]), float(loc.alpha[0])
    inside = bool(located_inside(held, canal.end_depths, canal.radii, CONTAINS_TOLERANCE)[0])
    if outside == "raise" and not inside:
        raise OutsideCanalError(
            f"expected start inside the canal, got eta={eta:.4g} at section {index}"
            + (f" and {float(loc.axial[0]):.4g} beyond its end plane" if loc.axial[0] else ""),
            field="start",
        )
    first = min(index + 1, canal.n_sections - 1)
    s0 = float(canal.arclength[index] + alpha * (canal.arclength[first] - canal.arclength[index]))
    u = loc.direction[0]
    # (L2): one demonstration shows no spread to learn a persistence or an entry from.
    if entry is None and canal.n_demos == 1 and persistence != "constant":
        centre = (1.0 - alpha) * canal.directrix[index] + alpha * canal.directrix[first]
        path, ratios = lone_path(point - centre, s0, eta, u, canal.directrix[first:], canal.basis[first:],
                                 canal.arclength[first:], canal.curvature[first:], canal.sections, first)
    else:
        path, ratios = ratio_rule_path(canal, index, first, alpha, s0, u, eta, entry, end_decay, persistence,
                                       target is not None)
    positions = np.vstack([point, path])
    blocked, detoured, start_clearance = None, None, None
    if scene is not None:
        largest = demonstrated_largest_step(canal.directrix, canal.basis, canal.section_points)
        avoided = avoided_path(point, path, first, canal.directrix, canal.basis, canal.sections, scene, largest,
                               deadline)
        positions, blocked, detoured = avoided.positions, avoided.blocked, avoided.detoured
        start_clearance = avoided.start_clearance
        if blocked is not None and blocked.reason == "start":
            # The ratio rule's first step cannot leave the clearance the start is in: back
            # out first, as a live robot is, then reproduce from there.
            way_out = backed_out_path(point, scene, largest)
            if way_out is not None:
                rest = reproduce(canal, way_out[-1], "project", start_orientation, goal, None, entry=entry,
                                 end_decay=end_decay, persistence=persistence, obstacles=scene,
                                 deadline=deadline)
                return _after_backing_out(canal, point, way_out, rest, eta, index, inside, seconds,
                                          avoided.start_clearance)
    shares = np.ones(1)
    behind = index == 0 and loc.axial[0] < 0.0
    if positions.shape[0] > 1:
        far = float(np.linalg.norm(positions[1] - point))
        if behind:
            # (E4): behind the first plane, the first point is a straight line away; the path
            # takes it in the directrix's own first steps.
            shares = approach_shares(canal.arclength, far)
        elif not inside and entry != 0.0:
            # (E5) A start outside whose first point lies farther than the demonstrations ever
            # stepped there (the tube's cap, F1, brought the entry down to meet it at their
            # pace) goes there along the straight line, one demonstrated step at a time.
            # ``entry=0`` is the paper's clamp, onto the wall at once, and keeps it.
            shares = paced_approach_shares(far, float(canal.section_steps[first]), canal.n_sections)
    if shares.size > 1:
        # The line is the one the obstacle check cleared (a detour starts after it), so its
        # points need no second check.
        approach = point + shares[:-1, None] * (positions[1] - point)
        positions = np.vstack([point, approach, positions[1:]])
        if detoured is not None:
            detoured = np.concatenate([np.zeros(shares.size - 1, dtype=bool), detoured])
    n_approach = shares.size - 1
    times = None
    # Seconds from the stamps; a steady logger's pace only once a duration says how long.
    profile = canal.section_times if canal.section_times is not None or seconds is None else canal.section_pace
    if profile is not None:
        times = reproduction_times(profile, index, alpha, path.shape[0] + 1)
        if n_approach and behind:
            # The approach points at their sections' times; the path m - 1 sections later.
            t0 = profile[1] - times[1]
            times = np.concatenate([times[:1], profile[1 : n_approach + 1] - t0,
                                    times[1:] + (profile[n_approach + 1] - profile[1])])
        elif n_approach:
            # Evenly along the line, each of its m - 1 further steps a section's time at the
            # first point: the path follows as much later.
            pace = float(profile[first] - profile[first - 1]) if first > 0 else float(profile[1] - profile[0])
            span = float(times[1]) + n_approach * pace
            times = np.concatenate([times[:1], shares[:-1] * span, times[1:] + (span - times[1])])
        times = times[: positions.shape[0]]  # a blocked path keeps its own times
        # No step faster than the demonstrations moved: a start past the end, or left far
        # from the path, would otherwise cover its distance in a section's time (or 1 ns).
        times = speed_limited_times(times, positions[: times.shape[0]], top_speed(profile, canal.section_steps))
        if seconds is not None:
            times = rescaled_times(times, seconds)
    elif seconds is not None:
        times = arc_length_times(positions, seconds)
    orientations, orientation_eta = None, None
    if canal.orientation is not None:
        orientations, orientation_eta = canal.orientation.reproduced(index, first, quat)
        if n_approach:
            turn = slerped(orientations[0], orientations[1], shares[:-1])
            orientations = hemisphere_continuous(np.vstack([orientations[:1], turn, orientations[1:]]),
                                                 orientations[0])
        orientations = orientations[: positions.shape[0]]
    if scene is None and n_approach == 0:
        # The path is the schedule's, point for point: measuring it again would cost a sixth
        # of the reproduction.
        measured = np.concatenate([[eta], ratios])
    else:
        measured = position_ratios(canal, positions, first, n_approach, eta, 0 if behind else index)
    return Reproduction(
        positions=positions,
        start=point,
        inside=inside,
        eta=min(eta, 1.0),
        section_index=index,
        projected=eta > 1.0,
        times=times,
        velocities=None if times is None else finite_velocities(positions, times),
        orientations=orientations,
        orientation_eta=orientation_eta,
        goal=target,
        blocked=blocked,
        detoured=detoured,
        start_clearance=start_clearance,
        entry_index=0 if inside else 1 + n_approach + int(np.argmax(np.append(ratios <= 1.0 + CONTAINS_TOLERANCE, True))),
        approach=n_approach,
        ratios=measured,
    )


def _after_backing_out(
    canal: Canal, point: FloatArray, way_out: FloatArray, rest: Reproduction, eta: float, index: int,
    inside: bool, seconds: float | None, start_clearance: float | None,
) -> Reproduction:
    """The start, its steps out of an obstacle's clearance (``way_out``, ending where ``rest``
    starts), then ``rest``: one reproduction, its times from the start (the steps at the
    demonstrations' fastest pace), rescaled to ``seconds`` when asked."""
    n = way_out.shape[0]
    positions = np.vstack([point, way_out, rest.positions[1:]])
    times = None
    if rest.times is not None:
        profile = canal.section_times if canal.section_times is not None else canal.section_pace
        speed = top_speed(profile, canal.section_steps) if profile is not None else float("inf")
        lengths = np.sqrt(((positions[1 : n + 1] - positions[:n]) ** 2).sum(axis=1))
        dt = lengths / speed if np.isfinite(speed) and speed > 0.0 else np.full(n, float(np.diff(rest.times)[0]))
        out = np.concatenate([[0.0], np.cumsum(dt)])
        times = strictly_increasing(np.concatenate([out, out[-1] + rest.times[1:]]))
        if seconds is not None:
            times = rescaled_times(times, seconds)
    orientations = None
    if rest.orientations is not None:
        orientations = np.vstack([np.repeat(rest.orientations[:1], n, axis=0), rest.orientations])
    ratios = None
    if rest.ratios is not None:
        between = section_ratios(way_out[:-1], np.full(n - 1, index, dtype=np.intp), canal.directrix, canal.basis,
                                 canal.sections)
        ratios = np.concatenate([[eta], between, rest.ratios])
    detoured = rest.detoured if rest.detoured is not None else np.zeros(rest.positions.shape[0] - 1, dtype=bool)
    # The rest (goal, blocked, orientation_eta) is the reproduction from the way out's end.
    return replace(
        rest, positions=positions, start=point, inside=inside, eta=min(eta, 1.0), section_index=index,
        projected=eta > 1.0, times=times, velocities=None if times is None else finite_velocities(positions, times),
        orientations=orientations, detoured=np.concatenate([np.ones(n, dtype=bool), detoured]),
        start_clearance=start_clearance, entry_index=0 if inside else n + rest.entry_index,
        approach=n + rest.approach, ratios=ratios,
    )


def position_ratios(
    canal: Canal, positions: FloatArray, first: int, n_approach: int, eta: float, approach_section: int = 0
) -> FloatArray:
    """:attr:`Reproduction.ratios`: ``eta`` for the start, then each later position's ratio in
    the plane it belongs to (``approach_section`` for the ``n_approach`` approach points: 0
    behind the canal, the start's own section beside it; then ``first``, ``first + 1``, ...),
    shape (N',)."""
    m = positions.shape[0] - 1 - n_approach
    index = np.concatenate([np.full(n_approach, approach_section, dtype=np.intp), first + np.arange(m, dtype=np.intp)])
    later = section_ratios(positions[1:], index, canal.directrix, canal.basis, canal.sections)
    return np.concatenate([[eta], later])
