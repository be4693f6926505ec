"""The engineer's session end to end, on SQLite and (when available) PostgreSQL."""

from __future__ import annotations

import numpy as np
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
