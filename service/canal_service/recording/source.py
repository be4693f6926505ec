"""The database as the recorder's source of truth: demos and models to (re-)log, read in batches.

The request path tells the recorder only *which* demo or model changed (ids); the recorder's
worker reads the arrays here, many at a time, off the request path. The same reads rebuild a
recording and fill in what a crash kept out of it (reconcile).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from sqlalchemy import select

from ..storage import Database, Demonstration, ModelVersion, Skill, StoredReproduction, arrays
from ..storage import repository as repo

#: Rows read per query when a whole skill is (re-)logged.
BATCH = 256


@dataclass(frozen=True)
class StoredDemo:
    """A stored demonstration as the recorder logs it."""

    skill: str
    demo_id: int
    positions: arrays.FloatArray  # (T, D)
    timestamps: arrays.FloatArray | None  # (T,)
    orientations: arrays.FloatArray | None  # (T, 4)
    label: str | None
    t_ns: int  # when it was stored


@dataclass(frozen=True)
class StoredModel:
    """A stored model version (the canal decoded) as the recorder logs it."""

    skill: str
    version: int
    canal: Any
    t_ns: int


@dataclass(frozen=True)
class Inventory:
    """What the database holds of one skill: its instance and the ids of its parts."""

    instance: str
    dim: int
    demos: set[int]
    models: set[int]
    reproductions: set[int]


@dataclass(frozen=True)
class StoredReproductionView:
    """A kept reproduction, with the attributes of a ``canal_core.Reproduction`` the
    recording draws."""

    number: int
    version: int
    positions: arrays.FloatArray  # (M, D)
    start: arrays.FloatArray  # (D,)
    times: arrays.FloatArray | None  # (M,)
    orientations: arrays.FloatArray | None  # (M, 4)
    inside: bool
    projected: bool
    eta: float
    section_index: int
    t_ns: int
    ratios: arrays.FloatArray | None = None  # (M,)


def _reproduction(row: StoredReproduction) -> StoredReproductionView:
    n, dim = row.n_points, row.dim
    return StoredReproductionView(
        number=int(row.number), version=int(row.model_version),
        positions=arrays.unpack(row.positions, n, dim), start=arrays.unpack(row.start, dim),
        times=None if row.times is None else arrays.unpack(row.times, n),
        orientations=None if row.orientations is None else arrays.unpack(row.orientations, n, 4),
        inside=bool(row.inside), projected=bool(row.projected), eta=float(row.eta),
        section_index=int(row.section_index), t_ns=_t_ns(row.created_at),
        ratios=None if row.ratios is None else arrays.unpack(row.ratios, n))


def _t_ns(created_at: Any) -> int:
    return 0 if created_at is None else repo.created_ns(created_at)


def _demo(skill: str, row: Demonstration) -> StoredDemo:
    return StoredDemo(
        skill=skill, demo_id=int(row.id),
        positions=arrays.unpack(row.positions, row.n_points, row.dim),
        timestamps=None if row.timestamps is None else arrays.unpack(row.timestamps, row.n_points),
        orientations=None if row.orientations is None else arrays.unpack(
            row.orientations, row.n_points, 4),
        label=row.label, t_ns=_t_ns(row.created_at))


class DbSource:
    """Reads what the recorder logs from the service's database (its own connections)."""

    def __init__(self, db: Database | str) -> None:
        self._own = isinstance(db, str)
        self.db = Database(db) if isinstance(db, str) else db

    def skills(self) -> dict[str, int]:
        """Every skill name with its dimension."""
        with self.db.read() as s:
            return {name: int(dim) for name, dim in s.execute(select(Skill.name, Skill.dim))}

    def instance(self, skill: str) -> str | None:
        """The skill's :func:`~canal_service.storage.repository.skill_instance`, or None
        when no skill has that name."""
        with self.db.read() as s:
            return repo.skill_instances(s, skill).get(skill)

    def instances(self) -> dict[str, str]:
        """Every skill's name with its instance."""
        with self.db.read() as s:
            return repo.skill_instances(s)

    def inventory(self, skill: str) -> Inventory | None:
        """What the database holds of ``skill`` (ids only), or None when it does not exist."""
        with self.db.read() as s:
            row = s.execute(select(Skill.id, Skill.created_at, Skill.dim)
                            .where(Skill.name == skill)).first()
            if row is None:
                return None
            sid = row[0]
            demos = set(s.scalars(select(Demonstration.id).where(Demonstration.skill_id == sid)))
            versions = set(s.scalars(select(ModelVersion.version)
                                     .where(ModelVersion.skill_id == sid)))
            numbers = set(s.scalars(select(StoredReproduction.number)
                                    .where(StoredReproduction.skill_id == sid)))
        return Inventory(repo.skill_instance(row[0], row[1]), int(row[2]), {int(d) for d in demos},
                         {int(v) for v in versions}, {int(n) for n in numbers})

    def reproductions(self, skill: str, numbers: Iterable[int]) -> list[StoredReproductionView]:
        """The skill's kept reproductions of these numbers (those still kept), in order."""
        wanted = sorted({int(n) for n in numbers})
        out: list[StoredReproductionView] = []
        with self.db.read() as s:
            sid = s.scalar(select(Skill.id).where(Skill.name == skill))
            if sid is None:
                return out
            for k in range(0, len(wanted), BATCH):
                rows = s.scalars(select(StoredReproduction)
                                 .where(StoredReproduction.skill_id == sid,
                                        StoredReproduction.number.in_(wanted[k:k + BATCH]))
                                 .order_by(StoredReproduction.number))
                out.extend(_reproduction(r) for r in rows)
        return out

    def demos(self, skill: str, ids: Iterable[int] | None = None) -> list[StoredDemo]:
        """Stored demos of ``skill`` (the given ids that still exist, or all), in id order."""
        wanted = None if ids is None else sorted({int(i) for i in ids})
        out: list[StoredDemo] = []
        with self.db.read() as s:
            sid = s.scalar(select(Skill.id).where(Skill.name == skill))
            if sid is None:
                return out
            query = select(Demonstration).where(Demonstration.skill_id == sid)
            if wanted is None:
                out.extend(_demo(skill, r) for r in s.scalars(query.order_by(Demonstration.id)))
                return out
            for k in range(0, len(wanted), BATCH):
                rows = s.scalars(query.where(Demonstration.id.in_(wanted[k:k + BATCH]))
                                 .order_by(Demonstration.id))
                out.extend(_demo(skill, r) for r in rows)
        return out

    def models(self, skill: str, versions: Sequence[int] | None = None) -> list[StoredModel]:
        """Stored model versions of ``skill`` (the given ones, or all), oldest first."""
        import canal_core

        out: list[StoredModel] = []
        with self.db.read() as s:
            sid = s.scalar(select(Skill.id).where(Skill.name == skill))
            if sid is None:
                return out
            query = select(ModelVersion).where(ModelVersion.skill_id == sid)
            if versions is not None:
                query = query.where(ModelVersion.version.in_([int(v) for v in versions]))
            for row in s.scalars(query.order_by(ModelVersion.version)):
                out.append(StoredModel(
                    skill, int(row.version),
                    canal_core.routes.served_model(
                        canal_core.routes.routes_from_dict(repo.model_canal(s, row))),
                    _t_ns(row.created_at)))
        return out

    def close(self) -> None:
        """Close the connections this source opened."""
        if self._own:
            self.db.dispose()


def as_array(value: Any) -> Any:
    """``value`` as float64 without copying when it already is (None stays None)."""
    return None if value is None else np.asarray(value, dtype=np.float64)
