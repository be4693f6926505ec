"""Exports are consistent snapshots, even while the skill keeps being written; restarts append."""

from __future__ import annotations

import re
import subprocess
import threading
from pathlib import Path
from typing import Any

import numpy as np
from canal_service.recording import Recorder
from canal_service.recording.rerun_log import rerun_cli
from recording_helpers import mcap_counts, record_session, rrd_rows, rrd_verify


def test_exports_while_writing_are_finished_growing_snapshots(
        recorder: Recorder, demos3: list[np.ndarray], rerun_env: dict[str, str]) -> None:
    n_demos = 60
    started = threading.Event()

    def keep_adding() -> None:
        for j in range(1, n_demos + 1):
            recorder.demo_added("pour", 3, j, demos3[j % 3], None, f"take {j}")
            started.set()

    writer = threading.Thread(target=keep_adding)
    writer.start()
    started.wait(10)
    snapshots: list[tuple[Path, int]] = []
    for _ in range(4):
        path = recorder.export_mcap("pour")
        snapshots.append((path, mcap_counts(path).get("/canal/demos", 0)))
        rrd = recorder.export_rrd("pour")
        assert rrd_verify(rrd, rerun_env).returncode == 0
    writer.join()
    final = recorder.export_mcap("pour")
    assert mcap_counts(final)["/canal/demos"] == n_demos
    seen = [n for _, n in snapshots]
    assert seen == sorted(seen) and seen[0] >= 1
    # A snapshot never changes after it was handed out, whatever was written since.
    for path, n in snapshots:
        assert mcap_counts(path).get("/canal/demos", 0) == n
    rows = rrd_rows(recorder.export_rrd("pour"), rerun_env)
    assert sum(n for (entity, comp), n in rows.items()
               if entity.endswith("/path") and comp == "LineStrips3D:strips") == n_demos


def test_exports_compact_the_segments(recorder: Recorder, demos3: list[np.ndarray],
                                      canal3: Any) -> None:
    for round_ in range(3):
        record_session(recorder, "pour", demos3, canal3, n_live=5)
        recorder.export_mcap("pour").unlink()
        recorder.export_rrd("pour").unlink()
        files = sorted(p.name for p in (recorder.root / "pour").iterdir())
        assert files == ["ledger", "recording_id", f"seg-000001-{round_ + 1:06d}.mcap",
                         f"seg-000001-{round_ + 1:06d}.rrd"]
    assert mcap_counts(recorder.export_mcap("pour"))["/canal/model"] == 3
    assert list((recorder.root / ".exports").iterdir())  # the caller deletes snapshots


def _recording_ids(path: Path, env: dict[str, str]) -> set[str]:
    out = subprocess.run([*rerun_cli(), "rrd", "print", str(path)], env=env,
                         capture_output=True, text=True, timeout=120).stdout
    return set(re.findall(r'Recording,\s*"canal",\s*"([^"]+)"', out))


def test_a_restart_appends_to_the_same_recording(tmp_path: Path, demos3: list[np.ndarray],
                                                 rerun_env: dict[str, str]) -> None:
    root = tmp_path / "rec"
    first = Recorder(root, flush_interval_s=0.1)
    first.demo_added("pour", 3, 1, demos3[0], None, "a")
    first.demo_added("pour", 3, 2, demos3[1], None, "b")
    first.close()
    second = Recorder(root, flush_interval_s=0.1)
    try:
        second.demo_added("pour", 3, 3, demos3[2], None, "c")
        mcap, rrd = second.export_mcap("pour"), second.export_rrd("pour")
    finally:
        second.close()
    assert mcap_counts(mcap)["/canal/demos"] == 3
    rows = rrd_rows(rrd, rerun_env)
    assert [rows[(f"/demos/{j}/path", "LineStrips3D:strips")] for j in (1, 2, 3)] == [1, 1, 1]
    assert len(_recording_ids(rrd, rerun_env)) == 1


def test_a_raw_logs_equal_and_late_stamps_are_recorded_as_logged(
        recorder: Recorder, demos3: list[np.ndarray], rerun_env: dict[str, str]) -> None:
    # Uploads store a raw log's stamps as sent (the fit repairs them): every row twice with
    # its stamp (a polling logger), and the first sample stamped after the second, so its
    # demo_time starts below zero.
    demo = np.repeat(demos3[0], 2, axis=0)
    times = np.repeat(np.linspace(0.0, 2.0, len(demos3[0])), 2)
    times[[0, 2]] = times[[2, 0]]
    recorder.demo_added("pour", 3, 1, demo, times, "raw")
    rrd = recorder.export_rrd("pour")
    assert rrd_verify(rrd, rerun_env).returncode == 0
    rows = rrd_rows(rrd, rerun_env)
    assert rows[("/demos/1/position", "Scalars:scalars")] == len(demo)
    assert mcap_counts(recorder.export_mcap("pour"))["/canal/demos"] == 1
