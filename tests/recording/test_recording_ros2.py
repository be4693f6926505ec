"""The ros2 MCAP profile, read back with ``rosbags`` (an independent rosbag2/CDR reader)."""

from __future__ import annotations

from collections import Counter
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from canal_service.recording import Recorder
from mcap.reader import make_reader
from recording_helpers import mcap_messages, record_session
from rosbags import highlevel


def _read(path: Path) -> list[tuple[str, str, Any]]:
    """Every message, deserialised by rosbags from the file's own ros2msg schemas."""
    out = []
    with highlevel.AnyReader([path]) as reader:
        for conn, _t, raw in reader.messages():
            out.append((conn.topic, conn.msgtype, reader.deserialize(raw, conn.msgtype)))
    return out


def test_ros2_profile_reads_back_with_rosbags(recorder: Recorder, demos3: list[np.ndarray],
                                              canal3: Any) -> None:
    logged = record_session(recorder, "pour", demos3, canal3, n_live=30, robot="arm-1")
    rep = canal3.reproduce_detailed(demos3[2][0])
    n = len(rep.positions)
    quats = np.c_[np.zeros(n), np.sin(np.linspace(0, 1, n)), np.zeros(n),
                  np.cos(np.linspace(0, 1, n))]
    recorder.reproduction("pour", 1, replace(rep, inside=True, eta=0.4, section_index=0,
                                             projected=False, orientations=quats))
    m = len(demos3[0])
    demo_q = np.c_[np.sin(np.linspace(0, 1, m)), np.zeros(m), np.zeros(m),
                   np.cos(np.linspace(0, 1, m))]
    recorder.demo_added("pour", 3, 9, demos3[0], None, "with q", orientations=demo_q)
    foxglove = mcap_messages(recorder.export_mcap("pour"), "/canal/demo_poses/9")
    q9 = foxglove[0]["poses"][-1]["orientation"]  # the JSON flavour carries them too
    assert np.allclose([q9["x"], q9["y"], q9["z"], q9["w"]], demo_q[-1])
    path = recorder.export_mcap("pour", profile="ros2")

    with open(path, "rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        assert summary is not None
        assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
        assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
        total = sum(summary.statistics.channel_message_counts.values())

    messages = _read(path)
    assert len(messages) == total  # rosbags decodes every message
    counts = Counter((topic, msgtype) for topic, msgtype, _ in messages)
    assert counts[("/canal/live/arm_1/pose", "geometry_msgs/msg/PoseStamped")] == logged["live"]
    assert counts[("/canal/live/arm_1/target", "geometry_msgs/msg/PoseStamped")] == logged["live"]
    assert counts[("/tf", "tf2_msgs/msg/TFMessage")] == logged["live"] + 1  # + world -> canal
    for j in (2, 3):
        assert counts[(f"/canal/demos/demo_{j}", "nav_msgs/msg/Path")] == 1
    assert counts[("/canal/demos/demo_1", "nav_msgs/msg/Path")] == 2  # added, then deleted
    assert counts[("/canal/model/directrix", "nav_msgs/msg/Path")] == 1
    assert counts[("/canal/model/mesh", "visualization_msgs/msg/MarkerArray")] == 1
    assert counts[("/canal/reproductions", "nav_msgs/msg/Path")] == 2

    by_topic: dict[str, list[Any]] = {}
    for topic, _, msg in messages:
        by_topic.setdefault(topic, []).append(msg)
    demo2 = by_topic["/canal/demos/demo_2"][0]
    got = np.array([[p.pose.position.x, p.pose.position.y, p.pose.position.z]
                    for p in demo2.poses])
    assert np.allclose(got, demos3[1])
    assert len(by_topic["/canal/demos/demo_1"][-1].poses) == 0  # the deletion
    mesh = canal3.mesh(n_angles=32)
    surface = next(m for m in by_topic["/canal/model/mesh"][0].markers if m.ns == "canal/mesh")
    assert surface.type == 11 and len(surface.points) == 3 * len(mesh.faces)
    q9 = by_topic["/canal/demos/demo_9"][0].poses[-1].pose.orientation
    assert np.allclose([q9.x, q9.y, q9.z, q9.w], demo_q[-1])
    timed = by_topic["/canal/reproductions"][-1]
    q = timed.poses[-1].pose.orientation
    assert np.allclose([q.x, q.y, q.z, q.w], quats[-1])
    assert len(timed.poses) == n
    assert by_topic["/canal/live/arm_1/pose"][0].header.frame_id == "canal"


def test_robots_whose_names_make_one_ros_token_keep_topics_of_their_own(
        recorder: Recorder, demos3: list[np.ndarray], canal3: Any) -> None:
    # arm-1, arm.1, arm_1 and arm:1 all became /canal/live/arm_1/...: four robots in one
    # topic, with one frame_id, that no reader could tell apart.
    robots = ["arm-1", "arm.1", "arm_1", "arm:1"]
    tracker = canal3.tracker()
    for i, robot in enumerate(robots):
        for k in range(i + 2):  # 2, 3, 4, 5 poses: each robot's count is its own
            p = demos3[1][k]
            recorder.live("pour", robot, p, tracker.step(p), t_ns=1_000_000_000 * (i + 1) + k)
    counts = Counter(topic for topic, _, _ in _read(recorder.export_mcap("pour", profile="ros2"))
                     if topic.startswith("/canal/live/") and topic.endswith("/pose"))
    assert len(counts) == 4, counts
    assert counts["/canal/live/arm_1/pose"] == 4  # the name that is a token keeps it
    assert sorted(counts.values()) == [2, 3, 4, 5], counts
    # the same topics in every export
    again = Counter(topic for topic, _, _ in _read(recorder.export_mcap("pour", profile="ros2"))
                    if topic.startswith("/canal/live/") and topic.endswith("/pose"))
    assert again == counts
