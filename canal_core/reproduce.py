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
from .validation import BoolArray, FloatArray, IntArray

#: Relative slack on eta when preferring a section that holds a point (rounding only).
INSIDE_TOLERANCE = 1e-9
#: Largest factor by which one demo sample may enlarge its two sections (see enclosing_scales).
MAX_STRETCH = 1.5


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


def unit_directions(coords: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Norms, shape (M,), and unit directions, shape (M, K), of in-plane coordinates."""
    norm = np.linalg.norm(coords, axis=1)
    direction = np.zeros_like(coords)
    direction[:, 0] = 1.0  # arbitrary on the directrix, where eta = 0 makes it irrelevant
    moved = norm > 0.0
    direction[moved] = coords[moved] / norm[moved, None]
    return norm, direction


def ratio(norm: FloatArray, reach: FloatArray) -> FloatArray:
    """eta = |p c| / |g c|, with 0/0 = 0 (start on the directrix) and x/0 = inf."""
    with np.errstate(divide="ignore", invalid="ignore"):
        eta = np.where(reach > 0.0, norm / np.where(reach > 0.0, reach, 1.0), np.where(norm > 0.0, np.inf, 0.0))
    return np.asarray(eta, dtype=np.float64)


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
    q0 = np.einsum("mkd,md->mk", basis[index], points - centres[index])
    q1 = np.einsum("mkd,md->mk", basis[upper], points - centres[upper])
    coords = (1.0 - alpha)[:, None] * q0 + alpha[:, None] * q1
    # Offsets at rounding level (a point on the directrix) count as zero, not as a
    # direction: a zero-size section would otherwise turn them into eta = inf.
    coords[np.linalg.norm(coords, axis=1) <= 1e-12 * (1.0 + np.abs(centres).max())] = 0.0
    norm, direction = unit_directions(coords)
    reach = (1.0 - alpha) * boundary_distance(sections, index, direction) + alpha * boundary_distance(
        sections, upper, direction
    )
    return coords, direction, ratio(norm, reach)


def located_points(
    points: FloatArray,
    centres: FloatArray,
    tangents: FloatArray,
    basis: FloatArray,
    sections: CrossSections,
) -> Location:
    """Locate points in the swept canal (see module docstring).

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
    m, n = points.shape[0], centres.shape[0]
    offsets = np.einsum("nd,nd->n", centres, tangents)
    dist = points @ tangents.T - offsets[None, :]  # (M, N) signed plane distances
    # A point on a plane up to rounding is on it: where the sweep folds, the neighbouring
    # planes may all lie on one side of it and no sign change would be seen.
    dist[np.abs(dist) <= 1e-12 * (1.0 + np.abs(centres).max())] = 0.0
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
    sec = np.concatenate([sec, np.zeros(behind.size, np.int64), np.full(past.size, n - 2)])
    alpha = np.concatenate([alpha, np.zeros(behind.size), np.ones(past.size)])
    axial = np.concatenate([axial, dist[behind, 0], dist[past, -1]])
    if n == 1:  # a single section: everything is measured against it
        sec[:] = 0

    coords, direction, eta = blended_location(points[pt], sec, alpha, centres, basis, sections)
    # Prefer a section that holds the point; else the end or pair where it is least outside.
    key = np.where((axial == 0.0) & (eta <= 1.0 + INSIDE_TOLERANCE), eta, 2.0 + eta)
    order = np.lexsort((key, pt))
    first = order[np.searchsorted(pt[order], np.arange(m))]
    return Location(
        index=sec[first].astype(np.int64),
        alpha=alpha[first],
        coords=coords[first],
        direction=direction[first],
        eta=eta[first],
        axial=axial[first],
    )


def ratio_rule_positions(
    start_index: int,
    eta: float,
    direction: FloatArray,
    centres: FloatArray,
    basis: FloatArray,
    sections: CrossSections,
) -> FloatArray:
    """Points at ratio ``eta`` along ``direction`` on sections start_index..N-1 (Alg. 1 l. 12-15).

    Parameters
    ----------
    start_index : int
    eta : float
    direction : array, shape (D - 1,)
    centres : array, shape (N, D)
    basis : array, shape (N, D - 1, D)
    sections : CrossSections

    Returns
    -------
    positions : array, shape (N - start_index, D)
    """
    idx = np.arange(start_index, centres.shape[0])
    dirs = np.broadcast_to(direction, (idx.size, direction.size))
    reach = boundary_distance(sections, idx, np.ascontiguousarray(dirs))
    offset = np.einsum("k,nkd->nd", direction, basis[idx])
    return np.asarray(centres[idx] + (eta * reach)[:, None] * offset, dtype=np.float64)


def bracketing_sections(
    samples: FloatArray,
    approx_index: IntArray,
    tangents: FloatArray,
    plane: FloatArray,
    window: int,
) -> tuple[IntArray, FloatArray, BoolArray]:
    """For each sample, the pair (i, i + 1) of planes around it nearest ``approx_index``.

    Parameters
    ----------
    samples : array, shape (M, D)
    approx_index : array of int, shape (M,)
    tangents : array, shape (N, D)
    plane : array, shape (N,)
        t_i . c_i.
    window : int
        Half-width of the search, in sections.

    Returns
    -------
    index : array of int, shape (M,)
    alpha : array, shape (M,)
    found : array of bool, shape (M,)
    """
    n = tangents.shape[0]
    offsets = np.arange(-window, window)
    lower = np.clip(approx_index[:, None] + offsets[None, :], 0, n - 2)  # (M, W)
    dist = np.einsum("md,mwd->mw", samples, tangents[lower]) - plane[lower]
    dist_next = np.einsum("md,mwd->mw", samples, tangents[lower + 1]) - plane[lower + 1]
    crossing = crosses_plane(dist, dist_next)
    score = np.where(crossing, np.abs(offsets + 0.5)[None, :], np.inf)
    best = np.argmin(score, axis=1)
    rows = np.arange(samples.shape[0])
    a, b = dist[rows, best], dist_next[rows, best]
    alpha = np.divide(a, a - b, out=np.zeros_like(a), where=(a - b) != 0.0)
    return lower[rows, best], alpha, np.isfinite(score[rows, best])


def _blocked_bracketing(
    samples: FloatArray, approx_index: IntArray, tangents: FloatArray, plane: FloatArray, window: int
) -> tuple[IntArray, FloatArray, BoolArray]:
    """:func:`bracketing_sections` over blocks of at most ``MAX_BLOCK`` (sample x offset) entries."""
    index, alpha, found = in_row_blocks(
        lambda rows: bracketing_sections(samples[rows], approx_index[rows], tangents, plane, window),
        samples.shape[0],
        2 * window,
    )
    return index, alpha, found


def enclosing_scales(
    samples: FloatArray,
    approx_index: IntArray,
    centres: FloatArray,
    tangents: FloatArray,
    basis: FloatArray,
    sections: CrossSections,
    window: int = 8,
) -> FloatArray:
    """Per-section enlargement that makes every demo sample lie inside the swept canal.

    A demo sample between planes i and i + 1 is judged against the blend of sections i and
    i + 1. Demonstrations that define the boundary lie exactly on it at the planes, but in
    between the blend is a chord and leaves them out by a second-order amount. Enlarging
    both sections by the sample's eta puts it back on the boundary; taking the largest such
    factor per section makes the canal a true envelope of its demonstrations. Samples are
    searched only within ``window`` sections of ``approx_index`` (their own phase).

    Parameters
    ----------
    samples : array, shape (M, D)
    approx_index : array of int, shape (M,)
    centres, tangents : arrays, shape (N, D)
    basis : array, shape (N, D - 1, D)
    sections : CrossSections

    Returns
    -------
    scale : array, shape (N,), >= 1
    """
    n = centres.shape[0]
    scale = np.ones(n)
    if n < 2:
        return scale
    plane = np.einsum("nd,nd->n", centres, tangents)
    # Most samples sit within a few sections of their phase: search there first, and
    # widen only for the rest.
    # Doubling the width finds the same nearest pair as one search of the whole window; each
    # search runs over blocks of samples so that memory stays bounded for large N.
    width = min(4, window)
    index, alpha, found = _blocked_bracketing(samples, approx_index, tangents, plane, width)
    while width < window and not found.all():
        width = min(2 * width, window)
        miss = np.flatnonzero(~found)
        index[miss], alpha[miss], found[miss] = _blocked_bracketing(
            samples[miss], approx_index[miss], tangents, plane, width
        )
    # Only samples whose phase is at an end may be measured on the end sections.
    behind = ~found & (approx_index < window) & (samples @ tangents[0] - plane[0] < 0.0)
    past = ~found & (approx_index > n - 1 - window) & (samples @ tangents[-1] - plane[-1] > 0.0)
    index = np.where(behind, 0, np.where(past, n - 2, index))
    alpha = np.where(behind, 0.0, np.where(past, 1.0, alpha))
    use = found | behind | past
    _, _, eta = blended_location(samples[use], index[use], alpha[use], centres, basis, sections)
    # The blend's chord error is second order: a sample far outside (eta > MAX_STRETCH) was
    # matched to the wrong sections by phase (demos that start far apart and merge late),
    # and stretching a near-zero section by its eta would blow it up; it is left out.
    need = np.where(np.isfinite(eta) & (eta <= MAX_STRETCH), eta, 1.0)
    np.maximum.at(scale, index[use], need)
    np.maximum.at(scale, index[use] + 1, need)
    return scale
