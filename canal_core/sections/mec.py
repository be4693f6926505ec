"""``mec``: the minimum enclosing circle of the crossings and c_i.

The paper's "circumscribed circle" (Section 4.1), made well defined for any number of demos;
its centre may sit off the directrix, so the boundary distance depends on the direction.
"""

from __future__ import annotations

from itertools import combinations

import numpy as np

from ..validation import FloatArray, IntArray
from .base import CrossSections, SectionKind, copied_params, with_origin

#: Above this many points per section, the minimum enclosing circle is found per section
#: with Welzl's algorithm instead of the vectorised enumeration of all pairs and triples.
MEC_ENUMERATION_LIMIT = 13


def _circumcircles(a: FloatArray, b: FloatArray, c: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Circumcentres and radii of triangles (..., 2); collinear triples get an infinite radius."""
    d = 2.0 * (
        a[..., 0] * (b[..., 1] - c[..., 1])
        + b[..., 0] * (c[..., 1] - a[..., 1])
        + c[..., 0] * (a[..., 1] - b[..., 1])
    )
    sa, sb, sc = (np.einsum("...i,...i->...", p, p) for p in (a, b, c))
    ux = sa * (b[..., 1] - c[..., 1]) + sb * (c[..., 1] - a[..., 1]) + sc * (a[..., 1] - b[..., 1])
    uy = sa * (c[..., 0] - b[..., 0]) + sb * (a[..., 0] - c[..., 0]) + sc * (b[..., 0] - a[..., 0])
    scale = np.maximum(np.abs(a).max(axis=-1), np.maximum(np.abs(b).max(axis=-1), np.abs(c).max(axis=-1)))
    ok = np.abs(d) > 1e-12 * np.maximum(scale, 1e-300) ** 2
    safe = np.where(ok, d, 1.0)
    centre = np.stack([ux / safe, uy / safe], axis=-1)
    radius = np.where(ok, np.linalg.norm(centre - a, axis=-1), np.inf)
    return centre, radius


def _mec_by_enumeration(points: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Exact MEC of few points per section: the smallest enclosing pair- or triple-circle."""
    m = points.shape[1]
    pairs = np.array(list(combinations(range(m), 2)))
    triples = np.array(list(combinations(range(m), 3)))
    pair_centre = 0.5 * (points[:, pairs[:, 0]] + points[:, pairs[:, 1]])
    pair_radius = 0.5 * np.linalg.norm(points[:, pairs[:, 0]] - points[:, pairs[:, 1]], axis=2)
    tri_centre, tri_radius = _circumcircles(
        points[:, triples[:, 0]], points[:, triples[:, 1]], points[:, triples[:, 2]]
    )
    centres = np.concatenate([pair_centre, tri_centre], axis=1)  # (N, C, 2)
    radii = np.concatenate([pair_radius, tri_radius], axis=1)  # (N, C)
    reach = np.linalg.norm(centres[:, :, None, :] - points[:, None, :, :], axis=3).max(axis=2)
    encloses = reach <= radii * (1.0 + 1e-10) + 1e-300
    best = np.argmin(np.where(encloses, radii, np.inf), axis=1)
    return centres[np.arange(points.shape[0]), best], radii[np.arange(points.shape[0]), best]


def _mec_welzl(points: FloatArray) -> tuple[FloatArray, FloatArray]:
    """MEC of one section's points (m, 2) by Welzl's randomised incremental algorithm."""
    rng = np.random.default_rng(0)
    pts = points[rng.permutation(points.shape[0])]
    centre, radius = pts[0].copy(), 0.0

    def outside(p: FloatArray) -> bool:
        return float(np.linalg.norm(p - centre)) > radius * (1.0 + 1e-12) + 1e-300

    for i in range(1, pts.shape[0]):
        if not outside(pts[i]):
            continue
        centre, radius = pts[i].copy(), 0.0
        for j in range(i):
            if not outside(pts[j]):
                continue
            centre = 0.5 * (pts[i] + pts[j])
            radius = 0.5 * float(np.linalg.norm(pts[i] - pts[j]))
            for k in range(j):
                if outside(pts[k]):
                    c, r = _circumcircles(pts[i], pts[j], pts[k])
                    if np.isfinite(r):
                        centre, radius = c, float(r)
    return centre, np.array(radius)


def mec_sections(coords: FloatArray) -> CrossSections:
    """Minimum enclosing circles of each section's crossings and its directrix point.

    Parameters
    ----------
    coords : array, shape (N, n, 2)
    """
    points = with_origin(coords)
    if points.shape[1] <= MEC_ENUMERATION_LIMIT:
        centre, _ = _mec_by_enumeration(points)
    else:  # many demos: per-section loop, expected O(n) each
        centre = np.stack([_mec_welzl(p)[0] for p in points])
    # The radius is re-measured so that containment holds exactly, whatever the rounding.
    radius = np.linalg.norm(points - centre[:, None, :], axis=2).max(axis=1)
    return CrossSections("mec", {"center": centre, "radius": radius})


def mec_distance(sections: CrossSections, index: IntArray, direction: FloatArray) -> FloatArray:
    """Where the ray from c_i along ``direction`` leaves the circle (c_i is inside), shape (M,)."""
    p = sections.params
    o = p["center"][index]
    uo = np.einsum("ij,ij->i", direction, o)
    disc = uo**2 - np.einsum("ij,ij->i", o, o) + p["radius"][index] ** 2
    return np.maximum(uo + np.sqrt(np.maximum(disc, 0.0)), 0.0)


def scaled_mecs(sections: CrossSections, scale: FloatArray) -> CrossSections:
    p = sections.params
    return CrossSections("mec", {"center": p["center"] * scale[:, None], "radius": p["radius"] * scale})


def floored_mecs(sections: CrossSections, floor: float) -> CrossSections:
    """Circles reaching at least ``floor`` beyond c_i (a circle through c_i grows around it)."""
    p = copied_params(sections)
    p["radius"] = np.maximum(p["radius"], np.linalg.norm(p["center"], axis=1) + floor)
    return CrossSections("mec", p)


MEC = SectionKind(
    name="mec",
    params=("center", "radius"),
    fitted=mec_sections,
    boundary_distance=mec_distance,
    scaled=scaled_mecs,
    floored=floored_mecs,
)
