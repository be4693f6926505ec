"""The bridge's model table: each served skill's latest canal, and a bounded negative cache.

A skill's entry says what a pose of it gets: a tracker geometry (``ok``), or why not
(``unknown_skill``, ``no_model``). Unknown skills go to a bounded, expiring negative cache
so that a flood of junk names costs one database read per name and nothing afterwards.

Loading a model (a database read, decoding the canal, building the tracker geometry and the
bank's step tables) takes milliseconds. On the worker that is a stall of every stream, so
the table loads ahead of the first pose wherever it can: at bridge start the most recently
fitted skills (:meth:`ModelTable.preload`, a background thread) and on each fit notice
(:meth:`ModelTable.updated`, on the thread that heard it). Every shard preloads every skill:
:func:`canal_protocol.keys.shard_of` splits streams by robot, so each shard serves each
skill. The worker reads ``models`` without a lock; every writer builds an entry completely,
then installs it with one dict assignment (:meth:`ModelTable.install`).

Routes (:mod:`canal_core.routes`): a model of several routes is one entry for its canal of
all the demonstrations, holding one sub-entry per route (``routes``), each with its own
tracker bank; the step puts each stream in one of them at its first pose
(:meth:`canal_core.routes.Routes.choose`, ``chooser``). A model of one route is a plain entry
(``routes`` None), served as it always was.
"""

from __future__ import annotations

import collections
import itertools
import logging
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from canal_core.errors import InvalidInputError
from canal_core.routes import Routes, served_model
from canal_core.tracker_bank import TrackerBank
from canal_core.tracker_obstacles import scene_tables
from canal_protocol import keys as keyspace
from canal_protocol import wire

from ..errors import ModelVersionNotFound, NoModelYet, SkillNotFound
from ..service import CanalService
from .config import BridgeOptions

log = logging.getLogger("canal_service.bridge")

_SERIALS = itertools.count(1)
#: reads of a skill's latest model, each finding its row deleted before reading it, before
#: the error is raised (one delete or re-creation takes one more)
_READ_ATTEMPTS = 3


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
    #: when it was installed or last seen with live streams (``time.monotonic``): an entry
    #: without streams is kept ``preload_keep_s`` after that
    used: float = 0.0
    #: the steering axes of every section (canal_core.steering), built at the first steer
    steer_axes: Any = None
    #: a model of several routes: one sub-entry per route (this entry is the canal of all)
    routes: tuple[ModelEntry, ...] | None = None
    #: ... and the Routes that chooses a stream's route at its first pose
    chooser: Any = None
    #: what a JSON answer says of the route: wire.NO_ROUTE for a model of one route, else the
    #: route this entry tracks (None: the canal of all the demonstrations)
    route: int | None = wire.NO_ROUTE
    #: the skill's creation time (ns): with ``version``, which model this is. A skill
    #: deleted and created again under its name starts its versions at 1 again.
    created_ns: int = -1
    #: this entry among every entry the process built: a stream whose serial is not its
    #: skill's entry's any more is in another model now
    serial: int = field(default_factory=lambda: next(_SERIALS))

    @property
    def revision(self) -> tuple[int, int]:
        """(``created_ns``, ``version``)."""
        return self.created_ns, self.version

    def succeeds(self, old: ModelEntry) -> bool:
        """Whether this model replaces ``old``: a later version of the same skill, or any
        version of a skill created again (whose versions start again at 1)."""
        return self.created_ns != old.created_ns or self.version > old.version


def ok_entry(version: int, canal: Any, lookahead: int = 2, created_ns: int = -1) -> ModelEntry:
    """A served model: its canal, the tracker geometry every stream of it shares, and the
    bank that holds those streams' tracker states as arrays. ``canal`` may be
    :class:`canal_core.Routes`: with several routes, the entry of the canal of all holds one
    entry per route."""
    model = served_model(canal) if isinstance(canal, Routes) else canal
    if not isinstance(model, Routes):
        entry = _plain_entry(version, model, lookahead)
    else:
        entry = _plain_entry(version, model.pooled, lookahead)
        entry.route, entry.chooser = None, model
        entry.routes = tuple(_plain_entry(version, c, lookahead, k)
                             for k, c in enumerate(model.canals))
    for each in (entry, *(entry.routes or ())):
        each.created_ns = int(created_ns)
    return entry


def _plain_entry(version: int, canal: Any, lookahead: int,
                 route: int | None = wire.NO_ROUTE) -> ModelEntry:
    # The canal's own geometry: with the orientations and section times it learned, so live
    # targets carry the model's orientation and feed-forward velocity, as Canal.tracker's do.
    geometry = canal.tracker_geometry()
    return ModelEntry("ok", int(version), int(canal.dim), canal,
                      bank=TrackerBank(geometry, lookahead), route=route)


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
        # Installs come from the worker (a first pose), the housekeeper, the preload thread
        # and whichever thread hears a fit notice: the version check and the assignment
        # happen under this lock, so an older version never replaces a newer one. The
        # worker's reads never take it.
        self._install_lock = threading.Lock()
        #: skill -> (version, scene or None): the scene each skill's streams go around
        self.scenes: dict[str, tuple[int, Any]] = {}
        self._scene_lock = threading.Lock()

    def load(self, skill: str, current: ModelEntry | None = None) -> ModelEntry:
        """The skill's latest model from the service; ``current`` itself when it already
        serves that version (a refresh then costs one query: no canal read or decoded, no
        geometry rebuilt)."""
        if current is not None and current.status == "ok":
            try:
                if self.service.latest_revision(skill) == current.revision:
                    return current
            except (SkillNotFound, NoModelYet):
                pass  # deleted meanwhile: the full read below says which entry it gets
        for attempt in range(_READ_ATTEMPTS):
            try:
                canal, revision, _dim = self.service.latest_model(skill)
                break
            except SkillNotFound as exc:
                return ModelEntry("unknown_skill", message=exc.message)
            except NoModelYet as exc:
                return ModelEntry("no_model", dim=exc.dim, message=exc.message)
            except ModelVersionNotFound:
                # The latest row was deleted between finding it and reading it (the skill
                # deleted, refitted elsewhere or created again): asking again says which.
                if attempt == _READ_ATTEMPTS - 1:
                    raise
        if current is not None and current.status == "ok" and current.revision == revision:
            return current
        return ok_entry(revision[1], canal, self.options.lookahead, created_ns=revision[0])

    def install(self, skill: str, entry: ModelEntry, used: float | None = None) -> bool:
        """Replace the skill's entry unless it would go back to an older version (False
        then); ``used`` (default: now) starts its keep period. Unknown skills go to the
        bounded, expiring negative cache instead."""
        if entry.status == "unknown_skill":
            self.models.pop(skill, None)
            with self._scene_lock:
                self.scenes.pop(skill, None)  # forgotten with the skill, not kept for ever
            entry.expires = time.monotonic() + self.options.negative_ttl_s
            unknown = self.unknown
            with self._unknown_lock:
                unknown[skill] = entry
                unknown.move_to_end(skill)
                while len(unknown) > self.options.negative_max:
                    unknown.popitem(last=False)
            return True
        self.unknown.pop(skill, None)
        with self._install_lock:
            old = self.models.get(skill)
            if (old is not None and old.status == "ok" and entry.status == "ok"
                    and not entry.succeeds(old)):
                return False
        if old is None or old.created_ns != entry.created_ns:
            with self._scene_lock:
                # Another skill under the name, or no entry to tell (the deleted skill's was
                # dropped): the scene known may be the deleted one's, whose version a new
                # skill's scenes start below. Read again from the database.
                self.scenes.pop(skill, None)
        # The scene goes into the entry before any pose can reach it: published first, the
        # entry's streams were answered without the skill's obstacles until it was built.
        applied = self._apply_scene(skill, entry) if entry.status == "ok" else None
        with self._install_lock:
            now = self.models.get(skill)
            if (now is not None and now is not old and now.status == "ok"
                    and entry.status == "ok" and not entry.succeeds(now)):
                return False  # a newer version was installed while the scene was built
            entry.used = time.monotonic() if used is None else used
            self.models[skill] = entry  # built completely before: one atomic assignment
        if entry.status == "ok" and self.scenes.get(skill) is not applied:
            # A scene changed between building this entry's and publishing it, and went to
            # the entry it replaced.
            self._apply_scene(skill, entry)
        return True

    def scene_changed(self, skill: str, version: int, scene: Any) -> bool:
        """The skill's scene is now ``scene`` (None: none): its streams go around it from their
        next pose. An older version than the one known is ignored (False)."""
        with self._scene_lock:
            old = self.scenes.get(skill)
            if old is not None and old[0] > version:
                return False
            self.scenes[skill] = (int(version), scene)
        entry = self.models.get(skill)
        if entry is not None and entry.status == "ok":
            self._apply_scene(skill, entry)
        return True

    def scene_version(self, skill: str) -> int:
        """The version of the skill's scene this bridge serves (-1: not read yet)."""
        known = self.scenes.get(skill)
        return -1 if known is None else known[0]

    def reload_scene(self, skill: str) -> None:
        """Read the skill's stored scene and serve it (a notice from another bridge)."""
        try:
            version, scene = self.service.scene_of(skill, self.service.skill_dim(skill))
        except (SkillNotFound, InvalidInputError):
            return
        self.scene_changed(skill, 0 if version is None else version, scene)

    def _apply_scene(self, skill: str, entry: ModelEntry) -> tuple[int, Any] | None:
        """Give the entry's banks the skill's scene (read from the service the first time);
        the (version, scene) given, or None for an entry without a model.

        Tables are built outside the lock (a large scene takes tens of ms) and given to the
        banks only if that scene is still the skill's: two threads building two versions at
        once (a refit's install and a scene notice) would otherwise leave the older one."""
        while True:
            with self._scene_lock:
                known = self.scenes.get(skill)
            if known is None:
                try:
                    version, scene = self.service.scene_of(skill, entry.dim)
                except (SkillNotFound, InvalidInputError):
                    version, scene = None, None
                with self._scene_lock:
                    known = self.scenes.setdefault(
                        skill, (0 if version is None else version, scene))
            version, scene = known
            # A scene applies to every route: each route's bank goes around it too.
            built = []
            for each in (entry, *(entry.routes or ())):
                if each.bank is None:
                    continue
                tables = (None if scene is None or not len(scene) or scene.dim != each.dim
                          else scene_tables(each.bank.geometry, scene, each.canal.section_steps,
                                            version))
                built.append((each.bank, tables))
            with self._scene_lock:
                if self.scenes.get(skill) is known:
                    for bank, tables in built:
                        bank.scene = tables
                    return known
            # a newer scene came while these were built: build that one

    def _drop(self, skill: str, entry: ModelEntry) -> None:
        """Forget the skill's entry if it is still ``entry`` (not one installed meanwhile)."""
        with self._install_lock:
            if self.models.get(skill) is entry:
                del self.models[skill]

    def cached(self, skill: str) -> ModelEntry | None:
        """The skill's entry if one is at hand (a model, or an unexpired negative entry);
        None when it must be loaded."""
        entry = self.models.get(skill)
        if entry is not None:
            return entry
        entry = self.unknown.get(skill)
        if entry is not None and entry.expires > time.monotonic():
            return entry
        return None

    def entry(self, skill: str) -> ModelEntry:
        """The skill's entry, loaded on first use (and after a negative entry expired)."""
        entry = self.cached(skill)
        if entry is not None:
            return entry
        entry = self.load(skill)
        self.install(skill, entry)
        return entry

    def updated(self, skill: str, canal: Any, version: int) -> tuple[int, int] | None:
        """A fit landed: the skill's new model is built and installed now, on the calling
        thread (from ``canal`` when given, else read), so its next pose, or its first, finds
        it ready. With ``preload_max`` 0 only a skill in use is reloaded. Answers the skill's
        latest revision (None: it has no model, or is gone)."""
        self.unknown.pop(skill, None)
        # A notice names a version only: the skill under that name may have been deleted and
        # created again since the entry was built, its versions counting from 1 again. One
        # query says which model is the latest (fits are rare; poses never wait on it).
        try:
            revision: tuple[int, int] | None = self.service.latest_revision(skill)
        except (SkillNotFound, NoModelYet):
            revision = None  # gone meanwhile: the load below says which entry it gets
        old = self.models.get(skill)
        if old is None and self.options.preload_max <= 0:
            return revision  # not in use and not preloading: its first pose loads it
        if old is not None and old.status == "ok" and old.revision == revision:
            return revision  # already served
        if canal is not None and revision is not None and revision[1] == version:
            entry = ok_entry(version, canal, self.options.lookahead, created_ns=revision[0])
        else:  # read: the revision just asked for is not the entry's (no second query for it)
            entry = self.load(skill)
        if entry is not old:
            self.install(skill, entry)
        return revision

    def preload(self, stop: threading.Event | None = None) -> list[str]:
        """Load the models of the ``preload_max`` most recently fitted skills, newest first
        (one query lists them); the skills installed. Stops early when ``stop`` is set."""
        limit = self.options.preload_max
        if limit <= 0:
            return []
        started = time.monotonic()
        installed = []
        for rank, (skill, _version) in enumerate(self.service.skills_by_latest_fit(limit)):
            if stop is not None and stop.is_set():
                break
            if not keyspace.is_plain_chunk(skill):
                continue  # no pose key can name it
            old = self.models.get(skill)
            try:
                entry = self.load(skill, old)
            except Exception:
                log.exception("preloading the model of %r failed", skill)
                continue
            # The older the fit, the earlier it counts as used: when more skills are kept
            # than preload_max, the refresh drops the least recently fitted first.
            if (entry.status == "ok" and entry is not old
                    and self.install(skill, entry, used=started - 1e-6 * rank)):
                installed.append(skill)
        return installed

    def refresh(self, live_skills: set[str]) -> None:
        """Re-read the skills that have streams and the models kept ready for others (within
        ``preload_keep_s`` of their last use, at most ``preload_max`` of them, the most
        recently used); forget the rest and the expired negatives, so the table stays as
        small as the live fleet plus ``preload_max``."""
        now = time.monotonic()
        keep_s = self.options.preload_keep_s
        idle: list[tuple[float, str, ModelEntry]] = []
        for skill, entry in list(self.models.items()):
            if skill in live_skills:
                entry.used = now
            elif entry.status == "ok" and now - entry.used <= keep_s:
                idle.append((entry.used, skill, entry))
            else:
                self._drop(skill, entry)
        idle.sort(key=lambda item: item[0], reverse=True)
        for _used, skill, entry in idle[max(self.options.preload_max, 0):]:
            self._drop(skill, entry)
        for skill in list(self.models):
            old = self.models.get(skill)
            if old is None:
                continue
            try:
                entry = self.load(skill, old)
            except Exception:
                log.exception("model refresh for %r failed", skill)
                continue
            if entry is not old:
                self.install(skill, entry, used=old.used)
        # Under the lock: the worker installs entries meanwhile (iterating the live
        # OrderedDict raised "mutated during iteration" and killed the housekeeper; popping
        # between the worker's insert and move_to_end raised KeyError in the worker).
        with self._unknown_lock:
            expired = [skill for skill, entry in self.unknown.items() if entry.expires <= now]
            for skill in expired:
                del self.unknown[skill]


__all__ = ["ModelEntry", "ModelTable", "ok_entry"]
