"""Reproductions kept for the recordings: each position's ratio, for the viewer's ratio plot.

Revision ID: 0006_reproduction_ratios
Revises: 0005_correction_route
Create Date: 2026-12-06
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0006_reproduction_ratios"
down_revision = "0005_correction_route"
branch_labels = None
depends_on = None


def upgrade() -> None:
    # Null: a reproduction kept before; its recording draws no ratio plot.
    with op.batch_alter_table("reproductions") as batch:
        batch.add_column(sa.Column("ratios", sa.LargeBinary(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("reproductions") as batch:
        batch.drop_column("ratios")
