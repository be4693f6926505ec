"""Obstacles: what stands in the canal, and a reproduction that goes around it inside the canal.

The canal says where a skill may go; a *scene* says where it may not. An obstacle is a sphere
(a disc in 2-D), a box (axis-aligned, or oriented by a rotation) or a capsule, each with a
*clearance*: the distance the path keeps from its surface. Every obstacle is measured by its
exact signed distance d(x) (negative inside), and ``free = d - clearance`` (what is left of
the clearance, negative inside the inflated obstacle). Signed distances are 1-Lipschitz, so a
straight segment [p, q] keeps the clearance whenever ``free(p) + free(q) >= |p - q|``: a
check of the whole segment, not only of its ends (:func:`segments_keep_clearance`, sufficient;
:func:`segment_free_distances` measures the exact segment distance for spheres and capsules,
and finds it for boxes, whose signed distance is convex along a line).

Reproduction around obstacles (the generalized cylinders' follow-up: use the *free part* of
each cross-section). The ratio rule's path p_k is kept wherever it is clear. Where it is not,
each cross-section in a window around the obstruction offers candidates on a polar grid of
its own in-plane coordinates (ratios up to :data:`INSIDE_RATIO` of the boundary distance, so
every candidate is inside the canal) plus the ratio rule's point. A dynamic programme along
the window picks one clear candidate per section minimising the deviation from the ratio
rule's path and its change from section to section (a smooth entry and exit), under two hard
constraints per step: the segment keeps the clearance (the Lipschitz test above) and is no
longer than the demonstrations' own largest step (:func:`demonstrated_largest_step`). A
section where no candidate is clear, or none can be reached within a step, *blocks* the
reproduction there: it ends at the last section it reaches and says which section blocked it
and why (:class:`Blocked`); it never returns a path through an obstacle.
"""

from __future__ import annotations

import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any, Literal, get_args

import numpy as np

from .cross_sections import CrossSections, boundary_distance
from .errors import InvalidInputError, TooSlowError
from .validation import BoolArray, FloatArray, IntArray

ObstacleKind = Literal["sphere", "disc", "box", "capsule"]
OBSTACLE_KINDS: tuple[ObstacleKind, ...] = get_args(ObstacleKind)
#: Kinds per dimension: a sphere is 3-D, a disc its 2-D form; boxes and capsules are both.
KINDS_BY_DIM: dict[int, tuple[ObstacleKind, ...]] = {2: ("disc", "box", "capsule"), 3: ("sphere", "box", "capsule")}
#: Most obstacles in one scene (the live kernel measures every pose against each).
MAX_OBSTACLES = 64
#: Largest ratio of a candidate point to its section's boundary distance: the path stays
#: strictly inside the canal, with 5 % of the local width to spare.
INSIDE_RATIO = 0.95
#: Candidate grid of a 3-D section: directions around the directrix x ratios out to
#: INSIDE_RATIO (plus the centre). 2-D: ratios on each side of the directrix.
GRID_ANGLES = 24
GRID_RATIOS_3D = 8
GRID_RATIOS_2D = 16
#: Weights of the path's cost, in units of the local section radius squared: deviation from
#: the ratio rule's point and change of that deviation from one section to the next. The
#: change weighs more, so a detour fades in and out over several sections.
DEVIATION_WEIGHT = 1.0
SMOOTHNESS_WEIGHT = 25.0
#: A detour to one side shifts the ratio rule's points along one of this many in-plane
#: directions, by at most this many levels (as fine as a step's sideways room allows).
SHIFT_DIRECTIONS = 32
SHIFT_LEVELS = 128
#: Points per block in :func:`free_distances` (keeps its temporaries within a few MB).
FREE_BLOCK = 4096
#: Golden-section steps of the segment search against boxes (:func:`segment_free_distances`):
#: each keeps 0.618 of the interval, so 60 leave 3e-13 of the segment's length.
GOLDEN_ITERATIONS = 60
#: Why a reproduction stops short.
BlockedReason = Literal["closed", "unreachable", "start"]


@dataclass(frozen=True, eq=False)
class Obstacle:
    """One obstacle, validated (see :func:`obstacle_from_dict`).

    Attributes
    ----------
    kind : {"sphere", "disc", "box", "capsule"}
    center : array, shape (D,)
        Centre (sphere, disc, box); a capsule's midpoint.
    radius : float
        Sphere, disc or capsule radius; 0 for a box.
    half_extents : array, shape (D,)
        A box's half sizes along its own axes; zeros otherwise.
    rotation : array, shape (D, D)
        Columns: the box's axes in world coordinates (identity for an axis-aligned box).
    a, b : arrays, shape (D,)
        A capsule's segment ends (both the centre for a sphere or disc).
    clearance : float
        Distance the path keeps from the surface, >= 0.
    name : str or None
    """

    kind: ObstacleKind
    center: FloatArray
    radius: float
    half_extents: FloatArray
    rotation: FloatArray
    a: FloatArray
    b: FloatArray
    clearance: float = 0.0
    name: str | None = None

    @property
    def dim(self) -> int:
        return int(self.center.shape[0])

    def to_dict(self) -> dict[str, Any]:
        """The JSON form :func:`obstacle_from_dict` reads back."""
        out: dict[str, Any] = {"kind": self.kind}
        if self.kind == "capsule":
            out.update(a=self.a.tolist(), b=self.b.tolist(), radius=self.radius)
        elif self.kind == "box":
            out.update(center=self.center.tolist(), half_extents=self.half_extents.tolist())
            if not np.allclose(self.rotation, np.eye(self.dim)):
                out["rotation"] = rotation_parameters(self.rotation)
        else:
            out.update(center=self.center.tolist(), radius=self.radius)
        out["clearance"] = self.clearance
        if self.name is not None:
            out["name"] = self.name
        return out


@dataclass(frozen=True, eq=False)
class Scene:
    """Obstacles of one dimension, packed for vectorised distances.

    Spheres, discs and capsules are all "a segment with a radius" (a sphere's segment is a
    point); boxes are kept apart.
    """

    dim: int
    obstacles: tuple[Obstacle, ...] = ()

    def __len__(self) -> int:
        return len(self.obstacles)

    @cached_property
    def round_index(self) -> Any:
        return np.array([i for i, o in enumerate(self.obstacles) if o.kind != "box"], dtype=np.int64)

    @cached_property
    def box_index(self) -> Any:
        return np.array([i for i, o in enumerate(self.obstacles) if o.kind == "box"], dtype=np.int64)

    @cached_property
    def round_arrays(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Segment starts (S, D), ends (S, D) and reach = radius + clearance (S,)."""
        obs = [self.obstacles[i] for i in self.round_index]
        if not obs:
            return np.zeros((0, self.dim)), np.zeros((0, self.dim)), np.zeros(0)
        return (
            np.array([o.a for o in obs]),
            np.array([o.b for o in obs]),
            np.array([o.radius + o.clearance for o in obs]),
        )

    @cached_property
    def round_groups(self) -> list[tuple[IntArray, FloatArray, FloatArray, FloatArray]]:
        """:attr:`round_arrays` split into the spheres and the capsules (each group that has
        any): their indices in the scene, segment starts, ends and reach."""
        a, b, reach = self.round_arrays
        point = ~(b != a).any(axis=1)
        return [(self.round_index[part], a[part], b[part], reach[part]) for part in (point, ~point) if part.any()]

    @cached_property
    def box_arrays(self) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """Centres (B, D), rotations (B, D, D), half extents (B, D), clearances (B,)."""
        obs = [self.obstacles[i] for i in self.box_index]
        if not obs:
            d = self.dim
            return np.zeros((0, d)), np.zeros((0, d, d)), np.zeros((0, d)), np.zeros(0)
        return (
            np.array([o.center for o in obs]),
            np.array([o.rotation for o in obs]),
            np.array([o.half_extents for o in obs]),
            np.array([o.clearance for o in obs]),
        )

    def to_list(self) -> list[dict[str, Any]]:
        return [o.to_dict() for o in self.obstacles]


# -- validation ------------------------------------------------------------------------


def _number(value: Any, field: str, minimum: float | None = 0.0, strict: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise InvalidInputError(f"expected {field} as a number, got {type(value).__name__}", field=field)
    x = float(value)
    if not np.isfinite(x):
        raise InvalidInputError(f"expected {field} as a finite number, got {x}", field=field)
    if minimum is not None and (x < minimum or (strict and x <= minimum)):
        bound = ">" if strict else ">="
        raise InvalidInputError(f"expected {field} {bound} {minimum}, got {x}", field=field)
    return x


def _vector(value: Any, dim: int, field: str) -> FloatArray:
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"expected {field} as {dim} numbers, got {value!r}", field=field) from exc
    if array.shape != (dim,):
        raise InvalidInputError(f"expected {field} of shape ({dim},), got {array.shape}", field=field)
    if not np.all(np.isfinite(array)):
        raise InvalidInputError(f"expected finite {field}, got {array.tolist()}", field=field)
    return array


def rotation_matrix(value: Any, dim: int, field: str = "rotation") -> FloatArray:
    """A box's rotation: 2-D an angle in radians, 3-D a unit quaternion [qx, qy, qz, qw].

    Returns
    -------
    R : array, shape (D, D)
        Columns are the box's axes in world coordinates.
    """
    if dim == 2:
        angle = _number(value, field, minimum=None)
        c, s = np.cos(angle), np.sin(angle)
        return np.array([[c, -s], [s, c]])
    q = _vector(value, 4, field)
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > 1e-3:
        raise InvalidInputError(
            f"expected {field} as a unit quaternion [qx, qy, qz, qw], got norm {norm:.6g}", field=field
        )
    x, y, z, w = q / norm
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def rotation_parameters(matrix: FloatArray) -> float | list[float]:
    """The inverse of :func:`rotation_matrix`: an angle (2-D) or a quaternion [qx, qy, qz, qw]."""
    if matrix.shape == (2, 2):
        return float(np.arctan2(matrix[1, 0], matrix[0, 0]))
    m = matrix
    w = 0.5 * np.sqrt(max(1.0 + m[0, 0] + m[1, 1] + m[2, 2], 0.0))
    if w > 1e-6:
        q = [(m[2, 1] - m[1, 2]) / (4 * w), (m[0, 2] - m[2, 0]) / (4 * w), (m[1, 0] - m[0, 1]) / (4 * w), w]
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(max(1.0 + m[i, i] - m[j, j] - m[k, k], 1e-300))
        q = [0.0, 0.0, 0.0, (m[k, j] - m[j, k]) / s]
        q[i], q[j], q[k] = 0.25 * s, (m[j, i] + m[i, j]) / s, (m[k, i] + m[i, k]) / s
    return [float(v) for v in q]


def obstacle_from_dict(data: Any, dim: int, field: str = "obstacles[0]") -> Obstacle:
    """Validate one obstacle's JSON form; errors name ``field.key``.

    Forms (D = ``dim``; ``clearance`` >= 0 defaults to 0, ``name`` is optional)::

        {"kind": "sphere", "center": [x, y, z], "radius": r}          (3-D)
        {"kind": "disc", "center": [x, y], "radius": r}               (2-D)
        {"kind": "box", "center": [...D], "half_extents": [...D],
         "rotation": [qx, qy, qz, qw] (3-D) or angle in radians (2-D), optional}
        {"kind": "capsule", "a": [...D], "b": [...D], "radius": r}
    """
    if not isinstance(data, Mapping):
        raise InvalidInputError(f"expected {field} as an object with a kind, got {type(data).__name__}", field=field)
    kind = data.get("kind")
    allowed = KINDS_BY_DIM[dim]
    if kind not in allowed:
        hint = ""
        if kind in OBSTACLE_KINDS:
            hint = f" ({kind!r} is not a {dim}-D obstacle)"
        raise InvalidInputError(
            f"expected {field}.kind among {', '.join(map(repr, allowed))} for a {dim}-D canal, got {kind!r}{hint}",
            field=f"{field}.kind",
        )
    known = {"kind", "clearance", "name"} | {
        "sphere": {"center", "radius"}, "disc": {"center", "radius"},
        "box": {"center", "half_extents", "rotation"}, "capsule": {"a", "b", "radius"},
    }[kind]
    extra = sorted(set(data) - known)
    if extra:
        raise InvalidInputError(
            f"expected {field} ({kind}) keys among {', '.join(sorted(known))}, got {', '.join(extra)}",
            field=f"{field}.{extra[0]}",
        )
    clearance = _number(data.get("clearance", 0.0), f"{field}.clearance")
    name = data.get("name")
    if name is not None and not isinstance(name, str):
        raise InvalidInputError(f"expected {field}.name as text, got {type(name).__name__}", field=f"{field}.name")
    for key in sorted(known - {"clearance", "name", "rotation", "kind"}):
        if key not in data:
            raise InvalidInputError(f"expected {field}.{key} for a {kind}, got nothing", field=f"{field}.{key}")
    eye = np.eye(dim)
    zero = np.zeros(dim)
    if kind == "box":
        center = _vector(data["center"], dim, f"{field}.center")
        half = _vector(data["half_extents"], dim, f"{field}.half_extents")
        if np.any(half <= 0.0):
            raise InvalidInputError(
                f"expected {field}.half_extents > 0, got {half.tolist()}", field=f"{field}.half_extents"
            )
        rot = eye if data.get("rotation") is None else rotation_matrix(data["rotation"], dim, f"{field}.rotation")
        return Obstacle("box", center, 0.0, half, rot, center, center, clearance, name)
    radius = _number(data["radius"], f"{field}.radius", strict=True)
    if kind == "capsule":
        a = _vector(data["a"], dim, f"{field}.a")
        b = _vector(data["b"], dim, f"{field}.b")
        return Obstacle("capsule", 0.5 * (a + b), radius, zero, eye, a, b, clearance, name)
    center = _vector(data["center"], dim, f"{field}.center")
    return Obstacle(kind, center, radius, zero, eye, center, center, clearance, name)


def scene_from_list(items: Any, dim: int, field: str = "obstacles") -> Scene:
    """Validate a list of obstacles' JSON forms (:func:`obstacle_from_dict`) into a :class:`Scene`."""
    if isinstance(items, Scene):
        if items.dim != dim:
            raise InvalidInputError(f"expected a {dim}-D scene in {field}, got {items.dim}-D", field=field)
        return items
    if not isinstance(items, Sequence) or isinstance(items, str | bytes):
        raise InvalidInputError(f"expected {field} as a list of obstacles, got {type(items).__name__}", field=field)
    if len(items) > MAX_OBSTACLES:
        raise InvalidInputError(f"expected at most {MAX_OBSTACLES} {field}, got {len(items)}", field=field)
    obstacles = tuple(
        o if isinstance(o, Obstacle) and o.dim == dim else obstacle_from_dict(o, dim, f"{field}[{i}]")
        for i, o in enumerate(items)
    )
    return Scene(dim, obstacles)


def merged_scene(first: Scene, second: Scene) -> Scene:
    """Both scenes' obstacles (``first``'s, then ``second``'s)."""
    if first.dim != second.dim:
        raise InvalidInputError(f"expected scenes of one dimension, got {first.dim}-D and {second.dim}-D", field="obstacles")
    return Scene(first.dim, first.obstacles + second.obstacles)


# -- distances -------------------------------------------------------------------------


def _point_segment_distances(points: FloatArray, a: FloatArray, b: FloatArray) -> FloatArray:
    """Distance from each point (M, D) to each segment [a_s, b_s] (S, D), shape (M, S)."""
    ab = b - a  # (S, D)
    length2 = np.einsum("sd,sd->s", ab, ab)
    if not length2.any():
        # Points only (spheres): the distance to each, without the projection's temporaries
        # (five times faster on a detour's thousands of candidates).
        rel = points[:, None, :] - a[None, :, :]
        return np.asarray(np.sqrt(np.einsum("msd,msd->ms", rel, rel)))
    rel = points[:, None, :] - a[None, :, :]  # (M, S, D)
    t = np.einsum("msd,sd->ms", rel, ab) / np.where(length2 > 0.0, length2, 1.0)
    t = np.clip(np.where(length2 > 0.0, t, 0.0), 0.0, 1.0)
    diff = rel - t[:, :, None] * ab[None, :, :]
    return np.asarray(np.sqrt(np.einsum("msd,msd->ms", diff, diff)))


def _box_distances(points: FloatArray, centres: FloatArray, rotations: FloatArray, half: FloatArray) -> FloatArray:
    """Signed distance from each point (M, D) to each box, shape (M, B) (negative inside)."""
    local = np.einsum("mbd,bde->mbe", points[:, None, :] - centres[None, :, :], rotations)
    q = np.abs(local) - half[None, :, :]
    outside = np.sqrt(np.einsum("mbd,mbd->mb", np.maximum(q, 0.0), np.maximum(q, 0.0)))
    return np.asarray(outside + np.minimum(q.max(axis=2), 0.0))


def _free_parts(points: FloatArray, scene: Scene) -> Iterator[tuple[IntArray, FloatArray]]:
    """Signed distance minus clearance from each point (M, D) to the spheres, the capsules and
    the boxes in turn: each group's columns in the scene and its (M, k) distances. Spheres
    apart from capsules: a sphere's distance needs no projection onto a segment."""
    for index, a, b, reach in scene.round_groups:
        yield index, _point_segment_distances(points, a, b) - reach[None, :]
    if scene.box_index.size:
        c, rot, half, clearance = scene.box_arrays
        yield scene.box_index, _box_distances(points, c, rot, half) - clearance[None, :]


def obstacle_free_distances(points: FloatArray, scene: Scene) -> FloatArray:
    """Signed distance minus clearance from each point to each obstacle, shape (M, O).

    Negative: the point is inside the obstacle grown by its clearance.

    Parameters
    ----------
    points : array, shape (M, D)
    scene : Scene
    """
    out = np.full((points.shape[0], len(scene)), np.inf)
    for index, distances in _free_parts(points, scene):
        out[:, index] = distances
    return out


def free_distances(points: FloatArray, scene: Scene) -> FloatArray:
    """Smallest :func:`obstacle_free_distances` per point, shape (M,) (inf with no obstacle)."""
    m = points.shape[0]
    out = np.full(m, np.inf)
    # A detour asks for tens of thousands of candidates at once: in blocks, each group's
    # smallest straight away, without the (M, O) table (a third of the time, and memory).
    for lo in range(0, m, FREE_BLOCK):
        block = out[lo : lo + FREE_BLOCK]
        for _, distances in _free_parts(points[lo : lo + FREE_BLOCK], scene):
            np.minimum(block, distances.min(axis=1), out=block)
    return out


def backed_away_points(scene: Scene, p: FloatArray, free_each: FloatArray, step: FloatArray) -> FloatArray:
    """Points one step (at most) out of the obstacles: along the deepest one's outward normal,
    or, where that leads into another (obstacles that overlap), the way out of all of them
    that leaves the most room. A live robot inside an obstacle or its clearance is sent there
    (:mod:`canal_core.tracker_obstacles`), and a reproduction's start backs out that way.

    Parameters
    ----------
    scene : Scene
    p : array, shape (R, D)
        Points inside an obstacle or its clearance.
    free_each : array, shape (R, O)
        :func:`obstacle_free_distances` of ``p``.
    step : array, shape (R,)
        The longest step each may take.

    Returns
    -------
    points : array, shape (R, D)
    """
    deepest = free_each.argmin(axis=1)
    depth = -free_each[np.arange(p.shape[0]), deepest]
    # The normal by central differences of that obstacle's distance (exact shapes, tiny h),
    # every row and axis in one evaluation.
    r, d = p.shape
    h = 1e-7 * (1.0 + np.abs(p).max(axis=1))
    steps = np.concatenate([np.eye(d), -np.eye(d)])  # (2D, D)
    probes = (p[:, None, :] + h[:, None, None] * steps[None, :, :]).reshape(-1, d)
    dist = obstacle_free_distances(probes, scene).reshape(r, 2 * d, -1)[np.arange(r), :, deepest]
    grad = (dist[:, :d] - dist[:, d:]) / (2.0 * h[:, None])
    norm = np.sqrt((grad**2).sum(axis=1))
    flat = norm <= 1e-12  # at a sphere's centre: any way out
    grad[flat] = 0.0
    grad[flat, 0] = 1.0
    norm[flat] = 1.0
    out = p + (np.minimum(depth, step) / norm)[:, None] * grad
    # The normal step when it gets out (or is as good as any); else one step along the one of
    # a fixed set of directions with the most room.
    ways = _escape_directions(d)  # (W, D)
    tries = np.concatenate([out[:, None, :], p[:, None, :] + step[:, None, None] * ways[None, :, :]], axis=1)
    room = obstacle_free_distances(tries.reshape(-1, d), scene).min(axis=1).reshape(r, -1)
    best = np.where((room[:, 0] >= 0.0) | (room[:, 0] >= room.max(axis=1)), 0, room.argmax(axis=1))
    return np.asarray(tries[np.arange(r), best])


def _escape_directions(d: int) -> FloatArray:
    """Unit directions a robot inside obstacles may try: 16 in the plane, 26 in space."""
    if d == 2:
        a = np.linspace(0.0, 2.0 * np.pi, 16, endpoint=False)
        return np.column_stack([np.cos(a), np.sin(a)])
    grid = np.array(np.meshgrid(*[[-1.0, 0.0, 1.0]] * d, indexing="ij")).reshape(d, -1).T
    grid = grid[(grid != 0.0).any(axis=1)]
    return np.asarray(grid / np.sqrt((grid**2).sum(axis=1))[:, None])


def backed_out_path(start: FloatArray, scene: Scene, step: float, most: int = 64) -> FloatArray | None:
    """A start inside an obstacle or its clearance, backed out in steps of at most ``step``
    (:func:`backed_away_points`) until it keeps every clearance, shape (k, D); the last point
    is clear. None when ``most`` steps do not get it out (or the start is clear already).

    Parameters
    ----------
    start : array, shape (D,)
    scene : Scene
    step : float
    most : int
    """
    p = np.asarray(start, dtype=np.float64)
    out: list[FloatArray] = []
    for _ in range(most):
        each = obstacle_free_distances(p[None, :], scene)
        if each.min() >= 0.0:
            break
        p = backed_away_points(scene, p[None, :], each, np.array([step]))[0]
        out.append(p)
    if not out or free_distances(p[None, :], scene)[0] < 0.0:
        return None
    return np.asarray(out, dtype=np.float64)


def segments_keep_clearance(free_p: FloatArray, free_q: FloatArray, length: FloatArray) -> BoolArray:
    """Whether segments keep every clearance, from their ends' free distances (sufficient test).

    Signed distances are 1-Lipschitz: a point at t along [p, q] is at least
    max(free_p - t, free_q - (L - t)) >= (free_p + free_q - L) / 2 from every grown obstacle.

    Parameters
    ----------
    free_p, free_q : arrays, shape (M,)
        :func:`free_distances` of the segments' ends.
    length : array, shape (M,)
    """
    return np.asarray((free_p >= 0.0) & (free_q >= 0.0) & (free_p + free_q >= length))


def segments_clear(p: FloatArray, q: FloatArray, free_p: FloatArray, free_q: FloatArray,
                   scene: Scene) -> BoolArray:
    """Whether segments [p_m, q_m] keep every clearance: the sufficient test of
    :func:`segments_keep_clearance` first, the segment itself measured
    (:func:`segment_free_distances`) where both ends are clear but too near an obstacle for it.

    Parameters
    ----------
    p, q : arrays, shape (M, D)
    free_p, free_q : arrays, shape (M,)
        :func:`free_distances` of the ends (NaN: not clear).
    scene : Scene
    """
    length = np.sqrt(((q - p) ** 2).sum(axis=1))
    with np.errstate(invalid="ignore"):
        clear = segments_keep_clearance(free_p, free_q, length)
        unsure = np.flatnonzero(~clear & (free_p >= 0.0) & (free_q >= 0.0))
    if unsure.size:
        clear[unsure] = segment_free_distances(p[unsure], q[unsure], scene) >= 0.0
    return clear


def _segment_segment_distances(p: FloatArray, q: FloatArray, a: FloatArray, b: FloatArray) -> FloatArray:
    """Distance between each segment [p_m, q_m] (M, D) and each [a_s, b_s] (S, D), shape (M, S).

    The closest points P(s) = p + s (q - p), Q(t) = a + t (b - a), s and t clamped to [0, 1]
    in turn (Ericson, Real-Time Collision Detection, 5.1.9), for all pairs at once.
    """
    eps = 1e-300
    d1 = (q - p)[:, None, :]
    d2 = (b - a)[None, :, :]
    r = p[:, None, :] - a[None, :, :]
    shape = r.shape[:2]
    aa = np.broadcast_to((d1**2).sum(axis=2), shape)
    ee = np.broadcast_to((d2**2).sum(axis=2), shape)
    f = (d2 * r).sum(axis=2)
    c = (d1 * r).sum(axis=2)
    bb = np.broadcast_to((d1 * d2).sum(axis=2), shape)
    safe_a = np.where(aa > eps, aa, 1.0)
    safe_e = np.where(ee > eps, ee, 1.0)
    denom = aa * ee - bb * bb
    s = np.where(denom > eps, np.clip((bb * f - c * ee) / np.where(denom > eps, denom, 1.0), 0.0, 1.0), 0.0)
    t = (bb * s + f) / safe_e
    s = np.where(t < 0.0, np.clip(-c / safe_a, 0.0, 1.0), np.where(t > 1.0, np.clip((bb - c) / safe_a, 0.0, 1.0), s))
    t = np.clip(t, 0.0, 1.0)
    # Degenerate segments (a sphere's is a point; so may a path's step be).
    point_p, point_q = aa <= eps, ee <= eps
    s = np.where(point_q, np.where(point_p, 0.0, np.clip(-c / safe_a, 0.0, 1.0)), s)
    t = np.where(point_q, 0.0, t)
    s = np.where(point_p, 0.0, s)
    t = np.where(point_p & ~point_q, np.clip(f / safe_e, 0.0, 1.0), t)
    diff = r + s[:, :, None] * d1 - t[:, :, None] * d2
    return np.asarray(np.sqrt((diff**2).sum(axis=2)))


def segment_free_distances(p: FloatArray, q: FloatArray, scene: Scene) -> FloatArray:
    """Smallest distance minus clearance between each segment [p_m, q_m] and the obstacles.

    Exact for spheres, discs and capsules (segment-to-segment distance). Boxes: the smallest
    signed distance along the segment, found by golden-section search (the signed distance of
    a convex set is convex along a line), within 3e-13 of the segment's length: a segment
    through a box is as negative as it goes deep, not "touching".

    Parameters
    ----------
    p, q : arrays, shape (M, D)
    scene : Scene

    Returns
    -------
    free : array, shape (M,)
        Negative: the segment enters an obstacle grown by its clearance.
    """
    out = np.full(p.shape[0], np.inf)
    if scene.round_index.size:
        a, b, reach = scene.round_arrays
        out = np.minimum(out, (_segment_segment_distances(p, q, a, b) - reach[None, :]).min(axis=1))
    if scene.box_index.size:
        c, rot, half, clearance = scene.box_arrays
        out = np.minimum(out, _box_segment_free_each(p, q, c, rot, half, clearance).min(axis=1))
    return out


def obstacle_segment_free_distances(p: FloatArray, q: FloatArray, scene: Scene) -> FloatArray:
    """:func:`segment_free_distances` to each obstacle apart, shape (M, O).

    Parameters
    ----------
    p, q : arrays, shape (M, D)
    scene : Scene
    """
    out = np.full((p.shape[0], len(scene)), np.inf)
    if scene.round_index.size:
        a, b, reach = scene.round_arrays
        out[:, scene.round_index] = _segment_segment_distances(p, q, a, b) - reach[None, :]
    if scene.box_index.size:
        c, rot, half, clearance = scene.box_arrays
        out[:, scene.box_index] = _box_segment_free_each(p, q, c, rot, half, clearance)
    return out


def _box_free(x: FloatArray, centres: FloatArray, rotations: FloatArray, half: FloatArray,
              clearance: FloatArray) -> FloatArray:
    """Signed distance minus clearance of points x (M, B, D) to boxes (B), shape (M, B)."""
    local = np.einsum("mbd,bde->mbe", x - centres[None, :, :], rotations)
    q = np.abs(local) - half[None, :, :]
    outside = np.maximum(q, 0.0)
    return np.asarray(np.sqrt(np.einsum("mbd,mbd->mb", outside, outside))
                      + np.minimum(q.max(axis=2), 0.0) - clearance[None, :])


def _box_segment_free_each(
    p: FloatArray, q: FloatArray, centres: FloatArray, rotations: FloatArray, half: FloatArray, clearance: FloatArray
) -> FloatArray:
    """Smallest free distance of segments (M) to each box (B), shape (M, B): golden-section
    search of the convex signed distance along each segment, both ends included."""
    seg = q - p
    m, nb = p.shape[0], centres.shape[0]

    def free_at(t: FloatArray) -> FloatArray:
        return _box_free(p[:, None, :] + t[:, :, None] * seg[:, None, :], centres, rotations, half, clearance)

    shrink = (np.sqrt(5.0) - 1.0) / 2.0
    a, b = np.zeros((m, nb)), np.ones((m, nb))
    c, d = b - shrink, a + shrink
    fc, fd = free_at(c), free_at(d)
    for _ in range(GOLDEN_ITERATIONS):
        left = fc < fd  # the smallest lies in [a, d]: d becomes the inner point on the right
        a, b = np.where(left, a, c), np.where(left, d, b)
        new = np.where(left, b - shrink * (b - a), a + shrink * (b - a))
        f_new = free_at(new)
        c, d, fc, fd = (np.where(left, new, d), np.where(left, c, new),
                        np.where(left, f_new, fd), np.where(left, fc, f_new))
    ends = np.minimum(free_at(np.zeros((m, nb))), free_at(np.ones((m, nb))))
    return np.asarray(np.minimum(np.minimum(fc, fd), ends))


# -- the demonstrations' own step ------------------------------------------------------


def demonstrated_steps(centres: FloatArray, basis: FloatArray, section_points: FloatArray) -> FloatArray:
    """The largest step any demonstration (or the directrix) takes into or out of each section.

    A demonstration that sets off from far aside, or crosses the last planes in a jump, steps
    far once; around every other section the steps are the demonstrations' own pace there.

    Parameters
    ----------
    centres : array, shape (N, D)
    basis : array, shape (N, D - 1, D)
    section_points : array, shape (N, n, D - 1)
        Where each demonstration crosses each section, in-plane.

    Returns
    -------
    steps : array, shape (N,)
    """
    n = centres.shape[0]
    if n < 2:
        return np.zeros(n)
    world = centres[:, None, :] + np.einsum("njk,nkd->njd", section_points, basis)  # (N, n, D)
    between = np.sqrt(((world[1:] - world[:-1]) ** 2).sum(axis=2)).max(axis=1, initial=0.0)
    between = np.maximum(between, np.sqrt(((centres[1:] - centres[:-1]) ** 2).sum(axis=1)))
    return np.maximum(np.concatenate([between[:1], between]), np.concatenate([between, between[-1:]]))


def demonstrated_largest_step(centres: FloatArray, basis: FloatArray, section_points: FloatArray) -> float:
    """The largest step any demonstration takes from one cross-section to the next.

    Parameters
    ----------
    centres : array, shape (N, D)
    basis : array, shape (N, D - 1, D)
    section_points : array, shape (N, n, D - 1)
        Where each demonstration crosses each section, in-plane.
    """
    return float(demonstrated_steps(centres, basis, section_points).max(initial=0.0))


# -- avoidance ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Blocked:
    """Why and where a reproduction stops short of the canal's end.

    Attributes
    ----------
    section : int
        The cross-section it cannot enter.
    reason : {"closed", "unreachable", "start"}
        ``closed``: no clear point is left in that section inside the canal;
        ``unreachable``: clear points are left but none within one step of the demonstrations'
        largest from the section before; ``start``: the start is inside an obstacle (or its
        clearance) deeper than 64 such steps back out of (move it out first).
    obstacles : tuple of int
        Indices (in the scene) of the obstacles in the way: for ``closed`` those that take part
        of that section, else those the steps into it run into (never empty).
    """

    section: int
    reason: BlockedReason
    obstacles: tuple[int, ...]

    def to_dict(self) -> dict[str, Any]:
        return {"section": self.section, "reason": self.reason, "obstacles": list(self.obstacles)}


@dataclass(frozen=True, eq=False)
class Avoidance:
    """A path around obstacles (:func:`avoided_path`).

    Attributes
    ----------
    positions : array, shape (1 + K', D)
        The start, then one point per reached section (K' = K unless blocked).
    blocked : Blocked or None
    detoured : array of bool, shape (K',)
        Sections whose point left the ratio rule's path.
    start_clearance : float
        The start's free distance (negative: the start is inside an obstacle's clearance).
    """

    positions: FloatArray
    blocked: Blocked | None
    detoured: BoolArray
    start_clearance: float


def _grid(in_plane: int) -> FloatArray:
    """Unit-free candidate offsets (ratio x unit direction), shape (G, D - 1), centre first."""
    if in_plane == 1:
        ratios = np.linspace(0.0, INSIDE_RATIO, GRID_RATIOS_2D + 1)[1:]
        return np.concatenate([[[0.0]], ratios[:, None], -ratios[:, None]])
    angles = np.linspace(0.0, 2.0 * np.pi, GRID_ANGLES, endpoint=False)
    ratios = np.linspace(0.0, INSIDE_RATIO, GRID_RATIOS_3D + 1)[1:]
    units = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    return np.concatenate([np.zeros((1, 2)), (ratios[:, None, None] * units[None, :, :]).reshape(-1, 2)])


def section_candidates(
    sections_index: Any, centres: FloatArray, basis: FloatArray, sections: CrossSections
) -> FloatArray:
    """Candidate points inside each listed section, shape (K, G, D) (:data:`INSIDE_RATIO` at most).

    Parameters
    ----------
    sections_index : array of int, shape (K,)
    centres : array, shape (N, D)
    basis : array, shape (N, D - 1, D)
    sections : CrossSections
    """
    idx = np.asarray(sections_index, dtype=np.int64)
    grid = _grid(basis.shape[1])  # (G, D - 1)
    norm = np.sqrt((grid**2).sum(axis=1))
    unit = grid / np.where(norm > 0.0, norm, 1.0)[:, None]
    unit[norm == 0.0, 0] = 1.0
    k, g = idx.size, grid.shape[0]
    reach = boundary_distance(
        sections, np.repeat(idx, g), np.ascontiguousarray(np.tile(unit, (k, 1)))
    ).reshape(k, g)
    offsets = (norm[None, :] * reach)[:, :, None] * unit[None, :, :]  # (K, G, D - 1)
    return np.asarray(centres[idx][:, None, :] + np.einsum("kgi,kid->kgd", offsets, basis[idx]))


def avoided_path(
    start: FloatArray,
    nominal: FloatArray,
    first: int,
    centres: FloatArray,
    basis: FloatArray,
    sections: CrossSections,
    scene: Scene,
    largest_step: float,
    deadline: float | None = None,
) -> Avoidance:
    """The ratio rule's path, detoured through the free part of the sections where obstacles are.

    Parameters
    ----------
    start : array, shape (D,)
    nominal : array, shape (K, D)
        The ratio rule's points on sections first .. first + K - 1.
    first : int
    centres : array, shape (N, D)
    basis : array, shape (N, D - 1, D)
    sections : CrossSections
    scene : Scene
    largest_step : float
        The longest step a detour may take (:func:`demonstrated_largest_step`); a step of
        the ratio rule's own path that is longer is allowed at its place.
    deadline : float, optional
        ``time.monotonic()`` by which the detour must be found: the search stops there with
        :class:`~canal_core.errors.TooSlowError` (among many obstacles it takes seconds).

    Returns
    -------
    Avoidance
    """
    k_total = nominal.shape[0]
    start_free = float(free_distances(start[None, :], scene)[0]) if len(scene) else float("inf")
    nothing = np.zeros(k_total, dtype=bool)
    if not len(scene) or k_total == 0:
        return Avoidance(np.vstack([start, nominal]), None, nothing, start_free)
    path = np.vstack([start, nominal])  # row 0 the start, row k + 1 section first + k
    free = free_distances(path, scene)
    if free[0] < 0.0:
        free[0] = np.inf  # a start inside an obstacle may leave it: only its next point counts
    steps = np.sqrt(((path[1:] - path[:-1]) ** 2).sum(axis=1))
    # The ratio rule's own segments by their exact distance (a long step far from every
    # obstacle fails the Lipschitz test without coming near one); segment k: row k -> k + 1.
    clear = segment_free_distances(path[:-1], path[1:], scene) >= 0.0
    if start_free < 0.0:
        clear[0] = free[1] >= 0.0
    if clear.all():
        return Avoidance(path, None, nothing, start_free)
    # Rows touched by an unclear segment (the start row is never moved).
    bad = np.zeros(k_total + 1, dtype=bool)
    bad[np.flatnonzero(~clear)] = True
    bad[np.flatnonzero(~clear) + 1] = True
    bad[0] = False
    rows = np.flatnonzero(bad)
    # A detour needs sections to swerve in: as many as a step's sideways room takes to cross
    # the widest section around the obstruction (and at least 3), on each side.
    sideways = np.sqrt(max(largest_step**2 - float(np.median(steps)) ** 2, 1e-300))
    widest = float(np.sqrt(((section_candidates(first + rows - 1, centres, basis, sections)
                              - centres[first + rows - 1][:, None, :]) ** 2).sum(axis=2)).max())
    margin = int(np.clip(np.ceil(widest / sideways) + 2, 3, max(3, k_total // 3)))
    windows = _windows(rows, margin, k_total)
    detoured = nothing.copy()
    for lo, hi in windows:  # rows lo..hi (inclusive) are free to move
        rows_path, blocked = _window_path(path, free, lo, hi, first, centres, basis, sections, scene, largest_step, steps,
                                          deadline)
        end = lo + rows_path.shape[0]
        path[lo:end] = rows_path
        detoured[lo - 1 : end - 1] = np.any(rows_path != nominal[lo - 1 : end - 1], axis=1)
        if blocked is not None:
            # Rows 0 .. blocked section - first are kept: the start and the sections before it.
            kept = blocked.section - first + 1
            if kept == 1 and start_free < 0.0 and blocked.reason == "unreachable":
                blocked = Blocked(blocked.section, "start", blocked.obstacles)
            return Avoidance(path[:kept], blocked, detoured[: kept - 1], start_free)
    return Avoidance(path, None, detoured, start_free)


def _check_deadline(deadline: float | None) -> None:
    if deadline is not None and time.monotonic() > deadline:
        raise TooSlowError("expected a detour around the obstacles within the time given, got a search "
                           "still running: give fewer obstacles near the path, or more time", field="obstacles")


def _windows(rows: Any, margin: int, k_total: int) -> list[tuple[int, int]]:
    """Runs of rows grown by ``margin`` on each side, merged, within 1..k_total."""
    out: list[tuple[int, int]] = []
    for r in rows:
        lo, hi = max(1, int(r) - margin), min(k_total, int(r) + margin)
        if out and lo <= out[-1][1] + 1:
            out[-1] = (out[-1][0], max(out[-1][1], hi))
        else:
            out.append((lo, hi))
    return out


@dataclass(frozen=True, eq=False)
class _Chain:
    """One dynamic programme's answer: the rows it chose (as far as it reached) and their cost."""

    rows: FloatArray  # (R, D), R <= W
    complete: bool
    cost: float


def _chain(
    cand: FloatArray,
    cfree: FloatArray,
    nominal: FloatArray,
    scale2: FloatArray,
    before: tuple[FloatArray, float],
    after: tuple[FloatArray, float] | None,
    limits: FloatArray,
    exact: Any = None,
) -> _Chain:
    """The cheapest chain of clear candidates, one per row, between two fixed points.

    Cost: deviation from ``nominal`` plus its change from row to row (both over the local
    radius squared); hard constraints per step: the segment keeps the clearance
    (:func:`segments_keep_clearance`) and is no longer than its limit.

    Parameters
    ----------
    cand : array, shape (W, G, D)
    cfree : array, shape (W, G)
        Free distance of each candidate (negative: not usable; inf-free and outside-canal
        candidates are marked by the caller with -inf).
    nominal : array, shape (W, D)
    scale2 : array, shape (W,)
    before : (point (D,), free distance)
    after : (point (D,), free distance) or None
    limits : array, shape (W + 1,)
        Longest step into each row, and into ``after``.
    exact : callable (p (M, D), q (M, D)) -> free (M,), optional
        The exact segment distance, for the steps from ``before`` and into ``after`` that the
        Lipschitz test refuses (a long first or last step need not pass near an obstacle).
    """
    w, g, d = cand.shape
    dev = cand - nominal[:, None, :]
    dev2 = (dev**2).sum(axis=2)  # (W, G)
    cost = DEVIATION_WEIGHT * dev2 / scale2[:, None]
    # Squared distances as |x|^2 + |y|^2 - 2 x.y (one matrix product per row, not (G, G, D)
    # arrays), about the row's ratio-rule point so that nothing large cancels.
    rel = cand - nominal[:, None, :]  # = dev
    prev_rel, prev_free, prev_dev = (before[0] - nominal[0])[None, :], np.array([before[1]]), np.zeros((1, d))
    acc = np.zeros(1)
    back: list[Any] = []
    for i in range(w):
        shift = nominal[i - 1] - nominal[i] if i else np.zeros(d)
        prev_pts = prev_rel + (shift if i else 0.0)
        length2 = (prev_pts**2).sum(axis=1)[:, None] + dev2[i][None, :] - 2.0 * (prev_pts @ rel[i].T)
        length = np.sqrt(np.maximum(length2, 0.0))
        ok = segments_keep_clearance(prev_free[:, None], cfree[i][None, :], length) & (length <= limits[i])
        if i == 0 and exact is not None:
            retry = np.flatnonzero(~ok[0] & (cfree[0] >= 0.0) & (length[0] <= limits[0]))
            if retry.size:
                ends = cand[0][retry]
                ok[0, retry] = exact(np.broadcast_to(before[0], ends.shape), ends) >= 0.0
        prev_d2 = (prev_dev**2).sum(axis=1)
        change = (prev_d2[:, None] + dev2[i][None, :] - 2.0 * (prev_dev @ dev[i].T)) * (SMOOTHNESS_WEIGHT / scale2[i])
        total = np.where(ok, acc[:, None] + change, np.inf)
        best = np.argmin(total, axis=0)
        reached = total[best, np.arange(g)] + cost[i]
        if not np.isfinite(reached).any():
            rows = _backtracked(cand[:i], back, int(np.argmin(acc)) if i else 0)
            return _Chain(rows, False, float(np.min(acc)) if i else np.inf)
        acc = reached
        back.append(best)
        prev_rel, prev_free, prev_dev = rel[i], cfree[i], dev[i]
    if after is not None:
        length = np.sqrt(((cand[-1] - after[0][None, :]) ** 2).sum(axis=1))
        ok = segments_keep_clearance(cfree[-1], np.full(g, after[1]), length) & (length <= limits[-1])
        if exact is not None:
            retry = np.flatnonzero(~ok & (cfree[-1] >= 0.0) & (length <= limits[-1]))
            if retry.size:
                ends = cand[-1][retry]
                ok[retry] = exact(ends, np.broadcast_to(after[0], ends.shape)) >= 0.0
        final = np.where(ok, acc + dev2[-1] * (SMOOTHNESS_WEIGHT / scale2[-1]), np.inf)
        if not np.isfinite(final).any():
            return _Chain(_backtracked(cand, back, int(np.argmin(acc))), False, float(np.min(acc)))
        return _Chain(_backtracked(cand, back, int(np.argmin(final))), True, float(np.min(final)))
    return _Chain(_backtracked(cand, back, int(np.argmin(acc))), True, float(np.min(acc)))


def _backtracked(cand: FloatArray, back: list[Any], state: int) -> FloatArray:
    """The candidates (W, G, D) chosen on the way to ``state`` on the last row."""
    w = cand.shape[0]
    chosen = np.empty(w, dtype=np.int64)
    for i in range(w - 1, -1, -1):
        chosen[i] = state
        state = int(back[i][state])
    return np.asarray(cand[np.arange(w), chosen]).reshape(w, cand.shape[2])


def _shift_candidates(
    nominal: FloatArray, sec: Any, centres: FloatArray, basis: FloatArray, sections: CrossSections,
    direction: FloatArray, step: float, levels: int,
) -> tuple[FloatArray, BoolArray]:
    """The ratio rule's points shifted along one in-plane direction by 0, h, 2h, ...: (W, L, D),
    and whether each stays within :data:`INSIDE_RATIO` of its section."""
    shift = np.arange(levels) * step  # (L,)
    inplane = np.einsum("wd,wkd->wk", nominal - centres[sec], basis[sec])  # (W, D - 1)
    moved = inplane[:, None, :] + shift[None, :, None] * direction[None, None, :]  # (W, L, D - 1)
    norm = np.sqrt((moved**2).sum(axis=2))
    unit = moved / np.where(norm > 0.0, norm, 1.0)[:, :, None]
    unit[norm == 0.0, 0] = 1.0
    w, n_lv = norm.shape
    reach = boundary_distance(
        sections, np.repeat(np.asarray(sec, dtype=np.int64), n_lv), np.ascontiguousarray(unit.reshape(w * n_lv, -1))
    ).reshape(w, n_lv)
    inside = norm <= INSIDE_RATIO * reach
    # The ratio rule's own point is kept even where it is outside (a start outside the canal).
    inside[:, 0] = True
    return np.asarray(centres[sec][:, None, :] + np.einsum("wlk,wkd->wld", moved, basis[sec])), inside


def _window_path(
    path: FloatArray,
    free: FloatArray,
    lo: int,
    hi: int,
    first: int,
    centres: FloatArray,
    basis: FloatArray,
    sections: CrossSections,
    scene: Scene,
    largest_step: float,
    steps: FloatArray,
    deadline: float | None = None,
) -> tuple[FloatArray, Blocked | None]:
    """Rows lo..hi of the path through the free part of their sections, and where it blocks.

    Row r is section first + r - 1; row lo - 1 (fixed) precedes the window, row hi + 1 (fixed,
    when it exists) follows it. Two families of candidates are tried: the ratio rule's points
    shifted along one in-plane direction (:data:`SHIFT_DIRECTIONS` of them, each a smooth
    detour to one side), then a polar grid of each whole section (detours that change side).
    When blocked, the rows returned end at the last section reached.
    """
    sec = first + np.arange(lo, hi + 1) - 1
    nominal = path[lo : hi + 1]
    w, d = nominal.shape
    grid = section_candidates(sec, centres, basis, sections)  # (W, G, D)
    each = obstacle_free_distances(grid.reshape(-1, d), scene).reshape(w, grid.shape[1], len(scene))
    gfree = each.min(axis=2)
    closed = np.flatnonzero(~(gfree >= 0.0).any(axis=1))
    end = int(closed[0]) if closed.size else w  # rows before a closed section
    radius = np.sqrt(((grid[:, 1:] - centres[sec][:, None, :]) ** 2).sum(axis=2)).max(axis=1)
    scale2 = np.maximum(radius, 1e-300) ** 2
    limits = np.maximum(largest_step, steps[lo - 1 : hi + 1])
    before = (path[lo - 1], float(free[lo - 1]))
    after = None if (end < w or hi + 1 >= path.shape[0]) else (path[hi + 1], float(free[hi + 1]))
    if end == 0:
        taking = np.flatnonzero((each[0] < 0.0).any(axis=0))
        return nominal[:0], Blocked(int(sec[0]), "closed", tuple(int(x) for x in taking))
    nom, sc, lim = nominal[:end], scale2[:end], np.concatenate([limits[:end], limits[end : end + 1]])

    def exact(a: FloatArray, b: FloatArray) -> FloatArray:
        return segment_free_distances(np.ascontiguousarray(a), np.ascontiguousarray(b), scene)

    chains: list[_Chain] = []
    # Shifts: as fine as a step's sideways room, out to the section's diameter.
    sideways = np.sqrt(max(largest_step**2 - float(np.median(steps[lo - 1 : hi + 1])) ** 2, 0.0))
    reach = 2.0 * float(radius[:end].max())
    h = max(min(0.5 * sideways, reach / 16.0), reach / SHIFT_LEVELS)
    levels = int(min(SHIFT_LEVELS, np.ceil(reach / h) + 1))
    inward = -np.einsum("wd,wkd->k", nom - centres[sec[:end]], basis[sec[:end]])
    for angle in _shift_angles(basis.shape[1], inward):
        _check_deadline(deadline)
        cand, inside = _shift_candidates(nom, sec[:end], centres, basis, sections, angle, h, levels)
        cfree = free_distances(cand.reshape(-1, d), scene).reshape(cand.shape[:2])
        cfree[~inside] = -1e300  # unusable (finite: inf + -inf would be NaN)
        chains.append(_chain(cand, cfree, nom, sc, before, after, lim, exact))
    done = [c for c in chains if c.complete]
    if not done:
        cand = np.concatenate([nom[:, None, :], grid[:end]], axis=1)
        cfree = np.concatenate([free[lo : lo + end, None], gfree[:end]], axis=1)
        chains.append(_chain(cand, cfree, nom, sc, before, after, lim, exact))
        done = [c for c in chains if c.complete]
    if done:
        best = min(done, key=lambda c: c.cost)
        if end < w:
            taking = np.flatnonzero((each[end] < 0.0).any(axis=0))
            return best.rows, Blocked(int(sec[end]), "closed", tuple(int(x) for x in taking))
        return best.rows, None
    furthest = max(chains, key=lambda c: (c.rows.shape[0], -c.cost))
    at = furthest.rows.shape[0]
    last = furthest.rows[-1] if at else before[0]
    if at < end:
        ahead = np.concatenate([nom[at : at + 1], grid[at]])
        return furthest.rows, Blocked(int(sec[at]), "unreachable", _in_the_way(last, ahead, float(lim[at]), scene))
    # Every row reached but not the fixed row after the window.
    return furthest.rows, Blocked(int(first + hi), "unreachable",
                                  _in_the_way(last, path[hi + 1][None, :], float(lim[end]), scene))


def _in_the_way(last: FloatArray, ahead: FloatArray, limit: float, scene: Scene) -> tuple[int, ...]:
    """The obstacles that stand between the last point reached and a section it cannot reach.

    The steps from ``last`` to the section's candidates ``ahead`` within one step
    (``limit``; all of them when none is): the obstacles one of those steps runs into (a
    candidate inside an obstacle counts: its step ends in it), else those within reach of
    one (the step's ends nearer an obstacle than its length: what the quick clearance test
    refuses), else the obstacle nearest the step to the first candidate (the ratio rule's
    point). Never empty for a scene with obstacles.

    Parameters
    ----------
    last : array, shape (D,)
    ahead : array, shape (G, D)
        The ratio rule's point of the section first.
    limit : float
    scene : Scene
    """
    length = np.sqrt(((ahead - last[None, :]) ** 2).sum(axis=1))
    near = length <= limit
    ends = ahead[near] if near.any() else ahead
    starts = np.broadcast_to(last, ends.shape)
    run_into = obstacle_segment_free_distances(np.ascontiguousarray(starts), np.ascontiguousarray(ends), scene)
    named = np.flatnonzero((run_into < 0.0).any(axis=0))
    if not named.size:
        at_last = obstacle_free_distances(last[None, :], scene)[0]
        at_ends = obstacle_free_distances(ends, scene)
        steps = np.sqrt(((ends - last[None, :]) ** 2).sum(axis=1))
        named = np.flatnonzero((at_last[None, :] + at_ends < steps[:, None]).any(axis=0))
    if not named.size and len(scene):
        nominal = obstacle_segment_free_distances(last[None, :], ahead[:1], scene)[0]
        named = np.array([int(np.argmin(nominal))])
    return tuple(int(x) for x in named)


def _shift_angles(in_plane: int, inward: FloatArray) -> list[FloatArray]:
    """Unit in-plane directions a detour may shift along: :data:`SHIFT_DIRECTIONS` of them,
    evenly spread from ``inward`` (the way back toward the directrix from the ratio rule's
    points, which ride the boundary after a start outside the canal; any when zero)."""
    if in_plane == 1:
        return [np.array([1.0]), np.array([-1.0])]
    base = float(np.arctan2(inward[1], inward[0])) if np.any(inward != 0.0) else 0.0
    angles = base + np.linspace(0.0, 2.0 * np.pi, SHIFT_DIRECTIONS, endpoint=False)
    return [np.array([np.cos(a), np.sin(a)]) for a in angles]


__all__ = [
    "INSIDE_RATIO",
    "KINDS_BY_DIM",
    "MAX_OBSTACLES",
    "OBSTACLE_KINDS",
    "Avoidance",
    "Blocked",
    "Obstacle",
    "Scene",
    "avoided_path",
    "backed_away_points",
    "backed_out_path",
    "demonstrated_largest_step",
    "demonstrated_steps",
    "free_distances",
    "merged_scene",
    "obstacle_free_distances",
    "obstacle_from_dict",
    "obstacle_segment_free_distances",
    "rotation_matrix",
    "scene_from_list",
    "section_candidates",
    "segment_free_distances",
    "segments_clear",
    "segments_keep_clearance",
]
