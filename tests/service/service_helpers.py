"""Helpers shared by the service tests: demo data, a real uvicorn on loopback, a throwaway
PostgreSQL cluster. A module of its own: every test folder has a conftest.py, so
``from conftest import`` would be ambiguous."""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import tempfile
import uuid
from pathlib import Path

import numpy as np
from canal_testing import LiveServer, arc_demo, free_port

__all__ = ["LiveServer", "PostgresServer", "demo_positions", "free_port"]


def demo_positions(j: int, n: int = 50, dim: int = 3, seed: int = 0) -> np.ndarray:
    """A smooth arc, shifted by 0.02 per demonstration."""
    return arc_demo(j, n, dim, seed, spread=0.02)


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

    def new_database(self, options: str = "") -> str:
        """A new empty database's URL; ``options`` follow CREATE DATABASE (an encoding)."""
        import psycopg

        name = f"t_{uuid.uuid4().hex[:12]}"
        with psycopg.connect(f"postgresql://canal@127.0.0.1:{self.port}/postgres",
                             autocommit=True) as conn:
            conn.execute(f'CREATE DATABASE "{name}" {options}')
        return f"postgresql+psycopg://canal@127.0.0.1:{self.port}/{name}"
