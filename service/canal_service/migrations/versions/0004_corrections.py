"""Corrections: a table of people's corrections, and the lineage of refined model versions.

Revision ID: 0004_corrections
Revises: 0003_scenes
Create Date: 2026-12-02
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0004_corrections"
down_revision = "0003_scenes"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "corrections",
        sa.Column("id", sa.Integer(), primary_key=True),
        sa.Column(
            "skill_id", sa.Integer(), sa.ForeignKey("skills.id", ondelete="CASCADE"), nullable=False
        ),
        sa.Column("kind", sa.String(16), nullable=False),
        sa.Column("label", sa.String(256), nullable=False),
        sa.Column("weight", sa.Float(), nullable=False),
        sa.Column("n_points", sa.Integer(), nullable=False),
        sa.Column("dim", sa.Integer(), nullable=False),
        sa.Column("samples", sa.LargeBinary(), nullable=False),
        sa.Column("timestamps", sa.LargeBinary(), nullable=True),
        sa.Column("orientations", sa.LargeBinary(), nullable=True),
        sa.Column("plan", sa.LargeBinary(), nullable=True),
        sa.Column("base_version", sa.Integer(), nullable=False),
        sa.Column("model_version", sa.Integer(), nullable=False),
        sa.Column("first_section", sa.Integer(), nullable=False),
        sa.Column("last_section", sa.Integer(), nullable=False),
        sa.Column("undone", sa.Boolean(), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=True),
    )
    op.create_index("ix_corrections_skill_id", "corrections", ["skill_id"])
    op.create_table(
        "model_lineage",
        sa.Column(
            "model_id", sa.Integer(), sa.ForeignKey("models.id", ondelete="CASCADE"), primary_key=True
        ),
        sa.Column(
            "skill_id", sa.Integer(), sa.ForeignKey("skills.id", ondelete="CASCADE"), nullable=False
        ),
        sa.Column("parent_version", sa.Integer(), nullable=False),
        sa.Column("fit_version", sa.Integer(), nullable=False),
        sa.Column("correction_ids", sa.JSON(), nullable=False),
    )
    op.create_index("ix_model_lineage_skill_id", "model_lineage", ["skill_id"])


def downgrade() -> None:
    op.drop_index("ix_model_lineage_skill_id", table_name="model_lineage")
    op.drop_table("model_lineage")
    op.drop_index("ix_corrections_skill_id", table_name="corrections")
    op.drop_table("corrections")
