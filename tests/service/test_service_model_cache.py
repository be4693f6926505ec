"""The decoded-canal cache never answers with a model the database no longer holds.

Two replicas (two apps, each behind its own uvicorn) share one database, SQLite file or
PostgreSQL: replica A reproduces (and so caches decoded canals) while replica B fits new
versions, deletes the skill and re-creates it. A must always answer with what the database
holds now: "latest" is never cached, and a re-created skill's version 1 is not the old one's
(on SQLite the new model row even gets the deleted row's id).
"""

from __future__ import annotations

from collections.abc import Iterator

import httpx
import numpy as np
import pytest
from canal_service.app import create_app
from canal_service.core.config import Settings
from service_helpers import LiveServer, demo_positions

WAIT_S = 120.0  # a loaded 2-core machine; reached only when something is broken
LIFT = 5.0  # the "high" demos: the same arcs, 5 up in z; their canal ends near z = 5.1


def low(j: int) -> np.ndarray:
    return demo_positions(j)


def high(j: int) -> np.ndarray:
    return demo_positions(j) + np.array([0.0, 0.0, LIFT])


@pytest.fixture
def replicas(any_db_settings: Settings) -> Iterator[tuple[httpx.Client, httpx.Client]]:
    with LiveServer(create_app(any_db_settings)) as a, \
            LiveServer(create_app(any_db_settings)) as b, \
            httpx.Client(base_url=a.url, timeout=WAIT_S) as http_a, \
            httpx.Client(base_url=b.url, timeout=WAIT_S) as http_b:
        yield http_a, http_b


def upload(http: httpx.Client, demos: list[np.ndarray]) -> list[int]:
    ids = []
    for positions in demos:
        r = http.post("/skills/pour/demonstrations", json={"positions": positions.tolist()})
        assert r.status_code == 201, r.text
        ids.append(r.json()["id"])
    return ids


def fit(http: httpx.Client, demo_ids: list[int]) -> int:
    r = http.post("/skills/pour/fit", json={"n_samples": 50, "demo_ids": demo_ids})
    assert r.status_code == 201, r.text
    version: int = r.json()["version"]
    return version


def reproduce(http: httpx.Client, model: str | int = "latest") -> tuple[int, float]:
    """(model version, z of the reproduction's end) of a reproduction from the origin."""
    r = http.post("/skills/pour/reproductions", json={"start": [0.0, 0.0, 0.0], "model": model})
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "application/json"
    out = r.json()
    return out["model_version"], out["positions"][-1][2]


def test_a_replica_never_reproduces_a_stale_or_ghost_model(
        replicas: tuple[httpx.Client, httpx.Client]) -> None:
    a, b = replicas
    assert a.post("/skills", json={"name": "pour", "dim": 3}).status_code == 201
    low_ids = upload(a, [low(j) for j in range(3)])
    assert fit(a, low_ids) == 1
    version, z_end = reproduce(a)  # A decodes version 1 and keeps it
    assert version == 1 and z_end == pytest.approx(0.1, abs=0.05)

    # B fits version 2 from other demos: A's next "latest" is version 2, not its cached 1
    assert fit(b, upload(b, [high(j) for j in range(3)])) == 2
    version, z_end = reproduce(a)
    assert version == 2 and z_end == pytest.approx(LIFT + 0.1, abs=0.05)
    version, z_end = reproduce(a, 1)  # and version 1 is still version 1
    assert version == 1 and z_end == pytest.approx(0.1, abs=0.05)

    # B deletes the skill and makes it again with high demos only: A serves no ghost of the
    # old version 1 (on SQLite the new row takes the deleted row's id)
    assert b.delete("/skills/pour").status_code == 204
    r = a.post("/skills/pour/reproductions", json={"start": [0.0, 0.0, 0.0]})
    assert r.status_code == 404 and r.json()["error"]["field"] == "name"
    assert b.post("/skills", json={"name": "pour", "dim": 3}).status_code == 201
    r = a.post("/skills/pour/reproductions", json={"start": [0.0, 0.0, 0.0]})
    assert r.status_code == 409 and r.json()["error"]["field"] == "model"
    assert fit(b, upload(b, [high(j) for j in range(3)])) == 1
    version, z_end = reproduce(a)
    assert version == 1 and z_end == pytest.approx(LIFT + 0.1, abs=0.05)
    model = a.get("/skills/pour/models/1").json()
    assert model["directrix"][-1][2] == pytest.approx(LIFT + 0.1, abs=0.05)
    r = a.post("/skills/pour/reproductions", json={"start": [0.0, 0.0, 0.0], "model": 2})
    assert r.status_code == 404 and r.json()["error"]["field"] == "model"


def test_reproductions_answer_what_the_model_says(live_server: LiveServer) -> None:
    """The answer (serialised by the route, not by FastAPI's response model) keeps the
    schema's fields and types, for one start and for a batch."""
    with httpx.Client(base_url=live_server.url, timeout=WAIT_S) as http:
        assert http.post("/skills", json={"name": "pour", "dim": 3}).status_code == 201
        fit(http, upload(http, [low(j) for j in range(3)]))
        one = http.post("/skills/pour/reproductions", json={"start": [0.0, 0.0, 0.0]}).json()
        assert set(one) == {"positions", "start", "inside", "eta", "section_index", "projected",
                            "model_version", "times", "velocities", "orientations", "goal",
                            "blocked", "scene_version", "obstacles", "start_clearance", "notes",
                            "route", "route_reason", "approach", "ratios"}
        assert one["model_version"] == 1 and isinstance(one["inside"], bool)
        assert isinstance(one["approach"], int)
        assert len(one["ratios"]) == len(one["positions"])
        assert all(isinstance(x, float) for x in one["ratios"])
        assert one["route"] is None and one["route_reason"] == "single"
        assert one["blocked"] is None and one["scene_version"] is None and one["obstacles"] == 0
        assert np.asarray(one["positions"], dtype=float).shape[1] == 3
        assert one["start"] == [0.0, 0.0, 0.0] and one["goal"] is None and one["notes"] == []
        batch = http.post("/skills/pour/reproductions",
                          json={"starts": [[0.0, 0.0, 0.0], [0.0, 0.01, 0.0]]}).json()
        assert [r["start"] for r in batch["reproductions"]] == [[0.0, 0.0, 0.0], [0.0, 0.01, 0.0]]
        assert batch["reproductions"][0]["positions"] == one["positions"]
