"""The .rrd export: verified by ``rerun rrd verify``, entities and row counts as logged."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import rerun.blueprint as rrb
from canal_service.recording import Recorder
from canal_service.recording.rerun_log import review_blueprint
from recording_helpers import helix_demo, mcap_messages, record_session, rrd_rows, rrd_verify


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
        # named at its start: at the path's mean point every demo's name fell on the others'
        assert rows[(f"/demos/{j}/start", "Points3D:labels")] == 1
        assert rows.get((f"/demos/{j}/path", "LineStrips3D:labels"), 0) == 0
    # The removal is a recursive clear of the demo, not a silent omission.
    assert rows[("/demos/1", "Clear:is_recursive")] == 1
    assert rows[("/demos/2", "Clear:is_recursive")] == 0
    for v in range(1, logged["versions"] + 1):  # every model version its own entity
        for entity, component in [(f"/model/v{v}/mesh", "Mesh3D:vertex_positions"),
                                  (f"/model/v{v}/mesh", "Mesh3D:vertex_normals"),
                                  (f"/model/v{v}/mesh", "Mesh3D:vertex_colors"),
                                  (f"/model/v{v}/mesh", "Mesh3D:albedo_factor"),
                                  (f"/model/v{v}/directrix", "LineStrips3D:strips"),
                                  (f"/model/v{v}/rings", "LineStrips3D:strips"),
                                  (f"/model/v{v}/radius", "BarChart:values"),
                                  (f"/frames/v{v}", "Arrows3D:vectors")]:
            assert rows[(entity, component)] == 1, entity
    # a new version clears the one before it from its time on
    assert rows[("/model/v1", "Clear:is_recursive")] == 1
    assert rows[(f"/model/v{logged['versions']}", "Clear:is_recursive")] == 0
    for v in (1, 2):
        assert rows[(f"/radius/v{v}", "Scalars:scalars")] == canal3.n_sections
    assert rows[("/reproductions/1/path", "LineStrips3D:strips")] == 1
    assert rows[("/reproductions/1/start", "Points3D:positions")] == 1
    assert rows[("/reproductions/1/eta", "Scalars:scalars")] == 1
    assert rows[("/reproductions/1/inside", "Scalars:scalars")] == 1
    # the latest reproduction's ratio per position, one bar chart for all of them
    assert rows[("/ratio", "BarChart:values")] == 1
    for entity in ("/live/ur5/pose", "/live/ur5/target"):
        assert rows[(entity, "Points3D:positions")] == logged["live"]
    assert rows[("/live/ur5/progress", "Scalars:scalars")] == logged["live"]
    # Live poses carry a frame (translation + quaternion) drawn as axes.
    assert rows[("/live/ur5/frame", "Transform3D:quaternion")] == logged["live"]
    assert rows[("/live/ur5/frame", "Transform3D:translation")] == logged["live"]
    assert rows[("/live/ur5/frame", "TransformAxes3D:axis_length")] == 1
    # The world is Z-up, right-handed.
    assert rows[("/", "ViewCoordinates:xyz")] == 1
    # The default blueprint travels with the recording: one at its start, and one framed on
    # each new canal (the last one sent is the one a viewer opens with).
    assert rows[("/time_panel", "TimePanelBlueprint:timeline")] == 1 + logged["versions"]
    assert rows[("/viewport", "ViewportBlueprint:root_container")] == 1 + logged["versions"]


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
    assert wipe[("/model/v1/mesh", "Mesh3D:vertex_positions")] == 0


def test_deleting_a_skill_deletes_its_recording(tmp_path: Path, demos3: list[np.ndarray],
                                                canal3: Any, rerun_env: dict[str, str]) -> None:
    rec = Recorder(tmp_path / "rec", flush_interval_s=0.1)
    try:
        record_session(rec, "pour", demos3, canal3, n_live=5)
        rec.export_rrd("pour").unlink()
        assert (tmp_path / "rec" / "pour").is_dir()
        rec.skill_deleted("pour")
        rows = rrd_rows(rec.export_rrd("pour"), rerun_env)  # a new, empty recording
        assert rows[("/model/v1/mesh", "Mesh3D:vertex_positions")] == 0
        assert not (tmp_path / "rec" / "pour").exists()
    finally:
        rec.close()


def test_every_reproduction_keeps_its_entity_with_times_and_orientations(
        recorder: Recorder, demos3: list[np.ndarray], canal3: Any,
        rerun_env: dict[str, str]) -> None:
    base = canal3.reproduce_detailed(demos3[0][0])
    n = len(base.positions)
    angle = np.linspace(0.0, np.pi / 2, n)
    quats = np.c_[np.zeros(n), np.zeros(n), np.sin(angle / 2), np.cos(angle / 2)]
    recorder.reproduction("pour", 1, base)
    recorder.reproduction("pour", 1, replace(base, inside=True, eta=0.5, section_index=0,
                                             projected=False, times=np.linspace(0.0, 3.0, n),
                                             orientations=quats))
    recorder.reproduction("pour", 1, canal3.reproduce_detailed(demos3[1][0]))
    rows = rrd_rows(recorder.export_rrd("pour"), rerun_env)
    for k in (1, 2, 3):  # none overwrites another
        assert rows[(f"/reproductions/{k}/path", "LineStrips3D:strips")] == 1
    assert rows[("/reproductions/2/orientation", "Arrows3D:vectors")] == 1
    assert rows[("/reproductions/1/orientation", "Arrows3D:vectors")] == 0
    # The timed one moves along its own timeline, with its orientation.
    assert rows[("/reproductions/2/point", "Points3D:positions")] == n
    assert rows[("/reproductions/2/point", "Transform3D:quaternion")] == n
    mcap = mcap_messages(recorder.export_mcap("pour"), "/canal/reproduction_poses")
    assert len(mcap) == 1
    q = mcap[0]["poses"][-1]["orientation"]
    assert np.allclose([q["x"], q["y"], q["z"], q["w"]], quats[-1])


def test_a_2d_skill_is_drawn_in_2d(recorder: Recorder, canal2: Any,
                                   rerun_env: dict[str, str]) -> None:
    demo = helix_demo(0, dim=2)
    recorder.demo_added("plane", 2, 1, demo, None, None)
    recorder.model_fitted("plane", 1, canal2)
    recorder.reproduction("plane", 1, canal2.reproduce_detailed(demo[0]))
    rows = rrd_rows(recorder.export_rrd("plane"), rerun_env)
    assert rows[("/demos/1/path", "LineStrips2D:strips")] == 1
    assert rows[("/model/v1/directrix", "LineStrips2D:strips")] == 1
    assert rows[("/reproductions/1/path", "LineStrips2D:strips")] == 1
    assert rows[("/demos/1/path", "LineStrips3D:strips")] == 0
    assert rows[("/", "ViewCoordinates:xyz")] == 0  # 3-D axes mean nothing in a 2-D view
    assert isinstance(review_blueprint(2).root_container.contents[0], rrb.Spatial2DView)
    assert isinstance(review_blueprint(3).root_container.contents[0], rrb.Spatial3DView)


def test_review_eye_sees_every_point_of_the_canal(canal3: Any) -> None:
    from canal_service.recording.rerun_log import _FOV_Y, framing_eye, up_axis

    points = np.asarray(canal3.mesh(n_angles=16).vertices)
    up = up_axis("RIGHT_HAND_Z_UP")
    eye, target = framing_eye(points, up)
    forward = (target - eye) / np.linalg.norm(target - eye)
    rays = points - eye
    # every vertex in front of the eye, within half the vertical field of view of the axis
    cos_angle = rays @ forward / np.linalg.norm(rays, axis=1)
    assert np.all(cos_angle > np.cos(_FOV_Y / 2))
    assert eye @ up > target @ up  # seen from above
    np.testing.assert_allclose(up_axis("RIGHT_HAND_Y_DOWN"), [0.0, -1.0, 0.0])
