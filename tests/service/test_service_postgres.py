"""PostgreSQL-specific behaviour of a multi-instance deployment (skipped without a server)."""

from __future__ import annotations

import threading

import pytest
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from canal_service.app import create_app
from canal_service.core.config import Settings
from canal_service.storage import Database
from canal_service.storage.db import alembic_config
from canal_service.storage.models import Skill
from fastapi.testclient import TestClient
from service_helpers import PostgresServer, demo_positions
from sqlalchemy import select

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
    db = Database(postgres_server.new_database())
    db.migrate()
    with db.write() as session:
        session.add(Skill(name="kept", description="survives a second migration", dim=3))
    db.migrate()  # a replica starting against an up-to-date database: no change, no error
    db.ping()
    head = ScriptDirectory.from_config(alembic_config(db.url)).get_current_head()
    with db.read_engine.connect() as connection:
        assert MigrationContext.configure(connection).get_current_revision() == head
    with db.read() as session:
        kept = session.scalars(select(Skill).where(Skill.name == "kept")).one()
        assert kept.description == "survives a second migration" and kept.dim == 3
    db.dispose()
