"""The Zenoh bridge: one reactive canal_core tracker per (skill, robot) pose stream.

Threads (none of Zenoh's callback threads ever runs our code; everything arrives through
Zenoh FIFO channels):

- **worker**: the only thread that steps trackers and publishes targets. It blocks in the
  pose channel's ``recv()`` (GIL released), then drains what else is queued without
  blocking. Samples are handled in arrival order, so each stream keeps its order.
  *Overload policy*: when one stream has more than ``coalesce_backlog`` poses queued in one
  drain, only its newest pose is answered; the older ones are counted in
  ``canal_live_poses_coalesced_total`` (and still captured into a live demonstration when
  one is being recorded). The channel itself holds ``queue_capacity`` samples; when it is
  full, Zenoh's receive thread waits, which pushes back on the TCP link (never reached in
  the benchmarks: the worker drains far faster than 16 x 1 kHz).
- **control**: answers the queryables (model, demo start/stop): database work, never on
  the pose path.
- **housekeeper**: every ``refresh_s`` re-reads the latest model version of every skill it
  has seen (so a fit on another replica is picked up), and forgets streams idle for
  ``idle_s``.

Models are looked up in an in-memory table per skill, never in the database per pose. The
table is filled on the first pose of a skill (one read), updated at once by
``CanalService.fit`` (``fit_listeners``) and by the housekeeper. Unknown skills and skills
without a model are cached the same way, so a robot hammering a wrong name costs no reads.

Model switching: a stream holds the version its tracker was built from. On the first pose
after the version changed, the tracker is rebuilt from the new canal and seeded at the
section the live position is located at (the same rule as a REST reproduction start:
smallest eta among the planes that bracket it), so the stream keeps going from where the
robot is; the new model's answers carry the new ``model_version``. A new stream and a pose
with the ``restart`` flag are seeded the same way.
"""

from __future__ import annotations

import gc
import logging
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import orjson
import zenoh
from canal_client import wire

from ..errors import Conflict, NotFound, ServiceError
from ..validation import check_demonstration

log = logging.getLogger("canal_service.bridge")

ENC_JSON = zenoh.Encoding.APPLICATION_JSON
ENC_BINARY = zenoh.Encoding.APPLICATION_OCTET_STREAM
_OK = wire.STATUS_CODES["ok"]
_OUTSIDE = wire.STATUS_CODES["outside_canal"]
_MAX_DRAIN = 4096
_STOP_WAIT_S = 2.0
SWITCH_INTERVAL_S = 0.0005


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

    @classmethod
    def from_settings(cls, settings: Any) -> BridgeOptions:
        """Options from the service's Settings (``zenoh_*`` fields)."""
        return cls(
            prefix=settings.zenoh_prefix, listen=tuple(settings.zenoh_listen),
            connect=tuple(settings.zenoh_connect), config_file=settings.zenoh_config,
            queue_capacity=settings.zenoh_queue_capacity,
            coalesce_backlog=settings.zenoh_coalesce_backlog, idle_s=settings.zenoh_idle_s,
            refresh_s=settings.zenoh_refresh_s, lookahead=settings.zenoh_lookahead,
        )


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


@dataclass(eq=False)
class ModelEntry:
    """What the bridge knows about one skill: a model, or why there is none."""

    status: str  # "ok" | "unknown_skill" | "no_model"
    version: int = -1
    dim: int = 0
    canal: Any = None
    message: str | None = None


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
    capture: list[wire.Pose] | None = None
    capture_from: int = 0
    capture_label: str | None = None
    lock: threading.Lock = field(default_factory=threading.Lock)
    closed: bool = False


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
        self._models: dict[str, ModelEntry] = {}
        self._streams: dict[str, Stream] = {}
        self._streams_lock = threading.Lock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._subscriber: Any = None
        self._queryable: Any = None
        m = service.metrics
        self._m_poses = m.live_poses
        self._m_targets = m.live_targets
        self._m_coalesced = m.live_coalesced
        self._m_errors = m.live_errors
        self._m_streams = m.live_streams
        self._m_step = m.live_step_seconds
        self._m_switches = m.live_model_switches
        self._m_error_children = {key: m.live_errors.labels(key) for key in wire.STATUS_CODES
                                  if key != "ok"}

    # ---- lifecycle ----------------------------------------------------------------------------

    def start(self) -> bool:
        """Open the session and start the threads; False (and state "down") when Zenoh fails."""
        try:
            config = zenoh_config(self.options)
            self.mode = _config_value(config, "mode")
            self.listen = _per_mode(_config_value(config, "listen/endpoints"), self.mode)
            self.multicast_scouting = _config_value(config, "scouting/multicast/enabled")
            self.session = zenoh.open(config)
        except Exception as exc:  # port taken, bad config file, ...
            self.state, self.detail = "down", f"{type(exc).__name__}: {exc}"
            log.error("live bridge not started (the REST API still runs): %s", self.detail)
            return False
        # Python hands the GIL over every 5 ms by default: a pose arriving while the recorder's
        # writer or a request thread holds it would wait that long. 0.5 ms bounds the wait.
        if sys.getswitchinterval() > SWITCH_INTERVAL_S:
            sys.setswitchinterval(SWITCH_INTERVAL_S)
        # A full (generation 2) garbage collection walks every object of the process with the
        # GIL held: 22 ms measured with the service and recorder loaded, which stalls every
        # stream at once (and, at 16 x 1 kHz, overflows the coalescing backlog). Everything
        # alive now (modules, app, caches) is moved out of the collector's reach; what the
        # pose path allocates later is short-lived and dies in generation 0.
        gc.collect()
        gc.freeze()
        s = self.session
        self._subscriber = s.declare_subscriber(
            wire.pose_wildcard(self.prefix),
            zenoh.handlers.FifoChannel(self.options.queue_capacity))
        self._queryable = s.declare_queryable(f"{self.prefix}/**",
                                              zenoh.handlers.FifoChannel(256))
        listeners = getattr(self.service, "fit_listeners", None)
        if listeners is not None:
            listeners.append(self._on_fit)
        for name, target in (("worker", self._work), ("control", self._control),
                             ("housekeeper", self._housekeep)):
            t = threading.Thread(target=target, name=f"canal-bridge-{name}", daemon=True)
            t.start()
            self._threads.append(t)
        self.state, self.detail = "ok", None
        self.service.metrics.live_up.set(1)
        log.info("live bridge on %s (prefix %r, multicast scouting %s)",
                 ", ".join(self.listen) or "(config file)", self.prefix, self.multicast_scouting)
        return True

    def close(self) -> None:
        """Stop the threads and close the session (idempotent)."""
        if self.session is None:
            return
        self._stop.set()
        listeners = getattr(self.service, "fit_listeners", None)
        if listeners is not None and self._on_fit in listeners:
            listeners.remove(self._on_fit)
        for entity in (self._subscriber, self._queryable):
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
        self._m_streams.set(0)
        self.service.metrics.live_up.set(0)
        self.state = "stopped"

    def health(self) -> dict[str, Any]:
        """State for /healthz."""
        return {"status": self.state, "detail": self.detail, "prefix": self.prefix,
                "mode": self.mode, "listen": self.listen,
                "multicast_scouting": self.multicast_scouting,
                "config_file": None if self.options.config_file is None
                else str(self.options.config_file),
                "streams": len(self._streams)}

    # ---- models -------------------------------------------------------------------------------

    def _load(self, skill: str) -> ModelEntry:
        """The skill's latest model from the service (database, decoded-canal cache)."""
        try:
            canal, _row, version, dim = self.service.load_canal(skill, None)
        except NotFound as exc:
            return ModelEntry("unknown_skill", message=exc.message)
        except Conflict:
            try:
                dim = self.service.skill_dim(skill)
            except NotFound as exc:
                return ModelEntry("unknown_skill", message=exc.message)
            return ModelEntry("no_model", dim=dim,
                              message=f"skill {skill!r} has no fitted model yet")
        return ModelEntry("ok", version, dim, canal)

    def _install(self, skill: str, entry: ModelEntry) -> None:
        """Replace the skill's entry unless it would go back to an older version."""
        old = self._models.get(skill)
        if (old is not None and old.status == "ok" and entry.status == "ok"
                and entry.version <= old.version):
            return
        self._models[skill] = entry

    def _on_fit(self, skill: str, version: int, canal: Any) -> None:
        """``CanalService.fit`` listener: serve the new version from the next pose on."""
        if skill in self._models:
            self._install(skill, ModelEntry("ok", int(version), int(canal.dim), canal))

    # ---- streams ------------------------------------------------------------------------------

    def _stream(self, key: str) -> Stream:
        with self._streams_lock:
            st = self._streams.get(key)
            if st is not None:
                return st
            parts = key.split("/")
            skill, robot = parts[-3], parts[-2]
            # Not express: an express put writes to the socket on the calling thread (10-35 us
            # measured here), a batched one hands over to Zenoh's TX task (< 1 us) at no cost in
            # round-trip latency; the worker's GIL time is the bridge's throughput limit.
            publisher = self.session.declare_publisher(
                f"{self.prefix}/{skill}/{robot}/target", express=False,
                congestion_control=zenoh.CongestionControl.BLOCK)
            st = Stream(key, skill, robot, publisher, last_seen=time.monotonic())
            self._streams[key] = st
            self._m_streams.set(len(self._streams))
            return st

    # ---- the pose path ------------------------------------------------------------------------

    def _work(self) -> None:
        handler = self._subscriber.handler
        recv, try_recv = handler.recv, handler.try_recv
        backlog = self.options.coalesce_backlog
        while True:
            try:
                sample = recv()
            except Exception:  # channel closed: shutting down
                return
            nxt = try_recv()
            if nxt is None:
                self._safe_handle(sample, True)
                continue
            batch = [sample, nxt]
            while len(batch) < _MAX_DRAIN and (nxt := try_recv()) is not None:
                batch.append(nxt)
            groups: dict[str, list[Any]] = {}
            for s in batch:
                groups.setdefault(str(s.key_expr), []).append(s)
            # Streams interleave in first-arrival order; each keeps its own order.
            for samples in groups.values():
                if len(samples) > backlog:
                    for s in samples[:-1]:
                        self._safe_handle(s, False)
                    self._m_coalesced.inc(len(samples) - 1)
                    self._safe_handle(samples[-1], True)
                else:
                    for s in samples:
                        self._safe_handle(s, True)

    def _safe_handle(self, sample: Any, answer: bool) -> None:
        try:
            self._handle(sample, answer)
        except Exception:
            log.exception("live step failed")
            self._m_errors.labels("internal_error").inc()

    def _handle(self, sample: Any, answer: bool) -> None:
        """Decode one pose, capture it, step the tracker, publish the target, record."""
        started = time.perf_counter()
        key = str(sample.key_expr)
        st = self._streams.get(key)
        if st is None or st.closed:
            st = self._stream(key)
        st.last_seen = time.monotonic()
        data = sample.payload.to_bytes()
        as_json = wire.is_json(str(sample.encoding), data)
        if answer:
            self._m_poses.inc()
        try:
            pose = wire.decode_pose_json(data) if as_json else wire.decode_pose(data)
        except wire.WireError as exc:
            if answer:
                self._error(st, None, exc.key, exc.message, as_json)
            return
        st.last_seq = pose.seq
        if st.capture is not None:
            with st.lock:
                if st.capture is not None and pose.seq >= st.capture_from:
                    st.capture.append(pose)
        if not answer:
            return
        entry = self._models.get(st.skill)
        if entry is None:
            entry = self._load(st.skill)
            self._install(st.skill, entry)
        if entry.status != "ok":
            self._error(st, pose.seq, entry.status, entry.message, as_json)
            return
        position = pose.position
        if len(position) != entry.dim:
            self._error(st, pose.seq, "wrong_dimension",
                        f"expected {entry.dim} coordinates for skill {st.skill!r}, "
                        f"got {len(position)}", as_json)
            return
        point = np.array(position)
        if st.version != entry.version or pose.restart or st.tracker is None:
            if st.tracker is not None and st.version != entry.version:
                self._m_switches.inc()
            st.tracker = entry.canal.tracker(self.options.lookahead)
            st.tracker.reset(int(entry.canal.reproduce_detailed(point).section_index))
            st.version = entry.version
        tt = st.tracker.step(point)
        inside, done = tt.inside, tt.done
        if inside or done:
            status = "ok"
        else:
            status = "outside_canal"
            self._m_error_children["outside_canal"].inc()
        target = tt.target.tolist()
        if as_json:
            payload = wire.pack_target_json(pose.seq, status, target, tt.progress, tt.eta,
                                            tt.section_index, inside, done, entry.version)
            st.publisher.put(payload, encoding=ENC_JSON)
        else:
            payload = wire.pack_target(pose.seq, _OK if status == "ok" else _OUTSIDE, target,
                                       tt.progress, tt.eta, tt.section_index, inside, done,
                                       entry.version)
            st.publisher.put(payload, encoding=ENC_BINARY)
        self._m_targets.inc()
        recorder = self.service.recorder
        if recorder is not None:
            recorder.live(st.skill, st.robot, point, tt)
        self._m_step.observe(time.perf_counter() - started)

    def _error(self, st: Stream, seq: int | None, key: str, message: str | None,
               as_json: bool) -> None:
        answer = wire.Target(seq=seq, status=key, message=message)
        if as_json:
            st.publisher.put(wire.target_json(answer), encoding=ENC_JSON)
        else:
            st.publisher.put(wire.encode_target(answer), encoding=ENC_BINARY)
        self._m_targets.inc()
        self._m_error_children[key].inc()

    # ---- queryables ---------------------------------------------------------------------------

    def _control(self) -> None:
        recv = self._queryable.handler.recv
        while True:
            try:
                query = recv()
            except Exception:
                return
            try:
                self._answer(query)
            except Exception:
                log.exception("live query failed")
                _reply_error(query, "internal_error", "the bridge failed; see the service log")
            finally:
                try:
                    query.drop()
                except Exception:
                    pass

    def _answer(self, query: Any) -> None:
        key = str(query.key_expr)
        parts = key[len(self.prefix) + 1:].split("/") if key.startswith(self.prefix + "/") else []
        if len(parts) == 2 and parts[1] == "model":
            self._answer_model(query, parts[0])
        elif len(parts) == 4 and parts[2] == "demo" and parts[3] in ("start", "stop"):
            payload = query.payload
            try:
                body = orjson.loads(payload.to_bytes()) if payload is not None else {}
                if not isinstance(body, dict):
                    raise ValueError("expected a JSON object")
            except (ValueError, orjson.JSONDecodeError) as exc:
                _reply_error(query, "bad_payload", f"expected a JSON object: {exc}")
                return
            stream = self._stream(f"{self.prefix}/{parts[0]}/{parts[1]}/pose")
            if parts[3] == "start":
                self._demo_start(query, stream, body)
            else:
                self._demo_stop(query, stream, body)
        # anything else under the prefix is not ours to answer

    def _answer_model(self, query: Any, skill: str) -> None:
        try:
            model = self.service.get_model(skill, None, True)
        except ServiceError as exc:
            _reply_error(query, exc.error_type, exc.message, exc.field)
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
            _reply_error(query, exc.error_type, exc.message, exc.field)
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
            for skill in list(self._models):
                try:
                    entry = self._load(skill)
                except Exception:
                    log.exception("model refresh for %r failed", skill)
                    continue
                old = self._models.get(skill)
                if old is None or old.status != entry.status or old.version != entry.version:
                    self._install(skill, entry)
            now = time.monotonic()
            with self._streams_lock:
                idle = [k for k, st in self._streams.items()
                        if now - st.last_seen > self.options.idle_s and st.capture is None]
                gone = [self._streams.pop(k) for k in idle]
                self._m_streams.set(len(self._streams))
            for st in gone:
                st.closed = True
                try:
                    st.publisher.undeclare()
                except Exception:
                    pass


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


def _reply_error(query: Any, key: str, message: str, field: str | None = None) -> None:
    body = {"error": {"type": key, "field": field, "message": message}}
    try:
        query.reply_err(orjson.dumps(body), encoding=ENC_JSON)
    except Exception:
        log.exception("could not answer a live query")


__all__ = ["Bridge", "BridgeOptions", "ModelEntry", "Stream", "zenoh_config"]
