"""``ellipse``: the minimum-area enclosing ellipse of the crossings and c_i.

Khachiyan's algorithm, batched over sections, then scaled so every point is inside exactly.
"""

from __future__ import annotations

import numpy as np

from ..validation import FloatArray, IntArray
from .base import CrossSections, SectionKind, copied_params, with_origin

#: Smallest ellipse semi-axis, relative to the canal's largest offset. Khachiyan's scatter
#: matrix has a condition number of about (size / floor)^2: 1e-9 made it singular in double
#: precision for collinear crossings (two demos), 1e-6 keeps it near 1e12.
ELLIPSE_RELATIVE_FLOOR = 1e-6
KHACHIYAN_TOLERANCE = 1e-8
KHACHIYAN_MAX_ITERATIONS = 2000


def ellipse_matrices(axes: FloatArray, angle: FloatArray) -> FloatArray:
    """Shape matrices A with (q - o)^T A (q - o) <= 1 inside, shape (N, 2, 2)."""
    c, s = np.cos(angle), np.sin(angle)
    rot = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)  # (N, 2, 2)
    inv_sq = 1.0 / axes**2
    return np.asarray(np.einsum("nij,nj,nkj->nik", rot, inv_sq, rot), dtype=np.float64)


def khachiyan_ellipses(points: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Minimum-volume enclosing ellipses of point sets, batched over sections.

    Khachiyan's barycentric coordinate ascent with Todd and Yildirim's "away" steps
    (Todd & Yildirim 2007, "On Khachiyan's algorithm for the computation of minimum-volume
    enclosing ellipsoids"), which converges linearly where plain Khachiyan crawls.

    Parameters
    ----------
    points : array, shape (N, m, 2)
        Must span the plane in every section (add a tiny regularising cross if not).

    Returns
    -------
    centres : array, shape (N, 2)
    matrices : array, shape (N, 2, 2)
        (q - centre)^T A (q - centre) <= 1 up to the tolerance (rescale for exactness).
    """
    n_sec, m, d = points.shape
    lifted = np.concatenate([points, np.ones((n_sec, m, 1))], axis=2)  # (N, m, 3)
    u = np.full((n_sec, m), 1.0 / m)
    active = np.arange(n_sec)
    for _ in range(KHACHIYAN_MAX_ITERATIONS):
        q, ua = lifted[active], u[active]
        x = np.einsum("nmi,nm,nmj->nij", q, ua, q)
        g = np.einsum("nmi,nij,nmj->nm", q, np.linalg.inv(x), q)
        rows = np.arange(active.size)
        up = np.argmax(g, axis=1)
        down = np.argmin(np.where(ua > 0.0, g, np.inf), axis=1)
        g_up, g_down = g[rows, up], g[rows, down]
        eps_up = g_up / (d + 1.0) - 1.0
        eps_down = 1.0 - g_down / (d + 1.0)
        toward = eps_up >= eps_down
        beta_up = (g_up - d - 1.0) / ((d + 1.0) * np.maximum(g_up - 1.0, 1e-300))
        u_down = ua[rows, down]
        beta_down = np.minimum(
            (d + 1.0 - g_down) / ((d + 1.0) * np.maximum(g_down - 1.0, 1e-300)),
            u_down / np.maximum(1.0 - u_down, 1e-300),
        )
        scale = np.where(toward, 1.0 - beta_up, 1.0 + beta_down)
        ua = ua * scale[:, None]
        ua[rows[toward], up[toward]] += beta_up[toward]
        ua[rows[~toward], down[~toward]] -= beta_down[~toward]
        u[active] = np.maximum(ua, 0.0)
        active = active[np.maximum(eps_up, eps_down) > KHACHIYAN_TOLERANCE]
        if active.size == 0:
            break
    centre = np.einsum("nmi,nm->ni", points, u)
    scatter = np.einsum("nmi,nm,nmj->nij", points, u, points) - np.einsum("ni,nj->nij", centre, centre)
    return centre, np.linalg.inv(scatter) / d


def ellipse_sections(coords: FloatArray, floor: float) -> CrossSections:
    """Minimum-area enclosing ellipses of each section's crossings and its directrix point.

    Sections whose points are collinear (two demos, or demos in a line) have no finite
    minimum-area ellipse; a cross of four points at distance ``floor`` around c_i is added
    so the fit is defined, which gives those sections a minor axis of about ``floor``.

    Parameters
    ----------
    coords : array, shape (N, n, 2)
    floor : float
        Smallest semi-axis, in the data's units.
    """
    cross = floor * np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])
    points = np.concatenate(
        [with_origin(coords), np.broadcast_to(cross, (coords.shape[0], 4, 2))], axis=1
    )
    centre, matrix = khachiyan_ellipses(points)
    eigval, eigvec = np.linalg.eigh(0.5 * (matrix + np.swapaxes(matrix, 1, 2)))
    # eigh sorts ascending: the smallest eigenvalue is the major axis.
    axes = 1.0 / np.sqrt(np.maximum(eigval, 1e-300))
    axes = np.maximum(axes, floor)
    angle = np.arctan2(eigvec[:, 1, 0], eigvec[:, 0, 0])
    # Scale to the farthest point so that containment is exact, not approximate.
    a = ellipse_matrices(axes, angle)
    rel = points - centre[:, None, :]
    reach = np.einsum("nmi,nij,nmj->nm", rel, a, rel).max(axis=1)
    axes = axes * np.sqrt(np.maximum(reach, 1.0))[:, None]
    return CrossSections("ellipse", {"center": centre, "axes": axes, "angle": angle})


def fitted_ellipses(coords: FloatArray) -> CrossSections:
    """:func:`ellipse_sections` with the floor at ELLIPSE_RELATIVE_FLOOR of the largest offset."""
    size = max(float(np.abs(coords).max(initial=0.0)), 1e-300)
    return ellipse_sections(coords, ELLIPSE_RELATIVE_FLOOR * size)


def ellipse_distance(sections: CrossSections, index: IntArray, direction: FloatArray) -> FloatArray:
    """Where the ray from c_i along ``direction`` leaves the ellipse (c_i is inside), shape (M,)."""
    p = sections.params
    o = p["center"][index]
    a = sections._derived["matrix"][index]
    au = np.einsum("nij,nj->ni", a, direction)
    uau = np.einsum("ni,ni->n", direction, au)
    uao = np.einsum("ni,ni->n", o, au)
    oao = np.einsum("ni,nij,nj->n", o, a, o)
    disc = uao**2 - uau * (oao - 1.0)
    return np.asarray(np.maximum((uao + np.sqrt(np.maximum(disc, 0.0))) / uau, 0.0), dtype=np.float64)


def scaled_ellipses(sections: CrossSections, scale: FloatArray) -> CrossSections:
    p = sections.params
    return CrossSections(
        "ellipse",
        {"center": p["center"] * scale[:, None], "axes": p["axes"] * scale[:, None], "angle": p["angle"].copy()},
    )


def floored_ellipses(sections: CrossSections, floor: float) -> CrossSections:
    """Ellipses with c_i on their boundary (o^T A o = 1) grown into a disc around c_i.

    c_i sits strictly inside by the regularising cross of :func:`ellipse_sections`; only
    loaded or hand-built ellipses can have it on the boundary.
    """
    p = copied_params(sections)
    o = p["center"]
    depth = np.einsum("ni,nij,nj->n", o, sections._derived["matrix"], o)
    edge = depth > 1.0 - 1e-9
    if not edge.any():
        return sections
    p["axes"][edge] = np.maximum(p["axes"][edge], np.linalg.norm(o[edge], axis=1)[:, None] + floor)
    return CrossSections("ellipse", p)


def ellipse_derived(params: dict[str, FloatArray]) -> dict[str, FloatArray]:
    return {"matrix": ellipse_matrices(params["axes"], params["angle"])}


ELLIPSE = SectionKind(
    name="ellipse",
    params=("center", "axes", "angle"),
    fitted=fitted_ellipses,
    boundary_distance=ellipse_distance,
    scaled=scaled_ellipses,
    floored=floored_ellipses,
    min_demos=3,
    derived=ellipse_derived,
)
