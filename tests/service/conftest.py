"""Fixtures for the service tests: real SQLite files, real uvicorn on loopback, real PostgreSQL
when the server binaries are on this machine."""

from __future__ import annotations

import contextlib
import os
import shutil
import socket
import subprocess
import tempfile
import threading
import time
import uuid
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

with warnings.catch_warnings():
    # starlette 1.x warns that its TestClient will move to httpx2; the client still works.
    warnings.simplefilter("ignore")
    from fastapi.testclient import TestClient

import uvicorn
from canal_service.app import create_app
from canal_service.core.config import Settings

os.environ.setdefault("RERUN_TELEMETRY_ENABLED", "false")


# ---- data -------------------------------------------------------------------------------------


def demo_positions(j: int, n: int = 50, dim: int = 3, seed: int = 0) -> np.ndarray:
    """A smooth arc, shifted a little per demonstration so the canal has a real radius."""
    rng = np.random.default_rng(seed + j)
    t = np.linspace(0.0, 1.0, n)
    offset = 0.02 * (j - 1.5)
    x = t
    y = 0.3 * np.sin(np.pi * t) + offset + 0.002 * rng.standard_normal(n)
    if dim == 2:
        return np.column_stack([x, y])
    z = 0.1 * t + 0.5 * offset * np.cos(np.pi * t) + 0.002 * rng.standard_normal(n)
    return np.column_stack([x, y, z])


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


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class LiveServer:
    """uvicorn serving an app on 127.0.0.1 in a background thread."""

    def __init__(self, app: Any) -> None:
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        config = uvicorn.Config(app, host="127.0.0.1", port=self.port, log_level="warning",
                                lifespan="on")
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(target=self.server.run, daemon=True)

    def __enter__(self) -> LiveServer:
        self.thread.start()
        deadline = time.monotonic() + 10
        while not self.server.started:
            if time.monotonic() > deadline or not self.thread.is_alive():
                raise RuntimeError("uvicorn did not start")
            time.sleep(0.01)
        return self

    def __exit__(self, *exc: object) -> None:
        self.server.should_exit = True
        self.thread.join(10)


@pytest.fixture
def live_server(settings: Settings) -> Iterator[LiveServer]:
    with LiveServer(create_app(settings)) as server:
        yield server


# ---- PostgreSQL -------------------------------------------------------------------------------


class PostgresServer:
    """A throwaway PostgreSQL cluster owned by the 'postgres' user (the server refuses root)."""

    def __init__(self) -> None:
        self.dir = Path(tempfile.mkdtemp(prefix="canal-pg-"))
        self.port = free_port()
        self.started = False

    def _as_postgres(self, *cmd: str) -> subprocess.CompletedProcess[str]:
        prefix: list[str] = []
        if os.geteuid() == 0:
            prefix = ["runuser", "-u", "postgres", "--"]
        return subprocess.run([*prefix, *cmd], capture_output=True, text=True, timeout=60,
                              check=True)

    def start(self) -> None:
        if os.geteuid() == 0:
            shutil.chown(self.dir, "postgres", "postgres")
        data = self.dir / "data"
        self._as_postgres("initdb", "-D", str(data), "-A", "trust", "-U", "canal",
                          "--no-sync")
        self._as_postgres(
            "pg_ctl", "-D", str(data), "-o",
            f"-k {self.dir} -p {self.port} -h 127.0.0.1 -F", "-l", str(self.dir / "log"),
            "-w", "start",
        )
        self.started = True

    def stop(self) -> None:
        if self.started:
            with contextlib.suppress(Exception):
                self._as_postgres("pg_ctl", "-D", str(self.dir / "data"), "-m", "fast", "-w",
                                  "stop")
        shutil.rmtree(self.dir, ignore_errors=True)

    def new_database(self) -> str:
        import psycopg

        name = f"t_{uuid.uuid4().hex[:12]}"
        with psycopg.connect(f"postgresql://canal@127.0.0.1:{self.port}/postgres",
                             autocommit=True) as conn:
            conn.execute(f'CREATE DATABASE "{name}"')
        return f"postgresql+psycopg://canal@127.0.0.1:{self.port}/{name}"


@pytest.fixture(scope="session")
def postgres_server() -> Iterator[PostgresServer]:
    missing = [b for b in ("initdb", "pg_ctl", "postgres") if shutil.which(b) is None]
    if missing:
        pytest.skip(f"PostgreSQL server binaries not found: {', '.join(missing)}")
    if os.geteuid() == 0 and shutil.which("runuser") is None:
        pytest.skip("running as root without runuser: cannot start PostgreSQL as 'postgres'")
    server = PostgresServer()
    try:
        server.start()
    except (subprocess.CalledProcessError, subprocess.TimeoutExpired, KeyError, OSError) as exc:
        detail = getattr(exc, "stderr", "") or str(exc)
        server.stop()
        pytest.skip(f"could not start a PostgreSQL server: {detail.strip()[:300]}")
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
