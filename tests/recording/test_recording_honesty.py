"""What a recording cannot hold in full is left out whole and counted (``incomplete`` in the
recorder's health, so in /healthz), never written as a timeline with null times."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from canal_service.app import create_app
from canal_service.core.config import Settings
from canal_service.recording import Recorder
from canal_testing import LiveServer, arc_demo
from recording_helpers import rrd_rows, rrd_verify

from canal_core import bounds


@pytest.mark.parametrize("span", [1e12, 1e308])
def test_a_reproduction_whose_times_overflow_nanoseconds_is_counted_incomplete(
        recorder: Recorder, demos3: list[np.ndarray], canal3: Any, rerun_env: dict[str, str],
        span: float) -> None:
    base = canal3.reproduce_detailed(demos3[0][0])
    n = len(base.positions)
    recorder.reproduction("pour", 1, replace(base, times=np.linspace(0.0, 3.0, n)))
    recorder.reproduction("pour", 1, replace(base, times=np.linspace(0.0, span, n)))
    path = recorder.export_rrd("pour")
    health = recorder.health()
    assert health["incomplete"] == 1 and health["status"] == "ok"
    assert rrd_verify(path, rerun_env).returncode == 0
    rows = rrd_rows(path, rerun_env)
    assert rows[("/reproductions/1/point", "Points3D:positions")] == n
    # the second is there without the timeline it could not have, not with null times
    assert rows[("/reproductions/2/path", "LineStrips3D:strips")] == 1
    assert rows[("/reproductions/2/point", "Points3D:positions")] == 0


def test_over_http_a_huge_duration_is_refused_and_the_longest_is_recorded_whole(
        tmp_path: Path, rerun_env: dict[str, str]) -> None:
    settings = Settings(data_dir=tmp_path / "data", recordings_enabled=True, zenoh_enabled=False)
    with LiveServer(create_app(settings)) as server, httpx.Client(base_url=server.url,
                                                                  timeout=60) as http:
        assert http.post("/skills", json={"name": "pour", "dim": 3}).status_code == 201
        for j in range(3):
            positions = arc_demo(j, 50)
            r = http.post("/skills/pour/demonstrations", json={
                "positions": positions.tolist(),
                "timestamps": np.linspace(0.0, 2.0, len(positions)).tolist()})
            assert r.status_code == 201
        assert http.post("/skills/pour/fit", json={"n_samples": 30}).status_code == 201
        for duration in (1e12, 1e308):
            r = http.post("/skills/pour/reproductions",
                          json={"start": [0, 0, 0], "duration": duration})
            assert r.status_code == 422 and r.json()["error"]["field"] == "duration", r.text
        r = http.post("/skills/pour/reproductions",
                      json={"start": [0, 0, 0], "duration": bounds.MAX_DURATION})
        assert r.status_code == 200, r.text
        n = len(r.json()["positions"])
        rrd = tmp_path / "pour.rrd"
        rrd.write_bytes(http.get("/skills/pour/recording.rrd").content)
        assert http.get("/healthz").json()["recorder"]["incomplete"] == 0
    rows = rrd_rows(rrd, rerun_env)
    assert rows[("/reproductions/1/point", "Points3D:positions")] == n
    assert rows[("/reproductions/2/point", "Points3D:positions")] == 0
