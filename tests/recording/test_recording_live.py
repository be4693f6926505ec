"""Live recording fed by the bridge's batches (real app, real Zenoh on 127.0.0.1, the
recording read back with mcap's reader).

The bridge runs in the test's process (``zenoh_processes=0``) except in the crash test, where
``canal serve``'s bridge process is killed. Robots are real Zenoh sessions; ROS 2 poses are
serialised with ``rosbags`` (an independent implementation).
"""

from __future__ import annotations

import logging
import os
import signal
import time
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import orjson
import pytest
import zenoh

with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    from fastapi.testclient import TestClient

from canal_client.live import PoseStreamer, client_config
from canal_service import record_batches
from canal_service.app import create_app
from canal_service.core.config import Settings
from canal_service.recording.live import LiveOptions
from canal_testing import arc_demo, free_port
from recording_helpers import mcap_counts, mcap_messages

from canal_protocol import keys as keyspace
from canal_protocol import wire

pytestmark = pytest.mark.timeout(120)
os.environ.setdefault("RERUN_TELEMETRY_ENABLED", "false")


def _make_skill(client: TestClient, name: str, dim: int = 3) -> np.ndarray:
    assert client.post("/skills", json={"name": name, "dim": dim}).status_code == 201
    for j in range(4):
        r = client.post(f"/skills/{name}/demonstrations",
                        json={"positions": arc_demo(j, 60, dim, 0, spread=0.03).tolist()})
        assert r.status_code == 201, r.text
    assert client.post(f"/skills/{name}/fit", json={"n_samples": 100}).status_code == 201
    return np.array(client.get(f"/skills/{name}/models/latest").json()["directrix"])


def _app(tmp: Path, **overrides: Any) -> tuple[TestClient, str]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    values: dict[str, Any] = dict(data_dir=tmp, recordings_enabled=True,
                                  zenoh_listen=[endpoint], zenoh_processes=0)
    values.update(overrides)
    return TestClient(create_app(Settings(**values))), endpoint


def _live_health(client: TestClient) -> dict[str, Any]:
    return client.get("/healthz").json()["recorder"]["live"]  # type: ignore[no-any-return]


def _settled(client: TestClient, poses: int, timeout: float = 15.0,
             stream: str | None = None) -> dict[str, Any]:
    """The recorder's live block once it has heard of ``poses`` poses (in total, or of
    ``stream`` when the app is shared with earlier tests) and flushed them."""
    deadline = time.monotonic() + timeout
    while True:
        live = _live_health(client)
        heard = live["poses"] if stream is None else live["streams"].get(stream, {}).get(
            "poses", 0)
        if (heard >= poses and live["pending"] == 0) or time.monotonic() > deadline:
            return live
        time.sleep(0.1)


def _mcap(client: TestClient, skill: str, tmp: Path) -> Path:
    r = client.get(f"/skills/{skill}/recording.mcap")
    assert r.status_code == 200, r.text
    path = tmp / f"{skill}.mcap"
    path.write_bytes(r.content)
    return path


@pytest.fixture(scope="module")
def app(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[TestClient, str, Path]]:
    tmp = tmp_path_factory.mktemp("live-rec")
    client, endpoint = _app(tmp, recordings_live_hz=100.0)
    with client:
        yield client, endpoint, tmp


def test_recording_holds_the_decimated_stream_and_counts_add_up_to_what_was_sent(app):
    client, endpoint, tmp = app
    directrix = _make_skill(client, "pour")
    n = 600
    path = np.linspace(0, len(directrix) - 1, n)
    points = np.array([directrix[int(i)] for i in path])
    q = [0.0, 0.0, np.sin(0.2), np.cos(0.2)]
    started = time.monotonic()
    with PoseStreamer("pour", "arm1", endpoint=endpoint, encoding="json") as ps:
        for k in range(n):
            ps.send(points[k], q, restart=k == 0)
            time.sleep(0.001)  # ~1 kHz at most
        assert ps.wait_for(n - 1, 5.0) is not None
    seconds = time.monotonic() - started
    live = _settled(client, n)
    stream = live["streams"]["pour/arm1"]
    assert stream["poses"] == n  # every pose the robot sent, as the bridge counted it
    assert stream["answered"] + stream["errors"] + stream["coalesced"] == n
    assert stream["recorded"] + stream["decimated"] == n and stream["dropped"] == 0
    assert live["complete"] is True and live["lost_batches"] == 0
    # decimated to ~100 Hz: at most one row per 10 ms (plus the flips), far fewer than sent
    assert 0.5 * seconds * 100 <= stream["recorded"] <= seconds * 100 + 20
    poses = mcap_messages(_mcap(client, "pour", tmp), "/live/arm1/pose")
    assert len(poses) == stream["recorded"]
    xs = np.array([[p["pose"]["position"][c] for c in "xyz"] for p in poses])
    # the recorded poses are the robot's own positions, in the order sent
    idx = [int(np.argmin(np.linalg.norm(points - x, axis=1))) for x in xs]
    assert np.allclose(xs, points[idx]) and idx == sorted(idx)
    o = poses[-1]["pose"]["orientation"]
    assert np.allclose([o["x"], o["y"], o["z"], o["w"]], q)
    targets = mcap_messages(_mcap(client, "pour", tmp), "/live/arm1/target")
    assert len(targets) == len(poses)
    # the metrics say the same: every pose handled is recorded or decimated
    bridge = client.app.state.bridge  # type: ignore[attr-defined]
    bridge.flush_metrics()
    text = client.get("/metrics").text
    values = {line.split()[0]: float(line.split()[1]) for line in text.splitlines()
              if line.startswith("canal_live_poses_")}
    assert (values["canal_live_poses_recorded_total"]
            + values["canal_live_poses_decimated_total"]) == values["canal_live_poses_total"]


def test_a_status_flip_is_recorded_between_decimated_samples(tmp_path):
    client, endpoint = _app(tmp_path, recordings_live_hz=0.5)  # one row per 2 s, flips aside
    with client:
        directrix = _make_skill(client, "flip")
        far = directrix[30] + np.array([5.0, 5.0, 5.0])
        sent = [directrix[20], directrix[22], far, far, directrix[24], directrix[26]]
        with PoseStreamer("flip", "arm", endpoint=endpoint) as ps:
            answers = []
            for k, p in enumerate(sent):
                # back in after the excursion: re-located (restart), not lost ahead
                answers.append(ps.wait_for(ps.send(p, restart=k in (0, 4)), 2.0))
        assert [a.status for a in answers] == ["ok", "ok", "outside_canal", "outside_canal",
                                               "ok", "ok"]
        live = _settled(client, len(sent))
        stream = live["streams"]["flip/arm"]
        # the first pose (rate), the flip out (3rd) and the flip back in (5th): 3 of 6
        assert stream["recorded"] == 3 and stream["decimated"] == 3
        states = mcap_messages(_mcap(client, "flip", tmp_path), "/live/arm/state")
        assert [s["inside"] for s in states] == [True, False, True]
        poses = mcap_messages(_mcap(client, "flip", tmp_path), "/live/arm/pose")
        assert poses[1]["pose"]["position"]["x"] == pytest.approx(far[0])


def test_ros2_cdr_stream_is_recorded_from_the_bridge(app):
    from rosbags import typesys as rosbags

    client, endpoint, tmp = app
    directrix = _make_skill(client, "ros")
    store = rosbags.get_typestore(rosbags.Stores.ROS2_HUMBLE)
    g = "geometry_msgs/msg/"
    msg_t, header_t = store.types[f"{g}PoseStamped"], store.types["std_msgs/msg/Header"]
    time_t = store.types["builtin_interfaces/msg/Time"]
    pose_t, point_t, quat_t = (store.types[f"{g}{t}"] for t in ("Pose", "Point", "Quaternion"))
    q = [0.0, 0.0, np.sin(0.3), np.cos(0.3)]
    robot = zenoh.open(client_config(endpoint))
    try:
        seen: list[bytes] = []
        robot.declare_subscriber("canal/ros/cdr/target", lambda s: seen.append(b""))
        time.sleep(0.3)
        for k in range(5):
            p = directrix[10 + 10 * k]
            msg = msg_t(header=header_t(stamp=time_t(sec=k, nanosec=0), frame_id="base"),
                        pose=pose_t(position=point_t(x=p[0], y=p[1], z=p[2]),
                                    orientation=quat_t(x=q[0], y=q[1], z=q[2], w=q[3])))
            robot.put("canal/ros/cdr/pose", bytes(store.serialize_cdr(msg, f"{g}PoseStamped")),
                      encoding=wire.CDR_ENCODING)
            time.sleep(0.03)  # 30 ms apart: every pose is over the 100 Hz rate limit
        deadline = time.monotonic() + 5
        while len(seen) < 5 and time.monotonic() < deadline:
            time.sleep(0.02)
    finally:
        robot.close()
    live = _settled(client, 5, stream="ros/cdr")
    stream = live["streams"]["ros/cdr"]
    # 30 ms apart, each over the rate limit: all kept, unless a loaded machine lets two
    # reach the bridge in one drain (one timestamp: the second is decimated)
    assert stream["recorded"] + stream["decimated"] == 5 and stream["recorded"] >= 2
    poses = mcap_messages(_mcap(client, "ros", tmp), "/live/cdr/pose")
    sent_x = [directrix[10 + 10 * k][0] for k in range(5)]
    xs = [p["pose"]["position"]["x"] for p in poses]
    assert len(xs) == stream["recorded"] and xs[0] == pytest.approx(sent_x[0])
    idx = [int(np.argmin(np.abs(np.array(sent_x) - x))) for x in xs]
    assert xs == pytest.approx([sent_x[i] for i in idx]) and idx == sorted(set(idx))
    o = poses[0]["pose"]["orientation"]
    assert np.allclose([o["x"], o["y"], o["z"], o["w"]], q)


def _pose_stamped(position: Any, sec: int) -> bytes:
    """A ROS 2 PoseStamped (CDR, always x, y, z) serialised by rosbags."""
    from rosbags import typesys as rosbags

    store = rosbags.get_typestore(rosbags.Stores.ROS2_HUMBLE)
    g = "geometry_msgs/msg/"
    msg = store.types[f"{g}PoseStamped"](
        header=store.types["std_msgs/msg/Header"](
            stamp=store.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=0), frame_id="base"),
        pose=store.types[f"{g}Pose"](
            position=store.types[f"{g}Point"](x=position[0], y=position[1], z=position[2]),
            orientation=store.types[f"{g}Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)))
    return bytes(store.serialize_cdr(msg, f"{g}PoseStamped"))


def _batch_failures(caplog: pytest.LogCaptureFixture) -> list[logging.LogRecord]:
    return [r for r in caplog.records if r.name.startswith("canal_service")
            and "recording batch" in r.getMessage()]


def test_ros2_poses_on_a_2d_skill_are_recorded_as_tracked_and_other_robots_with_them(
        app, caplog):
    # A PoseStamped always has z; on a 2-D skill x, y are tracked and z only passed through.
    # Its rows kept z beside a 2-D target: no batch could be encoded, so every robot's rows
    # were lost unseen (no lost batch, no dropped row), with a traceback every 0.1 s.
    client, endpoint, tmp = app
    flat = _make_skill(client, "flat", dim=2)
    onlooker = _make_skill(client, "onlooker")
    before = _live_health(client)
    caplog.set_level(logging.WARNING, logger="canal_service")
    n = 40
    sent = [flat[min(5 + k, len(flat) - 1)] for k in range(n)]
    robot = zenoh.open(client_config(endpoint))
    try:
        answers: list[bytes] = []
        robot.declare_subscriber("canal/flat/ros/target", lambda s: answers.append(b""))
        time.sleep(0.3)
        with PoseStreamer("onlooker", "arm", endpoint=endpoint, encoding="json") as ps:
            for k, p in enumerate(sent):
                if k % 2:  # a ROS 2 robot and a JSON one on the same stream
                    robot.put("canal/flat/ros/pose", _pose_stamped([p[0], p[1], 0.7], 100 + k),
                              encoding=wire.CDR_ENCODING)
                else:
                    robot.put("canal/flat/ros/pose",
                              orjson.dumps({"seq": k, "position": p.tolist()}),
                              encoding=zenoh.Encoding.APPLICATION_JSON)
                ps.send(onlooker[10 + k], restart=k == 0)
                time.sleep(0.01)
            assert ps.wait_for(n - 1, 5.0) is not None
        deadline = time.monotonic() + 5
        while len(answers) < n and time.monotonic() < deadline:
            time.sleep(0.02)
        assert len(answers) == n
    finally:
        robot.close()
    _settled(client, n, stream="flat/ros")
    live = _settled(client, n, stream="onlooker/arm")
    for name in ("flat/ros", "onlooker/arm"):
        stream = live["streams"][name]
        assert stream["poses"] == n, (name, stream)
        assert stream["recorded"] + stream["decimated"] == n and stream["dropped"] == 0
    assert live["lost_batches"] == before["lost_batches"]
    assert _batch_failures(caplog) == []
    poses = mcap_messages(_mcap(client, "flat", tmp), "/live/ros/pose")
    assert len(poses) == live["streams"]["flat/ros"]["recorded"] > 0
    xy = np.array([[p["pose"]["position"][c] for c in "xy"] for p in poses])
    idx = [int(np.argmin(np.linalg.norm(np.array(sent) - x, axis=1))) for x in xy]
    assert np.allclose(xy, np.array(sent)[idx])  # x, y as tracked; z is not
    assert {p["pose"]["position"]["z"] for p in poses} == {0.0}  # the 2-D skill's plane


def test_a_skill_created_again_with_another_dimension_keeps_every_robots_rows(app, caplog):
    # A robot's stream outlives its skill: rows of the deleted 3-D skill and of the 2-D one
    # created again under its name meet in one batch (here the batch is held back while it
    # happens). Each is sent with its own dimension, the old ones counted as stale.
    client, endpoint, tmp = app
    directrix3 = _make_skill(client, "morph")
    watch = _make_skill(client, "watch")
    bridge = client.app.state.bridge  # type: ignore[attr-defined]
    before = _live_health(client)
    caplog.set_level(logging.WARNING, logger="canal_service")
    with PoseStreamer("morph", "arm", endpoint=endpoint) as ps, \
            PoseStreamer("watch", "arm", session=ps.session) as other:
        with bridge._record_lock:  # the recording thread waits: one batch gets it all
            for k in range(5):
                assert ps.wait_for(ps.send(directrix3[10 + 5 * k], restart=k == 0), 5.0)
            assert client.delete("/skills/morph").status_code == 204
            directrix2 = _make_skill(client, "morph", dim=2)
            for k in range(5):
                answer = ps.wait_for(ps.send(directrix2[10 + 5 * k], restart=k == 0), 5.0)
                assert answer is not None and answer.status == "ok"
            for k in range(5):
                assert other.wait_for(other.send(watch[10 + 5 * k], restart=k == 0), 5.0)
    live = _settled(client, 10, stream="morph/arm")
    arm, onlooker = live["streams"]["morph/arm"], live["streams"]["watch/arm"]
    assert arm["poses"] == 10 and arm["dropped"] == 0 and arm["pending"] == 0
    assert arm["recorded"] + arm["stale"] + arm["decimated"] == 10
    assert arm["stale"] >= 1 and arm["recorded"] >= 1  # the first pose of each is kept
    assert onlooker["poses"] == 5 and onlooker["recorded"] + onlooker["decimated"] == 5
    assert live["lost_batches"] == before["lost_batches"]
    assert _batch_failures(caplog) == []
    poses = mcap_messages(_mcap(client, "morph", tmp), "/live/arm/pose")
    assert len(poses) == arm["recorded"]  # the new skill's own, in its plane
    assert {p["pose"]["position"]["z"] for p in poses} == {0.0}


def test_a_deleted_skills_late_rows_are_stale_not_lost(tmp_path):
    # The rows a bridge kept for a skill deleted since were counted as dropped (a loss:
    # `complete` false until the service restarted); its recording is gone with it.
    client, endpoint = _app(tmp_path, recordings_live_hz=0.0)
    with client:
        directrix = _make_skill(client, "gone")
        bridge = client.app.state.bridge  # type: ignore[attr-defined]
        with PoseStreamer("gone", "arm", endpoint=endpoint) as ps:
            with bridge._record_lock:  # the rows are still in the bridge at the delete
                for k in range(20):
                    assert ps.wait_for(ps.send(directrix[10 + k], restart=k == 0), 5.0)
                assert client.delete("/skills/gone").status_code == 204
        live = _settled(client, 20)
        stream = live["streams"]["gone/arm"]
        assert stream["poses"] == 20 and stream["stale"] + stream["coalesced"] == 20
        assert stream["dropped"] == 0 and stream["recorded"] == 0 and stream["pending"] == 0
        assert live["complete"] is True and live["dropped"] == 0
        assert live["stale"] == stream["stale"]
        # (plus the skill's demonstrations and fit, when the writer had not written them yet)
        assert client.get("/healthz").json()["recorder"]["stale"] >= 2 * stream["stale"]


def test_forged_garbage_and_missing_batches_are_counted_not_recorded(app):
    client, endpoint, tmp = app
    before = _live_health(client)
    config = client_config(endpoint)
    # client mode: the bridge's session routes its puts (a peer would need the recorder's
    # session to listen, and it listens nowhere)
    config.insert_json5("mode", '"client"')
    stranger = zenoh.open(config)
    try:
        time.sleep(0.3)
        key = keyspace.recorder_key("x1", "canal")
        row = [1, [0.0, 0.0, 0.0], None, [0.0, 0.0, 0.0], None, 0.0, 0.1, 0, True, False, "ok"]

        def batch(n: int, bridge: str = "x1", rows: int = 1, poses: int = 1) -> bytes:
            return record_batches.encode_record_batch(bridge, n, [
                ("forged", "r", poses, poses, 0, 0, poses - rows, [row] * rows)])

        stranger.put(key, b"{not json")
        stranger.put(key, batch(0, bridge="someone-else"))  # the key names another bridge
        stranger.put(key, batch(0, rows=2, poses=1))  # more rows than poses
        stranger.put(key, batch(0))
        stranger.put(key, batch(3))  # batches 1 and 2 never came
        deadline = time.monotonic() + 5
        while (_live_health(client)["batches"] < before["batches"] + 2
               and time.monotonic() < deadline):
            time.sleep(0.05)
    finally:
        stranger.close()
    live = _settled(client, 0)
    assert live["bad_payload"] == before["bad_payload"] + 3
    assert live["lost_batches"] == before["lost_batches"] + 2
    assert live["complete"] is False  # a lost batch: the recording cannot be complete
    # the two well-formed rows name a skill the database does not hold: counted, not recorded
    assert live["streams"]["forged/r"]["recorded"] == 0
    assert live["streams"]["forged/r"]["dropped"] == 2


def test_recorder_keys_are_verbatim_and_never_a_streams() -> None:
    key = keyspace.recorder_key("b0-12-ab", "canal")
    assert key == "canal/@recorder/live/b0-12-ab"
    assert keyspace.bridge_of_batch(key) == "b0-12-ab"
    assert keyspace.bridge_of_batch("canal/@recorder/live/*") is None
    assert keyspace.stream_of(key.replace("/live/b0-12-ab", "/x/pose")) is None
    # Zenoh: '**' (a stranger's or a robot's wildcard) does not reach a verbatim chunk
    assert not zenoh.KeyExpr("canal/**").intersects(zenoh.KeyExpr(key))
    assert zenoh.KeyExpr(keyspace.recorder_wildcard()).intersects(zenoh.KeyExpr(key))
    assert LiveOptions().capacity > 0


def test_a_killed_bridge_process_loses_at_most_its_last_batch(tmp_path):
    """``canal serve``'s bridge process, kill -9: what it handled up to its last batch is
    recorded; the poses after it are the only ones missing."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    settings = Settings(data_dir=tmp_path, recordings_enabled=True, zenoh_listen=[endpoint],
                        recordings_live_hz=0.0)  # keep every pose: the count is exact
    with TestClient(create_app(settings)) as client:
        directrix = _make_skill(client, "crash")
        with PoseStreamer("crash", "arm", endpoint=endpoint) as ps:
            for k in range(200):
                ps.send(directrix[k % 90], restart=k == 0)
                time.sleep(0.001)
            assert ps.wait_for(199, 5.0) is not None
            # Everything handled reaches the recorder in the bridge's next batches (a bridge
            # holds them for up to RECORDER_WAIT_S while the recorder's session connects,
            # which a cold start can make later than the last answer): then the kill.
            heard = _settled(client, 200, stream="crash/arm")["streams"]["crash/arm"]
            assert heard["poses"] == 200
            pid = client.app.state.bridge.children[0].proc.pid  # type: ignore[attr-defined]
            os.kill(pid, signal.SIGKILL)
            for k in range(50):  # into the void: the bridge is gone
                ps.send(directrix[k], restart=False)
        live = _settled(client, 200)
        stream = live["streams"]["crash/arm"]
        # every pose is kept, but a loaded machine can make the bridge coalesce (latest
        # pose wins): those are counted, never lost
        assert stream["poses"] == 200 and stream["decimated"] == stream["coalesced"]
        assert stream["recorded"] + stream["coalesced"] == 200 and stream["pending"] == 0
        assert live["complete"] is True
        deadline = time.monotonic() + 10  # the kill takes effect asynchronously
        while (orjson.loads(client.get("/healthz").content)["bridge"]["status"] != "down"
               and time.monotonic() < deadline):
            time.sleep(0.05)
        assert orjson.loads(client.get("/healthz").content)["bridge"]["status"] == "down"
        # the file holds what the recorder counted (how many were coalesced first depends on
        # the machine's load: 53 of 200 on a busy one; they are counted above, not lost)
        poses = mcap_messages(_mcap(client, "crash", tmp_path), "/live/arm/pose")
        assert len(poses) == stream["recorded"] > 0


def test_two_bridge_processes_both_feed_the_recorder(tmp_path):
    """``--zenoh-processes 2``: bridge 1 listens elsewhere and connects to bridge 0; its
    batches still reach the recorder, named as a bridge of their own."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    settings = Settings(data_dir=tmp_path, recordings_enabled=True, zenoh_listen=[endpoint],
                        zenoh_processes=2)
    with TestClient(create_app(settings)) as client:
        directrix = _make_skill(client, "two")
        for robot in ("r0", "r1"):  # shard 0 and shard 1 (ord('0') % 2, ord('1') % 2)
            # generous waits: bridge 1 is reached through bridge 0's gossip
            with PoseStreamer("two", robot, endpoint=endpoint, connect_timeout=20) as ps:
                # The publisher matches bridge 0's subscriber first; until gossip connects
                # this Zenoh session to bridge 1, r1's poses reach only bridge 0, which drops
                # another shard's pose uncounted. So the first pose is sent until answered.
                deadline, answer = time.monotonic() + 20.0, None
                while answer is None and time.monotonic() < deadline:
                    answer = ps.wait_for(ps.send(directrix[10], restart=True), 5.0)
                assert answer is not None and answer.status == "ok"
                for k in range(1, 20):
                    answer = ps.wait_for(ps.send(directrix[10 + k]), 5.0)
                    assert answer is not None and answer.status == "ok"
        live = _settled(client, 40, timeout=30)
        assert live["bridges"] == 2 and live["complete"] is True
        for robot in ("r0", "r1"):
            stream = live["streams"][f"two/{robot}"]
            assert stream["poses"] >= 20  # more when a first pose was resent
            assert (stream["recorded"] + stream["decimated"] == stream["poses"]
                    and stream["recorded"] >= 1)


def test_robots_past_the_cap_of_a_skills_recording_are_counted_not_drawn(tmp_path):
    # Every robot name a client invented became entities in the skill's recording, without
    # bound: past about 12,000 names the exported .rrd no longer passed `rerun rrd verify`.
    client, endpoint = _app(tmp_path, recordings_live_hz=0.0, recordings_max_robots=2)
    with client:
        directrix = _make_skill(client, "crowd")
        with PoseStreamer("crowd", "r0", endpoint=endpoint) as first:
            for name in ("r0", "r1", "r2"):
                with PoseStreamer("crowd", name, session=first.session) as ps:
                    for k in range(5):
                        assert ps.wait_for(ps.send(directrix[10 + k]), 2.0) is not None
        live = _settled(client, 15)
        streams = live["streams"]
        assert [streams[f"crowd/r{i}"]["recorded"] for i in range(3)] == [5, 5, 0]
        assert streams["crowd/r2"]["dropped"] == 5  # counted, not drawn
        assert live["complete"] is False  # and the recording says it does not hold them
        topics = set(mcap_counts(_mcap(client, "crowd", tmp_path)))
        assert "/live/r0/pose" in topics and "/live/r1/pose" in topics
        assert not any(t.startswith("/live/r2/") for t in topics), topics
