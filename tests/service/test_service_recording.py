"""Recorder wiring: exports stream as files, health shows the recorder.

Needs ``canal_service.recording`` (written separately); skipped with a reason until it exists.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from canal_service.app import create_app
from canal_service.core.config import Settings
from fastapi.testclient import TestClient
from service_helpers import demo_positions


def test_recordings_disabled_is_a_clean_404(client: TestClient, skill: str) -> None:
    for kind in ("rrd", "mcap"):
        r = client.get(f"/skills/{skill}/recording.{kind}")
        assert r.status_code == 404 and r.json()["error"]["type"] == "disabled"
    assert client.get("/healthz").json()["recorder"]["status"] == "disabled"


def test_recording_exports(tmp_path: Path) -> None:
    pytest.importorskip("canal_service.recording",
                        reason="canal_service.recording (the Recorder) is not importable yet")
    settings = Settings(data_dir=tmp_path / "data", recordings_enabled=True, zenoh_enabled=False)
    with TestClient(create_app(settings)) as c:
        health = c.get("/healthz").json()
        assert health["recorder"]["status"] in ("ok", "degraded")
        c.post("/skills", json={"name": "pour", "dim": 3})
        ids = [c.post("/skills/pour/demonstrations",
                      json={"positions": demo_positions(j).tolist()}).json()["id"]
               for j in range(3)]
        assert c.post("/skills/pour/fit", json={"n_samples": 30}).status_code == 201
        assert c.post("/skills/pour/reproductions", json={"start": [0, 0, 0]}).status_code == 200
        assert c.delete(f"/skills/pour/demonstrations/{ids[0]}").status_code == 204
        rrd = c.get("/skills/pour/recording.rrd")
        assert rrd.status_code == 200 and len(rrd.content) > 0
        mcap = c.get("/skills/pour/recording.mcap")
        assert mcap.status_code == 200 and mcap.content.startswith(b"\x89MCAP0\r\n")
        assert c.get("/skills/nope/recording.rrd").status_code == 404
    assert settings.resolved_recordings_dir.exists()
