"""The binary layout of poses and targets (version 1, little-endian; see :mod:`canal_protocol.wire`)."""

from __future__ import annotations

import math
import struct
from typing import Any

from .messages import (
    KIND_POSE,
    KIND_TARGET,
    MAX_COORDINATE,
    MAX_DIM,
    NO_ROUTE,
    POSE_ORIENTATION,
    POSE_RESTART,
    POSE_TIME,
    STATUS_CODES,
    STATUS_KEYS,
    TARGET_COALESCED,
    TARGET_DONE,
    TARGET_INSIDE,
    TARGET_MESSAGE,
    TARGET_ORIENTATION,
    TARGET_ROUTE,
    TARGET_SEQ,
    TARGET_VELOCITY,
    VERSION,
    Pose,
    Target,
    WireError,
    all_finite,
    check_pose_numbers,
    plain_pose,
)

HEADER = struct.Struct("<BBBBQ")
TARGET_BODY = struct.Struct("<iiddH")
_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_QUAT = struct.Struct("<4d")

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
_hypot = math.hypot


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


_POSE_FLAGS = POSE_ORIENTATION | POSE_TIME | POSE_RESTART


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
    """A binary pose; WireError (bad_payload, non_finite) when it cannot be used, with the
    pose's seq once its header was read."""
    flags, dim, seq = _check_header(data, KIND_POSE)
    try:
        if not 1 <= dim <= MAX_DIM:
            raise WireError("bad_payload", f"expected a dimension in 1..{MAX_DIM}, got {dim}")
        if flags & ~_POSE_FLAGS:  # a flag this reader does not know would be obeyed by none
            raise WireError("bad_payload", f"expected pose flags within 0x{_POSE_FLAGS:02x} "
                                           f"(orientation, time, restart), got 0x{flags:02x}")
        s = _pose_struct(dim, flags)
        if len(data) != s.size:
            raise WireError("bad_payload",
                            f"expected {s.size} bytes for this pose, got {len(data)}")
        values = s.unpack(data)
        position = values[5 : 5 + dim]
        # the common pose in one test: a norm within the bound means finite coordinates
        # within it (NaN and infinity give NaN or infinity)
        if not flags and _hypot(*position) <= MAX_COORDINATE:
            return plain_pose(seq, position)
        orientation = values[5 + dim : 9 + dim] if flags & POSE_ORIENTATION else None
        t = values[-1] if flags & POSE_TIME else None
        # a finite sum means finite numbers; one that overflows takes the check one by one
        if not _isfinite(sum(values[5:])) and not all_finite(values[5:]):
            raise WireError("non_finite", "expected finite numbers, got NaN or infinity")
        check_pose_numbers(position, orientation, t)
    except WireError as exc:
        exc.seq = seq  # the header was read: the answer says which pose it refuses
        raise
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
    route = NO_ROUTE if answer.route is None else answer.route
    flags |= _extra_flags(answer.orientation, answer.velocity, answer.coalesced, route)
    data = _target_struct(dim).pack(
        VERSION, KIND_TARGET, flags, dim, 0 if answer.seq is None else answer.seq,
        -1 if answer.model_version is None else answer.model_version,
        -1 if answer.section is None else answer.section, answer.progress,
        math.nan if answer.eta is None else answer.eta, STATUS_CODES[answer.status], *position)
    if message:
        data += _U16.pack(len(message)) + message
    return data + _extras(flags, answer.orientation, answer.velocity, answer.coalesced, route)


def _extra_flags(orientation: Any, velocity: Any, coalesced: int, route: int = NO_ROUTE) -> int:
    return ((TARGET_ORIENTATION if orientation is not None else 0)
            | (TARGET_VELOCITY if velocity is not None else 0)
            | (TARGET_COALESCED if coalesced else 0)
            | (TARGET_ROUTE if route >= 0 else 0))


_EXTRAS = TARGET_ORIENTATION | TARGET_VELOCITY | TARGET_COALESCED | TARGET_ROUTE


def _extras(flags: int, orientation: Any, velocity: Any, coalesced: int,
            route: int = NO_ROUTE) -> bytes:
    """The optional tail of a target (flags 0x10, 0x20, 0x40, 0x80), after the message."""
    if not flags & _EXTRAS:
        return b""
    tail = b""
    if flags & TARGET_ORIENTATION:
        tail += _QUAT.pack(*orientation)
    if flags & TARGET_VELOCITY:
        tail += struct.pack(f"<{len(velocity)}d", *velocity)
    if flags & TARGET_COALESCED:
        tail += _U32.pack(min(int(coalesced), 0xFFFFFFFF))
    if flags & TARGET_ROUTE:
        tail += _U16.pack(route)
    return tail


def pack_target(seq: int, status: int, target: Any, progress: float, eta: float, section: int,
                inside: bool, done: bool, model_version: int, orientation: Any = None,
                velocity: Any = None, coalesced: int = 0, route: int = NO_ROUTE) -> bytes:
    """Fast path for the bridge: a usable target, no message, ``target`` a (D,) sequence;
    ``route`` >= 0: the route of a model of several routes the stream follows."""
    flags = TARGET_SEQ | (TARGET_INSIDE if inside else 0) | (TARGET_DONE if done else 0)
    flags |= _extra_flags(orientation, velocity, coalesced, route)
    dim = len(target)
    data = _target_struct(dim).pack(VERSION, KIND_TARGET, flags, dim, seq, model_version,
                                    section, progress, eta, status, *target)
    if flags & _EXTRAS:
        data += _extras(flags, orientation, velocity, coalesced, route)
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
    route: int | None = None
    try:
        if flags & TARGET_ORIENTATION:
            orientation = _QUAT.unpack_from(data, at)
            at += _QUAT.size
        if flags & TARGET_VELOCITY:
            velocity = struct.unpack_from(f"<{dim}d", data, at)
            at += 8 * dim
        if flags & TARGET_COALESCED:
            (coalesced,) = _U32.unpack_from(data, at)
            at += _U32.size
        if flags & TARGET_ROUTE:
            (route,) = _U16.unpack_from(data, at)
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
        route=route,
    )
