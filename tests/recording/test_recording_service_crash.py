"""kill -9 a real ``canal serve`` right after acknowledged uploads: after a restart the
recording holds every acknowledged demonstration (the database is the source of truth)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx
import numpy as np
import orjson
from canal_testing import free_port
from recording_helpers import helix_demo, mcap_messages, rrd_rows


def _serve(data: Path, port: int) -> subprocess.Popen[bytes]:
    env = dict(os.environ, RERUN_TELEMETRY_ENABLED="false")
    return subprocess.Popen(
        [sys.executable, "-m", "canal_service", "--port", str(port), "--data-dir", str(data),
         "--no-zenoh", "--log-level", "warning"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)


def _wait_up(client: httpx.Client, proc: subprocess.Popen[bytes]) -> None:
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        assert proc.poll() is None, proc.stderr.read() if proc.stderr else b""
        try:
            if client.get("/healthz").status_code in (200, 503):
                return
        except httpx.TransportError:
            pass
        time.sleep(0.1)
    raise AssertionError("the service did not start")


def test_kill9_right_after_acknowledged_uploads_loses_no_demo(
        tmp_path: Path, rerun_env: dict[str, str]) -> None:
    data, port = tmp_path / "data", free_port()
    url = f"http://127.0.0.1:{port}"
    proc = _serve(data, port)
    acknowledged: list[int] = []
    try:
        with httpx.Client(base_url=url, timeout=30) as c:
            _wait_up(c, proc)
            assert c.post("/skills", json={"name": "pour", "dim": 3}).status_code == 201
            for k in range(40):
                r = c.post("/skills/pour/demonstrations",
                           json={"positions": helix_demo(k, n=200).tolist(), "label": f"t{k}"})
                assert r.status_code == 201
                acknowledged.append(r.json()["id"])
            # Killed right away: most of these have not reached the recording files yet.
            proc.send_signal(signal.SIGKILL)
            proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()

    proc = _serve(data, port)
    try:
        with httpx.Client(base_url=url, timeout=120) as c:
            _wait_up(c, proc)
            mcap = tmp_path / "pour.mcap"
            r = c.get("/skills/pour/recording.mcap")
            assert r.status_code == 200
            mcap.write_bytes(r.content)
            rrd = tmp_path / "pour.rrd"
            rrd.write_bytes(c.get("/skills/pour/recording.rrd").content)
            health = c.get("/healthz").json()["recorder"]
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()

    recorded = {int(e["id"].split("/")[1]) for m in mcap_messages(mcap, "/canal/demos")
                for e in m["entities"]}
    assert recorded >= set(acknowledged), sorted(set(acknowledged) - recorded)
    rows = rrd_rows(rrd, rerun_env)
    for demo_id in acknowledged:
        assert rows[(f"/demos/{demo_id}/path", "LineStrips3D:strips")] >= 1, demo_id
    # The demo arrays in the recording are the stored ones.
    first = next(e for m in mcap_messages(mcap, "/canal/demos") for e in m["entities"]
                 if e["id"] == f"demo/{acknowledged[-1]}")
    pts = np.array([[p["x"], p["y"], p["z"]] for p in first["lines"][0]["points"]])
    assert np.allclose(pts, helix_demo(39, n=200))
    assert health["status"] == "ok", orjson.dumps(health)
