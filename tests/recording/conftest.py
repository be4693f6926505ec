"""Fixtures for the recorder tests: real canals (canal_core.fit), a recorder on a temp root."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from canal_service.recording import Recorder
from canal_service.recording.rerun_log import cli_env
from recording_helpers import helix_demo

import canal_core


@pytest.fixture(scope="session")
def demos3() -> list[np.ndarray]:
    return [helix_demo(k) for k in range(3)]


@pytest.fixture(scope="session")
def canal3(demos3: list[np.ndarray]) -> Any:
    return canal_core.fit(demos3, n_samples=80)


@pytest.fixture(scope="session")
def canal2() -> Any:
    return canal_core.fit([helix_demo(k, dim=2) for k in range(3)], n_samples=50)


@pytest.fixture(scope="session")
def rerun_env(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """Environment for ``rerun`` CLI calls with analytics disabled."""
    return cli_env(tmp_path_factory.mktemp("rerun-config"))


@pytest.fixture
def recorder(tmp_path: Path) -> Iterator[Recorder]:
    rec = Recorder(tmp_path / "rec", flush_interval_s=0.1, live_max_hz=None)
    yield rec
    rec.close()


