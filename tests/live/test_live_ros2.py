"""ROS 2 on the live path: CDR geometry_msgs/msg/PoseStamped in and out, serialised and read
back with rosbags (an independent CDR implementation), never with our own encoder."""

from __future__ import annotations

import threading
import time
from dataclasses import replace

import numpy as np
import orjson
import pytest
import zenoh
from canal_client.live import PoseStreamer, client_config
from rosbags import typesys as rosbags_typesys

from canal_protocol import wire

TS = rosbags_typesys.get_typestore(rosbags_typesys.Stores.ROS2_HUMBLE)
T = TS.types
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"

pytestmark = pytest.mark.timeout(60)


def pose_stamped(position, orientation=(0.0, 0.0, 0.0, 1.0), frame_id="base_link",
                 sec=12, nanosec=345, little_endian=True) -> bytes:
    if len(position) == 2:
        position = [*position, 0.7]
    msg = T[POSE_STAMPED](
        header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](
            sec=sec, nanosec=nanosec), frame_id=frame_id),
        pose=T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](x=float(position[0]), y=float(position[1]),
                                                  z=float(position[2])),
            orientation=T["geometry_msgs/msg/Quaternion"](
                x=orientation[0], y=orientation[1], z=orientation[2], w=orientation[3])))
    return bytes(TS.serialize_cdr(msg, POSE_STAMPED, little_endian=little_endian))


class Robot:
    """A ROS 2 robot behind a bridge: CDR puts on .../pose, listens on .../target, .../status."""

    def __init__(self, session, skill, robot):
        self.session = session
        self.base = f"canal/{skill}/{robot}"
        self.targets: list[bytes] = []
        self.statuses: list[dict] = []
        self.cond = threading.Condition()
        self.subs = [
            session.declare_subscriber(self.base + "/target", self._target),
            session.declare_subscriber(self.base + "/status", self._status)]
        self.pub = session.declare_publisher(self.base + "/pose")
        deadline = time.monotonic() + 5
        while not self.pub.matching_status.matching and time.monotonic() < deadline:
            time.sleep(0.01)

    def _target(self, sample):
        with self.cond:
            self.targets.append(sample.payload.to_bytes())
            self.cond.notify_all()

    def _status(self, sample):
        with self.cond:
            self.statuses.append(orjson.loads(sample.payload.to_bytes()))
            self.cond.notify_all()

    def put(self, data, encoding=None):
        if encoding is None:
            self.pub.put(data)
        else:
            self.pub.put(data, encoding=encoding)

    def put_answered(self, data, encoding=None):
        """Put one pose and wait for its target: a backlog of poses put at once is
        coalesced to one answer for its newest pose, so counting targets needs one at a time."""
        n = len(self.targets)
        self.put(data, encoding)
        assert len(self.wait("targets", n + 1)) == n + 1, "no target for the pose"

    def wait(self, what, n, timeout=10.0):
        deadline = time.monotonic() + timeout
        with self.cond:
            while len(getattr(self, what)) < n and time.monotonic() < deadline:
                self.cond.wait(0.05)
            return list(getattr(self, what))

    def close(self):
        for s in self.subs:
            s.undeclare()
        self.pub.undeclare()


def _directrix(live, skill="arc3"):
    return np.array(live.client.get(f"/skills/{skill}/models/latest").json()["directrix"])


@pytest.mark.parametrize("encoding", [None, zenoh.Encoding.APPLICATION_CDR,
                                      zenoh.Encoding.APPLICATION_OCTET_STREAM])
@pytest.mark.parametrize("little_endian", [True, False])
def test_cdr_pose_stamped_is_answered_with_a_cdr_pose_stamped(live, encoding, little_endian):
    directrix = _directrix(live)
    quat = (0.0, np.sin(0.2), 0.0, np.cos(0.2))
    robot_name = f"ros-{str(encoding).replace('/', '-')}-{little_endian}"
    with zenoh.open(client_config(live.endpoint)) as session, \
            PoseStreamer("arc3", robot_name + "-json", endpoint=live.endpoint,
                         encoding="json", session=session) as twin:
        robot = Robot(session, "arc3", robot_name)
        try:
            for k, frame in enumerate(["base_link", "", "world_frame_7"]):
                x = directrix[10 + 5 * k] + [0.0, 0.004, 0.0]
                robot.put(pose_stamped(x, quat, frame, sec=100 + k, nanosec=7 * k,
                                       little_endian=little_endian), encoding)
                got = robot.wait("targets", k + 1)
                assert len(got) == k + 1, "no CDR answer"
                answer = TS.deserialize_cdr(got[k], POSE_STAMPED)
                assert answer.header.frame_id == frame
                assert (answer.header.stamp.sec, answer.header.stamp.nanosec) == (100 + k, 7 * k)
                # orientation: the model has none, so the pose's own comes back
                q = answer.pose.orientation
                np.testing.assert_allclose([q.x, q.y, q.z, q.w], quat)
                # position: what a JSON robot at the same place is told
                json_answer = twin.wait_for(twin.send(x, restart=k == 0), 1.0)
                p = answer.pose.position
                np.testing.assert_allclose([p.x, p.y, p.z], json_answer.target, atol=1e-12)
                assert json_answer.orientation is None  # a JSON pose without one has none
            # the status travels on its own key: on a loaded machine it may land after the targets
            robot.wait("statuses", 1)
        finally:
            robot.close()
    # ok statuses are announced on change only: the first answer said "ok", nothing since
    assert [s["status"] for s in robot.statuses] == ["ok"]


def test_cdr_errors_go_to_the_status_key_as_json(live):
    with zenoh.open(client_config(live.endpoint)) as session:
        unknown = Robot(session, "no-such-skill", "ros")
        bad = Robot(session, "arc3", "ros-bad")
        try:
            unknown.put(pose_stamped([0.1, 0.2, 0.3]))
            status = unknown.wait("statuses", 1)
            assert status and status[0]["status"] == "unknown_skill" and status[0]["message"]
            good = pose_stamped([0.1, 0.2, 0.3])
            bad.put(good[:30], zenoh.Encoding.APPLICATION_CDR)  # truncated
            bad.put(b"\x00\x01\x00\x00" + b"\xff" * 8)  # frame_id length beyond the data
            nan = pose_stamped([float("nan"), 0.2, 0.3])
            bad.put(nan)
            # numbers out of range, as in every encoding: named in the message
            bad.put(pose_stamped([0.1, 0.2, 0.3], (0.0, 0.0, 0.0, 0.0)))
            bad.put(pose_stamped([1e308, 0.2, 0.3]))
            statuses = bad.wait("statuses", 5)
            assert [s["status"] for s in statuses] == ["bad_payload", "bad_payload",
                                                       "non_finite", "bad_payload",
                                                       "bad_payload"]
            assert "orientation" in statuses[3]["message"]
            assert "position" in statuses[4]["message"]
            assert unknown.targets == [] and bad.targets == []
        finally:
            unknown.close()
            bad.close()


def test_cdr_far_pose_answers_a_way_back_and_says_outside(live):
    with zenoh.open(client_config(live.endpoint)) as session:
        robot = Robot(session, "arc3", "ros-far")
        try:
            robot.put(pose_stamped([50.0, 50.0, 50.0]))
            targets = robot.wait("targets", 1)
            statuses = robot.wait("statuses", 1)
            assert statuses[0]["status"] == "outside_canal" and not statuses[0]["done"]
            p = TS.deserialize_cdr(targets[0], POSE_STAMPED).pose.position
            assert np.isfinite([p.x, p.y, p.z]).all() and abs(p.x) < 5
        finally:
            robot.close()


def test_cdr_on_a_2d_skill_carries_z(live):
    directrix = _directrix(live, "arc2")
    with zenoh.open(client_config(live.endpoint)) as session:
        robot = Robot(session, "arc2", "ros-2d")
        try:
            robot.put(pose_stamped(directrix[20]))
            got = robot.wait("targets", 1)
            p = TS.deserialize_cdr(got[0], POSE_STAMPED).pose.position
            assert p.z == 0.7  # the pose's own z, untouched
            assert np.linalg.norm(np.array([p.x, p.y]) - directrix[22]) < 0.1
        finally:
            robot.close()


def test_a_demonstration_captured_from_pose_stamped_on_a_2d_skill_keeps_x_and_y(live):
    # A PoseStamped always has z; the tracker reads x, y on a 2-D skill, and so must the
    # capture: it used to store nothing, refusing every row for its third value.
    from canal_client.live import query_json

    pts = np.column_stack([np.linspace(0, 1, 30), np.linspace(0, 0.5, 30)])
    with zenoh.open(client_config(live.endpoint)) as session:
        robot = Robot(session, "arc2", "ros-demo")
        try:
            query_json(session, "canal/arc2/ros-demo/demo/start", {"label": "from ROS 2"})
            for k, p in enumerate(pts):
                robot.put_answered(pose_stamped(p, sec=100 + k), encoding="application/cdr")
            created = query_json(session, "canal/arc2/ros-demo/demo/stop", {})
        finally:
            robot.close()
    demo = live.client.get(f"/skills/arc2/demonstrations/{created['id']}").json()
    assert np.array_equal(np.array(demo["positions"]), pts)
    assert np.allclose(np.diff(demo["timestamps"]), 1.0)  # the messages' stamps
    live.client.delete(f"/skills/arc2/demonstrations/{created['id']}")


@pytest.mark.parametrize("frame", ["", "a", "ab", "abc", "abcd", "base_link", "x" * 300])
def test_wire_cdr_codec_agrees_with_rosbags(frame):
    for little in (True, False):
        data = pose_stamped([1.5, -2.25, 3.0], (0.1, 0.2, 0.3, 0.9), frame, 5, 6, little)
        pose, stamp = wire.decode_pose_cdr(data, seq=9)
        assert pose.position == (1.5, -2.25, 3.0) and pose.orientation == (0.1, 0.2, 0.3, 0.9)
        assert (stamp.sec, stamp.nanosec, stamp.frame_id, stamp.little) == (5, 6, frame, little)
        back = TS.deserialize_cdr(
            wire.encode_pose_stamped_cdr(stamp, [4.0, 5.0, 6.0], (0.0, 0.0, 0.0, 1.0)),
            POSE_STAMPED)
        assert back.header.frame_id == frame and back.header.stamp.nanosec == 6
        assert (back.pose.position.x, back.pose.position.z) == (4.0, 6.0)


@pytest.mark.parametrize("encoding", ["json", "binary"])
def test_targets_carry_the_orientation(live, encoding):
    directrix = _directrix(live)
    quat = (0.0, 0.0, np.sin(0.3), np.cos(0.3))
    with PoseStreamer("arc3", f"oriented-{encoding}", endpoint=live.endpoint,
                      encoding=encoding) as ps:
        answer = ps.wait_for(ps.send(directrix[12], quat, restart=True), 1.0)
        assert answer is not None and answer.status == "ok"
        np.testing.assert_allclose(answer.orientation, quat)
        plain = ps.wait_for(ps.send(directrix[13]), 1.0)
        assert plain.orientation is None


def test_binary_target_extras_keep_old_readers_working():
    """A reader of the original layout (fixed part, then the message) still reads a target
    with orientation, velocity and coalesced count: the extras come after all of it."""
    import struct

    answer = wire.Target(3, "ok", (1.0, 2.0, 3.0), 0.5, 0.1, 4, True, False, 2,
                         orientation=(0.0, 0.0, 0.0, 1.0), velocity=(0.1, 0.2, 0.3),
                         coalesced=7)
    data = wire.encode_target(answer)
    assert len(data) == 62 + 32 + 24 + 4
    old = struct.unpack_from("<BBBBQiiddH3d", data)
    assert old[:2] == (1, 2) and old[4] == 3 and old[-3:] == (1.0, 2.0, 3.0)
    assert old[2] & 0x0F == 0x05  # the old flags mean what they meant
    assert wire.decode_target(data) == answer
    fast = wire.pack_target(3, 0, [1.0, 2.0, 3.0], 0.5, 0.1, 4, True, False, 2,
                            (0.0, 0.0, 0.0, 1.0), (0.1, 0.2, 0.3), 7)
    assert fast == data
    doc = orjson.loads(wire.pack_target_json(3, "ok", [1.0, 2.0, 3.0], 0.5, 0.1, 4, True,
                                             False, 2, (0.0, 0.0, 0.0, 1.0), None, 7))
    assert doc["orientation"] == [0.0, 0.0, 0.0, 1.0] and doc["coalesced"] == 7
    assert "velocity" not in doc
    # the route (flag 0x80, a uint16 after the coalesced count) of a model of several routes
    routed = wire.encode_target(replace(answer, route=1))
    assert routed[:len(data)] == data[:2] + bytes([data[2] | 0x80]) + data[3:]
    assert len(routed) == len(data) + 2 and struct.unpack_from("<H", routed, len(data)) == (1,)
    assert wire.decode_target(routed) == replace(answer, route=1)
    assert wire.pack_target(3, 0, [1.0, 2.0, 3.0], 0.5, 0.1, 4, True, False, 2,
                            (0.0, 0.0, 0.0, 1.0), (0.1, 0.2, 0.3), 7, 1) == routed
    bare = wire.pack_target(3, 0, [1.0, 2.0, 3.0], 0.5, 0.1, 4, True, False, 2, route=0)
    assert len(bare) == 62 + 2 and wire.decode_target(bare).route == 0
    assert wire.decode_target(wire.pack_target(3, 0, [1.0, 2.0, 3.0], 0.5, 0.1, 4, True, False,
                                               2)).route is None


def test_rmw_zenoh_adapter_round_trip(live):
    """examples/ros2/rmw_zenoh_adapter.py: a robot publishing on rmw_zenoh's key for
    /canal/arc3/rosbot/pose gets Canal's CDR answer on rmw_zenoh's key for .../target."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "examples" / "ros2" / "rmw_zenoh_adapter.py"
    spec = importlib.util.spec_from_file_location("rmw_zenoh_adapter", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    type_hash = "RIHS01_0123456789abcdef"
    ros_pose = f"0/canal/arc3/rosbot/pose/{module.POSE_TYPE}/{type_hash}"
    ros_target = f"0/canal/arc3/rosbot/target/{module.POSE_TYPE}/{type_hash}"
    directrix = _directrix(live)
    got: list[bytes] = []
    from canal_testing import free_port

    # peers do not route for each other: the robot talks to the adapter, the adapter to Canal
    near = f"tcp/127.0.0.1:{free_port()}"
    adapter_config = client_config(live.endpoint)
    adapter_config.insert_json5("listen/endpoints", f'["{near}"]')
    with zenoh.open(adapter_config) as adapter_session, \
            zenoh.open(client_config(near)) as robot:
        adapter = module.Adapter(adapter_session)
        robot.declare_subscriber(ros_target, lambda s: got.append(s.payload.to_bytes()))
        # declarations travel robot -> adapter -> bridge: repeat the pose until they have
        deadline = time.monotonic() + 10
        while not got and time.monotonic() < deadline:
            robot.put(ros_pose, pose_stamped(directrix[30], frame_id="tool0", sec=3))
            time.sleep(0.2)
        adapter.close()
    assert got, "no target on the rmw_zenoh key"
    answer = TS.deserialize_cdr(got[0], POSE_STAMPED)
    assert answer.header.frame_id == "tool0" and answer.header.stamp.sec == 3
    assert np.linalg.norm([answer.pose.position.x - directrix[32][0],
                           answer.pose.position.y - directrix[32][1]]) < 0.1


def test_a_capture_of_pose_stamped_with_unset_stamps_is_stored_untimed(live):
    # A PoseStamped whose header.stamp is left at zero (as a `ros2 topic pub` without a
    # stamp sends) made every captured t 0: demo/stop refused the demonstration for
    # timestamps that do not advance and ended the capture, losing it. Stamps that are set
    # but do not advance are still refused, and the capture stays open to start over.
    from canal_client.live import LiveError, query_json

    directrix = _directrix(live)
    base = "canal/arc3/ros-unset"
    with zenoh.open(client_config(live.endpoint)) as session:
        robot = Robot(session, "arc3", "ros-unset")
        try:
            def capture(sec_of, discarded=0):
                started = query_json(session, base + "/demo/start", {})
                assert started["discarded"] == discarded, started
                for k in range(30):
                    robot.put_answered(pose_stamped(directrix[5 + 3 * k], sec=sec_of(k), nanosec=0),
                                       encoding="application/cdr")

            capture(lambda k: 0)
            created = query_json(session, base + "/demo/stop", {})
            assert created["n_points"] == 30, created
            demo = live.client.get(f"/skills/arc3/demonstrations/{created['id']}").json()
            assert demo["timestamps"] is None, demo["timestamps"]
            assert np.array_equal(np.array(demo["positions"]), directrix[5:95:3])
            live.client.delete(f"/skills/arc3/demonstrations/{created['id']}")

            n_demos = live.client.get("/skills/arc3").json()["n_demonstrations"]
            capture(lambda k: 7)  # set, and all the same
            with pytest.raises(LiveError) as err:
                query_json(session, base + "/demo/stop", {})
            error = err.value.body["error"]
            assert (error["type"], error["field"]) == ("invalid_input", "timestamps"), error
            assert "30 equal values" in error["message"], error
            assert live.client.get("/skills/arc3").json()["n_demonstrations"] == n_demos
            # the refused capture is still open: starting it over says what it throws away
            capture(lambda k: 100 + k, discarded=30)
            created = query_json(session, base + "/demo/stop", {})
            assert created["n_points"] == 30, created
            demo = live.client.get(f"/skills/arc3/demonstrations/{created['id']}").json()
            assert np.allclose(np.diff(demo["timestamps"]), 1.0)
            live.client.delete(f"/skills/arc3/demonstrations/{created['id']}")
        finally:
            robot.close()
