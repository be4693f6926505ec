"""The .rrd export: verified by ``rerun rrd verify``, entities and row counts as logged."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from canal_service.recording import Recorder
from recording_helpers import record_session, rrd_rows, rrd_verify


def test_rrd_export_verifies_and_holds_every_entity(
        recorder: Recorder, demos3: list[np.ndarray], canal3: Any,
        rerun_env: dict[str, str]) -> None:
    logged = record_session(recorder, "pour", demos3, canal3, versions=2, n_live=40)
    path = recorder.export_rrd("pour")

    verify = rrd_verify(path, rerun_env)
    assert verify.returncode == 0, verify.stderr[-2000:]
    rows = rrd_rows(path, rerun_env)
    for j in range(1, logged["demos"] + 1):
        assert rows[(f"/demos/{j}/path", "LineStrips3D:strips")] == 1
        assert rows[(f"/demos/{j}/position", "Scalars:scalars")] == len(demos3[j - 1])
        assert rows[(f"/demos/{j}/info", "label")] == 1
    # The removal is a recursive clear of the demo, not a silent omission.
    assert rows[("/demos/1", "Clear:is_recursive")] == 1
    assert rows[("/demos/2", "Clear:is_recursive")] == 0
    for entity, component in [("/model/mesh", "Mesh3D:vertex_positions"),
                              ("/model/mesh", "Mesh3D:vertex_normals"),
                              ("/model/mesh", "Mesh3D:vertex_colors"),
                              ("/model/directrix", "LineStrips3D:strips"),
                              ("/model/rings", "LineStrips3D:strips"),
                              ("/model/frames", "Arrows3D:vectors")]:
        assert rows[(entity, component)] == logged["versions"], entity
    for v in (1, 2):
        assert rows[(f"/radius/v{v}", "Scalars:scalars")] == canal3.n_sections
    assert rows[("/reproductions/path", "LineStrips3D:strips")] == 1
    assert rows[("/reproductions/start", "Points3D:positions")] == 1
    assert rows[("/reproductions/eta", "Scalars:scalars")] == 1
    assert rows[("/reproductions/inside", "Scalars:scalars")] == 1
    for entity in ("/live/ur5/pose", "/live/ur5/target"):
        assert rows[(entity, "Points3D:positions")] == logged["live"]
    assert rows[("/live/ur5/progress", "Scalars:scalars")] == logged["live"]
    # The default blueprint travels with the recording.
    assert rows[("/time_panel", "TimePanelBlueprint:timeline")] == 1
    assert rows[("/viewport", "ViewportBlueprint:root_container")] == 1


def test_rrd_snapshot_of_a_skill_without_events_is_a_valid_file(
        recorder: Recorder, rerun_env: dict[str, str]) -> None:
    path = recorder.export_rrd("nothing-yet")
    assert rrd_verify(path, rerun_env).returncode == 0
    rows = rrd_rows(path, rerun_env)
    assert not any(entity.startswith(("/demos", "/model", "/live")) for entity, _ in rows)


def test_two_skills_are_two_recordings(recorder: Recorder, demos3: list[np.ndarray],
                                       canal3: Any, rerun_env: dict[str, str]) -> None:
    record_session(recorder, "pour", demos3, canal3, n_live=5)
    recorder.demo_added("wipe", 3, 7, demos3[0], None, None)
    wipe = rrd_rows(recorder.export_rrd("wipe"), rerun_env)
    assert wipe[("/demos/7/path", "LineStrips3D:strips")] == 1
    assert wipe[("/demos/1/path", "LineStrips3D:strips")] == 0
    assert wipe[("/model/mesh", "Mesh3D:vertex_positions")] == 0


def test_deleting_a_skill_deletes_its_recording(tmp_path: Path, demos3: list[np.ndarray],
                                                canal3: Any, rerun_env: dict[str, str]) -> None:
    rec = Recorder(tmp_path / "rec", flush_interval_s=0.1)
    try:
        record_session(rec, "pour", demos3, canal3, n_live=5)
        rec.export_rrd("pour").unlink()
        assert (tmp_path / "rec" / "pour").is_dir()
        rec.skill_deleted("pour")
        rows = rrd_rows(rec.export_rrd("pour"), rerun_env)  # a new, empty recording
        assert rows[("/model/mesh", "Mesh3D:vertex_positions")] == 0
        assert not (tmp_path / "rec" / "pour").exists()
    finally:
        rec.close()
