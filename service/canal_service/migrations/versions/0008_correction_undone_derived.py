"""Corrections: whether one is undone is read off the latest model version, not stored.

A correction of an older version can bring back a correction undone since; a stored flag
then said the opposite of what the latest version holds.

Revision ID: 0008_correction_undone_derived
Revises: 0007_ids_never_reused
Create Date: 2026-12-07
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0008_correction_undone_derived"
down_revision = "0007_ids_never_reused"
branch_labels = None
depends_on = None


# SQLite copies the table to drop a column: the copy keeps ids never given twice (0007).
_KEEP = {"sqlite_autoincrement": True}


def upgrade() -> None:
    with op.batch_alter_table("corrections", table_kwargs=_KEEP) as batch:
        batch.drop_column("undone")


def downgrade() -> None:
    # False for every row: the flag is derived again from the versions when read.
    with op.batch_alter_table("corrections", table_kwargs=_KEEP) as batch:
        batch.add_column(sa.Column("undone", sa.Boolean(), nullable=False,
                                   server_default=sa.false()))
