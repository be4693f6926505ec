"""Sections grown to enclose every demonstrated sample: how much each fitted section grows.

Not the envelope of Eqs. 1-2 (the surface a family of spheres sweeps, Eq. 9, which is
:mod:`canal_core.surface`): this is the fit's guarantee that the canal holds its demonstrations.

The cross-sections are fitted to where the demonstrations cross each plane (paper Section 4.1);
between the planes the swept canal blends neighbouring sections, and a demonstrated sample can
fall outside that blend. :func:`enclosing_scales` measures every sample on the pairs of
planes :meth:`canal_core.Canal.contains` weighs and returns the homothety about c_i per
section that puts them all inside, so the canal is the envelope of its demonstrations by
construction (docs/method.md, section 1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .cross_sections import CrossSections
from .crossings import WORK_CHUNK, in_row_blocks, sign_changes
from .reproduce import Location, blended_location, growth_locations, location_columns
from .validation import BoolArray, FloatArray, IntArray

#: Largest eta at which a demo sample near its own phase enlarges the two sections around it
#: directly; samples further out are located over the whole canal (see enclosing_scales).
MAX_STRETCH = 1.5


def bracketing_sections(
    samples: FloatArray,
    approx_index: IntArray,
    tangents: FloatArray,
    plane: FloatArray,
    window: int,
    inner: int = 0,
) -> tuple[IntArray, FloatArray, BoolArray]:
    """For each sample, the pair (i, i + 1) of planes around it nearest ``approx_index``.

    Pairs i = approx_index + o with o in [-window, -inner) or [inner, window) are searched;
    the one with the smallest |o + 0.5| that the sample lies between wins (the earlier one
    on a tie). ``inner`` > 0 searches only the shell a previous search of half-width
    ``inner`` did not cover.

    Parameters
    ----------
    samples : array, shape (M, D)
    approx_index : array of int, shape (M,)
    tangents : array, shape (N, D)
    plane : array, shape (N,)
        t_i . c_i.
    window : int
        Half-width of the search, in sections.
    inner : int
        Half-width already searched (0: none).

    Returns
    -------
    index : array of int, shape (M,)
    alpha : array, shape (M,)
    found : array of bool, shape (M,)
    """
    n = tangents.shape[0]
    m, dim = samples.shape
    pairs = window - inner  # per shell
    # Plane columns of the left shell (offsets -window .. -inner) and of the right one
    # (inner .. window); pair o uses columns o and o + 1 of its shell.
    starts = np.array([-window, inner])
    # Plane arrays padded by ``window`` copies of their end values on each side (what
    # clipping the columns would read), so every column is in range without a clip.
    cols = (approx_index + window)[:, None, None] + (starts[:, None] + np.arange(pairs + 1)[None, :])[None]  # (M, 2, S + 1)
    axes = np.concatenate([np.repeat(tangents[:1], window, axis=0), tangents, np.repeat(tangents[-1:], window, axis=0)]).T.copy()
    levels = np.concatenate([np.full(window, plane[0]), plane, np.full(window, plane[-1])])
    valid = None
    if m and (int(approx_index.min()) - window < 0 or int(approx_index.max()) + window > n - 2):
        pair_ok = np.zeros(n + 2 * window, dtype=bool)  # a real pair, not a copy at the ends
        pair_ok[window : window + n - 1] = True
        valid = np.take(pair_ok, cols[:, :, :-1])
    # t_k . x - t_k . c_k, one axis at a time from contiguous rows (no (M, W, D) gather).
    dist = np.take(axes[0], cols) * samples[:, 0, None, None]
    for axis in range(1, dim):
        dist += np.take(axes[axis], cols) * samples[:, axis, None, None]
    dist -= np.take(levels, cols)
    changes = sign_changes(dist).reshape(m, 2 * pairs)
    if valid is not None:
        changes &= valid.reshape(m, 2 * pairs)
    # Pairs in order of preference: smallest |o + 0.5| first, the earlier pair on a tie.
    offsets = (starts[:, None] + np.arange(pairs)[None, :]).reshape(-1)
    preference = np.lexsort((offsets, np.abs(offsets + 0.5)))
    ranked = changes[:, preference]
    first = np.argmax(ranked, axis=1)
    best = preference[first]
    rows = np.arange(m)
    found = ranked[rows, first]
    shell, step = np.divmod(best, pairs)
    at = (rows * 2 + shell) * (pairs + 1) + step  # flat index into dist (M, 2, S + 1)
    a, b = np.take(dist, at), np.take(dist, at + 1)
    alpha = np.divide(a, a - b, out=np.zeros_like(a), where=(a - b) != 0.0)
    index = np.clip(approx_index + offsets[best], 0, n - 2).astype(np.int64)
    return index, alpha, np.asarray(found)


def _blocked_bracketing(
    samples: FloatArray,
    approx_index: IntArray,
    tangents: FloatArray,
    plane: FloatArray,
    window: int,
    inner: int = 0,
) -> tuple[IntArray, FloatArray, BoolArray]:
    """:func:`bracketing_sections` over blocks of at most ``WORK_CHUNK`` (sample x offset) entries
    (temporaries of a few hundred kB, reused from block to block)."""
    index, alpha, found = in_row_blocks(
        lambda rows: bracketing_sections(samples[rows], approx_index[rows], tangents, plane, window, inner),
        samples.shape[0],
        2 * (window - inner + 1),
        WORK_CHUNK,
    )
    return index, alpha, found


def _far_locations(
    samples: FloatArray,
    centres: FloatArray,
    tangents: FloatArray,
    basis: FloatArray,
    sections: CrossSections,
) -> Location:
    """:func:`growth_locations` over blocks of rows, so memory stays bounded for large N."""
    n = centres.shape[0]
    parts = in_row_blocks(
        lambda rows: location_columns(growth_locations(samples[rows], centres, tangents, basis, sections)),
        samples.shape[0],
        4 * n,
    )
    return Location(parts[0], parts[1], parts[2], parts[3], parts[4], parts[5])


@dataclass(frozen=True, eq=False)
class Enclosure:
    """How much the fitted sections had to grow to hold every demonstrated sample.

    Attributes
    ----------
    scale : array, shape (N,)
        Homothety factor about c_i per section, >= 1.
    depths : array, shape (2,)
        Axial reach needed behind the first plane and past the last one.
    far : int
        Samples that were not held near their own phase and were located over the whole
        canal (each costs one row of N plane distances, whatever its distance from its phase).
    """

    scale: FloatArray
    depths: FloatArray
    far: int


def enclosing_scales(
    samples: FloatArray,
    approx_index: IntArray,
    centres: FloatArray,
    tangents: FloatArray,
    basis: FloatArray,
    sections: CrossSections,
    window: int = 32,
) -> Enclosure:
    """Per-section enlargement that puts every demo sample inside the swept canal.

    Two passes, both vectorised:

    1. Near its phase. A sample between planes i and i + 1 (the pair nearest
       ``approx_index``: searched in windows of 4, 8, ... sections around it, up to the
       whole canal) is judged against the blend of sections i and i + 1.
       Demonstrations that define the boundary lie on it at the planes, but in between the
       blend is a chord and leaves them out by a second-order amount; enlarging both
       sections by the sample's eta (a homothety about c_i, so every boundary distance
       scales by it) puts it back on the boundary. Samples with eta <= ``MAX_STRETCH`` are
       settled here.
    2. Anywhere. The rest (not bracketed near their phase, or far outside there: demos
       that start far apart and merge late, still ends, lagging demos) are located among the
       same candidates :meth:`Canal.contains` weighs (every pair of planes around them and the
       two ends): one that holds them, else the one whose boundary must move least to reach
       them, in lengths (:func:`growth_locations`; the smallest eta would pick a wide section
       across a turn, metres away). That candidate is enlarged by their eta there; an end
       candidate also sets the axial depth. One
       row of N plane distances per such sample: the cost does not depend on how far from
       its phase the sample lies.

    Enlarging only ever lowers every other candidate's eta, so after both passes every
    sample is held: the canal is the envelope of its demonstrations by construction.

    Parameters
    ----------
    samples : array, shape (M, D)
    approx_index : array of int, shape (M,)
    centres, tangents : arrays, shape (N, D)
    basis : array, shape (N, D - 1, D)
    sections : CrossSections
        Every section must have a positive boundary distance in every direction
        (:func:`canal_core.cross_sections.floored_sections`).
    window : int
        Still heads and tails within ``window`` sections of the ends are measured on the end
        section directly (they are bracketed by no pair of planes).

    Returns
    -------
    Enclosure
    """
    n = centres.shape[0]
    scale = np.ones(n)
    depths = np.zeros(2)
    if n < 2 or samples.shape[0] == 0:
        return Enclosure(scale, depths, 0)
    plane = np.einsum("nd,nd->n", centres, tangents)
    # Most samples sit within a few sections of their phase: search there first; the rest
    # get one row of all N plane distances each (the nearest bracketing pair to their phase,
    # however far: noisy or lagging demos are tens of sections off their arc-length phase).
    # The local search doubles its width up to ``window``; past that the cost per sample is
    # one row of N, whatever its distance from its phase.
    width = min(4, window)
    index, alpha, found = _blocked_bracketing(samples, approx_index, tangents, plane, width)
    # Still heads and tails (seconds of a standing arm in a raw log: often most of the
    # samples) lie behind the first plane or past the last, where no nearby pair of planes
    # brackets them. Each holds on its end section alone, so it is measured there directly
    # instead of costing rows of N plane distances in the wider searches below. A sample
    # behind the first plane *and* past the last goes the general way (either end may count).
    behind = samples @ tangents[0] - plane[0] < 0.0
    past = samples @ tangents[-1] - plane[-1] > 0.0
    head = ~found & behind & ~past & (approx_index <= window)
    tail = ~found & past & ~behind & (approx_index >= n - 1 - window)
    for end, rows, section, pair, blend in (
        (0, np.flatnonzero(head), 0, 0, 0.0), (1, np.flatnonzero(tail), n - 1, n - 2, 1.0)
    ):
        if rows.size == 0:
            continue
        pts = np.take(samples, rows, axis=0)  # measured as _candidates measures an end: on its section alone
        _, _, end_eta = blended_location(
            pts, np.full(rows.size, pair), np.full(rows.size, blend), centres, basis, sections
        )
        scale[section] = max(scale[section], float(np.where(np.isfinite(end_eta), end_eta, 1.0).max()))
        depths[end] = max(depths[end], float(np.abs(pts @ tangents[section] - plane[section]).max()))
    settled_at_end = head | tail
    found |= settled_at_end
    # Doubling on past ``window`` up to the whole canal finds the same pair as one row of N
    # plane distances per sample would (the nearest bracketing pair to the phase), at a
    # cost that grows with how far the pair lies, not with N.
    # Each step searches only the shell the previous one did not cover.
    while width < n - 1 and not found.all():
        inner = width
        width = min(2 * width, window) if width < window else min(2 * width, n - 1)
        miss = np.flatnonzero(~found)
        index[miss], alpha[miss], found[miss] = _blocked_bracketing(
            np.take(samples, miss, axis=0), approx_index[miss], tangents, plane, width, inner
        )
    # eta only where a pair brackets the sample (the others are settled or go the far way).
    bracketed = np.flatnonzero(found & ~settled_at_end)
    eta = np.full(samples.shape[0], np.inf)
    eta[bracketed] = blended_location(
        np.take(samples, bracketed, axis=0), index[bracketed], alpha[bracketed], centres, basis, sections
    )[2]
    eta[settled_at_end] = 0.0  # held above; index/alpha of these rows are not a bracket
    near = found & np.isfinite(eta) & (eta <= MAX_STRETCH)
    np.maximum.at(scale, index[near], eta[near])
    np.maximum.at(scale, index[near] + 1, eta[near])

    far = np.flatnonzero(~near)
    if far.size:
        loc = _far_locations(np.take(samples, far, axis=0), centres, tangents, basis, sections)
        need = np.where(np.isfinite(loc.eta), loc.eta, 1.0)
        behind, past = loc.axial < 0.0, loc.axial > 0.0
        # An end candidate is measured on the end section alone (alpha 0 or 1).
        lower = np.where(behind | (loc.alpha < 1.0), loc.index, -1)
        upper = np.where(past | (loc.alpha > 0.0), loc.index + 1, -1)
        for rows in (lower, upper):
            ok = rows >= 0
            np.maximum.at(scale, rows[ok], need[ok])
        depths[0] = max(depths[0], -float(loc.axial[behind].min(initial=0.0)))
        depths[1] = max(depths[1], float(loc.axial[past].max(initial=0.0)))
    return Enclosure(scale, depths, int(far.size))
