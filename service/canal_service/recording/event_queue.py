"""The recorder's intake: what callers (request handlers, the live bridge) call. Every
record method only enqueues and never raises; the writer thread
(:class:`~canal_service.recording.recorder.Recorder`) owns every file.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .events import (
    ControlEvent,
    DemoAdded,
    DemoRef,
    DemoRemoved,
    LiveRows,
    ModelFitted,
    ReproductionMade,
    SceneChanged,
    SkillDeleted,
    live_rows,
)
from .rerun_log import view_coordinates
from .source import DbSource

if TYPE_CHECKING:
    from .segments import SkillState

log = logging.getLogger("canal_service.recording")

# A deleted skill's delete time is kept to tell its late live rows from those of a skill
# created again under its name; rows are minutes late at worst, so older times are
# forgotten once many names have been deleted.
_DELETES_KEPT = 256
_DELETE_HORIZON_NS = 600 * 1_000_000_000


def _route(value: Any) -> int:
    """A target's route as a live row's column: -1 for none."""
    return -1 if value is None or int(value) < 0 else int(value)


def _vector(value: Any) -> list[float]:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim != 1 or not 1 <= arr.shape[0] <= 16:
        raise ValueError(f"expected a position of 1 to 16 coordinates, got shape {arr.shape}")
    return arr.tolist()


class RecorderQueue:
    """The queues and state of a :class:`~canal_service.recording.recorder.Recorder`, and its
    record methods (the first of its layers; see that class for the parameters)."""

    def __init__(self, root: Path, *, enabled: bool = True, flush_interval_s: float = 1.0,
                 live_max_hz: float | None = 100.0, live_queue_size: int = 20_000,
                 event_queue_size: int = 10_000, idle_close_s: float = 60.0,
                 export_timeout_s: float = 30.0, source: DbSource | None = None,
                 coordinates: str = "RIGHT_HAND_Z_UP", quiet_s: float = 0.25,
                 max_lag_s: float = 30.0, max_robots: int = 1024) -> None:
        self.quiet_s = float(quiet_s)
        #: Robots whose live rows a skill's recording draws (robot names are the clients'
        #: choice: each one is entities of their own, and a recording of tens of thousands
        #: no longer reads back); the rows of robots past it are counted as dropped.
        self.max_robots = int(max_robots)
        self._robots: dict[str, set[str]] = {}
        self._robots_full: set[str] = set()
        self.max_lag_s = float(max_lag_s)
        self._last_put = 0.0
        self._urgent = 0  # urgent events queued (export, rebuild, reconcile, stop)
        self._urgent_lock = threading.Lock()
        view_coordinates(coordinates)  # a bad name fails here, not in the writer
        self.coordinates = coordinates
        self.source = source
        self._dims: dict[str, int] = {}
        self.reconciled: dict[str, int] = {"demos": 0, "models": 0, "removed": 0,
                                           "reproductions": 0}
        self.root = Path(root)
        self.enabled = enabled
        self.flush_interval_s = float(flush_interval_s)
        self.idle_close_s = float(idle_close_s)
        self.export_timeout_s = float(export_timeout_s)
        self._events: deque[ControlEvent] = deque()
        self._event_cap = int(event_queue_size)
        self._live: deque[LiveRows] = deque()
        self._live_cap = max(int(live_queue_size) // 2, 1)  # rows: a pose and a target each
        self._live_queued = 0  # rows in _live
        self._live_lock = threading.Lock()
        self._live_last: dict[tuple[str, str], tuple[int, bool, bool]] = {}
        self._period_ns = int(1e9 / live_max_hz) if live_max_hz else 0
        self._wake = threading.Event()
        self._state_lock = threading.Lock()
        self._skill_locks: dict[str, threading.RLock] = {}
        self._errors: dict[str, str] = {}
        self._skills: dict[str, SkillState] = {}
        self._rerun_env: dict[str, str] | None = None
        # Each skill's instance in the database, read at most once per pass of the writer.
        self._current: dict[str, str | None] = {}
        self.dropped_events = 0
        self.stale_events = 0  # events about a skill instance that is gone: not written
        #: Events recorded without a part the logs cannot hold (named in a warning)
        self.incomplete = 0
        self.dropped_live = 0
        #: Live samples (two per row) of a skill deleted since: neither written nor lost
        self.stale_live = 0
        # CPU seconds the writer thread spent on its work (not waiting): what the recorder
        # costs the process, whatever else runs in it (the upload benchmark reads it).
        self.writer_cpu_s = 0.0
        self.decimated_live = 0
        self.written_live = 0
        # Live poses per (skill, robot): written but not yet flushed (by skill), flushed to
        # the files (recorded), lost (dropped), of a skill deleted since (stale: its
        # recording is gone with it, nothing was lost); the live source's completeness
        # reads them.
        self._live_unflushed: dict[str, dict[str, int]] = {}
        self._live_recorded: dict[tuple[str, str], int] = {}
        self._live_dropped: dict[tuple[str, str], int] = {}
        self._live_stale: dict[tuple[str, str], int] = {}
        # Each deleted skill's last delete time: live rows answered before it are that
        # skill's, never those of a skill created again under its name.
        self._deleted_ns: dict[str, int] = {}
        self._closed = not enabled
        self.live_source: Any = None  # a LiveSubscriber feeding live_rows()
        self._thread: threading.Thread | None = None

    def demo_added(self, skill: str, dim: int, demo_id: int, positions: Any, timestamps: Any,
                   label: str | None, orientations: Any = None) -> None:
        """A demonstration was stored: positions (T, D), timestamps (T,) or None.

        With a database ``source`` only the id is queued (the writer reads the stored arrays,
        orientations included, in batches); without one the arrays are copied.
        """
        if self._closed:
            return
        try:
            if self.source is not None:
                self._put(DemoRef(time.time_ns(), skill, int(demo_id)))
                return
            ts = None if timestamps is None else np.array(timestamps, dtype=np.float64)
            q = None if orientations is None else np.array(orientations, dtype=np.float64)
            self._put(DemoAdded(time.time_ns(), skill, int(demo_id),
                                np.array(positions, dtype=np.float64, ndmin=2),
                                ts, None if label is None else str(label), q))
        except Exception:
            self._caller_error("demo_added")

    def demo_removed(self, skill: str, demo_id: int, *, instance: str | None = None) -> None:
        """A demonstration was deleted (cleared in the recording from now on); ``instance``
        is the skill instance it was deleted from, when known."""
        if self._closed:
            return
        try:
            self._put(DemoRemoved(time.time_ns(), skill, int(demo_id), instance))
        except Exception:
            self._caller_error("demo_removed")

    def model_fitted(self, skill: str, version: int, canal: Any, *, t_ns: int | None = None,
                     instance: str | None = None) -> None:
        """A model version was fitted (geometry is built on the writer thread); ``t_ns`` is
        its stored creation time and ``instance`` the skill instance, when known."""
        if self._closed:
            return
        try:
            self._put(ModelFitted(time.time_ns() if t_ns is None else int(t_ns), skill,
                                  int(version), canal, instance))
        except Exception:
            self._caller_error("model_fitted")

    def scene_changed(self, skill: str, version: int, obstacles: list[dict[str, Any]], dim: int,
                      *, t_ns: int | None = None, instance: str | None = None) -> None:
        """The skill's scene is now ``obstacles`` (canal_core's JSON form) at ``version``;
        ``instance`` is the skill instance whose scene it is, when known."""
        if self._closed:
            return
        try:
            self._put(SceneChanged(time.time_ns() if t_ns is None else int(t_ns), skill,
                                   int(version), [dict(o) for o in obstacles], int(dim),
                                   instance))
        except Exception:
            self._caller_error("scene_changed")

    def reproduction(self, skill: str, version: int, result: Any, *, number: int | None = None,
                     t_ns: int | None = None, instance: str | None = None) -> None:
        """A reproduction was computed with model ``version``; ``number``, ``t_ns`` and
        ``instance`` when the database keeps it (the recorder numbers it otherwise)."""
        if self._closed:
            return
        try:
            self._put(ReproductionMade(time.time_ns() if t_ns is None else int(t_ns), skill,
                                       int(version), result,
                                       None if number is None else int(number), instance))
        except Exception:
            self._caller_error("reproduction")

    def live(self, skill: str, robot: str, position: Any, target: Any,
             t_ns: int | None = None, orientation: Any = None) -> None:
        """One live tracker step: robot ``position`` (D,) and the ``TrackerTarget``.

        Kept at most ``live_max_hz`` per (skill, robot), plus every step whose ``inside`` or
        ``done`` flag differs from the last kept one (the bridges' rule); queued as one row (a
        pose and its target). The service's live recording comes from the bridges' batches
        instead (:class:`~.live.LiveSubscriber`, :meth:`live_rows`).
        """
        if self._closed:
            return
        try:
            t = time.time_ns() if t_ns is None else int(t_ns)
            inside, done = bool(target.inside), bool(target.done)
            row = live_rows(skill, robot, [t], _vector(position), orientation,
                            _vector(target.target), getattr(target, "orientation", None),
                            [float(target.progress)], [float(target.eta)],
                            [int(target.section_index)], [inside], [done],
                            [_route(getattr(target, "route", None))])
            key = (skill, robot)
            with self._live_lock:
                last = self._live_last.get(key)
                if (last is not None and 0 <= t - last[0] < self._period_ns
                        and last[1] == inside and last[2] == done):
                    self.decimated_live += 2  # a pose and a target sample
                    return
                self._live_last[key] = (t, inside, done)
            self.live_rows([row])
        except Exception:
            self._caller_error("live")

    def live_rows(self, chunks: list[LiveRows]) -> None:
        """Queue live rows a bridge already chose (no rate limit here). Beyond the queue's
        size (``live_queue_size`` samples, two per row) the oldest rows are dropped (counted
        per stream)."""
        if self._closed:
            return
        with self._live_lock:
            live = self._live
            for chunk in chunks:
                live.append(chunk)
                self._live_queued += len(chunk)
            excess = self._live_queued - self._live_cap
            while excess > 0:
                old = live[0]
                k = min(len(old), excess)
                if k == len(old):
                    live.popleft()
                else:
                    live[0] = old.tail(len(old) - k)
                excess -= k
                self._live_queued -= k
                self.dropped_live += 2 * k
                key = (old.skill, old.robot)
                self._live_dropped[key] = self._live_dropped.get(key, 0) + k

    def live_stream_counts(self) -> tuple[dict[tuple[str, str], int],
                                          dict[tuple[str, str], int],
                                          dict[tuple[str, str], int]]:
        """Live poses per (skill, robot): (recorded, i.e. flushed to the files; dropped;
        stale, i.e. of a skill deleted since)."""
        with self._live_lock:
            return dict(self._live_recorded), dict(self._live_dropped), dict(self._live_stale)

    def forget_live_streams(self, keys: list[tuple[str, str]]) -> None:
        """Stop counting these (skill, robot) streams one by one (their counts were summed by
        the live source: :meth:`~.live.LiveSubscriber.health`)."""
        with self._live_lock:
            for key in keys:
                self._live_recorded.pop(key, None)
                self._live_dropped.pop(key, None)
                self._live_stale.pop(key, None)

    def _live_count(self, skill: str, robot: str, n: int) -> None:
        unflushed = self._live_unflushed.setdefault(skill, {})
        unflushed[robot] = unflushed.get(robot, 0) + n

    def _live_settle(self, skill: str, into: dict[tuple[str, str], int]) -> None:
        """The skill's unflushed live poses are now recorded (or dropped)."""
        unflushed = self._live_unflushed.pop(skill, None)
        if not unflushed:
            return
        with self._live_lock:
            for robot, n in unflushed.items():
                into[(skill, robot)] = into.get((skill, robot), 0) + n

    def skill_deleted(self, skill: str) -> None:
        """The skill is gone: its recording is deleted."""
        if self._closed:
            return
        try:
            t = time.time_ns()
            with self._live_lock:
                for key in [k for k in self._live_last if k[0] == skill]:
                    del self._live_last[key]
                self._deleted_ns[skill] = t
                if len(self._deleted_ns) > _DELETES_KEPT:  # many names deleted: forget old ones
                    cutoff = t - _DELETE_HORIZON_NS
                    self._deleted_ns = {k: v for k, v in self._deleted_ns.items() if v > cutoff}
            self._put(SkillDeleted(t, skill))
        except Exception:
            self._caller_error("skill_deleted")

    def _put(self, event: ControlEvent) -> None:
        if len(self._events) >= self._event_cap:
            self.dropped_events += 1
            self._note("queue", f"event queue full ({self._event_cap}); "
                       f"{self.dropped_events} events dropped")
            return
        idle = not self._events
        self._events.append(event)
        self._last_put = time.monotonic()
        # With events queued the writer is already on its quiet_s timer: waking it for each
        # upload of a burst would cost a thread wake-up and two GIL hand-overs per request,
        # only for it to see the burst and sleep again. (A put racing the writer's last pop
        # waits at most flush_interval_s.)
        if idle or self._urgent or self.quiet_s <= 0:
            self._wake.set()

    def _mark_urgent(self) -> None:
        with self._urgent_lock:
            self._urgent += 1

    def _caller_error(self, method: str) -> None:
        self.dropped_events += 1
        log.exception("recorder.%s could not queue its event", method)

    def _note(self, key: str, detail: str) -> None:
        with self._state_lock:
            self._errors[key] = detail

    def _clear(self, key: str) -> None:
        with self._state_lock:
            self._errors.pop(key, None)

    def _skill_lock(self, skill: str) -> threading.RLock:
        """The lock an export lists the skill's closed files under. Reentrant: the writer
        holds it over a whole rebuild, whose wipe takes it again."""
        with self._state_lock:
            return self._skill_locks.setdefault(skill, threading.RLock())
