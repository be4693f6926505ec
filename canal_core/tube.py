"""The tube condition: an offset from the directrix never reaches its centre of curvature.

Sections are planes normal to the directrix. Where the directrix turns with radius of
curvature rho, two neighbouring planes meet on a line rho from the directrix, on the side the
curve turns towards. A point kept at the same ratio from plane to plane (the ratio rule) at
more than rho on that side is carried *backwards* as the planes turn: the swept surface folds
there, and a reproduction riding the inner side of a tight turn traces a small loop (a U-turn
tighter than the canal is wide, or LASA's ``Multi_Models_1`` forced into one canal: docs/method.md
section 4c). A tube of radius
r is regular exactly when r kappa < 1 (kappa = 1 / rho); the reproduction and the live
tracker keep every planned point inside that condition by capping its ratio on section k,

    eta_k <= TUBE_MARGIN / (R_k(u) <u, b_k>)   where <u, b_k> > 0,   b_k = B_k kappa_k     (F1)

(u: the offset's in-plane direction, R_k(u): the section's boundary distance along it,
kappa_k = dt/ds the directrix's curvature vector, pointing at the centre of curvature, B_k
the section's in-plane basis). On the outer side of a turn, on straight stretches and for
offsets below the margin nothing changes; the cap is a ratio, so a capped point is still on
its section and inside the canal.
"""

from __future__ import annotations

import numpy as np

from .validation import FloatArray

#: (F1): the share of the radius of curvature an offset towards the centre of curvature may
#: reach (below 1: the tangents of the discretised directrix are differences, and a point at
#: exactly rho would stand still from one plane to the next).
TUBE_MARGIN = 0.95


def in_plane_curvature(tangents: FloatArray, basis: FloatArray, arclength: FloatArray) -> FloatArray:
    """b_k = B_k kappa_k of (F1): each section's curvature vector in its own in-plane coordinates.

    Parameters
    ----------
    tangents : array, shape (N, D)
    basis : array, shape (N, D - 1, D)
    arclength : array, shape (N,)
        The directrix's arc length at each section (strictly increasing).

    Returns
    -------
    curvature : array, shape (N, D - 1)
        Its length is the curvature 1 / rho; zero where the directrix is straight.
    """
    if tangents.shape[0] < 2:
        return np.zeros((tangents.shape[0], basis.shape[1]))
    # Central differences over the arc length between the neighbours; where the directrix
    # stands still (no length between them) it does not turn either.
    turn = np.gradient(tangents, axis=0)
    step = np.gradient(np.asarray(arclength, dtype=np.float64))
    kappa = np.divide(turn, step[:, None], out=np.zeros_like(turn), where=step[:, None] > 0.0)
    return np.asarray(np.einsum("nkd,nd->nk", basis, kappa), dtype=np.float64)


def tube_ratio_caps(reach: FloatArray, direction: FloatArray, curvature: FloatArray) -> FloatArray:
    """The largest ratio (F1) allows on each section, shape (K,) (inf where it allows any).

    Parameters
    ----------
    reach : array, shape (K,)
        R_k(u) on those sections.
    direction : array, shape (D - 1,) or (K, D - 1)
        u, one for every section or one per section.
    curvature : array, shape (K, D - 1)
        b_k on those sections (:func:`in_plane_curvature`).
    """
    bend = reach * np.einsum("kd,kd->k", np.broadcast_to(direction, curvature.shape), curvature)
    return np.asarray(np.divide(TUBE_MARGIN, bend, out=np.full_like(bend, np.inf), where=bend > 0.0),
                      dtype=np.float64)


def wall_slope_shares(reach: FloatArray, arclength: FloatArray) -> FloatArray:
    """The share of R_k(u) a reproduced point may use (F2), shape (K,): 1 where the wall's
    slope along the directrix is at most 1, less where it is steeper.

    A canal surface is the envelope of spheres of radius r(s) swept along the directrix; it
    exists only where |dr/ds| < 1 (a sphere that grows faster than it moves swallows its
    neighbours). Fitted sections can break that where one section is grown to hold a sample
    of another stretch of a stroke that folds back: the wall then jumps by centimetres from
    one section to the next, and a point riding it at a constant ratio jumps with it. The
    point is placed against the largest wall of slope 1 under the sections,

        R'_k(u) = min_j (R_j(u) + |s_j - s_k|)        (F2)

    (forward and backward running minima), at eta_k R'_k(u) = (eta_k R'_k / R_k) R_k: never
    further out than the ratio rule's own point, so inside stays inside.

    Parameters
    ----------
    reach : array, shape (K,)
        R_k(u) on consecutive sections.
    arclength : array, shape (K,)
        s_k, the directrix's arc length there.
    """
    if reach.size == 0:
        return np.ones(0)
    wall = np.minimum(_floor_ahead(reach, arclength), _floor_behind(reach, arclength))
    return np.asarray(np.divide(wall, reach, out=np.ones_like(reach), where=reach > 0.0), dtype=np.float64)


def paced_offsets(
    offsets: FloatArray, allowed: FloatArray, wall: FloatArray, scheduled: FloatArray | None = None
) -> FloatArray:
    """Offsets that change by at most ``allowed`` from one section to the next (F3), shape (K,).

    With A_k = allowed_1 + ... + allowed_k:

    * a fade is slowed to that pace, on the wall at most (a point inside stays inside):
      r_k = max(m_k, min(max_{j <= k} (m_j - (A_k - A_j)), W_k)), the last point kept
      (the reproduction lands where its schedule does);
    * a rise is lowered to it: m'_k = min_{j <= k} (r_j + A_k - A_j);
    * and, from the first point inside on, so is what is left of a fade (the last sections
      before a landing): m'_k <- min_{j >= k} (m'_j + A_j - A_k);
    * from the first point inside on, every point stays inside (E3): m'_k <- min(m'_k, W_k);
    * a point outside (m_k > W_k: a start outside, entering) is never raised; it comes in as
      fast as its entry schedule does (``scheduled``) or as a demonstration stepped, whichever
      is faster: where the tube's cap (F1) cuts the schedule short, the points before it come
      down to meet it at that pace instead of dropping onto the wall in one step.

    Parameters
    ----------
    offsets : array, shape (K,)
        m_k = eta_k R_k(u), the reproduced points' distances from the directrix.
    allowed : array, shape (K - 1,)
        The largest change from section k - 1 to k.
    wall : array, shape (K,)
        W_k, the boundary distance along the points' direction.
    scheduled : array, shape (K,), optional
        The entry schedule's offsets before the tube's cap; None: the offsets themselves.
    """
    m = np.asarray(offsets, dtype=np.float64)
    if m.size < 2:
        return m.copy()
    a = np.concatenate([[0.0], np.cumsum(allowed)])
    slowed = np.maximum.accumulate(m + a) - a
    raised = np.maximum(m, np.minimum(slowed, wall))
    raised[-1] = m[-1]
    paced = _floor_ahead(raised, a)
    # Before the entry the schedule's own fall is allowed too: the learned entry is smooth,
    # only the cap's cut is not.
    plan = m if scheduled is None else np.asarray(scheduled, dtype=np.float64)
    outside = (m > wall)[:-1]
    fall = np.where(outside, np.maximum(allowed, plan[:-1] - plan[1:]), allowed)
    paced = _floor_behind(paced, np.concatenate([[0.0], np.cumsum(fall)]))
    # Lowering an entering point can bring it inside before its schedule does: from there on
    # the path stays in (E3), whatever the pace.
    entered = np.flatnonzero(paced <= wall)
    if entered.size:
        e = int(entered[0])
        paced[e:] = np.minimum(paced[e:], wall[e:])
    return np.asarray(paced, dtype=np.float64)


def _floor_ahead(values: FloatArray, along: FloatArray) -> FloatArray:
    """min_{j <= k} (v_j + along_k - along_j): the largest values under ``values`` that rise
    by at most the growth of ``along`` (non-decreasing), from each point on."""
    return np.asarray(along + np.minimum.accumulate(values - along), dtype=np.float64)


def _floor_behind(values: FloatArray, along: FloatArray) -> FloatArray:
    """min_{j >= k} (v_j + along_j - along_k): the largest values under ``values`` that fall
    by at most the growth of ``along``, up to each point."""
    return np.asarray(np.minimum.accumulate((values + along)[::-1])[::-1] - along, dtype=np.float64)
