"""The bridge's model table: each served skill's latest canal, and a bounded negative cache.

A skill's entry says what a pose of it gets: a tracker geometry (``ok``), or why not
(``unknown_skill``, ``no_model``). Unknown skills go to a bounded, expiring negative cache
so that a flood of junk names costs one database read per name and nothing afterwards.
"""

from __future__ import annotations

import collections
import logging
import math
import threading
import time
from dataclasses import dataclass
from typing import Any

from canal_core.tracker import TrackerBank

from ..errors import NoModelYet, SkillNotFound
from ..service import CanalService
from .config import BridgeOptions

log = logging.getLogger("canal_service.bridge")

@dataclass(eq=False)
class ModelEntry:
    """What the bridge knows about one skill: a model, or why there is none."""

    status: str  # "ok" | "unknown_skill" | "no_model"
    version: int = -1
    dim: int = 0
    canal: Any = None
    message: str | None = None
    expires: float = math.inf
    #: the tracker states of every stream of this model (stepped by the worker only)
    bank: TrackerBank | None = None


def ok_entry(version: int, canal: Any, lookahead: int = 2) -> ModelEntry:
    """A served model: its canal, the tracker geometry every stream of it shares, and the
    bank that holds those streams' tracker states as arrays."""
    # The canal's own geometry: with the orientations and section times it learned, so live
    # targets carry the model's orientation and feed-forward velocity, as Canal.tracker's do.
    geometry = canal.tracker_geometry()
    return ModelEntry("ok", int(version), int(canal.dim), canal,
                      bank=TrackerBank(geometry, lookahead))


class ModelTable:
    """Skill -> :class:`ModelEntry`, read through the service (database, decoded-canal cache)."""

    def __init__(self, service: CanalService, options: BridgeOptions) -> None:
        self.service = service
        self.options = options
        self.models: dict[str, ModelEntry] = {}
        self.unknown: collections.OrderedDict[str, ModelEntry] = collections.OrderedDict()
        # The worker installs negative entries while the housekeeper expires them: each
        # compound change of the negative cache happens under this lock (misses only; a
        # served pose never takes it).
        self._unknown_lock = threading.Lock()

    def load(self, skill: str, current: ModelEntry | None = None) -> ModelEntry:
        """The skill's latest model from the service; ``current`` itself when it already
        serves that version (a refresh then costs one query, no geometry rebuilt)."""
        try:
            canal, _row, version, _dim = self.service.load_canal(skill, None)
        except SkillNotFound as exc:
            return ModelEntry("unknown_skill", message=exc.message)
        except NoModelYet as exc:
            return ModelEntry("no_model", dim=exc.dim, message=exc.message)
        if current is not None and current.status == "ok" and current.version == version:
            return current
        return ok_entry(version, canal, self.options.lookahead)

    def install(self, skill: str, entry: ModelEntry) -> None:
        """Replace the skill's entry unless it would go back to an older version. Unknown
        skills go to the bounded, expiring negative cache instead."""
        if entry.status == "unknown_skill":
            self.models.pop(skill, None)
            entry.expires = time.monotonic() + self.options.negative_ttl_s
            unknown = self.unknown
            with self._unknown_lock:
                unknown[skill] = entry
                unknown.move_to_end(skill)
                while len(unknown) > self.options.negative_max:
                    unknown.popitem(last=False)
            return
        self.unknown.pop(skill, None)
        old = self.models.get(skill)
        if (old is not None and old.status == "ok" and entry.status == "ok"
                and entry.version <= old.version):
            return
        self.models[skill] = entry

    def entry(self, skill: str) -> ModelEntry:
        """The skill's entry, loaded on first use (and after a negative entry expired)."""
        entry = self.models.get(skill)
        if entry is not None:
            return entry
        entry = self.unknown.get(skill)
        if entry is not None and entry.expires > time.monotonic():
            return entry
        entry = self.load(skill)
        self.install(skill, entry)
        return entry

    def updated(self, skill: str, canal: Any, version: int) -> None:
        """A fit landed: a skill in use is reloaded (from ``canal`` when given)."""
        self.unknown.pop(skill, None)
        old = self.models.get(skill)
        if old is None or (old.status == "ok" and old.version >= version):
            return  # not in use, or already served: install() would keep it anyway
        entry = (ok_entry(version, canal, self.options.lookahead) if canal is not None
                 else self.load(skill, old))
        if entry is not old:
            self.install(skill, entry)

    def refresh(self, live_skills: set[str]) -> None:
        """Re-read the skills that have streams; forget the others and expired negatives,
        so the table stays as small as the live fleet."""
        for skill in list(self.models):
            if skill not in live_skills:
                self.models.pop(skill, None)
                continue
            old = self.models.get(skill)
            try:
                entry = self.load(skill, old)
            except Exception:
                log.exception("model refresh for %r failed", skill)
                continue
            if entry is not old:
                self.install(skill, entry)
        now = time.monotonic()
        # Under the lock: the worker installs entries meanwhile (iterating the live
        # OrderedDict raised "mutated during iteration" and killed the housekeeper; popping
        # between the worker's insert and move_to_end raised KeyError in the worker).
        with self._unknown_lock:
            expired = [skill for skill, entry in self.unknown.items() if entry.expires <= now]
            for skill in expired:
                del self.unknown[skill]


__all__ = ["ModelEntry", "ModelTable", "ok_entry"]
