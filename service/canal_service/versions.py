"""The model-version store: new model versions of a skill, made on its latest and stored one
after the other.

A fit, a correction and an undo each make a version on the skill's latest; this replica makes
a skill's versions one at a time (:class:`SkillLocks`), and the storing transaction checks that
what a version was made on is still the latest (another replica may have stored one
meanwhile), else the version is made again on the new latest.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypeVar

from sqlalchemy.exc import IntegrityError

from canal_core.routes import Routes, served_model
from canal_protocol import schemas

from .errors import SkillNotFound, VersionConflict
from .listeners import FitListeners
from .model_cache import CacheKey, CanalCache, model_cache_key
from .storage import Database, ModelVersion, Skill
from .storage import repository as repo

if TYPE_CHECKING:
    from .service import RecorderLike

_VERSION_RETRIES = 5
T = TypeVar("T")

InTransaction = Callable[[Any, Skill, int, list[int]], list[int]]


@dataclass(frozen=True)
class StoredLineage:
    """The lineage a new version is stored with; ``in_transaction(session, skill, version,
    ids)`` writes what must commit with it and answers the version's correction ids.

    ``parent_version`` and ``fit_version`` None: the fit stored just before it, in the same
    transaction (a refit's version with the corrections re-applied)."""

    parent_version: int | None
    fit_version: int | None
    correction_ids: list[int]
    in_transaction: InTransaction | None = None


@dataclass(frozen=True)
class NewVersion:
    """A model version to store: its options, demonstrations, serialised model, fit time,
    the model itself and, for a refined one, its lineage (None: a fit)."""

    options: dict[str, Any]
    demo_ids: list[int]
    serialized: dict[str, Any]
    fit_seconds: float
    routes: Routes
    lineage: StoredLineage | None = None


@dataclass(frozen=True)
class StoredVersion:
    """A model version just stored: its cache key, its summary, the skill's instance (for
    the recorder) and the model."""

    key: CacheKey
    summary: schemas.ModelSummary
    instance: str
    routes: Routes


class _StaleBase(Exception):
    """A new version was made on a latest version that is no longer the latest (another
    replica stored one meanwhile); nothing was stored. Never leaves the version store: the
    request is made again on the new latest."""

    def __init__(self, found: int) -> None:
        super().__init__(f"the latest is now version {found}")
        self.found = found


class SkillLocks:
    """One lock per skill name, held by the requests of this process that make model
    versions of it; a skill's lock is dropped when nobody holds it or waits for it."""

    def __init__(self) -> None:
        self._guard = threading.Lock()
        self._locks: dict[str, tuple[threading.Lock, int]] = {}

    @contextmanager
    def hold(self, name: str) -> Iterator[None]:
        with self._guard:
            lock, users = self._locks.get(name, (None, 0))
            if lock is None:
                lock = threading.Lock()
            self._locks[name] = (lock, users + 1)
        try:
            with lock:
                yield
        finally:
            with self._guard:
                users = self._locks[name][1] - 1
                if users:
                    self._locks[name] = (lock, users)
                else:
                    del self._locks[name]


def model_summary(row: ModelVersion, dim: int, lineage: repo.Lineage,
                  n_demos: int | None = None) -> schemas.ModelSummary:
    """The summary of a stored model version, with its lineage."""
    return schemas.ModelSummary(
        parent_version=lineage.parent_version, corrections=list(lineage.correction_ids),
        version=row.version, created_at=row.created_at, demo_ids=list(row.demo_ids),
        options=dict(row.options), dim=dim,
        n_demos=len(row.demo_ids) if n_demos is None else n_demos,
        n_sections=row.n_sections, section_kind=row.section_kind, fit_seconds=row.fit_seconds,
        has_orientation=bool(dict(row.options).get("orientation", False)),
        routes=int(dict(row.options).get("routes", 1)),
        demo_routes=dict(row.options).get("demo_routes"),
    )


class VersionStore:
    """Makes and stores the model versions of skills, and tells who hears of them.

    Parameters
    ----------
    db : Database
        Storage; every query goes through ``storage.repository``.
    cache : CanalCache
        Decoded models: a version just stored is kept decoded.
    fit_listeners : FitListeners
        Told of every committed version that is served (the live bridge subscribes).
    record : callable
        ``record(what, call)`` tells the recorder by ``call(recorder)``, if there is one, and
        never raises.
    """

    def __init__(self, db: Database, cache: CanalCache, fit_listeners: FitListeners,
                 record: Callable[[str, Callable[[RecorderLike], None]], None]) -> None:
        self.db = db
        self.cache = cache
        self.fit_listeners = fit_listeners
        self._record = record
        self._making = SkillLocks()

    def on_latest(self, name: str, what: str,
                  build: Callable[[], tuple[T, Callable[[], None]]]) -> T:
        """Make a new model version of a skill on its latest version.

        ``build`` reads the latest version, makes the new one and stores it with that latest
        as its base (:meth:`store`); it answers the result and what to tell once the version
        is stored (the recorder, the fit listeners: :meth:`tell`), told here after the skill
        is let go. This replica's requests that make versions of one skill (fits,
        corrections, undos) run ``build`` one at a time, so each one builds on the one
        before; a version another replica stored meanwhile makes the store refuse, and
        ``build`` runs again on the new latest.
        """
        stale: _StaleBase | None = None
        with self._making.hold(name):
            for _attempt in range(_VERSION_RETRIES):
                try:
                    result, tell = build()
                    break
                except _StaleBase as exc:
                    stale = exc
            else:
                assert stale is not None
                raise VersionConflict(
                    f"other replicas stored new versions of skill {name!r} while this {what} "
                    f"was made on the latest, {_VERSION_RETRIES} times in a row (the latest is "
                    f"now version {stale.found}); send it again", field="model") from stale
        tell()
        return result

    def store(self, name: str, made: Sequence[NewVersion], *, instance: str,
              base: int | None = None, kept: Sequence[int] | None = None
              ) -> list[StoredVersion]:
        """Store new model versions, numbered one after the other, in one transaction (a fit
        and its version with the corrections re-applied go in together: nobody sees the fit
        alone as the latest), with their lineage and what ``lineage.in_transaction`` writes
        in the same transaction (a new correction, a kept correction's new route).

        What they were made on must still be the latest, else nothing is stored and
        :class:`_StaleBase` says which version is the latest now: ``base``, the latest
        version a correction or an undo was made on; ``kept``, the corrections of the latest
        version a refit re-applied (any version with those same corrections will do: a fit
        is made of demonstrations, not of the version before it). Neither stores them
        whatever the latest is: a fit that keeps no correction, a correction of the version
        a request named. ``instance``: the skill the versions were made from
        (:func:`repo.skill_instance`, read with what they were made of); one deleted and
        created again under its name meanwhile is another skill, and gets none of them.
        """
        # Versions are max + 1 under a unique constraint, read with the skill's row locked
        # (next_model_version): the latest cannot change between the check and the insert.
        # Should two replicas still take one number, one wins, the other retries.
        clash: IntegrityError | None = None
        for _attempt in range(_VERSION_RETRIES):
            try:
                with self.db.write() as s:
                    skill = repo.get_skill(s, name)
                    if repo.skill_instance(skill.id, skill.created_at) != instance:
                        raise SkillNotFound(f"skill {name!r} was deleted while a new version of it "
                                            "was being made (a skill of that name was created "
                                            "since)", field="name")
                    first = repo.next_model_version(s, skill)
                    if base is not None and first - 1 != base:
                        raise _StaleBase(first - 1)
                    if kept is not None:
                        latest, ids = repo.latest_corrections(s, skill)
                        if ids != list(kept):
                            raise _StaleBase(latest)
                    return [self._add_version(s, skill, version, each)
                            for version, each in enumerate(made, start=first)]
            except IntegrityError as exc:
                clash = exc
        raise VersionConflict(
            f"concurrent fits of skill {name!r} took {_VERSION_RETRIES} version numbers in a "
            "row; fit again", field="version") from clash

    @staticmethod
    def _add_version(s: Any, skill: Skill, version: int, made: NewVersion) -> StoredVersion:
        canal = made.routes.pooled
        found = repo.Lineage(None, version, [])
        lineage = made.lineage
        if lineage is not None:
            # None: the fit stored just before it, in the same transaction
            parent = version - 1 if lineage.parent_version is None else lineage.parent_version
            fit = version - 1 if lineage.fit_version is None else lineage.fit_version
            ids = list(lineage.correction_ids)
            if lineage.in_transaction is not None:
                ids = lineage.in_transaction(s, skill, version, ids)
            found = repo.Lineage(parent, fit, ids)
        # the corrections' paths are stored in their rows, which the new one's joined above
        row = repo.add_model(s, skill, version, made.options, made.demo_ids, made.serialized,
                             made.fit_seconds, int(canal.n_sections), str(canal.section_kind),
                             found.correction_ids)
        if found.parent_version is not None:
            repo.add_lineage(s, row, found.parent_version, found.fit_version,
                             found.correction_ids)
        return StoredVersion(model_cache_key(row.id, skill.created_at),
                             model_summary(row, skill.dim, found, len(made.demo_ids)),
                             repo.skill_instance(skill.id, skill.created_at), made.routes)

    def tell(self, name: str, stored: StoredVersion, notify: bool = True) -> None:
        """Keep a stored version decoded, tell the recorder and (``notify``) the fit
        listeners: they serve it from the next pose on."""
        self.cache.put(stored.key, stored.routes)  # the next reproduction needs no decoding
        served = served_model(stored.routes)
        version, instance = stored.summary.version, stored.instance
        created = stored.summary.created_at
        stored_ns = None if created is None else repo.created_ns(created)
        self._record("model_fitted", lambda r: r.model_fitted(name, version, served,
                                                              t_ns=stored_ns, instance=instance))
        if notify:
            self.fit_listeners.notify(name, version, served)


__all__: Sequence[str] = ["NewVersion", "SkillLocks", "StoredLineage", "StoredVersion",
                          "VersionStore", "model_summary"]
