"""The recorder's open segments: one Rerun and one MCAP file per skill, written, flushed,
closed (renamed to their closed name) or abandoned after a write error (writer thread
only), and which skill instance a skill's files record.
"""

from __future__ import annotations

import logging
import os
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path

from .event_queue import RecorderQueue
from .events import (
    ControlEvent,
    DemoAdded,
    DemoRemoved,
    LiveRows,
    ModelFitted,
    ModelRef,
    Reconcile,
    ReproductionMade,
    SceneChanged,
    concat_rows,
    reproduction_view,
)
from .geometry import model_geometry, obstacle_shapes, points3d
from .layout import SkillDir
from .mcap_log import McapSegment, merge_mcap
from .rerun_log import RerunSegment, cli_env, merge_rrd

log = logging.getLogger("canal_service.recording")

RERUN_CONFIG = ".rerun"


def batch_writer_rerun(rows: LiveRows) -> Callable[[RerunSegment], None]:
    """Log one stream's live rows to a Rerun segment (bound now, called by ``_write``)."""
    return lambda r: r.live(rows)


def batch_writer_mcap(rows: LiveRows) -> Callable[[McapSegment], None]:
    """Log one stream's live rows to an MCAP segment (bound now, called by ``_write``)."""
    return lambda m: m.live(rows)


class SkillState:
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


class SegmentWriter(RecorderQueue):
    """The recorder's layer that owns the open segments (see the module docstring)."""

    def _log(self, event: ControlEvent) -> None:
        """Write one recorded event (a demo added or removed, a model, a reproduction) to
        the skill's open segment, unless the skill instance it was made for is gone."""
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
            if not self._owner(event.skill, event.instance):
                return  # removed from a skill deleted since
            self._write(event.skill, event.t_ns,
                        lambda r: r.demo_removed(event.t_ns, event.demo_id),
                        lambda m: m.demo_removed(event.t_ns, event.demo_id),
                        ledger=f"x {event.demo_id}")
        elif isinstance(event, ModelFitted):
            if not self._owner(event.skill, event.instance):
                return  # fitted for a skill deleted since
            if self.source is not None and event.version in self._state(event.skill).models:
                return  # reconciled from the database before its own event came
            geo = model_geometry(event.version, event.canal)
            self._dims[event.skill] = geo.dim
            self._write(event.skill, event.t_ns, lambda r: r.model(event.t_ns, geo),
                        lambda m: m.model(event.t_ns, geo), ledger=f"m {event.version}")
        elif isinstance(event, ModelRef):
            assert self.source is not None
            for stored in self.source.models(event.skill, [event.version]):
                self._log(ModelFitted(event.t_ns, event.skill, stored.version, stored.canal))
        elif isinstance(event, ReproductionMade):
            if not self._owner(event.skill, event.instance):
                return  # computed for a skill deleted since
            state = self._state(event.skill)
            number = event.number if event.number is not None else state.n_reproductions + 1
            if number in state.reproductions:
                return  # reconciled from the database before its own event came
            rep = reproduction_view(event.version, event.result, number)
            if rep.incomplete:
                self.incomplete += 1
                log.warning("recording of %s reproduction %d leaves out its %s: beyond what "
                            "the logs can hold", event.skill, number, ", ".join(rep.incomplete))
            self._write(event.skill, event.t_ns, lambda r: r.reproduction(event.t_ns, rep),
                        lambda m: m.reproduction(event.t_ns, rep), ledger=f"p {number}")
            state.n_reproductions = max(state.n_reproductions, number)
        elif isinstance(event, SceneChanged):
            if not self._owner(event.skill, event.instance):
                return  # the scene of a skill deleted since
            shapes = obstacle_shapes(event.obstacles, event.dim)
            self._write(event.skill, event.t_ns,
                        lambda r: r.scene(event.t_ns, event.version, shapes),
                        lambda m: m.scene(event.t_ns, event.version, shapes))

    def _wipe(self, skill: str) -> None:
        """Drop the skill's open segment and delete its files."""
        state = self._skills.pop(skill, None)
        if state is not None:
            self._discard(state)
        with self._skill_lock(skill):
            SkillDir.of(self.root, skill).remove()
        self._dims.pop(skill, None)
        self._robots.pop(skill, None)
        self._robots_full.discard(skill)
        self._clear(skill)

    def _owner(self, skill: str, instance: str | None, events: int = 1) -> bool:
        """Whether an event of ``skill`` (computed for ``instance``, None when unknown) may
        be written: the skill's files then record the database's current instance.

        A name is not an identity: another replica may have deleted the skill and created
        it again. Files of another instance are deleted here, before anything new is
        written, and an event computed for an instance that is gone is dropped (``events``
        of them are counted as stale).
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
            self.stale_events += events
            return False
        if state.instance != current:
            if state.instance is not None:
                self._wipe(skill)  # another instance's recording: gone with its skill
                state = self._state(skill)
            state.instance = current  # files without an instance are this skill's own
            state.dir.write_instance(skill, current)
        return True

    def _records_current(self, skill: str) -> bool:
        """Whether the skill's files record the skill the database holds under its name now
        (read afresh, not from ``_current``: a skill deleted since this pass began is not)."""
        if self.source is None:
            return False
        recorded = self._state(skill).instance
        return recorded is not None and recorded == self.source.instance(skill)

    def _state(self, skill: str) -> SkillState:
        state = self._skills.get(skill)
        if state is None:
            state = self._skills[skill] = SkillState(skill, SkillDir.of(self.root, skill))
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
            elif kind == "y":
                state.reproductions.discard(int(value))

    def _open(self, skill: str, t_ns: int) -> SkillState:
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
            deleted = self._deleted_ns.get(skill)
            if deleted is not None and int(rows.t_ns.min()) <= deleted:
                # The deleted skill's rows (queued, or on their way, when it was created again
                # under its name): not the new skill's.
                later = rows.after(deleted)
                self._stale_live(skill, robot, len(rows) - len(later))
                if not len(later):
                    continue
                rows = later
            if not self._owner(skill, None, events=0):  # the skill is gone: counted as rows
                if deleted is not None:
                    self._stale_live(skill, robot, len(rows))
                else:  # not a skill deleted here (another replica's, or none ever)
                    self._drop_live(skill, robot, len(rows))
                continue
            robots = self._robots.setdefault(skill, set())
            if robot not in robots:
                if len(robots) >= self.max_robots:
                    self._drop_live(skill, robot, len(rows))
                    if skill not in self._robots_full:  # said once per skill
                        self._robots_full.add(skill)
                        log.warning("recording of %s draws its first %d robots; the poses of "
                                    "robots after them are counted as dropped", skill,
                                    self.max_robots)
                    continue
                robots.add(robot)
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

    def _drop_live(self, skill: str, robot: str, n: int) -> None:
        """Count ``n`` live rows of (skill, robot) as dropped, not written."""
        with self._live_lock:
            self.dropped_live += 2 * n
            self._live_dropped[(skill, robot)] = self._live_dropped.get((skill, robot), 0) + n

    def _stale_live(self, skill: str, robot: str, n: int) -> None:
        """Count ``n`` live rows of (skill, robot) as stale: the skill was deleted, and its
        recording with it; they are not written, and not lost either."""
        with self._live_lock:
            self.stale_live += 2 * n
            self._live_stale[(skill, robot)] = self._live_stale.get((skill, robot), 0) + n

    def _source_dim(self, skill: str) -> int:
        if self.source is None:
            return 3
        try:
            return self.source.skills().get(skill, 3)
        except Exception:
            return 3

    def _flushed(self, state: SkillState) -> None:
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

    def _close_segment(self, state: SkillState) -> None:
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

    def _discard(self, state: SkillState) -> None:
        """Drop the open segment of a recording that is being deleted (rebuilt, or its skill
        is gone): what it held since its last flush is superseded, not lost, so it is not
        counted as dropped, as what was flushed before it is not."""
        state.pending_events = state.pending_live = 0
        self._live_settle(state.skill, self._live_recorded)  # written, then deleted with the rest
        state.pending_ledger = []
        if state.rerun is not None:
            state.rerun.discard()
        if state.mcap is not None:
            state.mcap.abandon()
        state.rerun = state.mcap = state.segment = None

    def _abandon(self, state: SkillState, *, reconcile: bool = True) -> None:
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
            elif kind == "y":
                state.reproductions.add(int(value))  # not cleared for sure: again next time
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

    def _merge(self, inputs: list[Path], out: Path, kind: str, *, recover: bool = False) -> None:
        if kind == "rrd":
            merge_rrd(inputs, out, self._cli_env(), recover=recover)
        else:
            merge_mcap(inputs, out, recover=recover)

    def _cli_env(self) -> dict[str, str]:
        if self._rerun_env is None:
            self._rerun_env = cli_env(self.root / RERUN_CONFIG)
        return self._rerun_env
