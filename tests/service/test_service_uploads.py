"""Demonstrations in every accepted form, read back exactly."""

from __future__ import annotations

import hashlib
import io
import json

import numpy as np
import pytest
from canal_service.recording.ros2_msgdefs import MSGDEFS
from fastapi.testclient import TestClient
from mcap.writer import CompressionType, Writer
from service_helpers import demo_positions

# geometry_msgs/msg/PoseStamped with its dependencies, as ROS 2 bags store it (ros2msg).
POSE_STAMPED_MSGDEF = MSGDEFS["geometry_msgs/msg/PoseStamped"]


def checksum(positions: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(positions, dtype="<f8").tobytes()).hexdigest()


def ros2_mcap(positions: np.ndarray, topic: str = "/ee_pose", extra_topic: bool = False,
              frame_ids: tuple[str, ...] = ("base",), zero_stamps: bool = False,
              t0: int = 1_700_000_000_000_000_000) -> bytes:
    from mcap_ros2.writer import Writer as Ros2Writer

    buf = io.BytesIO()
    writer = Ros2Writer(buf)
    schema = writer.register_msgdef("geometry_msgs/msg/PoseStamped", POSE_STAMPED_MSGDEF)
    for i, p in enumerate(positions):
        stamp = t0 + i * 10_000_000
        sec, nsec = (0, 0) if zero_stamps else (stamp // 10**9, stamp % 10**9)
        msg = {"header": {"stamp": {"sec": sec, "nanosec": nsec},
                          "frame_id": frame_ids[i % len(frame_ids)]},
               "pose": {"position": {"x": p[0], "y": p[1], "z": p[2]},
                        "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}}
        writer.write_message(topic, schema, msg, log_time=stamp, publish_time=stamp)
        if extra_topic:
            writer.write_message("/other_pose", schema, msg, log_time=stamp, publish_time=stamp)
    writer.finish()
    return buf.getvalue()


def foxglove_mcap(positions: np.ndarray, schema_name: str, topic: str = "/pose") -> bytes:
    buf = io.BytesIO()
    writer = Writer(buf, compression=CompressionType.ZSTD)
    writer.start()
    schema_id = writer.register_schema(name=schema_name, encoding="jsonschema",
                                       data=json.dumps({"type": "object"}).encode())
    channel = writer.register_channel(topic=topic, message_encoding="json", schema_id=schema_id)

    def pose(p: np.ndarray) -> dict[str, object]:
        return {"position": {"x": p[0], "y": p[1], "z": p[2]},
                "orientation": {"x": 0, "y": 0, "z": 0, "w": 1}}

    if schema_name == "foxglove.PosesInFrame":
        payload = {"timestamp": {"sec": 1, "nsec": 0}, "frame_id": "base",
                   "poses": [pose(p) for p in positions]}
        writer.add_message(channel, log_time=1, publish_time=1, data=json.dumps(payload).encode())
    else:
        for i, p in enumerate(positions):
            payload = {"timestamp": {"sec": 100 + i, "nsec": 500}, "frame_id": "base",
                       "pose": pose(p)}
            writer.add_message(channel, log_time=i, publish_time=i,
                               data=json.dumps(payload).encode())
    writer.finish()
    return buf.getvalue()


def read_back(client: TestClient, skill: str, demo_id: int) -> dict[str, object]:
    r = client.get(f"/skills/{skill}/demonstrations/{demo_id}")
    assert r.status_code == 200, r.text
    return r.json()


def test_json_with_timestamps_and_orientations_round_trips(client: TestClient, skill: str) -> None:
    p = demo_positions(0, n=20)
    t = np.linspace(0, 2, 20)
    q = np.tile([0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5)], (20, 1))
    r = client.post(f"/skills/{skill}/demonstrations",
                    json={"positions": p.tolist(), "timestamps": t.tolist(),
                          "orientations": q.tolist(), "label": "first try"})
    assert r.status_code == 201
    created = r.json()
    assert created["n_points"] == 20 and created["checksum"] == checksum(p)
    back = read_back(client, skill, created["id"])
    assert np.array_equal(back["positions"], p) and np.array_equal(back["timestamps"], t)
    assert np.array_equal(back["orientations"], q)
    assert back["label"] == "first try" and back["source"] == "json"
    assert back["has_timestamps"] and back["has_orientations"]


@pytest.mark.parametrize("header", ["t,x,y,z", "x,y,z", None, "time,x,y,z,qx,qy,qz,qw"])
def test_csv_upload(client: TestClient, skill: str, header: str | None) -> None:
    p = demo_positions(1, n=12)
    t = np.arange(12) * 0.1
    if header is None:
        table = np.column_stack([t, p])
    elif header.startswith("time"):
        table = np.column_stack([t, p, np.tile([0, 0, 0, 1.0], (12, 1))])
    elif header.startswith("t,"):
        table = np.column_stack([t, p])
    else:
        table = p
    lines = ([header] if header else []) + [",".join(repr(float(v)) for v in row) for row in table]
    r = client.post(f"/skills/{skill}/demonstrations?label=csv",
                    files={"file": ("demo.csv", "\n".join(lines).encode(), "text/csv")})
    assert r.status_code == 201, r.text
    back = read_back(client, skill, r.json()["id"])
    assert np.array_equal(back["positions"], p) and back["source"] == "csv"
    assert (back["timestamps"] is not None) == (header != "x,y,z")
    assert (back["orientations"] is not None) == (header is not None and "qx" in header)


@pytest.mark.parametrize("encoding", ["utf-8-sig", "utf-16", "utf-16-be", "utf-16-le"])
def test_a_csv_with_a_byte_order_mark_is_read_in_its_encoding(client: TestClient, skill: str, encoding: str) -> None:
    # Spreadsheets and Windows tools save "Unicode text" as UTF-16 with a byte-order mark;
    # it was refused as "CSV must be text; found NUL bytes".
    p = demo_positions(1, n=12)
    text = "x,y,z\r\n" + "\r\n".join(",".join(repr(float(v)) for v in row) for row in p)
    data = text.encode(encoding)
    if encoding in ("utf-16-be", "utf-16-le"):  # these codecs write no mark: add it
        data = "\ufeff".encode(encoding) + data
    r = client.post(f"/skills/{skill}/demonstrations", files={"file": ("demo.csv", data, "text/csv")})
    assert r.status_code == 201, r.text
    assert np.array_equal(read_back(client, skill, r.json()["id"])["positions"], p)


def test_a_csv_that_is_not_the_utf_16_its_mark_says_is_refused(client: TestClient, skill: str) -> None:
    r = client.post(f"/skills/{skill}/demonstrations",
                    files={"file": ("demo.csv", b"\xff\xfex\x00,\x00\x00\xd8", "text/csv")})
    assert r.status_code == 400, r.text
    error = r.json()["error"]
    assert error["field"] == "file" and "expected UTF-16 text after its byte-order mark" in error["message"]
    assert client.get(f"/skills/{skill}/demonstrations").json()["total"] == 0


def test_an_uploaded_file_without_a_label_is_labelled_by_its_name(client: TestClient, skill: str) -> None:
    # A folder of demonstrations uploaded file by file used to be stored unlabelled: in the
    # list and the viewer nothing said which demonstration came from which file.
    body = "x,y,z\n" + "\n".join(",".join(repr(float(v)) for v in row)
                                  for row in demo_positions(1, n=12))
    labels = []
    for filename, query in (("run_03.csv", ""), ("C:\\logs\\run_04.csv", ""),
                            ("run_05.csv", "?label=given"), ("x" * 300 + ".csv", "")):
        r = client.post(f"/skills/{skill}/demonstrations{query}",
                        files={"file": (filename, body.encode(), "text/csv")})
        assert r.status_code == 201, r.text
        labels.append(read_back(client, skill, r.json()["id"])["label"])
    assert labels[:3] == ["run_03.csv", "run_04.csv", "given"]
    assert len(labels[3]) == 256 and labels[3].startswith("xxx")
    # A raw body has no file name, and no label.
    r = client.post(f"/skills/{skill}/demonstrations", content=body.encode(),
                    headers={"content-type": "text/csv"})
    assert read_back(client, skill, r.json()["id"])["label"] in (None, "")
    # a multipart label too long says how long it was; one with NUL says that
    for label, came in (("y" * 300, "got 300 characters"), ("a\x00b", "got text with a NUL character")):
        r = client.post(f"/skills/{skill}/demonstrations", data={"label": label},
                        files={"file": ("run.csv", body.encode(), "text/csv")})
        assert r.status_code == 422 and r.json()["error"]["field"] == "label", r.text
        assert r.json()["error"]["message"].endswith(came), r.text


def test_csv_raw_body_for_a_2d_skill(client: TestClient) -> None:
    client.post("/skills", json={"name": "wipe", "dim": 2})
    p = demo_positions(0, n=8, dim=2)
    body = "t,x,y\n" + "\n".join(f"{i * 0.5},{float(x)!r},{float(y)!r}" for i, (x, y) in enumerate(p))
    r = client.post("/skills/wipe/demonstrations", content=body.encode(),
                    headers={"content-type": "text/csv"})
    assert r.status_code == 201, r.text
    back = read_back(client, "wipe", r.json()["id"])
    assert np.array_equal(back["positions"], p) and back["dim"] == 2
    # a 3-D CSV for the 2-D skill names the problem
    r = client.post("/skills/wipe/demonstrations", content=b"x,y,z\n1,2,3\n2,3,4\n3,4,5\n4,5,6\n",
                    headers={"content-type": "text/csv"})
    assert r.status_code == 422 and "header" in r.json()["error"]["field"]


@pytest.mark.parametrize("with_time", [False, True])
def test_npy_upload(client: TestClient, skill: str, with_time: bool) -> None:
    p = demo_positions(2, n=15)
    array = np.column_stack([np.arange(15.0), p]) if with_time else p.astype(np.float32)
    buf = io.BytesIO()
    np.save(buf, array, allow_pickle=False)
    r = client.post(f"/skills/{skill}/demonstrations", content=buf.getvalue(),
                    headers={"content-type": "application/x-npy"})
    assert r.status_code == 201, r.text
    back = read_back(client, skill, r.json()["id"])
    expected = p if with_time else p.astype(np.float32).astype(np.float64)
    assert np.array_equal(back["positions"], expected) and back["source"] == "npy"
    assert (back["timestamps"] is not None) == with_time


def test_mcap_ros2_pose_stamped(client: TestClient, skill: str) -> None:
    p = demo_positions(0, n=25)
    data = ros2_mcap(p, extra_topic=True)
    # two pose topics: the service asks which one
    r = client.post(f"/skills/{skill}/demonstrations", files={"file": ("run.mcap", data)})
    assert r.status_code == 422 and r.json()["error"]["field"] == "topic"
    assert "/ee_pose" in r.json()["error"]["message"]
    r = client.post(f"/skills/{skill}/demonstrations?topic=/nope", files={"file": ("run.mcap", data)})
    assert r.status_code == 422 and r.json()["error"]["field"] == "topic"
    r = client.post(f"/skills/{skill}/demonstrations?topic=/ee_pose",
                    files={"file": ("run.mcap", data)})
    assert r.status_code == 201, r.text
    back = read_back(client, skill, r.json()["id"])
    assert np.allclose(back["positions"], p)
    assert np.allclose(back["timestamps"], np.arange(25) * 0.01)
    assert np.allclose(back["orientations"], [[0, 0, 0, 1]] * 25)
    assert client.get(f"/skills/{skill}").json()["n_demonstrations"] == 1


@pytest.mark.parametrize(("frame_ids", "zero_stamps"),
                         [(("base",), False), (("base_link",), True), (("a", "base_link"), False)],
                         ids=["one frame", "stamps unset: log time", "mixed frames: generic"])
def test_mcap_ros2_decoders_agree(frame_ids: tuple[str, ...], zero_stamps: bool) -> None:
    """The one-pass numpy decoder of PoseStamped (same-length messages) and the generic
    mcap_ros2 decoder (everything else) read the same values."""
    from canal_service.uploads import parse_mcap

    p = demo_positions(2, n=40) * 123.456
    parsed = parse_mcap(ros2_mcap(p, frame_ids=frame_ids, zero_stamps=zero_stamps), 3, None)
    assert np.array_equal(parsed.positions, p)
    assert parsed.orientations is not None and np.array_equal(parsed.orientations,
                                                              [[0, 0, 0, 1]] * 40)
    assert parsed.timestamps is not None
    assert np.allclose(parsed.timestamps, np.arange(40) * 0.01, atol=1e-9)


def test_mcap_foxglove_pose_in_frame(client: TestClient, skill: str) -> None:
    p = demo_positions(1, n=10)
    data = foxglove_mcap(p, "foxglove.PoseInFrame")
    r = client.post(f"/skills/{skill}/demonstrations", content=data,
                    headers={"content-type": "application/x-mcap"})
    assert r.status_code == 201, r.text
    back = read_back(client, skill, r.json()["id"])
    assert np.allclose(back["positions"], p) and back["source"] == "mcap"
    assert np.allclose(back["timestamps"], np.arange(10.0))


def test_mcap_foxglove_poses_in_frame(client: TestClient, skill: str) -> None:
    p = demo_positions(2, n=10)
    r = client.post(f"/skills/{skill}/demonstrations",
                    files={"file": ("path.mcap", foxglove_mcap(p, "foxglove.PosesInFrame"))})
    assert r.status_code == 201, r.text
    back = read_back(client, skill, r.json()["id"])
    assert np.allclose(back["positions"], p) and back["timestamps"] is None


def test_mcap_for_a_2d_skill_keeps_x_and_y(client: TestClient) -> None:
    client.post("/skills", json={"name": "draw", "dim": 2})
    p = demo_positions(0, n=10)
    r = client.post("/skills/draw/demonstrations", files={"file": ("a.mcap", ros2_mcap(p))})
    assert r.status_code == 201, r.text
    assert np.allclose(read_back(client, "draw", r.json()["id"])["positions"], p[:, :2])


def test_list_is_paginated_and_delete_removes(client: TestClient, skill: str) -> None:
    ids = [client.post(f"/skills/{skill}/demonstrations",
                       json={"positions": demo_positions(j, n=6).tolist()}).json()["id"]
           for j in range(5)]
    page = client.get(f"/skills/{skill}/demonstrations?offset=1&limit=2").json()
    assert page["total"] == 5 and [d["id"] for d in page["items"]] == ids[1:3]
    assert "positions" not in page["items"][0]
    assert page["items"][0]["checksum"] == checksum(demo_positions(1, n=6))
    assert client.delete(f"/skills/{skill}/demonstrations/{ids[2]}").status_code == 204
    assert client.get(f"/skills/{skill}/demonstrations/{ids[2]}").status_code == 404
    assert [d["id"] for d in client.get(f"/skills/{skill}/demonstrations").json()["items"]] == [
        ids[0], ids[1], ids[3], ids[4]]


def test_skills_list_and_cascade(client: TestClient, fitted: str) -> None:
    client.post("/skills", json={"name": "a-first", "dim": 2})
    listing = client.get("/skills").json()
    assert [s["name"] for s in listing["items"]] == ["a-first", "pour"]
    pour = listing["items"][1]
    assert pour["n_demonstrations"] == 4 and pour["latest_model_version"] == 1
    assert client.get("/skills?limit=1&offset=1").json()["items"][0]["name"] == "pour"
    assert client.delete(f"/skills/{fitted}").status_code == 204
    # recreated under the same name: nothing of the old skill survives
    client.post("/skills", json={"name": fitted, "dim": 3})
    s = client.get(f"/skills/{fitted}").json()
    assert s["n_demonstrations"] == 0 and s["n_models"] == 0
    assert client.get(f"/skills/{fitted}/demonstrations").json()["total"] == 0


@pytest.mark.parametrize("how", ["json", "csv"])
def test_wrong_dimension_or_skill_is_refused_by_the_single_insert(client: TestClient, skill: str,
                                                                 how: str) -> None:
    """The insert itself checks the skill and its dimension (one statement): a 2-D demo for
    the 3-D skill is a 422 naming positions[0] with the skill's axes, an unknown skill a 404,
    and neither stores anything."""
    client.post("/skills", json={"name": "flat", "dim": 2})
    good = demo_positions(0)
    assert client.post(f"/skills/{skill}/demonstrations",
                       json={"positions": good.tolist()}).status_code == 201
    flat = good[:, :2]
    if how == "json":
        r = client.post(f"/skills/{skill}/demonstrations", json={"positions": flat.tolist()})
    else:
        text = "x,y\n" + "\n".join(f"{a!r},{b!r}" for a, b in flat)
        r = client.post(f"/skills/{skill}/demonstrations?format=csv", content=text,
                        headers={"content-type": "text/csv"})
    assert r.status_code == 422, r.text
    error = r.json()["error"]
    if how == "json":
        assert error["field"] == "positions[0]"
        assert "x, y, z for the 3-D skill 'pour'" in error["message"]
    r = client.post("/skills/nope/demonstrations", json={"positions": good.tolist()})
    assert r.status_code == 404 and r.json()["error"]["field"] == "name"
    assert client.get(f"/skills/{skill}").json()["n_demonstrations"] == 1
    assert client.get("/skills/flat").json()["n_demonstrations"] == 0
    # the 2-D skill takes the same rows, and its checksum is of what was sent
    r = client.post("/skills/flat/demonstrations", json={"positions": flat.tolist()})
    assert r.status_code == 201 and r.json()["checksum"] == checksum(flat)
    stored = client.get(f"/skills/flat/demonstrations/{r.json()['id']}").json()
    assert stored["dim"] == 2 and np.array_equal(np.asarray(stored["positions"]), flat)


def test_a_topic_sent_with_a_file_that_has_none_is_refused(client: TestClient, skill: str) -> None:
    # ?topic= picks an MCAP file's pose topic; with a CSV, NumPy or JSON body it was ignored
    # and the upload stored, so a client that meant another file was not told.
    csv = "\n".join(f"{k / 10},{k / 20},0" for k in range(12)).encode()
    for kwargs, got in (({"files": {"file": ("demo.csv", csv, "text/csv")}}, "a CSV file"),
                        ({"json": {"positions": [[k / 10, 0.0, 0.0] for k in range(12)]}},
                         "a JSON body")):
        r = client.post(f"/skills/{skill}/demonstrations", params={"topic": "/arm/pose"}, **kwargs)
        assert r.status_code == 422, r.text
        error = r.json()["error"]
        assert error["field"] == "topic" and error["message"] == (
            f"expected topic only with an MCAP file, got {got}"), error
    assert client.get(f"/skills/{skill}/demonstrations").json()["total"] == 0


def _pose_in_frame_mcap(payloads: list[dict[str, object]], log_times: list[int]) -> bytes:
    buf = io.BytesIO()
    writer = Writer(buf, compression=CompressionType.ZSTD)
    writer.start()
    schema_id = writer.register_schema(name="foxglove.PoseInFrame", encoding="jsonschema",
                                       data=json.dumps({"type": "object"}).encode())
    channel = writer.register_channel(topic="/pose", message_encoding="json", schema_id=schema_id)
    for payload, log_time in zip(payloads, log_times, strict=True):
        writer.add_message(channel, log_time=log_time, publish_time=log_time,
                           data=json.dumps(payload).encode())
    writer.finish()
    return buf.getvalue()


def _pose_payload(p: np.ndarray, stamp: object) -> dict[str, object]:
    return {"timestamp": stamp, "frame_id": "base",
            "pose": {"position": {"x": p[0], "y": p[1], "z": p[2]},
                     "orientation": {"x": 0, "y": 0, "z": 0, "w": 1}}}


# A stamp no clock gives (too large for 64-bit nanoseconds, fractional, of another type) was a
# 500 (an overflow) or truncated without a word: refused, naming the message and the field.
@pytest.mark.parametrize(("tried", "stamp", "field"), [
    ("seconds past 64-bit nanoseconds", {"sec": 2**70, "nsec": 0}, "timestamp.sec"),
    ("nanoseconds of 1e30", {"sec": 1, "nsec": 1e30}, "timestamp.nsec"),
    ("fractional seconds", {"sec": 1.5, "nsec": 0}, "timestamp.sec"),
    ("seconds as a string", {"sec": "1", "nsec": 0}, "timestamp.sec"),
    ("seconds as true", {"sec": True, "nsec": 0}, "timestamp.sec"),
    ("negative seconds", {"sec": -1, "nsec": 0}, "timestamp.sec"),
    ("a billion nanoseconds", {"sec": 1, "nsec": 10**9}, "timestamp.nsec"),
])
def test_a_pose_in_frame_stamp_no_clock_gives_is_refused(
        client: TestClient, skill: str, tried: str, stamp: dict[str, object], field: str) -> None:
    p = demo_positions(1, n=6)
    payloads = [_pose_payload(q, {"sec": 100 + i, "nsec": 0}) for i, q in enumerate(p)]
    payloads[3] = _pose_payload(p[3], stamp)
    r = client.post(f"/skills/{skill}/demonstrations", content=_pose_in_frame_mcap(
        payloads, list(range(6))), headers={"content-type": "application/x-mcap"})
    assert r.status_code == 422, (tried, r.text)
    error = r.json()["error"]
    assert field in error["field"] and "3" in error["field"], (tried, error)
    assert client.get(f"/skills/{skill}/demonstrations").json()["items"] == []


@pytest.mark.parametrize("value", ["0.5", True, None, [1]])
def test_a_pose_in_frame_coordinate_that_is_not_a_number_is_refused(
        client: TestClient, skill: str, value: object) -> None:
    p = demo_positions(1, n=6)
    payloads = [_pose_payload(q, {"sec": 100 + i, "nsec": 0}) for i, q in enumerate(p)]
    payloads[2]["pose"]["position"]["y"] = value  # type: ignore[index]
    r = client.post(f"/skills/{skill}/demonstrations", content=_pose_in_frame_mcap(
        payloads, list(range(6))), headers={"content-type": "application/x-mcap"})
    assert r.status_code == 422, (value, r.text)
    assert "position.y" in r.json()["error"]["field"], r.json()
    assert client.get(f"/skills/{skill}/demonstrations").json()["items"] == []


def test_log_times_past_the_signed_64_bit_range_give_the_times_between_them(
        client: TestClient, skill: str) -> None:
    # MCAP log times are unsigned 64-bit: ones past 2**63 overflowed a signed array (a 500)
    p = demo_positions(1, n=6)
    payloads = [_pose_payload(q, {"sec": 0, "nsec": 0}) for q in p]
    base = 2**64 - 10**9
    r = client.post(f"/skills/{skill}/demonstrations", content=_pose_in_frame_mcap(
        payloads, [base + i * 10**7 for i in range(6)]),
        headers={"content-type": "application/x-mcap"})
    assert r.status_code == 201, r.text
    back = read_back(client, skill, r.json()["id"])
    assert np.allclose(back["timestamps"], np.arange(6) * 0.01, atol=1e-6)
    # and a PoseStamped whose stamps are unset (the log time is taken), read column-wise
    r = client.post(f"/skills/{skill}/demonstrations", content=ros2_mcap(
        p, zero_stamps=True, t0=base), headers={"content-type": "application/x-mcap"})
    assert r.status_code == 201, r.text
    back = read_back(client, skill, r.json()["id"])
    assert np.allclose(back["timestamps"], np.arange(6) * 0.01, atol=1e-6)
