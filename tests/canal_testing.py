"""Test support shared by every test folder (on ``sys.path`` through pytest's ``pythonpath``):
free loopback ports, a real uvicorn serving an app on 127.0.0.1, and arc demonstrations."""

from __future__ import annotations

import io
import json
import socket
import threading
import time
from typing import Any

import numpy as np
import uvicorn
from mcap.writer import CompressionType, Writer

ZENOH_DEFAULT_PORT = 7447


def free_port() -> int:
    """A TCP port free on 127.0.0.1 right now (never Zenoh's default, which a running
    service on this machine may hold)."""
    while True:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            s.bind(("127.0.0.1", 0))
            port = int(s.getsockname()[1])
        if port != ZENOH_DEFAULT_PORT:
            return port


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
        # generous: the app's startup (imports, migrations, bridge) takes seconds on an idle
        # machine and tens of seconds on a shared, loaded one; a real failure still ends it
        deadline = time.monotonic() + 90
        while not self.server.started:
            if time.monotonic() > deadline or not self.thread.is_alive():
                raise RuntimeError("uvicorn did not start")
            time.sleep(0.01)
        return self

    def __exit__(self, *exc: object) -> None:
        self.server.should_exit = True
        self.thread.join(15)


def arc_demo(j: int, n: int, dim: int = 3, seed: int = 0, spread: float = 0.02) -> np.ndarray:
    """A smooth arc, shifted by ``spread`` per demonstration so the canal has a real radius."""
    rng = np.random.default_rng(seed + j)
    t = np.linspace(0.0, 1.0, n)
    offset = spread * (j - 1.5)
    x = t
    y = 0.3 * np.sin(np.pi * t) + offset + 0.002 * rng.standard_normal(n)
    if dim == 2:
        return np.column_stack([x, y])
    z = 0.1 * t + 0.5 * offset * np.cos(np.pi * t) + 0.002 * rng.standard_normal(n)
    return np.column_stack([x, y, z])


#: The two routes of :func:`two_route_demo`: each one's start.
ROUTE_STARTS = ((0.0, 0.15, 0.0), (0.0, -0.15, 0.0))


def two_route_demo(j: int, n: int = 120, n_each: int = 4, dim: int = 3) -> np.ndarray:
    """Demonstrations that go two clearly different ways: the first ``n_each`` from
    ``ROUTE_STARTS[0]`` arc through +y, the next from ``ROUTE_STARTS[1]`` through -y (an
    obstacle in the middle is passed on either side), both ending near (1, 0, 0)."""
    route, k = divmod(j, n_each)
    side = 1.0 if route == 0 else -1.0
    s = np.linspace(0.0, 1.0, n)
    y = ROUTE_STARTS[route][1] * (1 - s) + side * 0.4 * np.sin(np.pi * s) + 0.01 * (k - n_each / 2)
    z = 0.02 * np.cos(3 * k) * np.sin(np.pi * s)
    return np.column_stack([s, y, z][:dim])


def fit_two_route_skill(client: Any, name: str, n_samples: int) -> Any:
    """Skill ``name`` with eight :func:`two_route_demo` demonstrations, fitted over ``client``
    (an httpx client of the service) as two routes; the fit's answer."""
    assert client.post("/skills", json={"name": name, "dim": 3}).status_code == 201
    for j in range(8):
        r = client.post(f"/skills/{name}/demonstrations", json={"positions": two_route_demo(j).tolist()})
        assert r.status_code == 201, r.text
    r = client.post(f"/skills/{name}/fit", json={"n_samples": n_samples})
    assert r.status_code == 201 and r.json()["routes"] == 2, r.text
    return r.json()


def path_distance(path: Any, demo: Any) -> float:
    """The mean distance from each point of ``path`` to the nearest point of ``demo``."""
    a, b = np.asarray(path, dtype=np.float64), np.asarray(demo, dtype=np.float64)
    return float(np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2).min(axis=1).mean())


def foxglove_pose_mcap(positions: np.ndarray, topic: str = "/ee_pose") -> bytes:
    """An MCAP file with one foxglove.PoseInFrame (JSON) message per sample."""
    buf = io.BytesIO()
    writer = Writer(buf, compression=CompressionType.ZSTD)
    writer.start()
    schema_id = writer.register_schema(name="foxglove.PoseInFrame", encoding="jsonschema",
                                       data=json.dumps({"type": "object"}).encode())
    channel = writer.register_channel(topic=topic, message_encoding="json", schema_id=schema_id)
    for i, p in enumerate(positions):
        pos = {"x": float(p[0]), "y": float(p[1]), "z": float(p[2]) if len(p) > 2 else 0.0}
        payload = {"timestamp": {"sec": 100 + i, "nsec": 0}, "frame_id": "base",
                   "pose": {"position": pos, "orientation": {"x": 0, "y": 0, "z": 0, "w": 1}}}
        writer.add_message(channel, log_time=i, publish_time=i, data=json.dumps(payload).encode())
    writer.finish()
    return buf.getvalue()
