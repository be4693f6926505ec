"""Helpers for the live bridge tests (a module of its own: several test folders have a
conftest.py, so ``from conftest import`` would be ambiguous)."""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np

with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    from fastapi.testclient import TestClient

from canal_service.core.config import Settings
from canal_testing import arc_demo


def wait_until(predicate: Callable[[], Any], timeout: float = 10.0) -> Any:
    """Poll ``predicate`` every 10 ms until it returns something truthy (returned) or
    ``timeout`` seconds pass (its last value is returned)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.01)
    return predicate()


def arc(j: int, n: int = 60, dim: int = 3, seed: int = 0) -> np.ndarray:
    """A smooth arc, shifted by 0.03 per demonstration."""
    return arc_demo(j, n, dim, seed, spread=0.03)


def make_skill(client: TestClient, name: str, dim: int = 3, fit: bool = True,
               n_samples: int = 100, scale: float = 1.0) -> None:
    """A skill with four arc demonstrations, fitted unless told not to."""
    r = client.post("/skills", json={"name": name, "dim": dim})
    assert r.status_code == 201, r.text
    for j in range(4):
        r = client.post(f"/skills/{name}/demonstrations",
                        json={"positions": (scale * arc(j, dim=dim)).tolist()})
        assert r.status_code == 201, r.text
    if fit:
        r = client.post(f"/skills/{name}/fit", json={"n_samples": n_samples})
        assert r.status_code == 201, r.text


def metric(client: TestClient, name: str, labels: str = "") -> float:
    """One sample of /metrics (0 when absent), after the in-process bridge has handed its
    counts over (its metrics thread does that every 0.25 s)."""
    bridge = getattr(client.app.state, "bridge", None)  # type: ignore[attr-defined]
    if bridge is not None and hasattr(bridge, "flush_metrics"):
        bridge.flush_metrics()
    wanted = f"{name}{{{labels}}}" if labels else name
    for line in client.get("/metrics").text.splitlines():
        if line.startswith(wanted + " "):
            return float(line.split()[-1])
    return 0.0


class Live:
    """The running app: REST client, Zenoh endpoint, settings."""

    def __init__(self, client: TestClient, endpoint: str, settings: Settings) -> None:
        self.client = client
        self.endpoint = endpoint
        self.settings = settings

    def metric(self, name: str, labels: str = "") -> float:
        return metric(self.client, name, labels)
