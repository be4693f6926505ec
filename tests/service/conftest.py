"""Fixtures for the service tests: real SQLite files, real uvicorn on loopback, real PostgreSQL
when the server binaries are on this machine."""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

with warnings.catch_warnings():
    # starlette 1.x warns that its TestClient will move to httpx2; the client still works.
    warnings.simplefilter("ignore")
    from fastapi.testclient import TestClient

from canal_service.app import create_app
from canal_service.core.config import Settings
from service_helpers import LiveServer, PostgresServer, demo_positions

os.environ.setdefault("RERUN_TELEMETRY_ENABLED", "false")


# ---- data -------------------------------------------------------------------------------------


@pytest.fixture
def make_demo() -> Callable[..., np.ndarray]:
    return demo_positions


# ---- apps -------------------------------------------------------------------------------------


@pytest.fixture
def settings(tmp_path: Path) -> Settings:
    """Embedded defaults in a temp data folder, recordings off (tests that want them say so)."""
    return Settings(data_dir=tmp_path / "data", recordings_enabled=False, zenoh_enabled=False)


@pytest.fixture
def client(settings: Settings) -> Iterator[TestClient]:
    with TestClient(create_app(settings)) as c:
        yield c


def make_client(settings: Settings) -> contextlib.AbstractContextManager[TestClient]:
    return TestClient(create_app(settings))


@pytest.fixture
def skill(client: TestClient) -> str:
    """A 3-D skill named 'pour'."""
    r = client.post("/skills", json={"name": "pour", "description": "pour water", "dim": 3})
    assert r.status_code == 201, r.text
    return "pour"


@pytest.fixture
def fitted(client: TestClient, skill: str) -> str:
    """'pour' with four demonstrations and one fitted model (version 1)."""
    for j in range(4):
        r = client.post(f"/skills/{skill}/demonstrations",
                        json={"positions": demo_positions(j).tolist(), "label": f"demo {j}"})
        assert r.status_code == 201, r.text
    r = client.post(f"/skills/{skill}/fit", json={"n_samples": 50})
    assert r.status_code == 201, r.text
    return skill


# ---- real HTTP --------------------------------------------------------------------------------


@pytest.fixture
def live_server(settings: Settings) -> Iterator[LiveServer]:
    with LiveServer(create_app(settings)) as server:
        yield server


# ---- PostgreSQL -------------------------------------------------------------------------------


@pytest.fixture(scope="session")
def postgres_server() -> Iterator[PostgresServer]:
    missing = [b for b in ("initdb", "pg_ctl", "postgres") if shutil.which(b) is None]
    if missing:
        pytest.skip(f"needs the PostgreSQL server binaries on PATH (missing: {', '.join(missing)})")
    if os.geteuid() == 0 and shutil.which("runuser") is None:
        pytest.skip("needs runuser to start PostgreSQL as 'postgres' when running as root")
    server = PostgresServer()
    try:
        server.start()
    except (subprocess.CalledProcessError, subprocess.TimeoutExpired, KeyError, OSError) as exc:
        detail = getattr(exc, "stderr", "") or str(exc)
        server.stop()
        # the binaries are here, so a server that does not start is a failure, not a skip
        pytest.fail(f"could not start a PostgreSQL server: {detail.strip()[:300]}")
    yield server
    server.stop()


@pytest.fixture(params=["sqlite", pytest.param("postgres", marks=pytest.mark.postgres)])
def any_db_settings(request: pytest.FixtureRequest, tmp_path: Path) -> Settings:
    """Settings on SQLite, and on PostgreSQL when a server can be started here."""
    if request.param == "sqlite":
        return Settings(data_dir=tmp_path / "data", recordings_enabled=False, zenoh_enabled=False)
    server: PostgresServer = request.getfixturevalue("postgres_server")
    return Settings(data_dir=tmp_path / "data", recordings_enabled=False, zenoh_enabled=False,
                    database_url=server.new_database())


@pytest.fixture
def any_db_client(any_db_settings: Settings) -> Iterator[TestClient]:
    with TestClient(create_app(any_db_settings)) as c:
        yield c
