"""Numbers on the live path: every pose field is checked against the magnitudes Canal
computes with, in every encoding, and refused naming the field (bad_payload); whatever is
taken gets a finite answer. The codecs and the tracker directly (hypothesis), then a few
cases over a real Zenoh session."""

from __future__ import annotations

import re
import struct
import sys

import numpy as np
import orjson
import pytest
from canal_client.live import LiveError, PoseStreamer, query_json
from canal_testing import arc_demo
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import canal_core
from canal_core.preprocess import MAX_COORDINATE as CORE_MAX_COORDINATE
from canal_core.tracker_bank import TrackerBank
from canal_core.tracker_kernel import compile_step_rows
from canal_core.validation import QUATERNION_NORM_TOLERANCE as CORE_TOLERANCE
from canal_protocol import wire
from canal_protocol.codecs import messages
from canal_protocol.codecs.cdr import RosStamp, decode_pose_cdr, encode_pose_stamped_cdr

pytestmark = pytest.mark.timeout(120)

BIG = sys.float_info.max
Q = (0.0, 0.0, 0.0, 1.0)


def test_the_live_bounds_are_the_core_s() -> None:
    assert messages.MAX_COORDINATE == CORE_MAX_COORDINATE
    assert messages.QUATERNION_NORM_TOLERANCE == CORE_TOLERANCE


def _json(**fields) -> bytes:  # type: ignore[no-untyped-def]
    return orjson.dumps({"seq": 3, "position": [0.1, 0.2, 0.3], **fields})


BAD_JSON = [
    ("orientation norm 0", _json(orientation=[0.0, 0.0, 0.0, 0.0]), "orientation"),
    ("orientation norm 7", _json(orientation=[7.0, 0.0, 0.0, 0.0]), "orientation"),
    ("orientation 1e308", _json(orientation=[1e308, 0.0, 0.0, 0.0]), "orientation"),
    ("restart yes", _json(restart="yes"), "restart"),
    ("restart [1]", _json(restart=[1]), "restart"),
    ("restart 1", _json(restart=1), "restart"),
    ("t 1e308", _json(t=1e308), "t"),
    ("t -1e12", _json(t=-1e12), "t"),
    ("position 1e308", orjson.dumps({"seq": 3, "position": [1e308, 0.0, 0.0]}), "position"),
    ("position -1e16", orjson.dumps({"seq": 3, "position": [0.1, -1e16, 0.0]}), "position"),
    ("position far with t", _json(position=[1e200, 0.0, 0.0], t=1.0), "position"),
]


@pytest.mark.parametrize("name,data,field", BAD_JSON, ids=[b[0] for b in BAD_JSON])
def test_json_poses_out_of_range_are_refused_naming_the_field(name: str, data: bytes,
                                                              field: str) -> None:
    with pytest.raises(wire.WireError) as caught:
        wire.decode_pose_json(data)
    assert caught.value.key == "bad_payload"
    assert f"expected {field}" in caught.value.message or \
        f"'{field}'" in caught.value.message, caught.value.message


@pytest.mark.parametrize("position,orientation,t,field", [
    ((1e308, 0.0, 0.0), None, None, "position"),
    ((0.1, 0.2, 0.3), (0.0, 0.0, 0.0, 0.0), None, "orientation"),
    ((0.1, 0.2, 0.3), (7.0, 0.0, 0.0, 0.0), 1.0, "orientation"),
    ((0.1, 0.2, 0.3), None, 1e308, "t"),
])
def test_binary_and_cdr_poses_out_of_range_are_refused(position, orientation, t,  # type: ignore[no-untyped-def]
                                                       field: str) -> None:
    with pytest.raises(wire.WireError, match=f"expected {field}") as caught:
        wire.decode_pose(wire.encode_pose(1, position, orientation, t))
    assert caught.value.key == "bad_payload"
    if t is None:  # a PoseStamped has no free time field; the bridge checks its numbers
        cdr = encode_pose_stamped_cdr(RosStamp(1, 0, "base", True), position,
                                      orientation or (0.0, 0.0, 0.0, 0.0))
        pose, _ = decode_pose_cdr(cdr)
        with pytest.raises(wire.WireError) as caught:
            messages.check_pose_numbers(pose.position, pose.orientation, None)
        assert caught.value.key == "bad_payload"


def _pose_stamped(frame: bytes, sec: int = 1, nanosec: int = 0) -> bytes:
    """A little-endian PoseStamped CDR body with ``frame`` as frame_id's bytes, as sent."""
    end = 12 + len(frame)
    pad = ((end + 7) & ~7) - end
    return (bytes((0, 1, 0, 0)) + struct.pack("<iII", sec, nanosec, len(frame)) + frame
            + b"\x00" * pad + struct.pack("<7d", 0.1, 0.2, 0.3, 0.0, 0.0, 0.0, 1.0))


@pytest.mark.parametrize("frame,sec,nanosec,expected", [
    # a CDR string ends in NUL: "base" without it was read as "bas", and the target went
    # back in a frame the robot's TF tree does not know
    (b"base", 1, 0, "frame_id ending in NUL"),
    (b"ba\x00e\x00", 1, 0, "frame_id ending in NUL"),
    # builtin_interfaces/Time: nanosec in [0, 1e9); 2e9 was taken as two more seconds
    (b"base\x00", 1, 2_000_000_000, "nanosec in [0, 1000000000)"),
])
def test_a_pose_stamped_that_breaks_its_message_definition_is_refused(
        frame: bytes, sec: int, nanosec: int, expected: str) -> None:
    with pytest.raises(wire.WireError, match=re.escape(expected)) as caught:
        decode_pose_cdr(_pose_stamped(frame, sec, nanosec))
    assert caught.value.key == "bad_payload"
    pose, stamp = decode_pose_cdr(_pose_stamped(b"base\x00", -5, 999_999_999))
    assert stamp.frame_id == "base" and pose.t == pytest.approx(-5 + 0.999999999)


def test_poses_at_the_bounds_are_taken() -> None:
    # a norm beyond the bound with every coordinate within it: taken (by the full checks)
    assert wire.decode_pose(wire.encode_pose(1, [1e15, -1e15, 1e15])).position[1] == -1e15
    for data in (_json(position=[1e15, -1e15, 0.0], t=1e11, restart=True),
                 _json(orientation=[0.0, 0.0, 0.0, 1.0009], restart=None),
                 wire.encode_pose_json(4, [0.1, 0.2, 0.3], (0.0, 0.6, 0.0, 0.8), -1e11)):
        pose = wire.decode_pose_json(data)
        assert pose.seq in (3, 4)


# ---- decode + step over extreme floats ---------------------------------------------------

_CANAL = canal_core.fit([arc_demo(j, 60, 3, 0, spread=0.03) for j in range(4)], n_samples=60)
_BANKS = {name: TrackerBank(_CANAL.tracker(2).geometry, 2, compiled=name == "compiled")
          for name in ("numpy", "compiled")}
_SLOTS = {name: bank.add() for name, bank in _BANKS.items()}

extreme = st.floats(min_value=-BIG, max_value=BIG, allow_nan=False, allow_infinity=False)
near = st.floats(min_value=-2.0, max_value=2.0, allow_nan=False, allow_infinity=False)
coordinate = st.one_of(extreme, near, st.sampled_from([1e15, -1e15, 1e16, 5e-324, 0.0]))


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(position=st.lists(coordinate, min_size=3, max_size=3),
       orientation=st.none() | st.lists(st.one_of(extreme, near), min_size=4, max_size=4),
       t=st.none() | extreme, restart=st.booleans(), binary=st.booleans())
def test_decode_and_step_answer_an_error_or_a_finite_target(position, orientation, t, restart,  # type: ignore[no-untyped-def]
                                                            binary: bool) -> None:
    """What the bridge does per pose: decode, then step the stream's bank slot (both the
    numpy pass and the compiled kernel); an error status or every number finite."""
    assert compile_step_rows() is not None
    data = wire.encode_pose(7, position, orientation, t, restart) if binary else \
        wire.encode_pose_json(7, position, orientation, t, restart)
    try:
        pose = wire.decode_pose(data) if binary else wire.decode_pose_json(data)
    except wire.WireError as exc:
        assert exc.key in ("bad_payload", "non_finite") and exc.message
        return
    assert all(abs(v) <= messages.MAX_COORDINATE for v in pose.position)
    for name, bank in _BANKS.items():
        if pose.restart:
            bank.reset(_SLOTS[name], 0)
        rows = bank.step_packed([_SLOTS[name]], np.array([pose.position]))
        d = 3
        assert np.isfinite(rows[0, : d + 2]).all(), (name, rows)  # target, progress, eta
        assert 0.0 <= rows[0, d] <= 1.0


# ---- over a real Zenoh session -----------------------------------------------------------

@pytest.mark.parametrize("payload,json_encoded,field", [
    (_json(orientation=[0.0, 0.0, 0.0, 0.0]), True, "orientation"),
    (_json(restart="yes"), True, "restart"),
    (_json(t=1e308), True, "t"),
    (orjson.dumps({"seq": 3, "position": [1e308, 1e308, 1e308]}), True, "position"),
    (wire.encode_pose(3, [0.1, 0.2, 0.3], (7.0, 0.0, 0.0, 0.0)), False, "orientation"),
    (wire.encode_pose(3, [1e308, 0.2, 0.3]), False, "position"),
])
def test_out_of_range_poses_get_bad_payload_over_zenoh(live, payload: bytes,
                                                       json_encoded: bool, field: str) -> None:
    x = np.array(live.client.get("/skills/arc3/models/latest").json()["directrix"])[3]
    with PoseStreamer("arc3", "numbers", endpoint=live.endpoint) as ps:
        assert ps.wait_for(ps.send(x, restart=True), 2.0).status == "ok"
        ps._latest = None
        ps.send_raw(payload, json=json_encoded)
        got = _wait_latest(ps)
        assert got.status == "bad_payload" and field in got.message, got
        assert got.seq == 3, got  # the refused pose's own seq
        # and the stream goes on where it was (the streamer's own seqs are behind that 3)
        ps._latest = None
        after = ps.wait_for(ps.send(x), 2.0)
        assert after is not None and after.status == "ok"


@pytest.mark.parametrize("action,body,field", [
    ("start", {"from_seq": "x"}, "from_seq"), ("start", {"from_seq": True}, "from_seq"),
    ("start", {"from_seq": -1}, "from_seq"), ("start", {"label": 5}, "label"),
    ("stop", {"last_seq": "x"}, "last_seq")])
def test_demo_queries_with_mistyped_fields_are_refused(live, action: str, body: dict,  # type: ignore[type-arg]
                                                       field: str) -> None:
    robot = f"demo-{action}-{field}"
    with PoseStreamer("arc3", robot, endpoint=live.endpoint) as ps:
        with pytest.raises(LiveError) as caught:
            query_json(ps.session, f"canal/arc3/{robot}/demo/{action}", body)
        error = caught.value.body["error"]
        assert error["type"] == "bad_payload" and error["field"] == field
        assert field in error["message"]


def _wait_latest(ps: PoseStreamer, timeout: float = 2.0) -> wire.Target:
    import time

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        latest = ps.latest()
        if latest is not None:
            return latest
        time.sleep(0.002)
    raise AssertionError("no answer")

