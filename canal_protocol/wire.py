"""The live wire protocol between a robot and Canal's Zenoh bridge (stdlib + orjson only).

Robots import this module without the service: it names the key expressions and encodes and
decodes the two messages, a *pose* (robot -> Canal) and a *target* (Canal -> robot).

Key expressions (defined in :mod:`canal_protocol.keys`; ``prefix`` defaults to ``canal``;
``skill`` and ``robot`` are single chunks, no ``/``, ``*``, ``$``, ``?`` or ``#``)::

    {prefix}/{skill}/{robot}/pose          robot -> Canal   put, one pose per sample
    {prefix}/{skill}/{robot}/target        Canal -> robot   put, one answer per pose
    {prefix}/{skill}/model                 queryable: latest model, JSON (= REST body of
                                           GET /skills/{skill}/models/latest?serialized=true)
    {prefix}/{skill}/{robot}/demo/start    queryable: begin capturing this stream's poses
    {prefix}/{skill}/{robot}/demo/stop     queryable: store them as a new demonstration;
                                           the reply is {"id", "n_points", "checksum"}

Encoding is chosen by the Zenoh encoding of the sample: ``application/json`` (or
``text/json``) is JSON, anything else is the binary layout below (a default-encoded payload
whose first byte is ``{`` is read as JSON too). Canal answers in the encoding the pose came
in.

Binary layout, version 1, little-endian, no padding. Every message starts with a 12-byte
header ``<BBBBQ``:

====== ======= ===========================================================================
offset type    field
====== ======= ===========================================================================
0      uint8   version (1)
1      uint8   kind: 1 pose, 2 target
2      uint8   flags (per kind, below)
3      uint8   dim D: number of position coordinates (2 or 3; 0 in a target without one)
4      uint64  seq: the pose's sequence number / the seq of the pose a target answers
====== ======= ===========================================================================

Pose (kind 1) after the header: ``D x float64`` position, then ``4 x float64`` orientation
quaternion (x, y, z, w) if flag 0x01, then ``float64`` timestamp in seconds if flag 0x02.
Flag 0x04 (restart) tells Canal to re-locate the robot in the canal instead of continuing
from the section reached so far (send it on the first pose of a new run). A 3-D pose
without extras is 36 bytes.

Target (kind 2) after the header: ``<iiddH`` = int32 model version (-1 none), int32 section
index (-1 none), float64 progress in [0, 1], float64 eta (NaN when none), uint16 status
code; then ``D x float64`` target position; then, if flag 0x08, ``uint16`` length and that
many bytes of UTF-8 message. Target flags: 0x01 inside, 0x02 done, 0x04 seq is known (not
set when the pose could not be read), 0x08 has message. A 3-D target is 62 bytes.
Optional extras follow, each present when its flag is set, in this order: 0x10 ``4 x
float64`` target orientation (x, y, z, w); 0x20 ``D x float64`` feed-forward velocity;
0x40 ``uint32`` poses of this stream coalesced so far. They sit after everything an older
reader looks at, so clients written before them keep working (they ignore the tail).

ROS 2 (CDR): a sample whose Zenoh encoding is ``application/cdr`` or whose first two bytes
are a CDR encapsulation header (``00 01`` little-endian, ``00 00`` big-endian; a binary
pose starts with ``01``) is read as a ``geometry_msgs/msg/PoseStamped``. The answer on
``.../target`` is a ``PoseStamped`` with the pose's stamp and frame_id, the target position
and orientation; statuses that PoseStamped cannot carry go to ``{prefix}/{skill}/{robot}/status``
as a JSON target (errors always, ``outside_canal``/``ok`` when the status changes). A CDR
pose has no seq: the bridge numbers each stream's CDR poses itself.

JSON pose::

    {"seq": 17, "position": [x, y, z], "orientation": [qx, qy, qz, qw]?, "t": 1.25?,
     "restart": false?}

JSON target::

    {"v": 1, "seq": 17, "status": "ok", "target": [x, y, z], "progress": 0.41, "eta": 0.3,
     "section": 82, "inside": true, "done": false, "model_version": 3, "message": null,
     "orientation": [qx, qy, qz, qw] | null, "coalesced": 0, "velocity": [vx, vy, vz]?}

``orientation`` is the model's orientation at the target when it learned one, else the
pose's own (null when the pose had none); ``velocity`` is there only when the model gives
one; ``coalesced`` counts this stream's poses skipped under overload so far (latest wins).

``seq`` is null when the pose could not be read; ``target``, ``eta``, ``section`` and
``model_version`` are null when there is none. JSON has no NaN: a JSON pose with NaN is
not JSON (nor is a number that overflows to infinity) and is answered ``bad_payload``.

Status keys (code, key, whether the target is usable):

==== ================= ====== ================================================================
code key               target meaning
==== ================= ====== ================================================================
0    ok                yes    inside the canal (or done)
1    outside_canal     yes    the pose is outside the canal; the target is on the boundary of
                              the section ahead, the way back in
16   bad_payload       no     not a pose: garbage, truncated, wrong version/kind, missing fields
17   wrong_dimension   no     D differs from the skill's dimension
18   non_finite        no     NaN or infinity in the position, orientation or time
19   unknown_skill     no     no skill of that name
20   no_model          no     the skill has no fitted model yet
21   internal_error    no     a bug; logged by the service
==== ================= ====== ================================================================
"""

from __future__ import annotations

import math
import struct
import sys
from array import array
from dataclasses import dataclass
from itertools import chain
from typing import Any

import orjson

from .keys import Keys, check_chunk, is_plain_chunk, keys, model_key, pose_wildcard, stream_of

VERSION = 1
KIND_POSE = 1
KIND_TARGET = 2
MAX_DIM = 16

POSE_ORIENTATION = 0x01
POSE_TIME = 0x02
POSE_RESTART = 0x04

TARGET_INSIDE = 0x01
TARGET_DONE = 0x02
TARGET_SEQ = 0x04
TARGET_MESSAGE = 0x08
TARGET_ORIENTATION = 0x10
TARGET_VELOCITY = 0x20
TARGET_COALESCED = 0x40

SEQ_MAX = 2**64 - 1

HEADER = struct.Struct("<BBBBQ")
TARGET_BODY = struct.Struct("<iiddH")
_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_QUAT = struct.Struct("<4d")

STATUS_CODES: dict[str, int] = {
    "ok": 0,
    "outside_canal": 1,
    "bad_payload": 16,
    "wrong_dimension": 17,
    "non_finite": 18,
    "unknown_skill": 19,
    "no_model": 20,
    "internal_error": 21,
}
STATUS_KEYS: dict[int, str] = {code: key for key, code in STATUS_CODES.items()}
USABLE = frozenset({"ok", "outside_canal"})

JSON_ENCODING = "application/json"
BINARY_ENCODING = "application/octet-stream"
CDR_ENCODING = "application/cdr"

FORMAT_JSON = 0
FORMAT_BINARY = 1
FORMAT_CDR = 2


class WireError(ValueError):
    """A message that cannot be read; ``key`` is the status key to answer with."""

    def __init__(self, key: str, message: str) -> None:
        super().__init__(message)
        self.key = key
        self.message = message


# ---- messages -----------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Pose:
    """A robot pose: ``position`` (D floats), optional quaternion (x, y, z, w) and time (s)."""

    seq: int
    position: tuple[float, ...]
    orientation: tuple[float, float, float, float] | None = None
    t: float | None = None
    restart: bool = False


@dataclass(frozen=True, slots=True)
class Target:
    """Canal's answer to one pose. ``target`` is None when ``status`` is an error."""

    seq: int | None
    status: str
    target: tuple[float, ...] | None = None
    progress: float = 0.0
    eta: float | None = None
    section: int | None = None
    inside: bool = False
    done: bool = False
    model_version: int | None = None
    message: str | None = None
    orientation: tuple[float, float, float, float] | None = None
    velocity: tuple[float, ...] | None = None
    coalesced: int = 0

    @property
    def usable(self) -> bool:
        """Whether ``target`` can be moved to (status ok or outside_canal)."""
        return self.status in USABLE


_pose_structs: dict[tuple[int, int], struct.Struct] = {}
_target_structs: dict[int, struct.Struct] = {}


def _pose_struct(dim: int, flags: int) -> struct.Struct:
    key = (dim, flags & (POSE_ORIENTATION | POSE_TIME))
    s = _pose_structs.get(key)
    if s is None:
        fmt = f"<BBBBQ{dim}d"
        if flags & POSE_ORIENTATION:
            fmt += "4d"
        if flags & POSE_TIME:
            fmt += "d"
        s = _pose_structs[key] = struct.Struct(fmt)
    return s


def _target_struct(dim: int) -> struct.Struct:
    s = _target_structs.get(dim)
    if s is None:
        s = _target_structs[dim] = struct.Struct(f"<BBBBQiiddH{dim}d")
    return s


for _d in (2, 3):
    for _f in range(4):
        _pose_struct(_d, _f)
    _target_struct(_d)
_target_struct(0)

_isfinite = math.isfinite


def _all_finite(values: Any) -> bool:
    for v in values:
        if not _isfinite(v):
            return False
    return True


# ---- binary -------------------------------------------------------------------------------------


def encode_pose(seq: int, position: Any, orientation: Any = None, t: float | None = None,
                restart: bool = False) -> bytes:
    """A pose in the binary layout."""
    flags = (POSE_ORIENTATION if orientation is not None else 0) | (
        POSE_TIME if t is not None else 0) | (POSE_RESTART if restart else 0)
    position = [float(v) for v in position]
    values = position
    if orientation is not None:
        values = values + [float(v) for v in orientation]
    if t is not None:
        values = [*values, float(t)]
    return _pose_struct(len(position), flags).pack(VERSION, KIND_POSE, flags, len(position),
                                                  seq, *values)


def _check_header(data: bytes, kind: int) -> tuple[int, int, int]:
    if len(data) < HEADER.size:
        raise WireError("bad_payload", f"expected at least {HEADER.size} bytes, got {len(data)}")
    version, got_kind, flags, dim, seq = HEADER.unpack_from(data)
    if version != VERSION:
        raise WireError("bad_payload", f"expected protocol version {VERSION}, got {version}")
    if got_kind != kind:
        raise WireError("bad_payload", f"expected message kind {kind}, got {got_kind}")
    return flags, dim, seq


def decode_pose(data: bytes) -> Pose:
    """A binary pose; WireError (bad_payload, non_finite) when it cannot be used."""
    flags, dim, seq = _check_header(data, KIND_POSE)
    if not 1 <= dim <= MAX_DIM:
        raise WireError("bad_payload", f"expected a dimension in 1..{MAX_DIM}, got {dim}")
    s = _pose_struct(dim, flags)
    if len(data) != s.size:
        raise WireError("bad_payload", f"expected {s.size} bytes for this pose, got {len(data)}")
    values = s.unpack(data)
    position = values[5 : 5 + dim]
    orientation = values[5 + dim : 9 + dim] if flags & POSE_ORIENTATION else None
    t = values[-1] if flags & POSE_TIME else None
    # a finite sum means finite numbers; one that overflows takes the check one by one
    if not _isfinite(sum(values[5:])) and not _all_finite(values[5:]):
        raise WireError("non_finite", "expected finite numbers, got NaN or infinity")
    if not flags:
        return _plain_pose(seq, position)
    return Pose(seq, position, orientation, t, bool(flags & POSE_RESTART))  # type: ignore[arg-type]


def encode_target(answer: Target) -> bytes:
    """A target in the binary layout."""
    position = answer.target or ()
    dim = len(position)
    flags = (TARGET_INSIDE if answer.inside else 0) | (TARGET_DONE if answer.done else 0)
    if answer.seq is not None:
        flags |= TARGET_SEQ
    message = answer.message.encode("utf-8")[:65535] if answer.message else b""
    if message:
        flags |= TARGET_MESSAGE
    flags |= _extra_flags(answer.orientation, answer.velocity, answer.coalesced)
    data = _target_struct(dim).pack(
        VERSION, KIND_TARGET, flags, dim, 0 if answer.seq is None else answer.seq,
        -1 if answer.model_version is None else answer.model_version,
        -1 if answer.section is None else answer.section, answer.progress,
        math.nan if answer.eta is None else answer.eta, STATUS_CODES[answer.status], *position)
    if message:
        data += _U16.pack(len(message)) + message
    return data + _extras(flags, answer.orientation, answer.velocity, answer.coalesced)


def _extra_flags(orientation: Any, velocity: Any, coalesced: int) -> int:
    return ((TARGET_ORIENTATION if orientation is not None else 0)
            | (TARGET_VELOCITY if velocity is not None else 0)
            | (TARGET_COALESCED if coalesced else 0))


def _extras(flags: int, orientation: Any, velocity: Any, coalesced: int) -> bytes:
    """The optional tail of a target (flags 0x10, 0x20, 0x40), after the message."""
    if not flags & (TARGET_ORIENTATION | TARGET_VELOCITY | TARGET_COALESCED):
        return b""
    tail = b""
    if flags & TARGET_ORIENTATION:
        tail += _QUAT.pack(*orientation)
    if flags & TARGET_VELOCITY:
        tail += struct.pack(f"<{len(velocity)}d", *velocity)
    if flags & TARGET_COALESCED:
        tail += _U32.pack(min(int(coalesced), 0xFFFFFFFF))
    return tail


def pack_target(seq: int, status: int, target: Any, progress: float, eta: float, section: int,
                inside: bool, done: bool, model_version: int, orientation: Any = None,
                velocity: Any = None, coalesced: int = 0) -> bytes:
    """Fast path for the bridge: a usable target, no message, ``target`` a (D,) sequence."""
    flags = TARGET_SEQ | (TARGET_INSIDE if inside else 0) | (TARGET_DONE if done else 0)
    flags |= _extra_flags(orientation, velocity, coalesced)
    dim = len(target)
    data = _target_struct(dim).pack(VERSION, KIND_TARGET, flags, dim, seq, model_version,
                                    section, progress, eta, status, *target)
    if flags & 0x70:
        data += _extras(flags, orientation, velocity, coalesced)
    return data


def decode_target(data: bytes) -> Target:
    """A binary target; WireError when it cannot be read."""
    flags, dim, seq = _check_header(data, KIND_TARGET)
    s = _target_struct(dim)
    if len(data) < s.size:
        raise WireError("bad_payload", f"expected {s.size} bytes for this target, got {len(data)}")
    values = s.unpack_from(data)
    version, section, progress, eta, code = values[5:10]
    message = None
    at = s.size
    if flags & TARGET_MESSAGE:
        (n,) = _U16.unpack_from(data, at)
        message = bytes(data[at + 2 : at + 2 + n]).decode("utf-8", "replace")
        at += 2 + n
    orientation = velocity = None
    coalesced = 0
    try:
        if flags & TARGET_ORIENTATION:
            orientation = _QUAT.unpack_from(data, at)
            at += _QUAT.size
        if flags & TARGET_VELOCITY:
            velocity = struct.unpack_from(f"<{dim}d", data, at)
            at += 8 * dim
        if flags & TARGET_COALESCED:
            (coalesced,) = _U32.unpack_from(data, at)
    except struct.error:
        raise WireError("bad_payload", "expected the target's optional fields, got fewer bytes"
                        ) from None
    return Target(
        seq=seq if flags & TARGET_SEQ else None,
        status=STATUS_KEYS.get(code, f"code_{code}"),
        target=tuple(values[10:]) if dim else None,
        progress=progress,
        eta=None if math.isnan(eta) else eta,
        section=None if section < 0 else section,
        inside=bool(flags & TARGET_INSIDE),
        done=bool(flags & TARGET_DONE),
        model_version=None if version < 0 else version,
        message=message,
        orientation=orientation,  # type: ignore[arg-type]
        velocity=velocity,
        coalesced=coalesced,
    )


# ---- JSON ---------------------------------------------------------------------------------------


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


def _numbers(value: Any, field: str, n: int | None = None) -> tuple[float, ...]:
    if not isinstance(value, list) or (n is not None and len(value) != n):
        raise WireError("bad_payload", f"expected {field} as a list of {n or 'D'} numbers")
    for v in value:
        if type(v) is not float and type(v) is not int:
            raise WireError("bad_payload", f"expected numbers in {field}, got {v!r}")
    return tuple(float(v) for v in value)


_loads = orjson.loads
_JSONDecodeError = orjson.JSONDecodeError
_new = object.__new__
_set_seq, _set_position, _set_orientation, _set_t, _set_restart = (
    Pose.__dict__[name].__set__ for name in ("seq", "position", "orientation", "t", "restart"))


def _plain_pose(seq: int, position: tuple[float, ...]) -> Pose:
    """``Pose(seq, position)`` without the frozen dataclass's ``__init__`` (its
    ``object.__setattr__`` per field costs 0.3 us a pose on the bridge's path)."""
    pose: Pose = _new(Pose)
    _set_seq(pose, seq)
    _set_position(pose, position)
    _set_orientation(pose, None)
    _set_t(pose, None)
    _set_restart(pose, False)
    return pose


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
                if _isfinite(sum(position)):
                    return _plain_pose(seq, tuple(position))
    return _checked_pose_json(body)


def _checked_pose_json(body: Any) -> Pose:
    """A decoded JSON pose, every field checked."""
    if not isinstance(body, dict):
        raise WireError("bad_payload", "expected a JSON object")
    seq = body.get("seq")
    if type(seq) is not int or not 0 <= seq <= SEQ_MAX:
        raise WireError("bad_payload", "expected 'seq', an integer in [0, 2**64)")
    if "position" not in body:
        raise WireError("bad_payload", "expected 'position'")
    position = _numbers(body["position"], "position")
    if not 1 <= len(position) <= MAX_DIM:
        raise WireError("bad_payload", f"expected 1..{MAX_DIM} coordinates in 'position'")
    raw_orientation = body.get("orientation")
    orientation: tuple[float, float, float, float] | None = None
    if raw_orientation is not None:
        qx, qy, qz, qw = _numbers(raw_orientation, "orientation", 4)
        orientation = (qx, qy, qz, qw)
    t = body.get("t")
    if t is not None and type(t) is not float and type(t) is not int:
        raise WireError("bad_payload", "expected 't' as a number of seconds")
    if not _all_finite(position) or (orientation is not None and not _all_finite(orientation)) or (
            t is not None and not _isfinite(t)):
        raise WireError("non_finite", "expected finite numbers, got NaN or infinity")
    return Pose(seq, position, orientation, None if t is None else float(t),
                bool(body.get("restart", False)))


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
    return orjson.dumps(body)


_NUMPY = orjson.OPT_SERIALIZE_NUMPY


def pack_target_json(seq: int, status: str, target: Any, progress: float, eta: float,
                     section: int, inside: bool, done: bool, model_version: int,
                     orientation: Any = None, velocity: Any = None, coalesced: int = 0) -> bytes:
    """Fast path for the bridge (see :func:`pack_target`); numpy arrays are fine."""
    body = {
        "v": VERSION, "seq": seq, "status": status, "target": target, "progress": progress,
        "eta": eta, "section": section, "inside": inside, "done": done,
        "model_version": model_version, "message": None, "orientation": orientation,
        "coalesced": coalesced,
    }
    if velocity is not None:
        body["velocity"] = velocity
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
        )
    except (TypeError, ValueError) as exc:
        raise WireError("bad_payload", f"expected a JSON target: {exc}") from None


# ---- ROS 2 CDR: geometry_msgs/msg/PoseStamped ---------------------------------------------------

_CDR_HEAD = {0x00: ">", 0x01: "<"}  # encapsulation id (second byte): CDR_BE, CDR_LE
_CDR_MAX_FRAME = 4096


@dataclass(frozen=True, slots=True)
class RosStamp:
    """What a CDR PoseStamped's answer carries over: header stamp, frame_id, byte order."""

    sec: int
    nanosec: int
    frame_id: str
    little: bool = True


def is_cdr(encoding: str, data: bytes) -> bool:
    """Whether a payload is CDR: the Zenoh encoding says so, or (default or octet-stream
    encoding) it starts with a CDR encapsulation header, which no binary pose does."""
    if encoding.startswith(CDR_ENCODING):
        return True
    return (len(data) >= 4 and data[0] == 0 and data[1] in _CDR_HEAD
            and encoding.startswith(("zenoh/bytes", BINARY_ENCODING)))


def decode_pose_cdr(data: bytes, seq: int = 0) -> tuple[Pose, RosStamp]:
    """A CDR ``geometry_msgs/msg/PoseStamped`` as a pose (3-D position, orientation, the
    stamp as ``t``) and its header; WireError (bad_payload, non_finite) when it is not one."""
    if len(data) < 4 or data[0] != 0 or data[1] not in _CDR_HEAD:
        raise WireError("bad_payload", "expected a CDR encapsulation header (00 01 or 00 00), "
                        f"got {bytes(data[:2]).hex(' ') or 'nothing'}")
    order = _CDR_HEAD[data[1]]
    body = memoryview(data)[4:]
    try:
        sec, nanosec, n = struct.unpack_from(order + "iII", body, 0)
        if n == 0 or n > _CDR_MAX_FRAME:
            raise WireError("bad_payload", f"expected a frame_id of 1..{_CDR_MAX_FRAME} bytes "
                            f"with its NUL, got length {n}")
        end = 12 + n
        frame_id = bytes(body[12 : end - 1]).decode("utf-8")
        at = (end + 7) & ~7
        values = struct.unpack_from(order + "7d", body, at)
    except (struct.error, UnicodeDecodeError):
        raise WireError("bad_payload", "expected a geometry_msgs/msg/PoseStamped in CDR, "
                        f"got {len(data)} bytes that are not one") from None
    if len(body) - (at + 56) > 7:
        raise WireError("bad_payload", "expected a geometry_msgs/msg/PoseStamped in CDR, "
                        f"got {len(body) - (at + 56)} bytes too many")
    if not _all_finite(values):
        raise WireError("non_finite", "expected finite numbers, got NaN or infinity")
    pose = Pose(seq, values[:3], values[3:], sec + nanosec * 1e-9)  # type: ignore[arg-type]
    return pose, RosStamp(sec, nanosec, frame_id, order == "<")


def encode_pose_stamped_cdr(stamp: RosStamp, position: Any, orientation: Any) -> bytes:
    """A CDR ``geometry_msgs/msg/PoseStamped`` (the bridge's answer on ``.../target``)."""
    order = "<" if stamp.little else ">"
    frame = stamp.frame_id.encode("utf-8") + b"\x00"
    end = 12 + len(frame)
    pad = ((end + 7) & ~7) - end
    x, y, z = (float(v) for v in position) if len(position) == 3 else (
        float(position[0]), float(position[1]), 0.0)
    qx, qy, qz, qw = orientation if orientation is not None else (0.0, 0.0, 0.0, 1.0)
    return (bytes((0, 1 if stamp.little else 0, 0, 0))
            + struct.pack(order + "iII", stamp.sec, stamp.nanosec, len(frame)) + frame
            + b"\x00" * pad + struct.pack(order + "7d", x, y, z, qx, qy, qz, qw))


# ---- either -------------------------------------------------------------------------------------


def is_json(encoding: str, data: bytes) -> bool:
    """Whether a payload with this Zenoh encoding (its string form) is JSON."""
    if encoding.startswith(("application/json", "text/json")):
        return True
    return encoding.startswith("zenoh/bytes") and data[:1] == b"{"


def decode_any_target(encoding: str, data: bytes) -> Target:
    """A target in either encoding, chosen by the sample's encoding string."""
    return decode_target_json(data) if is_json(encoding, data) else decode_target(data)


def decode_any_pose(encoding: str, data: bytes) -> Pose:
    """A pose in either encoding, chosen by the sample's encoding string."""
    return decode_pose_json(data) if is_json(encoding, data) else decode_pose(data)


# ---- recording batches: bridge -> the service's live recorder ----------------------------------
#
# Every ``interval`` (0.1 s by default) a bridge puts one message on
# ``{prefix}/@recorder/live/{bridge}`` (:func:`canal_protocol.keys.recorder_key`): what each
# stream kept for the recording since its last batch, as columns (no per-row parsing on the
# recorder's side), and the stream's count deltas. Binary, version 2, little-endian:
#
# ====== ============ =========================================================================
# offset type         field
# ====== ============ =========================================================================
# 0      3 bytes      magic ``CRB`` (a version 1 batch was a JSON object: it starts with ``{``)
# 3      uint8        version (2)
# 4      uint32       header length H
# 8      H bytes      header, JSON: ``{"bridge": str, "n": int, "streams": [[skill, robot,
#                     poses, answered, coalesced, errors, decimated, rows, dim], ...]}``
# 8+H    ...          each stream's columns in header order, ``rows`` = M entries each:
#                     ``t_ns`` int64[M], ``position`` float64[M*dim], ``orientation``
#                     float64[M*4], ``target`` float64[M*dim], ``target_orientation``
#                     float64[M*4], ``progress`` float64[M], ``eta`` float64[M], ``section``
#                     int32[M], ``flags`` uint8[M], ``status`` uint8[M] (:data:`STATUS_CODES`)
# ====== ============ =========================================================================
#
# ``flags``: :data:`RECORD_ORIENTATION` (the pose had an orientation), :data:`RECORD_TARGET_
# ORIENTATION`, :data:`RECORD_INSIDE`, :data:`RECORD_DONE`; a missing orientation is sent as
# the identity with its flag clear. ``n`` counts the bridge's batches from 0 (a gap is a lost
# batch). The counts are *deltas* since the stream's previous batch: ``poses`` received
# (coalesced included), ``answered`` (ok or outside_canal), ``coalesced``, ``errors``
# (answered with an error status) and ``decimated`` (not kept for the recording). Each row is
# one kept pose and its target, so ``poses == rows + decimated`` in every batch. The message
# is exactly as long as its header says: anything else is refused whole.

RECORD_BATCH_MAGIC = b"CRB"
RECORD_BATCH_VERSION = 2
RECORD_ROW_FIELDS = 11
RECORD_ORIENTATION = 0x01
RECORD_TARGET_ORIENTATION = 0x02
RECORD_INSIDE = 0x04
RECORD_DONE = 0x08
_RECORD_PREFIX = struct.Struct("<3sBI")
_IDENTITY_Q = (0.0, 0.0, 0.0, 1.0)
_NAN = float("nan")
_SWAP = sys.byteorder != "little"


@dataclass(frozen=True, slots=True)
class RecordRow:
    """One pose the bridge kept for the recording, with the target it answered."""

    t_ns: int
    position: tuple[float, ...]
    orientation: tuple[float, ...] | None
    target: tuple[float, ...]
    target_orientation: tuple[float, ...] | None
    progress: float
    eta: float
    section: int
    inside: bool
    done: bool
    status: str


@dataclass(frozen=True, slots=True)
class RecordStream:
    """One stream's part of a batch: its count deltas and its kept rows, as columns.

    Columns are :class:`array.array` (native byte order; ``numpy.frombuffer`` reads them
    without a copy): ``position`` and ``target`` hold ``dim`` values per row, the
    orientations 4 (identity where ``flags`` says there was none).
    """

    skill: str
    robot: str
    poses: int
    answered: int
    coalesced: int
    errors: int
    decimated: int
    dim: int
    t_ns: array[int]
    position: array[float]
    orientation: array[float]
    target: array[float]
    target_orientation: array[float]
    progress: array[float]
    eta: array[float]
    section: array[int]
    flags: bytes
    status: bytes

    def __len__(self) -> int:
        return len(self.t_ns)

    @property
    def rows(self) -> tuple[RecordRow, ...]:
        """The columns as rows (tests, debugging: the recorder reads the columns)."""
        d = self.dim
        out = []
        for i, t in enumerate(self.t_ns):
            f = self.flags[i]
            out.append(RecordRow(
                t, tuple(self.position[i * d:(i + 1) * d]),
                tuple(self.orientation[4 * i:4 * i + 4]) if f & RECORD_ORIENTATION else None,
                tuple(self.target[i * d:(i + 1) * d]),
                tuple(self.target_orientation[4 * i:4 * i + 4])
                if f & RECORD_TARGET_ORIENTATION else None,
                self.progress[i], self.eta[i], self.section[i], bool(f & RECORD_INSIDE),
                bool(f & RECORD_DONE), STATUS_KEYS[self.status[i]]))
        return tuple(out)


@dataclass(frozen=True, slots=True)
class RecordBatch:
    """What one bridge hands the recorder in one message."""

    bridge: str
    n: int
    streams: tuple[RecordStream, ...]


def _column(typecode: str, values: Any) -> bytes:
    col = array(typecode, values)
    if _SWAP:
        col.byteswap()
    return col.tobytes()


def _vectors(values: tuple[Any, ...], dim: int, field: str) -> bytes:
    flat = array("d", chain.from_iterable(values))
    if len(flat) != dim * len(values):
        raise WireError("bad_payload", f"expected every {field} of a stream with {dim} values")
    if _SWAP:
        flat.byteswap()
    return flat.tobytes()


def _quaternions(values: tuple[Any, ...]) -> bytes:
    return _column("d", chain.from_iterable(_IDENTITY_Q if q is None else q for q in values))


def encode_record_batch(bridge: str, n: int, streams: list[tuple[Any, ...]]) -> bytes:
    """A recording batch (binary, version 2); ``streams`` holds ``(skill, robot, poses,
    answered, coalesced, errors, decimated, rows)`` with rows as tuples ``(t_ns, position,
    orientation|None, target, target_orientation|None, progress, eta, section, inside,
    done, status)``. A stream's positions and targets share one dimension."""
    heads: list[list[Any]] = []
    body: list[bytes] = []
    for skill, robot, poses, answered, coalesced, errors, decimated, rows in streams:
        m = len(rows)
        dim = len(rows[0][1]) if m else 0
        heads.append([skill, robot, poses, answered, coalesced, errors, decimated, m, dim])
        if not m:
            continue
        cols = tuple(zip(*rows, strict=True))
        if len(cols) != RECORD_ROW_FIELDS:
            raise WireError("bad_payload", f"expected rows of {RECORD_ROW_FIELDS} fields")
        t, pos, q, target, tq, progress, eta, section, inside, done, status = cols
        body += [
            _column("q", t), _vectors(pos, dim, "position"), _quaternions(q),
            _vectors(target, dim, "target"), _quaternions(tq),
            _column("d", [_NAN if v is None else v for v in progress]),
            _column("d", [_NAN if v is None else v for v in eta]), _column("i", section),
            bytes([(RECORD_ORIENTATION if a is not None else 0)
                   | (RECORD_TARGET_ORIENTATION if b is not None else 0)
                   | (RECORD_INSIDE if c else 0) | (RECORD_DONE if d else 0)
                   for a, b, c, d in zip(q, tq, inside, done, strict=True)]),
            bytes([STATUS_CODES[s] for s in status])]
    header = orjson.dumps({"bridge": bridge, "n": n, "streams": heads})
    return b"".join([_RECORD_PREFIX.pack(RECORD_BATCH_MAGIC, RECORD_BATCH_VERSION, len(header)),
                     header, *body])


def _count(value: Any, name: str) -> int:
    if not isinstance(value, int) or isinstance(value, bool) or value < 0:
        raise WireError("bad_payload", f"expected {name} as an integer >= 0, got {value!r}")
    return value


def _take(data: memoryview, at: int, typecode: str, count: int) -> tuple[array[Any], int]:
    col: array[Any] = array(typecode)
    end = at + col.itemsize * count
    if end > len(data):
        raise WireError("bad_payload", "expected the columns the header announces: "
                        f"the batch ends at byte {len(data)}")
    col.frombytes(data[at:end])
    if _SWAP:
        col.byteswap()
    return col, end


_STREAM_COUNTS = ("poses", "answered", "coalesced", "errors", "decimated", "rows", "dim")


def decode_record_batch(data: bytes) -> RecordBatch:
    """A recording batch; WireError (``bad_payload``) when it is not a whole version 2 batch
    (a bridge of another Canal version is named as such)."""
    if data[:1] == b"{":
        raise WireError("bad_payload", "expected a binary recording batch of version "
                        f"{RECORD_BATCH_VERSION}, got a JSON (version 1) batch: the bridge "
                        "runs an older Canal than the service")
    if len(data) < _RECORD_PREFIX.size:
        raise WireError("bad_payload", "expected a recording batch, got "
                        f"{len(data)} bytes")
    magic, version, size = _RECORD_PREFIX.unpack_from(data)
    if magic != RECORD_BATCH_MAGIC:
        raise WireError("bad_payload", f"expected a recording batch (magic {RECORD_BATCH_MAGIC!r}),"
                        f" got {magic!r}")
    if version != RECORD_BATCH_VERSION:
        raise WireError("bad_payload", f"expected a recording batch of version "
                        f"{RECORD_BATCH_VERSION}, got version {version}: the bridge and the "
                        "service run different Canal versions")
    at = _RECORD_PREFIX.size + size
    try:
        body = orjson.loads(data[_RECORD_PREFIX.size:at])
    except orjson.JSONDecodeError as exc:
        raise WireError("bad_payload", f"expected a JSON batch header: {exc}") from None
    if not isinstance(body, dict):
        raise WireError("bad_payload", "expected the batch header as an object")
    bridge, streams = body.get("bridge"), body.get("streams")
    if not isinstance(bridge, str) or not isinstance(streams, list):
        raise WireError("bad_payload", "expected 'bridge' (string) and 'streams' (list)")
    n = _count(body.get("n"), "n")
    view = memoryview(data)
    out = []
    for head in streams:
        if not isinstance(head, list) or len(head) != 2 + len(_STREAM_COUNTS):
            raise WireError("bad_payload", "expected each stream as [skill, robot, poses, "
                            "answered, coalesced, errors, decimated, rows, dim]")
        skill, robot = head[0], head[1]
        if not (isinstance(skill, str) and is_plain_chunk(skill) and isinstance(robot, str)
                and is_plain_chunk(robot)):
            raise WireError("bad_payload", "expected plain skill and robot names")
        poses, answered, coalesced, errors, decimated, m, dim = (
            _count(v, k) for v, k in zip(head[2:], _STREAM_COUNTS, strict=True))
        if m and not 1 <= dim <= MAX_DIM:
            raise WireError("bad_payload", f"expected dim in 1..{MAX_DIM}, got {dim}")
        t, at = _take(view, at, "q", m)
        pos, at = _take(view, at, "d", m * dim)
        q, at = _take(view, at, "d", m * 4)
        target, at = _take(view, at, "d", m * dim)
        tq, at = _take(view, at, "d", m * 4)
        progress, at = _take(view, at, "d", m)
        eta, at = _take(view, at, "d", m)
        section, at = _take(view, at, "i", m)
        flags, at = _take(view, at, "B", m)
        status, at = _take(view, at, "B", m)
        if any(code not in STATUS_KEYS for code in set(status)):
            raise WireError("bad_payload", "expected known status codes in the rows")
        out.append(RecordStream(skill, robot, poses, answered, coalesced, errors, decimated,
                                dim, t, pos, q, target, tq, progress, eta, section,
                                flags.tobytes(), status.tobytes()))
    if at != len(data):
        raise WireError("bad_payload", f"expected {at} bytes as the header announces, got "
                        f"{len(data)}")
    return RecordBatch(bridge, n, tuple(out))


__all__ = [
    "BINARY_ENCODING",
    "CDR_ENCODING",
    "FORMAT_BINARY",
    "FORMAT_CDR",
    "FORMAT_JSON",
    "JSON_ENCODING",
    "RECORD_BATCH_VERSION",
    "STATUS_CODES",
    "STATUS_KEYS",
    "VERSION",
    "Keys",
    "Pose",
    "RecordBatch",
    "RecordRow",
    "RecordStream",
    "RosStamp",
    "Target",
    "WireError",
    "check_chunk",
    "decode_any_pose",
    "decode_any_target",
    "decode_pose",
    "decode_pose_cdr",
    "decode_pose_json",
    "decode_record_batch",
    "decode_target",
    "decode_target_json",
    "encode_pose",
    "encode_pose_json",
    "encode_pose_stamped_cdr",
    "encode_record_batch",
    "encode_target",
    "is_cdr",
    "is_json",
    "is_plain_chunk",
    "keys",
    "model_key",
    "pack_target",
    "pack_target_json",
    "pose_wildcard",
    "stream_of",
    "target_json",
]
