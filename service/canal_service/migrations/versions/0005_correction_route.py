"""Corrections: the route of a model of several routes that a correction applies to.

Revision ID: 0005_correction_route
Revises: 0004_corrections
Create Date: 2026-12-03
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0005_correction_route"
down_revision = "0004_corrections"
branch_labels = None
depends_on = None


def upgrade() -> None:
    # Null: every route (and every correction stored before routes, on one-canal models).
    with op.batch_alter_table("corrections") as batch:
        batch.add_column(sa.Column("route", sa.Integer(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("corrections") as batch:
        batch.drop_column("route")
