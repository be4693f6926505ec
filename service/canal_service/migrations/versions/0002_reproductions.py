"""Reproductions kept for the recordings, so every replica's recording holds them.

Revision ID: 0002_reproductions
Revises: 0001
Create Date: 2026-12-02
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0002_reproductions"
down_revision = "0001"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "reproductions",
        sa.Column("id", sa.Integer(), primary_key=True),
        sa.Column(
            "skill_id", sa.Integer(), sa.ForeignKey("skills.id", ondelete="CASCADE"), nullable=False
        ),
        sa.Column("number", sa.Integer(), nullable=False),
        sa.Column("model_version", sa.Integer(), nullable=False),
        sa.Column("n_points", sa.Integer(), nullable=False),
        sa.Column("dim", sa.Integer(), nullable=False),
        sa.Column("positions", sa.LargeBinary(), nullable=False),
        sa.Column("start", sa.LargeBinary(), nullable=False),
        sa.Column("times", sa.LargeBinary(), nullable=True),
        sa.Column("orientations", sa.LargeBinary(), nullable=True),
        sa.Column("inside", sa.Boolean(), nullable=False),
        sa.Column("projected", sa.Boolean(), nullable=False),
        sa.Column("eta", sa.Float(), nullable=False),
        sa.Column("section_index", sa.Integer(), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=True),
        sa.UniqueConstraint("skill_id", "number", name="uq_reproductions_skill_number"),
    )
    op.create_index("ix_reproductions_skill_id", "reproductions", ["skill_id"])


def downgrade() -> None:
    op.drop_index("ix_reproductions_skill_id", table_name="reproductions")
    op.drop_table("reproductions")
