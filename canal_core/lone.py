"""Reproducing from a canal of one demonstration: the start's offset as a fading translation.

A canal of one demonstration, a route shown once, has a borrowed width: it takes its
sections from the nearest route ((L1) of :mod:`canal_core.routes`). Neither that width, nor
its narrowing, nor the section frames turning with the one path say how a start off that
path comes back to it: there is no spread to learn a persistence from
(:func:`canal_core.reproduce.learned_persistence`) and no demonstrations converging to enter
by ((E2) of :mod:`canal_core.entry`). Carried by the ratio rule, the start's offset turns
with the frames and collapses at the donor's pace; the held-out demonstrations of a route
shown once keep it instead as a shift in the world that fades over the motion, much as DMP
started off its one demonstration does. So on such a canal the offset d = x_0 - c(s_0) of
the start from the directrix is carried as that translation, fading linearly in arc length
to 0 at the end, and placed on each later section plane by its in-plane part:

    v_k = (1 - (s_k - s_0) / (s_{N-1} - s_0)) B_k d,   p_k = c_k + B_k^T v_k            (L2)

(B_k: section k's in-plane basis, rows; s_k: the directrix's arc length; s_0 the start's).
The along-tangent part of d is a shift in time, not in space, and a start behind the first
plane is approached along a straight line first ((E4) of :mod:`canal_core.entry`). The
ratios of p_k then take the same rules as the ratio rule's: the tube condition (F1) and
"inside stays inside" (E3), and a start inside keeps every p_k inside.
"""

from __future__ import annotations

import numpy as np

from .cross_sections import CrossSections, boundary_distance
from .entry import inside_stays_inside
from .tube import tube_ratio_caps
from .validation import FloatArray


def lone_offsets(
    start_offset: FloatArray,
    basis: FloatArray,
    arclength: FloatArray,
    start_arclength: float,
) -> FloatArray:
    """v_k of (L2), shape (K, D - 1): the start's offset on each remaining section's plane.

    Parameters
    ----------
    start_offset : array, shape (D,)
        d = x_0 - c(s_0), the start less the directrix at the start's arc length.
    basis : array, shape (K, D - 1, D)
        B_k of the remaining sections.
    arclength : array, shape (K,)
        s_k of the remaining sections (the last is the canal's length).
    start_arclength : float
        s_0.

    Returns
    -------
    offsets : array, shape (K, D - 1)
        In-plane coordinates; 0 on the last section, whatever s_0.
    """
    left = max(float(arclength[-1]) - start_arclength, 1e-300) if arclength.size else 1e-300
    kept = np.clip(1.0 - (arclength - start_arclength) / left, 0.0, 1.0)
    # The end is reached, also from a start on or beyond the last plane (nothing left to fade over).
    kept[-1:] = 0.0
    return np.asarray(kept[:, None] * np.einsum("kad,d->ka", basis, start_offset), dtype=np.float64)


def lone_path(
    start_offset: FloatArray,
    start_arclength: float,
    eta: float,
    direction: FloatArray,
    centres: FloatArray,
    basis: FloatArray,
    arclength: FloatArray,
    curvature: FloatArray,
    sections: CrossSections,
    first: int,
) -> tuple[FloatArray, FloatArray]:
    """The (L2) path on the remaining sections first .. N - 1 and its ratios.

    The ratios are capped by the tube condition (F1) and kept inside by (E3): from the first
    section inside on for a start outside, everywhere for a start inside.

    Parameters
    ----------
    start_offset : array, shape (D,)
        d = x_0 - c(s_0).
    start_arclength : float
        s_0.
    eta : float
        The start's ratio (above 1: outside).
    direction : array, shape (D - 1,)
        The start's in-plane direction, used where the offset has faded to nothing.
    centres, basis, arclength, curvature : arrays, shapes (K, D), (K, D - 1, D), (K,), (K, D - 1)
        The directrix, the in-plane bases, the arc length and the in-plane curvature of
        sections first .. N - 1.
    sections : CrossSections
        All the canal's sections.
    first : int
        Index of the first remaining section.

    Returns
    -------
    path : array, shape (K, D)
    ratios : array, shape (K,)
    """
    offsets = lone_offsets(start_offset, basis, arclength, start_arclength)
    length = np.linalg.norm(offsets, axis=1)
    # Where the offset has faded to nothing its direction does not matter: the start's is taken.
    directions = np.where(length[:, None] > 0.0, offsets / np.maximum(length, 1e-300)[:, None], direction)
    reach = boundary_distance(sections, np.arange(first, first + length.size), directions)
    ratios = np.divide(length, reach, out=np.zeros_like(length), where=reach > 0.0)
    ratios = np.minimum(ratios, tube_ratio_caps(reach, directions, curvature))  # (F1)
    ratios = inside_stays_inside(ratios) if eta > 1.0 else np.minimum(ratios, 1.0)  # (E3)
    kept = (ratios * reach)[:, None] * directions
    return np.asarray(centres + np.einsum("ka,kad->kd", kept, basis), dtype=np.float64), ratios
