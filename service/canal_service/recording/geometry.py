"""What a fitted canal looks like in a review: mesh, colours, rings, frames, all as 3-D arrays.

Computed once per model version on the writer thread and shared by the Rerun and MCAP logs.
Only the canal attributes listed in docs/CONTRACTS.md are used (``directrix``, ``tangents``,
``normals``, ``binormals``, ``radii``, ``arclength``, ``dim``, ``n_sections``, ``mesh()``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from canal_core.routes import Routes, served_model

FloatArray = NDArray[np.float64]

#: Stops of the radius colour ramp (viridis-like: narrow = dark blue, wide = yellow), RGBA 0..1.
_RAMP = np.array([
    [0.267, 0.005, 0.329, 1.0],
    [0.229, 0.322, 0.546, 1.0],
    [0.128, 0.567, 0.551, 1.0],
    [0.369, 0.789, 0.383, 1.0],
    [0.993, 0.906, 0.144, 1.0],
])
#: How opaque the canal's surface is drawn in both logs: see-through, so what lies inside it
#: (demonstrations, directrix, reproductions, live poses) stays visible.
CANAL_ALPHA = 0.3
#: About this many rings and frames are drawn along the canal, whatever its sample count.
TARGET_MARKS = 20
MESH_ANGLES = 32


def points3d(points: Any) -> FloatArray:
    """Points as 3-D, 2-D input drawn in the z=0 plane.

    Parameters
    ----------
    points : array_like, shape (..., D), D in {1, 2, 3}

    Returns
    -------
    ndarray, shape (..., 3), float64
    """
    arr = np.asarray(points, dtype=np.float64)
    if arr.shape[-1] == 3:
        return arr
    pad = [(0, 0)] * (arr.ndim - 1) + [(0, 3 - arr.shape[-1])]
    return np.pad(arr, pad)


def ramp_colors(values: FloatArray, lo: float, hi: float) -> FloatArray:
    """Colours of ``values`` on the radius ramp between ``lo`` and ``hi``.

    Parameters
    ----------
    values : ndarray, shape (M,)

    Returns
    -------
    ndarray, shape (M, 4), RGBA in [0, 1]
    """
    span = hi - lo
    u = np.clip((values - lo) / span, 0.0, 1.0) if span > 0 else np.full(values.shape, 0.5)
    stops = np.linspace(0.0, 1.0, len(_RAMP))
    return np.stack([np.interp(u, stops, _RAMP[:, c]) for c in range(4)], axis=-1)


def mark_stride(n_sections: int) -> int:
    """Section stride that draws about :data:`TARGET_MARKS` rings and frames."""
    return max(1, n_sections // TARGET_MARKS)


@dataclass(frozen=True)
class ModelGeometry:
    """Review geometry of one fitted model version (all 3-D, float64 unless noted).

    Attributes
    ----------
    version : int
    dim : int
        Dimension of the canal (2-D canals are drawn at z=0).
    directrix : (N, 3)
    radii, arclength : (N,)
    vertices, vertex_normals : (V, 3)
        ``canal.mesh(n_angles=MESH_ANGLES)``.
    faces : (F, 3) uint32
    vertex_colors : (V, 4)
        Radius ramp, RGBA in [0, 1].
    rings : (R, K, 3)
        Cross-section rings at a stride, each closed (last point repeats the first).
    frame_origins : (S, 3)
    frame_vectors : (S, A, 3)
        Tangent, normal (and binormal in 3-D) per drawn frame, scaled for display.
    """

    version: int
    dim: int
    directrix: FloatArray
    radii: FloatArray
    arclength: FloatArray
    vertices: FloatArray
    vertex_normals: FloatArray
    faces: NDArray[np.uint32]
    vertex_colors: FloatArray
    rings: FloatArray
    frame_origins: FloatArray
    frame_vectors: FloatArray
    #: the correction that made this version (a refined model), else None
    correction: CorrectionGeometry | None = None
    #: a model of several routes: each route's geometry (this one is the canal of all)
    routes: tuple[ModelGeometry, ...] = ()

    @property
    def n_sections(self) -> int:
        """Number of sections N."""
        return int(self.directrix.shape[0])


def model_geometry(version: int, canal: Any) -> ModelGeometry:
    """The review geometry of ``canal`` (slow: builds the mesh; call it off the request path).
    ``canal`` may be :class:`canal_core.Routes`: with several routes, the geometry of the
    canal of all with each route's in ``routes``."""
    if isinstance(canal, Routes):
        model = served_model(canal)
        if not isinstance(model, Routes):
            return model_geometry(version, model)
        return _undrawn_geometry(version, model.pooled,
                                 tuple(model_geometry(version, c) for c in model.canals))
    dim = int(canal.dim)
    directrix = points3d(canal.directrix)
    radii = np.asarray(canal.radii, dtype=np.float64)
    mesh = canal.mesh(n_angles=MESH_ANGLES)
    vertices = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
    # Colour each vertex by its distance to the directrix: the local radius of the surface,
    # exact for any section kind and independent of how canal_core orders mesh vertices.
    distance, _ = cKDTree(directrix).query(vertices)
    colors = ramp_colors(distance, float(radii.min()), float(radii.max()))

    stride = mark_stride(directrix.shape[0])
    idx = np.arange(0, directrix.shape[0], stride)
    if idx[-1] != directrix.shape[0] - 1:
        idx = np.append(idx, directrix.shape[0] - 1)
    centres = directrix[idx]
    normals = points3d(canal.normals)[idx]
    tangents = points3d(canal.tangents)[idx]
    n = directrix.shape[0]
    if dim == 3 and canal.binormals is not None:
        binormals = points3d(canal.binormals)[idx]
        # The mesh is ring-major (canal_core.surface.Mesh): its rings are the true section
        # boundaries for every kind (circle, mec, ellipse, spline); close each loop.
        ring = vertices[: n * MESH_ANGLES].reshape(n, MESH_ANGLES, 3)[idx]
        rings = np.concatenate([ring, ring[:, :1]], axis=1)
        axes = np.stack([tangents, normals, binormals], axis=1)
    else:
        # A 2-D section is the interval [lower, upper] across the strip (vertices 2i, 2i+1).
        rings = vertices.reshape(n, 2, 3)[idx]
        axes = np.stack([tangents, normals], axis=1)
    scale = float(np.median(radii)) if np.median(radii) > 0 else 0.05 * float(
        np.asarray(canal.arclength)[-1] or 1.0)
    return ModelGeometry(
        version=int(version), dim=dim, directrix=directrix, radii=radii,
        arclength=np.asarray(canal.arclength, dtype=np.float64),
        vertices=vertices,
        vertex_normals=np.ascontiguousarray(mesh.normals, dtype=np.float64),
        faces=np.ascontiguousarray(mesh.faces, dtype=np.uint32),
        vertex_colors=colors, rings=rings, frame_origins=centres, frame_vectors=axes * scale,
        correction=correction_geometry(canal),
    )


def _undrawn_geometry(version: int, canal: Any, routes: tuple[ModelGeometry, ...]
                      ) -> ModelGeometry:
    """The canal of all of a model of several routes: only what the logs say of the model
    (its sections, radii, arclength and correction). The logs draw the routes, never this
    canal, so it gets no mesh, rings or frames (the mesh is the slow part)."""
    dim = int(canal.dim)
    none = np.empty((0, 3), dtype=np.float64)
    ring_points = MESH_ANGLES + 1 if dim == 3 else 2
    return ModelGeometry(
        version=int(version), dim=dim, directrix=points3d(canal.directrix),
        radii=np.asarray(canal.radii, dtype=np.float64),
        arclength=np.asarray(canal.arclength, dtype=np.float64),
        vertices=none, vertex_normals=none, faces=np.empty((0, 3), dtype=np.uint32),
        vertex_colors=np.empty((0, 4), dtype=np.float64),
        rings=np.empty((0, ring_points, 3), dtype=np.float64), frame_origins=none,
        frame_vectors=np.empty((0, dim, 3), dtype=np.float64),
        correction=correction_geometry(canal), routes=routes)


#: Most section rings drawn before and after a correction.
CORRECTION_RINGS = 24


@dataclass(frozen=True)
class CorrectionGeometry:
    """The correction that made a refined model version, as both logs draw it (3-D arrays).

    ``samples`` (M, 3) the path the person showed; ``before`` and ``after`` (K, A + 1, 3) closed
    section rings of the changed range, in the parent canal and in this one (2-D canals: the
    two ends of each section's interval, (K, 2, 3)); ``first``/``last`` the corrected span.
    """

    number: int
    kind: str
    label: str
    weight: float
    first: int
    last: int
    samples: FloatArray
    before: FloatArray
    after: FloatArray


def _section_rings(centres: FloatArray, basis: FloatArray, sections: Any, dim: int) -> FloatArray:
    """Closed rings (3-D) or interval ends (2-D) of sections, as 3-D points (K, A, 3)."""
    from canal_core.surface import ring_vertices

    if dim == 3:
        ring = ring_vertices(centres, basis, sections, MESH_ANGLES)
        return np.concatenate([ring, ring[:, :1]], axis=1)
    lower, upper = sections.params["lower"], sections.params["upper"]
    normal = basis[:, 0, :]
    ends = np.stack([centres + lower[:, None] * normal, centres + upper[:, None] * normal], axis=1)
    return np.concatenate([ends, np.zeros((*ends.shape[:2], 1))], axis=2)


def correction_geometry(canal: Any) -> CorrectionGeometry | None:
    """The last correction of a refined canal with its changed range before and after."""
    from canal_core.cross_sections import CrossSections

    applied = canal.corrections[-1] if getattr(canal, "corrections", ()) else None
    if applied is None or applied.before is None:
        return None
    before = applied.before
    rows = before["directrix"].shape[0]
    first_row = max(applied.lo - 1, 0)
    pick = np.unique(np.linspace(0, rows - 1, min(rows, CORRECTION_RINGS)).astype(int))
    dim = int(canal.dim)
    old_sections = CrossSections(canal.sections.kind,
                                 {k: v[pick] for k, v in before["sections"].items()})
    old = _section_rings(before["directrix"][pick], before["basis"][pick], old_sections, dim)
    index = first_row + pick
    new_sections = CrossSections(canal.sections.kind,
                                 {k: v[index] for k, v in canal.sections.params.items()})
    new = _section_rings(canal.directrix[index], canal.basis[index], new_sections, dim)
    c = applied.correction
    return CorrectionGeometry(
        number=len(canal.corrections), kind=str(c.kind), label=str(c.label), weight=float(c.weight),
        first=int(applied.first), last=int(applied.last), samples=points3d(c.samples),
        before=np.asarray(old, dtype=np.float64), after=np.asarray(new, dtype=np.float64))


@dataclass(frozen=True)
class ObstacleShape:
    """One obstacle of a scene as both logs draw it, in 3-D (a 2-D scene in the z=0 plane).

    ``kind`` sphere (a disc too), box or capsule; ``center`` (3,); ``half_sizes`` (3,): a
    box's half extents along its axes, a sphere's radius thrice; ``quaternion`` (4,) [x, y, z,
    w]: a box's rotation, a capsule's rotation from +z to its axis; ``radius`` and ``length``
    a capsule's (``center`` its midpoint, ``a`` and ``b`` its ends).
    """

    kind: str
    name: str
    center: FloatArray
    half_sizes: FloatArray
    quaternion: FloatArray
    radius: float
    length: float
    a: FloatArray
    b: FloatArray


def _quaternion_between(u: FloatArray, v: FloatArray) -> FloatArray:
    """The shortest rotation [x, y, z, w] taking unit vector ``u`` to unit vector ``v``."""
    w = 1.0 + float(u @ v)
    if w < 1e-12:  # opposite: any perpendicular axis
        axis = np.cross(u, [1.0, 0.0, 0.0])
        if np.linalg.norm(axis) < 1e-9:
            axis = np.cross(u, [0.0, 1.0, 0.0])
        axis = axis / np.linalg.norm(axis)
        return np.array([*axis, 0.0])
    q = np.array([*np.cross(u, v), w])
    return np.asarray(q / np.linalg.norm(q))


def obstacle_shapes(obstacles: list[dict[str, Any]], dim: int) -> list[ObstacleShape]:
    """A scene's stored obstacles (canal_core's JSON form) as :class:`ObstacleShape` s."""
    from canal_core.obstacles import rotation_parameters, scene_from_list

    out = []
    for i, o in enumerate(scene_from_list(obstacles, dim).obstacles):
        center, a, b = points3d(o.center), points3d(o.a), points3d(o.b)
        if o.kind == "box":
            half = points3d(o.half_extents) if dim == 3 else np.array([*o.half_extents, 0.0])
            if dim == 2:
                half[2] = 0.5 * float(np.min(o.half_extents))  # a slab to see it by
                angle = float(rotation_parameters(o.rotation))  # type: ignore[arg-type]
                quat = np.array([0.0, 0.0, np.sin(angle / 2), np.cos(angle / 2)])
            else:
                quat = np.asarray(rotation_parameters(o.rotation), dtype=np.float64)
            shape = ObstacleShape("box", o.name or f"obstacle {i}", center, half, quat, 0.0, 0.0, a, b)
        elif o.kind == "capsule":
            axis = b - a
            length = float(np.linalg.norm(axis))
            quat = (np.array([0.0, 0.0, 0.0, 1.0]) if length == 0.0
                    else _quaternion_between(np.array([0.0, 0.0, 1.0]), axis / length))
            shape = ObstacleShape("capsule", o.name or f"obstacle {i}", center,
                                  np.full(3, o.radius), quat, o.radius, length, a, b)
        else:
            shape = ObstacleShape("sphere", o.name or f"obstacle {i}", center, np.full(3, o.radius),
                                  np.array([0.0, 0.0, 0.0, 1.0]), o.radius, 0.0, a, b)
        out.append(shape)
    return out
