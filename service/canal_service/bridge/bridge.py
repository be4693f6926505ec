"""The Zenoh bridge: reactive canal_core trackers for many (skill, robot) pose streams.

Threads (none of Zenoh's callback threads ever runs our code; everything arrives through
Zenoh FIFO channels):

- **worker**: the only thread that steps trackers and publishes targets. It blocks in the
  pose channel's ``recv()`` (GIL released), then drains everything else queued without
  blocking, and handles the drain as one batch: decode every pose, then step the trackers
  of all streams of one model in **one** vectorised numpy call
  (:func:`canal_core.tracker.step_trackers`), then encode and put each answer. A stream
  with several poses in one drain is stepped in order (one pass per pose). Metrics are
  plain integers on the worker; the **metrics** thread hands them to Prometheus.
  *Overload policy*: when one stream has more than ``coalesce_backlog`` poses queued in one
  drain, only its newest pose is answered; the older ones are counted per stream (the
  target's ``coalesced``) and in ``canal_live_poses_coalesced_total``.
- **control**: answers the queryables (model, demo start/stop): database work, never on
  the pose path.
- **housekeeper**: every ``refresh_s`` re-reads the latest model version of the skills it
  serves (a fit elsewhere is picked up even without a push), forgets streams idle for
  ``idle_s`` and expired negative cache entries.

Security (see docs/live.md): a key chunk that is not a plain name (``*``, ``**``, ``$*``,
``?``, ``#``, an ``@`` verbatim chunk) is refused, logged (rate-limited) and counted as
``bad_key``; nothing is answered, so a wildcard put can never reach another robot's target.
Each stream's state is keyed by its exact key; who may put on a key is Zenoh's access
control (docker/zenoh/). Unknown skills are remembered in a bounded, expiring negative
cache and get no stream (no publisher, no refresh).

Sharding: with ``shards = K > 1`` this bridge answers only the streams whose
``crc32("skill/robot") % K == shard``; K bridges with the same K and shards 0..K-1 share the
robots through Zenoh. When a fit lands, every bridge hears it (``fit`` lines on stdin from
``canal serve``, and ``{prefix}/{skill}/model/updated`` puts between bridges).

Model switching: a stream holds the version its tracker was built from. On the first pose
after the version changed, the tracker is rebuilt from the new canal and seeded at the
section the live position is located at, so the stream keeps going from where the robot
is. A new stream and a pose with the ``restart`` flag are seeded the same way.
"""

from __future__ import annotations

import collections
import gc
import logging
import math
import sys
import threading
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import orjson
import zenoh

from canal_core.tracker import Tracker, step_trackers, tracker_geometry
from canal_protocol import wire

from ..errors import NoModelYet, ServiceError, SkillNotFound, error_type
from ..validation import check_demonstration

log = logging.getLogger("canal_service.bridge")

ENC_JSON = zenoh.Encoding.APPLICATION_JSON
ENC_BINARY = zenoh.Encoding.APPLICATION_OCTET_STREAM
ENC_CDR = zenoh.Encoding.APPLICATION_CDR
_OK = wire.STATUS_CODES["ok"]
_OUTSIDE = wire.STATUS_CODES["outside_canal"]
_FJSON, _FBIN, _FCDR = wire.FORMAT_JSON, wire.FORMAT_BINARY, wire.FORMAT_CDR
_MAX_DRAIN = 4096
_STOP_WAIT_S = 2.0
_BEHIND_S = 1.0
SWITCH_INTERVAL_S = 0.0005
ERROR_KEYS = ("outside_canal", "bad_payload", "wrong_dimension", "non_finite",
              "unknown_skill", "no_model", "internal_error", "bad_key")


@dataclass(frozen=True)
class BridgeOptions:
    """How the bridge joins Zenoh and how it behaves under load."""

    prefix: str = "canal"
    listen: tuple[str, ...] = ("tcp/127.0.0.1:7447",)
    connect: tuple[str, ...] = ()
    config_file: Path | None = None
    queue_capacity: int = 4096
    coalesce_backlog: int = 16
    idle_s: float = 30.0
    refresh_s: float = 2.0
    lookahead: int = 2
    shard: int = 0
    shards: int = 1
    negative_ttl_s: float = 10.0
    negative_max: int = 16384

    @classmethod
    def from_settings(cls, settings: Any, **overrides: Any) -> BridgeOptions:
        """Options from the service's Settings (``zenoh_*`` fields)."""
        values: dict[str, Any] = dict(
            prefix=settings.zenoh_prefix, listen=tuple(settings.zenoh_listen),
            connect=tuple(settings.zenoh_connect), config_file=settings.zenoh_config,
            queue_capacity=settings.zenoh_queue_capacity,
            coalesce_backlog=settings.zenoh_coalesce_backlog, idle_s=settings.zenoh_idle_s,
            refresh_s=settings.zenoh_refresh_s, lookahead=settings.zenoh_lookahead,
        )
        values.update(overrides)
        return cls(**values)


def zenoh_config(options: BridgeOptions) -> zenoh.Config:
    """The session config: the user's file unchanged, else peer mode on the given endpoints
    with multicast scouting off."""
    if options.config_file is not None:
        return zenoh.Config.from_file(str(options.config_file))
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("listen/endpoints", orjson.dumps(list(options.listen)).decode())
    config.insert_json5("connect/endpoints", orjson.dumps(list(options.connect)).decode())
    return config


def access_of(config: zenoh.Config) -> dict[str, Any]:
    """How the live path is closed: ``open`` or ``authenticated`` (user/password or mutual
    TLS), with TLS and the access-control policy reported beside it."""
    user = _config_value(config, "transport/auth/usrpwd/user")
    users = _config_value(config, "transport/auth/usrpwd/dictionary_file")
    mtls = _config_value(config, "transport/link/tls/enable_mtls")
    acl = _config_value(config, "access_control/enabled")
    default = _config_value(config, "access_control/default_permission")
    mode = _config_value(config, "mode")
    endpoints = [*_per_mode(_config_value(config, "listen/endpoints"), mode),
                 *_per_mode(_config_value(config, "connect/endpoints"), mode)]
    tls = bool(endpoints) and all(str(e).startswith(("tls/", "quic/")) for e in endpoints)
    authenticated = bool(users or user or (mtls and tls))
    return {"access": "authenticated" if authenticated else "open", "tls": tls,
            "acl": bool(acl), "acl_default": default if acl else None}


def shard_of(skill: str, robot: str, shards: int) -> int:
    """The bridge shard (0..shards-1) that answers this stream: crc32 of ``skill/robot``."""
    return zlib.crc32(f"{skill}/{robot}".encode()) % shards if shards > 1 else 0


@dataclass(eq=False)
class ModelEntry:
    """What the bridge knows about one skill: a model, or why there is none."""

    status: str  # "ok" | "unknown_skill" | "no_model"
    version: int = -1
    dim: int = 0
    canal: Any = None
    message: str | None = None
    geometry: Any = None
    expires: float = math.inf


@dataclass(eq=False)
class Stream:
    """One (skill, robot) pose stream."""

    key: str
    skill: str
    robot: str
    publisher: Any
    tracker: Any = None
    version: int = -1
    last_seen: float = 0.0
    last_seq: int = -1
    coalesced: int = 0
    cdr_seq: int = 0
    cdr_status: str = ""
    status_key: str = ""
    capture: list[wire.Pose] | None = None
    capture_from: int = 0
    capture_label: str | None = None
    lock: threading.Lock = field(default_factory=threading.Lock)
    closed: bool = False


class Counts:
    """The worker's metrics as plain integers (read and reset by the metrics thread)."""

    __slots__ = (
        "batches",
        "busy_s",
        "coalesced",
        "errors",
        "last_idle",
        "poses",
        "switches",
        "targets",
        "waiting",
    )

    def __init__(self) -> None:
        self.poses = 0
        self.targets = 0
        self.coalesced = 0
        self.errors: dict[str, int] = dict.fromkeys(ERROR_KEYS, 0)
        self.switches = 0
        self.batches: collections.deque[tuple[float, int]] = collections.deque(maxlen=100_000)
        self.busy_s = 0.0
        self.last_idle = time.monotonic()
        self.waiting = True  # blocked on an empty queue

    def snapshot(self) -> dict[str, Any]:
        return {"poses": self.poses, "targets": self.targets, "coalesced": self.coalesced,
                "errors": dict(self.errors), "switches": self.switches}


class Bridge:
    """Serve live tracking over Zenoh for a :class:`~canal_service.service.CanalService`."""

    def __init__(self, service: Any, options: BridgeOptions | None = None) -> None:
        self.service = service
        self.options = options or BridgeOptions()
        self.prefix = self.options.prefix.rstrip("/")
        self.session: Any = None
        self.state = "stopped"
        self.detail: str | None = None
        self.listen: list[str] = []
        self.multicast_scouting: bool | None = None
        self.mode: str | None = None
        self.access: dict[str, Any] = {"access": "open", "tls": False, "acl": False,
                                       "acl_default": None}
        self.counts = Counts()
        self._models: dict[str, ModelEntry] = {}
        self._unknown: collections.OrderedDict[str, ModelEntry] = collections.OrderedDict()
        self._streams: dict[str, Stream] = {}
        self._others: set[str] = set()  # keys of other shards' streams
        self._streams_lock = threading.Lock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._subscriber: Any = None
        self._queryable: Any = None
        self._updates: Any = None
        self._bad_key_logged = 0.0
        self._published: dict[str, int] = {}
        m = service.metrics
        self._metrics = m
        self._m_streams = m.live_streams
        self._m_step = m.live_step_seconds
        self._m_error_children = {key: m.live_errors.labels(key) for key in ERROR_KEYS}
        self._flushed = Counts().snapshot()

    # ---- lifecycle ----------------------------------------------------------------------------

    def start(self) -> bool:
        """Open the session and start the threads; False (and state "down") when Zenoh fails."""
        try:
            config = zenoh_config(self.options)
            self.mode = _config_value(config, "mode")
            self.listen = _per_mode(_config_value(config, "listen/endpoints"), self.mode)
            self.multicast_scouting = _config_value(config, "scouting/multicast/enabled")
            self.access = access_of(config)
            self.session = zenoh.open(config)
        except Exception as exc:  # port taken, bad config file, ...
            self.state, self.detail = "down", f"{type(exc).__name__}: {exc}"
            log.error("live bridge not started (the REST API still runs): %s", self.detail)
            return False
        # Python hands the GIL over every 5 ms by default: a pose arriving while another
        # thread holds it would wait that long. 0.5 ms bounds the wait.
        if sys.getswitchinterval() > SWITCH_INTERVAL_S:
            sys.setswitchinterval(SWITCH_INTERVAL_S)
        # A full garbage collection walks every object of the process with the GIL held
        # (22 ms measured with the service loaded), stalling every stream at once. What is
        # alive now is moved out of the collector's reach; the pose path's garbage dies young.
        gc.collect()
        gc.freeze()
        s = self.session
        self._subscriber = s.declare_subscriber(
            wire.pose_wildcard(self.prefix),
            zenoh.handlers.FifoChannel(self.options.queue_capacity))
        self._queryable = s.declare_queryable(f"{self.prefix}/**",
                                              zenoh.handlers.FifoChannel(256))
        self._updates = s.declare_subscriber(f"{self.prefix}/*/model/updated",
                                             zenoh.handlers.FifoChannel(256))
        listeners = getattr(self.service, "fit_listeners", None)
        if listeners is not None:
            listeners.append(self._on_fit)
        for name, target in (("worker", self._work), ("control", self._control),
                             ("housekeeper", self._housekeep), ("metrics", self._flush_loop),
                             ("updates", self._hear_updates)):
            t = threading.Thread(target=target, name=f"canal-bridge-{name}", daemon=True)
            t.start()
            self._threads.append(t)
        self.state, self.detail = "ok", None
        self._metrics.live_up.set(1)
        log.info("live bridge on %s (prefix %r, shard %d/%d, live path %s)",
                 ", ".join(self.listen) or "(config file)", self.prefix, self.options.shard,
                 self.options.shards, self.access["access"])
        return True

    def close(self) -> None:
        """Stop the threads and close the session (idempotent)."""
        if self.session is None:
            return
        self._stop.set()
        listeners = getattr(self.service, "fit_listeners", None)
        if listeners is not None and self._on_fit in listeners:
            listeners.remove(self._on_fit)
        for entity in (self._subscriber, self._queryable, self._updates):
            try:
                entity.undeclare()  # unblocks recv() in the worker / control thread
            except Exception:
                pass
        for t in self._threads:
            t.join(timeout=5.0)
        with self._streams_lock:
            streams, self._streams = list(self._streams.values()), {}
        for st in streams:
            st.closed = True
            try:
                st.publisher.undeclare()
            except Exception:
                pass
        session, self.session = self.session, None
        try:
            session.close()
        except Exception:
            log.exception("closing the Zenoh session failed")
        self.flush_metrics()
        self._m_streams.set(0)
        self._metrics.live_up.set(0)
        self.state = "stopped"

    def behind(self) -> bool:
        """Whether the worker has not caught up with its queue for a while."""
        counts = self.counts
        return (self.state == "ok" and not counts.waiting
                and time.monotonic() - counts.last_idle > _BEHIND_S)

    def health(self) -> dict[str, Any]:
        """State for /healthz."""
        status = "behind" if self.behind() else self.state
        return {"status": status, "detail": self.detail, "prefix": self.prefix,
                "mode": self.mode, "listen": self.listen,
                "multicast_scouting": self.multicast_scouting,
                "config_file": None if self.options.config_file is None
                else str(self.options.config_file),
                "streams": len(self._streams), **self.access,
                "shard": self.options.shard, "shards": self.options.shards,
                "coalesced": self.counts.coalesced, "processes": 0}

    # ---- metrics (off the pose path) ----------------------------------------------------------

    def _flush_loop(self) -> None:
        while not self._stop.wait(0.25):
            try:
                self.flush_metrics()
            except Exception:
                log.exception("metrics flush failed")

    def flush_metrics(self) -> None:
        """Hand the worker's counts to Prometheus (deltas since the last flush)."""
        m, now, before = self._metrics, self.counts.snapshot(), self._flushed
        m.live_poses.inc(now["poses"] - before["poses"])
        m.live_targets.inc(now["targets"] - before["targets"])
        m.live_coalesced.inc(now["coalesced"] - before["coalesced"])
        m.live_model_switches.inc(now["switches"] - before["switches"])
        for key, n in now["errors"].items():
            if n != before["errors"][key]:
                self._m_error_children[key].inc(n - before["errors"][key])
        self._flushed = now
        batches = self.counts.batches
        while batches:
            seconds, n = batches.popleft()
            per = seconds / n
            for _ in range(min(n, 64)):
                self._m_step.observe(per)
        self._m_streams.set(len(self._streams))

    # ---- models -------------------------------------------------------------------------------

    def _load(self, skill: str) -> ModelEntry:
        """The skill's latest model from the service (database, decoded-canal cache)."""
        try:
            canal, _row, version, _dim = self.service.load_canal(skill, None)
        except SkillNotFound as exc:
            return ModelEntry("unknown_skill", message=exc.message)
        except NoModelYet as exc:
            return ModelEntry("no_model", dim=exc.dim, message=exc.message)
        return _ok_entry(version, canal)

    def _install(self, skill: str, entry: ModelEntry) -> None:
        """Replace the skill's entry unless it would go back to an older version. Unknown
        skills go to the bounded, expiring negative cache instead."""
        if entry.status == "unknown_skill":
            self._models.pop(skill, None)
            entry.expires = time.monotonic() + self.options.negative_ttl_s
            unknown = self._unknown
            unknown[skill] = entry
            unknown.move_to_end(skill)
            while len(unknown) > self.options.negative_max:
                unknown.popitem(last=False)
            return
        self._unknown.pop(skill, None)
        old = self._models.get(skill)
        if (old is not None and old.status == "ok" and entry.status == "ok"
                and entry.version <= old.version):
            return
        self._models[skill] = entry

    def _entry(self, skill: str) -> ModelEntry:
        entry = self._models.get(skill)
        if entry is not None:
            return entry
        entry = self._unknown.get(skill)
        if entry is not None and entry.expires > time.monotonic():
            return entry
        entry = self._load(skill)
        self._install(skill, entry)
        return entry

    def _on_fit(self, skill: str, version: int, canal: Any) -> None:
        """``CanalService.fit`` listener: serve the new version from the next pose on."""
        self.model_updated(skill, int(version), canal)

    def model_updated(self, skill: str, version: int, canal: Any = None,
                      announce: bool = True) -> None:
        """A fit landed (this process, ``canal serve`` or another bridge): load it and, when
        told, tell the other bridges on ``{prefix}/{skill}/model/updated``."""
        if not wire.is_plain_chunk(skill):
            return
        self._unknown.pop(skill, None)
        if skill in self._models:
            entry = _ok_entry(version, canal) if canal is not None else self._load(skill)
            self._install(skill, entry)
        if announce and self.session is not None and self._published.get(skill, -1) < version:
            self._published[skill] = version
            try:
                self.session.put(f"{self.prefix}/{skill}/model/updated",
                                 orjson.dumps({"version": version}), encoding=ENC_JSON)
            except Exception:
                log.exception("could not announce the new model of %r", skill)

    def _hear_updates(self) -> None:
        recv = self._updates.handler.recv
        while True:
            try:
                sample = recv()
            except Exception:
                return
            try:
                found = wire.stream_of(str(sample.key_expr) + "/x", self.prefix, "x")
                body = orjson.loads(sample.payload.to_bytes())
                if found is None or found[1] != "model" or not isinstance(body, dict):
                    continue
                version = body.get("version")
                if isinstance(version, int):
                    self._published[found[0]] = max(self._published.get(found[0], -1), version)
                    self.model_updated(found[0], version, announce=False)
            except Exception:
                log.exception("model update notice failed")

    # ---- streams ------------------------------------------------------------------------------

    def _bad_key(self, key: str) -> None:
        self.counts.errors["bad_key"] += 1
        now = time.monotonic()
        if now - self._bad_key_logged > 1.0:  # a flood must not flood the log
            self._bad_key_logged = now
            log.warning("refused a pose on %r: skill and robot must be plain key chunks "
                        "(no '*', '**', '$*', '?', '#', '@'); not answered", key)

    def _stream(self, key: str, skill: str, robot: str) -> Stream:
        with self._streams_lock:
            st = self._streams.get(key)
            if st is not None and not st.closed:
                return st
            base = f"{self.prefix}/{skill}/{robot}"
            # Not express: an express put writes to the socket on the calling thread (10-35 us
            # measured here), a batched one hands over to Zenoh's TX task (< 1 us).
            publisher = self.session.declare_publisher(
                base + "/target", express=False,
                congestion_control=zenoh.CongestionControl.BLOCK)
            st = Stream(key, skill, robot, publisher, last_seen=time.monotonic(),
                        status_key=base + "/status")
            self._streams[key] = st
            return st

    def _resolve(self, key: str) -> Stream | ModelEntry | None:
        """The stream of a pose key; the negative entry for an unknown skill; None for a key
        that is refused or another shard's."""
        if key in self._others:
            return None
        found = wire.stream_of(key, self.prefix)
        if found is None:
            self._bad_key(key)
            return None
        skill, robot = found
        if self.options.shards > 1 and shard_of(skill, robot, self.options.shards) != \
                self.options.shard:
            if len(self._others) < 100_000:
                self._others.add(key)
            return None
        entry = self._entry(skill)
        if entry.status == "unknown_skill":
            return entry
        return self._stream(key, skill, robot)

    # ---- the pose path ------------------------------------------------------------------------

    def _work(self) -> None:
        handler = self._subscriber.handler
        recv, try_recv = handler.recv, handler.try_recv
        counts = self.counts
        clock = time.perf_counter
        while True:
            counts.waiting = True
            try:
                sample = recv()
            except Exception:  # channel closed: shutting down
                return
            counts.waiting = False
            started = clock()
            batch = [sample]
            drained = False
            while len(batch) < _MAX_DRAIN:
                nxt = try_recv()
                if nxt is None:
                    drained = True
                    break
                batch.append(nxt)
            try:
                self._batch(batch)
            except Exception:
                log.exception("live step failed")
                counts.errors["internal_error"] += 1
            if drained:
                counts.last_idle = time.monotonic()
            counts.batches.append((clock() - started, len(batch)))

    def _batch(self, batch: list[Any]) -> None:
        """Decode, group, step and answer one drain of the pose channel."""
        counts = self.counts
        groups: dict[str, list[Any]] = {}
        for s in batch:
            key = str(s.key_expr)
            group = groups.get(key)
            if group is None:
                groups[key] = [s]
            else:
                group.append(s)
        backlog = self.options.coalesce_backlog
        now = time.monotonic()
        rounds: list[list[tuple[Stream, wire.Pose, int, Any]]] = []
        for key, samples in groups.items():
            st = self._streams.get(key)
            if st is None or st.closed:
                found = self._resolve(key)
                if found is None:
                    continue
                if isinstance(found, ModelEntry):
                    for s in samples:
                        self._answer_unknown(key, s, found)
                    continue
                st = found
            st.last_seen = now
            if len(samples) > backlog:
                skipped = len(samples) - 1
                if st.capture is not None:
                    for s in samples[:-1]:
                        self._decode(st, s, False)
                st.coalesced += skipped
                counts.coalesced += skipped
                samples = samples[-1:]
            k = 0
            for s in samples:
                job = self._decode(st, s, True)
                if job is None:
                    continue
                if k == len(rounds):
                    rounds.append([])
                rounds[k].append(job)
                k += 1
        for jobs in rounds:
            self._step(jobs)

    def _decode(self, st: Stream, sample: Any, answer: bool
                ) -> tuple[Stream, wire.Pose, int, Any] | None:
        """One sample as a pose job, or None (answered with an error, or not to answer)."""
        data = sample.payload.to_bytes()
        encoding = str(sample.encoding)
        ros = None
        if answer:
            self.counts.poses += 1
        fmt = _FBIN
        try:
            if encoding.startswith(("application/json", "text/json")):
                fmt = _FJSON
                pose = wire.decode_pose_json(data)
            elif encoding.startswith(wire.CDR_ENCODING):
                fmt = _FCDR
                pose, ros = wire.decode_pose_cdr(data, st.cdr_seq)
                st.cdr_seq += 1
            elif data[:1] == b"{" and encoding.startswith("zenoh/bytes"):
                fmt = _FJSON
                pose = wire.decode_pose_json(data)
            elif data[:1] == b"\x00":
                fmt = _FCDR
                pose, ros = wire.decode_pose_cdr(data, st.cdr_seq)
                st.cdr_seq += 1
            else:
                pose = wire.decode_pose(data)
        except wire.WireError as exc:
            if answer:
                self._error(st, None, exc.key, exc.message, fmt)
            return None
        st.last_seq = pose.seq
        if st.capture is not None:
            with st.lock:
                if st.capture is not None and pose.seq >= st.capture_from:
                    st.capture.append(pose)
        if not answer:
            return None
        return st, pose, fmt, ros

    def _step(self, jobs: list[tuple[Stream, wire.Pose, int, Any]]) -> None:
        """Step every job's tracker (one numpy call per model) and answer."""
        by_model: dict[int, tuple[ModelEntry, list[tuple[Stream, wire.Pose, int, Any]]]] = {}
        for job in jobs:
            st, pose, fmt, ros = job
            entry = self._models.get(st.skill)
            if entry is None:
                entry = self._entry(st.skill)
            if entry.status != "ok":
                self._error(st, pose.seq, entry.status, entry.message, fmt)
                continue
            position = pose.position
            if fmt == _FCDR and entry.dim == 2:
                position = position[:2]
            elif len(position) != entry.dim:
                self._error(st, pose.seq, "wrong_dimension",
                            f"expected {entry.dim} coordinates for skill {st.skill!r}, "
                            f"got {len(position)}", fmt)
                continue
            if st.version != entry.version or pose.restart or st.tracker is None:
                if st.tracker is not None and st.version != entry.version:
                    self.counts.switches += 1
                st.tracker = Tracker(entry.geometry, self.options.lookahead)
                point = np.array(position, dtype=np.float64)
                try:
                    st.tracker.reset(int(entry.canal.reproduce_detailed(point).section_index))
                except Exception:  # a start no section brackets: from the first one
                    st.tracker.reset(0)
                st.version = entry.version
            group = by_model.get(id(entry))
            if group is None:
                by_model[id(entry)] = (entry, [job])
            else:
                group[1].append(job)
        for entry, group in by_model.values():
            positions = np.array([j[1].position[:entry.dim] for j in group], dtype=np.float64)
            with np.errstate(all="ignore"):  # 1e308 poses overflow; they answer outside
                targets = step_trackers([j[0].tracker for j in group], positions)
            for (st, pose, fmt, ros), tt in zip(group, targets, strict=True):
                self._answer(st, pose, fmt, ros, entry, tt)

    def _answer(self, st: Stream, pose: wire.Pose, fmt: int, ros: Any, entry: ModelEntry,
                tt: Any) -> None:
        counts = self.counts
        inside = tt.inside
        eta = tt.eta
        # "done" only counts at the end *and* within the last sections: a pose far beyond
        # the last plane (50, 50, 50; 1e308) is lost, not finished.
        done = tt.done and eta <= 1.0 + 1e-9
        target = tt.target
        if inside or done:
            code, status = _OK, "ok"
            progress = tt.progress
        else:
            code, status = _OUTSIDE, "outside_canal"
            progress = tt.progress
            if tt.done:  # lost beyond the end is not the end reached
                progress = tt.section_index / max(entry.canal.n_sections - 1, 1)
            done = False
            counts.errors["outside_canal"] += 1
            if not (math.isfinite(target[0]) and math.isfinite(target[-1])
                    and np.isfinite(target).all()):
                # overflowed: the way back in is the section ahead's centre
                n = entry.canal.n_sections
                target = entry.canal.directrix[min(tt.section_index + self.options.lookahead,
                                                   n - 1)]
            if not math.isfinite(eta):
                eta = 1e308
        orientation = tt.orientation if tt.orientation is not None else pose.orientation
        velocity = tt.velocity
        if fmt == _FJSON:
            st.publisher.put(wire.pack_target_json(
                pose.seq, status, target, progress, eta, tt.section_index, inside, done,
                entry.version, orientation, velocity, st.coalesced), encoding=ENC_JSON)
        elif fmt == _FBIN:
            st.publisher.put(wire.pack_target(
                pose.seq, code, target.tolist(), progress, eta, tt.section_index, inside,
                done, entry.version, orientation, velocity, st.coalesced), encoding=ENC_BINARY)
        else:
            position = target.tolist()
            if len(position) == 2:
                position.append(pose.position[2])
            st.publisher.put(wire.encode_pose_stamped_cdr(ros, position, orientation),
                             encoding=ENC_CDR)
            if status != st.cdr_status:
                st.cdr_status = status
                self.session.put(st.status_key, wire.target_json(wire.Target(
                    pose.seq, status, tuple(position[:entry.dim]), progress, eta,
                    tt.section_index, inside, done, entry.version, None,
                    None if orientation is None else tuple(orientation),
                    coalesced=st.coalesced)), encoding=ENC_JSON)
        counts.targets += 1

    def _error(self, st: Stream, seq: int | None, key: str, message: str | None,
               fmt: int) -> None:
        answer = wire.Target(seq=seq, status=key, message=message, coalesced=st.coalesced)
        if fmt == _FJSON:
            st.publisher.put(wire.target_json(answer), encoding=ENC_JSON)
        elif fmt == _FBIN:
            st.publisher.put(wire.encode_target(answer), encoding=ENC_BINARY)
        else:
            st.cdr_status = key
            self.session.put(st.status_key, wire.target_json(answer), encoding=ENC_JSON)
        self.counts.targets += 1
        self.counts.errors[key] += 1

    def _answer_unknown(self, key: str, sample: Any, entry: ModelEntry) -> None:
        """An unknown skill's answer, on a put without a declared publisher (no stream)."""
        self.counts.poses += 1
        data = sample.payload.to_bytes()
        encoding = str(sample.encoding)
        seq: int | None = None
        try:
            if wire.is_json(encoding, data):
                seq = wire.decode_pose_json(data).seq
                fmt = _FJSON
            elif wire.is_cdr(encoding, data):
                fmt = _FCDR
            else:
                seq = wire.decode_pose(data).seq
                fmt = _FBIN
        except wire.WireError:
            fmt = _FJSON if data[:1] == b"{" else _FBIN
        answer = wire.Target(seq=seq, status=entry.status, message=entry.message)
        base = key[: -len("pose")]
        if fmt == _FJSON:
            self.session.put(base + "target", wire.target_json(answer), encoding=ENC_JSON)
        elif fmt == _FBIN:
            self.session.put(base + "target", wire.encode_target(answer), encoding=ENC_BINARY)
        else:
            self.session.put(base + "status", wire.target_json(answer), encoding=ENC_JSON)
        self.counts.targets += 1
        self.counts.errors[entry.status] += 1

    # ---- queryables ---------------------------------------------------------------------------

    def _control(self) -> None:
        recv = self._queryable.handler.recv
        while True:
            try:
                query = recv()
            except Exception:
                return
            try:
                self._answer_query(query)
            except Exception:
                log.exception("live query failed")
                _reply_error(query, "internal_error", "the bridge failed; see the service log")
            finally:
                try:
                    query.drop()
                except Exception:
                    pass

    def _answer_query(self, query: Any) -> None:
        key = str(query.key_expr)
        head = self.prefix + "/"
        parts = key[len(head):].split("/") if key.startswith(head) else []
        if not parts or not all(wire.is_plain_chunk(p) for p in parts):
            return  # a wildcard query (canal/*/arm1/demo/start, canal/**) is nobody's
        shards = self.options.shards
        if len(parts) == 2 and parts[1] == "model":
            if self.options.shard == 0:  # one answer, not one per bridge
                self._answer_model(query, parts[0])
        elif len(parts) == 4 and parts[2] == "demo" and parts[3] in ("start", "stop"):
            skill, robot = parts[0], parts[1]
            if shards > 1 and shard_of(skill, robot, shards) != self.options.shard:
                return
            payload = query.payload
            try:
                body = orjson.loads(payload.to_bytes()) if payload is not None else {}
                if not isinstance(body, dict):
                    raise ValueError("expected a JSON object")
            except (ValueError, orjson.JSONDecodeError) as exc:
                _reply_error(query, "bad_payload", f"expected a JSON object: {exc}")
                return
            entry = self._entry(skill)
            if entry.status == "unknown_skill":
                _reply_error(query, "not_found", entry.message or "unknown skill", "skill")
                return
            stream = self._stream(f"{head}{skill}/{robot}/pose", skill, robot)
            if parts[3] == "start":
                self._demo_start(query, stream, body)
            else:
                self._demo_stop(query, stream, body)
        # anything else under the prefix is not ours to answer

    def _answer_model(self, query: Any, skill: str) -> None:
        try:
            model = self.service.get_model(skill, None, True)
        except ServiceError as exc:
            _reply_error(query, error_type(exc), exc.message, exc.field)
            return
        query.reply(query.key_expr, orjson.dumps(model.model_dump(mode="json")),
                    encoding=ENC_JSON)

    def _demo_start(self, query: Any, st: Stream, body: dict[str, Any]) -> None:
        from_seq = body.get("from_seq")
        label = body.get("label")
        with st.lock:
            st.capture = []
            st.capture_from = int(from_seq) if isinstance(from_seq, int) else st.last_seq + 1
            st.capture_label = label if isinstance(label, str) else None
        query.reply(query.key_expr, orjson.dumps({"capturing": True,
                                                  "from_seq": st.capture_from}),
                    encoding=ENC_JSON)

    def _demo_stop(self, query: Any, st: Stream, body: dict[str, Any]) -> None:
        last_seq = body.get("last_seq")
        if isinstance(last_seq, int):  # wait for the worker to see the last pose sent
            deadline = time.monotonic() + _STOP_WAIT_S
            while st.last_seq < last_seq and time.monotonic() < deadline:
                time.sleep(0.001)
        with st.lock:
            poses, st.capture = st.capture, None
            label = st.capture_label
        if poses is None:
            _reply_error(query, "conflict", "no demonstration is being captured on this stream",
                         "demo")
            return
        if isinstance(last_seq, int):
            poses = [p for p in poses if p.seq <= last_seq]
        try:
            created = self._store_demo(st.skill, poses, label)
        except ServiceError as exc:
            _reply_error(query, error_type(exc), exc.message, exc.field)
            return
        query.reply(query.key_expr, orjson.dumps(created), encoding=ENC_JSON)

    def _store_demo(self, skill: str, poses: list[wire.Pose], label: str | None
                    ) -> dict[str, Any]:
        dim = self.service.skill_dim(skill)
        positions = [p.position for p in poses]
        times = [p.t for p in poses]
        quats = [p.orientation for p in poses]
        demo = check_demonstration(
            positions, dim,
            times if poses and all(t is not None for t in times) else None,
            quats if poses and all(q is not None for q in quats) else None)
        created = self.service.add_demonstration(skill, demo, label, "zenoh")
        return created.model_dump(mode="json")  # type: ignore[no-any-return]

    # ---- housekeeping -------------------------------------------------------------------------

    def _housekeep(self) -> None:
        period = max(self.options.refresh_s, 0.05)
        while not self._stop.wait(period):
            now = time.monotonic()
            with self._streams_lock:
                idle = [k for k, st in self._streams.items()
                        if now - st.last_seen > self.options.idle_s and st.capture is None]
                gone = [self._streams.pop(k) for k in idle]
                live_skills = {st.skill for st in self._streams.values()}
            for st in gone:
                st.closed = True
                try:
                    st.publisher.undeclare()
                except Exception:
                    pass
            # Only skills with streams are re-read; the others are forgotten (read again on
            # their next pose), so the table stays as small as the live fleet.
            for skill in list(self._models):
                if skill not in live_skills:
                    self._models.pop(skill, None)
                    continue
                try:
                    entry = self._load(skill)
                except Exception:
                    log.exception("model refresh for %r failed", skill)
                    continue
                old = self._models.get(skill)
                if old is None or old.status != entry.status or old.version != entry.version:
                    self._install(skill, entry)
            for skill in [s for s, e in self._unknown.items() if e.expires <= now]:
                self._unknown.pop(skill, None)


def _config_value(config: zenoh.Config, key: str) -> Any:
    """A value of the config as Python (``get_json`` answers JSON text)."""
    try:
        return orjson.loads(config.get_json(key))
    except Exception:
        return None


def _per_mode(endpoints: Any, mode: Any) -> list[str]:
    """Endpoints as a list: Zenoh configs may give one list or a list per mode."""
    if isinstance(endpoints, dict):
        endpoints = endpoints.get(str(mode) if mode else "peer", [])
    return [str(e) for e in endpoints] if isinstance(endpoints, list) else []


def _ok_entry(version: int, canal: Any) -> ModelEntry:
    """A served model: its canal and the tracker geometry every stream of it shares."""
    geometry = tracker_geometry(canal.directrix, canal.tangents, canal.basis, canal.sections)
    return ModelEntry("ok", int(version), int(canal.dim), canal, geometry=geometry)


def _reply_error(query: Any, key: str, message: str, field: str | None = None) -> None:
    body = {"error": {"type": key, "field": field, "message": message}}
    try:
        query.reply_err(orjson.dumps(body), encoding=ENC_JSON)
    except Exception:
        log.exception("could not answer a live query")


__all__ = ["Bridge", "BridgeOptions", "ModelEntry", "Stream", "access_of", "shard_of",
           "zenoh_config"]
