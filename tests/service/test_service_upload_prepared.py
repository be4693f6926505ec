"""Issue 12: uploads run canal_core's preparation stage, so what cannot be fitted is a 422 at
upload naming it, and raw robot logs (repeats, rounding-level steps, still ends) fit through REST."""

from __future__ import annotations

import numpy as np
from fastapi.testclient import TestClient
from raw_logs import raw_demo_set
from service_helpers import demo_positions


def _error(r) -> dict:  # type: ignore[no-untyped-def]
    assert r.status_code == 422, r.text
    return r.json()["error"]


def test_identical_points_are_refused_at_upload(client: TestClient, skill: str) -> None:
    r = client.post(f"/skills/{skill}/demonstrations", json={"positions": [[0.1, 0.2, 0.3]] * 10})
    error = _error(r)
    assert error["field"] == "positions" and "identical" in error["message"]
    for j in range(2):  # the skill still fits: nothing unfittable was stored
        client.post(f"/skills/{skill}/demonstrations", json={"positions": demo_positions(j).tolist()})
    assert client.post(f"/skills/{skill}/fit", json={}).status_code == 201


def test_huge_finite_coordinates_are_refused_at_upload(client: TestClient, skill: str) -> None:
    r = client.post(f"/skills/{skill}/demonstrations",
                    json={"positions": (demo_positions(0) * 1e306).tolist()})
    error = _error(r)
    assert error["field"] == "positions" and "1e+15" in error["message"]


def test_raw_logs_fit_by_arc_length_and_by_time(client: TestClient, skill: str) -> None:
    logs = raw_demo_set("task1", seed=5, n_demos=4, rate_hz=200.0)
    for g in logs:
        r = client.post(f"/skills/{skill}/demonstrations",
                        json={"positions": g.positions.tolist(), "timestamps": g.timestamps.tolist()})
        assert r.status_code == 201, r.text
    for by_time in (False, True):
        r = client.post(f"/skills/{skill}/fit", json={"by_time": by_time, "n_samples": 200})
        assert r.status_code == 201, r.text
    start = np.mean([g.positions[0] for g in logs], axis=0).tolist()
    r = client.post(f"/skills/{skill}/reproductions", json={"start": start})
    assert r.status_code == 200, r.text
