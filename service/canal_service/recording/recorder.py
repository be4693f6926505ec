"""``Recorder``: the service's review recorder (one Rerun + one MCAP recording per skill).

Callers (request handlers, the live bridge) only enqueue; a single background writer thread
owns every file. See docs/recording.md for the layout, flush interval, crash guarantees,
memory bound and drop policy.
"""

from __future__ import annotations

import atexit
import contextlib
import logging
import os
import shutil
import threading
import time
import uuid
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..lanes import name_os_thread
from .events import (
    ControlEvent,
    DemoAdded,
    DemoRef,
    DemoRemoved,
    LiveRows,
    ModelFitted,
    ModelRef,
    Rebuild,
    Reconcile,
    ReproductionMade,
    Rotate,
    SkillDeleted,
    Stop,
    concat_rows,
    live_rows,
    reproduction_view,
)
from .geometry import model_geometry, points3d
from .layout import KINDS, SkillDir, skill_dirname, skill_dirs
from .mcap_log import McapSegment, empty_mcap, merge_mcap
from .rerun_log import RerunSegment, cli_env, empty_rrd, merge_rrd, view_coordinates
from .source import DbSource, Inventory

log = logging.getLogger("canal_service.recording")

EXPORTS = ".exports"
#: Demonstrations the writer reads and logs in one go before it checks for new requests.
DEMO_BATCH = 32
RERUN_CONFIG = ".rerun"


def _vector(value: Any) -> list[float]:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim != 1 or not 1 <= arr.shape[0] <= 16:
        raise ValueError(f"expected a position of 1 to 16 coordinates, got shape {arr.shape}")
    return arr.tolist()


def batch_writer_rerun(rows: LiveRows) -> Callable[[RerunSegment], None]:
    """Log one stream's live rows to a Rerun segment (bound now, called by ``_write``)."""
    return lambda r: r.live(rows)


def batch_writer_mcap(rows: LiveRows) -> Callable[[McapSegment], None]:
    """Log one stream's live rows to an MCAP segment (bound now, called by ``_write``)."""
    return lambda m: m.live(rows)


class _SkillState:
    """The open segment of one skill (writer thread only)."""

    def __init__(self, skill: str, sdir: SkillDir) -> None:
        self.skill = skill
        self.dir = sdir
        self.segment: int | None = None
        self.rerun: RerunSegment | None = None
        self.mcap: McapSegment | None = None
        self.last_write = time.monotonic()
        # Written to the open segment since its last successful flush: lost if it fails.
        self.pending_events = 0
        self.pending_live = 0
        # Ledger lines of what was written since the last flush (appended once flushed).
        self.pending_ledger: list[str] = []
        ledger = sdir.ledger()
        self.n_reproductions = ledger.reproductions
        self.reproductions: set[int] = ledger.numbers
        # The skill instance the files record (None: not known yet, or no database).
        recorded = sdir.instance()
        self.instance: str | None = recorded[1] if recorded is not None else None
        # What the files hold or the open segment got (ledger + pending): never logged twice.
        self.demos: set[int] = ledger.demos
        self.models: set[int] = ledger.models


class Recorder:
    """Per-skill review recordings (``.rrd`` for Rerun, ``.mcap`` for Foxglove).

    Parameters
    ----------
    root : Path
        Folder of all recordings (one sub-folder per skill). One Recorder per root.
    enabled : bool
        False makes every record method a no-op and exports raise ``RuntimeError``.
    flush_interval_s : float
        How often open segments are pushed to the OS; a crash loses at most this much.
    live_max_hz : float or None
        Rows :meth:`live` keeps per (skill, robot) per second (None keeps every row); the
        bridges' rows (:meth:`live_rows`) are decimated by the bridges.
    live_queue_size : int
        Live samples (a pose and a target per row) waiting for the writer; beyond it the
        oldest rows are dropped (counted).
    event_queue_size : int
        Other events waiting for the writer; beyond it new events are dropped (counted).
    idle_close_s : float
        A skill's segment idle this long is closed (finished files, no open threads).
    export_timeout_s : float
        How long an export waits for the writer before exporting what is closed on disk.
    source : DbSource, optional
        The service's database. With it, the request path queues only ids (the writer reads
        the arrays in batches), the writer fills in at start what the database holds and the
        recording misses (after a crash), and :meth:`rebuild` regenerates a recording.
    coordinates : str
        ``rr.ViewCoordinates`` of the world in the ``.rrd`` (3-D skills).
    quiet_s, max_lag_s : float
        The writer yields to the request path: queued events wait while events keep coming
        (less than ``quiet_s`` apart), at most ``max_lag_s``; an export, rebuild or close
        writes everything queued at once. ``quiet_s=0`` writes as soon as possible.
    """

    def __init__(self, root: Path, *, enabled: bool = True, flush_interval_s: float = 1.0,
                 live_max_hz: float | None = 100.0, live_queue_size: int = 20_000,
                 event_queue_size: int = 10_000, idle_close_s: float = 60.0,
                 export_timeout_s: float = 30.0, source: DbSource | None = None,
                 coordinates: str = "RIGHT_HAND_Z_UP", quiet_s: float = 0.25,
                 max_lag_s: float = 30.0) -> None:
        self.quiet_s = float(quiet_s)
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
        self._skill_locks: dict[str, threading.Lock] = {}
        self._errors: dict[str, str] = {}
        self._skills: dict[str, _SkillState] = {}
        self._rerun_env: dict[str, str] | None = None
        # Each skill's instance in the database, read at most once per pass of the writer.
        self._current: dict[str, str | None] = {}
        self.dropped_events = 0
        self.dropped_live = 0
        # CPU seconds the writer thread spent on its work (not waiting): what the recorder
        # costs the process, whatever else runs in it (the upload benchmark reads it).
        self.writer_cpu_s = 0.0
        self.decimated_live = 0
        self.written_live = 0
        # Live poses per (skill, robot): written but not yet flushed (by skill), flushed to
        # the files (recorded), lost (dropped); the live source's completeness reads them.
        self._live_unflushed: dict[str, dict[str, int]] = {}
        self._live_recorded: dict[tuple[str, str], int] = {}
        self._live_dropped: dict[tuple[str, str], int] = {}
        self._closed = not enabled
        self.live_source: Any = None  # a LiveSubscriber feeding live_rows()
        self._thread: threading.Thread | None = None
        if enabled:
            self._thread = threading.Thread(target=self._run, name="canal-recorder", daemon=True)
            self._thread.start()
            atexit.register(self.close)

    # ---- record methods: enqueue only, never raise ----------------------------------------

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

    def demo_removed(self, skill: str, demo_id: int) -> None:
        """A demonstration was deleted (cleared in the recording from now on)."""
        if self._closed:
            return
        try:
            self._put(DemoRemoved(time.time_ns(), skill, int(demo_id)))
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
                            [int(target.section_index)], [inside], [done])
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
                                          dict[tuple[str, str], int]]:
        """Live poses per (skill, robot): (recorded, i.e. flushed to the files; dropped)."""
        with self._live_lock:
            return dict(self._live_recorded), dict(self._live_dropped)

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
            with self._live_lock:
                for key in [k for k in self._live_last if k[0] == skill]:
                    del self._live_last[key]
            self._put(SkillDeleted(time.time_ns(), skill))
        except Exception:
            self._caller_error("skill_deleted")

    # ---- exports ----------------------------------------------------------------------------

    def export_rrd(self, skill: str) -> Path:
        """A finished ``.rrd`` snapshot of the skill's recording; the caller deletes it."""
        return self._export(skill, "rrd")

    def export_mcap(self, skill: str, profile: str = "foxglove") -> Path:
        """A finished ``.mcap`` snapshot of the skill's recording; the caller deletes it.

        ``profile="ros2"`` converts it to a rosbag2-compatible MCAP (CDR messages, see
        :mod:`.ros2`).
        """
        if profile not in ("foxglove", "ros2"):
            raise ValueError(f"unknown MCAP profile {profile!r} (foxglove or ros2)")
        path = self._export(skill, "mcap")
        if profile == "foxglove":
            return path
        from .ros2 import foxglove_to_ros2

        out = path.with_name(path.stem + "-ros2.mcap")
        try:
            foxglove_to_ros2(path, out)
        finally:
            path.unlink(missing_ok=True)
        return out

    def rebuild(self, skill: str, timeout_s: float | None = None) -> dict[str, Any]:
        """Regenerate the skill's recording from the database; what was logged.

        Live samples and reproductions are not in the database: a rebuilt recording holds
        the demonstrations (deleted ones gone) and every model version.
        """
        if not self.enabled or self._closed:
            raise RuntimeError("recording is disabled")
        if self.source is None:
            raise RuntimeError("this recorder has no database to rebuild from")
        event = Rebuild(skill)
        self._events.append(event)  # never dropped, like Rotate
        self._mark_urgent()
        self._wake.set()
        if not event.done.wait(timeout_s or max(self.export_timeout_s, 600.0)):
            raise TimeoutError(f"rebuild of {skill!r} did not finish")
        if "error" in event.result:
            raise RuntimeError(event.result["error"])
        return dict(event.result)

    def reconcile(self, skill: str | None = None, timeout_s: float = 600.0) -> dict[str, Any]:
        """Log what the database holds and the recording misses; what was added."""
        if not self.enabled or self._closed or self.source is None:
            return {}
        event = Reconcile(skill)
        self._events.append(event)
        self._mark_urgent()
        self._wake.set()
        event.done.wait(timeout_s)
        return dict(event.result)

    def _export(self, skill: str, kind: str) -> Path:
        if not self.enabled:
            raise RuntimeError("recording is disabled")
        rotate = Rotate(skill)
        if not self._closed:
            # Never dropped: the writer closes the open segment after every event queued
            # before this one, so the snapshot holds everything recorded up to now.
            self._events.append(rotate)
            self._mark_urgent()
            self._wake.set()
            if not rotate.done.wait(self.export_timeout_s):
                self._note("export", f"writer did not answer within {self.export_timeout_s:g}"
                           " s; exported the closed segments only")
        exports = self.root / EXPORTS
        exports.mkdir(parents=True, exist_ok=True)
        out = exports / f"{uuid.uuid4().hex}-{skill_dirname(skill)}.{kind}"
        sdir = SkillDir.of(self.root, skill)
        with self._skill_lock(skill):
            segments = sdir.closed_segments(kind)
            if segments and self.source is not None and not self._current_files(skill, sdir):
                segments = []  # another skill instance's files: never served
            if not segments:
                if kind == "rrd":
                    empty_rrd(out, str(uuid.uuid4()), skill, dim=self._dims.get(skill, 3),
                              coordinates=self.coordinates)
                else:
                    empty_mcap(out, time.time_ns())
                return out
            if len(segments) > 1:
                merged = sdir.closed_path(segments[0].first, segments[-1].last, kind)
                self._merge([s.path for s in segments], merged, kind)
                for seg in segments:
                    seg.path.unlink(missing_ok=True)  # covered by the merged range
                source = merged
            else:
                source = segments[0].path
            # Closed files never change (they are only replaced by rename), so a hard link
            # is a consistent snapshot at no copying cost.
            try:
                os.link(source, out)
            except OSError:
                shutil.copyfile(source, out)
        return out

    def _current_files(self, skill: str, sdir: SkillDir) -> bool:
        """Whether the skill's files record the instance the database holds now (checked
        again at export: the skill may have been deleted and created again since the writer
        brought them up to date, or the writer did not answer in time)."""
        assert self.source is not None
        recorded = sdir.instance()
        try:
            current = self.source.instance(skill)
        except Exception:
            return False
        return recorded is not None and current == recorded[1]

    def _merge(self, inputs: list[Path], out: Path, kind: str, *, recover: bool = False) -> None:
        if kind == "rrd":
            merge_rrd(inputs, out, self._cli_env(), recover=recover)
        else:
            merge_mcap(inputs, out, recover=recover)

    def _cli_env(self) -> dict[str, str]:
        if self._rerun_env is None:
            self._rerun_env = cli_env(self.root / RERUN_CONFIG)
        return self._rerun_env

    # ---- state --------------------------------------------------------------------------------

    def health(self) -> dict[str, Any]:
        """``{"status": "ok"|"degraded", "detail", "queued", "dropped", ...}``."""
        with self._state_lock:
            errors = dict(self._errors)
        if self.enabled and not self._closed and (self._thread is None
                                                  or not self._thread.is_alive()):
            errors["writer"] = "writer thread is not running"
        return {
            "status": "degraded" if errors else "ok",
            "detail": "; ".join(f"{k}: {v}" for k, v in sorted(errors.items())) or (
                None if self.enabled else "recording disabled"),
            "queued": len(self._events) + 2 * self._live_queued,
            "dropped": self.dropped_events + self.dropped_live,
            "decimated": self.decimated_live,
            "live_written": self.written_live,
            "reconciled": dict(self.reconciled),
            "writer_cpu_s": round(self.writer_cpu_s, 6),
            "live": self.live_source.health() if self.live_source is not None else {
                "status": "disabled"},
        }

    def close(self) -> None:
        """Write everything queued, finish every file and stop the writer."""
        if self.live_source is not None:
            source, self.live_source = self.live_source, None
            try:
                source.close()
            except Exception:
                log.exception("closing the live subscriber")
        if self._thread is None or not self._thread.is_alive():
            self._closed = True
            return
        if not self._closed:
            self._closed = True
            atexit.unregister(self.close)
            self._events.append(Stop())
            self._mark_urgent()
            self._wake.set()
        self._thread.join(timeout=60)

    # ---- caller-side helpers ----------------------------------------------------------------

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

    def _skill_lock(self, skill: str) -> threading.Lock:
        with self._state_lock:
            return self._skill_locks.setdefault(skill, threading.Lock())

    # ---- writer thread ------------------------------------------------------------------------

    def _run(self) -> None:
        name_os_thread("canal-recorder")  # what top -H, py-spy and bench/service.py show
        try:
            self._recover_all()
        except Exception as exc:
            self._note("recovery", f"{type(exc).__name__}: {exc}")
        if self.source is not None:
            # The database is the source of truth: what it acknowledged and a crash kept
            # out of the files is logged now, before anything new.
            self._mark_urgent()
            self._events.appendleft(Reconcile(None))
        next_flush = time.monotonic() + self.flush_interval_s
        next_collect = time.monotonic() + self.idle_close_s
        while True:
            timeout = next_flush - time.monotonic()
            if self._events:
                timeout = min(timeout, self.quiet_s)
            self._wake.wait(max(0.0, timeout))
            self._wake.clear()
            started = time.thread_time()
            self._current.clear()
            try:
                if self._events and not self._busy() and self._drain_events():
                    break
                if time.monotonic() >= next_flush:
                    self._drain_live()
                    self._flush_all()
                    next_flush = time.monotonic() + self.flush_interval_s
                if time.monotonic() >= next_collect:
                    self._collect()
                    next_collect = time.monotonic() + self.idle_close_s
            except Exception as exc:  # the writer must outlive any bug in one event
                log.exception("recorder writer loop")
                self._note("writer", f"{type(exc).__name__}: {exc}")
            finally:
                self.writer_cpu_s += time.thread_time() - started
        self._drain_live()
        for state in list(self._skills.values()):
            self._close_segment(state)

    def _busy(self) -> bool:
        """Whether queued events should wait: the request path is busy and none is urgent."""
        if self._urgent or self.quiet_s <= 0 or self._closed:
            return False
        if time.monotonic() - self._last_put >= self.quiet_s:
            return False
        try:
            head_ns = getattr(self._events[0], "t_ns", None)
        except IndexError:
            return False
        return head_ns is None or time.time_ns() - head_ns < self.max_lag_s * 1e9

    def _drain_events(self) -> bool:
        """Handle queued events (until the request path is busy again); True to stop."""
        while True:
            if self._busy():
                return False  # a new burst: yield, the rest waits for the next lull
            try:
                event = self._events.popleft()
            except IndexError:
                self._clear("queue")
                return False
            if isinstance(event, Stop):
                return True
            if isinstance(event, DemoRef):
                self._demo_refs(event)
                continue  # at most DEMO_BATCH demos, then _busy() is asked again
            try:
                self._handle(event)
            except Exception as exc:
                log.exception("recorder could not record %s", type(event).__name__)
                self.dropped_events += 1
                self._note(getattr(event, "skill", None) or "writer",
                           f"{type(exc).__name__}: {exc}")
                if isinstance(event, Rebuild | Reconcile):
                    event.result["error"] = f"{type(exc).__name__}: {exc}"
            finally:
                if isinstance(event, Rotate | Rebuild | Reconcile):
                    with self._urgent_lock:
                        self._urgent -= 1
                    event.done.set()

    def _demo_refs(self, first: DemoRef) -> None:
        """``first`` and the demo refs queued right behind it (at most :data:`DEMO_BATCH`):
        one database read per skill.

        Bounded so that a burst of requests starting meanwhile waits for one batch (about
        0.1 s of writing), not for everything queued.
        """
        refs = [first]
        while (len(refs) < DEMO_BATCH and self._events
               and isinstance(self._events[0], DemoRef)):
            refs.append(self._events.popleft())  # type: ignore[arg-type]
        by_skill: dict[str, list[DemoRef]] = {}
        for ref in refs:
            by_skill.setdefault(ref.skill, []).append(ref)
        assert self.source is not None
        for skill, group in by_skill.items():
            try:
                if not self._owner(skill, None):
                    continue  # the skill is gone
                stored = {d.demo_id: d for d in self.source.demos(skill, [r.demo_id for r in group])}
                logged = self._state(skill).demos
                for ref in group:
                    d = stored.get(ref.demo_id)
                    if d is None or d.demo_id in logged:
                        continue  # deleted since (its removal is queued behind), or reconciled
                    self._handle(DemoAdded(d.t_ns or ref.t_ns, skill, d.demo_id, d.positions,
                                           d.timestamps, d.label, d.orientations))
            except Exception as exc:
                log.exception("recorder could not record demonstrations of %s", skill)
                self.dropped_events += len(group)
                self._note(skill, f"{type(exc).__name__}: {exc}")

    def _handle(self, event: ControlEvent) -> None:
        if isinstance(event, DemoAdded):
            self._dims[event.skill] = int(event.positions.shape[1])
            pts = points3d(event.positions)
            self._write(event.skill, event.t_ns,
                        lambda r: r.demo_added(event.t_ns, event.demo_id, pts, event.positions,
                                               event.timestamps, event.label, event.orientations),
                        lambda m: m.demo_added(event.t_ns, event.demo_id, pts, event.label,
                                               event.orientations),
                        ledger=f"d {event.demo_id}")
        elif isinstance(event, DemoRemoved):
            if not self._owner(event.skill, None):
                return
            self._write(event.skill, event.t_ns,
                        lambda r: r.demo_removed(event.t_ns, event.demo_id),
                        lambda m: m.demo_removed(event.t_ns, event.demo_id),
                        ledger=f"x {event.demo_id}")
        elif isinstance(event, ModelFitted):
            if not self._owner(event.skill, event.instance):
                return  # fitted for a skill deleted since
            if self.source is not None and event.version in self._state(event.skill).models:
                return  # reconciled from the database before its own event came
            self._dims[event.skill] = int(event.canal.dim)
            geo = model_geometry(event.version, event.canal)
            self._write(event.skill, event.t_ns, lambda r: r.model(event.t_ns, geo),
                        lambda m: m.model(event.t_ns, geo), ledger=f"m {event.version}")
        elif isinstance(event, ModelRef):
            assert self.source is not None
            for stored in self.source.models(event.skill, [event.version]):
                self._handle(ModelFitted(event.t_ns, event.skill, stored.version, stored.canal))
        elif isinstance(event, ReproductionMade):
            if not self._owner(event.skill, event.instance):
                return  # computed for a skill deleted since
            state = self._state(event.skill)
            number = event.number if event.number is not None else state.n_reproductions + 1
            if number in state.reproductions:
                return  # reconciled from the database before its own event came
            rep = reproduction_view(event.version, event.result, number)
            self._write(event.skill, event.t_ns, lambda r: r.reproduction(event.t_ns, rep),
                        lambda m: m.reproduction(event.t_ns, rep), ledger=f"p {number}")
            state.n_reproductions = max(state.n_reproductions, number)
        elif isinstance(event, Rotate):
            self._drain_live()
            if self.source is not None:
                self._sync(event.skill)
            open_state = self._skills.get(event.skill)
            if open_state is not None:
                self._close_segment(open_state)
            self._recover(SkillDir.of(self.root, event.skill))
        elif isinstance(event, SkillDeleted):
            self._delete(event.skill)
        elif isinstance(event, Rebuild):
            self._delete(event.skill)
            event.result.update(self._reconcile_skill(event.skill, full=True))
            rebuilt = self._skills.get(event.skill)
            if rebuilt is not None:
                self._close_segment(rebuilt)
        elif isinstance(event, Reconcile):
            event.result.update(self._reconcile(event.skill))

    def _delete(self, skill: str) -> None:
        self._drain_live()
        self._wipe(skill)
        self._current.pop(skill, None)  # deleted here: what comes next is another instance

    def _wipe(self, skill: str) -> None:
        """Drop the skill's open segment and delete its files."""
        state = self._skills.pop(skill, None)
        if state is not None:
            self._abandon(state, reconcile=False)
        with self._skill_lock(skill):
            SkillDir.of(self.root, skill).remove()
        self._dims.pop(skill, None)
        self._clear(skill)

    # ---- the database as source of truth --------------------------------------------------------

    def _reconcile(self, skill: str | None) -> dict[str, Any]:
        """Log what the database holds and the ledger does not (one skill or all)."""
        if self.source is None:
            return {}
        if skill is None:
            self._collect()
        names = [skill] if skill is not None else sorted(self.source.skills())
        total = {"demos": 0, "models": 0, "removed": 0, "reproductions": 0}
        for name in names:
            for k, v in self._reconcile_skill(name, full=False).items():
                total[k] += v
        for k, v in total.items():
            self.reconciled[k] += v
        if any(total.values()):
            log.info("recordings reconciled with the database: %s", total)
        return total

    def _reconcile_skill(self, skill: str, *, full: bool,
                         inventory: Inventory | None = None) -> dict[str, int]:
        assert self.source is not None
        if inventory is None:
            inventory = self.source.inventory(skill)
        if inventory is None:
            return {"demos": 0, "models": 0, "removed": 0, "reproductions": 0}
        self._current[skill] = inventory.instance
        if not self._owner(skill, inventory.instance):
            return {"demos": 0, "models": 0, "removed": 0, "reproductions": 0}
        db_demos, db_models = inventory.demos, inventory.models
        state = self._state(skill)
        logged_demos, logged_models = set(state.demos), set(state.models)
        logged_numbers = set(state.reproductions)
        if full:
            logged_demos, logged_models, logged_numbers = set(), set(), set()
        self._dims[skill] = inventory.dim
        missing = sorted(db_demos - logged_demos)
        stale = sorted(logged_demos - db_demos)
        now = time.time_ns()
        for d in self.source.demos(skill, missing) if missing else []:
            self._handle(DemoAdded(d.t_ns or now, skill, d.demo_id, d.positions, d.timestamps,
                                   d.label, d.orientations))
        for demo_id in stale:
            self._handle(DemoRemoved(now, skill, demo_id))
        versions = sorted(db_models - logged_models)
        for m in self.source.models(skill, versions) if versions else []:
            self._handle(ModelFitted(m.t_ns or now, skill, m.version, m.canal))
        numbers = sorted(inventory.reproductions - logged_numbers)
        for p in self.source.reproductions(skill, numbers) if numbers else []:
            self._handle(ReproductionMade(p.t_ns or now, skill, p.version, p, p.number))
        return {"demos": len(missing), "models": len(versions), "removed": len(stale),
                "reproductions": len(numbers)}

    # ---- which skill instance the files record ------------------------------------------------

    def _owner(self, skill: str, instance: str | None) -> bool:
        """Whether an event of ``skill`` (computed for ``instance``, None when unknown) may
        be written: the skill's files then record the database's current instance.

        A name is not an identity: another replica may have deleted the skill and created
        it again. Files of another instance are deleted here, before anything new is
        written, and an event computed for an instance that is gone is dropped.
        """
        if self.source is None:
            return True
        state = self._state(skill)
        if instance is not None and instance == state.instance:
            return True
        if skill not in self._current:
            self._current[skill] = self.source.instance(skill)
        current = self._current[skill]
        if current is None or (instance is not None and instance != current):
            return False
        if state.instance != current:
            if state.instance is not None:
                self._wipe(skill)  # another instance's recording: gone with its skill
                state = self._state(skill)
            state.instance = current  # files without an instance are this skill's own
            state.dir.write_instance(skill, current)
        return True

    def _sync(self, skill: str) -> None:
        """Bring the skill's files to what the database holds now (an export's first step):
        another instance's files are deleted, what other replicas stored is logged."""
        assert self.source is not None
        self._current.pop(skill, None)
        inventory = self.source.inventory(skill)
        if inventory is None:
            self._wipe(skill)
            return
        result = self._reconcile_skill(skill, full=False, inventory=inventory)
        for k, v in result.items():
            self.reconciled[k] = self.reconciled.get(k, 0) + v

    def _collect(self) -> None:
        """Delete the files of skill instances the database no longer holds (deleted on
        another replica: unreachable since, as every export checks the instance first)."""
        if self.source is None:
            return
        current = self.source.instances()
        for path in skill_dirs(self.root):
            recorded = SkillDir(path).instance()
            if recorded is not None and current.get(recorded[0]) != recorded[1]:
                self._wipe(recorded[0])

    def _state(self, skill: str) -> _SkillState:
        state = self._skills.get(skill)
        if state is None:
            state = self._skills[skill] = _SkillState(skill, SkillDir.of(self.root, skill))
        return state

    def _write(self, skill: str, t_ns: int, to_rerun: Callable[[RerunSegment], None],
               to_mcap: Callable[[McapSegment], None], *, n_live: int = 0,
               ledger: str | None = None) -> None:
        """Log one event (or ``n_live`` live samples) to both files of the skill."""
        state = self._open(skill, t_ns)
        try:
            assert state.rerun is not None and state.mcap is not None
            to_rerun(state.rerun)
            to_mcap(state.mcap)
        except Exception:
            self._abandon(state)
            raise
        state.last_write = time.monotonic()
        if n_live:
            state.pending_live += n_live
            self.written_live += n_live
        else:
            state.pending_events += 1
        if ledger is not None:
            state.pending_ledger.append(ledger)
            kind, _, value = ledger.partition(" ")
            if kind == "d":
                state.demos.add(int(value))
            elif kind == "x":
                state.demos.discard(int(value))
            elif kind == "m":
                state.models.add(int(value))
            elif kind == "p":
                state.reproductions.add(int(value))

    def _open(self, skill: str, t_ns: int) -> _SkillState:
        state = self._state(skill)
        if state.rerun is not None:
            return state
        sdir = state.dir
        sdir.ensure()
        n = sdir.next_segment()
        rerun = RerunSegment(sdir.open_path(n, "rrd"), sdir.recording_id(), skill,
                             blueprint=not sdir.closed_segments("rrd"),
                             dim=self._dims.get(skill, 3), coordinates=self.coordinates)
        try:
            mcap = McapSegment(sdir.open_path(n, "mcap"), t_ns)
        except Exception:
            rerun.abandon()
            raise
        state.segment, state.rerun, state.mcap = n, rerun, mcap
        return state

    def _drain_live(self) -> None:
        """Write the queued live rows: per stream one run of columns, both files."""
        with self._live_lock:
            if not self._live:
                return
            chunks, self._live = list(self._live), deque()
            self._live_queued = 0
        streams: dict[tuple[str, str], list[LiveRows]] = {}
        for chunk in chunks:
            streams.setdefault((chunk.skill, chunk.robot), []).append(chunk)
        for (skill, robot), parts in streams.items():
            rows = concat_rows(parts)
            if not self._owner(skill, None):
                with self._live_lock:
                    self.dropped_live += 2 * len(rows)
                    key = (skill, robot)
                    self._live_dropped[key] = self._live_dropped.get(key, 0) + len(rows)
                continue  # the skill is gone
            if skill not in self._dims:
                self._dims[skill] = self._source_dim(skill)
            try:
                self._write(skill, int(rows.t_ns[0]), batch_writer_rerun(rows),
                            batch_writer_mcap(rows), n_live=2 * len(rows))
                self._live_count(skill, robot, len(rows))
            except Exception as exc:
                log.exception("recorder could not record live samples of %s", skill)
                self.dropped_live += 2 * len(rows)
                self._live_count(skill, robot, len(rows))
                self._live_settle(skill, self._live_dropped)
                self._note(skill, f"{type(exc).__name__}: {exc}")

    def _source_dim(self, skill: str) -> int:
        if self.source is None:
            return 3
        try:
            return self.source.skills().get(skill, 3)
        except Exception:
            return 3

    def _flushed(self, state: _SkillState) -> None:
        """The open segment's data reached the OS: the ledger may now say so."""
        state.pending_events = state.pending_live = 0
        self._live_settle(state.skill, self._live_recorded)
        lines, state.pending_ledger = state.pending_ledger, []
        try:
            state.dir.append_ledger(lines)
        except OSError as exc:  # the recording is fine; a restart re-logs these (harmless)
            self._note(f"ledger {state.skill}", f"{type(exc).__name__}: {exc}")

    def _flush_all(self) -> None:
        now = time.monotonic()
        for state in list(self._skills.values()):
            if state.rerun is None or state.mcap is None:
                continue
            try:
                state.rerun.flush()
                state.mcap.flush()
            except Exception as exc:
                log.exception("recorder could not flush %s", state.skill)
                self._note(state.skill, f"{type(exc).__name__}: {exc}")
                self._abandon(state)
                continue
            self._flushed(state)
            self._clear(state.skill)
            if now - state.last_write > self.idle_close_s:
                self._close_segment(state)

    def _close_segment(self, state: _SkillState) -> None:
        """Finish the open segment and rename it closed (segment n covers n..n)."""
        if state.rerun is None or state.mcap is None or state.segment is None:
            return
        n, sdir = state.segment, state.dir
        rerun, mcap = state.rerun, state.mcap
        state.rerun = state.mcap = state.segment = None
        try:
            rerun.close()
            mcap.close()
            os.replace(sdir.open_path(n, "mcap"), sdir.closed_path(n, n, "mcap"))
        except Exception as exc:
            log.exception("recorder could not close a segment of %s", state.skill)
            self._note(state.skill, f"{type(exc).__name__}: {exc}")
            rerun.abandon()
            mcap.abandon()
            return
        self._flushed(state)
        # The open .rrd is a run of flushed streams; merged, it has one footer and index.
        try:
            self._merge([sdir.open_path(n, "rrd")], sdir.closed_path(n, n, "rrd"), "rrd")
            sdir.open_path(n, "rrd").unlink()
        except Exception as exc:
            log.exception("recorder could not merge a segment of %s", state.skill)
            self._note(state.skill, f"{type(exc).__name__}: {exc}")

    def _abandon(self, state: _SkillState, *, reconcile: bool = True) -> None:
        """Drop the open segment after a write error; its files are recovered later."""
        # Whatever reached the segment since its last good flush may be lost: count it.
        self.dropped_events += state.pending_events
        self.dropped_live += state.pending_live
        self.written_live -= state.pending_live
        state.pending_events = state.pending_live = 0
        self._live_settle(state.skill, self._live_dropped)
        lost = bool(state.pending_ledger)
        for line in state.pending_ledger:  # not in the files for sure: not logged
            kind, _, value = line.partition(" ")
            if kind == "d":
                state.demos.discard(int(value))
            elif kind == "m":
                state.models.discard(int(value))
            elif kind == "p":
                state.reproductions.discard(int(value))
        state.pending_ledger = []
        if reconcile and lost and self.source is not None:
            # Not in the ledger, so the database fills them in again at the next reconcile.
            self._mark_urgent()
            self._events.append(Reconcile(state.skill))
        if state.rerun is not None:
            state.rerun.abandon()
        if state.mcap is not None:
            state.mcap.abandon()
        state.rerun = state.mcap = state.segment = None

    # ---- crash recovery -----------------------------------------------------------------------

    def _recover_all(self) -> None:
        """Finish the segments a crashed process left open; drop stale export snapshots."""
        shutil.rmtree(self.root / EXPORTS, ignore_errors=True)
        for path in skill_dirs(self.root):
            self._recover(SkillDir(path))

    def _recover(self, sdir: SkillDir) -> None:
        """Turn every open segment of ``sdir`` that no writer owns into a closed one."""
        owned = {s.segment for s in self._skills.values() if s.dir.path == sdir.path}
        for kind in KINDS:
            for n, path in sdir.open_segments(kind):
                if n in owned:
                    continue
                if path.stat().st_size == 0:
                    path.unlink()
                    continue
                try:
                    self._merge([path], sdir.closed_path(n, n, kind), kind, recover=True)
                    path.unlink()
                except OSError as exc:  # e.g. disk full: keep the file and retry later
                    self._note(f"recovery {path.name}", f"{type(exc).__name__}: {exc}")
                except Exception as exc:
                    with contextlib.suppress(OSError):
                        path.rename(path.with_name(path.name + ".broken"))
                    self._note(f"recovery {path.name}", f"unreadable, kept as .broken: {exc}")
