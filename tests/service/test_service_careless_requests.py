"""Careless and hostile request bodies over real HTTP: each gets a 4xx whose ``type`` is in the
error table of docs/rest.md, says what was expected, and stores nothing."""

from __future__ import annotations

import logging
import re
import socket
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest
from canal_service import errors
from canal_service.app import create_app
from canal_service.core.config import Settings
from service_helpers import LiveServer, demo_positions

ROOT = Path(__file__).resolve().parents[2]


def readme_error_types() -> dict[str, int]:
    """``type`` word -> status, from the error table of docs/rest.md (rows ``| 4xx | `a`, `b` | ...``)."""
    table: dict[str, int] = {}
    for line in (ROOT / "docs" / "rest.md").read_text().splitlines():
        match = re.match(r"^\| (\d{3}) \| ([^|]+)\|", line)
        if match:
            for word in re.findall(r"`([a-z_]+)`", match.group(2)):
                table[word] = int(match.group(1))
    return table


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveServer]:
    data = Path(tmp_path_factory.mktemp("careless")) / "data"
    settings = Settings(data_dir=data, recordings_enabled=False, zenoh_enabled=False)
    with LiveServer(create_app(settings)) as live, httpx.Client(base_url=live.url) as http:
        assert http.post("/skills", json={"name": "pour", "dim": 3}).status_code == 201
        for j in range(3):
            r = http.post("/skills/pour/demonstrations", json={"positions": demo_positions(j).tolist()})
            assert r.status_code == 201
        yield live


@pytest.fixture
def http(server: LiveServer) -> Iterator[httpx.Client]:
    with httpx.Client(base_url=server.url, timeout=60) as client:
        yield client


def test_every_4xx_type_the_service_answers_is_in_the_readme_error_table() -> None:
    table = readme_error_types()
    answered = {kind: status for status, kind in errors.HTTP_STATUS.values() if status < 500}
    answered |= {kind: status for status, kind in errors._HTTP_TYPES.items() if status < 500}
    answered["invalid_input"] = 422  # request validation
    missing = {kind: status for kind, status in answered.items() if table.get(kind) != status}
    assert not missing, f"not in the error table of docs/rest.md with that status: {missing}"


def test_fit_with_a_null_body_is_refused_and_fits_nothing(http: httpx.Client) -> None:
    r = http.post("/skills/pour/fit", content=b"null", headers={"content-type": "application/json"})
    assert r.status_code == 422, r.text
    assert r.json()["error"]["field"] == "body"
    assert "null" in r.json()["error"]["message"]
    assert http.get("/skills/pour").json()["n_models"] == 0


@pytest.mark.parametrize(("body", "said"), [
    (b'{"start": [0, 0, \xff]}', "UTF-8"),
    (b"[" * 100_000 + b"]" * 100_000, "nested too deep"),
    (b'{"start": [' + b"9" * 5000 + b", 0, 0]}", "too many digits"),
    # Cut short, a trailing comma, a bare word: named "[26]" with "JSON decode error" before.
    (b'{"start": [0, 0.05, 0.025]', "invalid JSON at character 26"),
    (b'{"start": [0, 0, 0],}', "invalid JSON at character 20"),
    (b"start=0,0,0", "invalid JSON at character 0"),
])
def test_a_json_body_that_cannot_be_parsed_gets_a_type_from_the_error_table(
        http: httpx.Client, body: bytes, said: str) -> None:
    r = http.post("/skills/pour/reproductions", content=body,
                  headers={"content-type": "application/json"})
    assert 400 <= r.status_code < 500, r.text
    error = r.json()["error"]
    assert readme_error_types().get(error["type"]) == r.status_code, error
    assert error["field"] == "body"
    assert said in error["message"]


@pytest.mark.parametrize("path", ["/skills/pour/reproductions", "/skills/pour/demonstrations"])
@pytest.mark.parametrize(("body", "said"), [
    (b'{"start": [[0, 0, \xff]], "positions": [[0, 0, \xff]]}', "UTF-8"),
    (b"[" * 100_000 + b"]" * 100_000, "nested too deep"),
    (b'{"positions": [' * 3000 + b"]}" * 3000, "nested too deep"),
    (b'{"start": [' + b"9" * 5000 + b', 0, 0], "positions": [[' + b"9" * 5000 + b", 0, 0]]}",
     "too many digits"),
])
def test_a_body_that_is_no_json_in_utf8_is_a_bad_request_on_every_route(
        http: httpx.Client, path: str, body: bytes, said: str) -> None:
    """Uploads parse their JSON themselves (on the upload lane); what they cannot read is
    answered as every other route answers it."""
    before = http.get("/skills/pour").json()
    r = http.post(path, content=body, headers={"content-type": "application/json"})
    assert r.status_code == 400, r.text
    error = r.json()["error"]
    assert error["type"] == "bad_request" and error["field"] == "body", error
    assert said in error["message"], error
    assert http.get("/skills/pour").json() == before


def test_a_client_that_leaves_mid_upload_is_not_an_unhandled_error(
        server: LiveServer, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, logger="canal_service")
    with socket.create_connection(("127.0.0.1", server.port)) as sock:
        sock.sendall(b"POST /skills/pour/demonstrations HTTP/1.1\r\nHost: x\r\n"
                     b"Content-Type: text/csv\r\nContent-Length: 100000\r\n\r\nx,y,z\n0,0,0\n")
        time.sleep(0.3)
    deadline = time.monotonic() + 10
    while not any("went away" in r.getMessage() for r in caplog.records):
        assert time.monotonic() < deadline, [r.getMessage() for r in caplog.records]
        time.sleep(0.05)
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR], caplog.text


def test_demonstrations_below_the_canals_resolution_are_not_called_identical(
        http: httpx.Client) -> None:
    assert http.post("/skills", json={"name": "far", "dim": 3}).status_code == 201
    t = np.linspace(0.0, 1e14, 50)
    for j in range(3):
        line = np.column_stack([t, np.full(50, 10.0 * j), np.zeros(50)])
        r = http.post("/skills/far/demonstrations", json={"positions": line.tolist()})
        assert r.status_code == 201, r.text
    r = http.post("/skills/far/fit", json={})
    assert r.status_code == 422, r.text
    error = r.json()["error"]
    assert "identical" not in error["message"]
    assert "cannot be told apart" in error["message"] and "resolution" in error["message"]
    assert http.get("/skills/far").json()["n_models"] == 0


@pytest.mark.parametrize("encoded", ["%2F", "%2f"])
def test_an_encoded_slash_in_a_skill_name_reaches_no_other_resource(
        http: httpx.Client, encoded: str) -> None:
    # A skill name with an encoded '/' was decoded before routing: deleting the "skill"
    # victim%2Fdemonstrations%2F<id> deleted demonstration <id> of skill victim, and
    # victim%2Fscene cleared its scene.
    assert http.post("/skills", json={"name": "victim", "dim": 3}).status_code == 201
    made = http.post("/skills/victim/demonstrations", json={"positions": demo_positions(0).tolist()})
    demo = made.json()["id"]
    for method, path in [("DELETE", f"/skills/victim{encoded}demonstrations{encoded}{demo}"),
                         ("DELETE", f"/skills/victim{encoded}scene"),
                         ("GET", f"/skills/victim{encoded}demonstrations"),
                         ("POST", f"/skills/victim{encoded}fit")]:
        r = http.request(method, path, json={} if method == "POST" else None)
        assert r.status_code == 422, (path, r.status_code, r.text)
        error = r.json()["error"]
        assert error["type"] == "invalid_input" and error["field"] == "path", error
        assert "'/'" in error["message"] and encoded in error["message"], error
    assert http.get(f"/skills/victim/demonstrations/{demo}").status_code == 200
    assert http.delete("/skills/victim").status_code == 204


def test_a_query_parameter_a_route_does_not_take_is_refused(http: httpx.Client) -> None:
    # A misspelt query parameter was dropped without a word: `?wieght=2` left the default
    # weight, `?time_unit=` on a route without it left the stamps as seconds.
    models = http.get("/skills/pour/models").json()["total"]
    for method, path, params in [("GET", "/skills", {"limt": "5"}),
                                 ("POST", "/skills/pour/demonstrations", {"time_units": "ms"}),
                                 ("POST", "/skills/pour/fit", {"routes": "1"})]:
        r = http.request(method, path, params=params,
                         json=None if method == "GET" else {"positions": demo_positions(9).tolist()})
        assert r.status_code == 422, (path, r.text)
        error = r.json()["error"]
        name = next(iter(params))
        assert error["type"] == "invalid_input" and error["field"] == name, error
        assert repr(name) in error["message"] and "expected" in error["message"], error
    assert http.get("/skills/pour").json()["n_demonstrations"] == 3  # nothing stored
    assert http.get("/skills/pour/models").json()["total"] == models
    # the pages a browser opens keep theirs (the viewer reads ?url= itself)
    assert http.get("/skills", params={"limit": 5}).status_code == 200
    assert http.get("/healthz", params={"probe": "1"}).status_code == 200
