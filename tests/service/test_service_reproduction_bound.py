"""Reproductions are bounded over real HTTP: a request that outlives
``CANAL_REPRODUCE_MAX_SECONDS`` is stopped, between its starts or inside one start's detour
search (422 reproduction_too_slow), and a batch whose client leaves stops too. Starts among
many spheres cost a detour each."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest
from canal_service.app import create_app
from canal_service.core.config import Settings
from service_helpers import LiveServer

CAP = 0.5


def _demos() -> list[list[list[float]]]:
    x = np.linspace(0.0, 1.0, 80)
    out = []
    for j in range(5):
        a = 2.0 * np.pi * j / 5
        out.append(np.column_stack([x, 0.06 * np.cos(a) + 0.012 * np.sin(7 * x + j),
                                    0.06 * np.sin(a) + 0.012 * np.cos(9 * x + 2 * j)]).tolist())
    return out


SPHERES = [{"kind": "sphere", "center": [0.1 + 0.8 * i / 64, 0.03 * np.cos(i), 0.03 * np.sin(i)],
            "radius": 0.012, "clearance": 0.003} for i in range(64)]
STARTS = [[0.0, 0.03 * np.cos(i), 0.03 * np.sin(i)] for i in range(40)]


def _serving(data: Path, cap: float) -> Iterator[str]:
    settings = Settings(data_dir=data, recordings_enabled=False, zenoh_enabled=False,
                        reproduce_max_seconds=cap)
    with LiveServer(create_app(settings)) as server, httpx.Client(base_url=server.url, timeout=120) as http:
        assert http.post("/skills", json={"name": "among-spheres", "dim": 3}).status_code == 201
        for demo in _demos():
            assert http.post("/skills/among-spheres/demonstrations", json={"positions": demo}).status_code == 201
        assert http.post("/skills/among-spheres/fit", json={"n_samples": 200}).status_code == 201
        yield server.url


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    yield from _serving(Path(tmp_path_factory.mktemp("reprobound")) / "data", CAP)


@pytest.fixture(scope="module")
def served_uncapped(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    yield from _serving(Path(tmp_path_factory.mktemp("reprobound-long")) / "data", 600.0)


def _stopped(http: httpx.Client, reason: str) -> float:
    for line in http.get("/metrics").text.splitlines():
        if line.startswith("canal_reproductions_stopped_total") and f'reason="{reason}"' in line:
            return float(line.split()[-1])
    return 0.0


def test_a_request_beyond_the_cap_is_stopped(served: str) -> None:
    with httpx.Client(base_url=served, timeout=120) as http:
        r = http.post("/skills/among-spheres/reproductions", json={"starts": STARTS, "obstacles": SPHERES})
        assert r.status_code == 422, r.text
        error = r.json()["error"]
        # Between two starts (the batch) or inside one (that start), by the machine's pace.
        assert error["type"] == "reproduction_too_slow"
        assert error["field"] == "starts" or error["field"].startswith("starts["), error
        assert "CANAL_REPRODUCE_MAX_SECONDS" in error["message"]
        assert _stopped(http, "too_slow") == 1.0
        # One start among 64 spheres (seconds of detour search) is cut short too, inside its
        # search, and says so on its own field.
        r = http.post("/skills/among-spheres/reproductions", json={"start": STARTS[0], "obstacles": SPHERES})
        assert r.status_code == 422, r.text
        error = r.json()["error"]
        assert error["type"] == "reproduction_too_slow" and error["field"] == "start"
        assert _stopped(http, "too_slow") == 2.0
        # Without obstacles it is far within the cap.
        r = http.post("/skills/among-spheres/reproductions", json={"start": STARTS[0]})
        assert r.status_code == 200, r.text


def test_a_batch_whose_client_leaves_is_stopped(served_uncapped: str) -> None:
    served = served_uncapped
    with httpx.Client(base_url=served, timeout=120) as http:
        before = _stopped(http, "client_left")
        with pytest.raises(httpx.TimeoutException):
            httpx.post(f"{served}/skills/among-spheres/reproductions",
                       json={"starts": STARTS[:3] * 10, "obstacles": SPHERES[:8]}, timeout=0.2)
        deadline = time.monotonic() + 60.0
        while _stopped(http, "client_left") == before and time.monotonic() < deadline:
            time.sleep(0.1)
        assert _stopped(http, "client_left") == before + 1.0
