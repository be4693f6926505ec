"""The recorder and the database, and crash recovery.

The database is the source of truth: what it holds and the recording misses (after a crash,
a write error, or what another replica stored) is logged from it; :meth:`Reconciler.rebuild`
regenerates a recording from it; files of skill instances it no longer holds are collected.
Segments a crashed process left open are finished and closed at start.
"""

from __future__ import annotations

import contextlib
import logging
import shutil
import time
from typing import Any

from .events import (
    DemoAdded,
    DemoRemoved,
    ModelFitted,
    Rebuild,
    Reconcile,
    ReproductionMade,
)
from .exports import EXPORTS
from .layout import KINDS, SkillDir, skill_dirs
from .segments import SegmentWriter
from .source import Inventory

log = logging.getLogger("canal_service.recording")


class Reconciler(SegmentWriter):
    """The recorder's layer that reconciles with the database and recovers open segments."""

    def rebuild(self, skill: str, timeout_s: float | None = None) -> dict[str, Any]:
        """Regenerate the skill's recording from the database; what was logged, or
        ``{"gone": True}`` when the database no longer holds the skill.

        Live samples are not in the database: a rebuilt recording holds the demonstrations
        (deleted ones gone), every model version and the reproductions the database keeps.
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
        if not self._owner(skill, inventory.instance, events=0):
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
            self._log(DemoAdded(d.t_ns or now, skill, d.demo_id, d.positions, d.timestamps,
                                   d.label, d.orientations))
        for demo_id in stale:
            self._log(DemoRemoved(now, skill, demo_id, inventory.instance))
        versions = sorted(db_models - logged_models)
        for m in self.source.models(skill, versions) if versions else []:
            self._log(ModelFitted(m.t_ns or now, skill, m.version, m.canal))
        numbers = sorted(inventory.reproductions - logged_numbers)
        for p in self.source.reproductions(skill, numbers) if numbers else []:
            self._log(ReproductionMade(p.t_ns or now, skill, p.version, p, p.number))
        # No longer kept (the database keeps the newest recordings_reproductions_kept):
        # cleared, as every replica that logged them does, so the recordings agree.
        for number in sorted(logged_numbers - inventory.reproductions):
            self._clear_reproduction(skill, now, number)
        return {"demos": len(missing), "models": len(versions), "removed": len(stale),
                "reproductions": len(numbers)}

    def _clear_reproduction(self, skill: str, t_ns: int, number: int) -> None:
        self._write(skill, t_ns, lambda r: r.reproduction_removed(t_ns, number),
                    lambda m: m.reproduction_removed(t_ns, number), ledger=f"y {number}")

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
