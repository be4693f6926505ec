"""The adapters to mcap's and rerun's internals: the fast path and the public API write the
same recording (read back with each library's own reader), an untested library version
takes the public API, and /healthz-bound health says which path runs."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from canal_service.adapters import adapter_paths, mcap_writer, rerun_chunks
from canal_service.recording import Recorder
from canal_service.recording.events import LiveRows, live_rows
from canal_service.recording.mcap_log import McapSegment
from canal_service.recording.rerun_log import RerunSegment
from mcap.reader import make_reader
from recording_helpers import mcap_counts, rrd_rows


def _rows(robot: str, t0: int, m: int = 30, route: int | None = None) -> LiveRows:
    rng = np.random.default_rng(len(robot))
    q = rng.standard_normal((m, 4))
    return live_rows("pour", robot, t0 + 1_000_000 * np.arange(m), rng.random((m, 3)), q,
                     rng.random((m, 3)), q[::-1], np.linspace(0, 1, m), rng.random(m),
                     np.arange(m), np.arange(m) % 3 != 0, np.zeros(m, bool),
                     None if route is None else np.full(m, route))


def _mcap(path: Path, fast: bool) -> list[tuple[str, int, bytes]]:
    t0 = 1_700_000_000_000_000_000
    seg = McapSegment(path, t0, fast=fast)
    for k, robot in enumerate(("arm1", "arm2", "arm1")):
        seg.live(_rows(robot, t0 + 100_000_000 * k))
        if k == 1:
            seg.flush()
    seg.close()
    with open(path, "rb") as f:
        return [(c.topic, m.log_time, m.data) for _, c, m in make_reader(f).iter_messages(
            log_time_order=True)]


def test_mcap_fast_and_public_paths_write_the_same_messages(tmp_path: Path) -> None:
    assert mcap_writer.status().startswith("internals")  # mcap as pinned: the bulk path runs
    fast = _mcap(tmp_path / "fast.mcap", True)
    public = _mcap(tmp_path / "public.mcap", False)
    assert len(fast) == 1 + 4 * 90 and fast == public
    assert mcap_counts(tmp_path / "fast.mcap") == mcap_counts(tmp_path / "public.mcap")


def test_an_untested_mcap_takes_the_public_api(tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(mcap_writer, "INSTALLED", "2.0.0")
    mcap_writer.status.cache_clear()
    try:
        assert mcap_writer.status().startswith("public API (mcap 2.0.0")
        seg = McapSegment(tmp_path / "new.mcap", time.time_ns())
        assert mcap_writer.writer_internals(seg._writer) is None
        seg.live(_rows("arm1", time.time_ns()))
        seg.close()
        assert mcap_counts(tmp_path / "new.mcap")["/live/arm1/pose"] == 30
    finally:
        mcap_writer.status.cache_clear()


def _rrd(path: Path, fast: bool, env: dict[str, str]) -> Path:
    seg = RerunSegment(path, "0" * 32, "pour", blueprint=False, fast=fast)
    t0 = 1_700_000_000_000_000_000
    seg.live(_rows("arm1", t0))
    seg.live(_rows("arm2", t0 + 50_000_000, route=1))  # a stream on route 1
    seg.close()
    return path


@pytest.mark.parametrize("fast", [True, False], ids=["native", "public"])
def test_rerun_paths_log_the_same_live_rows(tmp_path: Path, rerun_env: dict[str, str],
                                            fast: bool) -> None:
    rows = rrd_rows(_rrd(tmp_path / "live.rrd", fast, rerun_env), rerun_env)
    live = {k: n for k, n in rows.items() if k[0].startswith("/live/")}
    assert live[("/live/arm1/pose", "Points3D:positions")] == 30
    assert live[("/live/arm2/target", "Points3D:colors")] == 30
    assert live[("/live/arm1/frame", "Transform3D:quaternion")] == 30
    assert live[("/live/arm2/eta", "Scalars:scalars")] == 30
    assert live[("/live/arm1/progress", "Scalars:scalars")] == 30
    assert live[("/live/arm2/route", "Scalars:scalars")] == 30
    assert not any(entity == "/live/arm1/route" for entity, _ in live)


def test_an_untested_rerun_takes_the_public_api(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(rerun_chunks, "INSTALLED", "0.99.0")
    rerun_chunks.status.cache_clear()
    try:
        assert not rerun_chunks.native_path()
        assert rerun_chunks.status().startswith("public API (rerun-sdk 0.99.0")
    finally:
        rerun_chunks.status.cache_clear()


def test_health_names_each_adapters_path(tmp_path: Path) -> None:
    rec = Recorder(tmp_path, enabled=False)
    assert rec.health()["adapters"] == adapter_paths() == {
        "mcap": mcap_writer.status(), "rerun-sdk": rerun_chunks.status()}
    assert all(p.startswith(("internals", "public API")) for p in adapter_paths().values())
