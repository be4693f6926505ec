"""Fixtures for the client tests: one real service (recordings on) for the session, real
SQLite in a temp folder, and a fresh skill name per test."""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterator

import pytest
from canal_client import CanalClient
from canal_live import LiveService, demo_positions

_names = itertools.count()


@pytest.fixture(scope="session")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveService]:
    with LiveService(tmp_path_factory.mktemp("client-service") / "data",
                     recordings_enabled=True) as live:
        yield live


@pytest.fixture
def client(service: LiveService) -> Iterator[CanalClient]:
    with CanalClient(service.url) as c:
        yield c


@pytest.fixture
def unique_name() -> Callable[[str], str]:
    """Skill names unique within the session (the service is shared)."""
    return lambda prefix="skill": f"{prefix}-{next(_names)}"


@pytest.fixture
def fitted(client: CanalClient, unique_name: Callable[[str], str]) -> str:
    """A 3-D skill with four demonstrations and one fitted model (version 1)."""
    name = unique_name("fitted")
    client.create_skill(name, dim=3)
    for j in range(4):
        client.add_demo(name, demo_positions(j))
    client.fit(name, n_samples=30)
    return name
