"""Every REST route that takes numbers, driven with floats up to the float64 limits (hypothesis):
the answer is a 4xx, or a success whose every number is finite (never NaN, Inf or ``null``).
One fitted skill is shared; examples are few so the module takes seconds."""

from __future__ import annotations

import io
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from canal_service.app import create_app
from canal_service.core.config import Settings
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from service_helpers import LiveServer, demo_positions

BIGGEST = float(np.finfo(np.float64).max)
# Extreme floats (allow_infinity=False, bounds at the float64 limits) mixed with ordinary
# ones, so both the refusals and the computed answers are exercised.
EXTREME = st.floats(min_value=-BIGGEST, max_value=BIGGEST, allow_nan=False, allow_infinity=False)
NUMBER = st.one_of(EXTREME, st.floats(min_value=-2.0, max_value=2.0), st.sampled_from(
    [0.0, 5e-324, -5e-324, 1e-300, 1e15, -1e15, 1e6, BIGGEST, -BIGGEST]))
POSITIVE = st.one_of(st.floats(min_value=5e-324, max_value=BIGGEST, allow_infinity=False),
                     st.floats(min_value=1e-3, max_value=1e3))
EXAMPLES = settings(max_examples=25, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow])


def point(dim: int) -> st.SearchStrategy[list[float]]:
    return st.lists(NUMBER, min_size=dim, max_size=dim)


@pytest.fixture(scope="module")
def http(tmp_path_factory: pytest.TempPathFactory) -> Iterator[httpx.Client]:
    data = Path(tmp_path_factory.mktemp("property")) / "data"
    config = Settings(data_dir=data, recordings_enabled=False, zenoh_enabled=False)
    with LiveServer(create_app(config)) as server, httpx.Client(base_url=server.url,
                                                                timeout=60) as client:
        for name in ("pour", "scratch"):
            assert client.post("/skills", json={"name": name, "dim": 3}).status_code == 201
        for j in range(4):
            positions = demo_positions(j)
            r = client.post("/skills/pour/demonstrations", json={
                "positions": positions.tolist(),
                "timestamps": np.linspace(0.0, 2.0, len(positions)).tolist(),
                "orientations": [[0.0, 0.0, 0.0, 1.0]] * len(positions)})
            assert r.status_code == 201, r.text
        assert client.post("/skills/pour/fit", json={"n_samples": 30}).status_code == 201
        yield client


def numbers_in(value: Any) -> Iterator[Any]:
    """Every leaf of a JSON value that sits in a list of numbers (where a number belongs)."""
    if isinstance(value, dict):
        for item in value.values():
            yield from numbers_in(item)
    elif isinstance(value, list):
        if any(isinstance(v, int | float) and not isinstance(v, bool) for v in value):
            yield from value
        else:
            for item in value:
                yield from numbers_in(item)


def assert_4xx_or_finite(r: httpx.Response, numeric: tuple[str, ...] = ()) -> Any:
    """A 4xx with the error envelope, or a 2xx whose numbers are all finite; ``numeric`` keys
    of the answer must hold numbers, not null."""
    assert r.status_code < 500, r.text
    # JSON has no NaN/Inf; a non-standard encoder would write these words.
    for word in ("NaN", "Infinity"):
        assert word not in r.text, r.text[:300]
    body = r.json()
    if r.status_code >= 400:
        assert set(body["error"]) >= {"type", "field", "message"}, body
        return None
    for leaf in numbers_in(body):
        assert isinstance(leaf, int | float) and math.isfinite(leaf), body
    for key in numeric:
        assert body.get(key) is not None, (key, body)
    return body


SPHERE = st.fixed_dictionaries({"kind": st.just("sphere"), "center": point(3),
                                 "radius": POSITIVE, "clearance": st.just(0.0) | POSITIVE})


@given(start=point(3), goal=st.none() | point(3), duration=st.none() | POSITIVE,
       orientation=st.none() | st.lists(NUMBER, min_size=4, max_size=4),
       obstacles=st.none() | st.lists(SPHERE, min_size=1, max_size=2))
@EXAMPLES
def test_reproductions_answer_4xx_or_finite_numbers(
        http: httpx.Client, start: list[float], goal: list[float] | None,
        duration: float | None, orientation: list[float] | None,
        obstacles: list[dict[str, Any]] | None) -> None:
    body: dict[str, Any] = {"start": start, "goal": goal, "duration": duration,
                            "start_orientation": orientation, "obstacles": obstacles}
    r = http.post("/skills/pour/reproductions", json={k: v for k, v in body.items() if v is not None})
    assert_4xx_or_finite(r, ("positions", "times", "velocities", "orientations", "eta"))


@given(starts=st.lists(point(3), min_size=1, max_size=3))
@EXAMPLES
def test_batch_reproductions_answer_4xx_or_finite_numbers(http: httpx.Client,
                                                          starts: list[list[float]]) -> None:
    r = http.post("/skills/pour/reproductions", json={"starts": starts})
    answer = assert_4xx_or_finite(r)
    if answer is not None:
        assert len(answer["reproductions"]) == len(starts)


@given(positions=st.lists(point(3), min_size=4, max_size=6), stamped=st.booleans(),
       times=st.lists(NUMBER, min_size=6, max_size=6),
       orientations=st.none() | st.lists(st.lists(NUMBER, min_size=4, max_size=4),
                                         min_size=6, max_size=6))
@EXAMPLES
def test_demonstrations_are_stored_finite_or_refused(
        http: httpx.Client, positions: list[list[float]], stamped: bool, times: list[float],
        orientations: list[list[float]] | None) -> None:
    body: dict[str, Any] = {"positions": positions}
    if stamped:
        body["timestamps"] = times[: len(positions)]
    if orientations is not None:
        body["orientations"] = orientations[: len(positions)]
    r = http.post("/skills/scratch/demonstrations", json=body)
    created = assert_4xx_or_finite(r)
    if created is not None:
        demo = http.get(f"/skills/scratch/demonstrations/{created['id']}")
        assert_4xx_or_finite(demo, ("positions",))
        assert http.delete(f"/skills/scratch/demonstrations/{created['id']}").status_code == 204


@given(smoothing=NUMBER, n_samples=st.integers(min_value=-2**63, max_value=2**63))
@settings(max_examples=8, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
def test_fits_and_their_models_answer_4xx_or_finite_numbers(
        http: httpx.Client, smoothing: float, n_samples: int) -> None:
    r = http.post("/skills/pour/fit", json={"frame_smoothing": smoothing,
                                            "n_samples": min(max(n_samples, -5), 40)})
    fitted = assert_4xx_or_finite(r)
    if fitted is not None:
        version = fitted["version"]
        model = http.get(f"/skills/pour/models/{version}", params={"serialized": True})
        assert_4xx_or_finite(model, ("directrix", "radii", "arclength", "bounds"))
        mesh = http.get(f"/skills/pour/models/{version}/mesh", params={"format": "json"})
        assert_4xx_or_finite(mesh)


@given(offset=st.integers(min_value=-2**70, max_value=2**70),
       limit=st.integers(min_value=-2**70, max_value=2**70),
       n_angles=st.integers(min_value=-2**70, max_value=2**70))
@EXAMPLES
def test_query_numbers_answer_4xx_or_finite(http: httpx.Client, offset: int, limit: int,
                                           n_angles: int) -> None:
    for path in ("/skills", "/skills/pour/demonstrations", "/skills/pour/models"):
        assert_4xx_or_finite(http.get(path, params={"offset": offset, "limit": limit}))
    assert_4xx_or_finite(http.get("/skills/pour/models/latest/mesh",
                                  params={"format": "json", "n_angles": n_angles}))


@given(rows=st.lists(point(4), min_size=4, max_size=6))
@EXAMPLES
def test_file_uploads_are_stored_finite_or_refused(http: httpx.Client,
                                                   rows: list[list[float]]) -> None:
    table = np.asarray(rows, dtype=np.float64)  # t then x, y, z
    buffer = io.BytesIO()
    np.save(buffer, table)
    csv = "\n".join(",".join(repr(v) for v in row) for row in rows).encode()
    for body, kind in ((buffer.getvalue(), "application/x-npy"), (csv, "text/csv")):
        r = http.post("/skills/scratch/demonstrations", content=body,
                      headers={"content-type": kind})
        created = assert_4xx_or_finite(r)
        if created is not None:
            demo = http.get(f"/skills/scratch/demonstrations/{created['id']}")
            assert_4xx_or_finite(demo, ("positions",))
            assert http.delete(f"/skills/scratch/demonstrations/{created['id']}").status_code == 204


@given(number=st.integers(min_value=-2**70, max_value=2**70))
@EXAMPLES
def test_path_numbers_answer_4xx_or_finite(http: httpx.Client, number: int) -> None:
    for path in (f"/skills/pour/demonstrations/{number}", f"/skills/pour/models/{number}"):
        assert_4xx_or_finite(http.get(path))
