"""Repository functions: every query the service runs, each taking the caller's session.

They raise the service's domain errors (``SkillNotFound``, ``SkillExists``, ...; no HTTP in
them) so callers never see SQLAlchemy exceptions for expected situations. Transactions
belong to the caller (except the upload insert, a transaction of one statement).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import numpy as np
from sqlalchemy import and_, bindparam, delete, func, insert, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session, defer

from ..errors import (
    CorrectionNotFound,
    DemoNotFound,
    InvalidInput,
    ModelVersionNotFound,
    NoModelYet,
    SkillExists,
    SkillNotFound,
    SkillReplaced,
)
from . import arrays, stored_models
from .db import Database
from .models import (
    Correction,
    Demonstration,
    ModelLineage,
    ModelVersion,
    SceneRow,
    Skill,
    StoredReproduction,
    utcnow,
)


@dataclass(frozen=True)
class SkillStats:
    """Counts shown with a skill."""

    n_demonstrations: int
    n_models: int
    latest_model_version: int | None


#: PostgreSQL advisory lock key under which skills are created ("canal" in ASCII).
_SKILL_NAMES_LOCK = 0x63616E616C


def create_skill(session: Session, name: str, description: str, dim: int) -> Skill:
    """Insert a skill; a name already taken, also in another letter case, is :class:`SkillExists`."""
    # A skill's recordings live in a folder named after it: on a case-insensitive file
    # system (macOS, Windows) "Pour" and "pour" would record into one.
    if session.get_bind().dialect.name == "postgresql":
        # The check below is a query, and replicas share the database: without this lock two
        # of them creating "Pour" and "pour" at once both pass it. (SQLite writes one
        # transaction at a time already.) Held to the end of the transaction.
        session.execute(select(func.pg_advisory_xact_lock(_SKILL_NAMES_LOCK)))
    taken = session.scalars(
        select(Skill.name).where(func.lower(Skill.name) == name.lower(), Skill.name != name).limit(1)
    ).first()
    if taken is not None:
        raise SkillExists(
            f"skill {taken!r} already exists: expected a name that differs from it by more than "
            f"letter case, got {name!r}", field="name")
    skill = Skill(name=name, description=description, dim=dim)
    session.add(skill)
    try:
        session.flush()
    except IntegrityError as exc:
        raise SkillExists(f"skill {name!r} already exists", field="name") from exc
    return skill


def get_skill(session: Session, name: str, *, lock: bool = False) -> Skill:
    """The skill called ``name``, or :class:`SkillNotFound`. ``lock``: its row stays locked
    until the write transaction ends, so writes of the same skill's rows run in turn (on
    PostgreSQL they otherwise run side by side; a skill deleted meanwhile is then not found)."""
    query = select(Skill).where(Skill.name == name)
    skill = session.scalars(query.with_for_update() if lock else query).one_or_none()
    if skill is None:
        raise SkillNotFound(f"no skill named {name!r}", field="name")
    return skill


def skill_stats(session: Session, skill_ids: Sequence[int]) -> dict[int, SkillStats]:
    """Counts for several skills in two grouped queries."""
    demos = dict(
        session.execute(
            select(Demonstration.skill_id, func.count())
            .where(Demonstration.skill_id.in_(skill_ids))
            .group_by(Demonstration.skill_id)
        ).all()
    )
    models = {
        sid: (n, latest)
        for sid, n, latest in session.execute(
            select(ModelVersion.skill_id, func.count(), func.max(ModelVersion.version))
            .where(ModelVersion.skill_id.in_(skill_ids))
            .group_by(ModelVersion.skill_id)
        )
    }
    return {
        sid: SkillStats(demos.get(sid, 0), models.get(sid, (0, None))[0], models.get(sid, (0, None))[1])
        for sid in skill_ids
    }


def list_skills(session: Session, offset: int, limit: int) -> tuple[list[Skill], int]:
    """A page of skills by name, and the total count."""
    total = session.scalar(select(func.count()).select_from(Skill)) or 0
    rows = session.scalars(select(Skill).order_by(Skill.name).offset(offset).limit(limit)).all()
    return list(rows), total


def delete_skill(session: Session, name: str) -> None:
    """Delete a skill; its demonstrations, models and kept reproductions go with it (FK
    cascade). Deleted once: a delete racing another finds no skill."""
    skill = get_skill(session, name, lock=True)
    # Explicit deletes too, so the cascade does not depend on the backend's FK enforcement.
    session.execute(delete(Demonstration).where(Demonstration.skill_id == skill.id))
    session.execute(delete(ModelLineage).where(ModelLineage.skill_id == skill.id))
    session.execute(delete(Correction).where(Correction.skill_id == skill.id))
    session.execute(delete(ModelVersion).where(ModelVersion.skill_id == skill.id))
    session.execute(delete(StoredReproduction).where(StoredReproduction.skill_id == skill.id))
    session.execute(delete(SceneRow).where(SceneRow.skill_id == skill.id))
    session.execute(delete(Skill).where(Skill.id == skill.id))


@dataclass(frozen=True)
class StoredDemo:
    """What the upload path needs back from an insert."""

    id: int
    n_points: int
    checksum: str
    dim: int


# Built once: constructing a statement per call costs more than running it on SQLite.
_SKILL_ID_AND_DIM = select(Skill.id, Skill.dim).where(Skill.name == bindparam("name"))
# One round trip: the row is inserted only when a skill of that name has the demo's
# dimension (INSERT ... SELECT ... RETURNING); no row back means one of the two is wrong,
# and only that error path looks up which.
def _insert_demonstration_into(skill: Any) -> Any:
    """INSERT ... SELECT of a demonstration into the skill ``skill`` picks out, when it has
    the demonstration's dimension."""
    return insert(Demonstration).from_select(
        ["skill_id", "label", "n_points", "dim", "positions", "timestamps", "orientations",
         "checksum", "source", "created_at"],
        select(
            Skill.id,
            bindparam("label", type_=Demonstration.label.type),
            bindparam("n_points", type_=Demonstration.n_points.type),
            Skill.dim,
            bindparam("positions", type_=Demonstration.positions.type),
            bindparam("timestamps", type_=Demonstration.timestamps.type),
            bindparam("orientations", type_=Demonstration.orientations.type),
            bindparam("checksum", type_=Demonstration.checksum.type),
            bindparam("source", type_=Demonstration.source.type),
            bindparam("created_at", type_=Demonstration.created_at.type),
        ).where(skill, Skill.dim == bindparam("dim")),
    ).returning(Demonstration.id)


_INSERT_DEMONSTRATION = _insert_demonstration_into(Skill.name == bindparam("name"))
# A capture's demonstration goes into the skill row it began on, by id, with that row
# locked and its instance checked in the same transaction.
_INSERT_DEMONSTRATION_OF_SKILL = _insert_demonstration_into(Skill.id == bindparam("skill_id"))


def insert_demonstration(
    db: Database,
    skill_name: str,
    positions: arrays.FloatArray,
    timestamps: arrays.FloatArray | None,
    orientations: arrays.FloatArray | None,
    label: str | None,
    source: str,
    *,
    captured_on: tuple[str, str] | None = None,
) -> StoredDemo:
    """Store a checked demonstration: one statement, committed on its own.

    The upload hot path, hence the exception to "transactions belong to the caller": the
    skill is looked up and its dimension compared by the insert itself (a skill deleted or
    recreated meanwhile cannot slip through), no ORM objects are built for a row that is
    only written, and :meth:`Database.write_one` runs it on SQLite without SQLAlchemy's
    per-execution work.

    ``captured_on``: (what was captured, :func:`skill_instance`) of the skill a live capture
    began on; the demonstration goes into that skill only, else :class:`SkillReplaced`.
    """
    packed = arrays.pack(positions)
    digest = arrays.checksum_of_packed(packed)
    n_points, dim = int(positions.shape[0]), int(positions.shape[1])
    values = {
        "name": skill_name, "dim": dim, "label": label, "n_points": n_points,
        "positions": packed,
        "timestamps": None if timestamps is None else arrays.pack(timestamps),
        "orientations": None if orientations is None else arrays.pack(orientations),
        "checksum": digest, "source": source, "created_at": utcnow(),
    }
    if captured_on is None:
        try:
            row = db.write_one(_INSERT_DEMONSTRATION, values)
        except IntegrityError:
            # Its foreign key, the one constraint the checked values can fail: on PostgreSQL
            # the skill was read before a delete committed. Why is looked up as for a miss.
            row = None
    else:
        with db.write() as session:
            skill_id = skill_of_instance(session, skill_name, *captured_on, lock=True)
            row = session.connection().execute(_INSERT_DEMONSTRATION_OF_SKILL,
                                               {**values, "skill_id": skill_id}).first()
    if row is None:
        with db.read() as session:
            raise _refused_insert(session, skill_name, dim)
    return StoredDemo(int(row[0]), n_points, digest, dim)


def skill_of_instance(session: Session, name: str, what: str, instance: str, *,
                      lock: bool = False) -> int:
    """The id of the skill under ``name`` when it is the instance ``instance``
    (:func:`skill_instance`) a capture of ``what`` began on, else :class:`SkillReplaced`;
    ``lock``: its row stays locked until the write transaction ends."""
    query = select(Skill.id, Skill.created_at).where(Skill.name == name)
    found = session.execute(query.with_for_update() if lock else query).first()
    if found is None or skill_instance(found[0], found[1]) != instance:
        raise SkillReplaced(name, what, exists=found is not None)
    return int(found[0])


def _refused_insert(session: Session, skill_name: str, dim: int
                    ) -> SkillNotFound | SkillReplaced | InvalidInput:
    """Why :data:`_INSERT_DEMONSTRATION` inserted nothing: no such skill, or another dimension."""
    found = session.execute(_SKILL_ID_AND_DIM, {"name": skill_name}).first()
    if found is None:
        return SkillNotFound(f"no skill named {skill_name!r}", field="name")
    skill_dim = int(found[1])
    if skill_dim == dim:  # the skill the insert missed was deleted, one was created since
        return SkillReplaced(skill_name, "demonstration", exists=True, field="name",
                             when="it was sent; send it again to store it in the new one")
    axes = "x, y, z" if skill_dim == 3 else "x, y"
    return InvalidInput(
        f"expected {skill_dim} values per row ({axes} for the {skill_dim}-D skill "
        f"{skill_name!r}), got {dim} at row 0",
        field="positions[0]",
    )


_BLOBS = (defer(Demonstration.positions), defer(Demonstration.timestamps),
          defer(Demonstration.orientations))


def list_demonstrations(
    session: Session, skill: Skill, offset: int, limit: int
) -> tuple[list[Demonstration], int, dict[int, tuple[bool, bool]]]:
    """A page of demonstrations without their arrays, the total, and which have t / q."""
    total = session.scalar(
        select(func.count()).select_from(Demonstration).where(Demonstration.skill_id == skill.id)
    ) or 0
    rows = session.scalars(
        select(Demonstration).options(*_BLOBS).where(Demonstration.skill_id == skill.id)
        .order_by(Demonstration.id).offset(offset).limit(limit)
    ).all()
    ids = [r.id for r in rows]
    flags = {
        did: (bool(has_t), bool(has_q))
        for did, has_t, has_q in session.execute(
            select(Demonstration.id, Demonstration.timestamps.is_not(None),
                   Demonstration.orientations.is_not(None)).where(Demonstration.id.in_(ids))
        )
    }
    return list(rows), total, flags


def get_demonstration(session: Session, skill: Skill, demo_id: int) -> Demonstration:
    """One demonstration of ``skill`` with its arrays, or :class:`DemoNotFound`."""
    demo = session.scalars(
        select(Demonstration).where(Demonstration.skill_id == skill.id, Demonstration.id == demo_id)
    ).one_or_none()
    if demo is None:
        raise DemoNotFound(f"skill {skill.name!r} has no demonstration {demo_id}", field="id")
    return demo


def delete_demonstration(session: Session, skill: Skill, demo_id: int) -> None:
    """Delete one demonstration; model versions that used it stay (they are history)."""
    demo = get_demonstration(session, skill, demo_id)
    session.delete(demo)


def demonstrations_for_fit(
    session: Session, skill: Skill, ids: Sequence[int] | None
) -> list[Demonstration]:
    """The demonstrations to fit, in id order (the caller names unknown ids)."""
    query = select(Demonstration).where(Demonstration.skill_id == skill.id)
    if ids is not None:
        query = query.where(Demonstration.id.in_(list(ids)))
    return list(session.scalars(query.order_by(Demonstration.id)).all())


def next_model_version(session: Session, skill: Skill) -> int:
    """One more than the highest version, with the skill row locked until the caller commits.

    Replicas fitting the same skill at once queue on that row lock instead of both reading
    the same maximum and colliding on ``uq_models_skill_version``. ``FOR NO KEY UPDATE``
    rather than ``FOR UPDATE``: uploads (which only take a key-share lock through their
    foreign key) keep flowing. SQLite has no row locks and needs none: its write
    transactions start with ``BEGIN IMMEDIATE`` and run one at a time.
    """
    session.execute(select(Skill.id).where(Skill.id == skill.id).with_for_update(key_share=True))
    latest = session.scalar(
        select(func.max(ModelVersion.version)).where(ModelVersion.skill_id == skill.id)
    )
    return int(latest or 0) + 1


def add_model(
    session: Session,
    skill: Skill,
    version: int,
    options: dict[str, Any],
    demo_ids: list[int],
    canal: dict[str, Any],
    fit_seconds: float,
    n_sections: int,
    section_kind: str,
    correction_ids: Sequence[int] = (),
) -> ModelVersion:
    """Insert a model version (flushes, so a version clash raises IntegrityError here).
    ``correction_ids``: the corrections it holds; their paths are stored in their rows only,
    and ``canal`` names them (:func:`stored_models.without_paths`)."""
    if correction_ids:
        canal = stored_models.without_paths(canal, get_corrections(session, skill,
                                                                   list(correction_ids)))
    model = ModelVersion(skill_id=skill.id, version=version, options=options, demo_ids=demo_ids,
                         canal=canal, fit_seconds=fit_seconds, n_sections=n_sections,
                         section_kind=section_kind)
    session.add(model)
    session.flush()
    return model


_NO_CANAL = (defer(ModelVersion.canal),)


def model_canal(session: Session, row: ModelVersion) -> dict[str, Any]:
    """A model row's canal dict with its corrections' paths filled in from their rows (a
    version names them: :mod:`~canal_service.storage.stored_models`), as canal_core decodes
    it; the row's own dict is left as stored."""
    ids = stored_models.path_ids(row.canal)
    if not ids:
        return row.canal
    rows = session.scalars(select(Correction).where(Correction.skill_id == row.skill_id,
                                                    Correction.id.in_(ids)))
    return stored_models.with_paths(row.canal, {int(r.id): stored_models.path_of(r) for r in rows})


def list_models(session: Session, skill: Skill, offset: int, limit: int
                ) -> tuple[list[ModelVersion], int]:
    """A page of model versions (newest first) without the serialised canal, and the total."""
    total = session.scalar(
        select(func.count()).select_from(ModelVersion).where(ModelVersion.skill_id == skill.id)
    ) or 0
    rows = session.scalars(
        select(ModelVersion).options(*_NO_CANAL).where(ModelVersion.skill_id == skill.id)
        .order_by(ModelVersion.version.desc()).offset(offset).limit(limit)
    ).all()
    return list(rows), total


def model_ref(session: Session, skill: Skill, version: int | None) -> tuple[int, int] | None:
    """(row id, version) of a version, or of the latest when ``version`` is None."""
    query = select(ModelVersion.id, ModelVersion.version).where(ModelVersion.skill_id == skill.id)
    if version is None:
        query = query.order_by(ModelVersion.version.desc()).limit(1)
    else:
        query = query.where(ModelVersion.version == version)
    row = session.execute(query).first()
    return None if row is None else (int(row[0]), int(row[1]))


def require_model_ref(session: Session, skill: Skill, version: int | None) -> tuple[int, int]:
    """(row id, version) of a version, or of the latest when ``version`` is None.

    :class:`NoModelYet` when the latest is asked of a skill never fitted,
    :class:`ModelVersionNotFound` when that version does not exist.
    """
    ref = model_ref(session, skill, version)
    if ref is not None:
        return ref
    if version is None:
        raise NoModelYet(skill.name, skill.dim)
    raise ModelVersionNotFound(f"skill {skill.name!r} has no model version {version}",
                               field="model")


@dataclass(frozen=True)
class ModelRef:
    """Which model row a request means, and the skill's id, dimension and creation time."""

    skill_id: int
    dim: int
    skill_created_at: datetime
    model_id: int
    version: int


# Nothing of the model row after its ``canal`` column: SQLite would walk that column's
# overflow pages (megabytes for a canal fitted from hundreds of demos) to reach it.
_REF_COLUMNS = (Skill.id, Skill.dim, Skill.created_at, ModelVersion.id, ModelVersion.version)
# One round trip for the skill and its model row, built once. The outer join keeps the
# skill's row when it has no model (or not that version): model columns NULL. Ordering by
# version descending is safe although PostgreSQL sorts NULLs first there: the NULL row
# only exists when no model row joins at all.
_LATEST_REF = (
    select(*_REF_COLUMNS).select_from(Skill)
    .outerjoin(ModelVersion, ModelVersion.skill_id == Skill.id)
    .where(Skill.name == bindparam("name"))
    .order_by(ModelVersion.version.desc()).limit(1)
)
_VERSION_REF = (
    select(*_REF_COLUMNS).select_from(Skill)
    .outerjoin(ModelVersion, and_(ModelVersion.skill_id == Skill.id,
                                  ModelVersion.version == bindparam("version")))
    .where(Skill.name == bindparam("name")).limit(1)
)


def model_ref_by_name(db: Database, skill_name: str, version: int | None) -> ModelRef:
    """The row of a version (or of the latest when ``version`` is None) of a skill by name.

    The reproduction hot path: one statement, no ORM objects. Raises :class:`SkillNotFound`,
    :class:`NoModelYet` or :class:`ModelVersionNotFound` as :func:`require_model_ref`.
    """
    if version is None:
        row = db.read_one(_LATEST_REF, {"name": skill_name})
    else:
        row = db.read_one(_VERSION_REF, {"name": skill_name, "version": version})
    if row is None:
        raise SkillNotFound(f"no skill named {skill_name!r}", field="name")
    skill_id, dim, skill_created_at, model_id, found = row
    if model_id is None:
        if version is None:
            raise NoModelYet(skill_name, int(dim))
        raise ModelVersionNotFound(f"skill {skill_name!r} has no model version {version}",
                                   field="model")
    return ModelRef(int(skill_id), int(dim), skill_created_at, int(model_id), int(found))


def skills_by_latest_fit(session: Session, limit: int) -> list[tuple[str, int]]:
    """(name, latest version) of at most ``limit`` skills that have a model, most recently
    fitted first: one grouped query, without reading any model's ``canal`` column.

    "Most recently fitted" is the highest model row id: both backends give a new row an id
    above every existing one (SQLite's max + 1, PostgreSQL's sequence), and the id, unlike
    ``created_at``, sits before the canal in the row (see ``_REF_COLUMNS``).
    """
    newest = func.max(ModelVersion.id)
    rows = session.execute(
        select(Skill.name, func.max(ModelVersion.version))
        .join(ModelVersion, ModelVersion.skill_id == Skill.id)
        .group_by(Skill.id, Skill.name)
        .order_by(newest.desc(), Skill.name)
        .limit(limit)
    ).all()
    return [(str(name), int(version)) for name, version in rows]


def get_model(session: Session, model_id: int) -> ModelVersion:
    """A model row by its primary key (the caller got the id from :func:`model_ref`)."""
    model = session.get(ModelVersion, model_id)
    if model is None:
        raise ModelVersionNotFound(f"model {model_id} is gone", field="model")
    return model


# ---- a skill's identity, and the reproductions its recording keeps ----------------------------


def skill_instance(skill_id: int, created_at: datetime) -> str:
    """The one name of a skill *instance*: its id with its creation time (UTC, microseconds).

    A name is not an identity: a skill deleted and created again under the same name is
    another skill, and on SQLite it can even get the deleted row's id back. Its creation
    time tells them apart. Naive times are UTC (SQLite returns them so).
    """
    if created_at.tzinfo is not None:
        created_at = created_at.astimezone(UTC).replace(tzinfo=None)
    return f"{int(skill_id)}-{created_at.strftime('%Y%m%dT%H%M%S%f')}"


def created_ns(created_at: datetime) -> int:
    """A row's creation time in nanoseconds since the epoch (naive times are UTC): the log
    time of what the row records, the same on every replica."""
    if created_at.tzinfo is None:
        created_at = created_at.replace(tzinfo=UTC)
    whole_seconds = int(created_at.replace(microsecond=0).timestamp())
    return whole_seconds * 1_000_000_000 + created_at.microsecond * 1_000


def skill_instances(session: Session, name: str | None = None) -> dict[str, str]:
    """Skill name -> :func:`skill_instance` of every skill (or of the one named)."""
    query = select(Skill.name, Skill.id, Skill.created_at)
    if name is not None:
        query = query.where(Skill.name == name)
    return {str(n): skill_instance(i, c) for n, i, c in session.execute(query)}


#: Attempts at a reproduction's number when replicas take the same one at once.
_NUMBER_RETRIES = 8


@dataclass(frozen=True)
class KeptReproduction:
    """A stored reproduction's number and creation time."""

    number: int
    created_at: datetime


_R = StoredReproduction
# One statement per reproduction, built once: the row is numbered one past the skill's last
# (a correlated subquery) and inserted only while the skill is the instance the reproduction
# was computed for (its id *and* creation time); no row back means it is gone.
_INSERT_REPRODUCTION = insert(_R).from_select(
    ["skill_id", "number", "model_version", "n_points", "dim", "positions", "start", "times",
     "orientations", "inside", "projected", "eta", "section_index", "ratios", "created_at"],
    select(
        Skill.id,
        select(func.coalesce(func.max(_R.number), 0) + 1).where(_R.skill_id == Skill.id)
        .scalar_subquery(),
        *(bindparam(name, type_=_R.__table__.c[name].type) for name in (
            "model_version", "n_points", "dim", "positions", "start", "times", "orientations",
            "inside", "projected", "eta", "section_index", "ratios", "created_at")),
    ).where(Skill.id == bindparam("skill_id"),
            Skill.created_at == bindparam("skill_created_at", type_=Skill.created_at.type)),
).returning(_R.number)
# FOR NO KEY UPDATE, as a fit's version takes it: uploads (a key-share lock) keep flowing.
_LOCK_SKILL = select(Skill.id).where(Skill.id == bindparam("skill_id")).with_for_update(
    key_share=True)
_PRUNE_REPRODUCTIONS = delete(_R).where(_R.skill_id == bindparam("skill_id"),
                                        _R.number <= bindparam("oldest_dropped"))


def insert_reproductions(db: Database, skill_id: int, skill_created_at: datetime, version: int,
                         results: Sequence[Any], keep: int) -> list[KeptReproduction]:
    """Store ``results`` (``canal_core.Reproduction``) for the skill's recording, numbered on
    from the skill's last one; the skill keeps its newest ``keep`` (older ones are deleted
    every ``min(32, keep // 2)`` numbers, so up to that many more are kept meanwhile).

    Nothing is stored when the skill is gone or is another instance than the one the
    reproduction was computed for (deleted and created again meanwhile). Two replicas that
    take the same number at once collide on ``uq_reproductions_skill_number``; the loser
    tries again holding the skill row's lock (as fits take theirs), so the numbers of those
    that collided are taken one at a time.
    """
    now = utcnow()
    rows = []
    for result in results:
        positions = np.asarray(result.positions, dtype=np.float64)
        times = getattr(result, "times", None)
        quats = getattr(result, "orientations", None)
        ratios = getattr(result, "ratios", None)
        rows.append({
            "skill_id": skill_id, "skill_created_at": skill_created_at,
            "model_version": int(version),
            "n_points": int(positions.shape[0]), "dim": int(positions.shape[1]),
            "positions": arrays.pack(positions),
            "start": arrays.pack(np.asarray(result.start, dtype=np.float64)),
            "times": None if times is None else arrays.pack(np.asarray(times, np.float64)),
            "orientations": None if quats is None else arrays.pack(
                np.asarray(quats, dtype=np.float64)),
            "inside": bool(result.inside), "projected": bool(result.projected),
            "eta": float(result.eta), "section_index": int(result.section_index),
            "ratios": None if ratios is None else arrays.pack(np.asarray(ratios, np.float64)),
            "created_at": now,
        })
    step = max(1, min(32, keep // 2))
    clash: IntegrityError | None = None
    for attempt in range(_NUMBER_RETRIES):
        try:
            numbers: list[int] = []
            with db.write_connection() as connection:  # Core only: no ORM session here
                if attempt > 0 and not db.is_sqlite:  # SQLite's writers never collide
                    connection.execute(_LOCK_SKILL, {"skill_id": skill_id})
                for values in rows:
                    number = connection.execute(_INSERT_REPRODUCTION, values).scalar()
                    if number is None:
                        return []  # the skill is gone (or is another instance now)
                    numbers.append(int(number))
                if keep > 0 and numbers and any(n > keep and n % step == 0 for n in numbers):
                    connection.execute(_PRUNE_REPRODUCTIONS, {
                        "skill_id": skill_id, "oldest_dropped": numbers[-1] - keep})
            return [KeptReproduction(n, now) for n in numbers]
        except IntegrityError as exc:
            clash = exc
    assert clash is not None
    raise clash


# ---- scenes ------------------------------------------------------------------------------------


def get_scene(session: Session, skill: Skill) -> SceneRow | None:
    """The skill's scene row, None when it never had one."""
    return session.get(SceneRow, skill.id)


def put_scene(session: Session, skill: Skill, obstacles: list[dict[str, Any]]) -> SceneRow:
    """Replace the skill's obstacles; the version goes up by one (the last write wins)."""
    row = session.get(SceneRow, skill.id, with_for_update=True)
    if row is None:
        row = SceneRow(skill_id=skill.id, version=1, obstacles=obstacles)
        session.add(row)
    else:
        row.version = row.version + 1
        row.obstacles = obstacles
        row.updated_at = utcnow()
    session.flush()
    return row


# ---- corrections and lineage -----------------------------------------------------------------


@dataclass(frozen=True)
class Lineage:
    """Where a model version came from: None / its own version / [] for a plain fit."""

    parent_version: int | None
    fit_version: int
    correction_ids: list[int]


def add_lineage(session: Session, model: ModelVersion, parent_version: int, fit_version: int,
                correction_ids: list[int]) -> None:
    """Record that ``model`` was refined from ``parent_version`` (of the fit ``fit_version``)."""
    session.add(ModelLineage(model_id=model.id, skill_id=model.skill_id,
                             parent_version=parent_version, fit_version=fit_version,
                             correction_ids=list(correction_ids)))
    session.flush()


def lineages(session: Session, models: Sequence[ModelVersion]) -> dict[int, Lineage]:
    """The lineage of each model row, by row id (a plain fit's from its own version)."""
    found = {
        row.model_id: row for row in session.scalars(
            select(ModelLineage).where(ModelLineage.model_id.in_([m.id for m in models])))
    }
    out = {}
    for m in models:
        row = found.get(m.id)
        out[m.id] = (Lineage(None, m.version, []) if row is None else
                     Lineage(row.parent_version, row.fit_version, list(row.correction_ids)))
    return out


def latest_corrections(session: Session, skill: Skill) -> tuple[int, list[int]]:
    """(the skill's latest model version, 0 when it has none; the ids of that version's
    corrections, in the order applied), from one query that leaves the canal unread."""
    row = session.execute(
        select(ModelVersion.version, ModelLineage.correction_ids)
        .outerjoin(ModelLineage, ModelLineage.model_id == ModelVersion.id)
        .where(ModelVersion.skill_id == skill.id)
        .order_by(ModelVersion.version.desc()).limit(1)
    ).first()
    if row is None:
        return 0, []
    return int(row[0]), [int(i) for i in row[1] or ()]


def insert_correction(session: Session, skill: Skill, kind: str, label: str, weight: float,
                      samples: arrays.FloatArray, timestamps: arrays.FloatArray | None,
                      orientations: arrays.FloatArray | None, plan: arrays.FloatArray | None,
                      base_version: int,
                      model_version: int, first_section: int, last_section: int,
                      route: int | None = None) -> Correction:
    """Store a correction (flushes, so its id is known)."""
    row = Correction(
        skill_id=skill.id, kind=kind, label=label, weight=weight, n_points=int(samples.shape[0]),
        dim=int(samples.shape[1]), samples=arrays.pack(samples),
        timestamps=None if timestamps is None else arrays.pack(timestamps),
        orientations=None if orientations is None else arrays.pack(orientations),
        plan=None if plan is None else arrays.pack(plan), base_version=base_version,
        model_version=model_version, first_section=first_section, last_section=last_section,
        route=route,
    )
    session.add(row)
    session.flush()
    return row


def list_corrections(session: Session, skill: Skill, offset: int, limit: int
                     ) -> tuple[list[Correction], int]:
    """A page of the skill's corrections, oldest first, and the total."""
    total = session.scalar(
        select(func.count()).select_from(Correction).where(Correction.skill_id == skill.id)
    ) or 0
    rows = session.scalars(
        select(Correction).where(Correction.skill_id == skill.id)
        .order_by(Correction.id).offset(offset).limit(limit)
    ).all()
    return list(rows), total


def correction_points(session: Session, skill: Skill, ids: Sequence[int]) -> list[int]:
    """The number of samples of each of the skill's corrections with these ids (those that
    exist), without reading their paths."""
    return [int(n) for n in session.scalars(
        select(Correction.n_points).where(Correction.skill_id == skill.id,
                                          Correction.id.in_(list(ids))))]


def get_corrections(session: Session, skill: Skill, ids: Sequence[int]) -> list[Correction]:
    """The skill's corrections with these ids, in the order of ``ids``
    (:class:`CorrectionNotFound` for the first missing)."""
    rows = {
        r.id: r for r in session.scalars(
            select(Correction).where(Correction.skill_id == skill.id, Correction.id.in_(list(ids))))
    }
    for i in ids:
        if i not in rows:
            raise CorrectionNotFound(f"skill {skill.name!r} has no correction {i}", field="id")
    return [rows[i] for i in ids]
