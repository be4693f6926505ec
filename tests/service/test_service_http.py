"""Real HTTP through uvicorn on 127.0.0.1: smoke, size limit, token, CORS, metrics, the main job."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import numpy as np
import pytest
from canal_service.app import create_app
from canal_service.core.cli import settings_from_args
from canal_service.core.config import Settings
from canal_testing import LiveServer, free_port
from service_helpers import demo_positions


def test_smoke_over_real_http(live_server: LiveServer) -> None:
    with httpx.Client(base_url=live_server.url) as http:
        assert http.get("/healthz").json()["status"] == "ok"
        assert http.post("/skills", json={"name": "pour", "dim": 3}).status_code == 201
        for j in range(3):
            r = http.post("/skills/pour/demonstrations",
                          json={"positions": demo_positions(j).tolist()})
            assert r.status_code == 201
        assert http.post("/skills/pour/fit", json={}).status_code == 201
        rep = http.post("/skills/pour/reproductions", json={"start": [0, 0, 0]}).json()
        assert np.asarray(rep["positions"]).shape[1] == 3
        assert http.get("/docs").status_code == 200
        spec = http.get("/openapi.json").json()
        assert "/skills/{name}/reproductions" in spec["paths"]
        metrics = http.get("/metrics").text
        assert 'canal_http_requests_total{method="POST",route="/skills/{name}/fit",status="201"}' \
            in metrics
        assert "canal_fit_duration_seconds_count 1.0" in metrics


def test_every_json_answer_ends_with_a_newline(live_server: LiveServer) -> None:
    """``curl`` leaves the prompt on its own line: every JSON body ends in one newline, and
    Content-Length counts it."""
    with httpx.Client(base_url=live_server.url) as http:
        answers = [http.get("/healthz"), http.get("/openapi.json"), http.get("/skills"),
                   http.post("/skills", json={"name": "nl", "dim": 3}),
                   http.get("/skills/nl"),
                   http.post("/skills/nl/demonstrations",
                             json={"positions": demo_positions(0).tolist()}),
                   http.get("/skills/no-such-skill"),  # 404, an error body
                   http.post("/skills", json={"name": "bad", "dim": 7})]  # 422
        for r in answers:
            assert r.headers["content-type"].startswith("application/json"), r.request.url
            assert r.content.endswith(b"}\n") or r.content.endswith(b"]\n"), r.request.url
            assert not r.content.endswith(b"\n\n")
            assert int(r.headers["content-length"]) == len(r.content)
        assert {r.status_code for r in answers} >= {200, 201, 404, 422}
        assert not http.get("/metrics").content.endswith(b"}\n")  # text, untouched


def _raw_post(port: int, path: str, headers: list[str], body_chunks: list[bytes]) -> bytes:
    """Send a request by hand (to control Content-Length and chunking) and read the reply."""
    with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
        head = "\r\n".join([f"POST {path} HTTP/1.1", "Host: 127.0.0.1", *headers, "", ""])
        s.sendall(head.encode())
        try:
            for chunk in body_chunks:
                s.sendall(chunk)
        except (BrokenPipeError, ConnectionResetError):
            pass  # the server may answer 413 and close before reading everything
        data = b""
        while b"\r\n\r\n" not in data or not data.rstrip().endswith(b"}"):
            part = s.recv(65536)
            if not part:
                break
            data += part
        return data


def test_a_json_route_sent_another_content_type_is_415(live_server: LiveServer) -> None:
    """A JSON route's body in another content type (text/plain, curl -d's form encoding) or
    with none is refused as 415 naming the content type that came, and nothing is stored; a
    JSON body, with or without a charset, is read as before."""
    with httpx.Client(base_url=live_server.url) as http:
        assert http.post("/skills", json={"name": "pour", "dim": 3}).status_code == 201
        for j in range(3):
            http.post("/skills/pour/demonstrations", json={"positions": demo_positions(j).tolist()})
        for content_type in ("text/plain", "text/plain; charset=utf-8",
                             "application/x-www-form-urlencoded", "application/xml", None):
            for method, path, body in (
                ("POST", "/skills", b'{"name": "other", "dim": 3}'),
                ("POST", "/skills/pour/fit", b"{}"),
                ("POST", "/skills/pour/fit", b"null"),
                ("POST", "/skills/pour/reproductions", b'{"start": [0, 0, 0]}'),
                ("PUT", "/skills/pour/scene", b'{"obstacles": []}'),
                ("POST", "/skills/pour/corrections", b'{"kind": "include", "samples": [[0, 0, 0]]}'),
            ):
                headers = {} if content_type is None else {"content-type": content_type}
                r = http.request(method, path, content=body, headers=headers)
                assert r.status_code == 415, (content_type, path, r.text)
                error = r.json()["error"]
                assert error["type"] == "unsupported_media_type" and error["field"] == "Content-Type"
                came = repr(content_type or "none")
                assert f"expected Content-Type application/json, got {came}" in error["message"], error
        assert http.get("/skills/pour").json()["n_models"] == 0
        assert [s["name"] for s in http.get("/skills").json()["items"]] == ["pour"]
        assert http.get("/skills/pour/scene").json()["version"] == 0
        # JSON as it is usually labelled still works, and a fit without a body takes the defaults
        for content_type in ("application/json", "application/json; charset=utf-8"):
            r = http.post("/skills", content=b'{"name": "x-%d", "dim": 3}' % len(content_type),
                          headers={"content-type": content_type})
            assert r.status_code == 201, (content_type, r.text)
        assert http.post("/skills/pour/fit").status_code == 201
        # a bad JSON body is still a 422 naming its field
        r = http.post("/skills", json={"name": "bad", "dim": 7})
        assert r.status_code == 422 and r.json()["error"]["field"] == "dim", r.text


def test_body_over_the_limit_is_413_and_nothing_stored(tmp_path: Path) -> None:
    settings = Settings(data_dir=tmp_path / "d", recordings_enabled=False, zenoh_enabled=False, max_body_bytes=10_000)
    with LiveServer(create_app(settings)) as server, httpx.Client(base_url=server.url) as http:
        http.post("/skills", json={"name": "pour", "dim": 3})
        big = {"positions": demo_positions(0, n=2000).tolist()}
        # declared too large: refused before the body is read
        r = http.post("/skills/pour/demonstrations", json=big)
        assert r.status_code == 413
        assert r.json()["error"]["type"] == "payload_too_large"
        assert r.json()["error"]["field"] == "body"
        # chunked, no Content-Length: cut off once the stream passes the limit
        reply = _raw_post(server.port, "/skills/pour/demonstrations",
                          ["Content-Type: application/json", "Transfer-Encoding: chunked"],
                          [f"{len(c):x}\r\n".encode() + c + b"\r\n"
                           for c in [b"{" + b" " * 4000] * 4] + [b"0\r\n\r\n"])
        assert reply.startswith(b"HTTP/1.1 413"), reply[:200]
        assert b'"payload_too_large"' in reply
        # same for a multipart upload and for the fit body
        files = {"file": ("a.csv", b"x,y,z\n" + b"1,2,3\n" * 3000)}
        assert http.post("/skills/pour/demonstrations", files=files).status_code == 413
        assert http.post("/skills/pour/fit", content=b"{" + b" " * 20000 + b"}",
                         headers={"content-type": "application/json"}).status_code == 413
        small = {"positions": demo_positions(0, n=20).tolist()}
        assert http.post("/skills/pour/demonstrations", json=small).status_code == 201
        assert http.get("/skills/pour").json()["n_demonstrations"] == 1


def test_default_limit_is_64_mib() -> None:
    assert Settings().max_body_bytes == 64 * 1024 * 1024


def test_bearer_token_on_every_route_but_health(tmp_path: Path) -> None:
    settings = Settings(data_dir=tmp_path / "d", recordings_enabled=False, zenoh_enabled=False, token="s3cret")
    with LiveServer(create_app(settings)) as server, httpx.Client(base_url=server.url) as http:
        assert http.get("/healthz").status_code == 200
        for method, path in [("GET", "/skills"), ("POST", "/skills"), ("GET", "/metrics"),
                             ("GET", "/openapi.json"), ("GET", "/docs"),
                             ("GET", "/skills/x/models/latest")]:
            r = http.request(method, path, json={"name": "a", "dim": 3})
            assert r.status_code == 401, (method, path)
            assert r.json()["error"]["field"] == "Authorization"
            assert r.headers["www-authenticate"] == "Bearer"
        wrong = http.get("/skills", headers={"authorization": "Bearer nope"})
        assert wrong.status_code == 401
        ok = {"authorization": "Bearer s3cret"}
        assert http.post("/skills", json={"name": "a", "dim": 3}, headers=ok).status_code == 201
        assert http.get("/skills", headers=ok).json()["total"] == 1
        spec = http.get("/openapi.json", headers=ok).json()
        assert spec["components"]["securitySchemes"]["bearer"]["scheme"] == "bearer"


def test_the_bearer_scheme_is_taken_in_any_case(tmp_path: Path) -> None:
    # RFC 9110 11.1: the scheme is case-insensitive; "bearer s3cret" was a 401.
    settings = Settings(data_dir=tmp_path / "d", recordings_enabled=False, zenoh_enabled=False,
                        token="s3cret")
    with LiveServer(create_app(settings)) as server, httpx.Client(base_url=server.url) as http:
        for given in ("bearer s3cret", "BEARER s3cret", "bEaReR s3cret", "Bearer   s3cret"):
            r = http.get("/skills", headers={"authorization": given})
            assert r.status_code == 200, (given, r.text)
        for given in ("bearer S3CRET", "bearer s3cre", "Basic s3cret", "bearers3cret",
                      "bearer", "s3cret", "bearer s3cret x"):
            r = http.get("/skills", headers={"authorization": given})
            assert r.status_code == 401, (given, r.text)
        assert http.get("/skills").json()["error"]["field"] == "Authorization"


def test_cors_off_by_default_and_on_when_configured(tmp_path: Path) -> None:
    origin = {"origin": "http://localhost:5173", "access-control-request-method": "GET"}
    off = Settings(data_dir=tmp_path / "a", recordings_enabled=False, zenoh_enabled=False)
    with LiveServer(create_app(off)) as server:
        r = httpx.options(f"{server.url}/skills", headers=origin)
        assert "access-control-allow-origin" not in r.headers
    on = Settings(data_dir=tmp_path / "b", recordings_enabled=False, zenoh_enabled=False,
                  cors_origins=["http://localhost:5173"])
    with LiveServer(create_app(on)) as server:
        r = httpx.options(f"{server.url}/skills", headers=origin)
        assert r.headers["access-control-allow-origin"] == "http://localhost:5173"


def test_flags_and_env(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    assert settings_from_args([]).host == "127.0.0.1"
    assert settings_from_args([]).port == 8000
    monkeypatch.setenv("CANAL_PORT", "9001")
    monkeypatch.setenv("CANAL_TOKEN", "")
    s = settings_from_args(["--data-dir", str(tmp_path), "--no-recordings",
                            "--cors-origin", "http://a", "--max-body-bytes", "1000"])
    assert s.port == 9001 and s.data_dir == tmp_path and not s.recordings_enabled
    assert s.cors_origins == ["http://a"] and s.max_body_bytes == 1000 and s.token is None
    assert s.resolved_database_url == f"sqlite:///{(tmp_path / 'canal.sqlite3').resolve()}"
    assert settings_from_args(["--port", "1234"]).port == 1234


def test_python_m_canal_service_starts_on_embedded_defaults(tmp_path: Path) -> None:
    port = free_port()
    env = {**os.environ, "CANAL_PORT": str(port), "CANAL_LOG_LEVEL": "warning"}
    proc = subprocess.Popen([sys.executable, "-m", "canal_service"], cwd=tmp_path, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + 30
        while True:
            try:
                r = httpx.get(f"http://127.0.0.1:{port}/healthz", timeout=1)
                if r.json()["status"] != "starting":  # 503 starting while the app loads
                    break
            except httpx.TransportError:
                pass
            assert proc.poll() is None, proc.stdout.read() if proc.stdout else ""
            assert time.monotonic() < deadline, "service did not start"
            time.sleep(0.1)
        assert r.status_code in (200, 503)
        assert r.json()["database"] == "ok"
        assert (tmp_path / "data" / "canal.sqlite3").exists()
    finally:
        proc.terminate()
        proc.wait(10)
