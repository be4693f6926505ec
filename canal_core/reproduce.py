"""Locating points in the canal and reproducing by the ratio rule (paper Section 4.2, Fig. 4).

The canal is the volume swept by its cross-sections. A point x lies "between" sections i and
i + 1 when its signed distances to their planes, d_k = t_k . (x - c_k), change sign; the
fraction alpha = d_i / (d_i - d_{i+1}) places it on an interpolated section whose in-plane
coordinates and boundary are linear blends of the two neighbours. Its ratio is
eta = |p c| / |g c| (Alg. 1 line 10) against that blended boundary in the direction of p.

A point may sit between several pairs of planes on a bending canal; the pair in whose
section it lies most centrally (smallest eta) is taken, so a start point is matched to its
nearest cross-section, not to the first. A point behind the first plane or past the last is
measured against that end section and reported with its axial offset.

Reproduction (Alg. 1 lines 11-15) carries (eta, direction) unchanged from section to section:
p_k = c_k + eta * |g_k c_k|(u) * (u_1 n_k + u_2 b_k). Because the direction u is expressed in
the rotation-minimising frame, "transforming from the current frame to the next" is exactly
this change of basis. The result lies inside every section by construction when eta <= 1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .cross_sections import CrossSections, boundary_distance
from .crossings import crosses_plane, in_row_blocks
from .entry import inside_stays_inside
from .validation import BoolArray, FloatArray, IntArray

#: Relative slack on eta when preferring a section that holds a point (rounding only).
INSIDE_TOLERANCE = 1e-9
#: A start not held by any section is placed on the earliest pair whose eta is within this
#: factor of its smallest eta anywhere (see start_locations).
START_ETA_FACTOR = 2.0
#: The entry blend of a start outside the canal, as a fraction of the canal's length
#: (path_ratios): 20 of 200 sections. A reproduction learns its own by default
#: (:func:`canal_core.entry.entry_fraction`); this is its fallback.
ENTRY_FRACTION = 0.1
#: The ratio rule's offset fades out over this last fraction of the canal's length, or over
#: all that is left after the start when less (path_ratios). 1.0: the whole motion, with a
#: smootherstep that keeps 94 % of the offset over the first fifth and 6 % over the last: a
#: demonstrator's offset at the start says less and less about where they are later (docs/method.md
#: section 4; BENCHMARKS.md's quality row "canal, end decay over the last fifth" is 0.2).
END_DECAY = 1.0
#: Weight of the paper's constant ratio in the learned persistence, in demonstrations: one
#: pseudo-demonstration that keeps its whole start offset. It keeps a profile regressed on a
#: few demos from following their noise where they barely spread (docs/method.md section 4b).
PERSISTENCE_PRIOR_WEIGHT = 1.0
#: Relative tolerance of :meth:`canal_core.model.Canal.contains` on eta and on the axial
#: offset at the ends.
CONTAINS_TOLERANCE = 1e-6


@dataclass(frozen=True, eq=False)
class Location:
    """Where points sit in the canal.

    Attributes
    ----------
    index : array of int, shape (M,)
        Lower section i of the bracketing pair (i, i + 1).
    alpha : array, shape (M,)
        Fraction between section i (0) and i + 1 (1).
    coords : array, shape (M, D - 1)
        In-plane coordinates relative to the (blended) directrix point.
    direction : array, shape (M, D - 1)
        Unit in-plane direction of ``coords`` (first axis when coords is zero).
    eta : array, shape (M,)
        |p c| / |g c|; 0 on the directrix, 1 on the boundary, inf off a zero-size section.
    axial : array, shape (M,)
        Signed distance behind the first plane (< 0) or past the last (> 0); 0 in between.
    """

    index: IntArray
    alpha: FloatArray
    coords: FloatArray
    direction: FloatArray
    eta: FloatArray
    axial: FloatArray


def section_basis(normals: FloatArray, binormals: FloatArray | None) -> FloatArray:
    """In-plane unit vectors per section, shape (N, D - 1, D): (n_i, b_i) or (n_i,)."""
    if binormals is None:
        return normals[:, None, :]
    return np.stack([normals, binormals], axis=1)


def unit_directions(coords: FloatArray, norm: FloatArray | None = None) -> tuple[FloatArray, FloatArray]:
    """Norms, shape (M,), and unit directions, shape (M, K), of in-plane coordinates.

    ``norm`` is |coords| per row when the caller has it already.
    """
    if norm is None:
        norm = np.sqrt(np.einsum("mk,mk->m", coords, coords))
    moved = norm > 0.0
    direction = coords / np.where(moved, norm, 1.0)[:, None]
    if not moved.all():
        direction[~moved] = 0.0
        direction[~moved, 0] = 1.0  # arbitrary on the directrix, where eta = 0 makes it irrelevant
    return norm, direction


def ratio(norm: FloatArray, reach: FloatArray) -> FloatArray:
    """eta = |p c| / |g c|, with 0/0 = 0 (start on the directrix) and x/0 = inf."""
    # np.divide's ``where`` instead of an errstate block: this runs once per reproduction.
    held = reach > 0.0
    eta = np.divide(norm, reach, out=np.where(norm > 0.0, np.inf, 0.0), where=held)
    return np.asarray(eta, dtype=np.float64)


def section_ratios(
    points: FloatArray, index: IntArray, centres: FloatArray, basis: FloatArray, sections: CrossSections
) -> FloatArray:
    """The ratio eta = |p c_i| / |g_i c_i| of each point in the plane of its section i (Alg. 1
    line 10), along the point's own in-plane direction.

    Parameters
    ----------
    points : array, shape (M, D)
    index : array of int, shape (M,)
        The section each point is read in (a point off the plane is read by its projection).
    centres : array, shape (N, D)
    basis : array, shape (N, D - 1, D)
    sections : CrossSections

    Returns
    -------
    ratios : array, shape (M,)
        0 on the directrix, 1 on the wall.
    """
    norm, direction = unit_directions(in_plane_offsets(points, index, centres, basis))
    return ratio(norm, boundary_distance(sections, index, direction))


def rounding_scale(centres: FloatArray) -> float:
    """Offsets at or below this (1e-12 of the directrix's reach) are rounding, not geometry."""
    return 1e-12 * (1.0 + float(np.abs(centres).max()))


def in_plane_offsets(points: FloatArray, index: IntArray, centres: FloatArray, basis: FloatArray) -> FloatArray:
    """Coordinates of points (M, D) relative to c_i in section i's in-plane basis, shape (M, D - 1).

    One coordinate axis at a time: a sum of D products of gathered columns, cheaper than
    a batched product of (M, D - 1, D) by (M, D) for D = 2, 3.
    """
    # np.take: a row gather without fancy indexing's overhead (several times faster here).
    rel = points - np.take(centres, index, axis=0)
    frame = np.take(basis, index, axis=0)  # (M, D - 1, D)
    out = frame[:, :, 0] * rel[:, 0, None]
    for axis in range(1, points.shape[1]):
        out += frame[:, :, axis] * rel[:, axis, None]
    return out


def blended_location(
    points: FloatArray,
    index: IntArray,
    alpha: FloatArray,
    centres: FloatArray,
    basis: FloatArray,
    sections: CrossSections,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """In-plane coords, directions and eta of points on sections blended between i and i + 1.

    Parameters
    ----------
    points : array, shape (M, D)
    index : array of int, shape (M,)
    alpha : array, shape (M,)
    centres : array, shape (N, D)
    basis : array, shape (N, D - 1, D)
    sections : CrossSections
    """
    upper = np.minimum(index + 1, centres.shape[0] - 1)
    coords = (1.0 - alpha)[:, None] * in_plane_offsets(points, index, centres, basis)
    coords += alpha[:, None] * in_plane_offsets(points, upper, centres, basis)
    # Offsets at rounding level (a point on the directrix) count as zero, not as a
    # direction: a zero-size section would otherwise turn them into eta = inf.
    norm = np.sqrt(np.einsum("mk,mk->m", coords, coords))
    rounding = norm <= rounding_scale(centres)
    coords[rounding] = 0.0
    norm[rounding] = 0.0
    norm, direction = unit_directions(coords, norm)
    reach = (1.0 - alpha) * boundary_distance(sections, index, direction) + alpha * boundary_distance(
        sections, upper, direction
    )
    return coords, direction, ratio(norm, reach)


def _candidates(
    points: FloatArray,
    centres: FloatArray,
    tangents: FloatArray,
    basis: FloatArray,
    sections: CrossSections,
    plane: FloatArray | None = None,
) -> tuple[IntArray, IntArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """Every (point, pair or end) a point may be measured on: pt, sec, alpha, axial, coords, direction, eta.

    ``plane`` is t_i . c_i, shape (N,), when the caller keeps it.
    """
    n = centres.shape[0]
    offsets = np.einsum("nd,nd->n", centres, tangents) if plane is None else plane
    dist = points @ tangents.T - offsets[None, :]  # (M, N) signed plane distances
    # A point on a plane up to rounding is on it: where the sweep folds, the neighbouring
    # planes may all lie on one side of it and no sign change would be seen.
    dist[np.abs(dist) <= rounding_scale(centres)] = 0.0
    lo, hi = dist[:, :-1], dist[:, 1:]
    crossing = crosses_plane(lo, hi) | (hi == 0.0)
    pt, sec = np.nonzero(crossing)
    denom = lo[pt, sec] - hi[pt, sec]
    alpha = np.divide(lo[pt, sec], denom, out=np.zeros_like(denom), where=denom != 0.0)
    axial = np.zeros(pt.size)

    # End candidates: behind the first plane or past the last.
    behind = np.flatnonzero(dist[:, 0] < 0.0)
    past = np.flatnonzero(dist[:, -1] > 0.0)
    pt = np.concatenate([pt, behind, past])
    sec = np.concatenate([sec, np.zeros(behind.size, np.int64), np.full(past.size, max(n - 2, 0))])
    alpha = np.concatenate([alpha, np.zeros(behind.size), np.ones(past.size)])
    axial = np.concatenate([axial, dist[behind, 0], dist[past, -1]])
    if n == 1:  # a single section: everything is measured against it
        sec[:] = 0

    coords, direction, eta = blended_location(np.take(points, pt, axis=0), sec, alpha, centres, basis, sections)
    return pt, sec, alpha, axial, coords, direction, eta


def location_columns(loc: Location) -> tuple[np.ndarray, ...]:
    """``loc``'s arrays in the order ``Location`` takes them (to join blocks of points)."""
    return (loc.index, loc.alpha, loc.coords, loc.direction, loc.eta, loc.axial)


def _picked(
    first: IntArray,
    sec: IntArray,
    alpha: FloatArray,
    axial: FloatArray,
    coords: FloatArray,
    direction: FloatArray,
    eta: FloatArray,
) -> Location:
    return Location(
        index=sec[first].astype(np.int64),
        alpha=alpha[first],
        coords=coords[first],
        direction=direction[first],
        eta=eta[first],
        axial=axial[first],
    )


def located_inside(loc: Location, end_depths: FloatArray, radii: FloatArray, tol: float) -> BoolArray:
    """Whether each located point (M,) lies in the canal: eta <= 1 + tol, and at the two
    ends an axial offset within the end depth (2,) plus tol times the largest radius of
    ``radii`` (N,)."""
    axial_tol = tol * float(radii.max(initial=0.0))
    reach = np.where(loc.axial < 0.0, end_depths[0], end_depths[1]) + axial_tol
    return np.asarray((loc.eta <= 1.0 + tol) & (np.abs(loc.axial) <= reach))


def located_points(
    points: FloatArray,
    centres: FloatArray,
    tangents: FloatArray,
    basis: FloatArray,
    sections: CrossSections,
    end_depths: FloatArray | None = None,
) -> Location:
    """Locate points in the swept canal for containment (see module docstring).

    Among every pair of planes (and end section) a point lies between, the one that holds
    it most centrally (smallest eta) is taken; else the one it is least outside of.

    Parameters
    ----------
    points : array, shape (M, D)
    centres, tangents : arrays, shape (N, D)
    basis : array, shape (N, D - 1, D)
    sections : CrossSections
    end_depths : array, shape (2,), optional
        How far the end sections are extruded (behind the first plane, past the last): an
        end candidate within its depth holds the point like a pair of planes does. Without
        them only pairs of planes hold points.

    Returns
    -------
    Location
    """
    plane = np.einsum("nd,nd->n", centres, tangents)

    def located(rows: slice) -> tuple[np.ndarray, ...]:
        # A block of points at a time: the plane distances are (points, sections), gigabytes
        # for tens of thousands of points on a canal of thousands of sections.
        block = points[rows]
        loc = _located_among(block.shape[0],
                             _candidates(block, centres, tangents, basis, sections, plane),
                             end_depths)
        return location_columns(loc)

    # each point's candidates take a few arrays of one row per section
    parts = in_row_blocks(located, points.shape[0], 4 * centres.shape[0])
    return Location(*parts)


Candidates = tuple[IntArray, IntArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]


def _located_among(m: int, candidates: Candidates, end_depths: FloatArray | None = None) -> Location:
    """:func:`located_points`' choice among the candidates of m points."""
    pt, sec, alpha, axial, coords, direction, eta = candidates
    # Prefer a section that holds the point; else the end or pair where it is least outside.
    within = axial == 0.0
    if end_depths is not None:
        depth = np.where(axial < 0.0, end_depths[0], end_depths[1]) * (1.0 + INSIDE_TOLERANCE)
        within = within | (np.abs(axial) <= depth)
    key = np.where(within & (eta <= 1.0 + INSIDE_TOLERANCE), eta, 2.0 + eta)
    order = np.lexsort((key, pt))
    first = order[np.searchsorted(pt[order], np.arange(m))]
    return _picked(first, sec, alpha, axial, coords, direction, eta)


def growth_locations(points: FloatArray, centres: FloatArray, tangents: FloatArray,
                     basis: FloatArray, sections: CrossSections) -> Location:
    """Locate points where holding them enlarges the canal least (the fit's envelope).

    Among every pair of planes (and end section) a point lies between, one that holds it
    (eta <= 1, smallest eta first); else the one whose boundary must move least to reach it,
    in lengths: hypot(|q| - R(u), axial) with |q| - R(u) = |q| (1 - 1 / eta).
    :func:`located_points` takes the smallest eta instead, the right question for
    containment but not for growth: where the planes fan out across a turn, a wide section
    far away holds a point at a small ratio and would be enlarged by metres to reach it,
    while the narrow section beside it needs millimetres. Parameters and result as
    :func:`located_points` (without end depths: the fit is still setting them).
    """
    pt, sec, alpha, axial, coords, direction, eta = _candidates(points, centres, tangents, basis, sections)
    distance = np.sqrt(np.einsum("kd,kd->k", coords, coords))
    shortfall = np.where(eta > 1.0, distance * (1.0 - 1.0 / np.maximum(eta, 1.0)), 0.0)
    order = np.lexsort((eta, np.hypot(shortfall, axial), pt))
    first = order[np.searchsorted(pt[order], np.arange(points.shape[0]))]
    return _picked(first, sec, alpha, axial, coords, direction, eta)


def start_locations(
    points: FloatArray,
    centres: FloatArray,
    tangents: FloatArray,
    basis: FloatArray,
    sections: CrossSections,
) -> Location:
    """Locate reproduction starts where a person would: as early in the motion as plausible.

    A start lies between many pairs of planes on a bending canal; the globally smallest
    eta can be a pair far down the motion (a wide later section), which would skip most of
    it. A start is placed instead on the *earliest* pair (or the first section, when it is
    behind the first plane) that holds it; when none holds it, on the earliest whose eta is
    within ``START_ETA_FACTOR`` of the smallest one it has anywhere.

    Parameters
    ----------
    points : array, shape (M, D)
    centres, tangents : arrays, shape (N, D)
    basis : array, shape (N, D - 1, D)
    sections : CrossSections

    Returns
    -------
    Location
    """
    return _start_among(points.shape[0], _candidates(points, centres, tangents, basis, sections))


def start_and_located_points(
    points: FloatArray,
    centres: FloatArray,
    tangents: FloatArray,
    basis: FloatArray,
    sections: CrossSections,
    plane: FloatArray | None = None,
    end_depths: FloatArray | None = None,
    end_radii: FloatArray | None = None,
) -> tuple[Location, Location]:
    """:func:`start_locations` and :func:`located_points` of the same points, from one search
    of the candidates (a reproduction needs both: where to start, and whether it is inside).
    ``plane`` (t_i . c_i, shape (N,)) when the caller keeps it. With ``end_depths`` and
    ``end_radii`` (the largest radius of the first and last section, shape (2,)), a start
    beyond an end section counts as far from it as it lies beyond its depth (see
    :func:`_start_among`)."""
    candidates = _candidates(points, centres, tangents, basis, sections, plane)
    return (_start_among(points.shape[0], candidates, end_depths, end_radii),
            _located_among(points.shape[0], candidates))


def _start_among(m: int, candidates: Candidates, end_depths: FloatArray | None = None,
                 end_radii: FloatArray | None = None) -> Location:
    """:func:`start_locations`' choice among the candidates of m points.

    An end candidate's eta is its offset across the end section only: a start far behind
    the first plane or past the last one, near the line of the end section's normal, would
    have a small eta there and be taken to start at the goal (the whole motion skipped). With
    the ends' depths and radii, the choice weighs an end candidate by
    hypot(eta, (|axial| - depth)_+ / R_end), its distance outside in the end's own radii.
    """
    pt, sec, alpha, axial, coords, direction, eta = candidates
    weighed = eta
    if end_depths is not None and end_radii is not None:
        behind = axial < 0.0
        over = np.maximum(np.abs(axial) - np.where(behind, end_depths[0], end_depths[1]), 0.0)
        radius = np.where(behind, end_radii[0], end_radii[1])
        weighed = np.where(over > 0.0, np.hypot(eta, np.divide(over, radius, out=np.full_like(over, np.inf),
                                                               where=radius > 0.0)), eta)
    holds = weighed <= 1.0 + INSIDE_TOLERANCE
    any_holds = np.zeros(m, dtype=bool)
    any_holds[pt[holds]] = True
    best = np.full(m, np.inf)
    np.minimum.at(best, pt, weighed)
    plausible = np.where(any_holds[pt], holds, weighed <= START_ETA_FACTOR * best[pt] + INSIDE_TOLERANCE)
    # Earliest along the motion: section index, then the end-behind candidate before pair 0.
    position = np.where(plausible, sec + np.where(axial < 0.0, -0.5, alpha), np.inf)
    order = np.lexsort((eta, position, pt))
    first = order[np.searchsorted(pt[order], np.arange(m))]
    return _picked(first, sec, alpha, axial, coords, direction, eta)


def smootherstep(x: FloatArray) -> FloatArray:
    """6x^5 - 15x^4 + 10x^3 on [0, 1] (clipped): zero slope and curvature at both ends."""
    x = np.clip(x, 0.0, 1.0)
    return np.asarray(x**3 * (10.0 + x * (-15.0 + 6.0 * x)), dtype=np.float64)


def end_faded(arclength: FloatArray, start_arclength: float, end_decay: float) -> FloatArray:
    """The end decay's share of the offset left on each section (K,): 1 - S((s_k - s_d) / L_out)."""
    total = float(arclength[-1]) if arclength.size else 0.0
    tail = min(end_decay * max(total, 1e-300), total - start_arclength)
    if end_decay <= 0.0 or tail <= 0.0:
        return np.ones_like(arclength)
    return np.asarray(1.0 - smootherstep((arclength - (total - tail)) / tail), dtype=np.float64)


def path_ratios(
    eta: float,
    arclength: FloatArray,
    start_arclength: float,
    entry: float = ENTRY_FRACTION,
    end_decay: float = END_DECAY,
    persistence: FloatArray | None = None,
    cap: FloatArray | None = None,
) -> FloatArray:
    """Ratio of the reproduced point on each remaining section (the schedule of the ratio rule).

    ``eta_k = (1 + (eta - 1) (1 - S((s_k - s_0) / L_in)))  *  (1 - S((s_k - s_d) / L_out))``

    for a start outside (eta > 1), ``eta_k = eta (1 - S(...))`` inside, where S is
    :func:`smootherstep`, s_0 the start's arc length, L_in = ``entry`` x the canal's length
    (the entry blend: an outside start reaches the boundary within a few sections and is
    inside from then on, instead of riding the boundary all the way) and L_out =
    min(``end_decay`` x length, what is left after the start), s_d = s_end - L_out (the end
    decay: the offset fades into the last sections, so the reproduction lands on the
    directrix's end, the mean of the demonstrated goals, whether the canal narrows there or
    not). ``entry = end_decay = 0`` is the paper's constant ratio (clamped to 1). A path that
    has entered stays inside (:func:`canal_core.entry.inside_stays_inside`); the entry length
    a reproduction uses by default is learned (:func:`canal_core.entry.entry_fraction`).

    Parameters
    ----------
    eta : float
        The start's ratio (may exceed 1).
    arclength : array, shape (K,)
        Arc length of the directrix at the remaining sections.
    start_arclength : float
    entry : float
        L_in as a fraction of the canal's length.
    end_decay : float
        Fraction of the canal's length.
    persistence : array, shape (K,), optional
        Share f_k in [0, 1] of the start's ratio kept on each section before the end decay
        (:func:`learned_persistence`): eta is replaced by eta f_k above (and an outside start
        by min(eta f_k, its entry blend)). None: f_k = 1, the paper's constant ratio.
    cap : array, shape (K,), optional
        The largest ratio on each section (the tube condition, F1 of :mod:`canal_core.tube`),
        applied before "inside stays inside": a path capped inside at a tight turn stays in.

    Returns
    -------
    ratios : array, shape (K,)
    """
    total = float(arclength[-1]) if arclength.size else 0.0
    length = max(total, 1e-300)
    along = arclength - start_arclength
    kept = np.full_like(arclength, eta) if persistence is None else eta * persistence
    if eta > 1.0:
        if entry > 0.0:
            ratios = np.minimum(kept, 1.0 + (eta - 1.0) * (1.0 - smootherstep(along / (entry * length))))
        else:
            ratios = np.minimum(kept, 1.0)
    else:
        ratios = kept
    tail = min(end_decay * length, total - start_arclength)
    if end_decay > 0.0 and tail > 0.0:
        ratios = ratios * (1.0 - smootherstep((arclength - (total - tail)) / tail))
    elif end_decay > 0.0 and ratios.size:
        ratios[-1] = 0.0
    if cap is not None:
        ratios = np.minimum(ratios, cap)
    if eta > 1.0:
        ratios = inside_stays_inside(ratios)
    return np.asarray(ratios, dtype=np.float64)


def learned_persistence(
    section_points: FloatArray,
    reach: FloatArray,
    direction: FloatArray,
    alpha: float,
    prior: FloatArray | float = 1.0,
    weight: float = 0.0,
) -> FloatArray | None:
    """How much of a start's ratio the demonstrations keep on each later section.

    The demonstrations' own ratios along the start's direction u, e_jk = <q_jk, u> / R_k(u)
    (q_jk: demo j's crossing of plane k in that plane's frame, R_k(u): the boundary distance
    along u), are regressed section by section on their ratio at the start,
    e_j0 = (1 - alpha) e_{j,i0} + alpha e_{j,i0+1}:

        f_k = (sum_j e_j0 e_jk + c p_k) / (sum_j e_j0^2 + c)

    the least-squares slope through the origin, shrunk towards a prior p_k by ``weight``
    pseudo-demonstrations (c = weight x the demos' mean squared start ratio per in-plane
    axis). f_k = 1 means that a demonstration's offset at the start is still there at
    section k (in units of the canal's width: where the canal narrows, the ratio rule already
    narrows the offset), 0 that the demonstrations forgot it there. It is what conditioning a
    ProMP on its start does with the demonstrations' covariance, in the canal's own
    coordinates; with p_k = 1 and no demonstrations it is the paper's constant ratio.

    Parameters
    ----------
    section_points : array, shape (K + 1, n, D - 1)
        Crossings of sections i0 .. N - 1.
    reach : array, shape (K + 1,)
        R_k(u) on those sections.
    direction : array, shape (D - 1,)
        u, a unit vector in the frames' in-plane coordinates.
    alpha : float
        Where the start lies between sections i0 and i0 + 1.
    prior : float or array, shape (K,)
    weight : float
        Pseudo-demonstrations on the prior (0: the plain regression).

    Returns
    -------
    f : array, shape (K,), on sections i0 + 1 .. N - 1, or None when the demonstrations do not
        spread along u at the start (nothing to learn from)
    """
    # One product per in-plane axis (at most two): cheaper than a matmul over (K + 1, n, D - 1).
    along = section_points[..., 0] * direction[0]
    for axis in range(1, direction.size):
        along = along + section_points[..., axis] * direction[axis]
    # A zero-size section says nothing about how an offset persists: it does not count.
    # e_jk = along_jk / R_k: the 1 / R_k is applied to the (K,) products, not to (K + 1, n).
    inverse = np.divide(1.0, reach, out=np.zeros_like(reach), where=reach > 0.0)
    e0 = (1.0 - alpha) * along[0] * inverse[0] + alpha * along[min(1, along.shape[0] - 1)] * inverse[min(1, along.shape[0] - 1)]
    denom = float(e0 @ e0)
    # ``weight`` pseudo-demonstrations that follow the prior, each with a demonstration's mean
    # squared ratio along one in-plane axis (what a demo contributes to ``denom`` on average).
    first = section_points[0]
    mean_square = float(np.einsum("jk,jk->", first, first)) / max(first.shape[0], 1)
    c = weight * mean_square / max(float(reach[0]), 1e-300) ** 2 / direction.size
    if not np.isfinite(denom + c) or denom + c <= 1e-6 * e0.size:
        return None
    return np.asarray(((along[1:] @ e0) * inverse[1:] + c * prior) / (denom + c), dtype=np.float64)


def ratio_rule_positions(
    start_index: int,
    eta: float | FloatArray,
    direction: FloatArray,
    centres: FloatArray,
    basis: FloatArray,
    sections: CrossSections,
    reach: FloatArray | None = None,
) -> FloatArray:
    """Points at ratio ``eta`` along ``direction`` on sections start_index..N-1 (Alg. 1 l. 12-15).

    Parameters
    ----------
    start_index : int
    eta : float or array, shape (N - start_index,)
        One ratio, or one per section (see :func:`path_ratios`).
    direction : array, shape (D - 1,)
    centres : array, shape (N, D)
    basis : array, shape (N, D - 1, D)
    sections : CrossSections
    reach : array, shape (N - start_index,), optional
        R_k(direction) on those sections, when the caller has it already
        (:func:`reach_along`).

    Returns
    -------
    positions : array, shape (N - start_index, D)
    """
    if reach is None:
        reach = reach_along(sections, start_index, centres.shape[0], direction)
    # Slices, not index arrays: views instead of copies of (N, D - 1, D) on the hot path.
    offset = direction[0] * basis[start_index:, 0]
    for axis in range(1, direction.size):
        offset = offset + direction[axis] * basis[start_index:, axis]
    return np.asarray(centres[start_index:] + (eta * reach)[:, None] * offset, dtype=np.float64)


def reach_along(sections: CrossSections, first: int, n: int, direction: FloatArray) -> FloatArray:
    """R_k(u), shape (n - first,): boundary distance along one in-plane direction u (D - 1,)
    on sections first .. n - 1."""
    idx = np.arange(first, n)
    return boundary_distance(sections, idx, np.ascontiguousarray(np.broadcast_to(direction, (idx.size, direction.size))))

