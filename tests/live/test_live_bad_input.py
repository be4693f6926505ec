"""Bad input on the live path: every case answered with its documented status, counted in
/metrics, and a good stream keeps being served."""

from __future__ import annotations

import contextlib
import struct
import time

import numpy as np
import orjson
import pytest
import zenoh
from canal_client.live import PoseStreamer
from live_helpers import wait_until

from canal_protocol import wire

pytestmark = pytest.mark.timeout(60)

GOOD = wire.encode_pose(1, [0.1, 0.05, 0.01])

CASES = [
    ("garbage", b"\xde\xad\xbe\xef garbage bytes", False, "bad_payload"),
    ("empty", b"", False, "bad_payload"),
    ("truncated", GOOD[:-5], False, "bad_payload"),
    ("too long", GOOD + b"\x00", False, "bad_payload"),
    ("wrong version", bytes([9]) + GOOD[1:], False, "bad_payload"),
    ("wrong kind", GOOD[:1] + bytes([2]) + GOOD[2:], False, "bad_payload"),
    ("nan", wire.encode_pose(1, [0.1, float("nan"), 0.0]), False, "non_finite"),
    ("inf time", wire.encode_pose(1, [0.1, 0.0, 0.0], t=float("inf")), False, "non_finite"),
    ("2-D on a 3-D skill", wire.encode_pose(1, [0.1, 0.0]), False, "wrong_dimension"),
    ("json not json", b"{not json", True, "bad_payload"),
    ("json nan", b'{"seq": 1, "position": [NaN, 0, 0]}', True, "bad_payload"),
    ("json missing position", b'{"seq": 1}', True, "bad_payload"),
    ("json missing seq", b'{"position": [0.1, 0, 0]}', True, "bad_payload"),
    ("json strings", b'{"seq": 1, "position": ["a", 0, 0]}', True, "bad_payload"),
    ("json array", b"[1, 2, 3]", True, "bad_payload"),
    ("json huge", b'{"seq": 1, "position": [1e999, 0, 0]}', True, "bad_payload"),
    ("json 4-D", b'{"seq": 1, "position": [0.1, 0, 0, 0]}', True, "wrong_dimension"),
    # a pose is a few hundred bytes: megabytes were parsed, and an unknown key beside a good
    # pose answered ok
    ("json of 100 kB", b'{"seq": 1, "position": [0.1, 0, 0], "note": "' + b"a" * 100_000 + b'"}',
     True, "bad_payload"),
    ("binary of 100 kB", GOOD + bytes(100_000), False, "bad_payload"),
]


def test_malformed_payloads_are_answered_and_counted(live):
    with PoseStreamer("arc3", "good", endpoint=live.endpoint) as good, \
            PoseStreamer("arc3", "bad", endpoint=live.endpoint, session=good.session) as bad:
        x = np.array(live.client.get("/skills/arc3/models/latest").json()["directrix"][0])
        for name, payload, as_json, status in CASES:
            before = live.metric("canal_live_errors_total", f'status="{status}"')
            bad.send_raw(payload, json=as_json)
            # the good stream is served while the bad one misbehaves
            seq = good.send(x)
            answer = good.wait_for(seq, 1.0)
            assert answer is not None and answer.status == "ok", name
            x = x + 0.5 * (np.array(answer.target) - x)
            got = _wait_status(bad)
            assert got.status == status, (name, got)
            assert got.target is None and not got.usable and got.message, name
            if as_json:
                assert got.seq in (None, 1), name
            assert live.metric("canal_live_errors_total", f'status="{status}"') == before + 1, name
            bad._latest = None
    assert live.client.get("/healthz").json()["bridge"]["status"] == "ok"


def _pose_header(seq: int, dim: int, flags: int = 0) -> bytes:
    return struct.pack("<BBBBQ", 1, 1, flags, dim, seq)


#: Poses refused after their seq was read: the answer says which pose it refuses.
SEQ_READ = [
    ("nan", _pose_header(13, 3) + struct.pack("<3d", float("nan"), 0.0, 0.0), False,
     "non_finite", 13),
    ("t=1e300", _pose_header(18, 3, 0x02) + struct.pack("<4d", 0.1, 0.01, 0.0, 1e300), False,
     "bad_payload", 18),
    ("coordinate 1e16", _pose_header(19, 3) + struct.pack("<3d", 1e16, 0.0, 0.0), False,
     "bad_payload", 19),
    ("quaternion of norm 7", _pose_header(20, 3, 0x01)
     + struct.pack("<7d", 0.1, 0.0, 0.0, 7.0, 0.0, 0.0, 0.0), False, "bad_payload", 20),
    ("a byte short", _pose_header(21, 3) + struct.pack("<3d", 0.1, 0.0, 0.0)[:-1], False,
     "bad_payload", 21),
    ("dimension 0", _pose_header(22, 0), False, "bad_payload", 22),
    ("2-D on a 3-D skill", _pose_header(15, 2) + struct.pack("<2d", 0.0, 0.0), False,
     "wrong_dimension", 15),
    ("json coordinate 1e16", b'{"seq": 31, "position": [1e16, 0, 0]}', True, "bad_payload", 31),
    ("json t=1e300", b'{"seq": 32, "position": [0.1, 0, 0], "t": 1e300}', True,
     "bad_payload", 32),
    ("json strings", b'{"seq": 33, "position": ["a", 0, 0]}', True, "bad_payload", 33),
    ("json restart 1", b'{"seq": 34, "position": [0.1, 0, 0], "restart": 1}', True,
     "bad_payload", 34),
    ("json no position", b'{"seq": 35}', True, "bad_payload", 35),
    # an unknown key (a typo) or flag bit would be a pose without what it meant to say
    ("json unknown key", b'{"seq": 37, "position": [0.1, 0, 0], "orientaton": [0, 0, 0, 1]}',
     True, "bad_payload", 37),
    ("unknown flag 0x08", _pose_header(23, 3, 0x08) + struct.pack("<3d", 0.1, 0.01, 0.0), False,
     "bad_payload", 23),
    # no seq to read: none is claimed
    ("wrong version", bytes([9]) + GOOD[1:], False, "bad_payload", None),
    ("header cut short", GOOD[:6], False, "bad_payload", None),
    ("json seq -1", b'{"seq": -1, "position": [0.1, 0, 0]}', True, "bad_payload", None),
    ("json not json", b'{"seq": 36, "position": [0.1', True, "bad_payload", None),
]


@pytest.mark.parametrize(("skill", "robot"), [("arc3", "which"), ("no-such-skill", "which")])
def test_a_refused_pose_is_answered_with_its_seq_when_it_could_be_read(live, skill, robot):
    # A binary pose with a readable header but a NaN coordinate or t = 1e300, or a JSON pose
    # with a number out of range, was answered without its seq (flag 0x04 unset, seq 0;
    # JSON seq null): the robot could not tell which pose was refused.
    with PoseStreamer(skill, robot, endpoint=live.endpoint) as ps:
        for name, payload, as_json, status, seq in SEQ_READ:
            ps._latest = None
            ps.send_raw(payload, json=as_json)
            got = _wait_status(ps, 2.0)
            want = status if skill == "arc3" else "unknown_skill"
            # (a binary answer's seq reads as None unless its flag 0x04 is set)
            assert got.status == want and got.seq == seq, (name, got)


def _wait_status(ps, timeout=1.0):
    import time

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        latest = ps.latest()
        if latest is not None:
            return latest
        time.sleep(0.002)
    raise AssertionError("no answer")


def test_answers_use_the_pose_encoding(live):
    with PoseStreamer("arc3", "enc-j", endpoint=live.endpoint, encoding="json") as ps:
        ps.send_raw(b"\x01\x01", json=False)  # binary garbage -> binary answer
        assert _wait_status(ps).status == "bad_payload"
    # and the JSON status answer has the documented JSON fields, read by a plain Zenoh
    # subscriber (not through the client's decoder)
    with PoseStreamer("arc3", "enc-raw", endpoint=live.endpoint) as ps:
        assert isinstance(ps.session, zenoh.Session)
        got = []
        sub = ps.session.declare_subscriber(ps.keys.target, lambda s: got.append(
            (str(s.encoding), s.payload.to_bytes())))
        ps.send_raw(b'{"seq": 5}', json=True)
        _wait_status(ps)
        # the two subscribers hear the answer on Zenoh's threads in no set order
        wait_until(lambda: got, 2.0)
        sub.undeclare()
    assert got, "no answer on the target key"
    encoding, body = got[0]
    assert encoding.startswith("application/json")
    import orjson

    doc = orjson.loads(body)
    assert doc["status"] == "bad_payload" and doc["target"] is None and doc["v"] == 1
    assert set(doc) == {"v", "seq", "status", "target", "progress", "eta", "section", "inside",
                        "done", "model_version", "message", "orientation", "coalesced"}


@pytest.mark.parametrize(("skill", "status"), [("no-such-skill", "unknown_skill"),
                                               ("empty", "no_model")])
def test_unknown_skill_and_skill_without_model(live, skill, status):
    before = live.metric("canal_live_errors_total", f'status="{status}"')
    for encoding in ("binary", "json"):
        with PoseStreamer(skill, f"r-{encoding}", endpoint=live.endpoint,
                          encoding=encoding) as ps:
            seq = ps.send([0.1, 0.0, 0.0])
            answer = ps.wait_for(seq, 1.0)
            assert answer is not None and answer.status == status and answer.seq == seq
            assert answer.target is None and answer.message
    assert live.metric("canal_live_errors_total", f'status="{status}"') == before + 2


def test_far_outside_pose_gets_a_way_back(live):
    before = live.metric("canal_live_errors_total", 'status="outside_canal"')
    with PoseStreamer("arc3", "lost", endpoint=live.endpoint) as ps:
        answer = ps.wait_for(ps.send([0.5, 40.0, -30.0], restart=True), 1.0)
    assert answer is not None and answer.status == "outside_canal"
    assert answer.usable and not answer.inside and answer.eta > 1.0
    assert np.linalg.norm(np.array(answer.target) - [0.5, 0.3, 0.05]) < 0.5  # on the canal
    assert live.metric("canal_live_errors_total", 'status="outside_canal"') == before + 1


def test_binary_target_layout_is_documented_size():
    answer = wire.Target(3, "ok", (1.0, 2.0, 3.0), 0.5, 0.1, 4, True, False, 2)
    data = wire.encode_target(answer)
    assert len(data) == 62 and struct.unpack_from("<BBBBQ", data) == (1, 2, 0x05, 3, 3)
    assert wire.decode_target(data) == answer
    assert len(wire.encode_pose(0, [1.0, 2.0, 3.0])) == 36


def test_step_histogram_counts_every_pose(live):
    """The worker counts its step histogram in plain ints; the metrics thread adds them to
    canal_live_step_seconds in one go: one observation per pose, whatever the drain size."""
    count = "canal_live_step_seconds_count"
    before = live.metric(count)
    before_sum = live.metric("canal_live_step_seconds_sum")
    before_inf = live.metric("canal_live_step_seconds_bucket", 'le="+Inf"')
    x = [0.1, 0.05, 0.01]
    with PoseStreamer("arc3", "histogram", endpoint=live.endpoint) as ps:
        for k in range(40):
            assert ps.wait_for(ps.send(x, restart=k == 0), 2.0) is not None
        burst = [ps.send(x) for _ in range(100)]  # drains of several poses
        assert ps.wait_for(burst[-1], 5.0) is not None
    assert live.metric(count) - before == 140
    assert live.metric("canal_live_step_seconds_bucket", 'le="+Inf"') - before_inf == 140
    assert live.metric("canal_live_step_seconds_sum") > before_sum


@contextlib.contextmanager
def _capped(tmp_path, max_streams: int, idle_s: float):  # type: ignore[no-untyped-def]
    """An app whose bridge serves at most ``max_streams`` streams, forgotten after
    ``idle_s``; skill 'arc3' fitted. Yields the Live and a point on its directrix."""
    import warnings

    from canal_service.app import create_app
    from canal_service.core.config import Settings
    from canal_testing import free_port
    from live_helpers import Live, make_skill

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        from fastapi.testclient import TestClient

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    settings = Settings(data_dir=tmp_path, recordings_enabled=False, zenoh_listen=[endpoint],
                        zenoh_processes=0, zenoh_max_streams=max_streams, zenoh_idle_s=idle_s,
                        zenoh_refresh_s=0.1)
    with TestClient(create_app(settings)) as client:
        make_skill(client, "arc3", 3)
        x = np.array(client.get("/skills/arc3/models/latest").json()["directrix"])[3]
        yield Live(client, endpoint, settings), x


def _ok_once_room(ps: PoseStreamer, x: np.ndarray, timeout: float) -> bool:
    def room() -> bool:
        got = ps.wait_for(ps.send(x), 0.5)
        return got is not None and got.status == "ok"

    return bool(wait_until(room, timeout))


def test_a_client_inventing_robot_names_is_held_to_the_stream_cap(tmp_path):
    # Every new robot name made a stream (a declared publisher, a tracker slot, a recording
    # entity) with no bound: a client that sent each pose under a new name grew the bridge
    # for as long as it went on.
    with _capped(tmp_path, 2, 0.5) as (live, x), \
            PoseStreamer("arc3", "a", endpoint=live.endpoint) as a, \
            PoseStreamer("arc3", "b", session=a.session) as b, \
            PoseStreamer("arc3", "c", session=a.session, encoding="json") as c:
        assert a.wait_for(a.send(x), 2.0).status == "ok"
        assert b.wait_for(b.send(x), 2.0).status == "ok"
        refused = c.wait_for(c.send(x), 2.0)
        assert refused is not None and refused.status == "too_many_streams", refused
        assert refused.target is None and "at most 2" in refused.message, refused
        assert a.wait_for(a.send(x), 2.0).status == "ok"  # the streams it has go on
        assert live.metric("canal_live_errors_total", 'status="too_many_streams"') == 1
        assert _ok_once_room(c, x, 10.0)  # a stream forgotten (idle) makes room for another


def test_steering_inputs_and_stream_queries_are_held_to_the_stream_cap(tmp_path):
    # A steering input made a stream for any skill name, past the cap, and pinned it (its
    # steered run was a capture, and a stream capturing is never forgotten); a stream query
    # (demo/start ...) made one past the cap too.
    # idle 2 s: long enough that a loaded machine does not forget the steered streams before
    # they are counted, short enough to see them forgotten below
    with _capped(tmp_path, 3, 2.0) as (live, x), \
            PoseStreamer("arc3", "a", endpoint=live.endpoint) as a:
        bridge = live.client.app.state.bridge  # type: ignore[attr-defined]
        session = a.session
        for i in range(20):
            session.put(f"canal/nosuchskill/ghost{i}/steer", b'{"u": 0.1, "v": 0.0}')
            session.put(f"canal/arc3/ghost{i}/steer", b'{"u": 0.1, "v": 0.0}')
        assert wait_until(lambda: len(bridge.streams) >= 3, 5.0), list(bridge.streams)
        time.sleep(0.3)  # any input handled late would make a stream past the cap by now
        assert not any("nosuchskill" in k for k in bridge.streams)
        assert len(bridge.streams) == 3  # a (the robot) and two steered
        replies = list(session.get("canal/arc3/q9/demo/start", payload=orjson.dumps({})))
        assert len(bridge.streams) == 3 and replies[0].err is not None
        body = orjson.loads(replies[0].err.payload.to_bytes())
        assert body["error"]["type"] == "too_many_streams", body
        # steered streams that go silent are forgotten like any other
        assert wait_until(lambda: a.wait_for(a.send(x), 0.5) is not None
                          and len(bridge.streams) <= 1, 10.0), list(bridge.streams)


def test_a_capture_with_no_poses_does_not_hold_its_stream_for_good(tmp_path):
    # demo/start with no poses after it held its stream until demo/stop, so one query per
    # slot kept every new robot out (too_many_streams) until the service restarted.
    from canal_service.bridge.streams import CAPTURE_IDLE_FACTOR

    idle = 0.2
    with _capped(tmp_path, 2, idle) as (live, x), \
            PoseStreamer("arc3", "late", endpoint=live.endpoint) as late:
        bridge = live.client.app.state.bridge  # type: ignore[attr-defined]
        for i in range(2):
            replies = list(late.session.get(f"canal/arc3/w{i}/demo/start",
                                            payload=orjson.dumps({})))
            assert replies[0].ok is not None, replies[0].err.payload.to_bytes()
        assert late.wait_for(late.send(x), 2.0).status == "too_many_streams"
        # still held a while after the idle time: a person may pause a demonstration
        time.sleep(2 * idle)
        assert len(bridge.streams) == 2
        assert _ok_once_room(late, x, CAPTURE_IDLE_FACTOR * idle + 5.0)


def test_stops_without_a_capture_hold_up_no_other_robot(live):
    # A stop query waited up to 2 s for the pose last_seq names before looking for a capture,
    # on the one thread that answers every stream query: ten stops with a last_seq no pose
    # will reach held another robot's demo/start for 20 s.
    replies: list = []
    with PoseStreamer("arc3", "honest", endpoint=live.endpoint) as ps:
        for i in range(10):
            for what in ("demo/stop", "correction/stop"):
                ps.session.get(f"canal/arc3/idle{i}/{what}", replies.append, timeout=30.0,
                               payload=orjson.dumps({"last_seq": 2**64 - 1}))
        started = list(ps.session.get("canal/arc3/honest/demo/start", payload=orjson.dumps({}),
                                      timeout=5.0))
        assert started and started[0].ok is not None, "demo/start was held up behind the stops"
        assert wait_until(lambda: len(replies) == 20, 10.0), len(replies)
        kinds = {orjson.loads(r.err.payload.to_bytes())["error"]["type"] for r in replies}
        assert kinds == {"conflict"}, kinds
        stopped = list(ps.session.get("canal/arc3/honest/demo/stop",
                                      payload=orjson.dumps({"last_seq": 2**64 - 1}), timeout=5.0))
        assert stopped  # its capture has no pose: refused, at once


def test_stops_naming_a_pose_never_sent_hold_up_no_other_robot(live):
    # With a capture running, a stop waited for its last_seq for 2 s (or until the
    # stream's poses stopped for 0.5 s), one stop after another: twelve robots capturing,
    # each stopping with a last_seq far beyond any pose it sent, held every other robot's
    # queries for seconds.
    replies: list = []
    names = [f"far{i}" for i in range(12)]
    robots = [PoseStreamer("arc3", name, endpoint=live.endpoint) for name in names]
    try:
        for name, ps in zip(names, robots, strict=True):
            assert ps.wait_for(ps.send([0.1, 0.05, 0.01]), 5.0) is not None
            list(ps.session.get(f"canal/arc3/{name}/demo/start", payload=orjson.dumps({})))
            ps.send([0.11, 0.05, 0.01])
        session = robots[0].session
        for name, ps in zip(names, robots, strict=True):
            session.get(f"canal/arc3/{name}/demo/stop", replies.append, timeout=30.0,
                        payload=orjson.dumps({"last_seq": ps.next_seq + 10**9}))
        model = list(session.get("canal/arc3/model", timeout=3.0))
        assert model and model[0].ok is not None, "the model query was held up behind the stops"
        assert wait_until(lambda: len(replies) == 12, 10.0), len(replies)
    finally:
        for ps in robots:
            ps.close()
