"""Cross-sections of the canal (paper Section 4.1, "Estimating the Radii"; Fig. 1 and 3).

A cross-section i lives in the plane through the directrix point c_i normal to t_i, in the
in-plane basis (n_i, b_i) (3-D) or (n_i,) (2-D). Its input is the in-plane coordinates of
where each demonstration crosses that plane (:mod:`canal_core.crossings`).

Kinds (3-D):

``circle``   centred on c_i, radius = the largest distance to a demo crossing
             (the paper's choice: "the vertex with a maximum distance from the center").
``mec``      the minimum enclosing circle of the crossings and c_i (the paper's
             "circumscribed circle", made well defined for any number of demos); its centre
             may sit off the directrix.
``ellipse``  the minimum-area enclosing ellipse of the crossings and c_i (Khachiyan's
             algorithm, batched over sections), then scaled so every point is inside exactly.
``spline``   a closed C2 periodic cubic spline in polar form r(theta) about c_i through the
             crossings on the section's convex hull, enclosing the rest (Fig. 3), >= 3 demos. Storing the section as a
             radius-by-angle function makes containment and the ratio rule a lookup.

In 2-D a cross-section is an interval [lower, upper] on the normal line, lower <= 0 <= upper:
symmetric for ``circle`` (the 1-D circle), tight and asymmetric for every other kind.

Every section contains c_i and every crossing, by construction: each fit ends by measuring
the points against the fitted boundary and enlarging the boundary if rounding left any out.
Every section is star-shaped about c_i, which is what the ratio rule needs: the function
:func:`boundary_distance` gives the distance from c_i to the boundary along any in-plane
direction, for every kind.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import combinations
from typing import Any

import numpy as np

from .validation import FloatArray, IntArray

KINDS_3D = ("circle", "mec", "ellipse", "spline")
KINDS = (*KINDS_3D, "interval")
TWO_PI = 2.0 * np.pi

#: Relative size (of the canal's largest offset) below which a length counts as zero.
RELATIVE_FLOOR = 1e-9
#: Smallest ellipse semi-axis, relative to the canal's largest offset. Khachiyan's scatter
#: matrix has a condition number of about (size / floor)^2: 1e-9 made it singular in double
#: precision for collinear crossings (two demos), 1e-6 keeps it near 1e12.
ELLIPSE_RELATIVE_FLOOR = 1e-6
#: Above this many points per section, the minimum enclosing circle is found per section
#: with Welzl's algorithm instead of the vectorised enumeration of all pairs and triples.
MEC_ENUMERATION_LIMIT = 13
KHACHIYAN_TOLERANCE = 1e-8
#: Evenly spaced extra knots of a spline section (on the hull polygon, like the demo knots).
SPLINE_GUIDES = 12
#: A spline section's boundary is never nearer c_i than this fraction of its largest knot
#: radius, so every direction has a positive reach the envelope can scale.
SPLINE_FLOOR = 1e-3
KHACHIYAN_MAX_ITERATIONS = 2000


@dataclass(frozen=True, eq=False)
class CrossSections:
    """The N cross-sections of a canal.

    Attributes
    ----------
    kind : str
        One of ``circle``, ``mec``, ``ellipse``, ``spline``, ``interval``.
    params : dict of str to array
        ``circle``: radius (N,). ``mec``: center (N, 2), radius (N,).
        ``ellipse``: center (N, 2), axes (N, 2), angle (N,) (axes[:, 0] along angle).
        ``spline``: knot_angles (N, K), knot_radii (N, K), scale (N,).
        ``interval``: lower (N,), upper (N,).
    """

    kind: str
    params: dict[str, FloatArray]
    # Arrays computed from params once (spline second derivatives need a linear solve per
    # section). Passed in only by this module, when the params they depend on are unchanged.
    _derived: dict[str, FloatArray] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        if self.kind == "spline" and "second" not in self._derived:
            self._derived["second"] = periodic_spline_second_derivatives(
                self.params["knot_angles"], self.params["knot_radii"]
            )
        elif self.kind == "ellipse":
            self._derived["matrix"] = ellipse_matrices(self.params["axes"], self.params["angle"])

    @property
    def n_sections(self) -> int:
        return int(next(iter(self.params.values())).shape[0])

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, **{k: v.tolist() for k, v in self.params.items()}}


# ---------------------------------------------------------------------------------------
# circle, interval


def circle_sections(coords: FloatArray) -> CrossSections:
    """Circles centred on the directrix through the farthest crossing.

    Parameters
    ----------
    coords : array, shape (N, n, 2)
    """
    return CrossSections("circle", {"radius": np.linalg.norm(coords, axis=2).max(axis=1)})


def interval_sections(coords: FloatArray, symmetric: bool) -> CrossSections:
    """2-D sections: the interval on the normal line holding c_i and every crossing.

    Parameters
    ----------
    coords : array, shape (N, n, 1)
    symmetric : bool
        ``[-r, r]`` with r the largest offset (the 1-D circle) when True.
    """
    offsets = coords[:, :, 0]
    if symmetric:
        radius = np.abs(offsets).max(axis=1)
        return CrossSections("interval", {"lower": -radius, "upper": radius})
    return CrossSections(
        "interval",
        {"lower": np.minimum(offsets.min(axis=1), 0.0), "upper": np.maximum(offsets.max(axis=1), 0.0)},
    )


# ---------------------------------------------------------------------------------------
# minimum enclosing circle


def _with_origin(coords: FloatArray) -> FloatArray:
    """Append c_i (the origin of each section) so every section contains its directrix point."""
    return np.concatenate([coords, np.zeros((coords.shape[0], 1, coords.shape[2]))], axis=1)


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
    points = _with_origin(coords)
    if points.shape[1] <= MEC_ENUMERATION_LIMIT:
        centre, _ = _mec_by_enumeration(points)
    else:  # many demos: per-section loop, expected O(n) each
        centre = np.stack([_mec_welzl(p)[0] for p in points])
    # The radius is re-measured so that containment holds exactly, whatever the rounding.
    radius = np.linalg.norm(points - centre[:, None, :], axis=2).max(axis=1)
    return CrossSections("mec", {"center": centre, "radius": radius})


# ---------------------------------------------------------------------------------------
# ellipse


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
        [_with_origin(coords), np.broadcast_to(cross, (coords.shape[0], 4, 2))], axis=1
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


# ---------------------------------------------------------------------------------------
# closed spline (polar)


def periodic_spline_second_derivatives(knots: FloatArray, values: FloatArray) -> FloatArray:
    """Second derivatives of the periodic C2 cubic spline through (knots, values), per row.

    Parameters
    ----------
    knots : array, shape (N, K)
        Strictly increasing angles within one turn, K >= 2.
    values : array, shape (N, K)

    Returns
    -------
    second : array, shape (N, K)
    """
    n_sec, k = knots.shape
    h = np.diff(np.concatenate([knots, knots[:, :1] + TWO_PI], axis=1), axis=1)  # (N, K)
    slope = np.diff(np.concatenate([values, values[:, :1]], axis=1), axis=1) / h
    rhs = 6.0 * (slope - np.roll(slope, 1, axis=1))
    h_prev = np.roll(h, 1, axis=1)
    system = np.zeros((n_sec, k, k))
    rows = np.arange(k)
    sec = np.arange(n_sec)[:, None]
    np.add.at(system, (sec, rows, (rows - 1) % k), h_prev)
    np.add.at(system, (sec, rows, rows), 2.0 * (h_prev + h))
    np.add.at(system, (sec, rows, (rows + 1) % k), h)
    return np.asarray(np.linalg.solve(system, rhs[..., None])[..., 0], dtype=np.float64)


def periodic_spline_values(
    knots: FloatArray, values: FloatArray, second: FloatArray, theta: FloatArray
) -> FloatArray:
    """Evaluate per-row periodic cubic splines at one angle per row.

    Parameters
    ----------
    knots, values, second : arrays, shape (M, K)
    theta : array, shape (M,)

    Returns
    -------
    r : array, shape (M,)
    """
    rows = np.arange(knots.shape[0])
    k = knots.shape[1]
    theta = np.mod(theta - knots[:, 0], TWO_PI) + knots[:, 0]
    seg = np.clip((knots <= theta[:, None]).sum(axis=1) - 1, 0, k - 1)
    nxt = (seg + 1) % k
    x0 = knots[rows, seg]
    x1 = np.where(seg + 1 < k, knots[rows, nxt], knots[:, 0] + TWO_PI)
    y0, y1 = values[rows, seg], values[rows, nxt]
    m0, m1 = second[rows, seg], second[rows, nxt]
    h = x1 - x0
    a, b = x1 - theta, theta - x0
    return np.asarray(
        (m0 * a**3 + m1 * b**3) / (6.0 * h) + (y0 / h - m0 * h / 6.0) * a + (y1 / h - m1 * h / 6.0) * b,
        dtype=np.float64,
    )


def hull_radial_function(points: FloatArray, theta: FloatArray, n_normals: int = 256) -> FloatArray:
    """Radial function about the origin of a polygon circumscribing each section's points.

    The polygon is the intersection of ``n_normals`` half-planes, each the support
    half-plane of the points (and the origin) in one direction, so it contains the convex
    hull and exceeds it by at most 1/cos(pi / n_normals) - 1 (8e-5 for 256 normals).

    Parameters
    ----------
    points : array, shape (N, m, 2)
    theta : array, shape (N, K)
        Angles at which to evaluate.

    Returns
    -------
    r : array, shape (N, K)
    """
    phi = np.linspace(0.0, TWO_PI, n_normals, endpoint=False)
    normals = np.stack([np.cos(phi), np.sin(phi)], axis=1)  # (L, 2)
    support = np.maximum(np.einsum("nmi,li->nml", points, normals).max(axis=1), 0.0)  # (N, L)
    cos = np.cos(theta[:, :, None] - phi[None, None, :])  # (N, K, L)
    with np.errstate(divide="ignore"):
        reach = np.where(cos > 1e-9, support[:, None, :] / np.where(cos > 1e-9, cos, 1.0), np.inf)
    return np.asarray(reach.min(axis=2), dtype=np.float64)


def _spline_knots(coords: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Polar knots (angle, radius) per section: each demo's angle, on the section's hull."""
    # Between two demos far apart in angle the cubic overshoots (through c_i, measured:
    # radius 0 over whole arcs of 200 sections of 1,000 with 6 noisy demos). Fixed knots
    # every 2 pi / SPLINE_GUIDES radians on the same hull polygon keep it on the hull there.
    guides = np.broadcast_to(np.arange(SPLINE_GUIDES) * (TWO_PI / SPLINE_GUIDES), (coords.shape[0], SPLINE_GUIDES))
    theta = np.concatenate([np.mod(np.arctan2(coords[:, :, 1], coords[:, :, 0]), TWO_PI), guides], axis=1)
    k = theta.shape[1]
    order = np.argsort(theta, axis=1)
    theta = np.take_along_axis(theta, order, axis=1)
    # Knots sit where each demo's ray meets the convex hull of the crossings (and c_i): the
    # outermost demos are interpolated, inner ones are enclosed. Interpolating every demo
    # instead makes the closed curve swing wildly (even through c_i) wherever two demos
    # cross the plane at nearly the same angle but different distances.
    rho = hull_radial_function(_with_origin(coords), theta)

    # Near-coincident angles would make the spline's slope explode: merge them to their
    # larger radius (which still contains both), then spread the knots minimally apart.
    min_gap = 1e-6
    for _ in range(k):
        close = np.diff(theta, axis=1) < min_gap
        if not close.any():
            break
        pair_max = np.maximum(rho[:, :-1], rho[:, 1:])
        rho[:, :-1] = np.where(close, pair_max, rho[:, :-1])
        rho[:, 1:] = np.where(close, np.maximum(rho[:, 1:], pair_max), rho[:, 1:])
        ramp = np.arange(k) * min_gap
        theta = np.maximum.accumulate(theta - ramp, axis=1) + ramp
    return theta, rho


def spline_sections(coords: FloatArray) -> CrossSections:
    """Closed periodic cubic splines r(theta) about c_i enclosing every crossing (>= 3 demos).

    The spline passes through the crossings on the convex hull of the section and encloses
    the others (see :func:`_spline_knots`).

    Parameters
    ----------
    coords : array, shape (N, n, 2)
    """
    knots, radii = _spline_knots(coords)
    sections = CrossSections(
        "spline", {"knot_angles": knots, "knot_radii": radii, "scale": np.ones(knots.shape[0])}
    )
    # Measure every crossing against the fitted boundary; enlarge a section if rounding or
    # the knot merging left one outside, so containment is exact by construction.
    n_sec, n = coords.shape[:2]
    rows = np.repeat(np.arange(n_sec), n)
    flat = coords.reshape(-1, 2)
    rho = np.linalg.norm(flat, axis=1)
    unit = np.divide(flat, rho[:, None], out=np.zeros_like(flat), where=rho[:, None] > 0)
    reach = boundary_distance(sections, rows, unit)
    ratio = np.divide(rho, reach, out=np.zeros_like(rho), where=reach > 0)
    scale = np.maximum(ratio.reshape(n_sec, n).max(axis=1), 1.0)
    return CrossSections(
        "spline", {"knot_angles": knots, "knot_radii": radii, "scale": scale}, dict(sections._derived)
    )


# ---------------------------------------------------------------------------------------
# the one lookup every consumer uses


def boundary_distance(sections: CrossSections, index: IntArray, direction: FloatArray) -> FloatArray:
    """Distance from c_i to the boundary of section i along an in-plane unit direction.

    This is |g_i c_i| of the ratio rule (Alg. 1 line 10, Fig. 4).

    Parameters
    ----------
    sections : CrossSections
    index : array of int, shape (M,)
        Section of each query.
    direction : array, shape (M, D - 1)
        Unit in-plane directions (2-D: +-1 on the normal line).

    Returns
    -------
    distance : array, shape (M,)
        Non-negative.
    """
    p = sections.params
    kind = sections.kind
    if kind == "circle":
        return p["radius"][index]
    if kind == "interval":
        return np.where(direction[:, 0] >= 0.0, p["upper"][index], -p["lower"][index])
    if kind == "mec":
        o = p["center"][index]
        uo = np.einsum("ij,ij->i", direction, o)
        disc = uo**2 - np.einsum("ij,ij->i", o, o) + p["radius"][index] ** 2
        return np.maximum(uo + np.sqrt(np.maximum(disc, 0.0)), 0.0)
    if kind == "ellipse":
        o = p["center"][index]
        a = sections._derived["matrix"][index]
        au = np.einsum("nij,nj->ni", a, direction)
        uau = np.einsum("ni,ni->n", direction, au)
        uao = np.einsum("ni,ni->n", o, au)
        oao = np.einsum("ni,nij,nj->n", o, a, o)
        disc = uao**2 - uau * (oao - 1.0)
        return np.maximum((uao + np.sqrt(np.maximum(disc, 0.0))) / uau, 0.0)
    if kind == "spline":
        theta = np.arctan2(direction[:, 1], direction[:, 0])
        r = periodic_spline_values(
            p["knot_angles"][index], p["knot_radii"][index], sections._derived["second"][index], theta
        )
        floor = SPLINE_FLOOR * p["knot_radii"][index].max(axis=1)
        return np.maximum(r, floor) * p["scale"][index]
    raise ValueError(f"unknown cross-section kind {kind!r}")


def fitted_sections(coords: FloatArray, kind: str) -> CrossSections:
    """Fit cross-sections of ``kind`` to in-plane crossings.

    Parameters
    ----------
    coords : array, shape (N, n, D - 1)
    kind : str
        ``circle``, ``mec``, ``ellipse`` or ``spline``; in 2-D every kind becomes an
        ``interval`` (symmetric for ``circle``).
    """
    if coords.shape[2] == 1:
        return interval_sections(coords, symmetric=(kind == "circle"))
    size = max(float(np.abs(coords).max(initial=0.0)), 1e-300)
    if kind == "circle":
        return circle_sections(coords)
    if kind == "mec":
        return mec_sections(coords)
    if kind == "ellipse":
        return ellipse_sections(coords, ELLIPSE_RELATIVE_FLOOR * size)
    if kind == "spline":
        return spline_sections(coords)
    raise ValueError(f"unknown cross-section kind {kind!r}")


def section_radii(sections: CrossSections, n_angles: int = 64) -> FloatArray:
    """Largest boundary distance from c_i per section, shape (N,) (for plots and colour ramps)."""
    n = sections.n_sections
    if sections.kind == "circle":
        return sections.params["radius"].copy()
    if sections.kind == "interval":
        return np.maximum(sections.params["upper"], -sections.params["lower"])
    angles = np.linspace(0.0, TWO_PI, n_angles, endpoint=False)
    dirs = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    index = np.repeat(np.arange(n), n_angles)
    dist = boundary_distance(sections, index, np.tile(dirs, (n, 1)))
    return np.asarray(dist.reshape(n, n_angles).max(axis=1), dtype=np.float64)


def scaled_sections(sections: CrossSections, scale: FloatArray) -> CrossSections:
    """Sections enlarged by a homothety about c_i: every boundary distance times ``scale`` (N,)."""
    p = {k: v.copy() for k, v in sections.params.items()}
    if sections.kind == "circle":
        p["radius"] *= scale
    elif sections.kind == "interval":
        p["lower"] *= scale
        p["upper"] *= scale
    elif sections.kind in ("mec", "ellipse"):
        p["center"] *= scale[:, None]
        key = "radius" if sections.kind == "mec" else "axes"
        p[key] *= scale if key == "radius" else scale[:, None]
    elif sections.kind == "spline":
        p["scale"] *= scale
        return CrossSections("spline", p, dict(sections._derived))  # knots unchanged
    return CrossSections(sections.kind, p)


def floored_sections(sections: CrossSections, floor: float) -> CrossSections:
    """Sections whose boundary lies at least about ``floor`` from c_i in every direction.

    The envelope (:func:`canal_core.reproduce.enclosing_scales`) grows sections by a
    homothety about c_i, which cannot enlarge a boundary that passes through c_i (a zero
    radius, a one-sided interval, a spline knot of radius 0). ``floor`` is a tiny length
    (1e-9 of the canal's size in :func:`canal_core.fit`), so every other section is unchanged.

    Parameters
    ----------
    sections : CrossSections
    floor : float
        Smallest boundary distance, in the data's units.
    """
    p = {k: v.copy() for k, v in sections.params.items()}
    kind = sections.kind
    if kind == "circle":
        p["radius"] = np.maximum(p["radius"], floor)
    elif kind == "interval":
        p["lower"] = np.minimum(p["lower"], -floor)
        p["upper"] = np.maximum(p["upper"], floor)
    elif kind == "mec":
        p["radius"] = np.maximum(p["radius"], np.linalg.norm(p["center"], axis=1) + floor)
    elif kind == "ellipse":
        # c_i sits strictly inside by the regularising cross of ellipse_sections; only an
        # ellipse with c_i on its boundary (o^T A o = 1) is grown, into a disc around c_i.
        o = p["center"]
        depth = np.einsum("ni,nij,nj->n", o, sections._derived["matrix"], o)
        edge = depth > 1.0 - 1e-9
        if not edge.any():
            return sections
        p["axes"][edge] = np.maximum(p["axes"][edge], np.linalg.norm(o[edge], axis=1)[:, None] + floor)
    elif kind == "spline":
        if np.all(p["knot_radii"] >= floor):
            return sections
        p["knot_radii"] = np.maximum(p["knot_radii"], floor)
        return CrossSections(kind, p)
    return CrossSections(kind, p)
