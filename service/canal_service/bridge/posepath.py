"""The pose path: samples in, ratio-rule targets out, on one worker thread.

The worker blocks on its pose channel (GIL released), drains everything else queued without
blocking and handles the drain as one batch: decode every pose, step the trackers of all
streams of one model in **one** vectorised numpy pass over the model's
:class:`canal_core.tracker_bank.TrackerBank` (every stream's tracker state is a slot of its
arrays: no per-tracker Python object on the way in or out), turn the answer arrays into
Python lists once per drain, then encode and put each answer. A stream with
several poses in one drain is stepped in order (one pass per pose). Metrics are plain
integers (:class:`Counts`); the bridge's metrics thread hands them to Prometheus.

*Overload policy*: when one stream has more than ``coalesce_backlog`` poses queued in one
drain, only its newest pose is answered; the older ones are counted per stream (the
target's ``coalesced``) and in ``canal_live_poses_coalesced_total``.

*Recording*: when the bridge records (``BridgeOptions.record_hz`` set), each stream keeps
the poses the recording wants, with their answers, as plain rows: at most ``record_hz`` per
second (0: every pose), plus every pose whose answer flips the status, ``inside`` or
``done``. The worker counts per stream what it received, answered, coalesced and answered
with an error; :meth:`PosePath.take_record` hands rows and count deltas to the bridge's
recording thread (under ``rec_lock``, which the worker holds for one drain at a time), so
every pose handled is either a row or counted as decimated.

*A skill's first pose* when its model is not loaded yet (beyond the preload bound, or
evicted after ``preload_keep_s``): loading takes milliseconds (a database read, decoding
the canal, building the tracker tables), and on the worker that would stall every other
robot. The worker parks the skill's samples instead and hands the skill to the bridge's
loader thread (:attr:`PosePath.loads`), which loads the model, installs it and answers the
parked samples in order, all under ``rec_lock`` (no drain runs meanwhile, and later samples
of the skill queue behind the parked ones). At most :data:`PARK_MAX` skills are parked at
once; beyond that (a flood of new names) the worker loads itself, as it does when no loader
runs (a :class:`PosePath` used without a bridge).

Security: a key chunk that is not a plain name is refused, logged (rate-limited) and
counted as ``bad_key``; nothing is answered. Each stream's state is keyed by its exact key
and answers only on its own target key.
"""

from __future__ import annotations

import bisect
import contextlib
import logging
import math
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import zenoh

from canal_core.tracker import start_section
from canal_core.tracker_bank import TrackerBank
from canal_protocol import keys as keyspace
from canal_protocol import wire

from .config import BridgeOptions
from .models import ModelEntry, ModelTable

log = logging.getLogger("canal_service.bridge")

ENC_JSON = zenoh.Encoding.APPLICATION_JSON
ENC_BINARY = zenoh.Encoding.APPLICATION_OCTET_STREAM
ENC_CDR = zenoh.Encoding.APPLICATION_CDR
_OK = wire.STATUS_CODES["ok"]
_OUTSIDE = wire.STATUS_CODES["outside_canal"]
_FJSON, _FBIN, _FCDR = wire.FORMAT_JSON, wire.FORMAT_BINARY, wire.FORMAT_CDR
MAX_DRAIN = 4096
#: Skills whose first samples wait for the loader thread at once (then the worker loads)
PARK_MAX = 256
_DONE_ETA = 1.0 + 1e-9
_pack_json = wire.pack_target_json
ERROR_KEYS = ("outside_canal", "bad_payload", "wrong_dimension", "non_finite",
              "unknown_skill", "no_model", "internal_error", "bad_key")

Job = tuple["Stream", wire.Pose, int, Any]


@dataclass(eq=False)
class Stream:
    """One (skill, robot) pose stream."""

    key: str
    skill: str
    robot: str
    publisher: Any
    bank: TrackerBank | None = None  # the bank of the model version it is tracked with
    slot: int = -1  # its row in that bank
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
                "parked": self.parked}


class PosePath:
    """The streams of one bridge and the worker that answers their poses."""

    def __init__(self, options: BridgeOptions, models: ModelTable, counts: Counts) -> None:
        self.options = options
        self.prefix = options.prefix.rstrip("/")
        self.models = models
        self.counts = counts
        self.session: Any = None
        self.streams: dict[str, Stream] = {}
        self.streams_lock = threading.Lock()
        self.others: set[str] = set()  # keys of other shards' streams (a stray delivery)
        self._bad_key_logged = 0.0
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

    # ---- streams ------------------------------------------------------------------------------

    def bad_key(self, key: str) -> None:
        self.counts.errors["bad_key"] += 1
        now = time.monotonic()
        if now - self._bad_key_logged > 1.0:  # a flood must not flood the log
            self._bad_key_logged = now
            log.warning("refused a pose on %r: skill and robot must be plain key chunks "
                        "(no '*', '**', '$*', '?', '#', '@'); not answered", key)

    def stream(self, key: str, skill: str, robot: str) -> Stream:
        """The stream of ``key``, created (with its target publisher) on first use."""
        with self.streams_lock:
            st = self.streams.get(key)
            if st is not None and not st.closed:
                return st
            k = keyspace.stream_keys(skill, robot, self.prefix)
            # Not express: an express put writes to the socket on the calling thread (10-35 us
            # measured here), a batched one hands over to Zenoh's TX task (< 1 us).
            # JSON by default: a JSON answer's put passes no encoding (0.2 us less a pose)
            publisher = self.session.declare_publisher(
                k.target, express=False, congestion_control=zenoh.CongestionControl.BLOCK,
                encoding=ENC_JSON)
            st = Stream(key, skill, robot, publisher, last_seen=time.monotonic(),
                        status_key=k.status)
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
        return self.stream(key, skill, robot)

    def forget_idle(self, now: float) -> set[str]:
        """Close the streams idle for ``idle_s`` (not capturing); the skills still live."""
        with self.rec_lock, self.streams_lock:
            idle = [k for k, st in self.streams.items()
                    if now - st.last_seen > self.options.idle_s and st.capture is None]
            gone = [self.streams.pop(k) for k in idle]
            live_skills = {st.skill for st in self.streams.values()}
            if self.record_period_ns is not None:
                self.retired.extend(gone)
            for st in gone:  # under rec_lock: the worker is not stepping the bank now
                _release(st)
        for st in gone:
            _close_stream(st)
        return live_skills

    def close_streams(self) -> None:
        with self.rec_lock, self.streams_lock:
            streams, self.streams = list(self.streams.values()), {}
            if self.record_period_ns is not None:
                self.retired.extend(streams)
            for st in streams:
                _release(st)
        for st in streams:
            _close_stream(st)

    # ---- the worker ---------------------------------------------------------------------------

    def work(self, recv: Callable[[], Any], try_recv: Callable[[], Any]) -> None:
        """The worker loop: ``recv`` blocks for a sample (raises, or returns None, when the
        channel closes); ``try_recv`` returns one or None."""
        counts = self.counts
        clock = time.perf_counter
        # NumPy keeps its error state per thread: set once here instead of an errstate
        # context per drain. Poses at 1e308 overflow in the step; they answer outside_canal.
        np.seterr(all="ignore")
        bounds = counts.step_bounds
        buckets = counts.step_buckets
        while True:
            counts.waiting = True
            try:
                sample = recv()
            except Exception:  # channel closed: shutting down
                return
            if sample is None:
                return
            counts.waiting = False
            started = clock()
            batch = [sample]
            drained = False
            while len(batch) < MAX_DRAIN:
                nxt = try_recv()
                if nxt is None:
                    drained = True
                    break
                batch.append(nxt)
            try:
                self._handle(batch)
            except Exception:
                log.exception("live step failed")
                counts.errors["internal_error"] += 1
            if drained:
                counts.last_idle = time.monotonic()
            # the step histogram as plain ints: each pose of the drain observes its share
            seconds = clock() - started
            n = len(batch)
            buckets[bisect.bisect_left(bounds, seconds / n)] += n
            counts.step_sum += seconds
            counts.drains += 1

    def batch(self, batch: list[Any]) -> None:
        """Decode, group, step and answer one drain of the pose channel (any thread)."""
        with np.errstate(all="ignore"):  # 1e308 poses overflow; they answer outside
            self._handle(batch)

    def _handle(self, batch: list[Any]) -> None:
        """:meth:`batch` on the worker, whose NumPy error state is already "ignore"."""
        with self.rec_lock:
            self._handle_locked(batch)

    def _handle_locked(self, batch: list[Any]) -> None:
        self.now_ns = time.time_ns()
        for jobs in self.decode_batch(batch):
            for entry, group, targets in self.step(jobs):
                self.answer_all(entry, group, targets)

    def load_parked(self) -> None:
        """The loader thread: load each parked skill's model off the worker, then install
        it and answer the skill's parked samples in one ``rec_lock`` hold (so no drain
        answers a later sample of the skill first). Returns when ``loads`` gets None."""
        loads = self.loads
        assert loads is not None
        while True:
            skill = loads.get()
            if skill is None:
                return
            try:
                entry: ModelEntry | None = self.models.load(skill)
            except Exception:  # the database is away: the answers say so (internal_error)
                log.exception("loading the model of %r failed", skill)
                entry = None
            with self.rec_lock, np.errstate(all="ignore"):
                if entry is not None:
                    self.models.install(skill, entry)
                samples = self.parked.pop(skill, [])
                self._flushing = True  # a failed load is retried once, here, not parked again
                try:
                    if samples:
                        self._handle_locked(samples)
                except Exception:
                    log.exception("answering the first poses of %r failed", skill)
                    self.counts.errors["internal_error"] += 1
                finally:
                    self._flushing = False

    def take_record(self) -> list[tuple[Any, ...]]:
        """Each stream's rows and count deltas since the last call, as
        ``(skill, robot, poses, answered, coalesced, errors, decimated, rows)`` (streams
        with nothing new are left out); see :func:`canal_service.record_batches.encode_record_batch`."""
        out = []
        with self.rec_lock:
            retired, self.retired = self.retired, []
            for st in [*self.streams.values(), *retired]:
                if not (st.rec_poses or st.rec_errors or st.rec_answered):
                    continue
                rows, st.rec_rows = st.rec_rows, []
                out.append((st.skill, st.robot, st.rec_poses, st.rec_answered,
                            st.rec_coalesced, st.rec_errors, st.rec_poses - len(rows), rows))
                st.rec_poses = st.rec_answered = st.rec_coalesced = st.rec_errors = 0
        return out

    def decode_batch(self, batch: list[Any]) -> list[list[Job]]:
        """The drain as rounds of jobs: round k holds each stream's k-th pose to answer."""
        if len(batch) == 1:  # the worker keeps up: most drains are one tick's poses
            s = batch[0]
            groups: dict[str, list[Any]] = {str(s.key_expr): batch}
        else:
            groups = {}
            for s in batch:
                key = str(s.key_expr)
                group = groups.get(key)
                if group is None:
                    groups[key] = [s]
                else:
                    group.append(s)
        counts = self.counts
        backlog = self.options.coalesce_backlog
        now = time.monotonic()
        first: list[Job] = []
        rounds: list[list[Job]] = [first]
        streams = self.streams
        decode = self.decode
        for key, samples in groups.items():
            st = streams.get(key)
            if st is None or st.closed:
                found = self.resolve(key)
                if found is None:
                    continue
                if isinstance(found, str):
                    self.parked.setdefault(found, []).extend(samples)
                    counts.parked += len(samples)
                    continue
                if isinstance(found, ModelEntry):
                    for s in samples:
                        self.answer_unknown(key, s, found)
                    continue
                st = found
            st.last_seen = now
            n = len(samples)
            st.rec_poses += n
            if n == 1:
                job = decode(st, samples[0], True)
                if job is not None:
                    first.append(job)
                continue
            if n > backlog:
                skipped = n - 1
                if st.capture is not None:
                    for s in samples[:-1]:
                        decode(st, s, False)
                st.coalesced += skipped
                st.rec_coalesced += skipped
                counts.coalesced += skipped
                samples = samples[-1:]
            k = 0
            for s in samples:
                job = decode(st, s, True)
                if job is None:
                    continue
                if k == len(rounds):
                    rounds.append([])
                rounds[k].append(job)
                k += 1
        return rounds

    def decode(self, st: Stream, sample: Any, answer: bool) -> Job | None:
        """One sample as a pose job, or None (answered with an error, or not to answer)."""
        data = sample.payload.to_bytes()
        encoding = sample.encoding
        ros = None
        if answer:
            self.counts.poses += 1
        try:
            if encoding == ENC_JSON:  # an object comparison, cheaper than str() (0.15 us)
                fmt = _FJSON
                pose = wire.decode_pose_json(data)
            else:
                fmt = wire.pose_format(str(encoding), data)
                pose, ros = wire.decode_pose_as(fmt, data, st.cdr_seq)
                if ros is not None:
                    st.cdr_seq += 1
        except wire.WireError as exc:
            if answer:
                self.error(st, None, exc.key, exc.message, fmt)
            return None
        st.last_seq = pose.seq
        if st.capture is not None:
            with st.lock:
                if st.capture is not None and pose.seq >= st.capture_from:
                    st.capture.append(pose)
        if not answer:
            return None
        return st, pose, fmt, ros

    def step(self, jobs: list[Job]) -> list[tuple[ModelEntry, list[Job], list[list[float]]]]:
        """Step every job's tracker, one bank pass per model, the answers as packed rows
        (:meth:`canal_core.tracker_bank.TrackerBank.step_packed`, one ``tolist()`` a pass); jobs
        that cannot be stepped are answered with their error here. The caller silences
        NumPy's overflow warnings (:meth:`batch`, or the worker thread's error state)."""
        by_model: dict[int, tuple[ModelEntry, list[Job], list[int],
                                  list[tuple[float, ...]]]] = {}
        models = self.models.models
        # most drains are one skill's poses: the last job's model and lists are reused
        last_skill = None
        entry: ModelEntry | None = None
        group_jobs: list[Job] = []
        slots: list[int] = []
        positions: list[tuple[float, ...]] = []
        for job in jobs:
            st, pose, fmt, _ros = job
            if st.skill != last_skill:
                entry = models.get(st.skill)
                if entry is None:
                    entry = self.models.entry(st.skill)
                if entry.status != "ok":
                    last_skill = None
                    self.error(st, pose.seq, entry.status, entry.message, fmt)
                    continue
                last_skill = st.skill
                group = by_model.get(id(entry))
                if group is None:
                    group = by_model[id(entry)] = (entry, [], [], [])
                _, group_jobs, slots, positions = group
            assert entry is not None
            position = pose.position
            if len(position) != entry.dim:
                if fmt == _FCDR and entry.dim == 2:  # a PoseStamped always has z
                    position = position[:2]
                else:
                    self.error(st, pose.seq, "wrong_dimension",
                               f"expected {entry.dim} coordinates for skill {st.skill!r}, "
                               f"got {len(position)}", fmt)
                    continue
            if st.bank is not entry.bank or st.version != entry.version or pose.restart:
                self._seed(st, entry, position)
            group_jobs.append(job)
            slots.append(st.slot)
            positions.append(position)
        out = []
        for model, model_jobs, model_slots, model_positions in by_model.values():
            if not model_jobs:
                continue
            assert model.bank is not None
            out.append((model, model_jobs, model.bank.step_packed(
                model_slots, np.array(model_positions, dtype=np.float64)).tolist()))
        return out

    def _seed(self, st: Stream, entry: ModelEntry, position: tuple[float, ...]) -> None:
        """The stream's slot in the entry's bank, started at the section the robot is
        located at (a new stream, a restart, a model switch)."""
        if st.bank is not None and st.version != entry.version:
            self.counts.switches += 1
        bank = entry.bank
        assert bank is not None
        if st.bank is not bank:
            _release(st)
            st.bank, st.slot = bank, bank.add()
        point = np.array(position, dtype=np.float64)
        try:
            located = int(entry.canal.reproduce_detailed(point).section_index)
            # a first pose far from the canal (a glitch?) places nothing: from the first
            # section, where the tracker places the stream at its first pose near the canal
            bank.reset(st.slot, start_section(bank.geometry, point, located))
        except Exception:  # a start no section brackets: from the first one
            bank.reset(st.slot, 0)
        st.version = entry.version

    def answer_all(self, entry: ModelEntry, group: list[Job], rows: list[list[float]]) -> None:
        """Publish the answer of each job of one bank pass (and keep it for the recording
        when it is due). ``rows`` are the pass's packed answers: target (D), progress, eta,
        section, inside, done, velocity (D), orientation (4).

        One loop with no call per answer but the encoder's and the put: on a one-robot
        bridge this runs once a millisecond on cold caches, where every Python call and
        temporary counts (the lean path halved a cold pose's cost)."""
        d = entry.dim
        v0, o0 = d + 5, 2 * d + 5
        bank = entry.bank
        assert bank is not None
        with_velocity, with_orientation = bank.has_velocity, bank.has_orientation
        version = entry.version
        counts = self.counts
        period = self.record_period_ns
        now = self.now_ns
        for (st, pose, fmt, ros), row in zip(group, rows, strict=True):
            target = row[:d]
            progress = row[d]
            eta = row[d + 1]
            section = int(row[d + 2])
            inside = row[d + 3] != 0.0
            # "done" only counts at the end *and* within the last sections: a pose far
            # beyond the last plane (50, 50, 50; 1e308) is lost, not finished
            done = row[d + 4] != 0.0 and eta <= _DONE_ETA
            velocity = row[v0:o0] if with_velocity else None
            if with_orientation:
                orientation: list[float] | None = row[o0:]
            elif pose.orientation is not None:
                orientation = list(pose.orientation)
            else:
                orientation = None
            if inside or done:
                code = _OK
                status = "ok"
            else:
                code = _OUTSIDE
                status = "outside_canal"
                progress, target, eta = self._outside(entry, row, section, target, eta)
            st.rec_answered += 1
            if period is not None and (now >= st.rec_next or code != st.rec_state[0]
                                       or inside != st.rec_state[1] or done != st.rec_state[2]):
                # a row when due, or when the status, inside or done flips
                st.rec_next = now + period
                st.rec_state = (code, inside, done)
                st.rec_rows.append((now, pose.position, pose.orientation, target, orientation,
                                    progress, eta, section, inside, done, status))
            if fmt == _FJSON:  # the publisher's default encoding
                st.publisher.put(_pack_json(
                    pose.seq, status, target, progress, eta, section, inside, done,
                    version, orientation, velocity, st.coalesced))
            elif fmt == _FBIN:
                st.publisher.put(wire.pack_target(
                    pose.seq, code, target, progress, eta, section, inside, done, version,
                    orientation, velocity, st.coalesced), encoding=ENC_BINARY)
            else:
                self._answer_cdr(st, pose, ros, entry, target, progress, eta, section, inside,
                                 done, orientation, status)
        counts.targets += len(rows)

    def _outside(self, entry: ModelEntry, row: list[float], section: int,
                 target: list[float], eta: float) -> tuple[float, list[float], float]:
        """An answer that is neither inside nor done: its progress, target and eta."""
        self.counts.errors["outside_canal"] += 1
        n = entry.canal.n_sections
        d = entry.dim
        # lost beyond the end is not the end reached: progress is the located section's
        progress = section / max(n - 1, 1) if row[d + 4] != 0.0 else row[d]
        if not all(map(math.isfinite, target)):
            # overflowed: the way back in is the section ahead's centre
            target = entry.canal.directrix[min(section + self.options.lookahead,
                                               n - 1)].tolist()
        if not math.isfinite(eta):
            eta = 1e308
        return progress, target, eta

    def _answer_cdr(self, st: Stream, pose: wire.Pose, ros: Any, entry: ModelEntry,
                    target: list[float], progress: float, eta: float, section: int,
                    inside: bool, done: bool, orientation: list[float] | None,
                    status: str) -> None:
        """A ROS 2 robot's answer: a PoseStamped on the target key, the status (JSON) on
        the status key when it changes."""
        position = list(target)
        if len(position) == 2:
            position.append(pose.position[2])
        st.publisher.put(wire.encode_pose_stamped_cdr(ros, position, orientation),
                         encoding=ENC_CDR)
        if status != st.cdr_status:
            st.cdr_status = status
            self.session.put(st.status_key, wire.target_json(wire.Target(
                pose.seq, status, tuple(position[:entry.dim]), progress, eta, section,
                inside, done, entry.version, None,
                None if orientation is None else tuple(orientation),  # type: ignore[arg-type]
                coalesced=st.coalesced)), encoding=ENC_JSON)

    def error(self, st: Stream, seq: int | None, key: str, message: str | None,
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
        st.rec_errors += 1

    def answer_unknown(self, key: str, sample: Any, entry: ModelEntry) -> None:
        """An unknown skill's answer, on a put without a declared publisher (no stream)."""
        self.counts.poses += 1
        data = sample.payload.to_bytes()
        encoding = str(sample.encoding)
        seq: int | None = None
        fmt = wire.pose_format(encoding, data)
        if fmt != _FCDR:
            with contextlib.suppress(wire.WireError):
                seq = wire.decode_pose_as(fmt, data)[0].seq
        answer = wire.Target(seq=seq, status=entry.status, message=entry.message)
        base = key[: -len(keyspace.POSE)]
        if fmt == _FJSON:
            self.session.put(base + keyspace.TARGET, wire.target_json(answer), encoding=ENC_JSON)
        elif fmt == _FBIN:
            self.session.put(base + keyspace.TARGET, wire.encode_target(answer),
                             encoding=ENC_BINARY)
        else:
            self.session.put(base + keyspace.STATUS, wire.target_json(answer),
                             encoding=ENC_JSON)
        self.counts.targets += 1
        self.counts.errors[entry.status] += 1
        if self.record_period_ns is not None:
            self.counts.unknown += 1  # no stream, nothing to record: decimated


def _release(st: Stream) -> None:
    """Give the stream's bank slot back (callers hold ``rec_lock``: the worker is idle)."""
    if st.bank is not None:
        st.bank.release(st.slot)
        st.bank, st.slot = None, -1


def _close_stream(st: Stream) -> None:
    st.closed = True
    try:
        st.publisher.undeclare()
    except Exception:
        pass


__all__ = ["ERROR_KEYS", "Counts", "PosePath", "Stream"]
