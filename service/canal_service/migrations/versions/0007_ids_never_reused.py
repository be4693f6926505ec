"""Demonstration and correction ids are never given twice on SQLite (AUTOINCREMENT).

Without it SQLite gives a new row the id of a deleted last row: a model's list of its
demonstrations, and a client holding an id, would name another row. PostgreSQL's sequences
never reuse an id, so its tables are left as they are.

Revision ID: 0007_ids_never_reused
Revises: 0006_reproduction_ratios
Create Date: 2026-12-06
"""

from __future__ import annotations

from alembic import op

revision = "0007_ids_never_reused"
down_revision = "0006_reproduction_ratios"
branch_labels = None
depends_on = None

_TABLES = ("demonstrations", "corrections")


def upgrade() -> None:
    if op.get_bind().dialect.name != "sqlite":
        return
    # The table is copied into one declared AUTOINCREMENT (SQLite cannot alter that in place);
    # no foreign key points at these tables, so dropping the old copy deletes nothing else.
    for table in _TABLES:
        with op.batch_alter_table(table, recreate="always",
                                  table_kwargs={"sqlite_autoincrement": True}):
            pass


def downgrade() -> None:
    if op.get_bind().dialect.name != "sqlite":
        return
    for table in _TABLES:
        with op.batch_alter_table(table, recreate="always",
                                  table_kwargs={"sqlite_autoincrement": False}):
            pass
