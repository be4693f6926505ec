"""Poses and targets as JSON (orjson; see :mod:`canal_protocol.wire` for the fields)."""

from __future__ import annotations

import math
from typing import Any

import orjson

from .messages import (
    MAX_COORDINATE,
    MAX_DIM,
    NO_ROUTE,
    SEQ_MAX,
    VERSION,
    Pose,
    Target,
    WireError,
    all_finite,
    check_pose_numbers,
    plain_pose,
)

_isfinite = math.isfinite
_hypot = math.hypot


def encode_pose_json(seq: int, position: Any, orientation: Any = None, t: float | None = None,
                     restart: bool = False) -> bytes:
    """A pose as JSON."""
    body: dict[str, Any] = {"seq": seq, "position": [float(v) for v in position]}
    if orientation is not None:
        body["orientation"] = [float(v) for v in orientation]
    if t is not None:
        body["t"] = float(t)
    if restart:
        body["restart"] = True
    return orjson.dumps(body)


def _shown(value: Any) -> str:
    """A refused value as the sender wrote it: JSON text, not Python's repr."""
    if value is None:
        # What orjson and most encoders make of a NaN, so the likeliest cause.
        return "null (JSON has no NaN or infinity)"
    text = orjson.dumps(value).decode()
    return text if len(text) <= 40 else text[:40] + "..."


def _kind(value: Any) -> str:
    """A JSON value's kind, for a message about a body that is not an object."""
    kinds = {list: "a list", str: "a string", bool: "a boolean", int: "a number", float: "a number"}
    return "null" if value is None else kinds.get(type(value), type(value).__name__)


def _numbers(value: Any, field: str, n: int | None = None) -> tuple[float, ...]:
    if not isinstance(value, list) or (n is not None and len(value) != n):
        raise WireError("bad_payload", f"expected {field} as a list of {n or 'D'} numbers, "
                                       f"got {_shown(value)}")
    for v in value:
        if type(v) is not float and type(v) is not int:
            raise WireError("bad_payload", f"expected numbers in {field}, got {_shown(v)}")
    return tuple(float(v) for v in value)


_loads = orjson.loads
_JSONDecodeError = orjson.JSONDecodeError


def decode_pose_json(data: bytes) -> Pose:
    """A JSON pose; WireError (bad_payload, non_finite) when it cannot be used."""
    try:
        body = _loads(data)
    except _JSONDecodeError as exc:
        raise WireError("bad_payload", f"expected JSON: {exc}") from None
    # The common pose, {"seq": n, "position": [floats]}, checked in a few type tests; a
    # finite sum means finite coordinates (a sum that overflows takes the full checks).
    if type(body) is dict and len(body) == 2:
        seq = body.get("seq")
        position = body.get("position")
        if type(seq) is int and 0 <= seq <= SEQ_MAX and type(position) is list \
                and 0 < len(position) <= MAX_DIM:
            for v in position:
                if type(v) is not float:
                    break
            else:
                # a norm within the bound: finite coordinates within it (NaN and
                # infinity give NaN or infinity; the full checks say which)
                if _hypot(*position) <= MAX_COORDINATE:
                    return plain_pose(seq, tuple(position))
    return _checked_pose_json(body)


def _checked_pose_json(body: Any) -> Pose:
    """A decoded JSON pose, every field checked."""
    if not isinstance(body, dict):
        raise WireError("bad_payload", f"expected a JSON object, got {_kind(body)}")
    seq = body.get("seq")
    if type(seq) is not int or not 0 <= seq <= SEQ_MAX:
        came = "no 'seq'" if "seq" not in body else _shown(seq)
        raise WireError("bad_payload", f"expected 'seq', an integer in [0, 2**64), got {came}")
    try:
        return _pose_fields(body, seq)
    except WireError as exc:
        exc.seq = seq  # the seq was read: the answer says which pose it refuses
        raise


#: The keys of a JSON pose (canal_protocol.wire); any other is refused, as a REST body's is:
#: a mistyped "orientaton" must not be a pose without its orientation.
_POSE_KEYS = frozenset(("seq", "position", "orientation", "t", "restart"))


def _pose_fields(body: dict[str, Any], seq: int) -> Pose:
    """The pose of a JSON object whose ``seq`` was read, its other fields checked."""
    if "position" not in body:
        raise WireError("bad_payload", "expected 'position', got the keys "
                                       f"{', '.join(map(str, body))[:80]}")
    unknown = [str(key) for key in body if key not in _POSE_KEYS]
    if unknown:
        raise WireError("bad_payload", f"expected only the keys {', '.join(sorted(_POSE_KEYS))}, "
                                       f"got {', '.join(unknown)[:80]}")
    position = _numbers(body["position"], "position")
    if not 1 <= len(position) <= MAX_DIM:
        raise WireError("bad_payload", f"expected 1..{MAX_DIM} coordinates in 'position', "
                                       f"got {len(position)}")
    raw_orientation = body.get("orientation")
    orientation: tuple[float, float, float, float] | None = None
    if raw_orientation is not None:
        qx, qy, qz, qw = _numbers(raw_orientation, "orientation", 4)
        orientation = (qx, qy, qz, qw)
    t = body.get("t")
    if t is not None and type(t) is not float and type(t) is not int:
        raise WireError("bad_payload", f"expected 't' as a number of seconds, got {_shown(t)}")
    if not all_finite(position) or (orientation is not None and not all_finite(orientation)) or (
            t is not None and not _isfinite(t)):
        raise WireError("non_finite", "expected finite numbers, got NaN or infinity")
    check_pose_numbers(position, orientation, t)
    restart = body.get("restart")
    if restart is None:  # absent or null, as every optional field
        restart = False
    elif type(restart) is not bool:
        raise WireError("bad_payload", f"expected 'restart' as true or false, got {_shown(restart)}")
    return Pose(seq, position, orientation, None if t is None else float(t), restart)


def target_json(answer: Target) -> bytes:
    """A target as JSON."""
    body: dict[str, Any] = {
        "v": VERSION, "seq": answer.seq, "status": answer.status,
        "target": None if answer.target is None else list(answer.target),
        "progress": answer.progress, "eta": answer.eta, "section": answer.section,
        "inside": answer.inside, "done": answer.done, "model_version": answer.model_version,
        "message": answer.message,
        "orientation": None if answer.orientation is None else list(answer.orientation),
        "coalesced": answer.coalesced,
    }
    if answer.velocity is not None:
        body["velocity"] = list(answer.velocity)
    if answer.route is not None:
        body["route"] = answer.route
    return orjson.dumps(body)


_NUMPY = orjson.OPT_SERIALIZE_NUMPY


def pack_target_json(seq: int, status: str, target: Any, progress: float, eta: float,
                     section: int, inside: bool, done: bool, model_version: int,
                     orientation: Any = None, velocity: Any = None, coalesced: int = 0,
                     route: int | None = NO_ROUTE) -> bytes:
    """Fast path for the bridge (see :func:`pack_target`); numpy arrays are fine. ``route``:
    a model of several routes answers the route the stream follows (null: the canal of all
    the demonstrations); :data:`NO_ROUTE` (a model of one route) leaves the key out."""
    body = {
        "v": VERSION, "seq": seq, "status": status, "target": target, "progress": progress,
        "eta": eta, "section": section, "inside": inside, "done": done,
        "model_version": model_version, "message": None, "orientation": orientation,
        "coalesced": coalesced,
    }
    if velocity is not None:
        body["velocity"] = velocity
    if route != NO_ROUTE:
        body["route"] = route
    return orjson.dumps(body, option=_NUMPY)


def _json_floats(values: Any) -> tuple[float, ...]:
    """A JSON list of numbers; ``null`` is the NaN or infinity the writer could not put in
    JSON (orjson writes them as null), read back as NaN."""
    return tuple(math.nan if v is None else float(v) for v in values)


def decode_target_json(data: bytes) -> Target:
    """A JSON target; WireError when it cannot be read."""
    try:
        body = orjson.loads(data)
    except orjson.JSONDecodeError as exc:
        raise WireError("bad_payload", f"expected JSON: {exc}") from None
    if not isinstance(body, dict) or "status" not in body:
        raise WireError("bad_payload", "expected a JSON target object")
    target = body.get("target")
    orientation = body.get("orientation")
    velocity = body.get("velocity")
    try:
        return Target(
            seq=body.get("seq"), status=str(body["status"]),
            target=None if target is None else _json_floats(target),
            progress=float(body.get("progress") or 0.0), eta=body.get("eta"),
            section=body.get("section"), inside=bool(body.get("inside")),
            done=bool(body.get("done")), model_version=body.get("model_version"),
            message=body.get("message"),
            orientation=None if orientation is None else _json_floats(orientation),  # type: ignore[arg-type]
            velocity=None if velocity is None else _json_floats(velocity),
            coalesced=int(body.get("coalesced") or 0),
            route=body.get("route"),
        )
    except (TypeError, ValueError) as exc:
        raise WireError("bad_payload", f"expected a JSON target: {exc}") from None
