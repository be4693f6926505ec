"""Initial schema: skills, demonstrations (packed float64 arrays), model versions.

Revision ID: 0001
Revises:
Create Date: 2025-11-25
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0001"
down_revision = None
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "skills",
        sa.Column("id", sa.Integer(), primary_key=True),
        sa.Column("name", sa.String(64), nullable=False, unique=True),
        sa.Column("description", sa.Text(), nullable=False),
        sa.Column("dim", sa.Integer(), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=True),
    )
    op.create_table(
        "demonstrations",
        sa.Column("id", sa.Integer(), primary_key=True),
        sa.Column(
            "skill_id", sa.Integer(), sa.ForeignKey("skills.id", ondelete="CASCADE"), nullable=False
        ),
        sa.Column("label", sa.String(256), nullable=True),
        sa.Column("n_points", sa.Integer(), nullable=False),
        sa.Column("dim", sa.Integer(), nullable=False),
        sa.Column("positions", sa.LargeBinary(), nullable=False),
        sa.Column("timestamps", sa.LargeBinary(), nullable=True),
        sa.Column("orientations", sa.LargeBinary(), nullable=True),
        sa.Column("checksum", sa.String(64), nullable=False),
        sa.Column("source", sa.String(16), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=True),
    )
    op.create_index("ix_demonstrations_skill_id", "demonstrations", ["skill_id"])
    op.create_table(
        "models",
        sa.Column("id", sa.Integer(), primary_key=True),
        sa.Column(
            "skill_id", sa.Integer(), sa.ForeignKey("skills.id", ondelete="CASCADE"), nullable=False
        ),
        sa.Column("version", sa.Integer(), nullable=False),
        sa.Column("options", sa.JSON(), nullable=False),
        sa.Column("demo_ids", sa.JSON(), nullable=False),
        sa.Column("canal", sa.JSON(), nullable=False),
        sa.Column("fit_seconds", sa.Float(), nullable=False),
        sa.Column("n_sections", sa.Integer(), nullable=False),
        sa.Column("section_kind", sa.String(16), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=True),
        sa.UniqueConstraint("skill_id", "version", name="uq_models_skill_version"),
    )
    op.create_index("ix_models_skill_id", "models", ["skill_id"])


def downgrade() -> None:
    op.drop_index("ix_models_skill_id", table_name="models")
    op.drop_table("models")
    op.drop_index("ix_demonstrations_skill_id", table_name="demonstrations")
    op.drop_table("demonstrations")
    op.drop_table("skills")
