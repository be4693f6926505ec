"""Foxglove well-known schemas (JSON encoding) and the messages the recorder writes with them.

Encoding: ``json`` messages with ``jsonschema`` schemas (see docs/recording.md for why). Foxglove
picks its 3-D renderer by schema *name* (``foxglove.SceneUpdate``, ``foxglove.PoseInFrame``,
``foxglove.FrameTransform``); the schema bodies below describe the fields we write, following
the published Foxglove definitions, so Foxglove's message-path tools can autocomplete them.
``canal.*`` schemas are ours: plain numbers for Foxglove's Plot panel.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import orjson

from .geometry import FloatArray

WORLD_FRAME = "world"
CANAL_FRAME = "canal"
LINE_STRIP, LINE_LOOP, LINE_LIST = 0, 1, 2
DELETE_MATCHING_ID = 0
DELETE_ALL = 1


# ---- schemas --------------------------------------------------------------------------------

def _obj(title: str, **props: Any) -> dict[str, Any]:
    return {"title": title, "type": "object", "properties": props}


def _numbers(*names: str) -> dict[str, Any]:
    return {n: {"type": "number"} for n in names}


def _array(items: dict[str, Any]) -> dict[str, Any]:
    return {"type": "array", "items": items}


_TIME = {"type": "object", "title": "time", "properties": {
    "sec": {"type": "integer", "minimum": 0},
    "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999}}}
_DURATION = {"type": "object", "title": "duration", "properties": {
    "sec": {"type": "integer"}, "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999}}}
_VECTOR3 = _obj("foxglove.Vector3", **_numbers("x", "y", "z"))
_POINT3 = _obj("foxglove.Point3", **_numbers("x", "y", "z"))
_QUATERNION = _obj("foxglove.Quaternion", **_numbers("x", "y", "z", "w"))
_POSE = _obj("foxglove.Pose", position=_VECTOR3, orientation=_QUATERNION)
_COLOR = _obj("foxglove.Color", **_numbers("r", "g", "b", "a"))
_KEY_VALUE = _obj("foxglove.KeyValuePair", key={"type": "string"}, value={"type": "string"})
_INDICES = _array({"type": "integer", "minimum": 0})
_LINE = _obj(
    "foxglove.LinePrimitive",
    type={"title": "foxglove.LineType", "oneOf": [
        {"title": "LINE_STRIP", "const": LINE_STRIP},
        {"title": "LINE_LOOP", "const": LINE_LOOP},
        {"title": "LINE_LIST", "const": LINE_LIST}]},
    pose=_POSE, thickness={"type": "number"}, scale_invariant={"type": "boolean"},
    points=_array(_POINT3), color=_COLOR, colors=_array(_COLOR), indices=_INDICES,
)
_TRIANGLES = _obj("foxglove.TriangleListPrimitive", pose=_POSE, points=_array(_POINT3),
                  color=_COLOR, colors=_array(_COLOR), indices=_INDICES)
#: Primitive lists a SceneEntity carries; we fill lines and triangles and send the rest empty.
_PRIMITIVES = ("arrows", "cubes", "spheres", "cylinders", "lines", "triangles", "texts", "models")
_OTHER_PRIMITIVE = {"arrows": "ArrowPrimitive", "cubes": "CubePrimitive",
                    "spheres": "SpherePrimitive", "cylinders": "CylinderPrimitive",
                    "texts": "TextPrimitive", "models": "ModelPrimitive"}
_ENTITY = _obj(
    "foxglove.SceneEntity",
    timestamp=_TIME, frame_id={"type": "string"}, id={"type": "string"}, lifetime=_DURATION,
    frame_locked={"type": "boolean"}, metadata=_array(_KEY_VALUE),
    lines=_array(_LINE), triangles=_array(_TRIANGLES),
    **{k: _array({"title": f"foxglove.{v}", "type": "object"}) for k, v in _OTHER_PRIMITIVE.items()},
)
_DELETION = _obj(
    "foxglove.SceneEntityDeletion", timestamp=_TIME, id={"type": "string"},
    type={"title": "foxglove.SceneEntityDeletionType", "oneOf": [
        {"title": "MATCHING_ID", "const": 0}, {"title": "ALL", "const": 1}]},
)

SCHEMAS: dict[str, dict[str, Any]] = {
    "foxglove.SceneUpdate": _obj("foxglove.SceneUpdate", deletions=_array(_DELETION),
                                 entities=_array(_ENTITY)),
    "foxglove.PoseInFrame": _obj("foxglove.PoseInFrame", timestamp=_TIME,
                                 frame_id={"type": "string"}, pose=_POSE),
    "foxglove.PosesInFrame": _obj("foxglove.PosesInFrame", timestamp=_TIME,
                                  frame_id={"type": "string"}, poses=_array(_POSE)),
    "foxglove.FrameTransform": _obj("foxglove.FrameTransform", timestamp=_TIME,
                                    parent_frame_id={"type": "string"},
                                    child_frame_id={"type": "string"},
                                    translation=_VECTOR3, rotation=_QUATERNION),
    "canal.ModelInfo": _obj("canal.ModelInfo", timestamp=_TIME, version={"type": "integer"},
                            n_sections={"type": "integer"}, radii=_array({"type": "number"}),
                            arclength=_array({"type": "number"}),
                            routes={"type": "integer"}),
    "canal.CorrectionInfo": _obj(
        "canal.CorrectionInfo", timestamp=_TIME, model_version={"type": "integer"},
        kind={"type": "string"}, label={"type": "string"}, weight={"type": "number"},
        first_section={"type": "integer"}, last_section={"type": "integer"},
        corrections={"type": "integer"}, n_samples={"type": "integer"}),
    "canal.ReproductionResult": _obj(
        "canal.ReproductionResult", timestamp=_TIME, model_version={"type": "integer"},
        eta={"type": "number"}, inside={"type": "boolean"}, projected={"type": "boolean"},
        section_index={"type": "integer"}, start=_VECTOR3, n_points={"type": "integer"},
        number={"type": "integer"}, times={"type": ["array", "null"], "items": {"type": "number"}},
        ratios={"type": ["array", "null"], "items": {"type": "number"}}),
    "canal.TrackerState": _obj(
        "canal.TrackerState", timestamp=_TIME, robot={"type": "string"},
        progress={"type": "number"}, eta={"type": ["number", "null"]}, section_index={"type": "integer"},
        inside={"type": "boolean"}, done={"type": "boolean"}, route={"type": "integer"}),
}


def schema_bytes(name: str) -> bytes:
    """The jsonschema of ``name`` as stored in the MCAP Schema record."""
    return orjson.dumps(SCHEMAS[name])


# ---- message pieces -------------------------------------------------------------------------

def stamp(t_ns: int) -> dict[str, int]:
    """Foxglove ``time`` of a nanosecond timestamp."""
    return {"sec": t_ns // 1_000_000_000, "nsec": t_ns % 1_000_000_000}


def json_objects(values: FloatArray, keys: str) -> orjson.Fragment:
    """Rows of ``values`` as a JSON list of objects keyed by the letters of ``keys``.

    Parameters
    ----------
    values : ndarray, shape (M, len(keys))
    keys : str
        e.g. ``"xyz"`` for Point3, ``"rgba"`` for Color.

    Returns
    -------
    orjson.Fragment
        ``[{"x": .., "y": .., "z": ..}, ...]``, embeddable in an ``orjson.dumps`` call.
    """
    flat = np.nan_to_num(np.ascontiguousarray(values, dtype=np.float64).ravel())
    if flat.size == 0:
        return orjson.Fragment(b"[]")
    # orjson formats the floats in C; %-formatting interleaves the keys, so meshes of 10^4
    # vertices encode in about a millisecond without a Python-level loop per point.
    numbers = orjson.dumps(flat, option=orjson.OPT_SERIALIZE_NUMPY)[1:-1].split(b",")
    item = b"{" + b",".join(b'"%s":%%b' % k.encode() for k in keys) + b"}"
    return orjson.Fragment(b"[" + b",".join([item] * (flat.size // len(keys))) % tuple(numbers)
                           + b"]")


def color(rgba: tuple[float, float, float, float]) -> dict[str, float]:
    """Foxglove ``Color`` of an RGBA tuple in [0, 1]."""
    r, g, b, a = rgba
    return {"r": r, "g": g, "b": b, "a": a}


_IDENTITY_POSE = {"position": {"x": 0.0, "y": 0.0, "z": 0.0},
                  "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}


def line(points: FloatArray, rgba: tuple[float, float, float, float], *, thickness: float = 2.0,
         kind: int = LINE_STRIP, colors: FloatArray | None = None) -> dict[str, Any]:
    """A ``foxglove.LinePrimitive`` through ``points`` (M, 3); thickness in screen pixels."""
    return {"type": kind, "pose": _IDENTITY_POSE, "thickness": thickness,
            "scale_invariant": True, "points": json_objects(points, "xyz"),
            "color": color(rgba),
            "colors": json_objects(colors, "rgba") if colors is not None else [],
            "indices": []}


def triangles(vertices: FloatArray, faces: np.ndarray, colors: FloatArray) -> dict[str, Any]:
    """A ``foxglove.TriangleListPrimitive``: vertices (V, 3), faces (F, 3), colours (V, 4)."""
    return {"pose": _IDENTITY_POSE, "points": json_objects(vertices, "xyz"),
            "color": {"r": 1.0, "g": 1.0, "b": 1.0, "a": 1.0},
            "colors": json_objects(colors, "rgba"),
            "indices": orjson.Fragment(orjson.dumps(np.ascontiguousarray(faces.ravel()),
                                                    option=orjson.OPT_SERIALIZE_NUMPY))}


Vec = Sequence[float] | FloatArray


def _pose(center: Vec, quaternion: Vec = (0.0, 0.0, 0.0, 1.0)) -> dict[str, Any]:
    x, y, z = (float(v) for v in center)
    qx, qy, qz, qw = (float(v) for v in quaternion)
    return {"position": {"x": x, "y": y, "z": z},
            "orientation": {"x": qx, "y": qy, "z": qz, "w": qw}}


def sphere(center: Vec, diameters: Vec,
           rgba: tuple[float, float, float, float]) -> dict[str, Any]:
    """A ``foxglove.SpherePrimitive`` (``diameters`` along x, y, z)."""
    x, y, z = (float(v) for v in diameters)
    return {"pose": _pose(center), "size": {"x": x, "y": y, "z": z}, "color": color(rgba)}


def cube(center: Vec, sizes: Vec, quaternion: Vec,
         rgba: tuple[float, float, float, float]) -> dict[str, Any]:
    """A ``foxglove.CubePrimitive`` (full ``sizes`` along its axes, rotated by ``quaternion``)."""
    x, y, z = (float(v) for v in sizes)
    return {"pose": _pose(center, quaternion), "size": {"x": x, "y": y, "z": z},
            "color": color(rgba)}


def cylinder(center: Vec, diameter: float, length: float, quaternion: Vec,
             rgba: tuple[float, float, float, float]) -> dict[str, Any]:
    """A ``foxglove.CylinderPrimitive`` along its z axis, rotated by ``quaternion``."""
    return {"pose": _pose(center, quaternion),
            "size": {"x": float(diameter), "y": float(diameter), "z": float(length)},
            "bottom_scale": 1.0, "top_scale": 1.0, "color": color(rgba)}


def entity(t_ns: int, entity_id: str, *, lines: list[dict[str, Any]] | None = None,
           triangle_lists: list[dict[str, Any]] | None = None,
           metadata: dict[str, Any] | None = None,
           spheres: list[dict[str, Any]] | None = None,
           cubes: list[dict[str, Any]] | None = None,
           cylinders: list[dict[str, Any]] | None = None) -> dict[str, Any]:
    """A ``foxglove.SceneEntity`` in the canal frame that stays until replaced or deleted."""
    out: dict[str, Any] = {
        "timestamp": stamp(t_ns), "frame_id": CANAL_FRAME, "id": entity_id,
        "lifetime": {"sec": 0, "nsec": 0}, "frame_locked": False,
        "metadata": [{"key": k, "value": str(v)} for k, v in (metadata or {}).items()],
    }
    for name in _PRIMITIVES:
        out[name] = []
    out["lines"] = lines or []
    out["triangles"] = triangle_lists or []
    out["spheres"] = spheres or []
    out["cubes"] = cubes or []
    out["cylinders"] = cylinders or []
    return out


def scene_update(entities: Sequence[dict[str, Any]] = (),
                 deletions: Sequence[tuple[int, str]] = (), *,
                 clear_at: int | None = None) -> bytes:
    """A ``foxglove.SceneUpdate`` message: ``deletions`` are (t_ns, entity id) pairs;
    ``clear_at`` (t_ns) first deletes every entity the topic showed."""
    cleared = [] if clear_at is None else [
        {"timestamp": stamp(clear_at), "type": DELETE_ALL, "id": ""}]
    return orjson.dumps({
        "deletions": cleared + [{"timestamp": stamp(t), "type": DELETE_MATCHING_ID, "id": i}
                                for t, i in deletions],
        "entities": list(entities),
    })


_IDENTITY_Q = (0.0, 0.0, 0.0, 1.0)


def pose_in_frame(t_ns: int, position: Sequence[float], orientation: Sequence[float] = _IDENTITY_Q,
                  frame_id: str = CANAL_FRAME) -> bytes:
    """A ``foxglove.PoseInFrame`` at ``position`` (3,) with ``orientation`` [qx, qy, qz, qw]."""
    x, y, z = position
    qx, qy, qz, qw = orientation
    return orjson.dumps({"timestamp": stamp(t_ns), "frame_id": frame_id, "pose": {
        "position": {"x": x, "y": y, "z": z},
        "orientation": {"x": qx, "y": qy, "z": qz, "w": qw}}})


def poses_in_frame(t_ns: int, positions: FloatArray, orientations: FloatArray,
                   frame_id: str = CANAL_FRAME) -> bytes:
    """A ``foxglove.PosesInFrame``: positions (M, 3) with orientations (M, 4) [qx, qy, qz, qw]."""
    return orjson.dumps({"timestamp": stamp(t_ns), "frame_id": frame_id, "poses": [
        {"position": {"x": p[0], "y": p[1], "z": p[2]},
         "orientation": {"x": q[0], "y": q[1], "z": q[2], "w": q[3]}}
        for p, q in zip(positions.tolist(), orientations.tolist(), strict=True)]})


def frame_transform(t_ns: int, parent: str, child: str,
                    translation: Sequence[float] = (0.0, 0.0, 0.0),
                    rotation: Sequence[float] = _IDENTITY_Q) -> bytes:
    """A ``foxglove.FrameTransform`` ``parent -> child`` (rotation [qx, qy, qz, qw])."""
    x, y, z = translation
    qx, qy, qz, qw = rotation
    return orjson.dumps({"timestamp": stamp(t_ns), "parent_frame_id": parent,
                         "child_frame_id": child,
                         "translation": {"x": x, "y": y, "z": z},
                         "rotation": {"x": qx, "y": qy, "z": qz, "w": qw}})


def plain(t_ns: int, **fields: Any) -> bytes:
    """A ``canal.*`` message: ``fields`` plus the timestamp."""
    return orjson.dumps({"timestamp": stamp(t_ns), **fields}, option=orjson.OPT_SERIALIZE_NUMPY)


# ---- live messages: one template per topic, filled for many rows at once ---------------------
#
# A live stream writes four small messages per row. The same JSON as the builders above, but
# formatted from a per-topic template: the numbers of all rows come out of one orjson call
# (the same float formatting; NaN and infinities as null), and each message is one
# bytes %-format.

_STAMP = b'{"timestamp":{"sec":%d,"nsec":%d},'
_XYZ = b'{"x":%b,"y":%b,"z":%b}'
_XYZW = b'{"x":%b,"y":%b,"z":%b,"w":%b}'
_BOOL = (b"false", b"true")


def _tokens(values: np.ndarray) -> list[bytes]:
    """The JSON numbers of ``values`` (flattened, C order), as orjson writes them."""
    flat = np.ascontiguousarray(values, dtype=np.float64).ravel()
    if flat.size == 0:
        return []
    return orjson.dumps(flat, option=orjson.OPT_SERIALIZE_NUMPY)[1:-1].split(b",")


def _literal(text: str) -> bytes:
    """A JSON string for a template (``%`` escaped)."""
    return orjson.dumps(text).replace(b"%", b"%%")


def _stamps(t_ns: np.ndarray) -> tuple[list[int], list[int]]:
    t = np.asarray(t_ns, dtype=np.int64)
    return (t // 1_000_000_000).tolist(), (t % 1_000_000_000).tolist()


def _pose_rows(t_ns: np.ndarray, positions: FloatArray,
               orientations: FloatArray) -> zip[tuple[Any, ...]]:
    """Per row: sec, nsec, x, y, z, qx, qy, qz, qw (JSON tokens for the floats)."""
    sec, nsec = _stamps(t_ns)
    p, q = _tokens(positions), _tokens(orientations)
    return zip(sec, nsec, p[0::3], p[1::3], p[2::3], q[0::4], q[1::4], q[2::4], q[3::4],
               strict=True)


def _pose_template(frame_id: str) -> bytes:
    return (_STAMP + b'"frame_id":' + _literal(frame_id) + b',"pose":{"position":' + _XYZ
            + b',"orientation":' + _XYZW + b"}}")


def _transform_template(parent: str, child: str) -> bytes:
    return (_STAMP + b'"parent_frame_id":' + _literal(parent) + b',"child_frame_id":'
            + _literal(child) + b',"translation":' + _XYZ + b',"rotation":' + _XYZW + b"}")


def pose_in_frame_messages(t_ns: np.ndarray, positions: FloatArray, orientations: FloatArray,
                           frame_id: str = CANAL_FRAME) -> list[bytes]:
    """``foxglove.PoseInFrame`` messages, one per row (as :func:`pose_in_frame` writes them).

    Parameters
    ----------
    t_ns : array, shape (M,)
    positions : array, shape (M, 3)
    orientations : array, shape (M, 4)
        [qx, qy, qz, qw].
    """
    template = _pose_template(frame_id)
    return [template % row for row in _pose_rows(t_ns, positions, orientations)]


def frame_transform_messages(t_ns: np.ndarray, parent: str, child: str,
                             translations: FloatArray, rotations: FloatArray) -> list[bytes]:
    """``foxglove.FrameTransform`` messages ``parent -> child``, one per row (as
    :func:`frame_transform` writes them): translations (M, 3), rotations (M, 4)."""
    template = _transform_template(parent, child)
    return [template % row for row in _pose_rows(t_ns, translations, rotations)]


def pose_and_frame_messages(t_ns: np.ndarray, positions: FloatArray, orientations: FloatArray,
                            child: str) -> tuple[list[bytes], list[bytes]]:
    """:func:`pose_in_frame_messages` (canal frame) and :func:`frame_transform_messages`
    (canal -> ``child``) of the same rows, their numbers formatted once."""
    pose, frame = _pose_template(CANAL_FRAME), _transform_template(CANAL_FRAME, child)
    rows = list(_pose_rows(t_ns, positions, orientations))
    return [pose % row for row in rows], [frame % row for row in rows]


def tracker_state_messages(t_ns: np.ndarray, robot: str, progress: FloatArray, eta: FloatArray,
                           section_index: np.ndarray, inside: np.ndarray,
                           done: np.ndarray, route: np.ndarray | None = None) -> list[bytes]:
    """``canal.TrackerState`` messages, one per row (as :func:`plain` writes them; a NaN
    eta is null; ``route`` only where the stream followed a route of a model of several).
    All arrays shape (M,)."""
    template = (_STAMP + b'"robot":' + _literal(robot)
                + b',"progress":%b,"eta":%b,"section_index":%d,"inside":%b,"done":%b}')
    sec, nsec = _stamps(t_ns)
    out = [template % row for row in zip(
        sec, nsec, _tokens(progress), _tokens(eta), np.asarray(section_index).tolist(),
        [_BOOL[v] for v in np.asarray(inside, dtype=bool).tolist()],
        [_BOOL[v] for v in np.asarray(done, dtype=bool).tolist()], strict=True)]
    if route is not None and np.any(route >= 0):
        out = [m if k < 0 else m[:-1] + b',"route":%d}' % k
               for m, k in zip(out, np.asarray(route).tolist(), strict=True)]
    return out
