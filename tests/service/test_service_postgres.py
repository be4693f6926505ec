"""PostgreSQL-specific behaviour of a multi-instance deployment (skipped without a server)."""

from __future__ import annotations

import threading
import time

import pytest
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from canal_service.app import create_app
from canal_service.core.config import Settings
from canal_service.errors import SkillExists
from canal_service.storage import Database
from canal_service.storage import repository as repo
from canal_service.storage.db import alembic_config
from fastapi.testclient import TestClient
from service_helpers import PostgresServer, demo_positions
from sqlalchemy import inspect, text

pytestmark = pytest.mark.postgres


def test_two_replicas_share_one_database(postgres_server: PostgresServer, tmp_path) -> None:
    url = postgres_server.new_database()
    a = create_app(Settings(data_dir=tmp_path / "a", database_url=url, recordings_enabled=False, zenoh_enabled=False))
    b = create_app(Settings(data_dir=tmp_path / "b", database_url=url, recordings_enabled=False, zenoh_enabled=False))
    with TestClient(a) as ca, TestClient(b) as cb:
        assert ca.post("/skills", json={"name": "pour", "dim": 3}).status_code == 201
        assert cb.post("/skills", json={"name": "pour", "dim": 3}).status_code == 409
        for j in range(3):
            client = ca if j % 2 else cb
            assert client.post("/skills/pour/demonstrations",
                               json={"positions": demo_positions(j).tolist()}).status_code == 201
        # both replicas fit at once: versions stay unique and gap-free
        results: list[int] = []

        def fit(client: TestClient) -> None:
            for _ in range(3):
                r = client.post("/skills/pour/fit", json={"n_samples": 20})
                assert r.status_code == 201, r.text
                results.append(r.json()["version"])

        threads = [threading.Thread(target=fit, args=(c,)) for c in (ca, cb)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert sorted(results) == [1, 2, 3, 4, 5, 6]
        # a model fitted on one replica reproduces on the other
        rep = cb.post("/skills/pour/reproductions", json={"start": [0, 0, 0], "model": 1})
        assert rep.status_code == 200
        assert ca.get("/skills/pour").json()["n_models"] == 6


def test_migrations_are_idempotent(postgres_server: PostgresServer) -> None:
    """A second migrate (every replica runs one at start) changes neither schema nor data."""
    db = Database(postgres_server.new_database())
    db.migrate()
    head = ScriptDirectory.from_config(alembic_config(db.url)).get_current_head()
    with db.write() as s:
        repo.create_skill(s, "kept", "", 3)
    with db.read_engine.connect() as connection:
        tables = set(inspect(connection).get_table_names())
        revision = MigrationContext.configure(connection).get_current_revision()
    assert {"skills", "demonstrations", "models"} <= tables and revision == head
    db.migrate()
    with db.read_engine.connect() as connection:
        assert set(inspect(connection).get_table_names()) == tables
        assert MigrationContext.configure(connection).get_current_revision() == head
        assert connection.execute(text("SELECT count(*) FROM alembic_version")).scalar() == 1
    with db.read() as s:
        assert repo.get_skill(s, "kept").dim == 3
    db.dispose()


def test_two_replicas_creating_one_name_in_two_letter_cases_make_one_skill(
        postgres_server: PostgresServer) -> None:
    # The letter-case check is a query: two replicas creating "Pour" and "pour" at once both
    # passed it before either committed, and two skills shared one recording folder.
    url = postgres_server.new_database()
    first, second = Database(url), Database(url)
    first.migrate()
    created = threading.Event()
    entered = threading.Event()
    outcome: dict[str, str] = {}

    def create_first() -> None:
        with first.write() as s:
            repo.create_skill(s, "Pour", "", 3)
            created.set()
            entered.wait(10)
            time.sleep(0.5)  # the second replica is inside its check by now
        outcome["Pour"] = "created"

    def create_second() -> None:
        created.wait(10)
        entered.set()
        try:
            with second.write() as s:
                repo.create_skill(s, "pour", "", 3)
            outcome["pour"] = "created"
        except SkillExists as exc:
            outcome["pour"] = exc.message

    threads = [threading.Thread(target=create_first), threading.Thread(target=create_second)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert outcome["Pour"] == "created"
    assert "differs from it by more than letter case" in outcome["pour"], outcome
    with first.read() as s:
        assert [k.name for k in repo.list_skills(s, 0, 10)[0]] == ["Pour"]
    first.dispose()
    second.dispose()


@pytest.mark.parametrize("encoding", ["LATIN1", "SQL_ASCII"])
def test_a_database_not_in_utf8_is_refused_at_start(postgres_server: PostgresServer,
                                                    encoding: str) -> None:
    # A LATIN1 database started, then answered 500 to a description holding an emoji; a
    # SQL_ASCII one failed at start with "cannot use a string pattern on a bytes-like object".
    url = postgres_server.new_database(
        f"ENCODING '{encoding}' LC_COLLATE 'C' LC_CTYPE 'C' TEMPLATE template0")
    db = Database(url)
    try:
        with pytest.raises(RuntimeError, match=f"expected a database in UTF8 encoding, got {encoding}"):
            db.migrate()
    finally:
        db.dispose()
