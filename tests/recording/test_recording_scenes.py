"""A skill's scene in its recordings: obstacles as their own entities in the .rrd, Foxglove
SceneUpdate primitives in the MCAP, MarkerArray markers in the ros2 profile (each file read back
by its own reader)."""

from __future__ import annotations

from typing import Any

import numpy as np
from canal_service.recording import Recorder
from recording_helpers import mcap_messages, record_session, rrd_rows, rrd_verify
from rosbags import highlevel

SCENE = [
    {"kind": "sphere", "center": [0.1, 0.2, 0.3], "radius": 0.05, "clearance": 0.01, "name": "cup"},
    {"kind": "box", "center": [0.4, 0.0, 0.1], "half_extents": [0.1, 0.02, 0.03],
     "rotation": [0.0, 0.0, 0.3826834323650898, 0.9238795325112867]},
    {"kind": "capsule", "a": [0.0, 0.0, 0.0], "b": [0.0, 0.0, 0.2], "radius": 0.02},
]


def test_scene_changes_are_recorded_in_every_format(recorder: Recorder, demos3: list[np.ndarray],
                                                     canal3: Any, rerun_env: dict[str, str]) -> None:
    record_session(recorder, "pour", demos3, canal3, n_live=5)
    recorder.scene_changed("pour", 1, SCENE, 3)
    recorder.scene_changed("pour", 2, SCENE[:1], 3)  # smaller: the others are gone

    rrd = recorder.export_rrd("pour")
    assert rrd_verify(rrd, rerun_env).returncode == 0
    rows = rrd_rows(rrd, rerun_env)
    assert rows[("/scene/obstacles/0", "Ellipsoids3D:half_sizes")] == 2
    assert rows[("/scene/obstacles/1", "Boxes3D:quaternions")] == 1
    assert rows[("/scene/obstacles/2", "Capsules3D:radii")] == 1
    assert rows[("/scene/obstacles", "Clear:is_recursive")] == 2

    updates = mcap_messages(recorder.export_mcap("pour"), "/canal/scene")
    assert len(updates) == 2
    first, second = updates
    assert [d["type"] for d in second["deletions"]] == [1]  # everything before goes first
    by_id = {e["id"]: e for e in first["entities"]}
    sphere = by_id["scene/0"]["spheres"][0]
    assert sphere["size"]["x"] == 0.1 and sphere["pose"]["position"]["z"] == 0.3
    cube = by_id["scene/1"]["cubes"][0]
    assert np.isclose(cube["size"]["x"], 0.2) and np.isclose(cube["pose"]["orientation"]["z"], 0.3826834)
    capsule = by_id["scene/2"]
    assert len(capsule["cylinders"]) == 1 and len(capsule["spheres"]) == 2
    assert np.isclose(capsule["cylinders"][0]["size"]["z"], 0.2)
    assert [e["id"] for e in second["entities"]] == ["scene/0"]

    ros = recorder.export_mcap("pour", profile="ros2")
    arrays = []
    with highlevel.AnyReader([ros]) as reader:
        for conn, _t, raw in reader.messages():
            if conn.topic == "/canal/scene":
                assert conn.msgtype == "visualization_msgs/msg/MarkerArray"
                arrays.append(reader.deserialize(raw, conn.msgtype))
    assert len(arrays) == 2
    kinds = [(m.action, m.type) for m in arrays[0].markers]
    assert kinds[0][0] == 3  # DELETEALL
    assert sorted(t for a, t in kinds[1:]) == [1, 2, 2, 2, 3]  # cube, sphere + capsule ends, cylinder
    assert [(m.action, m.type) for m in arrays[1].markers] == [(3, 2), (0, 2)]
