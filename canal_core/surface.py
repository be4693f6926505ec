"""The canal surface as a triangle mesh (paper Eq. 9 and Alg. 2).

Two forms for circular sections centred on the directrix:

* the ring form of Alg. 2: ring i is c_i + r_i (n_i cos v + b_i sin v);
* the true envelope of Eq. 9: c + r(-t r' + sqrt(1 - r'^2)(b sin v - n cos v)), r' = dr/ds.
  A sphere family whose radius changes along s touches its envelope on a circle shifted
  back along t by r r' and shrunk by sqrt(1 - r'^2); the ring form ignores this, which is
  visible where the canal narrows quickly. Eq. 9 needs |r'| < 1 (Hartmann's non-degeneracy
  condition); steeper radius changes are clipped to |r'| <= 0.999 and the mesh says so.

Every other section kind is meshed in the ring form through :func:`boundary_distance`.
2-D canals become a flat strip at z = 0 between the lower and upper boundaries.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .cross_sections import CrossSections, boundary_distance
from .validation import FloatArray, IntArray

MAX_RADIUS_SLOPE = 0.999


@dataclass(frozen=True, eq=False)
class Mesh:
    """A triangle mesh.

    Attributes
    ----------
    vertices : array, shape (V, 3)
        Ring-major: in 3-D, vertex ``i * K + k`` is section i at angle 2 pi k / K (K angles
        per ring), then the two cap centres when capped; in 2-D, vertices ``2 i`` and
        ``2 i + 1`` are the lower and upper ends of section i.
    faces : array of int, shape (F, 3)
        Counter-clockwise seen from outside.
    normals : array, shape (V, 3)
        Unit, area-weighted vertex normals.
    """

    vertices: FloatArray
    faces: IntArray
    normals: FloatArray


def ring_faces(n_rings: int, n_angles: int) -> IntArray:
    """Triangles joining consecutive closed rings of ``n_angles`` vertices, shape (2 (R-1) K, 3)."""
    i, k = np.meshgrid(np.arange(n_rings - 1), np.arange(n_angles), indexing="ij")
    a = i * n_angles + k
    b = i * n_angles + (k + 1) % n_angles
    c = b + n_angles
    d = a + n_angles
    tris = np.stack([np.stack([a, b, c], -1), np.stack([a, c, d], -1)], axis=2)
    return tris.reshape(-1, 3).astype(np.int64)


def cap_faces(ring_start: int, n_angles: int, centre: int, outward_forward: bool) -> IntArray:
    """Fan of triangles closing one ring with a centre vertex."""
    k = np.arange(n_angles)
    a = ring_start + k
    b = ring_start + (k + 1) % n_angles
    c = np.full(n_angles, centre)
    tris = np.stack([a, b, c], -1) if outward_forward else np.stack([b, a, c], -1)
    return tris.astype(np.int64)


def vertex_normals(vertices: FloatArray, faces: IntArray) -> FloatArray:
    """Area-weighted unit vertex normals, shape (V, 3); zero where no face has area."""
    tri = vertices[faces]
    face_normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals = np.zeros_like(vertices)
    for corner in range(3):
        np.add.at(normals, faces[:, corner], face_normals)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)


def ring_vertices(
    centres: FloatArray, basis: FloatArray, sections: CrossSections, n_angles: int
) -> FloatArray:
    """Boundary rings in the ring form (Alg. 2, line 8), for any section kind.

    Parameters
    ----------
    centres : array, shape (N, 3)
    basis : array, shape (N, 2, 3)
    sections : CrossSections
    n_angles : int

    Returns
    -------
    rings : array, shape (N, K, 3)
    """
    n = centres.shape[0]
    v = np.linspace(0.0, 2.0 * np.pi, n_angles, endpoint=False)
    dirs = np.stack([np.cos(v), np.sin(v)], axis=1)  # (K, 2)
    reach = boundary_distance(
        sections, np.repeat(np.arange(n), n_angles), np.tile(dirs, (n, 1))
    ).reshape(n, n_angles)
    offsets = np.einsum("kj,njd->nkd", dirs, basis)
    return np.asarray(centres[:, None, :] + reach[:, :, None] * offsets, dtype=np.float64)


def envelope_vertices(
    centres: FloatArray,
    tangents: FloatArray,
    basis: FloatArray,
    radius: FloatArray,
    arclength: FloatArray,
    n_angles: int,
) -> FloatArray:
    """Rings of the true envelope of spheres (Eq. 9), shape (N, K, 3).

    Parameters
    ----------
    centres, tangents : arrays, shape (N, 3)
    basis : array, shape (N, 2, 3)
        (n_i, b_i).
    radius : array, shape (N,)
    arclength : array, shape (N,)
    n_angles : int
    """
    slope = np.gradient(radius, arclength) if arclength[-1] > arclength[0] else np.zeros_like(radius)
    slope = np.clip(np.nan_to_num(slope), -MAX_RADIUS_SLOPE, MAX_RADIUS_SLOPE)
    v = np.linspace(0.0, 2.0 * np.pi, n_angles, endpoint=False)
    # Eq. 9 writes (b sin v - n cos v); v -> v + pi gives (n cos v + b sin v) with the same
    # ring, which keeps vertex k at the same angle as the ring form.
    around = np.einsum("k,nd->nkd", np.cos(v), basis[:, 0]) + np.einsum("k,nd->nkd", np.sin(v), basis[:, 1])
    shrink = np.sqrt(1.0 - slope**2)
    return np.asarray(
        centres[:, None, :]
        + radius[:, None, None]
        * (-(slope[:, None, None] * tangents[:, None, :]) + shrink[:, None, None] * around),
        dtype=np.float64,
    )


def tube_mesh(rings: FloatArray, centres: FloatArray, caps: bool) -> Mesh:
    """Mesh closed rings (N, K, 3) into a tube, optionally capped with fans to c_0 and c_{N-1}."""
    n, k, _ = rings.shape
    vertices = rings.reshape(-1, 3)
    faces = ring_faces(n, k)
    if caps:
        start_centre, end_centre = vertices.shape[0], vertices.shape[0] + 1
        vertices = np.vstack([vertices, centres[0], centres[-1]])
        faces = np.vstack(
            [
                faces,
                cap_faces(0, k, start_centre, outward_forward=False),
                cap_faces((n - 1) * k, k, end_centre, outward_forward=True),
            ]
        )
    return Mesh(vertices, faces, vertex_normals(vertices, faces))


def strip_mesh(centres: FloatArray, normals: FloatArray, sections: CrossSections) -> Mesh:
    """A 2-D canal as a flat strip at z = 0 between its lower and upper boundaries.

    Parameters
    ----------
    centres, normals : arrays, shape (N, 2)
    sections : CrossSections
        Of a kind with in-plane dimension 1 (``interval``).
    """
    n = centres.shape[0]
    index = np.arange(n)
    reach_up = sections.spec.boundary_distance(sections, index, np.ones((n, 1)))
    reach_down = sections.spec.boundary_distance(sections, index, -np.ones((n, 1)))
    lower = centres - reach_down[:, None] * normals
    upper = centres + reach_up[:, None] * normals
    flat = np.stack([lower, upper], axis=1).reshape(-1, 2)
    vertices = np.column_stack([flat, np.zeros(2 * n)])
    i = np.arange(n - 1)
    a, b, c, d = 2 * i, 2 * i + 2, 2 * i + 3, 2 * i + 1
    faces = np.concatenate([np.stack([a, b, c], -1), np.stack([a, c, d], -1)]).astype(np.int64)
    # Orient every triangle to face +z whatever the curve's turning direction.
    tri = vertices[faces]
    up = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])[:, 2] < 0
    faces[up] = faces[up][:, ::-1]
    normals = np.tile([0.0, 0.0, 1.0], (vertices.shape[0], 1))
    return Mesh(vertices, faces, normals)
