"""A person's steering input (u, v in [-1, 1]) on ``{prefix}/{skill}/{robot}/steer``.

Three encodings, told apart as poses are (by the sample's encoding, then its first byte):

- JSON: ``{"u": 0.5, "v": -1.0}`` (``application/json``);
- binary (any other encoding): the 12-byte header of :mod:`.binary` with kind 3, dim 2 and
  the sender's sequence number, then ``<2d`` u, v;
- ROS 2 (``application/cdr``): ``geometry_msgs/msg/Vector3`` in CDR, u = x, v = y (z is
  ignored). Vector3 because it is the plain 2- or 3-axis value every ROS 2 stack has, needs
  no header (steering is latest-wins, not time-stamped) and a joystick node maps its axes
  onto it with one line; a Twist would suggest velocities the bridge does not take.

Values outside [-1, 1] are clipped (a joystick's calibration overshoots a little); NaN or
infinity is refused.
"""

from __future__ import annotations

import math
import struct

import orjson

from .binary import HEADER
from .messages import CDR_ENCODING, JSON_ENCODING, VERSION, WireError

KIND_STEER = 3
_BODY = struct.Struct("<2d")
_CDR = {0x00: struct.Struct(">3d"), 0x01: struct.Struct("<3d")}


def _clipped(u: float, v: float) -> tuple[float, float]:
    if not (math.isfinite(u) and math.isfinite(v)):
        raise WireError("non_finite", "expected finite u and v, got NaN or infinity")
    return max(-1.0, min(1.0, u)), max(-1.0, min(1.0, v))


def encode_steer(u: float, v: float, seq: int = 0) -> bytes:
    """The binary steering message."""
    return HEADER.pack(VERSION, KIND_STEER, 0, 2, seq) + _BODY.pack(float(u), float(v))


def encode_steer_json(u: float, v: float) -> bytes:
    """The JSON steering message."""
    return orjson.dumps({"u": float(u), "v": float(v)})


def encode_steer_cdr(u: float, v: float) -> bytes:
    """A little-endian CDR ``geometry_msgs/msg/Vector3`` (x = u, y = v, z = 0)."""
    return b"\x00\x01\x00\x00" + _CDR[0x01].pack(float(u), float(v), 0.0)


def decode_steer(encoding: str, data: bytes) -> tuple[float, float]:
    """(u, v) in [-1, 1] of a steering message; WireError when it is not one."""
    if encoding.startswith(JSON_ENCODING) or encoding.startswith("text/json") or data[:1] == b"{":
        try:
            body = orjson.loads(data)
        except orjson.JSONDecodeError:
            raise WireError("bad_payload", 'expected {"u": number, "v": number}, got invalid JSON') from None
        # Numbers only, and no other field: "0.9" or a misspelt key is a client's mistake to
        # be told of, as a pose's JSON tells it, not a value to guess.
        if not isinstance(body, dict) or set(body) != {"u", "v"}:
            got = (f"fields {', '.join(sorted(body)) or 'none'}" if isinstance(body, dict)
                   else f"a JSON {type(body).__name__}")
            raise WireError("bad_payload", f'expected {{"u": number, "v": number}}, got {got}')
        for name in ("u", "v"):
            if type(body[name]) not in (int, float):
                raise WireError("bad_payload", f"expected {name} as a number, got {type(body[name]).__name__}")
        return _clipped(float(body["u"]), float(body["v"]))
    if encoding.startswith(CDR_ENCODING) or data[:1] == b"\x00":
        layout = _CDR.get(data[1]) if len(data) >= 28 else None
        if layout is None:
            raise WireError("bad_payload", "expected a geometry_msgs/msg/Vector3 in CDR "
                            f"(28 bytes), got {len(data)} bytes")
        x, y, _z = layout.unpack_from(data, 4)
        return _clipped(x, y)
    if len(data) != HEADER.size + _BODY.size:
        raise WireError("bad_payload", f"expected a {HEADER.size + _BODY.size}-byte binary "
                        f"steering message, got {len(data)} bytes")
    version, kind, _flags, dim, _seq = HEADER.unpack_from(data, 0)
    if version != VERSION or kind != KIND_STEER or dim != 2:
        raise WireError("bad_payload", f"expected version {VERSION}, kind {KIND_STEER}, dim 2, "
                        f"got {version}, {kind}, {dim}")
    u, v = _BODY.unpack_from(data, HEADER.size)
    return _clipped(u, v)


__all__ = ["KIND_STEER", "decode_steer", "encode_steer", "encode_steer_cdr", "encode_steer_json"]
