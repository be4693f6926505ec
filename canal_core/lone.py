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
        In-plane coordinates; 0 on the last section.
    """
    left = max(float(arclength[-1]) - start_arclength, 1e-300) if arclength.size else 1e-300
    kept = np.clip(1.0 - (arclength - start_arclength) / left, 0.0, 1.0)
    return np.asarray(kept[:, None] * np.einsum("kad,d->ka", basis, start_offset), dtype=np.float64)
