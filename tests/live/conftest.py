"""Fixtures for the live bridge tests: a real app (SQLite file, real Zenoh on a free loopback
port), skills fitted through the REST API, robots as real Zenoh sessions."""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    from fastapi.testclient import TestClient

from canal_service.app import create_app
from canal_service.core.config import Settings
from canal_testing import free_port
from live_helpers import Live, make_skill

os.environ.setdefault("RERUN_TELEMETRY_ENABLED", "false")


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    """One app per module, recordings on, bridge on a free port, skills 'arc3' (3-D),
    'arc2' (2-D) and 'empty' (no model)."""
    data: Path = tmp_path_factory.mktemp("live")
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    # The bridge in this process (zenoh_processes=0) so tests can look inside it;
    # test_live_processes.py covers the default, bridge processes of their own.
    settings = Settings(data_dir=data, recordings_enabled=True, zenoh_listen=[endpoint],
                        zenoh_refresh_s=0.2, zenoh_processes=0)
    with TestClient(create_app(settings)) as client:
        make_skill(client, "arc3", 3)
        make_skill(client, "arc2", 2)
        make_skill(client, "empty", 3, fit=False)
        yield Live(client, endpoint, settings)
        bridge: Any = client.app.state.bridge  # type: ignore[attr-defined]
    assert bridge.session is None, "the bridge's Zenoh session is still open"
    assert not any(t.is_alive() for t in bridge._threads)
