"""A real service (uvicorn on 127.0.0.1) holding one fitted skill, and one headless Chromium."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from canal_client import CanalClient
from canal_service.app import create_app
from canal_service.core.config import Settings
from canal_testing import LiveServer, arc_demo
from chromium import Chromium

SKILL = "stir"


@pytest.fixture(scope="module")
def service_url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """The service's URL; skill ``stir`` has four demos, a canal and one reproduction."""
    data = Path(tmp_path_factory.mktemp("browser-service"))
    app = create_app(Settings(data_dir=data, zenoh_enabled=False))
    with LiveServer(app) as server, CanalClient(server.url) as client:
        client.create_skill(SKILL)
        for j in range(4):
            client.add_demo(SKILL, arc_demo(j, 60, spread=0.05))
        client.fit(SKILL)
        client.reproduce(SKILL, np.array([0.0, 0.02, 0.0]))
        yield server.url


@pytest.fixture(scope="module")
def skill() -> str:
    """The skill ``service_url`` holds."""
    return SKILL


@pytest.fixture(scope="module")
def browser() -> Iterator[Chromium]:
    with Chromium() as chromium:
        yield chromium
