"""Fits, corrections and undos that run at once, on one replica or on two sharing a database:
every new model version is built on the version that is the latest when it is stored, so
nothing one of them made drops out of the latest model.

A request is held at a chosen query (a SQLAlchemy event on the replica's read engine, nothing
of the service replaced) while the other request runs to its end, then let go: the order is
the same on every run, on a machine of any speed.
"""

from __future__ import annotations

import itertools
import re
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from canal_service.app import create_app
from canal_service.core.config import Settings
from canal_testing import LiveServer
from service_helpers import demo_positions
from sqlalchemy import event
from sqlalchemy.engine import Engine

import canal_core

WAIT_S = 120  # how long a held request waits for the test at most: a hang, not a measure


class HoldAt:
    """Holds the first SELECT from ``table`` a replica runs once armed, until let go."""

    def __init__(self, engine: Engine, table: str) -> None:
        self.engine = engine
        self.pattern = re.compile(rf"^\s*SELECT\b.*\bFROM {table}\b", re.S | re.I)
        self.reached = threading.Event()
        self.go = threading.Event()
        self._armed = False
        self._lock = threading.Lock()
        event.listen(engine, "before_cursor_execute", self._check)

    def arm(self) -> None:
        with self._lock:
            self._armed = True

    def _check(self, _conn: Any, _cursor: Any, statement: str, *_args: Any) -> None:
        with self._lock:
            hit = self._armed and self.pattern.search(statement) is not None
            if hit:
                self._armed = False
        if hit:
            self.reached.set()
            self.go.wait(WAIT_S)

    def close(self) -> None:
        self.go.set()
        event.remove(self.engine, "before_cursor_execute", self._check)


def _settings(tmp_path: Path, name: str, url: str) -> Settings:
    return Settings(data_dir=tmp_path / name, database_url=url, recordings_enabled=False,
                    zenoh_enabled=False)


@pytest.fixture(params=["sqlite", pytest.param("postgres", marks=pytest.mark.postgres)])
def replicas(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[list[Any]]:
    """Two replicas (apps, each its own service and lock) on one database, served by uvicorn."""
    if request.param == "postgres":
        url = request.getfixturevalue("postgres_server").new_database()
    else:
        url = f"sqlite:///{tmp_path / 'shared.sqlite3'}"
    apps = [create_app(_settings(tmp_path, f"r{i}", url)) for i in range(2)]
    with LiveServer(apps[0]) as a, LiveServer(apps[1]) as b:
        yield [(apps[0], a), (apps[1], b)]


def _post(base: str, path: str, body: dict[str, Any], out: dict[str, httpx.Response],
          key: str) -> threading.Thread:
    def send() -> None:
        with httpx.Client(base_url=base, timeout=WAIT_S) as http:
            out[key] = http.post(path, json=body)

    thread = threading.Thread(target=send)
    thread.start()
    return thread


def _skill_with_v1(http: httpx.Client, n_samples: int = 200) -> canal_core.Canal:
    """'pour' with four demonstrations and a fit (version 1), then four more demonstrations."""
    assert http.post("/skills", json={"name": "pour", "dim": 3}).status_code == 201
    for j in range(4):
        r = http.post("/skills/pour/demonstrations", json={"positions": demo_positions(j).tolist()})
        assert r.status_code == 201, r.text
    r = http.post("/skills/pour/fit", json={"n_samples": n_samples})
    assert r.status_code == 201 and r.json()["version"] == 1, r.text
    for j in range(4, 8):
        r = http.post("/skills/pour/demonstrations", json={"positions": demo_positions(j).tolist()})
        assert r.status_code == 201, r.text
    got = http.get("/skills/pour/models/1", params={"serialized": True})
    return canal_core.Canal.from_dict(got.json()["serialized"])


def _include(canal: canal_core.Canal, first: float = 0.35, last: float = 0.65,
             side: float = 1.3) -> list[list[float]]:
    """A path a little outside the canal's +normal wall over part of it."""
    n = canal.n_sections
    idx = np.arange(int(first * n), int(last * n) + 1)
    return (canal.directrix[idx] + side * canal.radii[idx, None] * canal.normals[idx]).tolist()


def _latest(http: httpx.Client) -> dict[str, Any]:
    r = http.get("/skills/pour/models/latest")
    assert r.status_code == 200, r.text
    body: dict[str, Any] = r.json()
    return body


def test_a_correction_held_while_a_fit_lands_on_another_replica_is_applied_to_that_fit(
    replicas: list[Any],
) -> None:
    """The correction read version 1, then a fit of eight demonstrations landed: stored on
    version 1 it would be the latest and hide the fit (and its new demonstrations)."""
    (app_a, a), (_app_b, b) = replicas
    with httpx.Client(base_url=b.url, timeout=WAIT_S) as http:
        v1 = _skill_with_v1(http)
    hold = HoldAt(app_a.state.service.db.read_engine, "model_lineage")
    out: dict[str, httpx.Response] = {}
    try:
        hold.arm()
        correcting = _post(a.url, "/skills/pour/corrections",
                           {"kind": "include", "samples": _include(v1)}, out, "correction")
        assert hold.reached.wait(WAIT_S), "the correction never read the latest version"
        with httpx.Client(base_url=b.url, timeout=WAIT_S) as http:
            fit = http.post("/skills/pour/fit", json={"n_samples": 100})
        assert fit.status_code == 201, fit.text
        assert fit.json()["version"] == 2 and len(fit.json()["demo_ids"]) == 8
        hold.go.set()
        correcting.join(WAIT_S)
    finally:
        hold.close()
    made = out["correction"]
    assert made.status_code == 201, made.text
    body = made.json()
    assert body["version"] == 3 and body["parent_version"] == 2, body
    assert body["correction"]["base_version"] == 2
    with httpx.Client(base_url=b.url, timeout=WAIT_S) as http:
        latest = _latest(http)
    assert latest["version"] == 3 and latest["parent_version"] == 2
    assert len(latest["demo_ids"]) == 8 and latest["n_sections"] == 100
    assert latest["corrections"] == [body["correction"]["id"]]


@pytest.mark.parametrize("where", ["same replica", "other replica"])
def test_a_correction_that_lands_while_a_refit_runs_is_kept_by_the_refit(
    replicas: list[Any], where: str,
) -> None:
    """The person corrects version 1 while a refit of eight demonstrations runs: the refit
    lands as a plain fit and a version with that correction re-applied, the latest."""
    (app_a, a), (_app_b, b) = replicas
    other = a if where == "same replica" else b
    with httpx.Client(base_url=a.url, timeout=WAIT_S) as http:
        v1 = _skill_with_v1(http)
    hold = HoldAt(app_a.state.service.db.read_engine, "demonstrations")
    out: dict[str, httpx.Response] = {}
    try:
        hold.arm()
        fitting = _post(a.url, "/skills/pour/fit", {"n_samples": 100}, out, "fit")
        assert hold.reached.wait(WAIT_S), "the fit never read its demonstrations"
        with httpx.Client(base_url=other.url, timeout=WAIT_S) as http:
            made = http.post("/skills/pour/corrections",
                             json={"kind": "include", "samples": _include(v1)})
        assert made.status_code == 201, made.text
        assert made.json()["version"] == 2 and made.json()["parent_version"] == 1
        hold.go.set()
        fitting.join(WAIT_S)
    finally:
        hold.close()
    correction_id = made.json()["correction"]["id"]
    fit = out["fit"]
    assert fit.status_code == 201, fit.text
    assert fit.json()["version"] == 4 and fit.json()["parent_version"] == 3, fit.text
    assert fit.json()["corrections"] == [correction_id]
    with httpx.Client(base_url=other.url, timeout=WAIT_S) as http:
        latest = _latest(http)
        plain = http.get("/skills/pour/models/3").json()
    assert latest["version"] == 4 and len(latest["demo_ids"]) == 8
    assert latest["corrections"] == [correction_id] and latest["n_sections"] == 100
    assert plain["parent_version"] is None and plain["corrections"] == []


def test_an_undo_held_while_a_correction_lands_on_another_replica_keeps_that_correction(
    replicas: list[Any],
) -> None:
    """The undo read the latest version (two corrections), then a third landed: the undo's
    version is built on the third's, without the undone one and with the other two."""
    (app_a, a), (_app_b, b) = replicas
    with httpx.Client(base_url=b.url, timeout=WAIT_S) as http:
        v1 = _skill_with_v1(http)
        ids = []
        for first, last in ((0.1, 0.3), (0.4, 0.6)):
            r = http.post("/skills/pour/corrections",
                          json={"kind": "include", "samples": _include(v1, first, last)})
            assert r.status_code == 201, r.text
            ids.append(r.json()["correction"]["id"])
    hold = HoldAt(app_a.state.service.db.read_engine, "model_lineage")
    out: dict[str, httpx.Response] = {}
    try:
        hold.arm()

        def undo() -> None:
            with httpx.Client(base_url=a.url, timeout=WAIT_S) as http:
                out["undo"] = http.delete(f"/skills/pour/corrections/{ids[0]}")

        undoing = threading.Thread(target=undo)
        undoing.start()
        assert hold.reached.wait(WAIT_S), "the undo never read the latest version"
        with httpx.Client(base_url=b.url, timeout=WAIT_S) as http:
            third = http.post("/skills/pour/corrections",
                              json={"kind": "include", "samples": _include(v1, 0.7, 0.9)})
        assert third.status_code == 201 and third.json()["version"] == 4, third.text
        hold.go.set()
        undoing.join(WAIT_S)
    finally:
        hold.close()
    undone = out["undo"]
    assert undone.status_code == 200, undone.text
    third_id = third.json()["correction"]["id"]
    assert undone.json()["version"] == 5 and undone.json()["parent_version"] == 4
    assert undone.json()["corrections"] == [ids[1], third_id]
    with httpx.Client(base_url=b.url, timeout=WAIT_S) as http:
        assert _latest(http)["corrections"] == [ids[1], third_id]


def test_eight_corrections_at_once_each_build_on_the_one_before(tmp_path: Path) -> None:
    """Eight people correct the latest version at the same moment: eight versions in a row,
    each the one before with one more correction, the latest holding all eight."""
    app = create_app(_settings(tmp_path, "data", f"sqlite:///{tmp_path / 'canal.sqlite3'}"))
    with LiveServer(app) as server:
        with httpx.Client(base_url=server.url, timeout=WAIT_S) as http:
            v1 = _skill_with_v1(http, n_samples=1000)
        barrier = threading.Barrier(8)
        answers: list[httpx.Response] = []
        lock = threading.Lock()

        def correct(k: int) -> None:
            samples = _include(v1, 0.05 + 0.11 * k, 0.12 + 0.11 * k)
            with httpx.Client(base_url=server.url, timeout=WAIT_S) as http:
                barrier.wait()
                r = http.post("/skills/pour/corrections",
                              json={"kind": "include", "samples": samples})
            with lock:
                answers.append(r)

        threads = [threading.Thread(target=correct, args=(k,)) for k in range(8)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(WAIT_S)
        with httpx.Client(base_url=server.url, timeout=WAIT_S) as http:
            latest = _latest(http)
    assert len(answers) == 8
    for r in answers:
        assert r.status_code == 201, r.text
    made = sorted((r.json() for r in answers), key=lambda m: m["version"])
    assert [m["version"] for m in made] == list(range(2, 10))
    assert [m["parent_version"] for m in made] == list(range(1, 9))
    for before, after in itertools.pairwise(made):
        assert after["corrections"] == [*before["corrections"], after["correction"]["id"]]
    assert latest["version"] == 9
    assert latest["corrections"] == [m["correction"]["id"] for m in made]


def test_a_fit_whose_skill_is_deleted_and_created_again_meanwhile_lands_in_neither(
    replicas: list[Any],
) -> None:
    """The fit computed its canal, then (before storing it) its skill was deleted on the
    other replica and a new skill made under the same name: the new skill is another skill,
    and gets no model made of the deleted one's demonstrations."""
    (app_a, a), (_app_b, b) = replicas
    with httpx.Client(base_url=a.url, timeout=WAIT_S) as http:
        _skill_with_v1(http)
    hold = HoldAt(app_a.state.service.db.read_engine, "models")
    out: dict[str, httpx.Response] = {}
    try:
        hold.arm()
        fitting = _post(a.url, "/skills/pour/fit", {"n_samples": 100}, out, "fit")
        assert hold.reached.wait(WAIT_S), "the fit never read the latest version before storing"
        with httpx.Client(base_url=b.url, timeout=WAIT_S) as http:
            assert http.delete("/skills/pour").status_code == 204
            assert http.post("/skills", json={"name": "pour", "dim": 3}).status_code == 201
        hold.go.set()
        fitting.join(WAIT_S)
    finally:
        hold.close()
    fit = out["fit"]
    assert fit.status_code == 404, fit.text
    assert "deleted" in fit.text, fit.text
    with httpx.Client(base_url=b.url, timeout=WAIT_S) as http:
        assert http.get("/skills/pour/models").json()["items"] == []


def test_a_correction_of_a_named_version_whose_skill_is_created_again_meanwhile_is_not_stored(
    replicas: list[Any],
) -> None:
    """A correction of version 1 by name read it, then its skill was deleted and a new one
    made and fitted under the same name on the other replica: the correction belongs to
    neither, and the new skill's latest stays its own fit."""
    (app_a, a), (_app_b, b) = replicas
    with httpx.Client(base_url=a.url, timeout=WAIT_S) as http:
        v1 = _skill_with_v1(http)
    hold = HoldAt(app_a.state.service.db.read_engine, "model_lineage")
    out: dict[str, httpx.Response] = {}
    try:
        hold.arm()
        correcting = _post(a.url, "/skills/pour/corrections",
                           {"kind": "include", "samples": _include(v1), "model": 1}, out, "correction")
        assert hold.reached.wait(WAIT_S), "the correction never read its version"
        with httpx.Client(base_url=b.url, timeout=WAIT_S) as http:
            assert http.delete("/skills/pour").status_code == 204
            _skill_with_v1(http)
        hold.go.set()
        correcting.join(WAIT_S)
    finally:
        hold.close()
    made = out["correction"]
    assert made.status_code == 404 and "deleted" in made.text, made.text
    with httpx.Client(base_url=b.url, timeout=WAIT_S) as http:
        latest = _latest(http)
    assert latest["version"] == 1 and latest["corrections"] == []
