"""Moving frames along the directrix.

Three kinds:

* :func:`frenet_frames` -- the paper's Frenet-Serret TNB frame (Eqs. 5-7). It is undefined
  where the curvature vanishes (straight segments) and flips by 180 degrees at inflections;
  on noisy real data it flips many times per trajectory. Kept for comparison with the paper.
  Where the curvature vanishes we carry the previous normal (projected onto the new normal
  plane) instead of the paper's "random vector", so the frame stays deterministic.
* :func:`rotation_minimizing_frames` -- the default: the double-reflection method of
  Wang, Juettler, Zheng and Liu, "Computation of rotation minimizing frames" (ACM TOG 2008).
  It is defined on straight lines, never flips, and is fourth-order accurate.
* :func:`planar_frames` -- for 2-D curves: tangent and its left normal. No choice to make.

All return unit, mutually orthogonal vectors; 3-D frames are right-handed
(``t x n = b``).

Frames are computed on :func:`length_smoothed_curve` of the directrix, not on the directrix
itself (``FitOptions.frame_smoothing``, a Gaussian of 2 % of its length by default). The mean of
noisy demonstrations wiggles from sample to sample; its finite-difference tangents swing,
and even a rotation-minimising frame accumulates twist from those swings (about 27 degrees
over one noisy Task I instance). The ratio rule keeps a start's direction fixed in the
moving frame, so that twist turns straight into reproduction error: on the 3-D benchmark
sets smoothing took the mean RMSE from 80 to 34 (x1e-3), with LASA (2-D) unchanged. The
section centres stay on the unsmoothed directrix; only the planes' orientation is smoothed.

The smoothing is over length, not over a count of sections: where sections crowd (demos that
start apart and slowly, a mean that crawls a fraction of a millimetre over its first
sections while its direction drifts), a count of sections is almost no length, and the
planes swung with the drift. The sweep folded over itself there, far tighter than the canal
was wide: the tube condition (:mod:`canal_core.tube`) then pulled a start well inside the
canal onto the directrix, and where demonstrations settle slowly into their goal the last
sections turned into a fan of rings no demonstration swept (docs/method.md, 4c).
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import as_strided

from .options import FitOptions
from .validation import FloatArray

#: Relative size below which a tangent step or a curvature vector counts as zero.
EPS = 1e-12
#: Most (offset x sample x axis) entries of the smoothing's weighted copies held at once.
SMOOTHING_CHUNK = 1 << 20


def smoothed_curve(points: FloatArray, sigma: float) -> FloatArray:
    """Gaussian-smoothed copy of a curve, for stable tangents on noisy directrices.

    The ends are padded by point reflection (2 p_0 - p_k), which keeps a straight end
    straight and its direction unchanged, where edge padding would bend it towards a stop.

    Parameters
    ----------
    points : array, shape (N, D)
    sigma : float
        Standard deviation, in samples; 0 returns the points unchanged.

    Returns
    -------
    smoothed : array, shape (N, D)
    """
    n = points.shape[0]
    if sigma <= 0.0 or n < 3:
        return points
    k = min(max(1, int(np.ceil(4.0 * sigma))), n - 1)
    padded = np.concatenate([2.0 * points[0] - points[k:0:-1], points, 2.0 * points[-1] - points[-2 : -k - 2 : -1]])
    offsets = np.arange(-k, k + 1)
    weights = np.exp(-0.5 * (offsets / sigma) ** 2)
    weights /= weights.sum()
    # Sum of the 2k + 1 weighted shifted copies, added in order of offset: the copies are
    # rows of one strided view and np.add.reduce over that outer axis adds them one after
    # the other (the same sums, bit for bit, as one pass per offset, at a fraction of the
    # calls). Chunks of rows bound the temporaries; each chunk continues the running sum.
    row_stride, axis_stride = padded.strides
    copies = as_strided(
        padded, shape=(2 * k + 1, n, points.shape[1]), strides=(row_stride, row_stride, axis_stride), writeable=False
    )
    rows = max(1, SMOOTHING_CHUNK // points.size)
    out = np.add.reduce(weights[:rows, None, None] * copies[:rows], axis=0, initial=0.0)
    for first in range(rows, 2 * k + 1, rows):
        terms = weights[first : first + rows, None, None] * copies[first : first + rows]
        out = np.add.reduce(np.concatenate([out[None], terms]), axis=0)
    return np.asarray(out, dtype=np.float64)


def _normalised(vectors: FloatArray) -> tuple[FloatArray, np.ndarray]:
    norms = np.linalg.norm(vectors, axis=-1)
    valid = norms > EPS * max(float(norms.max(initial=0.0)), 1e-300)
    out = np.zeros_like(vectors)
    out[valid] = vectors[valid] / norms[valid, None]
    return out, valid


def _fill_from_neighbours(vectors: FloatArray, valid: np.ndarray) -> FloatArray:
    """Replace invalid rows by the previous valid row (or the next one at the head)."""
    if valid.all():
        return vectors
    index = np.where(valid, np.arange(valid.size), -1)
    index = np.maximum.accumulate(index)
    first_valid = int(np.argmax(valid))
    index[index < 0] = first_valid
    return vectors[index]


def unit_tangents(points: FloatArray) -> FloatArray:
    """Unit tangents e_T of a sampled curve (Eq. 5), by central differences.

    Samples where the curve does not move take the neighbouring tangent, so one repeated
    point never zeroes a frame.

    Parameters
    ----------
    points : array, shape (N, D)

    Returns
    -------
    tangents : array, shape (N, D)
    """
    tangents, valid = _normalised(np.gradient(points, axis=0))
    if not valid.any():
        raise ValueError("curve of zero length has no tangent")
    return _fill_from_neighbours(tangents, valid)


def perpendicular_vector(tangent: FloatArray) -> FloatArray:
    """A deterministic unit vector perpendicular to a 3-D unit ``tangent`` (shape (3,))."""
    axis = np.zeros(3)
    axis[int(np.argmin(np.abs(tangent)))] = 1.0
    normal = axis - (axis @ tangent) * tangent
    return normal / np.linalg.norm(normal)


def frenet_frames(points: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Frenet-Serret frames (Eqs. 5-7) of a 3-D sampled curve.

    Parameters
    ----------
    points : array, shape (N, 3)

    Returns
    -------
    tangents, normals, binormals : arrays, shape (N, 3)
    """
    tangents = unit_tangents(points)
    steps = np.linalg.norm(np.gradient(points, axis=0), axis=1)
    curvature = np.gradient(tangents, axis=0) / np.maximum(steps, 1e-300)[:, None]
    curvature -= np.einsum("ij,ij->i", curvature, tangents)[:, None] * tangents
    # Curvature below 1e-9 turns over the whole curve is rounding noise, not a direction.
    length = float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())
    kappa = np.linalg.norm(curvature, axis=1)
    valid = kappa > 1e-9 / max(length, 1e-300)
    normals = np.zeros_like(curvature)
    normals[valid] = curvature[valid] / kappa[valid, None]
    if not valid.any():
        normals = np.broadcast_to(perpendicular_vector(tangents[0]), tangents.shape).copy()
    else:
        normals = _fill_from_neighbours(normals, valid)
    # A carried-over normal is no longer perpendicular to the new tangent: re-project.
    normals -= np.einsum("ij,ij->i", normals, tangents)[:, None] * tangents
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    binormals = np.cross(tangents, normals)
    return tangents, normals, binormals


def double_reflection_matrices(points: FloatArray, tangents: FloatArray) -> FloatArray:
    """The rotations R_i = H2 H1 that carry frame i to frame i + 1 (Wang et al. 2008).

    H1 reflects in the bisector plane of x_i and x_{i+1}; H2 reflects the reflected
    tangent onto t_{i+1}. R_i depends on positions and tangents only, not on the frame,
    which is what lets the whole chain be composed with a parallel prefix product.

    Parameters
    ----------
    points, tangents : arrays, shape (N, 3)

    Returns
    -------
    rotations : array, shape (N - 1, 3, 3)
    """
    eye = np.eye(3)
    v1 = np.diff(points, axis=0)
    c1 = np.einsum("ij,ij->i", v1, v1)
    scale = float(c1.max(initial=0.0))
    c1_safe = np.where(c1 > EPS * scale, c1, np.inf)  # a repeated point reflects nothing
    h1 = eye - 2.0 * np.einsum("ni,nj->nij", v1, v1) / c1_safe[:, None, None]
    reflected_tangents = np.einsum("nij,nj->ni", h1, tangents[:-1])
    v2 = tangents[1:] - reflected_tangents
    c2 = np.einsum("ij,ij->i", v2, v2)
    c2_safe = np.where(c2 > EPS, c2, np.inf)
    h2 = eye - 2.0 * np.einsum("ni,nj->nij", v2, v2) / c2_safe[:, None, None]
    return np.asarray(h2 @ h1, dtype=np.float64)


def cumulative_products(matrices: FloatArray) -> FloatArray:
    """Prefix products P_k = M_k ... M_1 M_0 by Hillis-Steele doubling (log2 K batched steps).

    Parameters
    ----------
    matrices : array, shape (K, 3, 3)

    Returns
    -------
    products : array, shape (K, 3, 3)
    """
    products = matrices.copy()
    offset = 1
    while offset < products.shape[0]:
        products[offset:] = products[offset:] @ products[:-offset].copy()
        offset *= 2
    return products


def rotation_minimizing_frames(
    points: FloatArray, initial_normal: FloatArray | None = None
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Rotation-minimizing frames of a 3-D sampled curve by double reflection.

    Parameters
    ----------
    points : array, shape (N, 3)
    initial_normal : array, shape (3,), optional
        Normal at the first sample; a deterministic perpendicular of t_0 when None.

    Returns
    -------
    tangents, normals, binormals : arrays, shape (N, 3)
    """
    tangents = unit_tangents(points)
    if initial_normal is None:
        r0 = perpendicular_vector(tangents[0])
    else:
        r0 = initial_normal - (initial_normal @ tangents[0]) * tangents[0]
        r0 /= np.linalg.norm(r0)
    normals = np.empty_like(tangents)
    normals[0] = r0
    if points.shape[0] > 1:
        products = cumulative_products(double_reflection_matrices(points, tangents))
        normals[1:] = products @ r0
    # Products of reflections drift by rounding only; one Gram-Schmidt step removes it.
    normals -= np.einsum("ij,ij->i", normals, tangents)[:, None] * tangents
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    binormals = np.cross(tangents, normals)
    return tangents, normals, binormals


def planar_frames(points: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Tangent and left normal (tangent rotated by +90 degrees) of a 2-D sampled curve.

    Parameters
    ----------
    points : array, shape (N, 2)

    Returns
    -------
    tangents, normals : arrays, shape (N, 2)
    """
    tangents = unit_tangents(points)
    normals = np.column_stack([-tangents[:, 1], tangents[:, 0]])
    return tangents, normals


def length_smoothed_curve(points: FloatArray, fraction: float) -> FloatArray:
    """Gaussian-smoothed copy of a curve over its arc length, not its sample count.

    The curve is resampled evenly in arc length, smoothed there by :func:`smoothed_curve`
    (standard deviation ``fraction`` of its length) and read back at each point's own arc
    length. Where points crowd (a mean path that crawls), a count of samples is a tiny length
    and smoothing by count leaves the crawl's drift in the tangents; by length the crowded
    points share one direction.

    Parameters
    ----------
    points : array, shape (N, D)
    fraction : float
        Standard deviation, as a fraction of the curve's length; 0 returns the points.

    Returns
    -------
    smoothed : array, shape (N, D)
    """
    n = points.shape[0]
    along = np.concatenate([[0.0], np.cumsum(np.sqrt((np.diff(points, axis=0) ** 2).sum(axis=1)))])
    if fraction <= 0.0 or n < 3 or not along[-1] > 0.0:
        return points
    even = np.linspace(0.0, along[-1], n)
    resampled = np.column_stack([np.interp(even, along, points[:, d]) for d in range(points.shape[1])])
    smooth = smoothed_curve(resampled, fraction * (n - 1))
    return np.column_stack([np.interp(along, even, smooth[:, d]) for d in range(points.shape[1])])


def canal_frames(centres: FloatArray, options: FitOptions) -> tuple[FloatArray, FloatArray, FloatArray | None]:
    """Tangents, normals and binormals (None in 2-D) of a directrix (N, D), as ``options`` ask."""
    frame_curve = length_smoothed_curve(centres, options.frame_smoothing)
    if centres.shape[1] == 2:
        tangents, normals = planar_frames(frame_curve)
        return tangents, normals, None
    if options.frames == "frenet":
        return frenet_frames(frame_curve)
    return rotation_minimizing_frames(frame_curve)
