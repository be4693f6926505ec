"""What the live codecs carry: the pose and target messages, status codes and encodings.

Shared by :mod:`canal_protocol.codecs.binary`, :mod:`~canal_protocol.codecs.json` and
:mod:`~canal_protocol.codecs.cdr`; the layouts are described in :mod:`canal_protocol.wire`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

VERSION = 1
KIND_POSE = 1
KIND_TARGET = 2
MAX_DIM = 16
#: Largest live pose payload the bridge reads: a pose is a few hundred bytes (a PoseStamped
#: with a long frame_id a few more); a larger one is refused before it is parsed.
MAX_POSE_BYTES = 4096

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
TARGET_ROUTE = 0x80
#: The answer's route for a model of one route: none (no "route" key, no flag 0x80).
NO_ROUTE = -1

SEQ_MAX = 2**64 - 1

STATUS_CODES: dict[str, int] = {
    "ok": 0,
    "outside_canal": 1,
    # obstacles (the skill's scene): the target goes around one, holds the robot before a
    # section they close, or backs the robot out of one
    "detour": 2,
    "blocked": 3,
    "in_obstacle": 4,
    "bad_payload": 16,
    "wrong_dimension": 17,
    "non_finite": 18,
    "unknown_skill": 19,
    "no_model": 20,
    "internal_error": 21,
    "too_many_streams": 22,
    "restart_pending": 23,
}
STATUS_KEYS: dict[int, str] = {code: key for key, code in STATUS_CODES.items()}
USABLE = frozenset({"ok", "outside_canal", "detour", "blocked", "in_obstacle"})

JSON_ENCODING = "application/json"
BINARY_ENCODING = "application/octet-stream"
CDR_ENCODING = "application/cdr"

FORMAT_JSON = 0
FORMAT_BINARY = 1
FORMAT_CDR = 2


class WireError(ValueError):
    """A message that cannot be read; ``key`` is the status key to answer with, ``seq`` the
    seq of the pose refused when it could be read (a binary pose's header, a JSON pose's
    ``seq``), else None: the answer then carries it, so the robot knows which pose it was."""

    def __init__(self, key: str, message: str, seq: int | None = None) -> None:
        super().__init__(message)
        self.key = key
        self.message = message
        self.seq = seq





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
    #: The route of a model of several routes the stream follows; None: the model has one
    #: route, or the stream follows the canal of all.
    route: int | None = None

    @property
    def usable(self) -> bool:
        """Whether ``target`` can be moved to (status ok, outside_canal, or an obstacle's:
        detour, blocked (hold), in_obstacle (back away))."""
        return self.status in USABLE


_isfinite = math.isfinite

#: Largest absolute coordinate of a live pose: the canal computes with squares and products
#: of coordinates, which must stay far from float64 overflow (canal_core.preprocess's bound
#: on every demonstration; a test keeps the two equal).
MAX_COORDINATE = 1e15
#: Largest absolute pose time, seconds (~3,000 years: epoch seconds fit, nanoseconds not).
MAX_TIME = 1e11
#: Largest | |q| - 1 | of a pose's orientation (canal_core.validation's, what REST accepts).
QUATERNION_NORM_TOLERANCE = 1e-3


def check_pose_numbers(position: Any, orientation: Any, t: Any) -> None:
    """WireError (``bad_payload``, naming the field, what was expected and what came) unless
    every coordinate of ``position`` is within :data:`MAX_COORDINATE`, ``orientation`` (or
    None) is a unit quaternion within :data:`QUATERNION_NORM_TOLERANCE` and ``t`` (or None)
    within :data:`MAX_TIME`. The numbers are already known to be finite."""
    if not (-MAX_COORDINATE <= min(position) and max(position) <= MAX_COORDINATE):
        i = next(i for i, v in enumerate(position) if not abs(v) <= MAX_COORDINATE)
        raise WireError("bad_payload", f"expected position coordinates within "
                        f"+-{MAX_COORDINATE:g}, got {float(position[i])!r} at position[{i}]")
    if orientation is not None:
        norm = math.hypot(*orientation)
        if not abs(norm - 1.0) <= QUATERNION_NORM_TOLERANCE:
            raise WireError("bad_payload", "expected orientation as a unit quaternion [qx, qy, "
                            f"qz, qw] (norm 1 +- {QUATERNION_NORM_TOLERANCE:g}), got norm "
                            f"{norm:.6g}")
    if t is not None and not abs(t) <= MAX_TIME:
        raise WireError("bad_payload", f"expected t in seconds, within +-{MAX_TIME:g}, got "
                        f"{t:.6g} (a live pose's t is in seconds, not nanoseconds)")


def all_finite(values: Any) -> bool:
    """Whether every number of ``values`` is finite."""
    for v in values:
        if not _isfinite(v):
            return False
    return True


_new = object.__new__
_set_seq, _set_position, _set_orientation, _set_t, _set_restart = (
    Pose.__dict__[name].__set__ for name in ("seq", "position", "orientation", "t", "restart"))


def plain_pose(seq: int, position: tuple[float, ...]) -> Pose:
    """``Pose(seq, position)`` without the frozen dataclass's ``__init__`` (its
    ``object.__setattr__`` per field costs 0.3 us a pose on the bridge's path)."""
    pose: Pose = _new(Pose)
    _set_seq(pose, seq)
    _set_position(pose, position)
    _set_orientation(pose, None)
    _set_t(pose, None)
    _set_restart(pose, False)
    return pose
