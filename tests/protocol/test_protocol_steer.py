"""The steering message: JSON, binary and ROS 2 Vector3 read alike; bad ones refused."""

from __future__ import annotations

import struct

import pytest

from canal_protocol import codecs
from canal_protocol.codecs import WireError


@pytest.mark.parametrize(("encoding", "data"), [
    ("application/json", codecs.encode_steer_json(0.25, -1.0)),
    ("application/octet-stream", codecs.encode_steer(0.25, -1.0, seq=7)),
    ("application/cdr", codecs.encode_steer_cdr(0.25, -1.0)),
    ("", codecs.encode_steer_json(0.25, -1.0)),  # default encoding, JSON by its first byte
    ("", codecs.encode_steer_cdr(0.25, -1.0)),  # default encoding, CDR by its first byte
])
def test_every_encoding_reads_the_same_input(encoding: str, data: bytes) -> None:
    assert codecs.decode_steer(encoding, data) == (0.25, -1.0)


def test_a_big_endian_vector3_reads_too_and_overshoot_is_clipped() -> None:
    data = b"\x00\x00\x00\x00" + struct.pack(">3d", 1.2, -0.5, 9.0)
    assert codecs.decode_steer("application/cdr", data) == (1.0, -0.5)


@pytest.mark.parametrize(("encoding", "data", "key"), [
    ("application/json", b'{"u": 1}', "bad_payload"),
    ("application/json", b'{"u": true, "v": 0}', "bad_payload"),
    ("application/json", b'{"u": NaN, "v": 0}', "bad_payload"),
    # a number in a string, an unknown field, not an object: refused as a pose's JSON is
    ("application/json", b'{"u": "0.9", "v": 0}', "bad_payload"),
    ("application/json", b'{"u": 0.5, "v": 0, "w": 1}', "bad_payload"),
    ("application/json", b'[0.5, 0]', "bad_payload"),
    ("application/octet-stream", codecs.encode_steer(0.0, 0.0)[:-1], "bad_payload"),
    ("application/octet-stream", b"\x01\x01\x00\x02" + bytes(8) + bytes(16), "bad_payload"),
    ("application/octet-stream", codecs.encode_steer(float("inf"), 0.0), "non_finite"),
    ("application/cdr", b"\x00\x01\x00\x00" + bytes(8), "bad_payload"),
])
def test_bad_inputs_are_refused_with_their_status(encoding: str, data: bytes, key: str) -> None:
    with pytest.raises(WireError) as err:
        codecs.decode_steer(encoding, data)
    assert err.value.key == key
