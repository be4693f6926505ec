"""The Zenoh bridge: reactive canal_core trackers for many (skill, robot) pose streams.

Rooms: :mod:`.config` (options, Zenoh config, access report), :mod:`.models` (the model
table and negative cache), :mod:`.posepath` (streams and the worker that answers poses),
:mod:`.captures` (demonstrations, corrections and steered runs captured on a stream);
this module wires them to one Zenoh session and runs the threads. Key expressions come from
:mod:`canal_protocol.keys`.

Threads (no Zenoh callback thread runs our code on an unsharded bridge; poses arrive
through a Zenoh FIFO channel):

- **worker**: the only thread that steps trackers and publishes targets (see
  :mod:`.posepath`).
- **loader**: loads the model of a skill whose first pose finds none loaded (beyond the
  preload bound, or evicted), then answers the poses the worker parked for it, in order
  (:meth:`.posepath.PosePath.load_parked`): a model load never stalls the other robots'
  answers on the worker.
- **control**: answers the queryables (model, demo start/stop): database work, never on
  the pose path.
- **housekeeper**: every ``refresh_s`` re-reads the latest model version of the skills it
  serves (a fit elsewhere is picked up even without a push), forgets streams idle for
  ``idle_s`` and expired negative cache entries.
- **metrics** and **updates** (fit notices from other bridges: the new model is built on
  this thread, as on whichever thread brings a fit notice, never on the worker).
- **preload** (at start, when ``preload_max`` > 0): loads the models of the most recently
  fitted skills so their first poses find them ready, then ends (:attr:`Bridge.preloaded`).
- **compile**: at start, compiles the tracker kernel (:mod:`canal_core.tracker_kernel`,
  numba; a few seconds the first time, ~0.5 s from numba's cache afterwards). Until it is
  ready the banks step with numpy, so no pose waits for the compiler; ``/healthz`` says
  which (``tracker``: ``compiling``, ``compiled`` or ``numpy``).
- **recording** (when ``record_hz`` is set): every ``record_interval_s`` one message with
  what the worker kept for the recording and the per-stream counts, on
  ``{prefix}/@recorder/live/{bridge}`` (:func:`canal_protocol.keys.recorder_key`) for the
  service's live recorder (:mod:`canal_service.recording.live`). The service process hears
  ~10 messages a second per bridge instead of every pose and target. A crash loses at most
  the batch not yet sent; ``close()`` sends the last one.

Sharding: with ``shards = K > 1`` this bridge answers the robots whose name ends with a
character ``c`` with ``ord(c) % K == shard``. Subscribing by key
(``BridgeOptions.shard_subscribe``, by default from K = 4 on) declares one subscriber per
such character (:func:`canal_protocol.keys.shard_pose_keys`), so Zenoh delivers each pose to
one bridge only; those subscribers hand samples to the worker through one queue (a C-level
``SimpleQueue.put`` called on Zenoh's callback thread, no Python frame, but a GIL
acquisition per sample). Otherwise the bridge receives every pose through its FIFO channel
and drops the others' after a set lookup. When a fit lands,
every bridge hears it (``fit`` lines on stdin from ``canal serve``, and
``{prefix}/{skill}/model/updated`` puts between bridges).

Model switching: a stream holds the version its tracker was built from. On the first pose
after the version changed, the tracker is rebuilt from the new canal and seeded at the
section the live position is located at, so the stream keeps going from where the robot
is. A new stream and a pose with the ``restart`` flag are seeded the same way.
"""

from __future__ import annotations

import gc
import logging
import math
import os
import queue
import secrets
import sys
import threading
import time
from typing import Any

import orjson
import zenoh
from pydantic import ValidationError

import canal_core
from canal_core.tracker_kernel import compile_step_rows, numba_available
from canal_protocol import codecs, wire
from canal_protocol import keys as keyspace
from canal_protocol.schemas import SceneIn, shown_value

from ..errors import ServiceError, error_type
from ..memory import release_memory
from ..record_batches import encode_record_batch
from ..service import CanalService
from .captures import Captures, reply_error
from .config import BridgeOptions, access_of, config_value, per_mode, shard_of, zenoh_config
from .models import ModelEntry, ModelTable
from .posepath import PosePath
from .queries import STREAM_QUERIES, body_error
from .streams import ENC_JSON, ERROR_KEYS, Counts, Stream, add_counts

log = logging.getLogger("canal_service.bridge")

_BEHIND_S = 1.0
#: How long a bridge holds its recording batches while no recorder hears its key yet (the
#: service's recorder connects with retries, possibly after the first robots).
RECORDER_WAIT_S = 10.0
#: A recording batch that fails is logged at most once per this many seconds.
RECORD_LOG_S = 1.0
SWITCH_INTERVAL_S = 0.0005


class Bridge:
    """Serve live tracking over Zenoh for a :class:`~canal_service.service.CanalService`."""

    def __init__(self, service: CanalService, options: BridgeOptions | None = None) -> None:
        self.service = service
        self.options = options or BridgeOptions()
        self.prefix = self.options.prefix.rstrip("/")
        self.session: Any = None
        self.state = "stopped"
        self.detail: str | None = None
        #: how the trackers step: "compiling" (numpy meanwhile), "compiled" or "numpy"
        self.tracker = "compiling"
        self.listen: list[str] = []
        self.multicast_scouting: bool | None = None
        self.mode: str | None = None
        self.access: dict[str, Any] = {"access": "open", "tls": False, "acl": False,
                                       "acl_default": None}
        m = service.metrics
        # the worker counts its step histogram in plain ints on these bounds (+inf last)
        self.counts = Counts(m.live_step_seconds.bounds)
        self.models = ModelTable(service, self.options)
        self.path = PosePath(self.options, self.models, self.counts)
        self.captures = Captures(service, self.models, self.stream_route)
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._subscribers: list[Any] = []
        self._queue: queue.SimpleQueue[Any] | None = None
        self._queryable: Any = None
        self._updates: Any = None
        self._scenes: Any = None
        self._steers: Any = None
        #: skill -> the revision last announced or heard of (ModelEntry.revision)
        self._published: dict[str, tuple[int, int]] = {}
        self._metrics = m
        self._m_streams = m.live_streams
        self._m_error_children = {key: m.live_errors.labels(key) for key in ERROR_KEYS}
        self._flushed = Counts(self.counts.step_bounds).snapshot()
        #: this bridge's name on the recorder key (a restarted bridge gets a new one)
        self.bridge_id = f"b{self.options.shard}-{os.getpid()}-{secrets.token_hex(3)}"
        self._record_n = 0
        self._record_pub: Any = None
        self._record_lock = threading.Lock()
        self._record_said = -math.inf  # when a lost batch was last logged (monotonic)
        self._started = time.monotonic()
        #: set when the start-up preload has finished (or was not run)
        self.preloaded = threading.Event()

    @property
    def streams(self) -> dict[str, Stream]:
        """The live streams by pose key."""
        return self.path.streams

    # ---- lifecycle ----------------------------------------------------------------------------

    def start(self) -> bool:
        """Open the session and start the threads; False (and state "down") when Zenoh fails."""
        try:
            config = zenoh_config(self.options)
            self.mode = config_value(config, "mode")
            self.listen = per_mode(config_value(config, "listen/endpoints"), self.mode)
            self.multicast_scouting = config_value(config, "scouting/multicast/enabled")
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
        self.path.session = s
        recv, try_recv = self._subscribe_poses(s)
        self._queryable = s.declare_queryable(keyspace.everything(self.prefix),
                                              zenoh.handlers.FifoChannel(256))
        self._updates = s.declare_subscriber(keyspace.model_updated_wildcard(self.prefix),
                                             zenoh.handlers.FifoChannel(256))
        # Scenes are applied on Zenoh's own thread as they arrive: a scene put reaches every
        # bank before the worker's next drain (no queue behind a backlog of poses).
        self._scenes = s.declare_subscriber(keyspace.scene_wildcard(self.prefix),
                                            zenoh.handlers.Callback(self._hear_scene))
        self._steers = s.declare_subscriber(keyspace.steer_wildcard(self.prefix),
                                            zenoh.handlers.FifoChannel(1024))
        self.service.fit_listeners.append(self._on_fit)
        self.service.scene_listeners.append(self._on_scene)
        self.path.loads = queue.SimpleQueue()
        threads: list[tuple[str, Any, tuple[Any, ...]]] = [
            ("worker", self.path.work, (recv, try_recv)), ("loader", self.path.load_parked, ()),
            ("control", self._control, ()), ("housekeeper", self._housekeep, ()),
            ("metrics", self._flush_loop, ()), ("updates", self._hear_updates, ()),
            ("steer", self._hear_steers, ()),
            ("preload", self._preload, ()), ("compile", self._compile_tracker, ())]
        if self.options.record_hz is not None:
            # Blocking, not dropping: a batch is the only copy of what it carries.
            self._record_pub = s.declare_publisher(
                keyspace.recorder_key(self.bridge_id, self.prefix),
                congestion_control=zenoh.CongestionControl.BLOCK)
            threads.append(("recording", self._record_loop, ()))
        for name, target, args in threads:
            t = threading.Thread(target=target, args=args, name=f"canal-bridge-{name}",
                                 daemon=True)
            t.start()
            self._threads.append(t)
        self.state, self.detail = "ok", None
        self._started = time.monotonic()
        self._metrics.live_up.set(1)
        log.info("live bridge on %s (prefix %r, shard %d/%d, live path %s)",
                 ", ".join(self.listen) or "(config file)", self.prefix, self.options.shard,
                 self.options.shards, self.access["access"])
        return True

    def _compile_tracker(self) -> None:
        """Compile the tracker kernel off the pose path (the banks use it once it is ready)."""
        if not numba_available():
            self.tracker = "numpy"
            log.warning("numba is not installed: live trackers step with numpy (30-80 us a "
                        "call instead of 5-10)")
            return
        started = time.monotonic()
        try:
            compile_step_rows()
        except Exception:
            self.tracker = "numpy"
            log.exception("the tracker kernel did not compile: live trackers step with numpy")
            return
        self.tracker = "compiled"
        # numba's import and compiler leave ~120,000 long-lived objects (a full collection
        # then walks them for ~50 ms with the GIL held): frozen like the rest at start. No
        # collect first: the compiler's garbage is already gone (7 objects left, measured),
        # and a collect is itself that 50 ms stall.
        gc.freeze()
        log.info("tracker kernel ready in %.1f s", time.monotonic() - started)

    def _subscribe_poses(self, s: Any) -> tuple[Any, Any]:
        """The pose subscribers and the worker's (blocking, non-blocking) receive calls."""
        o = self.options
        if not o.subscribes_by_key():
            sub = s.declare_subscriber(keyspace.pose_wildcard(self.prefix),
                                       zenoh.handlers.FifoChannel(o.queue_capacity))
            self._subscribers = [sub]
            return sub.handler.recv, sub.handler.try_recv
        # Several key expressions, one worker: Zenoh gives each subscriber its own channel,
        # so they feed one queue. ``SimpleQueue.put`` is C: no Python frame on Zenoh's thread.
        q: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._queue = q
        put = q.put
        self._subscribers = [
            s.declare_subscriber(key, zenoh.handlers.Callback(put, indirect=False))
            for key in keyspace.shard_pose_keys(o.shard, o.shards, self.prefix)]
        get_nowait = q.get_nowait
        empty = queue.Empty

        def try_recv() -> Any:
            try:
                return get_nowait()
            except empty:
                return None

        return q.get, try_recv

    def close(self) -> None:
        """Stop the threads and close the session (idempotent)."""
        if self.session is None:
            return
        self._stop.set()
        if self._on_fit in self.service.fit_listeners:
            self.service.fit_listeners.remove(self._on_fit)
        try:
            self.service.scene_listeners.remove(self._on_scene)
        except ValueError:
            pass
        for entity in (*self._subscribers, self._queryable, self._updates, self._scenes,
                       self._steers):
            try:
                entity.undeclare()  # unblocks recv() in the worker / control thread
            except Exception:
                pass
        if self._queue is not None:
            self._queue.put(None)  # the sharded worker's "closed"
        if self.path.loads is not None:
            self.path.loads.put(None)
        for t in self._threads:
            t.join(timeout=5.0)
        self.path.close_streams()
        self.send_record()  # the worker has stopped: this is the last batch
        if self._record_pub is not None:
            try:
                self._record_pub.undeclare()
            except Exception:
                pass
            self._record_pub = None
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
                "streams": len(self.path.streams), **self.access,
                "shard": self.options.shard, "shards": self.options.shards,
                "coalesced": self.counts.coalesced, "drains": self.counts.drains,
                "parked": self.counts.parked, "routes": self.route_counts(),
                "tracker": self.tracker, "processes": 0}

    def route_counts(self) -> dict[str, dict[str, int]]:
        """Streams of each skill whose model has several routes, by the route they follow
        ("all": the canal of all the demonstrations)."""
        with self.path.streams_lock:
            streams = list(self.path.streams.values())
        counts: dict[str, dict[str, int]] = {}
        for st in streams:
            if self._routes_entry(st) is None:
                continue
            by_route = counts.setdefault(st.skill, {})
            key = "all" if st.route is None else str(st.route)
            by_route[key] = by_route.get(key, 0) + 1
        return counts

    def _routes_entry(self, st: Stream) -> ModelEntry | None:
        """The stream's model entry when it has several routes and the stream's route was
        chosen in it (``st.route`` is then current), else None."""
        entry = self.models.models.get(st.skill)
        if entry is None or entry.routes is None or st.route_serial != entry.serial:
            return None
        return entry

    def stream_route(self, st: Stream) -> int | None:
        """The route a stream follows in its skill's model now (None: one route, or the
        canal of all)."""
        return None if self._routes_entry(st) is None else st.route

    # ---- metrics (off the pose path) ----------------------------------------------------------

    def _flush_loop(self) -> None:
        while not self._stop.wait(0.25):
            try:
                self.flush_metrics()
            except Exception:
                log.exception("metrics flush failed")

    def flush_metrics(self) -> None:
        """Hand the worker's counts to Prometheus (deltas since the last flush)."""
        now, before = self.counts.snapshot(), self._flushed
        add_counts(self._metrics, now, before)
        for key, n in now["errors"].items():
            if n != before["errors"][key]:
                self._m_error_children[key].inc(n - before["errors"][key])
        self._flushed = now
        self._m_streams.set(len(self.path.streams))

    # ---- recording (off the pose path) ---------------------------------------------------------

    def _record_loop(self) -> None:
        while not self._stop.wait(self.options.record_interval_s):
            try:
                self.send_record()
            except Exception:
                # it would fail again every record_interval_s: once a second is enough
                if self._may_say_record():
                    log.exception("recording batch failed; its rows are lost (counted as a "
                                  "lost batch)")

    def _may_say_record(self) -> bool:
        now = time.monotonic()
        if now - self._record_said < RECORD_LOG_S:
            return False
        self._record_said = now
        return True

    def send_record(self) -> int:
        """Put what the streams kept for the recording since the last batch; the number of
        streams in it (0: nothing new, nothing sent)."""
        with self._record_lock:
            pub = self._record_pub
            if pub is None:
                return 0
            if (not pub.matching_status.matching and not self._stop.is_set()
                    and time.monotonic() - self._started < RECORDER_WAIT_S):
                return 0  # no recorder yet: keep the rows a little, it is connecting
            streams = self.path.take_record()
            if not streams:
                return 0
            # Rows taken and not sent are lost with their counts, as in a batch that never
            # arrived: their number is used up all the same, so the recorder counts the gap
            # as a lost batch and the recording does not say it is complete.
            try:
                left_out: list[tuple[tuple[Any, ...], Exception]] = []
                data = encode_record_batch(self.bridge_id, self._record_n, streams,
                                           left_out=left_out)
                if left_out:
                    self._record_n += 1  # the left-out streams' batch
                    gone = {id(stream) for stream, _ in left_out}
                    streams = [st for st in streams if id(st) not in gone]
                    # sent even with no stream left: the gap is seen now, not at the next one
                    data = encode_record_batch(self.bridge_id, self._record_n, streams)
                    if self._may_say_record():
                        (skill, robot, *_), exc = left_out[0]
                        log.warning("recording batch %d of %s left out %d stream(s) it could "
                                    "not encode (%s/%s: %s): counted as a lost batch",
                                    self._record_n - 1, self.bridge_id, len(left_out), skill,
                                    robot, exc)
                pub.put(data, encoding=wire.BINARY_ENCODING)
            finally:
                self._record_n += 1
            kept = sum(len(st[7]) for st in streams)
            # the metrics' identity is canal_live_poses_total == recorded + decimated; the
            # coalesced poses are not in canal_live_poses_total (they have their own counter)
            decimated = sum(st[6] - st[4] for st in streams)
            self.counts.recorded += kept
            self.counts.decimated += decimated
            return len(streams)

    # ---- models -------------------------------------------------------------------------------

    def _preload(self) -> None:
        try:
            started = time.monotonic()
            loaded = self.models.preload(self._stop)
            if loaded:
                log.info("preloaded the models of %d skills in %.3f s", len(loaded),
                         time.monotonic() - started)
        except Exception:  # the database may be unreachable now: first poses load instead
            log.exception("preloading models failed")
        finally:
            self.preloaded.set()

    def _on_fit(self, skill: str, version: int, canal: Any) -> None:
        """``CanalService.fit`` listener: serve the new version from the next pose on."""
        self.model_updated(skill, int(version), canal)

    def model_updated(self, skill: str, version: int, canal: Any = None,
                      announce: bool = True) -> None:
        """A fit landed (this process, ``canal serve`` or another bridge): build and install
        the new model on the calling thread (every shard serves every skill: shards split
        robots) and, when told, tell the other bridges on ``{prefix}/{skill}/model/updated``."""
        if not keyspace.is_plain_chunk(skill):
            return
        revision = self.models.updated(skill, canal, version)
        if revision is None:
            return
        if not announce:  # heard from another bridge: already announced
            self._published[skill] = revision
        elif self.session is not None and self._published.get(skill) != revision:
            self._published[skill] = revision
            try:
                self.session.put(keyspace.model_updated_key(skill, self.prefix),
                                 orjson.dumps({"version": version}), encoding=ENC_JSON)
            except Exception:
                log.exception("could not announce the new model of %r", skill)

    def _on_scene(self, skill: str, version: int, scene: Any) -> None:
        """``CanalService.put_scene`` listener: serve the new scene from the next pose on and
        tell the bridges elsewhere on ``{prefix}/{skill}/scene/updated``."""
        self.scene_updated(skill, int(version), scene, announce=True)

    def scene_updated(self, skill: str, version: int, scene: Any = None,
                      announce: bool = False) -> None:
        """A scene landed (stored by this process or another): serve it (``scene``, or read
        from the database when None) and, when told, announce its version."""
        if not keyspace.is_plain_chunk(skill):
            return
        if scene is None and version > self.models.scene_version(skill):
            self.models.reload_scene(skill)
        elif scene is not None:
            self.models.scene_changed(skill, version, scene)
        if announce and self.session is not None:
            try:
                self.session.put(keyspace.scene_updated_key(skill, self.prefix),
                                 orjson.dumps({"version": version}), encoding=ENC_JSON)
            except Exception:
                log.exception("could not announce the new scene of %r", skill)

    def _hear_scene(self, sample: Any) -> None:
        """A scene put (``{prefix}/{skill}/scene``, JSON ``{"obstacles": [...]}``) or another
        bridge's scene notice. Every bridge serves a put scene at once;
        shard 0 also stores it (a new version of the skill's scene, announced as REST's are)."""
        try:
            found = keyspace.scene_of_key(str(sample.key_expr), self.prefix)
            if found is None:
                return
            skill, notice = found
            body = orjson.loads(sample.payload.to_bytes())
            if notice:
                version = body.get("version") if isinstance(body, dict) else None
                if isinstance(version, int):
                    self.scene_updated(skill, version)
                return
            # The REST scene's own model: one set of rules for both ways in (fields, lengths).
            # A bare list is refused as REST refuses it: `[]` would remove every obstacle.
            checked = SceneIn.model_validate(body)
            dim = self.service.skill_dim(skill)
            scene = canal_core.obstacles.scene_from_list(
                [o.as_dict() for o in checked.obstacles], dim)
            if self.options.shard == 0:
                self.service.put_scene(skill, scene.to_list())  # -> _on_scene
            else:
                self.models.scene_changed(skill, self.models.scene_version(skill) + 1, scene)
        except (canal_core.CanalError, ServiceError, orjson.JSONDecodeError, ValidationError) as exc:
            log.warning("scene put on %s refused: %s", sample.key_expr, exc)
        except Exception:
            log.exception("scene put on %s failed", sample.key_expr)

    def _hear_updates(self) -> None:
        recv = self._updates.handler.recv
        while True:
            try:
                sample = recv()
            except Exception:
                return
            try:
                skill = keyspace.skill_of_update(str(sample.key_expr), self.prefix)
                body = orjson.loads(sample.payload.to_bytes())
                if skill is None or not isinstance(body, dict):
                    continue
                version = body.get("version")
                if isinstance(version, int):
                    self.model_updated(skill, version, announce=False)
            except Exception:
                log.exception("model update notice failed")

    # ---- steering (off the pose path) ----------------------------------------------------------

    def _hear_steers(self) -> None:
        recv = self._steers.handler.recv
        while True:
            try:
                sample = recv()
            except Exception:
                return
            try:
                self.steer_input(str(sample.key_expr), str(sample.encoding),
                                 sample.payload.to_bytes())
            except Exception:
                log.exception("steering input failed")

    def steer_input(self, key: str, encoding: str, data: bytes) -> bool:
        """Hold a steering input for the stream of ``key`` (``.../{robot}/steer``); the
        worker applies it at the stream's next poses. False when it is not this bridge's or
        cannot be read (a steering input has no answer: a bad one is logged and dropped)."""
        stream = keyspace.stream_of(key, self.prefix, keyspace.STEER)
        if stream is None:
            return False
        skill, robot = stream
        shards = self.options.shards
        if shards > 1 and shard_of(skill, robot, shards) != self.options.shard:
            return False
        try:
            u, v = codecs.decode_steer(encoding, data)
        except wire.WireError as exc:
            self.path.warn("steering input on %s refused: %s", key, exc.message)
            return False
        if self.models.entry(skill).status == "unknown_skill":
            self.path.warn("steering input on %s refused: unknown skill %r", key, skill)
            return False
        st = self.path.stream(keyspace.stream_keys(skill, robot, self.prefix).pose, skill, robot)
        if st is None:
            self.path.warn("steering input on %s refused: %s", key, self.path.full_message(robot))
            return False
        now = time.monotonic()
        st.last_seen = now  # steered: not idle
        if st.steer is None:
            st.steer_at = now
            self.captures.begin_steered(st)
        st.steer = (u, v, now)
        self.counts.steers += 1
        return True

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
                reply_error(query, "internal_error", "the bridge failed; see the service log")
            finally:
                try:
                    query.drop()
                except Exception:
                    pass

    def _answer_query(self, query: Any) -> None:
        parts = keyspace.query_of(str(query.key_expr), self.prefix)
        if parts is None:
            return  # a wildcard query (canal/*/arm1/demo/start, canal/**) is nobody's
        shards = self.options.shards
        if len(parts) == 2 and parts[1] == keyspace.MODEL:
            if self.options.shard == 0:  # one answer, not one per bridge
                self._answer_model(query, parts[0])
        elif len(parts) == 4 and (parts[2], parts[3]) in STREAM_QUERIES:
            skill, robot = parts[0], parts[1]
            if shards > 1 and shard_of(skill, robot, shards) != self.options.shard:
                return
            payload = query.payload
            try:
                body = orjson.loads(payload.to_bytes()) if payload is not None else {}
            except orjson.JSONDecodeError as exc:
                reply_error(query, "bad_payload", f"expected a JSON object, got invalid JSON ({exc})")
                return
            if not isinstance(body, dict):
                reply_error(query, "bad_payload",
                             f"expected a JSON object, got {shown_value(body)}")
                return
            refused = body_error(body, (parts[2], parts[3]))
            if refused is not None:
                reply_error(query, refused[0], refused[2], refused[1])
                return
            key = keyspace.stream_keys(skill, robot, self.prefix).pose
            if self.models.entry(skill).status == "unknown_skill":
                # a capture begun on the skill deleted since is answered for: its stop says
                # the capture is lost with the skill, as when a new skill took the name
                held = self.path.existing(key)
                if held is None or not self.captures.holds(held, (parts[2], parts[3])):
                    entry = self.models.entry(skill)
                    reply_error(query, "not_found", entry.message or "unknown skill", "skill")
                    return
            stream = self.path.stream(key, skill, robot)
            if stream is None:
                reply_error(query, "too_many_streams", self.path.full_message(robot), "robot")
                return
            self.captures.answer(query, stream, (parts[2], parts[3]), body)
        # anything else under the prefix is not ours to answer

    def _answer_model(self, query: Any, skill: str) -> None:
        try:
            model = self.service.get_model(skill, None, True)
        except ServiceError as exc:
            reply_error(query, error_type(exc), exc.message, exc.field)
            return
        query.reply(query.key_expr, orjson.dumps(model.model_dump(mode="json")),
                    encoding=ENC_JSON)

    # ---- housekeeping -------------------------------------------------------------------------

    def _housekeep(self) -> None:
        period = max(self.options.refresh_s, 0.05)
        expired = 0  # streams expired since memory was last handed back
        while not self._stop.wait(period):
            try:
                before = len(self.path.streams)
                live_skills = self.path.forget_idle(time.monotonic())
                expired += max(before - len(self.path.streams), 0)
                if expired >= TRIM_AFTER_EXPIRED:
                    # Thousands of streams gone leave their memory in the heaps: hand it
                    # back (malloc_trim only: a garbage collection here would stall the
                    # housekeeper for a busy process's whole heap).
                    release_memory(collect=False)
                    expired = 0
                self.models.refresh(live_skills)
            except Exception:  # one bad pass must not end every later refresh
                log.exception("bridge housekeeping failed")


#: Streams expired since the last trim that call for handing their memory back.
TRIM_AFTER_EXPIRED = 256


__all__ = ["Bridge", "BridgeOptions", "ModelEntry", "Stream", "access_of", "shard_of",
           "zenoh_config"]
