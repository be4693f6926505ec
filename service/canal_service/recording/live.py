"""Live recording: the recorder's own Zenoh session, subscribed to the robots' poses and targets.

The bridge answers poses and never calls the recorder. This subscriber listens to the same
keys (``{prefix}/*/*/pose`` and ``{prefix}/*/*/target``, from :mod:`canal_protocol.keys`) with
a session of its own, so the recorder's work never runs on the bridge's Zenoh callback:

- Samples wait in Zenoh ring channels (Rust, no Python callback, no GIL on Zenoh's thread);
  when a ring is full its oldest sample is dropped. A drain thread empties the rings every
  ``interval_s`` and counts what it missed (gaps in the poses' ``seq``, full rings).
- Each sample carries the time it reached the session (Zenoh timestamping on ingress), so
  the recorder's rate limit and the logs see arrival times, not drain times.
- Payloads are decoded with :mod:`canal_protocol.wire` (JSON and binary v1). A payload that
  starts with a CDR encapsulation header is a ROS 2 ``geometry_msgs/msg/PoseStamped``,
  decoded by the bridge's own CDR reader (no ROS install or rosbags needed).

Configured from the service settings the bridge uses (see :meth:`LiveOptions.from_settings`).
"""

from __future__ import annotations

import logging
import struct
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import orjson
import zenoh

from canal_protocol import keys as keyspace
from canal_protocol import wire

from .events import POSE, TARGET, LiveSample

log = logging.getLogger("canal_service.recording")

_SEQ = struct.Struct("<Q")
#: CDR encapsulation headers (big and little endian, plain CDR), options 0.
_CDR_HEADERS = (b"\x00\x00\x00\x00", b"\x00\x01\x00\x00")


@dataclass(frozen=True)
class LiveOptions:
    """Where the recorder's session connects and which keys it hears."""

    prefix: str = "canal"
    listen: tuple[str, ...] = ("tcp/127.0.0.1:7447",)
    connect: tuple[str, ...] = ()
    config_file: Path | None = None
    capacity: int = 65_536  # samples per ring (pose, target)
    interval_s: float = 0.05

    @classmethod
    def from_settings(cls, settings: Any) -> LiveOptions:
        """The bridge's Zenoh settings (``CANAL_ZENOH_*``)."""
        return cls(prefix=settings.zenoh_prefix, listen=tuple(settings.zenoh_listen),
                   connect=tuple(settings.zenoh_connect), config_file=settings.zenoh_config)


def _local(endpoint: str) -> str:
    """A listen endpoint as a connect endpoint (any-address -> loopback)."""
    return endpoint.replace("/0.0.0.0:", "/127.0.0.1:").replace("/[::]:", "/[::1]:")


def zenoh_config(options: LiveOptions) -> zenoh.Config:
    """The recorder session's config: the bridge's, but connecting instead of listening.

    With a config file (TLS, credentials, routers) the file is used as is, except that the
    session listens nowhere and also connects to whatever the file listens on. Without one,
    a peer that connects to the bridge's listen endpoints (and its routers). Samples are
    timestamped on arrival.
    """
    if options.config_file is not None:
        config = zenoh.Config.from_file(str(options.config_file))
        try:
            listen = orjson.loads(config.get_json("listen/endpoints"))
        except Exception:
            listen = []
        if isinstance(listen, dict):  # per-mode endpoints
            listen = [e for v in listen.values() for e in (v or [])]
        connect = orjson.loads(config.get_json("connect/endpoints") or "[]")
        if isinstance(connect, dict):
            connect = [e for v in connect.values() for e in (v or [])]
        endpoints = list(dict.fromkeys([*connect, *(_local(e) for e in listen or [])]))
        config.insert_json5("listen/endpoints", "[]")
        config.insert_json5("connect/endpoints", orjson.dumps(endpoints).decode())
    else:
        config = zenoh.Config()
        config.insert_json5("mode", '"peer"')
        config.insert_json5("scouting/multicast/enabled", "false")
        config.insert_json5("listen/endpoints", "[]")
        endpoints = list(dict.fromkeys([*options.connect, *(_local(e) for e in options.listen)]))
        config.insert_json5("connect/endpoints", orjson.dumps(endpoints).decode())
    # The bridge may start after us: retry soon and often rather than Zenoh's 1 s -> 4 s.
    config.insert_json5("connect/retry", '{"period_init_ms": 100, "period_max_ms": 1000, '
                                         '"period_increase_factor": 2}')
    config.insert_json5("timestamping/enabled",
                        '{"router": true, "peer": true, "client": true}')
    return config


@dataclass
class LiveStats:
    """Counters of the subscriber (read by ``Recorder.health``)."""

    received: int = 0
    bad_payload: int = 0
    missed_poses: int = 0  # gaps in a stream's pose seq: ring overflow or lost on the way
    full_rings: int = 0  # drains that found a ring at capacity (it dropped its oldest)
    status: str = "starting"
    detail: str | None = None
    last_seq: dict[tuple[str, str], int] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return {"status": self.status, "detail": self.detail, "received": self.received,
                "bad_payload": self.bad_payload,
                "missed_poses": self.missed_poses, "full_rings": self.full_rings}


def _json_seq(data: bytes) -> int | None:
    """The ``seq`` of a JSON pose without parsing all of it (None when not found)."""
    at = data.find(b'"seq":')
    if at < 0:
        return None
    end = at + 6
    while end < len(data) and data[end:end + 1] in b" 0123456789":
        end += 1
    digits = data[at + 6:end].strip()
    return int(digits) if digits else None


def decode_cdr_pose(data: bytes) -> tuple[list[float], list[float]]:
    """(position, [qx, qy, qz, qw]) of a CDR ``geometry_msgs/msg/PoseStamped``, read by the
    bridge's own decoder (:func:`canal_protocol.wire.decode_pose_cdr`, checked against
    ``rosbags`` in the tests), so a deployment records ROS 2 streams without extra packages.
    Raises ``WireError`` when the payload is not one."""
    pose, _ = wire.decode_pose_cdr(data)
    assert pose.orientation is not None  # a PoseStamped always has one
    return [float(v) for v in pose.position], [float(v) for v in pose.orientation]


class LiveSubscriber:
    """Feeds a :class:`~.recorder.Recorder` from Zenoh (see the module docstring)."""

    def __init__(self, recorder: Any, options: LiveOptions) -> None:
        self.recorder = recorder
        self.options = options
        self.stats = LiveStats()
        self._session: Any = None
        self._subs: list[tuple[int, Any]] = []
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._prefix = options.prefix.rstrip("/")

    def start(self) -> None:
        """Open the session, subscribe and start draining (errors go to ``stats``)."""
        try:
            self._session = zenoh.open(zenoh_config(self.options))
            prefix = self._prefix
            for kind, key in ((POSE, keyspace.pose_wildcard(prefix)),
                              (TARGET, keyspace.target_wildcard(prefix))):
                ring: zenoh.handlers.RingChannel[zenoh.Sample] = zenoh.handlers.RingChannel(
                    self.options.capacity)
                self._subs.append((kind, self._session.declare_subscriber(key, ring)))
        except Exception as exc:
            self.stats.status, self.stats.detail = "down", f"{type(exc).__name__}: {exc}"
            log.warning("live recording is off: %s", self.stats.detail)
            self.close()
            return
        self.stats.status = "ok"
        self._thread = threading.Thread(target=self._run, name="canal-recorder-live",
                                        daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Stop draining (what is queued is drained once more) and close the session."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10)
        for _, sub in self._subs:
            try:
                sub.undeclare()
            except Exception:
                pass
        self._subs = []
        if self._session is not None:
            try:
                self._session.close()
            except Exception:
                pass
            self._session = None

    def health(self) -> dict[str, Any]:
        """The counters and status."""
        return self.stats.as_dict()

    # ---- drain thread -------------------------------------------------------------------------

    def _run(self) -> None:
        while not self._stop.wait(self.options.interval_s):
            self.drain()
        self.drain()

    def drain(self) -> int:
        """Empty the rings into the recorder; the number of samples read."""
        n = 0
        for kind, sub in self._subs:
            got = 0
            try:
                while got < self.options.capacity:
                    sample = sub.try_recv()
                    if sample is None:
                        break
                    got += 1
                    self._sample(kind, sample)
            except Exception:
                log.exception("live recording drain")
            if got >= self.options.capacity:
                self.stats.full_rings += 1
            n += got
        self.stats.received += n
        return n

    def _sample(self, kind: int, sample: Any) -> None:
        # Most samples at high rates are over the recording rate: decide that from the key,
        # the arrival time and a peek at the payload, and decode only the samples kept.
        found = keyspace.stream_of(str(sample.key_expr), self._prefix,
                                   keyspace.POSE if kind == POSE else keyspace.TARGET)
        if found is None:  # a wildcard put is nobody's stream: not recorded as one
            return
        skill, robot = found
        ts = sample.timestamp
        t_ns = ts.get_time_as_ntp64().as_nanos() if ts is not None else time.time_ns()
        data = sample.payload.to_bytes()
        try:
            if data[:4] in _CDR_HEADERS:
                self._cdr(kind, skill, robot, t_ns, data)
            elif kind == POSE:
                self._pose(skill, robot, t_ns, sample, data)
            else:
                self._target(skill, robot, t_ns, sample, data)
        except Exception:  # WireError, a CDR SerdeError, a short struct: not ours to fix
            self.stats.bad_payload += 1

    def _seq(self, skill: str, robot: str, seq: int | None) -> None:
        if seq is None:
            return
        key = (skill, robot)
        last = self.stats.last_seq.get(key)
        if last is not None and seq > last + 1:
            self.stats.missed_poses += seq - last - 1
        if last is None or seq > last:
            self.stats.last_seq[key] = seq

    def _pose(self, skill: str, robot: str, t_ns: int, sample: Any, data: bytes) -> None:
        json = data[:1] == b"{" or wire.is_json(str(sample.encoding), data)
        if not json and len(data) >= 12 and data[0] == wire.VERSION:
            self._seq(skill, robot, _SEQ.unpack_from(data, 4)[0])
        elif json:
            self._seq(skill, robot, _json_seq(data))
        if not self.recorder.wants_live(skill, robot, POSE, t_ns):
            self.recorder.decimated_live += 1
            return  # decimated before decoding
        pose = wire.decode_pose_json(data) if json else wire.decode_pose(data)
        self.recorder.live_sample(LiveSample(
            skill, robot, POSE, t_ns, list(pose.position),
            None if pose.orientation is None else list(pose.orientation)))

    def _target(self, skill: str, robot: str, t_ns: int, sample: Any, data: bytes) -> None:
        json = data[:1] == b"{" or wire.is_json(str(sample.encoding), data)
        if not self.recorder.wants_live(skill, robot, TARGET, t_ns) and not self._flips(
                skill, robot, json, data):
            self.recorder.decimated_live += 1
            return
        target = wire.decode_target_json(data) if json else wire.decode_target(data)
        if target.target is None:
            return  # an error answer: no position to draw
        orientation = getattr(target, "orientation", None)
        self.recorder.live_sample(LiveSample(
            skill, robot, TARGET, t_ns, list(target.target),
            None if orientation is None else list(orientation), float(target.progress),
            float("nan") if target.eta is None else float(target.eta),
            -1 if target.section is None else int(target.section),
            bool(target.inside), bool(target.done)))

    def _flips(self, skill: str, robot: str, json: bool, data: bytes) -> bool:
        """Whether a target's inside/done flags differ from the last recorded (a peek)."""
        if json:
            inside, done = b'"inside":true' in data, b'"done":true' in data
        elif len(data) > 2:
            inside, done = bool(data[2] & wire.TARGET_INSIDE), bool(data[2] & wire.TARGET_DONE)
        else:
            return True
        return self.recorder.live_flags(skill, robot) != (inside, done)

    def _cdr(self, kind: int, skill: str, robot: str, t_ns: int, data: bytes) -> None:
        if not self.recorder.wants_live(skill, robot, kind, t_ns):
            self.recorder.decimated_live += 1
            return
        position, orientation = decode_cdr_pose(data)
        self.recorder.live_sample(LiveSample(skill, robot, kind, t_ns, position, orientation))
