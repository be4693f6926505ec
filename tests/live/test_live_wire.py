"""The bridge's fast wire paths give what the fully checked paths give: JSON and binary
poses (the common pose skips most checks), JSON targets (NaN and infinity as null)."""

from __future__ import annotations

import dataclasses
import math

import orjson
import pytest

from canal_protocol import wire
from canal_protocol.codecs import json as json_codec

NAN, INF = math.nan, math.inf

JSON_POSES = [
    b'{"seq": 0, "position": [0.1, 0.2, 0.3]}',
    b'{"seq": 7, "position": [0.1, -0.0]}',
    b'{"seq": 18446744073709551615, "position": [1e308, 1e308, 1e308]}',
    b'{"seq": 18446744073709551616, "position": [0.1, 0.2, 0.3]}',
    b'{"seq": -1, "position": [0.1, 0.2, 0.3]}',
    b'{"seq": 1.0, "position": [0.1, 0.2, 0.3]}',
    b'{"seq": true, "position": [0.1, 0.2, 0.3]}',
    b'{"seq": 3, "position": [1, 2, 3]}',
    b'{"seq": 3, "position": [1, 2.5, -3]}',
    b'{"seq": 3, "position": [true, 2.5, 3.0]}',
    b'{"seq": 3, "position": ["1", 2.5, 3.0]}',
    b'{"seq": 3, "position": [[1.0], 2.5, 3.0]}',
    b'{"seq": 3, "position": null}',
    b'{"seq": 3, "position": []}',
    b'{"seq": 3, "position": [' + b", ".join([b"0.5"] * 16) + b"]}",
    b'{"seq": 3, "position": [' + b", ".join([b"0.5"] * 17) + b"]}",
    b'{"seq": 3, "position": [0.1, 0.2, 0.3], "orientation": [0.0, 0.0, 0.0, 1.0]}',
    b'{"seq": 3, "position": [0.1, 0.2, 0.3], "orientation": [0.0, 0.0, 1.0]}',
    b'{"seq": 3, "position": [0.1, 0.2], "t": 1.25, "restart": true}',
    b'{"seq": 3, "position": [0.1, 0.2], "t": "now"}',
    b'{"seq": 3, "position": [0.1, 0.2], "extra": 1}',
    b'{"seq": 3, "pos": [0.1, 0.2]}',
    b'{"seq": 3, "position": [1e999, 0.2]}',
    b'{"seq": 3, "position": [1e15, 1e15, -1e15]}',
    b'{"seq": 3, "position": [1e15, 1.0000001e15, 0.0]}',
    b'{"seq": 3, "position": [NaN, 0.2]}',
    b'[3, [0.1, 0.2]]',
    b'"pose"',
]


def _outcome(fn, *args):
    try:
        return fn(*args)
    except wire.WireError as exc:
        return exc.key, exc.message


@pytest.mark.parametrize("data", JSON_POSES)
def test_json_pose_fast_path_equals_full_checks(data):
    got = _outcome(wire.decode_pose_json, data)
    try:
        body = orjson.loads(data)
    except orjson.JSONDecodeError:
        assert got[0] == "bad_payload"
        return
    assert got == _outcome(json_codec._checked_pose_json, body)
    if isinstance(got, wire.Pose):
        assert all(type(v) is float for v in got.position)
        assert got == wire.Pose(got.seq, got.position, got.orientation, got.t, got.restart)
        assert hash(got) == hash(wire.Pose(got.seq, got.position, got.orientation, got.t,
                                           got.restart))
        with pytest.raises(dataclasses.FrozenInstanceError):
            got.seq = 1  # type: ignore[misc]


@pytest.mark.parametrize("position", [(0.1, 0.2), (0.1, 0.2, 0.3), (-0.0, 0.0, -0.0),
                                      (1e15, 1e15, 1e15), (5e-324, -1e15, 2.5)])
@pytest.mark.parametrize("orientation", [None, (0.0, 0.0, 0.0, 1.0)])
def test_json_and_binary_poses_round_trip_exactly(position, orientation):
    for pose in (wire.decode_pose_json(wire.encode_pose_json(5, position, orientation)),
                 wire.decode_pose(wire.encode_pose(5, position, orientation))):
        assert pose.seq == 5 and pose.orientation == orientation and not pose.restart
        assert [v.hex() for v in pose.position] == [float(v).hex() for v in position]
        assert [math.copysign(1, v) for v in pose.position] == \
            [math.copysign(1, v) for v in position]


@pytest.mark.parametrize("bad", [NAN, INF, -INF])
@pytest.mark.parametrize("where", range(3))
def test_binary_pose_with_non_finite_number_is_refused(bad, where):
    position = [0.1, 0.2, 0.3]
    position[where] = bad
    with pytest.raises(wire.WireError) as exc:
        wire.decode_pose(wire.encode_pose(1, position))
    assert exc.value.key == "non_finite"
    with pytest.raises(wire.WireError) as exc:
        wire.decode_pose(wire.encode_pose(1, [0.1, 0.2, 0.3], (0.0, 0.0, bad, 1.0)))
    assert exc.value.key == "non_finite"


@pytest.mark.parametrize(("data", "seq"), [
    (wire.encode_pose(13, [NAN, 0.0, 0.0]), 13),
    (wire.encode_pose(18, [0.1, 0.0, 0.0], t=1e300), 18),
    (wire.encode_pose(19, [1e16, 0.0, 0.0]), 19),
    (wire.encode_pose(20, [0.1, 0.0, 0.0])[:-1], 20),
    (wire.encode_pose(20, [0.1, 0.0, 0.0])[:6], None),
    (bytes([9]) + wire.encode_pose(20, [0.1, 0.0, 0.0])[1:], None),
    (b'{"seq": 31, "position": [1e16, 0, 0]}', 31),
    (b'{"seq": 32, "position": [0.1, 0, 0], "t": 1e300}', 32),
    (b'{"seq": 33, "position": [0.1, 0, 0], "orientation": [0, 0, 0, 7]}', 33),
    (b'{"seq": 34}', 34),
    (b'{"seq": -1, "position": [0.1, 0, 0]}', None),
    (b'{"position": [0.1, 0, 0]}', None),
])
def test_a_refused_pose_keeps_its_seq_when_it_could_be_read(data, seq):
    decode = wire.decode_pose_json if data[:1] == b"{" else wire.decode_pose
    with pytest.raises(wire.WireError) as exc:
        decode(data)
    assert exc.value.seq == seq


def test_binary_pose_flags_are_kept():
    pose = wire.decode_pose(wire.encode_pose(9, [1.0, 2.0], (0.0, 0.0, 0.0, 1.0), 2.5, True))
    assert pose == wire.Pose(9, (1.0, 2.0), (0.0, 0.0, 0.0, 1.0), 2.5, True)


@pytest.mark.parametrize("target", [[0.1, 0.2], [0.1, -0.0, 1e308], [NAN, 1.0, INF]])
@pytest.mark.parametrize("eta", [0.25, NAN, INF, 1e308])
@pytest.mark.parametrize("extras", [(None, None), ((0.0, 0.0, 0.0, 1.0), None),
                                    ((0.0, 0.0, 0.0, 1.0), (1.0, -0.0, 2.0)),
                                    (None, (NAN, 0.5))])
def test_json_target_round_trips_with_nan_and_inf_as_null(target, eta, extras):
    orientation, velocity = extras
    data = wire.pack_target_json(2**64 - 1, "outside_canal", target, 0.5, eta, 7, False, True,
                                 3, orientation, velocity, 4)
    got = wire.decode_target_json(data)
    raw = orjson.loads(data)

    def json_of(v):
        return v if math.isfinite(v) else None

    assert raw["target"] == [json_of(v) for v in target]
    assert raw["eta"] == json_of(eta)
    assert got.seq == 2**64 - 1 and got.status == "outside_canal" and got.section == 7
    assert got.done and not got.inside and got.model_version == 3 and got.coalesced == 4
    assert got.orientation == orientation
    if velocity is None:
        assert "velocity" not in raw
    else:
        assert raw["velocity"] == [json_of(v) for v in velocity]
    finite = [v for v in target if math.isfinite(v)]
    assert [v.hex() for v in raw["target"] if v is not None] == [v.hex() for v in finite]
    assert data == wire.target_json(wire.Target(
        2**64 - 1, "outside_canal", tuple(target), 0.5, eta, 7, False, True, 3, None,
        orientation, velocity, 4))


@pytest.mark.parametrize(("data", "shown"), [
    # A Python client that puts NaN through orjson sends null: the answer says why.
    (b'{"seq": 3, "position": [null, 0.2, 0.3]}', "got null (JSON has no NaN or infinity)"),
    (b'{"seq": 3, "position": [true, 0.2, 0.3]}', "got true"),
    (b'{"seq": 3, "position": ["1", 0.2, 0.3]}', 'got "1"'),
    (b'{"seq": 3, "position": [0.1, 0.2], "restart": "yes"}', 'got "yes"'),
    # the rest of a pose's fields say what came too
    (b'[1, 2, 3]', "expected a JSON object, got a list"),
    (b'{"seq": -1, "position": [0.1, 0.2]}', "got -1"),
    (b'{"seq": "3", "position": [0.1, 0.2]}', 'got "3"'),
    (b'{"position": [0.1, 0.2]}', "got no 'seq'"),
    (b'{"seq": 3, "pos": [0.1, 0.2]}', "expected 'position', got the keys seq, pos"),
    (b'{"seq": 3, "position": 0.5}', "got 0.5"),
    (b'{"seq": 3, "position": []}', "got 0"),
    (b'{"seq": 3, "position": [0.1, 0.2], "orientation": [0, 0, 1]}', "got [0,0,1]"),
    (b'{"seq": 3, "position": [0.1, 0.2], "t": "now"}', 'got "now"'),
])
def test_a_refused_json_pose_shows_the_value_as_json(data, shown):
    key, message = _outcome(wire.decode_pose_json, data)
    assert key == "bad_payload" and message.endswith(shown), message


@pytest.mark.parametrize("encode", ["json", "binary"])
def test_a_coordinate_just_past_the_bound_is_not_shown_as_the_bound(encode):
    # 1.0000001e15 was refused as "got 1e+15": it read as within +-1e+15.
    position = [1.0000001e15, 0.0, 0.0]
    data = (orjson.dumps({"seq": 1, "position": position}) if encode == "json"
            else wire.encode_pose(1, position))
    decode = wire.decode_pose_json if encode == "json" else wire.decode_pose
    with pytest.raises(wire.WireError) as refused:
        decode(data)
    assert "got 1e+15" not in refused.value.message
    assert repr(1.0000001e15) in refused.value.message, refused.value.message


def test_the_restart_flag_is_read_without_decoding_the_pose_as_decoding_reads_it():
    """What the overload path keeps of a coalesced backlog: the restart flag as the decoder
    reads it, in every format; False for what is no pose."""
    from canal_protocol.codecs import asks_restart

    payloads = [
        wire.encode_pose(1, [0.1, 0.2, 0.3], restart=True),
        wire.encode_pose(2, [0.1, 0.2], t=1.5, restart=True),
        wire.encode_pose(3, [0.1, 0.2, 0.3], orientation=[0, 0, 0, 1]),
        wire.encode_pose_json(4, [0.1, 0.2, 0.3], restart=True),
        wire.encode_pose_json(5, [0.1, 0.2, 0.3]),
        b'{"seq": 6, "position": [0.1, 0.2, 0.3], "restart": false}',
        b'{"seq": 7, "position": [0.1, 0.2, 0.3], "\\u0072estart": true}',
        b'{"seq": 8, "position": [0.1, 0.2, 0.3], "restart": "yes"}',
        b'{"seq": 9, "note": "restart"}',
        b"\x01\x01\x04",  # a truncated binary header
        wire.encode_pose_stamped_cdr(wire.RosStamp(1, 0, "base"), [0.1, 0.2, 0.3],
                                     [0.0, 0.0, 0.0, 1.0]),
    ]
    for data in payloads:
        fmt = wire.pose_format("zenoh/bytes", data)
        try:
            expected = wire.decode_pose_as(fmt, data)[0].restart
        except wire.WireError:
            expected = False
        assert asks_restart(fmt, data) == expected, data
    assert [asks_restart(wire.pose_format("zenoh/bytes", d), d) for d in payloads[:5]] == [
        True, True, False, True, False]
