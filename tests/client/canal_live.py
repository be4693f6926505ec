"""Shared by the client and CLI tests: a real uvicorn serving the Canal service on a free
loopback port, and demonstration files in every accepted format."""

from __future__ import annotations

import contextlib
import http.server
import json
import os
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from canal_service.app import create_app
from canal_service.core.config import Settings
from canal_testing import LiveServer, arc_demo, foxglove_pose_mcap, free_port

os.environ.setdefault("RERUN_TELEMETRY_ENABLED", "false")

RRD_MAGIC = b"RRF2"
MCAP_MAGIC = b"\x89MCAP0\r\n"


def closed_port_url() -> str:
    """A loopback URL where nothing listens (the port was free a moment ago)."""
    return f"http://127.0.0.1:{free_port()}"


@contextlib.contextmanager
def other_web_app() -> Iterator[str]:
    """The URL of a web server on loopback that is not Canal: every request is answered
    200 with an HTML page (a URL pointing at the wrong port)."""

    class Page(http.server.BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            body = b"<html>hello</html>"
            self.send_response(200)
            self.send_header("Content-Type", "text/html")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args: Any) -> None:
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Page)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()


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
