"""Live recording from the recorder's own Zenoh session (real sessions on 127.0.0.1).

A plain session listens where the bridge would; a robot session (client mode) puts poses and
targets on the real keys in JSON, binary v1 and ROS 2 CDR (serialised with ``rosbags``, an
independent implementation). The recording is read back with mcap's reader.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import orjson
import pytest
import zenoh
from canal_service.recording import Recorder
from canal_service.recording.live import LiveOptions, LiveSubscriber
from canal_testing import free_port
from recording_helpers import mcap_messages

from canal_protocol import wire


def _config(mode: str, listen: list[str] | None = None,
            connect: list[str] | None = None) -> zenoh.Config:
    config = zenoh.Config()
    config.insert_json5("mode", orjson.dumps(mode).decode())
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("listen/endpoints", orjson.dumps(listen or []).decode())
    config.insert_json5("connect/endpoints", orjson.dumps(connect or []).decode())
    return config


@pytest.fixture
def live(tmp_path: Path) -> Iterator[tuple[Recorder, LiveSubscriber, Any]]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    bridge = zenoh.open(_config("peer", listen=[endpoint]))  # where the bridge listens
    rec = Recorder(tmp_path / "rec", flush_interval_s=0.1, live_max_hz=None)
    sub = LiveSubscriber(rec, LiveOptions(listen=(endpoint,), interval_s=0.02))
    sub.start()
    rec.live_source = sub
    robot = zenoh.open(_config("client", connect=[endpoint]))
    try:
        # Wait until the recorder's session hears the robot (it connects with retries).
        deadline = time.monotonic() + 10
        while sub.stats.received == 0 and time.monotonic() < deadline:
            robot.put("canal/warmup/r0/pose", wire.encode_pose_json(0, [0.0, 0.0, 0.0]),
                      encoding=wire.JSON_ENCODING)
            time.sleep(0.05)
        assert sub.stats.received > 0, "the recorder's session never heard the robot"
        yield rec, sub, robot
    finally:
        robot.close()
        rec.close()
        bridge.close()


def _wait_for(sub: LiveSubscriber, n: int) -> None:
    deadline = time.monotonic() + 10
    while sub.stats.received < n and time.monotonic() < deadline:
        time.sleep(0.02)


def test_json_and_binary_poses_and_targets_are_recorded_with_orientations(live: Any) -> None:
    rec, sub, robot = live
    base = sub.stats.received
    angle = np.linspace(0.0, np.pi / 2, 20)
    quats = np.c_[np.zeros(20), np.zeros(20), np.sin(angle / 2), np.cos(angle / 2)]
    for k in range(20):
        pos = [0.1 * k, 0.0, 0.5]
        robot.put("canal/pour/arm1/pose", wire.encode_pose_json(k + 1, pos, quats[k].tolist()),
                  encoding=wire.JSON_ENCODING)
        robot.put("canal/pour/arm2/pose", wire.encode_pose(k + 1, pos, quats[k].tolist()))
        robot.put("canal/pour/arm1/target", wire.pack_target_json(
            k + 1, "ok", [0.1 * k + 0.05, 0.0, 0.5], k / 19, 0.3, k, True, k == 19, 1),
            encoding=wire.JSON_ENCODING)
        robot.put("canal/pour/arm2/target", wire.pack_target(
            k + 1, 0, [0.1 * k + 0.05, 0.0, 0.5], k / 19, 0.3, k, True, False, 1))
        time.sleep(0.002)
    _wait_for(sub, base + 80)
    path = rec.export_mcap("pour")
    for robot_name in ("arm1", "arm2"):
        poses = mcap_messages(path, f"/live/{robot_name}/pose")
        assert len(poses) == 20
        q = poses[-1]["pose"]["orientation"]
        assert np.allclose([q["x"], q["y"], q["z"], q["w"]], quats[-1])  # not identity
        assert [p["pose"]["position"]["x"] for p in poses] == pytest.approx(
            [0.1 * k for k in range(20)])
        targets = mcap_messages(path, f"/live/{robot_name}/target")
        assert len(targets) == 20
        states = mcap_messages(path, f"/live/{robot_name}/state")
        assert states[-1]["progress"] == pytest.approx(1.0)
    assert mcap_messages(path, "/live/arm1/state")[-1]["done"] is True
    # The robot frame in /tf turns with the robot.
    tf = [m for m in mcap_messages(path, "/tf") if m["child_frame_id"] == "robot/arm1"]
    assert tf[-1]["rotation"]["z"] == pytest.approx(quats[-1][2])
    assert sub.stats.missed_poses == 0 and sub.stats.bad_payload == 0


def test_ros2_cdr_pose_stamped_is_decoded_with_its_orientation(live: Any) -> None:
    from rosbags import typesys as rosbags

    store = rosbags.get_typestore(rosbags.Stores.ROS2_HUMBLE)
    names = "geometry_msgs/msg/"
    msg_t = store.types[f"{names}PoseStamped"]
    header_t = store.types["std_msgs/msg/Header"]
    time_t = store.types["builtin_interfaces/msg/Time"]
    pose_t, point_t, quat_t = (store.types[f"{names}{t}"] for t in ("Pose", "Point", "Quaternion"))
    rec, sub, robot = live
    base = sub.stats.received
    q = [0.0, 0.0, np.sin(0.3), np.cos(0.3)]
    for k in range(5):
        msg = msg_t(header=header_t(stamp=time_t(sec=k, nanosec=0), frame_id="base_link"),
                    pose=pose_t(position=point_t(x=1.0 + k, y=2.0, z=3.0),
                                orientation=quat_t(x=q[0], y=q[1], z=q[2], w=q[3])))
        data = bytes(store.serialize_cdr(msg, "geometry_msgs/msg/PoseStamped"))
        robot.put("canal/pour/ros/pose", data)
        time.sleep(0.002)
    robot.put("canal/pour/ros/pose", b"\x00\x01\x00\x00garbage")  # CDR header, not a pose
    _wait_for(sub, base + 6)
    poses = mcap_messages(rec.export_mcap("pour"), "/live/ros/pose")
    assert [p["pose"]["position"]["x"] for p in poses] == [1.0, 2.0, 3.0, 4.0, 5.0]
    o = poses[0]["pose"]["orientation"]
    assert np.allclose([o["x"], o["y"], o["z"], o["w"]], q)
    assert sub.stats.bad_payload == 1


def test_garbage_and_gaps_are_counted_not_recorded(live: Any) -> None:
    rec, sub, robot = live
    base = sub.stats.received
    robot.put("canal/pour/arm1/pose", wire.encode_pose(1, [0.0, 0.0, 0.0]))
    robot.put("canal/pour/arm1/pose", wire.encode_pose(5, [1.0, 0.0, 0.0]))  # 3 poses missed
    robot.put("canal/pour/arm1/pose", b"\x07not a pose")
    robot.put("canal/pour/arm1/pose", b"{not json")
    _wait_for(sub, base + 4)
    assert sub.stats.bad_payload == 2
    assert sub.stats.missed_poses == 3
    assert len(mcap_messages(rec.export_mcap("pour"), "/live/arm1/pose")) == 2
    health = rec.health()["live"]
    assert health["status"] == "ok" and health["missed_poses"] == 3


def test_a_zenoh_config_file_is_used_with_its_listen_endpoints_as_connect(tmp_path: Path) -> None:
    from canal_service.recording.live import zenoh_config

    path = tmp_path / "zenoh.json5"
    path.write_text('{ mode: "peer", listen: { endpoints: ["tcp/0.0.0.0:7447"] },'
                    ' connect: { endpoints: ["tcp/10.0.0.5:7447"] } }')
    config = zenoh_config(LiveOptions(config_file=path))
    assert orjson.loads(config.get_json("listen/endpoints")) == []
    assert orjson.loads(config.get_json("connect/endpoints")) == ["tcp/10.0.0.5:7447",
                                                                   "tcp/127.0.0.1:7447"]
    assert orjson.loads(config.get_json("mode")) == "peer"
