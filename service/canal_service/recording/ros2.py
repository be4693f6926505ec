"""The ros2 MCAP profile: a skill's recording as a rosbag2-compatible MCAP (CDR messages).

Made on export from the recording's Foxglove JSON MCAP (one source of truth), with
``mcap-ros2-support`` (profile ``ros2``, schema encoding ``ros2msg``, message encoding
``cdr``). Topics::

    /tf                              tf2_msgs/msg/TFMessage        world -> canal, canal -> robot/<r>
    /canal/live/<robot>/pose         geometry_msgs/msg/PoseStamped  the robot's poses
    /canal/live/<robot>/target       geometry_msgs/msg/PoseStamped  Canal's targets
    /canal/demos/demo_<id>           nav_msgs/msg/Path              a demonstration, with its
                                                                    orientations (an empty Path
                                                                    when it was deleted)
    /canal/model/directrix           nav_msgs/msg/Path              per model version of one route
    /canal/model/mesh                visualization_msgs/msg/MarkerArray  DELETEALL, then TRIANGLE_LIST
                                                                    canal surface, LINE_LIST rings
                                                                    and frames (a model of several
                                                                    routes: ns canal/route_<k>/...)
    /canal/model/route_<k>/directrix nav_msgs/msg/Path              a model of several routes:
                                                                    each route's directrix
    /canal/corrections/samples       nav_msgs/msg/Path              the path of each correction
    /canal/corrections/sections      visualization_msgs/msg/MarkerArray  LINE_LIST: the sections it
                                                                    changed, before and after
    /canal/reproductions             nav_msgs/msg/Path              each reproduction (with its
                                                                    orientations when it has them)
    /canal/scene                     visualization_msgs/msg/MarkerArray  the skill's obstacles
                                                                    (DELETEALL, then SPHERE, CUBE,
                                                                    CYLINDER markers) per change

Robot names that are not valid ROS name tokens have their other characters replaced by ``_``.
The Canal-specific JSON topics (tracker state, model info, reproduction results) have no ROS
type and are left out of this profile.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import orjson
from mcap.reader import make_reader
from mcap_ros2.writer import Writer as Ros2Writer

from .ros2_msgdefs import MSGDEFS

_IDENTITY_Q = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}
_ZERO = {"x": 0.0, "y": 0.0, "z": 0.0}
_TOKEN = re.compile(r"[^A-Za-z0-9_]")
TRIANGLE_LIST, LINE_LIST, ADD = 11, 5, 0
CUBE, SPHERE, CYLINDER, DELETEALL = 1, 2, 3, 3


def ros_name(part: str) -> str:
    """``part`` as a valid ROS 2 name token (letters, digits, ``_``; not starting with a digit)."""
    token = _TOKEN.sub("_", part) or "_"
    return "_" + token if token[0].isdigit() else token


def robot_tokens(robots: Iterable[str]) -> dict[str, str]:
    """Each robot name's ROS name token (:func:`ros_name`), one per robot: names that become
    the same token (``arm-1``, ``arm.1``, ``arm_1``) keep it only when it is the name itself;
    the others get a short digest of their name (``arm_1_3f9c2a``), so no two robots share a
    topic, whichever order they come in."""
    by_token: dict[str, list[str]] = {}
    for robot in set(robots):
        by_token.setdefault(ros_name(robot), []).append(robot)
    out = {}
    for token, names in by_token.items():
        for robot in names:
            if len(names) > 1 and robot != token:
                digest = hashlib.sha1(robot.encode("utf-8", "surrogatepass")).hexdigest()[:6]
                out[robot] = f"{token}_{digest}"
            else:
                out[robot] = token
    return out


def _header(stamp: dict[str, int], frame_id: str) -> dict[str, Any]:
    return {"stamp": {"sec": int(stamp["sec"]), "nanosec": int(stamp["nsec"])},
            "frame_id": frame_id}


def _pose(position: dict[str, float], orientation: dict[str, float] | None = None
          ) -> dict[str, Any]:
    return {"position": {k: float(position[k]) for k in "xyz"},
            "orientation": {k: float((orientation or _IDENTITY_Q)[k]) for k in "xyzw"}}


def _path(stamp: dict[str, int], frame_id: str, points: list[dict[str, float]],
          orientations: list[dict[str, float]] | None = None) -> dict[str, Any]:
    header = _header(stamp, frame_id)
    quats = orientations if orientations and len(orientations) == len(points) else None
    return {"header": header, "poses": [
        {"header": header, "pose": _pose(p, quats[i] if quats else None)}
        for i, p in enumerate(points)]}


def _marker(stamp: dict[str, int], frame_id: str, ns: str, kind: int,
            points: list[dict[str, float]], colors: list[dict[str, float]],
            color: dict[str, float], scale: float = 1.0) -> dict[str, Any]:
    return {
        "header": _header(stamp, frame_id), "ns": ns, "id": 0, "type": kind, "action": ADD,
        "pose": _pose(_ZERO), "scale": {"x": scale, "y": scale, "z": scale},
        "color": {k: float(color[k]) for k in "rgba"},
        "lifetime": {"sec": 0, "nanosec": 0}, "frame_locked": False,
        "points": [{k: float(p[k]) for k in "xyz"} for p in points],
        "colors": [{k: float(c[k]) for k in "rgba"} for c in colors],
        "texture_resource": "",
        "texture": {"header": _header({"sec": 0, "nsec": 0}, ""), "format": "", "data": b""},
        "uv_coordinates": [], "text": "", "mesh_resource": "",
        "mesh_file": {"filename": "", "data": b""}, "mesh_use_embedded_materials": False,
    }


def _mesh_markers(stamp: dict[str, int], entities: list[dict[str, Any]]) -> dict[str, Any]:
    """The model's SceneUpdate as a MarkerArray: DELETEALL first (a model replaces the previous
    one, which may have had other routes), then each canal's surface, rings and the frames."""
    clear = _marker(stamp, "canal", "canal/model", SPHERE, [], [], {"r": 0, "g": 0, "b": 0, "a": 0})
    clear["action"] = DELETEALL
    markers = [clear]
    for ent in entities:
        frame = ent.get("frame_id", "canal")
        if ent["id"].endswith("/mesh"):
            for tri in ent.get("triangles", []):
                pts, cols, idx = tri["points"], tri.get("colors") or [], tri.get("indices") or []
                order = idx if idx else list(range(len(pts)))
                # TRIANGLE_LIST: every three points are a triangle (no index buffer in ROS).
                markers.append(_marker(stamp, frame, ent["id"], TRIANGLE_LIST,
                                       [pts[i] for i in order],
                                       [cols[i] for i in order] if cols else [],
                                       tri.get("color") or {"r": 1, "g": 1, "b": 1, "a": 1}))
        elif ent["id"].endswith("/rings") or ent["id"] == "canal/frames":
            for line in ent.get("lines", []):
                markers.append(_marker(stamp, frame, ent["id"], LINE_LIST, line["points"],
                                       line.get("colors") or [], line["color"], scale=0.002))
    return {"markers": markers}


def _shape(stamp: dict[str, int], frame_id: str, ns: str, marker_id: int, kind: int,
           prim: dict[str, Any]) -> dict[str, Any]:
    """A SPHERE, CUBE or CYLINDER marker from a Foxglove primitive (same pose, size, colour)."""
    marker = _marker(stamp, frame_id, ns, kind, [], [], prim["color"])
    marker["id"] = marker_id
    marker["pose"] = _pose(prim["pose"]["position"], prim["pose"]["orientation"])
    marker["scale"] = {k: float(prim["size"][k]) for k in "xyz"}
    return marker


def _scene_markers(msg: dict[str, Any]) -> dict[str, Any]:
    """The scene's SceneUpdate as a MarkerArray: DELETEALL first (the scene replaces the
    previous one), then one marker per sphere, cube and cylinder of each obstacle."""
    entities = msg.get("entities", [])
    stamp = entities[0]["timestamp"] if entities else (
        msg["deletions"][0]["timestamp"] if msg.get("deletions") else {"sec": 0, "nsec": 0})
    clear = _marker(stamp, "canal", "canal/scene", SPHERE, [], [], {"r": 0, "g": 0, "b": 0, "a": 0})
    clear["action"] = DELETEALL
    markers = [clear]
    for ent in entities:
        for name, kind in (("spheres", SPHERE), ("cubes", CUBE), ("cylinders", CYLINDER)):
            for prim in ent.get(name, []):
                markers.append(_shape(ent["timestamp"], ent["frame_id"], ent["id"],
                                      len(markers), kind, prim))
    return {"markers": markers}


def _messages(src: Path) -> Iterator[tuple[str, str, Any, int]]:
    """(topic, ROS type, message dict, log time) of the Foxglove recording, in log order."""
    poses_at: dict[int, list[dict[str, float]]] = {}
    demo_poses: dict[tuple[str, int], list[dict[str, float]]] = {}
    robots: set[str] = set()
    with open(src, "rb") as f:
        reader = make_reader(f)
        for _, channel, m in reader.iter_messages(log_time_order=False):
            if channel.topic.startswith("/live/"):
                robots.add(channel.topic.split("/")[2])
            elif channel.topic == "/canal/reproduction_poses":
                msg = orjson.loads(m.data)
                poses_at[m.log_time] = [p["orientation"] for p in msg["poses"]]
            elif channel.topic.startswith("/canal/demo_poses/"):
                msg = orjson.loads(m.data)
                demo_poses[(channel.topic.rsplit("/", 1)[1], m.log_time)] = [
                    p["orientation"] for p in msg["poses"]]
    tokens = robot_tokens(robots)
    with open(src, "rb") as f:
        reader = make_reader(f)
        for _, channel, m in reader.iter_messages(log_time_order=True):
            topic, t = channel.topic, m.log_time
            if (topic == "/canal/reproduction_poses" or topic.startswith("/canal/demo_poses/")
                    or not topic.startswith(("/tf", "/live/", "/canal/"))):
                continue
            msg = orjson.loads(m.data)
            if topic == "/tf":
                yield "/tf", "tf2_msgs/msg/TFMessage", {"transforms": [{
                    "header": _header(msg["timestamp"], msg["parent_frame_id"]),
                    "child_frame_id": msg["child_frame_id"],
                    "transform": {"translation": msg["translation"],
                                  "rotation": msg["rotation"]}}]}, t
            elif topic.startswith("/live/"):
                parts = topic.split("/")
                if len(parts) != 4 or parts[3] not in ("pose", "target"):
                    continue
                yield (f"/canal/live/{tokens[parts[2]]}/{parts[3]}",
                       "geometry_msgs/msg/PoseStamped",
                       {"header": _header(msg["timestamp"], msg["frame_id"]),
                        "pose": _pose(msg["pose"]["position"], msg["pose"]["orientation"])}, t)
            elif topic == "/canal/demos":
                for d in msg.get("deletions", []):
                    demo = d["id"].split("/")[-1]
                    yield (f"/canal/demos/{ros_name('demo_' + demo)}", "nav_msgs/msg/Path",
                           _path(d["timestamp"], "canal", []), t)
                for ent in msg.get("entities", []):
                    demo = ent["id"].split("/")[-1]
                    points = ent["lines"][0]["points"] if ent.get("lines") else []
                    yield (f"/canal/demos/{ros_name('demo_' + demo)}", "nav_msgs/msg/Path",
                           _path(ent["timestamp"], ent["frame_id"], points,
                                 demo_poses.get((demo, t))), t)
            elif topic == "/canal/model":
                entities = msg.get("entities", [])
                stamp = entities[0]["timestamp"] if entities else {"sec": 0, "nsec": 0}
                for ent in entities:
                    if ent["id"] == "canal/directrix" and ent.get("lines"):
                        yield ("/canal/model/directrix", "nav_msgs/msg/Path",
                               _path(ent["timestamp"], ent["frame_id"],
                                     ent["lines"][0]["points"]), t)
                    elif (ent["id"].startswith("canal/route_")
                          and ent["id"].endswith("/directrix") and ent.get("lines")):
                        # each route of a model of several routes: its own Path topic
                        route = ent["id"].split("/")[1]
                        yield (f"/canal/model/{route}/directrix", "nav_msgs/msg/Path",
                               _path(ent["timestamp"], ent["frame_id"],
                                     ent["lines"][0]["points"]), t)
                yield ("/canal/model/mesh", "visualization_msgs/msg/MarkerArray",
                       _mesh_markers(stamp, entities), t)
            elif topic == "/canal/scene":
                yield "/canal/scene", "visualization_msgs/msg/MarkerArray", _scene_markers(msg), t
            elif topic == "/canal/corrections":
                entities = msg.get("entities", [])
                for ent in entities:
                    if ent.get("lines"):
                        yield ("/canal/corrections/samples", "nav_msgs/msg/Path",
                               _path(ent["timestamp"], ent["frame_id"],
                                     ent["lines"][0]["points"]), t)
                markers = [
                    _marker(ent["timestamp"], ent.get("frame_id", "canal"), ent["id"], LINE_LIST,
                            line["points"], line.get("colors") or [], line["color"], scale=0.002)
                    for ent in entities for line in ent.get("lines", [])[1:]]
                if markers:
                    yield ("/canal/corrections/sections", "visualization_msgs/msg/MarkerArray",
                           {"markers": markers}, t)
            elif topic == "/canal/reproductions":
                for ent in msg.get("entities", []):
                    if ent.get("lines"):
                        yield ("/canal/reproductions", "nav_msgs/msg/Path",
                               _path(ent["timestamp"], ent["frame_id"],
                                     ent["lines"][0]["points"], poses_at.get(t)), t)


def foxglove_to_ros2(src: Path, out: Path) -> int:
    """Write the ros2-profile MCAP of the Foxglove recording ``src`` to ``out``; the count."""
    tmp = out.with_name(out.name + ".tmp")
    n = 0
    try:
        with open(tmp, "wb") as f:
            writer = Ros2Writer(f)
            schemas: dict[str, Any] = {}
            for topic, ros_type, message, t in _messages(src):
                schema = schemas.get(ros_type)
                if schema is None:
                    schema = schemas[ros_type] = writer.register_msgdef(ros_type,
                                                                        MSGDEFS[ros_type])
                writer.write_message(topic, schema, message, log_time=t, publish_time=t)
                n += 1
            writer.finish()  # type: ignore[no-untyped-call]  # mcap's Writer is untyped
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    tmp.replace(out)
    return n
