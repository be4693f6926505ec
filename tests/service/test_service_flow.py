"""The engineer's session end to end, on SQLite and (when available) PostgreSQL."""

from __future__ import annotations

import numpy as np
from canal_testing import arc_demo
from fastapi.testclient import TestClient
from service_helpers import demo_positions


def test_full_session(any_db_client: TestClient) -> None:
    c = any_db_client
    r = c.post("/skills", json={"name": "pour", "description": "pour water", "dim": 3})
    assert r.status_code == 201
    assert r.json()["n_demonstrations"] == 0 and r.json()["latest_model_version"] is None

    ids = []
    for j in range(4):
        r = c.post("/skills/pour/demonstrations",
                   json={"positions": demo_positions(j).tolist(), "label": f"d{j}"})
        assert r.status_code == 201, r.text
        assert r.json()["n_points"] == 50
        ids.append(r.json()["id"])

    r = c.post("/skills/pour/fit", json={"n_samples": 40})
    assert r.status_code == 201, r.text
    v1 = r.json()
    assert v1["version"] == 1 and v1["demo_ids"] == ids and v1["n_sections"] == 40
    assert v1["options"]["cross_section"] == "circle" and v1["n_demos"] == 4

    r = c.get("/skills/pour/models/latest")
    assert r.status_code == 200
    model = r.json()
    assert np.asarray(model["directrix"]).shape == (40, 3)
    assert len(model["radii"]) == 40 and min(model["radii"]) > 0
    assert np.asarray(model["frames"]["binormals"]).shape == (40, 3)
    lo, hi = np.asarray(model["bounds"])
    assert np.all(lo < hi)

    start = np.asarray(model["directrix"][0])
    r = c.post("/skills/pour/reproductions", json={"start": start.tolist()})
    assert r.status_code == 200, r.text
    rep = r.json()
    assert rep["inside"] is True and rep["projected"] is False and rep["model_version"] == 1
    path = np.asarray(rep["positions"])
    assert path.shape[1] == 3
    assert np.allclose(path[-1], model["directrix"][-1], atol=0.05)

    # remove a bad demonstration and refit: a new version, the old one kept
    assert c.delete(f"/skills/pour/demonstrations/{ids[0]}").status_code == 204
    r = c.post("/skills/pour/fit", json={"n_samples": 40, "cross_section": "ellipse"})
    assert r.status_code == 201, r.text
    assert r.json()["version"] == 2 and ids[0] not in r.json()["demo_ids"]
    listing = c.get("/skills/pour/models").json()
    assert [m["version"] for m in listing["items"]] == [2, 1] and listing["total"] == 2
    assert c.get("/skills/pour/models/1").json()["demo_ids"] == ids

    skill = c.get("/skills/pour").json()
    assert skill["n_demonstrations"] == 3 and skill["n_models"] == 2
    assert skill["latest_model_version"] == 2

    assert c.delete("/skills/pour").status_code == 204
    assert c.get("/skills/pour").status_code == 404
    assert c.get("/skills").json()["total"] == 0


def test_an_id_is_never_given_twice(any_db_client: TestClient) -> None:
    # SQLite gave a new row the id of a deleted last row: demonstration 3 deleted, the next
    # upload was demonstration 3 again, so model version 1 still listed demonstration 3 among
    # its own, now a trajectory made after it, and a client holding the old id got another.
    client = any_db_client
    assert client.post("/skills", json={"name": "ids", "dim": 3}).status_code == 201
    ids = []
    for j in range(3):
        r = client.post("/skills/ids/demonstrations",
                        json={"positions": (arc_demo(j, 40, 3, 0) + 0.01 * j).tolist()})
        ids.append(r.json()["id"])
    fit = client.post("/skills/ids/fit", json={"n_samples": 30})
    assert fit.status_code == 201, fit.text
    assert client.delete(f"/skills/ids/demonstrations/{ids[-1]}").status_code == 204
    again = client.post("/skills/ids/demonstrations",
                        json={"positions": arc_demo(5, 40, 3, 0).tolist()}).json()["id"]
    assert again not in ids, (again, ids)
    assert client.get(f"/skills/ids/demonstrations/{ids[-1]}").status_code == 404
    assert ids[-1] in client.get("/skills/ids/models/1").json()["demo_ids"]
    # corrections too: one undone and deleted with its version is not given again
    correction = {"kind": "include", "samples": (arc_demo(1, 40, 3, 0) + 0.005).tolist()}
    first = client.post("/skills/ids/corrections", json=correction)
    assert first.status_code == 201, first.text
    first_id = first.json()["correction"]["id"]
    assert client.delete("/skills/ids").status_code == 204
    assert client.post("/skills", json={"name": "ids", "dim": 3}).status_code == 201
    for j in range(3):
        client.post("/skills/ids/demonstrations", json={"positions": arc_demo(j, 40, 3, 0).tolist()})
    assert client.post("/skills/ids/fit", json={"n_samples": 30}).status_code == 201
    second = client.post("/skills/ids/corrections", json=correction)
    assert second.status_code == 201, second.text
    assert second.json()["correction"]["id"] != first_id
