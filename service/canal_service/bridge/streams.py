"""The pose path's stream table: one :class:`Stream` per (skill, robot) key, created at its
first pose with its target publisher, forgotten when idle; the path's shared state and
metrics (:class:`Counts`).

Security: a key chunk that is not a plain name is refused, logged (rate-limited) and
counted as ``bad_key``; nothing is answered. Each stream's state is keyed by its exact key
and answers only on its own target key.
"""

from __future__ import annotations

import logging
import math
import queue
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import zenoh

from canal_core.tracker_bank import TrackerBank
from canal_protocol import keys as keyspace
from canal_protocol import wire

from .config import BridgeOptions
from .models import ModelEntry, ModelTable

log = logging.getLogger("canal_service.bridge")

ENC_JSON = zenoh.Encoding.APPLICATION_JSON
ENC_BINARY = zenoh.Encoding.APPLICATION_OCTET_STREAM
ENC_CDR = zenoh.Encoding.APPLICATION_CDR
#: Skills whose first samples wait for the loader thread at once (then the worker loads)
PARK_MAX = 256
ERROR_KEYS = ("outside_canal", "bad_payload", "wrong_dimension", "non_finite",
              "unknown_skill", "no_model", "internal_error", "bad_key", "too_many_streams",
              "restart_pending")

#: A stream capturing a demonstration or a correction is forgotten (and the capture with it)
#: this many times ``idle_s`` after its last pose: a person may pause, not leave it open.
CAPTURE_IDLE_FACTOR = 10

Job = tuple["Stream", wire.Pose, int, Any]


class Capture(list[wire.Pose]):
    """A capture's poses, at most ``cap`` of them: the poses past it are counted
    (``over``, the first one's seq in ``over_from``), not held, so that a capture left open
    while a robot streams keeps the bridge's memory bounded (each pose held is some 370
    bytes)."""

    __slots__ = ("cap", "over", "over_from")

    def __init__(self, cap: int, poses: list[wire.Pose] | None = None) -> None:
        super().__init__(poses or ())
        self.cap = cap
        self.over = 0
        self.over_from = -1

    def append(self, pose: wire.Pose) -> None:
        if len(self) < self.cap:
            super().append(pose)
            return
        if not self.over:
            self.over_from = pose.seq
        self.over += 1

    @property
    def came(self) -> int:
        """How many poses came: those held and those past the cap."""
        return len(self) + self.over

    def over_until(self, last_seq: Any) -> int:
        """How many of the poses past the cap a stop at ``last_seq`` (an int; anything else:
        every pose) would have stored."""
        if isinstance(last_seq, int) and last_seq < self.over_from:
            return 0
        return self.over


@dataclass(eq=False)
class Stream:
    """One (skill, robot) pose stream."""

    key: str
    skill: str
    robot: str
    publisher: Any
    bank: TrackerBank | None = None  # the bank of the model version it is tracked with
    slot: int = -1  # its row in that bank
    #: the model it is tracked with (ModelEntry.revision)
    revision: tuple[int, int] = (-1, -1)
    #: a model of several routes: the route it follows (None: the canal of all), why
    #: (canal_core.routes.RouteChoice.reason) and the model entry it was chosen in
    #: (ModelEntry.serial)
    route: int | None = None
    route_reason: str = ""
    route_serial: int = -1
    #: the last pose it was stepped with (the robot's position a glitch is told from)
    position: tuple[float, ...] | None = None
    #: the progress its last answer reported: an answer outside the canal never reports
    #: less (a held answer knows the section reached, not the fraction past it)
    progress: float = 0.0
    #: when its last pose was answered, ``restart_pending`` too (``time.monotonic``)
    position_at: float = 0.0
    #: a restart waiting to be confirmed (:meth:`..step.Stepper.restart_of`): the last pose
    #: that asked for it or was answered ``restart_pending``, and how many agreeing in a row
    restart_at: tuple[float, ...] | None = None
    restart_streak: int = 0
    #: the poses (by id) answered after poses of the stream were coalesced away: the poses
    #: that would have broken a streak are gone, so none is counted across such a gap
    after_gap: set[int] | None = None
    #: ... and the first of those poses
    restart_from: wire.Pose | None = None
    last_seen: float = 0.0
    last_seq: int = -1
    coalesced: int = 0
    cdr_seq: int = 0
    cdr_status: str = ""
    status_key: str = ""
    capture: Capture | None = None
    capture_from: int = 0
    #: the most poses a capture holds (:class:`Capture`, ``BridgeOptions.capture_max``)
    capture_max: int = 200_000
    #: which steered run the capture is (``capture_kind`` "steer") and which one
    #: ``steered`` holds: a run kept is cleared wherever its end has moved it meanwhile
    capture_run: int = 0
    steered_run: int = -1
    runs: int = 0
    capture_label: str | None = None
    #: None: the capture is a demonstration; "include" / "exclude": a correction; "steer":
    #: the poses of a steered run (kept in ``steered`` when the steering ends)
    capture_kind: str | None = None
    capture_weight: float = 1.0
    #: the skill the capture was started on (:func:`..storage.repository.skill_instance`):
    #: one deleted and created again under the name is another skill, and the capture ends
    #: with the one it began on
    capture_instance: str | None = None
    #: the last steering input (u, v, time.monotonic() it arrived), None when not steered
    steer: tuple[float, float, float] | None = None
    steer_at: float = 0.0
    #: the poses of the last steered run (for ``steer/keep``)
    steered: Capture | None = None
    #: ... and the skill they were steered on (as ``capture_instance``)
    steered_instance: str | None = None
    #: ... and the route they were steered on (``route``), numbered as in the model entry of
    #: ``steered_serial`` (a later version may number its routes otherwise)
    steered_route: int | None = None
    steered_serial: int = -1
    lock: threading.Lock = field(default_factory=threading.Lock)
    closed: bool = False
    # the recording: count deltas since the last batch, the rows kept, the rate limit
    rec_poses: int = 0
    rec_answered: int = 0
    rec_coalesced: int = 0
    rec_errors: int = 0
    rec_rows: list[tuple[Any, ...]] = field(default_factory=list)
    rec_next: int = 0
    rec_state: tuple[int, bool, bool] = (-1, False, False)


class Counts:
    """The worker's metrics as plain integers (read and reset by the metrics thread)."""

    __slots__ = (
        "coalesced",
        "decimated",
        "drains",
        "errors",
        "last_idle",
        "parked",
        "poses",
        "recorded",
        "steers",
        "step_bounds",
        "step_buckets",
        "step_sum",
        "switches",
        "targets",
        "unknown",
        "waiting",
    )

    def __init__(self, step_bounds: tuple[float, ...] = (math.inf,)) -> None:
        self.poses = 0
        self.targets = 0
        self.coalesced = 0
        self.errors: dict[str, int] = dict.fromkeys(ERROR_KEYS, 0)
        self.switches = 0
        self.steers = 0  # steering inputs held for their streams (steering thread)
        self.drains = 0  # drains handled (poses / drains: the mean drain size)
        #: the step histogram's upper bounds (the last one +inf) and per-bucket pose counts:
        #: the worker adds to them, the metrics thread hands the deltas to Prometheus
        self.step_bounds = step_bounds
        self.step_buckets = [0] * len(step_bounds)
        self.step_sum = 0.0
        self.last_idle = time.monotonic()
        self.waiting = True  # blocked on an empty queue
        self.recorded = 0  # poses handed to the recorder (with their targets)
        self.decimated = 0  # poses handled but not handed to the recorder (recording thread)
        self.unknown = 0  # poses of unknown skills while recording (worker thread)
        self.parked = 0  # poses that waited for their skill's model on the loader thread

    def snapshot(self) -> dict[str, Any]:
        return {"poses": self.poses, "targets": self.targets, "coalesced": self.coalesced,
                "errors": dict(self.errors), "switches": self.switches, "drains": self.drains,
                "recorded": self.recorded, "decimated": self.decimated + self.unknown,
                "parked": self.parked, "steers": self.steers,
                "step_buckets": list(self.step_buckets), "step_sum": self.step_sum}


#: Each count of :meth:`Counts.snapshot` that /metrics shows, and its counter on
#: :class:`canal_service.metrics.Metrics`. One table for a bridge in the service's process and
#: for the supervisor of bridge processes: a count missing from one of two lists never reached
#: /metrics from bridge processes.
COUNT_METRICS = {"poses": "live_poses", "targets": "live_targets", "coalesced": "live_coalesced",
                 "switches": "live_model_switches", "steers": "live_steers",
                 "recorded": "live_recorded", "decimated": "live_decimated"}


def add_counts(metrics: Any, now: dict[str, Any], before: dict[str, Any]) -> None:
    """Add each count's growth from ``before`` to ``now`` (snapshots) to its counter, and
    the step histogram's."""
    for name, counter in COUNT_METRICS.items():
        grown = now.get(name, 0) - before.get(name, 0)
        if grown > 0:
            getattr(metrics, counter).inc(grown)
    histogram = metrics.live_step_seconds
    buckets = now.get("step_buckets")
    if not isinstance(buckets, list) or len(buckets) != len(histogram.bounds):
        return  # a bridge with other bucket bounds: its counts would land in the wrong ones
    old = before.get("step_buckets")
    if not isinstance(old, list) or len(old) != len(buckets):
        old = [0] * len(buckets)
    deltas = [n - b for n, b in zip(buckets, old, strict=True)]
    total = float(now.get("step_sum", 0.0)) - float(before.get("step_sum", 0.0))
    if min(deltas) >= 0 and total >= 0 and (any(deltas) or total > 0):
        histogram.add(deltas, total)


class StreamTable:
    """The streams of one bridge and the state every layer of the
    :class:`~canal_service.bridge.posepath.PosePath` shares (its first layer)."""

    def __init__(self, options: BridgeOptions, models: ModelTable, counts: Counts) -> None:
        self.options = options
        self.prefix = options.prefix.rstrip("/")
        self.models = models
        self.counts = counts
        self.session: Any = None
        self.streams: dict[str, Stream] = {}
        self.streams_lock = threading.Lock()
        self.others: set[str] = set()  # keys of other shards' streams (a stray delivery)
        self._warned_at = 0.0
        hz = options.record_hz
        #: None: not recording; else the least time between two kept rows of a stream
        self.record_period_ns: int | None = None if hz is None else (
            int(1e9 / hz) if hz > 0 else 0)
        self.rec_lock = threading.Lock()
        self.retired: list[Stream] = []  # forgotten streams whose last counts are not sent
        self.now_ns = 0  # wall clock of the drain being answered (the rows' time)
        #: skill -> samples waiting for its model (under ``rec_lock``), in arrival order
        self.parked: dict[str, list[Any]] = {}
        #: the loader thread's queue of skills to load (:meth:`load_parked`); None: the
        #: worker loads a model itself at its skill's first pose
        self.loads: queue.SimpleQueue[str | None] | None = None
        self._flushing = False  # the loader is answering parked samples: park nothing


    def bad_key(self, key: str) -> None:
        self.counts.errors["bad_key"] += 1
        self.warn("refused a pose on %r: skill and robot must be plain key chunks "
                  "(no '*', '**', '$*', '?', '#', '@'); not answered", key)

    def existing(self, key: str) -> Stream | None:
        """The open stream of ``key``, never created (None when there is none)."""
        with self.streams_lock:
            st = self.streams.get(key)
        return None if st is None or st.closed else st

    def stream(self, key: str, skill: str, robot: str) -> Stream | None:
        """The stream of ``key``, created (with its target publisher) on first use; None
        when that would pass ``max_streams`` (:meth:`full_message` says so)."""
        with self.streams_lock:
            st = self.streams.get(key)
            if st is not None and not st.closed:
                return st
            if len(self.streams) >= self.options.max_streams:
                # every robot name makes a stream (a publisher, a tracker slot, a recording
                # entity): a client inventing names must not grow the process without bound
                return None
            k = keyspace.stream_keys(skill, robot, self.prefix)
            # Not express: an express put writes to the socket on the calling thread (10-35 us
            # measured here), a batched one hands over to Zenoh's TX task (< 1 us).
            # JSON by default: a JSON answer's put passes no encoding (0.2 us less a pose)
            publisher = self.session.declare_publisher(
                k.target, express=False, congestion_control=zenoh.CongestionControl.BLOCK,
                encoding=ENC_JSON)
            st = Stream(key, skill, robot, publisher, last_seen=time.monotonic(),
                        status_key=k.status, capture_max=self.options.capture_max)
            self.streams[key] = st
            return st

    def resolve(self, key: str) -> Stream | ModelEntry | str | None:
        """The stream of a pose key; the negative entry for an unknown skill; the skill's
        name when its samples are to be parked until the loader has its model; None for a
        key that is refused or another shard's."""
        if key in self.others:
            return None
        found = keyspace.stream_of(key, self.prefix)
        if found is None:
            self.bad_key(key)
            return None
        skill, robot = found
        shards = self.options.shards
        if shards > 1 and keyspace.shard_of(skill, robot, shards) != self.options.shard:
            if len(self.others) < 100_000:
                self.others.add(key)
            return None
        if skill in self.parked:
            return skill  # behind the samples already waiting: answered in order
        if self.loads is not None and not self._flushing and len(self.parked) < PARK_MAX \
                and self.models.cached(skill) is None:
            self.loads.put(skill)
            return skill
        entry = self.models.entry(skill)
        if entry.status == "unknown_skill":
            return entry
        st = self.stream(key, skill, robot)
        if st is None:
            return ModelEntry("too_many_streams", message=self.full_message(robot))
        return st

    def full_message(self, robot: str) -> str:
        """Why a new ``robot`` gets no stream: the process serves ``max_streams`` already."""
        return (f"expected at most {self.options.max_streams} live streams in this bridge "
                f"process, got a new robot {robot!r}; a stream is forgotten "
                f"{self.options.idle_s:g} s after its last pose or steering input")

    def warn(self, message: str, *args: Any) -> None:
        """Log a refused input at most once a second (a flood must not flood the log)."""
        now = time.monotonic()
        if now - self._warned_at > 1.0:
            self._warned_at = now
            log.warning(message, *args)

    def forget_idle(self, now: float) -> set[str]:
        """Close the streams idle for ``idle_s`` (a demonstration or correction being
        captured: for :data:`CAPTURE_IDLE_FACTOR` times that); the skills still live."""
        idle_s = self.options.idle_s
        held_s = CAPTURE_IDLE_FACTOR * idle_s
        with self.rec_lock, self.streams_lock:
            # A steered run's poses are kept as a capture, but only a demonstration or a
            # correction someone started holds its stream, and not for good: one started
            # with no poses after it would keep a slot (max_streams) for as long as it went on.
            idle = [k for k, st in self.streams.items()
                    if now - st.last_seen > idle_s
                    and (st.capture is None or st.capture_kind == "steer"
                         or now - st.last_seen > held_s)]
            gone = [self.streams.pop(k) for k in idle]
            live_skills = {st.skill for st in self.streams.values()}
            if self.record_period_ns is not None:
                self.retired.extend(gone)
            for st in gone:  # under rec_lock: the worker is not stepping the bank now
                release_slot(st)
        for st in gone:
            close_stream(st)
        return live_skills

    def close_streams(self) -> None:
        with self.rec_lock, self.streams_lock:
            streams, self.streams = list(self.streams.values()), {}
            if self.record_period_ns is not None:
                self.retired.extend(streams)
            for st in streams:
                release_slot(st)
        for st in streams:
            close_stream(st)


def end_steered_run(st: Stream, route: int | None, serial: int,
                    at: wire.Pose | None = None) -> None:
    """End the stream's steered run in progress: its poses (those before ``at``, the pose
    that ends it, when given) become the last steered run, steered on ``route`` of the model
    entry ``serial``. The poses from ``at`` on go on as a new run (the steering is still
    held). Nothing changes when no steered run is in progress, or none of its poses came
    before ``at``."""
    with st.lock:
        end_steered_run_locked(st, route, serial, at)


def end_steered_run_locked(st: Stream, route: int | None, serial: int,
                           at: wire.Pose | None = None) -> None:
    """:func:`end_steered_run`, the caller holding ``st.lock``."""
    poses = st.capture
    if st.capture_kind != "steer" or poses is None:
        return
    cut = len(poses)
    if at is not None:
        # the pose that ends the run was added by the decoder (a 2-D skill's CDR pose as
        # a copy of it), and perhaps a few after it in the same drain
        cut = next((i for i in range(len(poses) - 1, -1, -1)
                    if poses[i] is at or poses[i].seq == at.seq), len(poses))
    if cut == 0:
        return
    steered = Capture(poses.cap, poses[:cut])
    st.steered, st.steered_instance = steered, st.capture_instance
    st.steered_route, st.steered_serial = route, serial
    st.steered_run = st.capture_run
    # the poses past the cap came last: they belong to the run that goes on, if any
    rest = steered if at is None else Capture(poses.cap, poses[cut:])
    rest.over, rest.over_from = poses.over, poses.over_from
    if at is None:
        st.capture, st.capture_kind = None, None
    else:
        st.capture = rest
        st.capture_from = at.seq
        st.runs += 1
        st.capture_run = st.runs


def new_capture(st: Stream) -> Capture:
    """An empty capture for the stream, a run of its own (the caller holds ``st.lock``)."""
    st.runs += 1
    st.capture_run = st.runs
    return Capture(st.capture_max)


def release_slot(st: Stream) -> None:
    """Give the stream's bank slot back (callers hold ``rec_lock``: the worker is idle)."""
    if st.bank is not None:
        st.bank.release(st.slot)
        st.bank, st.slot = None, -1


def close_stream(st: Stream) -> None:
    st.closed = True
    try:
        st.publisher.undeclare()
    except Exception:
        pass
