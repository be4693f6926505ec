"""The .mcap export: summary, Foxglove schemas, message counts, decoded geometry."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import jsonschema_rs
import numpy as np
import orjson
from canal_service.recording import Recorder
from canal_service.recording.foxglove import SCHEMAS
from recording_helpers import mcap_counts, mcap_messages, mcap_summary, record_session

EXPECTED_SCHEMAS = {
    "/tf": "foxglove.FrameTransform",
    "/canal/demos": "foxglove.SceneUpdate",
    "/canal/model": "foxglove.SceneUpdate",
    "/canal/model_info": "canal.ModelInfo",
    "/canal/reproductions": "foxglove.SceneUpdate",
    "/canal/reproduction_result": "canal.ReproductionResult",
    "/live/ur5/pose": "foxglove.PoseInFrame",
    "/live/ur5/target": "foxglove.PoseInFrame",
    "/live/ur5/state": "canal.TrackerState",
}


def test_summary_lists_channels_schemas_and_counts(recorder: Recorder, demos3: list[np.ndarray],
                                                   canal3: Any) -> None:
    logged = record_session(recorder, "pour", demos3, canal3, versions=2, n_live=40)
    path = recorder.export_mcap("pour")
    summary = mcap_summary(path)
    schemas = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
    assert schemas == EXPECTED_SCHEMAS
    assert {c.message_encoding for c in summary.channels.values()} == {"json"}
    assert {s.encoding for s in summary.schemas.values()} == {"jsonschema"}
    assert mcap_counts(path) == {
        "/tf": 1 + logged["live"],  # world -> canal once per segment, canal -> robot per sample
        "/canal/demos": logged["demos"] + logged["removed"],
        "/canal/model": logged["versions"],
        "/canal/model_info": logged["versions"],
        "/canal/reproductions": 1,
        "/canal/reproduction_result": 1,
        "/live/ur5/pose": logged["live"],
        "/live/ur5/target": logged["live"],
        "/live/ur5/state": logged["live"],
    }
    # Chunked, compressed, indexed.
    assert summary.chunk_indexes
    assert {c.compression for c in summary.chunk_indexes} == {"zstd"}
    assert all(c.message_index_offsets for c in summary.chunk_indexes)


def test_scene_update_mesh_matches_the_model_mesh(recorder: Recorder, demos3: list[np.ndarray],
                                                  canal3: Any) -> None:
    record_session(recorder, "pour", demos3, canal3, n_live=1)
    (update,) = mcap_messages(recorder.export_mcap("pour"), "/canal/model")
    entities = {e["id"]: e for e in update["entities"]}
    assert set(entities) == {"canal/mesh", "canal/directrix", "canal/rings", "canal/frames"}
    (tri,) = entities["canal/mesh"]["triangles"]
    mesh = canal3.mesh()
    assert len(tri["points"]) == mesh.vertices.shape[0]
    assert len(tri["colors"]) == mesh.vertices.shape[0]
    assert len(tri["indices"]) == mesh.faces.size
    points = np.array([[p["x"], p["y"], p["z"]] for p in tri["points"]])
    np.testing.assert_allclose(points, mesh.vertices)
    np.testing.assert_array_equal(np.array(tri["indices"]).reshape(-1, 3), mesh.faces)
    (line,) = entities["canal/directrix"]["lines"]
    assert len(line["points"]) == canal3.n_sections
    info = mcap_messages(recorder.export_mcap("pour"), "/canal/model_info")[0]
    np.testing.assert_allclose(info["radii"], canal3.radii)


def test_messages_validate_against_their_schemas(recorder: Recorder, demos3: list[np.ndarray],
                                                 canal3: Any) -> None:
    record_session(recorder, "pour", demos3, canal3, n_live=3)
    path = recorder.export_mcap("pour")
    summary = mcap_summary(path)
    for channel in summary.channels.values():
        schema = summary.schemas[channel.schema_id]
        assert orjson.loads(schema.data) == SCHEMAS[schema.name]
        validator = jsonschema_rs.validator_for(orjson.loads(schema.data))
        for message in mcap_messages(path, channel.topic):
            validator.validate(message)


def test_removed_demo_is_deleted_in_the_scene(recorder: Recorder, demos3: list[np.ndarray],
                                              canal3: Any) -> None:
    record_session(recorder, "pour", demos3, canal3, n_live=1)
    updates = mcap_messages(recorder.export_mcap("pour"), "/canal/demos")
    added = [e["id"] for u in updates for e in u["entities"]]
    deleted = [d["id"] for u in updates for d in u["deletions"]]
    assert added == ["demo/1", "demo/2", "demo/3"]
    assert deleted == ["demo/1"]
    labels = {m["key"]: m["value"] for m in updates[0]["entities"][0]["metadata"]}
    assert labels == {"demo_id": "1", "label": "take 1", "n_samples": str(len(demos3[0]))}


def test_a_reproduction_result_carries_its_ratio_per_position(
        recorder: Recorder, demos3: list[np.ndarray], canal3: Any) -> None:
    record_session(recorder, "pour", demos3, canal3, n_live=1)
    (result,) = mcap_messages(recorder.export_mcap("pour"), "/canal/reproduction_result")
    expected = canal3.reproduce_detailed(demos3[0][0]).ratios
    assert result["n_points"] == len(result["ratios"]) == len(expected)
    np.testing.assert_allclose(result["ratios"], expected, rtol=1e-12)


def test_two_d_skill_is_drawn_in_the_z0_plane(tmp_path: Path, canal2: Any) -> None:
    rec = Recorder(tmp_path / "rec", flush_interval_s=0.1, live_max_hz=None)
    demos = [np.c_[np.linspace(0, 1, 30), np.linspace(0, 1, 30) ** 2] for _ in range(3)]
    try:
        record_session(rec, "draw", demos, canal2, n_live=10)
        path = rec.export_mcap("draw")
    finally:
        rec.close()
    demo_points = [p for u in mcap_messages(path, "/canal/demos") for e in u["entities"]
                   for p in e["lines"][0]["points"]]
    assert len(demo_points) == 3 * 30
    assert all(p["z"] == 0.0 for p in demo_points)
    (update,) = mcap_messages(path, "/canal/model")
    mesh = next(e for e in update["entities"] if e["id"] == "canal/mesh")["triangles"][0]
    assert len(mesh["points"]) == canal2.mesh().vertices.shape[0]
    poses = mcap_messages(path, "/live/ur5/pose")
    assert len(poses) == 10 and all(p["pose"]["position"]["z"] == 0.0 for p in poses)
