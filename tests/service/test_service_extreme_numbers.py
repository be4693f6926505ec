"""Extreme numbers over real HTTP: a 4xx naming the field, or an answer of finite numbers.

Never a 500, never a ``null`` where a number belongs, and nothing stored by a refused request.
"""

from __future__ import annotations

import tracemalloc
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from canal_service.app import create_app
from canal_service.core.config import Settings
from canal_service.errors import InvalidInput
from canal_service.uploads import parse_csv
from service_helpers import LiveServer, demo_positions

from canal_core import bounds


@pytest.fixture(scope="module")
def http(tmp_path_factory: pytest.TempPathFactory) -> Iterator[httpx.Client]:
    """A real service with 'pour': four timed demonstrations and one fitted model."""
    data = Path(tmp_path_factory.mktemp("extreme")) / "data"
    settings = Settings(data_dir=data, recordings_enabled=False, zenoh_enabled=False)
    with LiveServer(create_app(settings)) as server, httpx.Client(base_url=server.url,
                                                                  timeout=60) as client:
        assert client.post("/skills", json={"name": "pour", "dim": 3}).status_code == 201
        for j in range(4):
            positions = demo_positions(j)
            r = client.post("/skills/pour/demonstrations", json={
                "positions": positions.tolist(),
                "timestamps": np.linspace(0.0, 2.0, len(positions)).tolist()})
            assert r.status_code == 201, r.text
        assert client.post("/skills/pour/fit", json={"n_samples": 50}).status_code == 201
        yield client


def _refused(r: httpx.Response, field: str) -> dict[str, Any]:
    assert r.status_code == 422, r.text
    error = r.json()["error"]
    assert error["type"] == "invalid_input"
    assert error["field"] == field, error
    assert "expected" in error["message"] and "got" in error["message"], error
    return error


@pytest.mark.parametrize("goal", [[1e200, 0, 0], [1e308, 0, 0], [-1e308, -1e308, -1e308],
                                  [1e9, 0, 0]])
def test_a_goal_beyond_the_canals_reach_is_refused_naming_goal(http: httpx.Client,
                                                               goal: list[float]) -> None:
    r = http.post("/skills/pour/reproductions", json={"start": [0, 0, 0], "goal": goal})
    _refused(r, "goal")


@pytest.mark.parametrize("start", [[-1e308, 0, 0], [1e308, 1e308, 1e308], [0, 0, 1e12]])
def test_a_start_beyond_the_canals_reach_is_refused_naming_start(http: httpx.Client,
                                                                 start: list[float]) -> None:
    _refused(http.post("/skills/pour/reproductions", json={"start": start}), "start")
    r = http.post("/skills/pour/reproductions", json={"starts": [[0, 0, 0], start]})
    _refused(r, "starts[1]")


@pytest.mark.parametrize("duration", [1e-300, 5e-324, 1e-6, 1e7, 1e12, 1e308])
def test_a_duration_outside_the_documented_bounds_is_refused(http: httpx.Client,
                                                             duration: float) -> None:
    r = http.post("/skills/pour/reproductions", json={"start": [0, 0, 0], "duration": duration})
    error = _refused(r, "duration")
    assert f"{bounds.MIN_DURATION:g} s" in error["message"]


@pytest.mark.parametrize("body", [
    {"start": [0, 0, 0], "duration": bounds.MIN_DURATION},
    {"start": [0, 0, 0], "duration": bounds.MAX_DURATION},
    {"start": [5e4, -5e4, 5e4], "goal": [-5e4, 5e4, 5e4]},
    {"start": [0.3, 0.2, 0.1], "goal": [1e-300, -1e-300, 0]},
])
def test_numbers_at_the_bounds_answer_finite_numbers(http: httpx.Client,
                                                     body: dict[str, Any]) -> None:
    r = http.post("/skills/pour/reproductions", json=body)
    assert r.status_code == 200, r.text
    answer = r.json()
    for key in ("positions", "times", "velocities", "start", "eta"):
        assert answer[key] is not None, key
        assert np.isfinite(np.asarray(answer[key], dtype=np.float64)).all(), key


def test_refused_reproductions_store_nothing(http: httpx.Client) -> None:
    before = http.get("/skills/pour").json()
    http.post("/skills/pour/reproductions", json={"start": [0, 0, 0], "goal": [1e308, 0, 0]})
    assert http.get("/skills/pour").json() == before


def _wide_csv(columns: int, rows: int = 5) -> bytes:
    return "\n".join([",".join(["0.5"] * columns)] * rows).encode()


def test_a_headerless_csv_20000_columns_wide_is_refused_naming_its_width(
        http: httpx.Client) -> None:
    before = http.get("/skills/pour").json()["n_demonstrations"]
    r = http.post("/skills/pour/demonstrations", content=_wide_csv(20_000),
                  headers={"content-type": "text/csv"})
    error = _refused(r, "file:line 1")
    assert "20000" in error["message"]
    assert http.get("/skills/pour").json()["n_demonstrations"] == before


@pytest.mark.parametrize("csv", [
    _wide_csv(5_000),
    # a header naming x, y, z among thousands of columns: only those are read
    ("x,y,z," + ",".join(f"c{i}" for i in range(5_000)) + "\n"
     + "\n".join(",".join(["0.5"] * 5_003) for _ in range(5))).encode(),
])
def test_parsing_a_csv_allocates_in_proportion_to_its_bytes(csv: bytes) -> None:
    tracemalloc.start()
    try:
        try:
            parse_csv(csv, 3)
        except InvalidInput:
            pass
        _current, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 20 * len(csv), f"{peak / 2**20:.1f} MiB for a {len(csv) / 2**10:.0f} KiB body"


def test_a_csv_with_cr_only_line_ends_is_read_row_by_row(http: httpx.Client) -> None:
    rows = demo_positions(0, n=8)
    body = "x,y,z\r" + "\r".join(",".join(f"{v:.6f}" for v in row) for row in rows) + "\r"
    r = http.post("/skills", json={"name": "classic-mac", "dim": 3})
    assert r.status_code == 201
    r = http.post("/skills/classic-mac/demonstrations", content=body.encode(),
                  headers={"content-type": "text/csv"})
    assert r.status_code == 201, r.text
    assert r.json()["n_points"] == 8
    stored = http.get(f"/skills/classic-mac/demonstrations/{r.json()['id']}").json()
    np.testing.assert_allclose(stored["positions"], rows, atol=1e-6)


@pytest.mark.parametrize(("obstacle", "field"), [
    ({"kind": "sphere", "center": [1e308, 0, 0], "radius": 0.1}, "obstacles[0].center"),
    ({"kind": "sphere", "center": [0.5, 0, 0], "radius": 1e300}, "obstacles[0].radius"),
    ({"kind": "sphere", "center": [0.5, 0, 0], "radius": 0.01, "clearance": 1e308},
     "obstacles[0].clearance"),
    ({"kind": "box", "center": [0.5, 0, 0], "half_extents": [1e308, 1, 1]},
     "obstacles[0].half_extents"),
    ({"kind": "capsule", "a": [-1e308, 0, 0], "b": [1e308, 0, 0], "radius": 0.01},
     "obstacles[0].a"),
])
def test_obstacles_beyond_the_coordinate_range_are_refused_and_not_stored(
        http: httpx.Client, obstacle: dict[str, Any], field: str) -> None:
    r = http.post("/skills/pour/reproductions", json={"start": [0, 0, 0], "obstacles": [obstacle]})
    _refused(r, field)
    before = http.get("/skills/pour/scene")
    _refused(http.put("/skills/pour/scene", json={"obstacles": [obstacle]}), field)
    after = http.get("/skills/pour/scene")
    assert (after.status_code, after.json()) == (before.status_code, before.json())


def test_a_2d_box_turned_past_the_angle_bound_is_refused_and_not_stored(http: httpx.Client) -> None:
    # 1e300 rad has no fraction left: it was stored as -2.18, a box turned some other way.
    assert http.post("/skills", json={"name": "flat", "dim": 2}).status_code == 201
    box = {"kind": "box", "center": [0.5, 0.0], "half_extents": [0.1, 0.1]}
    for angle in (1e300, -1000.5):
        _refused(http.put("/skills/flat/scene", json={"obstacles": [{**box, "rotation": angle}]}),
                 "obstacles[0].rotation")
    assert http.get("/skills/flat/scene").json()["obstacles"] == []
    r = http.put("/skills/flat/scene", json={"obstacles": [{**box, "rotation": 1000.0}]})
    assert r.status_code == 200, r.text


@pytest.mark.parametrize(("change", "field"), [
    ({"samples": [[1e308, 0, 0]] + [[0.1 * k, 0.0, 0.0] for k in range(1, 8)]}, "samples[0]"),
    ({"samples": [[0.1 * k, 0.0, 0.0] for k in range(8)],
      "timestamps": [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 1e300]}, "timestamps"),  # its span
    ({"kind": "exclude", "samples": [[0.1 * k, 0.0, 0.0] for k in range(8)],
      "plan": [[0.1 * k, -1e200, 0.0] for k in range(8)]}, "plan[0]"),
])
def test_a_correction_beyond_the_canals_reach_is_refused_and_not_stored(
        http: httpx.Client, change: dict[str, Any], field: str) -> None:
    before = http.get("/skills/pour").json()
    r = http.post("/skills/pour/corrections", json={"kind": "include", **change})
    _refused(r, field)
    assert http.get("/skills/pour").json() == before
