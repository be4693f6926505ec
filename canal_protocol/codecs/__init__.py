"""The live codecs: a pose or target in binary, JSON or ROS 2 CDR, and the one rule that
says which a payload is.

:func:`pose_format` is the only format detection: the bridge (every pose it receives), the
client (every target) and the MCAP upload path (a pose topic's message encoding) ask it, and
:func:`decode_pose_as` / :func:`decode_target_by_encoding` decode by its answer. The layouts
are described in :mod:`canal_protocol.wire`, the module robots import.
"""

from __future__ import annotations

from .binary import (
    HEADER,
    decode_pose,
    decode_target,
    encode_pose,
    encode_target,
    pack_target,
)
from .cdr import RosStamp, decode_pose_cdr, encode_pose_stamped_cdr, pose_stamped_columns
from .json import (
    decode_pose_json,
    decode_target_json,
    encode_pose_json,
    pack_target_json,
    target_json,
)
from .messages import (
    BINARY_ENCODING,
    CDR_ENCODING,
    FORMAT_BINARY,
    FORMAT_CDR,
    FORMAT_JSON,
    JSON_ENCODING,
    KIND_POSE,
    NO_ROUTE,
    POSE_RESTART,
    Pose,
    Target,
    WireError,
)
from .steer import decode_steer, encode_steer, encode_steer_cdr, encode_steer_json

__all__ = [
    "BINARY_ENCODING",
    "CDR_ENCODING",
    "FORMAT_BINARY",
    "FORMAT_CDR",
    "FORMAT_JSON",
    "JSON_ENCODING",
    "NO_ROUTE",
    "Pose",
    "RosStamp",
    "Target",
    "WireError",
    "asks_restart",
    "decode_pose",
    "decode_pose_as",
    "decode_pose_by_encoding",
    "decode_pose_cdr",
    "decode_pose_json",
    "decode_steer",
    "decode_target",
    "decode_target_by_encoding",
    "decode_target_json",
    "encode_pose",
    "encode_pose_json",
    "encode_pose_stamped_cdr",
    "encode_steer",
    "encode_steer_cdr",
    "encode_steer_json",
    "encode_target",
    "pack_target",
    "pack_target_json",
    "pose_format",
    "pose_stamped_columns",
    "target_json",
]

_JSON_PREFIXES = (JSON_ENCODING, "text/json")
#: What MCAP calls the same encodings (a channel's ``message_encoding``).
_MCAP_JSON, _MCAP_CDR = "json", "cdr"


def pose_format(encoding: str, data: bytes) -> int:
    """Which codec reads a payload: :data:`FORMAT_JSON`, :data:`FORMAT_BINARY` or
    :data:`FORMAT_CDR`.

    ``encoding`` is a Zenoh encoding's string form or an MCAP channel's message encoding.
    JSON and CDR encodings say so; a default-encoded (``zenoh/bytes``) payload starting with
    ``{`` is JSON; any other payload starting with a zero byte is CDR (its encapsulation
    header: a binary message starts with its version, 1); the rest is binary.
    """
    if encoding.startswith(_JSON_PREFIXES) or encoding == _MCAP_JSON:
        return FORMAT_JSON
    if encoding.startswith(CDR_ENCODING) or encoding == _MCAP_CDR:
        return FORMAT_CDR
    first = data[:1]
    if first == b"{" and encoding.startswith("zenoh/bytes"):
        return FORMAT_JSON
    if first == b"\x00":
        return FORMAT_CDR
    return FORMAT_BINARY


def asks_restart(fmt: int, data: bytes) -> bool:
    """Whether a pose in format ``fmt`` carries the restart flag, as decoding it would say
    (only a payload whose header or text names the flag is decoded); False for a payload that
    is no pose.

    The live path coalesces a stream's backlog to its newest pose without decoding the
    others; a restart among them must survive, or the newest pose is judged against the
    run the robot has left.
    """
    if fmt == FORMAT_BINARY:
        if len(data) < HEADER.size or data[1] != KIND_POSE or not data[2] & POSE_RESTART:
            return False
        try:  # flagged: a pose only if the whole of it reads
            return decode_pose(data).restart
        except WireError:
            return False
    if fmt == FORMAT_JSON:
        # the key may be written with escapes ("\\u0072estart"), which the decoder reads
        if b"restart" not in data and b"\\" not in data:
            return False
        try:
            return decode_pose_json(data).restart
        except WireError:
            return False
    return False  # a ROS 2 PoseStamped has no restart flag


def decode_pose_as(fmt: int, data: bytes, seq: int = 0) -> tuple[Pose, RosStamp | None]:
    """A pose in format ``fmt`` (:func:`pose_format`), and its ROS header when it is CDR
    (which has no seq: ``seq`` numbers it). Raises :class:`WireError`."""
    if fmt == FORMAT_JSON:
        return decode_pose_json(data), None
    if fmt == FORMAT_CDR:
        return decode_pose_cdr(data, seq)
    return decode_pose(data), None


def decode_pose_by_encoding(encoding: str, data: bytes, seq: int = 0
                            ) -> tuple[int, Pose, RosStamp | None]:
    """A pose whichever codec it is in: its format, the pose and its ROS header (CDR)."""
    fmt = pose_format(encoding, data)
    pose, stamp = decode_pose_as(fmt, data, seq)
    return fmt, pose, stamp


def decode_target_by_encoding(encoding: str, data: bytes) -> Target:
    """A target in JSON or binary, as :func:`pose_format` tells them apart."""
    fmt = pose_format(encoding, data)
    if fmt == FORMAT_JSON:
        return decode_target_json(data)
    if fmt == FORMAT_CDR:
        raise WireError("bad_payload", "expected a Canal target, got a CDR message (a ROS "
                        "robot's answer is a PoseStamped: decode_pose_cdr reads it)")
    return decode_target(data)
