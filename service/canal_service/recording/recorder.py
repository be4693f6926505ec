"""``Recorder``: the service's review recorder (one Rerun + one MCAP recording per skill).

Callers (request handlers, the live bridge) only enqueue; a single background writer thread
owns every file. See docs/recording.md for the layout, flush interval, crash guarantees,
memory bound and drop policy. The recorder is built in layers, one concern a module:
:mod:`.event_queue` (the record methods and the queues), :mod:`.segments` (the open files
and the skill instance they record), :mod:`.exports` (snapshots), :mod:`.reconcile` (the
database, rebuild and crash recovery); this module holds the writer thread's loop, health
and close.
"""

from __future__ import annotations

import atexit
import logging
import threading
import time
from pathlib import Path
from typing import Any

from ..adapters import adapter_paths
from ..lanes import name_os_thread
from .events import (
    ControlEvent,
    DemoAdded,
    DemoRef,
    Rebuild,
    Reconcile,
    Rotate,
    SkillDeleted,
    Stop,
)
from .exports import Exporter
from .layout import SkillDir
from .reconcile import Reconciler
from .source import DbSource

log = logging.getLogger("canal_service.recording")

#: Demonstrations the writer reads and logs in one go before it checks for new requests.
DEMO_BATCH = 32


class Recorder(Exporter, Reconciler):
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
                 max_lag_s: float = 30.0, max_robots: int = 1024) -> None:
        super().__init__(
            root, enabled=enabled, flush_interval_s=flush_interval_s, live_max_hz=live_max_hz,
            live_queue_size=live_queue_size, event_queue_size=event_queue_size,
            idle_close_s=idle_close_s, export_timeout_s=export_timeout_s, source=source,
            coordinates=coordinates, quiet_s=quiet_s, max_lag_s=max_lag_s,
            max_robots=max_robots)
        if enabled:
            self._thread = threading.Thread(target=self._run, name="canal-recorder", daemon=True)
            self._thread.start()
            atexit.register(self.close)

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
            # events and live samples of a skill deleted since (maybe on another replica):
            # not written, and not lost (its recording is gone with it)
            "stale": self.stale_events + self.stale_live,
            "incomplete": self.incomplete,
            "decimated": self.decimated_live,
            "live_written": self.written_live,
            "reconciled": dict(self.reconciled),
            "writer_cpu_s": round(self.writer_cpu_s, 6),
            "live": self.live_source.health() if self.live_source is not None else {
                "status": "disabled"},
            # which path the files' writers take through other libraries' internals
            "adapters": adapter_paths(),
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
                # Caught up: nothing dropped is waiting, and an export that timed out waiting
                # for this writer would now get its answer.
                self._clear("queue")
                self._clear("export")
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
                if not self._owner(skill, None, events=len(group)):
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
        if not isinstance(event, Rotate | SkillDeleted | Rebuild | Reconcile):
            self._log(event)
            return
        if isinstance(event, Rotate):
            self._drain_live()
            if self.source is not None:
                self._sync(event.skill)
            open_state = self._skills.get(event.skill)
            if open_state is not None:
                self._close_segment(open_state)
            self._recover(SkillDir.of(self.root, event.skill))
        elif isinstance(event, SkillDeleted):
            self._delete(event.skill, deleted=True)
        elif isinstance(event, Rebuild):
            # Held from the wipe to the closed rebuilt files: an export overlapping the
            # rebuild lists the files before or after it, never the emptied folder between.
            with self._skill_lock(event.skill):
                self._delete(event.skill)
                assert self.source is not None  # rebuild() asks for one
                inventory = self.source.inventory(event.skill)
                if inventory is None:  # deleted since the rebuild was asked for
                    event.result["gone"] = True
                    return
                event.result.update(self._reconcile_skill(event.skill, full=True,
                                                          inventory=inventory))
                rebuilt = self._skills.get(event.skill)
                if rebuilt is not None:
                    self._close_segment(rebuilt)
        elif isinstance(event, Reconcile):
            event.result.update(self._reconcile(event.skill))

    def _delete(self, skill: str, *, deleted: bool = False) -> None:
        """Delete the skill's recording, its queued live rows written first. ``deleted``: the
        skill was deleted; a recording of the skill created again under its name since (its
        robots' rows can come before this event) is the new skill's, and is kept."""
        self._drain_live()
        if not (deleted and self._records_current(skill)):
            self._wipe(skill)
        self._current.pop(skill, None)  # deleted here: what comes next is another instance
