"""Requests racing on one skill's rows answer as they would one after the other, on SQLite and
on PostgreSQL (where transactions run side by side)."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import httpx
import pytest
from canal_service.app import create_app
from canal_service.core.config import Settings
from canal_service.errors import Conflict
from canal_service.storage import Database
from canal_service.storage import repository as repo
from canal_testing import LiveServer

BACKENDS = ["sqlite", pytest.param("postgres", marks=pytest.mark.postgres)]


@pytest.fixture(params=BACKENDS)
def database_url(request: pytest.FixtureRequest, tmp_path: Path) -> str:
    if request.param == "postgres":
        return str(request.getfixturevalue("postgres_server").new_database())
    return f"sqlite:///{tmp_path / 'canal.sqlite3'}"


@pytest.fixture
def base(database_url: str, tmp_path: Path) -> Iterator[str]:
    app = create_app(Settings(data_dir=tmp_path / "data", database_url=database_url,
                              recordings_enabled=False, zenoh_enabled=False))
    with LiveServer(app) as server:
        yield server.url


def at_once(base: str, calls: list[Callable[[httpx.Client], httpx.Response]]) -> list[int]:
    """The status of each call, all sent together (one client each)."""
    statuses = [0] * len(calls)
    barrier = threading.Barrier(len(calls))

    def run(i: int) -> None:
        with httpx.Client(base_url=base, timeout=60) as http:
            barrier.wait()
            statuses[i] = calls[i](http).status_code

    threads = [threading.Thread(target=run, args=(i,)) for i in range(len(calls))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return statuses


def test_a_skills_first_scene_set_at_once_is_every_put_in_turn(base: str) -> None:
    # On PostgreSQL, PUTs racing to store a skill's first scene answered 409 (the scene row's
    # primary key, inserted twice): "the last write wins" held only once the row existed.
    scene = {"obstacles": [{"kind": "sphere", "center": [5, 5, 5], "radius": 0.1}]}
    for k in range(4):
        with httpx.Client(base_url=base) as http:
            assert http.post("/skills", json={"name": f"s{k}", "dim": 3}).status_code == 201
        statuses = at_once(base, [lambda h, k=k: h.put(f"/skills/s{k}/scene", json=scene)] * 3
                           + [lambda h, k=k: h.delete(f"/skills/s{k}/scene")])
        assert sorted(statuses) == [200, 200, 200, 204], statuses
        with httpx.Client(base_url=base) as http:
            assert http.get(f"/skills/s{k}/scene").json()["version"] == 4


def test_one_skill_deleted_at_once_is_deleted_once(base: str) -> None:
    # On PostgreSQL every one of three DELETEs answered 204 (each read the skill before the
    # first committed), and each ran a delete's side effects again under the name.
    for k in range(4):
        with httpx.Client(base_url=base) as http:
            assert http.post("/skills", json={"name": f"d{k}", "dim": 3}).status_code == 201
        statuses = at_once(base, [lambda h, k=k: h.delete(f"/skills/d{k}")] * 3)
        assert sorted(statuses) == [204, 404, 404], statuses


def test_an_upload_that_missed_a_skill_created_again_is_not_blamed_on_its_rows(
        database_url: str) -> None:
    # An upload whose skill was deleted and created again (same dimension) between its
    # insert and the look-up of why nothing was inserted was told "expected 3 values per
    # row ..., got 3": a client then takes its data for wrong and does not retry.
    db = Database(database_url)
    db.migrate()
    try:
        with db.write() as s:
            repo.create_skill(s, "pour", "", 3)
        with db.read() as s:
            why = repo._refused_insert(s, "pour", 3)  # what the insert's miss is put down to
            wrong_dim = repo._refused_insert(s, "pour", 2)
    finally:
        db.dispose()
    assert why.field == "name" and "created again" in why.message, why
    assert isinstance(why, Conflict), why  # 409: sent again, it is stored in the new skill
    assert wrong_dim.field == "positions[0]", wrong_dim


@pytest.mark.postgres
def test_an_upload_racing_its_skills_delete_is_told_the_skill_is_gone(
        postgres_server: object) -> None:
    # On PostgreSQL the insert read the skill before the delete committed, then failed its
    # foreign key: a 409 "clashed with a concurrent change; retry it", where a retry is 404.
    import time

    import numpy as np
    from canal_service.errors import SkillNotFound
    from sqlalchemy import text

    db = Database(postgres_server.new_database())  # type: ignore[attr-defined]
    db.migrate()
    try:
        with db.write() as s:
            skill_id = repo.create_skill(s, "pour", "", 3).id
        outcome: list[object] = []

        def upload() -> None:
            try:
                outcome.append(repo.insert_demonstration(
                    db, "pour", np.zeros((10, 3)), None, None, None, "json"))
            except Exception as exc:  # what it raised is the answer
                outcome.append(exc)

        with db.write_engine.connect() as other:
            other.execute(text("DELETE FROM skills WHERE id = :id"), {"id": skill_id})
            thread = threading.Thread(target=upload)
            thread.start()
            time.sleep(0.5)  # the insert waits on the deleted row's lock
            other.commit()
        thread.join()
    finally:
        db.dispose()
    assert isinstance(outcome[0], SkillNotFound), outcome
