"""ROS 2 ``geometry_msgs/msg/PoseStamped`` in CDR: the pose a ROS robot publishes, and the
answer the bridge sends it back (see :mod:`canal_protocol.wire`)."""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any

from .messages import Pose, WireError, all_finite

_CDR_HEAD = {0x00: ">", 0x01: "<"}  # encapsulation id (second byte): CDR_BE, CDR_LE
_CDR_MAX_FRAME = 4096


@dataclass(frozen=True, slots=True)
class RosStamp:
    """What a CDR PoseStamped's answer carries over: header stamp, frame_id, byte order."""

    sec: int
    nanosec: int
    frame_id: str
    little: bool = True


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
        frame = bytes(body[12:end])
        at = (end + 7) & ~7
        values = struct.unpack_from(order + "7d", body, at)
        # A CDR string is its bytes and one NUL. Cutting one that lacks it would answer the
        # robot in a frame its TF tree does not know.
        if frame.find(b"\x00") != n - 1:
            raise WireError("bad_payload", "expected a frame_id ending in NUL, with no NUL "
                            f"before it, got {frame[:64]!r}")
        frame_id = frame[:-1].decode("utf-8")
    except (struct.error, UnicodeDecodeError):
        raise WireError("bad_payload", "expected a geometry_msgs/msg/PoseStamped in CDR, "
                        f"got {len(data)} bytes that are not one") from None
    if nanosec >= 1_000_000_000:  # builtin_interfaces/msg/Time
        raise WireError("bad_payload", "expected header.stamp.nanosec in [0, 1000000000), "
                        f"got {nanosec}")
    if len(body) - (at + 56) > 7:
        raise WireError("bad_payload", "expected a geometry_msgs/msg/PoseStamped in CDR, "
                        f"got {len(body) - (at + 56)} bytes too many")
    if not all_finite(values):
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


def pose_stamped_columns(payloads: list[bytes]) -> tuple[Any, Any, Any] | None:
    """Many PoseStamped messages of one logger decoded in one numpy pass, or None when they
    do not share one little-endian layout (then :func:`decode_pose_cdr` reads each).

    A logger writes the same frame_id every time, so every message has the same length
    and layout: a 4-byte encapsulation header, then (offsets after it) stamp.sec int32 @0,
    stamp.nanosec uint32 @4, frame_id as uint32 length @8 and its bytes, then 7 float64
    (position, orientation) aligned to 8. numpy is imported here, not with the module:
    robots read single poses without it.

    Returns
    -------
    positions : array, shape (M, 3)
    orientations : array, shape (M, 4)
        [qx, qy, qz, qw] as written (not normalised, not checked finite).
    stamps : array of int64, shape (M,)
        Header stamps in nanoseconds (0 where the logger left them unset).
    """
    import numpy as np

    size = len(payloads[0]) if payloads else 0
    if size < 16 or any(len(m) != size for m in payloads):
        return None
    rows = np.frombuffer(b"".join(payloads), dtype=np.uint8).reshape(-1, size)
    if not ((rows[:, 0] == 0) & (rows[:, 1] == 1)).all():
        return None
    name_length = int.from_bytes(bytes(rows[0, 12:16]), "little")
    start = 4 + -(-(12 + name_length) // 8) * 8
    if start + 56 != size or not (rows[:, 12:16] == rows[0, 12:16]).all():
        return None
    values = np.ascontiguousarray(rows[:, start:start + 56]).view("<f8").astype(np.float64)
    sec = np.ascontiguousarray(rows[:, 4:8]).view("<i4").astype(np.int64).ravel()
    nsec = np.ascontiguousarray(rows[:, 8:12]).view("<u4").astype(np.int64).ravel()
    return values[:, :3], values[:, 3:7], sec * 1_000_000_000 + nsec
