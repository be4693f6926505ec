"""SQLAlchemy tables. The Alembic migrations in ``canal_service/migrations`` create them."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any

from sqlalchemy import (
    JSON,
    Boolean,
    DateTime,
    Float,
    ForeignKey,
    Integer,
    LargeBinary,
    String,
    Text,
    UniqueConstraint,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column, relationship


def utcnow() -> datetime:
    """Timezone-aware now; one clock for every row."""
    return datetime.now(UTC)


class Base(DeclarativeBase):
    """Declarative base of the service's tables."""


class Skill(Base):
    """A named task with one dimension; owns its demonstrations and model versions."""

    __tablename__ = "skills"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(String(64), unique=True, nullable=False)
    description: Mapped[str] = mapped_column(Text, nullable=False, default="")
    dim: Mapped[int] = mapped_column(Integer, nullable=False)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)

    demonstrations: Mapped[list[Demonstration]] = relationship(
        back_populates="skill", cascade="all, delete-orphan", passive_deletes=True
    )
    models: Mapped[list[ModelVersion]] = relationship(
        back_populates="skill", cascade="all, delete-orphan", passive_deletes=True
    )


class Demonstration(Base):
    """One recorded trajectory, arrays stored as packed float64 bytes (see ``arrays``)."""

    __tablename__ = "demonstrations"
    # An id is never given twice (SQLite would give a deleted last row's id to the next one):
    # models list their demonstrations by id, and clients hold ids.
    __table_args__ = ({"sqlite_autoincrement": True},)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    skill_id: Mapped[int] = mapped_column(
        ForeignKey("skills.id", ondelete="CASCADE"), index=True, nullable=False
    )
    label: Mapped[str | None] = mapped_column(String(256), nullable=True)
    n_points: Mapped[int] = mapped_column(Integer, nullable=False)
    dim: Mapped[int] = mapped_column(Integer, nullable=False)
    positions: Mapped[bytes] = mapped_column(LargeBinary, nullable=False)
    timestamps: Mapped[bytes | None] = mapped_column(LargeBinary, nullable=True)
    orientations: Mapped[bytes | None] = mapped_column(LargeBinary, nullable=True)
    checksum: Mapped[str] = mapped_column(String(64), nullable=False)
    source: Mapped[str] = mapped_column(String(16), nullable=False, default="json")
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)

    skill: Mapped[Skill] = relationship(back_populates="demonstrations")


class ModelVersion(Base):
    """One fit, kept forever: the options, the demos it used and the serialised canal."""

    __tablename__ = "models"
    __table_args__ = (UniqueConstraint("skill_id", "version", name="uq_models_skill_version"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    skill_id: Mapped[int] = mapped_column(
        ForeignKey("skills.id", ondelete="CASCADE"), index=True, nullable=False
    )
    version: Mapped[int] = mapped_column(Integer, nullable=False)
    options: Mapped[dict[str, Any]] = mapped_column(JSON, nullable=False)
    demo_ids: Mapped[list[int]] = mapped_column(JSON, nullable=False)
    canal: Mapped[dict[str, Any]] = mapped_column(JSON, nullable=False)
    fit_seconds: Mapped[float] = mapped_column(nullable=False, default=0.0)
    n_sections: Mapped[int] = mapped_column(Integer, nullable=False)
    section_kind: Mapped[str] = mapped_column(String(16), nullable=False)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)

    skill: Mapped[Skill] = relationship(back_populates="models")


class StoredReproduction(Base):
    """One reproduction the service answered, kept for the skill's recording.

    Every replica draws a skill's recording from the database; reproductions are not
    otherwise stored, so the recording keeps them here (the latest
    ``recordings_reproductions_kept`` per skill). ``number`` counts the skill's
    reproductions from 1 and names the reproduction's entity in the recording.
    """

    __tablename__ = "reproductions"
    __table_args__ = (UniqueConstraint("skill_id", "number", name="uq_reproductions_skill_number"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    skill_id: Mapped[int] = mapped_column(
        ForeignKey("skills.id", ondelete="CASCADE"), index=True, nullable=False
    )
    number: Mapped[int] = mapped_column(Integer, nullable=False)
    model_version: Mapped[int] = mapped_column(Integer, nullable=False)
    n_points: Mapped[int] = mapped_column(Integer, nullable=False)
    dim: Mapped[int] = mapped_column(Integer, nullable=False)
    positions: Mapped[bytes] = mapped_column(LargeBinary, nullable=False)
    start: Mapped[bytes] = mapped_column(LargeBinary, nullable=False)
    times: Mapped[bytes | None] = mapped_column(LargeBinary, nullable=True)
    orientations: Mapped[bytes | None] = mapped_column(LargeBinary, nullable=True)
    inside: Mapped[bool] = mapped_column(Boolean, nullable=False)
    projected: Mapped[bool] = mapped_column(Boolean, nullable=False)
    eta: Mapped[float] = mapped_column(Float, nullable=False)
    section_index: Mapped[int] = mapped_column(Integer, nullable=False)
    #: (n_points,) float64: each position's ratio (``canal_core.Reproduction.ratios``); null
    #: for a reproduction kept before they were stored
    ratios: Mapped[bytes | None] = mapped_column(LargeBinary, nullable=True)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)


class SceneRow(Base):
    """A skill's scene: the obstacles every reproduction and live stream of it goes around.

    One row per skill; ``version`` counts its changes (the last write wins).
    """

    __tablename__ = "scenes"

    skill_id: Mapped[int] = mapped_column(
        ForeignKey("skills.id", ondelete="CASCADE"), primary_key=True
    )
    version: Mapped[int] = mapped_column(Integer, nullable=False)
    obstacles: Mapped[list[dict[str, Any]]] = mapped_column(JSON, nullable=False)
    updated_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)


class ModelLineage(Base):
    """Where a refined model version came from; a plain fit has no row.

    A table of its own rather than columns of ``models``: those would sit after the canal
    column, and SQLite walks a canal's overflow pages to read what follows it.
    """

    __tablename__ = "model_lineage"

    model_id: Mapped[int] = mapped_column(
        ForeignKey("models.id", ondelete="CASCADE"), primary_key=True
    )
    skill_id: Mapped[int] = mapped_column(
        ForeignKey("skills.id", ondelete="CASCADE"), index=True, nullable=False
    )
    #: The version this one was refined from (by a correction, an undo or a refit).
    parent_version: Mapped[int] = mapped_column(Integer, nullable=False)
    #: The plain fit the corrections were applied to.
    fit_version: Mapped[int] = mapped_column(Integer, nullable=False)
    #: The corrections applied to that fit, in order.
    correction_ids: Mapped[list[int]] = mapped_column(JSON, nullable=False)


class Correction(Base):
    """A person's correction of a skill's canal: its path (packed float64) and its kind."""

    __tablename__ = "corrections"
    # ids are never given twice (as demonstrations')
    __table_args__ = ({"sqlite_autoincrement": True},)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    skill_id: Mapped[int] = mapped_column(
        ForeignKey("skills.id", ondelete="CASCADE"), index=True, nullable=False
    )
    kind: Mapped[str] = mapped_column(String(16), nullable=False)
    label: Mapped[str] = mapped_column(String(256), nullable=False, default="")
    weight: Mapped[float] = mapped_column(Float, nullable=False, default=1.0)
    n_points: Mapped[int] = mapped_column(Integer, nullable=False)
    dim: Mapped[int] = mapped_column(Integer, nullable=False)
    samples: Mapped[bytes] = mapped_column(LargeBinary, nullable=False)
    timestamps: Mapped[bytes | None] = mapped_column(LargeBinary, nullable=True)
    orientations: Mapped[bytes | None] = mapped_column(LargeBinary, nullable=True)
    #: exclude: the path the robot was on before the push, (P, dim) packed, when given
    plan: Mapped[bytes | None] = mapped_column(LargeBinary, nullable=True)
    base_version: Mapped[int] = mapped_column(Integer, nullable=False)
    model_version: Mapped[int] = mapped_column(Integer, nullable=False)
    first_section: Mapped[int] = mapped_column(Integer, nullable=False)
    last_section: Mapped[int] = mapped_column(Integer, nullable=False)
    #: The route of a model of several routes it corrects; None: every route.
    route: Mapped[int | None] = mapped_column(Integer, nullable=True)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
