"""Shared by the client and CLI tests: a real uvicorn serving the Canal service on a free
loopback port, and demonstration files in every accepted format."""

from __future__ import annotations

import io
import json
import os
from pathlib import Path
from typing import Any

import numpy as np
from canal_service.app import create_app
from canal_service.core.config import Settings
from canal_testing import LiveServer, arc_demo, free_port
from mcap.writer import CompressionType, Writer

os.environ.setdefault("RERUN_TELEMETRY_ENABLED", "false")

RRD_MAGIC = b"RRF2"
MCAP_MAGIC = b"\x89MCAP0\r\n"


def closed_port_url() -> str:
    """A loopback URL where nothing listens (the port was free a moment ago)."""
    return f"http://127.0.0.1:{free_port()}"


class LiveService(LiveServer):
    """The Canal service under uvicorn on 127.0.0.1 in a background thread."""

    def __init__(self, data_dir: Path, **settings: Any) -> None:
        # Recordings and the Zenoh bridge only when a test asks (the bridge's default listen
        # port is shared by every process on this machine).
        settings.setdefault("recordings_enabled", False)
        settings.setdefault("zenoh_enabled", False)
        self.settings = Settings(data_dir=data_dir, **settings)
        super().__init__(create_app(self.settings))


# ---- data -------------------------------------------------------------------------------------


def demo_positions(j: int, n: int = 40, dim: int = 3) -> np.ndarray:
    """A smooth arc shifted by 0.02 per demonstration (its own noise seeds)."""
    return arc_demo(j, n, dim, seed=100, spread=0.02)


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


def write_demo_files(folder: Path, dim: int = 3) -> dict[str, Path]:
    """One demonstration per format (csv with time column, npy, json, mcap) in ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    p = [demo_positions(j, dim=dim) for j in range(4)]
    t = np.linspace(0.0, 2.0, len(p[0]))
    files = {"csv": folder / "a_demo.csv", "npy": folder / "b_demo.npy",
             "json": folder / "c_demo.json", "mcap": folder / "d_demo.mcap"}
    cols = "t,x,y,z" if dim == 3 else "t,x,y"
    np.savetxt(files["csv"], np.column_stack([t, p[0]]), delimiter=",", header=cols,
               comments="", fmt="%.17g")
    np.save(files["npy"], p[1])
    files["json"].write_text(json.dumps({"positions": p[2].tolist(), "timestamps": t.tolist()}))
    if dim == 3:
        files["mcap"].write_bytes(foxglove_pose_mcap(p[3]))
    else:
        del files["mcap"]
    return files
