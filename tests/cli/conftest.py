"""Fixtures for the ``canal`` command-line tests: one real service (recordings on) for the
session on a free loopback port, and a runner that points the CLI at it."""

from __future__ import annotations

import itertools
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from click.testing import Result
from typer.testing import CliRunner

# The live-service helpers are shared with the client tests.
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "client"))

from canal_client.cli import app
from canal_live import LiveService

_names = itertools.count()

Run = Callable[..., Result]


@pytest.fixture(scope="session")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveService]:
    with LiveService(tmp_path_factory.mktemp("cli-service") / "data",
                     recordings_enabled=True) as live:
        yield live


@pytest.fixture
def run(service: LiveService, tmp_path: Path) -> Run:
    """``run("skill", "list")`` runs ``canal skill list`` against the session's service."""

    def invoke(*args: str, url: str | None = None, input: str | None = None,
               env: dict[str, str] | None = None) -> Result:
        full_env = {"CANAL_URL": url or service.url, "CANAL_TOKEN": "",
                    "CANAL_CACHE_DIR": str(tmp_path / "cache"), "COLUMNS": "200"}
        full_env.update(env or {})
        return CliRunner().invoke(app, list(args), input=input, env=full_env)

    return invoke


@pytest.fixture
def unique_name() -> Callable[[str], str]:
    return lambda prefix="skill": f"cli-{prefix}-{next(_names)}"
