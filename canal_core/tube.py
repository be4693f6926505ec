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
