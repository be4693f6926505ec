"""The Zenoh key layout of Canal's live path, in one place (stdlib only).

Every key the bridge, the live recorder, the client and the simulated robot use is built or
parsed here. ``prefix`` defaults to ``canal``; ``skill`` and ``robot`` are single plain
chunks (no ``/``, ``*``, ``$``, ``?``, ``#``, and no leading ``@``)::

    {prefix}/{skill}/{robot}/pose          robot -> Canal   put, one pose per sample
    {prefix}/{skill}/{robot}/target        Canal -> robot   put, one answer per pose
    {prefix}/{skill}/{robot}/status        Canal -> robot   put, JSON status of a ROS 2 stream
    {prefix}/{skill}/model                 queryable: latest model, JSON
    {prefix}/{skill}/model/updated         bridge -> bridges: a fit landed ({"version": v})
    {prefix}/{skill}/scene                 operator -> Canal  put, JSON {"obstacles": [...]}:
                                           the skill's new scene (the REST scene's twin)
    {prefix}/{skill}/scene/updated         bridge -> bridges: a scene landed ({"version": v})
    {prefix}/{skill}/{robot}/demo/start    queryable: begin capturing this stream's poses
    {prefix}/{skill}/{robot}/demo/stop     queryable: store them as a new demonstration
    {prefix}/{skill}/{robot}/correction/start  queryable: begin capturing a correction's poses
    {prefix}/{skill}/{robot}/correction/stop   queryable: apply them as a correction (a new model)
    {prefix}/{skill}/{robot}/steer         robot/person -> Canal   put, a 2-D input (u, v)
    {prefix}/{skill}/{robot}/steer/keep    queryable: keep the last steered run as an include
    {prefix}/@recorder/live/{bridge}       bridge -> recorder   put, the batches to record

The recorder key starts with the *verbatim* chunk ``@recorder``: Zenoh matches such a chunk
only by the same chunk, never by ``*`` or ``**``, so ``{prefix}/**`` (a stranger's
subscription, an ACL rule for robots) never covers it, and no skill can be named like it
(:func:`is_plain_chunk` refuses a leading ``@``). The shipped ACL gives it to the service only.

Sharding (``shards = K > 1``): a stream belongs to shard ``ord(last character of robot) % K``.
That rule is chosen because Zenoh can express it: shard I subscribes to
``{prefix}/*/$*{c}/pose`` for each character ``c`` of :data:`SHARD_ALPHABET` with
``ord(c) % K == I`` (:func:`shard_pose_keys`), so Zenoh itself delivers each pose to one
bridge only; a bridge never receives, let alone decodes, another shard's poses. Robots
numbered ``r0, r1, ...`` spread evenly. A robot whose name ends with a character outside
:data:`SHARD_ALPHABET` is answered only by a single, unsharded bridge.
"""

from __future__ import annotations

import string
from dataclasses import dataclass

POSE = "pose"
TARGET = "target"
STATUS = "status"
MODEL = "model"
MODEL_UPDATED = "model/updated"
SCENE = "scene"
SCENE_UPDATED = "scene/updated"
DEMO_START = "demo/start"
DEMO_STOP = "demo/stop"
CORRECTION_START = "correction/start"
CORRECTION_STOP = "correction/stop"
STEER = "steer"
STEER_KEEP = "steer/keep"
RECORDER = "@recorder/live"

_BAD_CHUNK = frozenset("/*$?#")

#: Last characters of robot names that sharded bridges subscribe to (see the module docstring).
SHARD_ALPHABET = string.ascii_letters + string.digits + "_-.~+=,;:!%&'()[]{}<>|^`\"\\ "


def check_chunk(name: str, what: str) -> str:
    """``name`` if it is a valid single key-expression chunk, else ValueError."""
    if not name:
        raise ValueError(f"expected {what} that is not empty, got ''")
    if any(c in _BAD_CHUNK for c in name):
        raise ValueError(f"expected {what} without '/', '*', '$', '?' or '#', got {name!r}")
    return name


def check_prefix(prefix: str) -> str:
    """``prefix`` if it is one or more plain key chunks (``canal``, ``site1/canal``), else
    ValueError: a wildcard there would put and answer on every key it matches."""
    for chunk in prefix.split("/"):
        if not chunk:
            raise ValueError(f"expected a key prefix of chunks that are not empty, got {prefix!r}")
        if any(c in _BAD_CHUNK for c in chunk) or chunk[0] == "@":
            raise ValueError(f"expected a key prefix of plain chunks (without '*', '$', '?', '#' "
                             f"or a leading '@'), got {prefix!r}")
    return prefix


def is_plain_chunk(name: str) -> bool:
    """Whether ``name`` is one literal key chunk (no wildcard, DSL or verbatim marker)."""
    if not name or name[0] == "@":
        return False
    for c in name:
        if c in _BAD_CHUNK:
            return False
    return True


def head(prefix: str) -> str:
    """``{prefix}/``: what every Canal key starts with."""
    return prefix.rstrip("/") + "/"


def stream_of(key: str, prefix: str = "canal", leaf: str = POSE) -> tuple[str, str] | None:
    """``(skill, robot)`` of ``{prefix}/{skill}/{robot}/{leaf}`` when both are plain chunks,
    else None (a wildcard put such as ``canal/pour/*/pose`` is not anyone's stream)."""
    start = head(prefix)
    if not key.startswith(start):
        return None
    parts = key[len(start):].split("/")
    if len(parts) != 3 or parts[2] != leaf:
        return None
    skill, robot = parts[0], parts[1]
    if not is_plain_chunk(skill) or not is_plain_chunk(robot):
        return None
    return skill, robot


def skill_of_update(key: str, prefix: str = "canal") -> str | None:
    """The skill of a ``{prefix}/{skill}/model/updated`` key, or None."""
    start = head(prefix)
    if not key.startswith(start):
        return None
    parts = key[len(start):].split("/")
    if len(parts) != 3 or parts[1:] != MODEL_UPDATED.split("/") or not is_plain_chunk(parts[0]):
        return None
    return parts[0]


def scene_of_key(key: str, prefix: str = "canal") -> tuple[str, bool] | None:
    """``(skill, updated)`` of a ``{prefix}/{skill}/scene`` (False) or
    ``{prefix}/{skill}/scene/updated`` (True) key, else None."""
    start = head(prefix)
    if not key.startswith(start):
        return None
    parts = key[len(start):].split("/")
    if not parts or not is_plain_chunk(parts[0]):
        return None
    if parts[1:] == [SCENE]:
        return parts[0], False
    if parts[1:] == SCENE_UPDATED.split("/"):
        return parts[0], True
    return None


def query_of(key: str, prefix: str = "canal") -> list[str] | None:
    """The chunks after the prefix of a query key when all are plain, else None."""
    start = head(prefix)
    parts = key[len(start):].split("/") if key.startswith(start) else []
    if not parts or not all(is_plain_chunk(p) for p in parts):
        return None
    return parts


@dataclass(frozen=True)
class Keys:
    """Key expressions of one (skill, robot) stream."""

    prefix: str
    skill: str
    robot: str

    @property
    def base(self) -> str:
        return f"{self.prefix}/{self.skill}/{self.robot}"

    @property
    def pose(self) -> str:
        return f"{self.base}/{POSE}"

    @property
    def target(self) -> str:
        return f"{self.base}/{TARGET}"

    @property
    def status(self) -> str:
        return f"{self.base}/{STATUS}"

    @property
    def model(self) -> str:
        return f"{self.prefix}/{self.skill}/{MODEL}"

    @property
    def demo_start(self) -> str:
        return f"{self.base}/{DEMO_START}"

    @property
    def demo_stop(self) -> str:
        return f"{self.base}/{DEMO_STOP}"

    @property
    def correction_start(self) -> str:
        return f"{self.base}/{CORRECTION_START}"

    @property
    def correction_stop(self) -> str:
        return f"{self.base}/{CORRECTION_STOP}"

    @property
    def steer(self) -> str:
        return f"{self.base}/{STEER}"

    @property
    def steer_keep(self) -> str:
        return f"{self.base}/{STEER_KEEP}"


def keys(skill: str, robot: str = "robot", prefix: str = "canal") -> Keys:
    """The key expressions for ``skill`` and ``robot`` under ``prefix``."""
    return Keys(prefix.rstrip("/"), check_chunk(skill, "skill"), check_chunk(robot, "robot"))


def stream_keys(skill: str, robot: str, prefix: str = "canal") -> Keys:
    """:func:`keys` for chunks already checked (the bridge's hot path)."""
    return Keys(prefix.rstrip("/"), skill, robot)


def model_key(skill: str, prefix: str = "canal") -> str:
    """``{prefix}/{skill}/model``."""
    return f"{prefix.rstrip('/')}/{check_chunk(skill, 'skill')}/{MODEL}"


def model_updated_key(skill: str, prefix: str = "canal") -> str:
    """``{prefix}/{skill}/model/updated``."""
    return f"{prefix.rstrip('/')}/{check_chunk(skill, 'skill')}/{MODEL_UPDATED}"


def pose_wildcard(prefix: str = "canal") -> str:
    """Every stream's poses: what an unsharded bridge subscribes to."""
    return f"{prefix.rstrip('/')}/*/*/{POSE}"


def target_wildcard(prefix: str = "canal") -> str:
    """Every stream's targets."""
    return f"{prefix.rstrip('/')}/*/*/{TARGET}"


def model_updated_wildcard(prefix: str = "canal") -> str:
    """Every skill's fit notices (between bridges)."""
    return f"{prefix.rstrip('/')}/*/{MODEL_UPDATED}"


def scene_key(skill: str, prefix: str = "canal") -> str:
    """``{prefix}/{skill}/scene``: where an operator puts the skill's scene."""
    return f"{prefix.rstrip('/')}/{check_chunk(skill, 'skill')}/{SCENE}"


def scene_updated_key(skill: str, prefix: str = "canal") -> str:
    """``{prefix}/{skill}/scene/updated``."""
    return f"{prefix.rstrip('/')}/{check_chunk(skill, 'skill')}/{SCENE_UPDATED}"


def scene_wildcard(prefix: str = "canal") -> str:
    """Every skill's scene puts and scene notices (``{prefix}/*/scene/**``)."""
    return f"{prefix.rstrip('/')}/*/{SCENE}/**"


def steer_wildcard(prefix: str = "canal") -> str:
    """Every stream's steering inputs."""
    return f"{prefix.rstrip('/')}/*/*/{STEER}"


def everything(prefix: str = "canal") -> str:
    """Every key under the prefix (the bridge's queryable)."""
    return f"{prefix.rstrip('/')}/**"


def recorder_key(bridge: str, prefix: str = "canal") -> str:
    """``{prefix}/@recorder/live/{bridge}``: where bridge ``bridge`` puts its recording batches."""
    return f"{prefix.rstrip('/')}/{RECORDER}/{check_chunk(bridge, 'bridge')}"


def recorder_wildcard(prefix: str = "canal") -> str:
    """Every bridge's recording batches (what the service's live recorder subscribes to)."""
    return f"{prefix.rstrip('/')}/{RECORDER}/*"


def bridge_of_batch(key: str, prefix: str = "canal") -> str | None:
    """The bridge chunk of a :func:`recorder_key`, or None when ``key`` is not one."""
    start = f"{head(prefix)}{RECORDER}/"
    if not key.startswith(start):
        return None
    bridge = key[len(start):]
    return bridge if is_plain_chunk(bridge) else None


def shard_of(skill: str, robot: str, shards: int) -> int:
    """The bridge shard (0..shards-1) that answers this stream: ``ord(robot[-1]) % shards``.

    ``skill`` does not take part: every shard serves every skill, so a fleet of one skill
    spreads too. See the module docstring for why the rule is the robot's last character.
    """
    del skill
    return ord(robot[-1]) % shards if shards > 1 and robot else 0


def shard_pose_keys(shard: int, shards: int, prefix: str = "canal") -> list[str]:
    """The pose key expressions shard ``shard`` of ``shards`` subscribes to.

    One expression (:func:`pose_wildcard`) when ``shards`` is 1; else
    ``{prefix}/*/$*{c}/pose`` for each character ``c`` of :data:`SHARD_ALPHABET` that
    :func:`shard_of` gives to this shard.
    """
    if shards <= 1:
        return [pose_wildcard(prefix)]
    if not 0 <= shard < shards:
        raise ValueError(f"expected a shard in 0..{shards - 1}, got {shard}")
    p = prefix.rstrip("/")
    return [f"{p}/*/$*{c}/{POSE}" for c in SHARD_ALPHABET if ord(c) % shards == shard]


__all__ = [
    "RECORDER", "SHARD_ALPHABET", "Keys", "bridge_of_batch", "check_chunk", "check_prefix",
    "everything",
    "head", "is_plain_chunk", "keys", "model_key", "model_updated_key",
    "model_updated_wildcard", "pose_wildcard", "query_of", "recorder_key",
    "recorder_wildcard", "shard_of", "shard_pose_keys", "skill_of_update", "steer_wildcard",
    "stream_keys",
    "stream_of", "target_wildcard",
]
