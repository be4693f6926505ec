"""``spline``: a closed C2 periodic cubic spline in polar form r(theta) about c_i (Fig. 3).

It passes through the crossings on the section's convex hull and encloses the rest (>= 3
demos). Storing the section as a radius-by-angle function makes containment and the ratio
rule a lookup.
"""

from __future__ import annotations

import numpy as np

from ..validation import FloatArray, IntArray
from .base import TWO_PI, CrossSections, SectionKind, copied_params, with_origin

#: Evenly spaced extra knots of a spline section (on the hull polygon, like the demo knots).
SPLINE_GUIDES = 12
#: A spline section's boundary is never nearer c_i than this fraction of its largest knot
#: radius, so every direction has a positive reach the envelope can scale.
SPLINE_FLOOR = 1e-3


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
    theta = np.mod(np.arctan2(coords[:, :, 1], coords[:, :, 0]), TWO_PI)
    # A demo a rounding error below angle 0 lands at 2 pi: the same knot as the guide at 0,
    # and a zero-length wrap-around interval (NaN slopes). It is merged with 0 below.
    theta = np.concatenate([np.where(theta > TWO_PI - 1e-6, theta - TWO_PI, theta), guides], axis=1)
    k = theta.shape[1]
    order = np.argsort(theta, axis=1)
    theta = np.take_along_axis(theta, order, axis=1)
    # Knots sit where each demo's ray meets the convex hull of the crossings (and c_i): the
    # outermost demos are interpolated, inner ones are enclosed. Interpolating every demo
    # instead makes the closed curve swing wildly (even through c_i) wherever two demos
    # cross the plane at nearly the same angle but different distances.
    rho = hull_radial_function(with_origin(coords), theta)

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
    reach = spline_distance(sections, rows, unit)
    ratio = np.divide(rho, reach, out=np.zeros_like(rho), where=reach > 0)
    scale = np.maximum(ratio.reshape(n_sec, n).max(axis=1), 1.0)
    return CrossSections(
        "spline", {"knot_angles": knots, "knot_radii": radii, "scale": scale}, dict(sections._derived)
    )


def spline_distance(sections: CrossSections, index: IntArray, direction: FloatArray) -> FloatArray:
    """The spline's radius at the direction's angle (floored, times the section's scale), shape (M,)."""
    p = sections.params
    theta = np.arctan2(direction[:, 1], direction[:, 0])
    r = periodic_spline_values(
        p["knot_angles"][index], p["knot_radii"][index], sections._derived["second"][index], theta
    )
    floor = SPLINE_FLOOR * p["knot_radii"][index].max(axis=1)
    return np.asarray(np.maximum(r, floor) * p["scale"][index], dtype=np.float64)


def scaled_splines(sections: CrossSections, scale: FloatArray) -> CrossSections:
    """The scale parameter times ``scale``; the knots, hence the spline's solve, are unchanged."""
    p = copied_params(sections)
    p["scale"] *= scale
    return CrossSections("spline", p, dict(sections._derived))


def floored_splines(sections: CrossSections, floor: float) -> CrossSections:
    """Knot radii of at least ``floor`` (a knot of radius 0 would put the boundary on c_i)."""
    if np.all(sections.params["knot_radii"] >= floor):
        return sections
    p = copied_params(sections)
    p["knot_radii"] = np.maximum(p["knot_radii"], floor)
    return CrossSections("spline", p)


def spline_derived(params: dict[str, FloatArray]) -> dict[str, FloatArray]:
    return {"second": periodic_spline_second_derivatives(params["knot_angles"], params["knot_radii"])}


SPLINE = SectionKind(
    name="spline",
    params=("knot_angles", "knot_radii", "scale"),
    fitted=spline_sections,
    boundary_distance=spline_distance,
    scaled=scaled_splines,
    floored=floored_splines,
    min_demos=3,
    derived=spline_derived,
)
