"""Readers for the recorder tests: the files are read back with their own tools.

The ``rerun`` CLI shipped in the rerun-sdk wheel (analytics off through its documented config
switch, in a private config home) and the ``mcap`` reader.
"""

from __future__ import annotations

import re
import subprocess
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import orjson
from canal_service.recording.rerun_log import rerun_cli
from mcap.reader import make_reader

T = 60


def helix_demo(k: int, dim: int = 3, n: int = T) -> np.ndarray:
    """A noisy helix (or its 2-D projection), different per ``k``."""
    s = np.linspace(0.0, 1.0, n)
    rng = np.random.default_rng(k)
    pts = np.c_[np.cos(3 * s), np.sin(3 * s), s] + 0.03 * rng.standard_normal((n, 3))
    return pts[:, :dim]


# ---- rerun CLI ------------------------------------------------------------------------------

def rrd_verify(path: Path, env: dict[str, str], *, footers: bool = True) -> subprocess.CompletedProcess[str]:
    """``rerun rrd verify`` (with or without the footer check)."""
    return subprocess.run([*rerun_cli(), "rrd", "verify", "--check-footers",
                           "true" if footers else "false", str(path)],
                          env=env, capture_output=True, text=True, timeout=120)


_CHUNK = re.compile(r"^Chunk\(\S+\) with (\d+) rows \([^)]*\) - (\S+) - data columns: \[(.*)\]$")


def rrd_rows(path: Path, env: dict[str, str]) -> Counter[tuple[str, str]]:
    """Rows per (entity path, component) from ``rerun rrd print`` (blueprint stores included)."""
    proc = subprocess.run([*rerun_cli(), "rrd", "print", "--continue-on-error", "true", str(path)],
                          env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    rows: Counter[tuple[str, str]] = Counter()
    for line in proc.stdout.splitlines():
        m = _CHUNK.match(line.strip())
        if m:
            for component in m.group(3).split():
                rows[(m.group(2), component)] += int(m.group(1))
    return rows


# ---- mcap -----------------------------------------------------------------------------------

def mcap_summary(path: Path) -> Any:
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    return summary


def mcap_counts(path: Path) -> dict[str, int]:
    """Message count per topic from the summary statistics."""
    summary = mcap_summary(path)
    counts = summary.statistics.channel_message_counts
    out: Counter[str] = Counter()
    for cid, channel in summary.channels.items():
        out[channel.topic] += counts.get(cid, 0)
    return dict(out)


def mcap_messages(path: Path, topic: str) -> list[dict[str, Any]]:
    """Decoded JSON messages of ``topic`` in log-time order."""
    with open(path, "rb") as f:
        return [orjson.loads(m.data) for _, _, m in make_reader(f).iter_messages(topics=[topic])]


# ---- a known session ------------------------------------------------------------------------

def record_session(rec: Any, skill: str, demos: list[np.ndarray], canal: Any, *,
                   versions: int = 1, n_live: int = 50, robot: str = "ur5") -> dict[str, int]:
    """Log demos (with timestamps and labels), fits, a reproduction, live steps and a removal.

    Live samples are 1 ms apart starting now. Returns how many of each thing was logged.
    """
    dim = demos[0].shape[1]
    for j, demo in enumerate(demos, start=1):
        rec.demo_added(skill, dim, j, demo, np.linspace(0.0, 2.0, len(demo)), f"take {j}")
    for v in range(1, versions + 1):
        rec.model_fitted(skill, v, canal)
    rec.reproduction(skill, versions, canal.reproduce_detailed(demos[0][0]))
    tracker = canal.tracker()
    t0 = time.time_ns()
    path = demos[1]
    for k in range(n_live):
        position = path[k * len(path) // n_live]
        rec.live(skill, robot, position, tracker.step(position), t_ns=t0 + k * 1_000_000)
    rec.demo_removed(skill, 1)
    return {"demos": len(demos), "versions": versions, "reproductions": 1, "live": n_live,
            "removed": 1}
