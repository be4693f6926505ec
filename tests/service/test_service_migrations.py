"""The schema's history is one line: every revision has one parent and there is one head, so
every replica and every upgrade path reaches the same schema."""

from __future__ import annotations

from alembic.script import ScriptDirectory
from canal_service.storage.db import alembic_config


def test_migrations_form_one_linear_history():
    script = ScriptDirectory.from_config(alembic_config("sqlite://"))
    heads = script.get_heads()
    assert len(heads) == 1, f"expected one Alembic head, got {sorted(heads)}"
    revisions = list(script.walk_revisions())
    assert [r.down_revision for r in revisions if r.down_revision is None] == [None]
    for rev in revisions:
        assert not isinstance(rev.down_revision, tuple | list), \
            f"{rev.revision} merges {rev.down_revision}: the history is kept linear"
    # every revision is reached walking down from the head
    assert len(revisions) == len(list(script.iterate_revisions(heads[0], "base")))
