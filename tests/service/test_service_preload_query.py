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
    assert service.latest_revision("b")[1] == 1


def test_json_columns_read_back_what_the_stdlib_wrote(any_db_settings) -> None:
    """The engines parse JSON columns with orjson (a canal's ~100 kB column held the GIL for
    milliseconds under ``json.loads``) and fall back to the stdlib for what orjson refuses:
    ``NaN`` and integers beyond 64 bits, which ``json.dumps`` writes."""
    import math

    from canal_service.storage import Database
    from sqlalchemy import JSON, Column, Integer, MetaData, Table, insert, select

    db = Database(any_db_settings.resolved_database_url)
    table = Table("json_probe", MetaData(), Column("id", Integer, primary_key=True),
                  Column("v", JSON))
    try:
        table.create(db.write_engine)
        # PostgreSQL's json type refuses NaN: only SQLite stores it
        nan = float("nan") if db.is_sqlite else 0.0
        values = [{"x": [1.5, -2.0e-300], "s": "é"}, {"x": nan, "big": 2**70}]
        with db.write_engine.begin() as connection:
            connection.execute(insert(table), [{"id": i, "v": v} for i, v in enumerate(values)])
        with db.read_engine.connect() as connection:
            rows = connection.execute(select(table.c.v).order_by(table.c.id)).scalars().all()
        assert rows[0] == values[0]
        assert rows[1]["big"] == 2**70
        assert math.isnan(rows[1]["x"]) if db.is_sqlite else rows[1]["x"] == 0.0
    finally:
        table.drop(db.write_engine)
        db.dispose()
