"""No 5xx leaks as a reset: unexpected errors are JSON 500s on a connection that stays usable,
database clashes are 409/503 with Retry-After."""

from __future__ import annotations

import http.client
import json
import logging
from pathlib import Path

import numpy as np
import pytest
from canal_service.app import create_app
from canal_service.core.config import Settings
from canal_testing import LiveServer


def _settings(tmp_path: Path) -> Settings:
    return Settings(data_dir=tmp_path / "data", recordings_enabled=False, zenoh_enabled=False)


def _request(conn: http.client.HTTPConnection, method: str, path: str,
             body: object | None = None) -> tuple[int, dict[str, str], object]:
    payload = None if body is None else json.dumps(body).encode()
    headers = {"content-type": "application/json"} if payload is not None else {}
    conn.request(method, path, body=payload, headers=headers)
    response = conn.getresponse()
    data = response.read()
    return response.status, {k.lower(): v for k, v in response.getheaders()}, json.loads(data)


def _rounding_level_repeats(j: int) -> list[list[float]]:
    """A polling logger's demo: every sample twice, the copy 1e-17 off in z.

    The copies pass the exact-repeat filter but add nothing to the cumulative arc length,
    which on today's canal_core reached scipy as "x must be strictly increasing".
    """
    t = np.linspace(0.0, 1.0, 60)
    p = np.column_stack([t, 0.3 * np.sin(np.pi * t) + 0.02 * j, 0.1 * t])
    p = np.repeat(p, 2, axis=0)
    p[1::2, 2] += 1e-17
    return p.tolist()


def test_unexpected_errors_are_json_500_on_a_connection_that_stays_open(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    app = create_app(_settings(tmp_path))

    @app.get("/boom")
    def boom() -> None:  # stands for any bug a request can reach
        raise RuntimeError("a bug")

    with LiveServer(app) as server:
        conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=30)
        try:
            with caplog.at_level(logging.ERROR, logger="canal_service"):
                first = _request(conn, "GET", "/boom")
                sock = conn.sock
                second = _request(conn, "GET", "/boom")
                assert conn.sock is sock  # the same keep-alive connection answered both
                health = _request(conn, "GET", "/healthz")
                assert conn.sock is sock
        finally:
            conn.close()
    for status, headers, body in (first, second):
        assert status == 500
        assert headers["content-type"] == "application/json"
        assert headers.get("connection", "").lower() != "close"
        assert body == {"error": {"type": "internal", "field": None,
                                  "message": "internal server error"}}
    assert health[0] == 200
    logged = [r for r in caplog.records if r.exc_info and "a bug" in str(r.exc_info[1])]
    assert len(logged) == 2  # each one logged with its traceback, and only once


def test_failing_fits_keep_the_connection_and_answer_json(tmp_path: Path) -> None:
    """The issue's case: a fit that canal_core could not handle reset the connection."""
    with LiveServer(create_app(_settings(tmp_path))) as server:
        conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=60)
        try:
            assert _request(conn, "POST", "/skills", {"name": "raw", "dim": 3})[0] == 201
            for j in range(3):
                status, _, body = _request(conn, "POST", "/skills/raw/demonstrations",
                                           {"positions": _rounding_level_repeats(j)})
                assert status in (201, 422), body
            sock = conn.sock
            answers = [_request(conn, "POST", "/skills/raw/fit", {"n_samples": 50, "by_time": b})
                       for b in (False, True, False)]
            assert conn.sock is sock
            assert _request(conn, "GET", "/skills/raw")[0] == 200
            assert conn.sock is sock
        finally:
            conn.close()
    for status, headers, body in answers:
        assert headers["content-type"] == "application/json"
        assert isinstance(body, dict)
        # A fit either works, or names what is wrong (422), or (a bug) is a JSON 500.
        assert status in (201, 409, 422, 500), body
        if status == 500:
            assert body["error"]["type"] == "internal"
        elif status != 201:
            assert body["error"]["field"]


@pytest.mark.parametrize("backend", ["sqlite", pytest.param("postgres", marks=pytest.mark.postgres)])
def test_forty_concurrent_fits_on_two_replicas_never_collide(
    request: pytest.FixtureRequest, tmp_path: Path, backend: str
) -> None:
    """On PostgreSQL with two replicas, 23 of 40 fits were UniqueViolation 500s before."""
    import threading

    import httpx
    from service_helpers import demo_positions

    if backend == "postgres":
        url = request.getfixturevalue("postgres_server").new_database()
    else:
        url = f"sqlite:///{tmp_path / 'shared.sqlite3'}"
    apps = [create_app(Settings(data_dir=tmp_path / f"r{i}", database_url=url,
                                recordings_enabled=False, zenoh_enabled=False))
            for i in range(2)]
    with LiveServer(apps[0]) as a, LiveServer(apps[1]) as b:
        with httpx.Client(base_url=a.url, timeout=120) as http:
            assert http.post("/skills", json={"name": "pour", "dim": 3}).status_code == 201
            for j in range(3):
                r = http.post("/skills/pour/demonstrations",
                              json={"positions": demo_positions(j, n=30).tolist()})
                assert r.status_code == 201
        answers: list[httpx.Response] = []
        lock = threading.Lock()
        barrier = threading.Barrier(40)

        def fit(base: str) -> None:
            with httpx.Client(base_url=base, timeout=120) as http:
                barrier.wait()
                r = http.post("/skills/pour/fit", json={"n_samples": 10})
            with lock:
                answers.append(r)

        threads = [threading.Thread(target=fit, args=((a, b)[i % 2].url,)) for i in range(40)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        with httpx.Client(base_url=b.url, timeout=60) as http:
            stored = http.get("/skills/pour/models", params={"limit": 100}).json()
    assert len(answers) == 40
    for r in answers:
        assert r.status_code in (201, 409, 503), r.text
        if r.status_code != 201:
            assert "retry-after" in r.headers, r.text
    versions = sorted(r.json()["version"] for r in answers if r.status_code == 201)
    assert len(versions) == len(set(versions))
    assert sorted(m["version"] for m in stored["items"]) == versions
    # Allocation cannot collide, so nothing needs a retry on a healthy database.
    assert versions == list(range(1, 41))


def test_an_unknown_path_or_method_says_which_and_what_there_is(tmp_path: Path) -> None:
    # Answered "Not Found" and "Method Not Allowed": a client with a mistyped path or a
    # wrong method could not tell which part of its request was wrong.
    with LiveServer(create_app(_settings(tmp_path))) as server:
        conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=30)
        try:
            assert _request(conn, "POST", "/skills", {"name": "arm", "dim": 3})[0] == 201
            status, _, body = _request(conn, "GET", "/skill/arm")
            assert status == 404, body
            assert body == {"error": {"type": "not_found", "field": "path", "message":
                                      "no route GET /skill/arm (the routes are listed at /docs)"}}
            status, headers, body = _request(conn, "GET", "/skills/arm/fit")
            assert status == 405 and headers["allow"] == "POST", (headers, body)
            assert body == {"error": {"type": "method_not_allowed", "field": "method", "message":
                                      "GET is not allowed on /skills/arm/fit; allowed: POST"}}
            # every method the path takes, not only the first route's (a skill is read and
            # deleted at one path: the answer said "allowed: GET")
            status, headers, body = _request(conn, "PUT", "/skills/arm")
            assert status == 405 and headers["allow"] == "DELETE, GET", (headers, body)
            assert body["error"]["message"].endswith("allowed: DELETE, GET"), body
            # a skill or model that is not there keeps its own message
            status, _, body = _request(conn, "GET", "/skills/nope")
            assert status == 404 and body["error"]["message"] == "no skill named 'nope'", body
        finally:
            conn.close()
