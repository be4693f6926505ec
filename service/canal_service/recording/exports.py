"""The recorder's exports: a finished ``.rrd`` or ``.mcap`` snapshot of a skill's recording
(the open segment closed first, the closed ones merged and hard-linked), only ever of the
skill instance the database holds."""

from __future__ import annotations

import logging
import os
import shutil
import time
import uuid
from pathlib import Path

from .events import (
    Rotate,
)
from .layout import SkillDir, skill_dirname
from .mcap_log import empty_mcap
from .rerun_log import empty_rrd
from .segments import SegmentWriter

log = logging.getLogger("canal_service.recording")

EXPORTS = ".exports"


class Exporter(SegmentWriter):
    """The recorder's layer that exports snapshots (see the module docstring)."""

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
            if rotate.done.wait(self.export_timeout_s):
                self._clear("export")  # the writer answers in time again: no longer behind
            else:
                self._note("export", f"writer did not answer within {self.export_timeout_s:g}"
                           " s; exported the closed segments only")
                # Noted after the wait, so the writer may have answered and drained its queue
                # (which clears the note) in between: then it is not behind either.
                if rotate.done.is_set() and not self._events:
                    self._clear("export")
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
