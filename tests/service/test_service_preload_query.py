"""The live bridge's start-up listing: skills with a model, most recently fitted first, in one
query, on SQLite and on PostgreSQL (grouping and ordering differ between the two)."""

from __future__ import annotations

from fastapi.testclient import TestClient
from service_helpers import demo_positions


def _skill(client: TestClient, name: str, fit: bool = True) -> None:
    assert client.post("/skills", json={"name": name, "dim": 3}).status_code == 201
    for j in range(3):
        r = client.post(f"/skills/{name}/demonstrations",
                        json={"positions": demo_positions(j).tolist()})
        assert r.status_code == 201, r.text
    if fit:
        assert client.post(f"/skills/{name}/fit", json={"n_samples": 20}).status_code == 201


def test_skills_by_latest_fit_orders_by_the_newest_model(any_db_client: TestClient) -> None:
    service = any_db_client.app.state.service  # type: ignore[attr-defined]
    assert service.skills_by_latest_fit(10) == []
    for name in ("a", "b", "c"):
        _skill(any_db_client, name)
    _skill(any_db_client, "unfitted", fit=False)
    assert service.skills_by_latest_fit(10) == [("c", 1), ("b", 1), ("a", 1)]
    # a refit makes "a" the most recently fitted, with its latest version
    assert any_db_client.post("/skills/a/fit", json={"n_samples": 20}).status_code == 201
    assert service.skills_by_latest_fit(2) == [("a", 2), ("c", 1)]
    assert any_db_client.delete("/skills/a").status_code == 204
    assert service.skills_by_latest_fit(10) == [("c", 1), ("b", 1)]
    assert service.latest_version("b") == 1
