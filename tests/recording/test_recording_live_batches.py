"""The live recording's batch codec and writers: columns in, the same files out.

The bridges hand the recorder binary column batches (``canal_service.record_batches``, version 3); the
recorder writes them as columns (MCAP messages from per-topic templates, added to the chunk
in one write). These tests decode what was encoded, refuse what is not a whole batch (and
queue nothing of it), and read the MCAP back record by record with mcap's own reader.
"""

from __future__ import annotations

import math
import struct
import time
from pathlib import Path
from typing import Any

import numpy as np
import orjson
import pytest
import rerun as rr
import zstandard
from canal_service import record_batches
from canal_service.adapters import mcap_writer
from canal_service.adapters.rerun_chunks import live_chunks
from canal_service.recording import Recorder
from canal_service.recording import foxglove as fx
from canal_service.recording.events import live_rows
from canal_service.recording.live import LiveOptions, LiveSubscriber
from canal_service.recording.mcap_log import McapSegment
from mcap.reader import make_reader
from mcap.records import Chunk, Message, MessageIndex
from mcap.stream_reader import StreamReader, breakup_chunk
from recording_helpers import mcap_counts, mcap_messages

from canal_protocol import keys as keyspace
from canal_protocol import wire

NAN = float("nan")
Q = (0.0, 0.0, 0.6, 0.8)


def _rows3() -> list[tuple[Any, ...]]:
    """A 3-D stream: an orientation or not, a NaN eta, a flip out of the canal and back."""
    return [
        (1_000, (0.1, 0.2, 0.3), None, [0.1, 0.2, 0.4], Q, 0.25, NAN, 3, True, False, "ok"),
        (2_000, (1.0, -2.5, 1e-300), Q, [1.0, 2.0, 3.0], None, 0.5, 1e308, 4, False, False,
         "outside_canal"),
        (3_000, (-0.0, 5.0, 6.0), (0.0, 0.0, 0.0, 1.0), (7.0, 8.0, 9.0), (1.0, 0.0, 0.0, 0.0),
         1.0, 0.0, 79, True, True, "ok"),
    ]


def _rows2() -> list[tuple[Any, ...]]:
    return [(5_000, (0.1, 0.2), None, (0.3, 0.4), None, 0.1, 0.2, 0, False, True, "ok")]


def _same(a: Any, b: Any) -> bool:
    """Equal, NaN equal to NaN, sequences elementwise (tuples and lists alike)."""
    if isinstance(a, float) and isinstance(b, float):
        return a == b or (math.isnan(a) and math.isnan(b))
    if isinstance(a, list | tuple) and isinstance(b, list | tuple):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    return bool(a == b)


def test_a_batch_round_trips_every_field() -> None:
    streams = [("pour", "arm1", 10, 9, 1, 0, 7, _rows3()), ("draw", "pen", 1, 1, 0, 0, 0, _rows2()),
               ("pour", "idle", 4, 0, 0, 4, 4, [])]
    batch = record_batches.decode_record_batch(record_batches.encode_record_batch("b0-1-ab", 17, streams))
    assert (batch.bridge, batch.n) == ("b0-1-ab", 17)
    assert [(s.skill, s.robot, s.poses, s.answered, s.coalesced, s.errors, s.decimated, len(s))
            for s in batch.streams] == [("pour", "arm1", 10, 9, 1, 0, 7, 3),
                                        ("draw", "pen", 1, 1, 0, 0, 0, 1),
                                        ("pour", "idle", 4, 0, 0, 4, 4, 0)]
    for sent, got in zip(streams, batch.streams, strict=True):
        assert len(got.rows) == len(sent[7])
        for row, back in zip(sent[7], got.rows, strict=True):
            assert _same(list(row), [back.t_ns, back.position, back.orientation, back.target,
                                     back.target_orientation, back.progress, back.eta,
                                     back.section, back.inside, back.done, back.status]), back
    assert batch.streams[1].dim == 2


def test_the_recorder_gets_the_columns_as_sent() -> None:
    stream = record_batches.decode_record_batch(record_batches.encode_record_batch(
        "b", 0, [("pour", "arm1", 3, 3, 0, 0, 0, _rows3())])).streams[0]
    from canal_service.recording.live import rows_of

    rows = rows_of(stream)
    assert rows.t_ns.tolist() == [1_000, 2_000, 3_000]
    assert rows.orientation.tolist() == [[0.0, 0.0, 0.0, 1.0], list(Q), [0.0, 0.0, 0.0, 1.0]]
    assert rows.target_orientation.tolist()[0] == list(Q)
    assert np.isnan(rows.eta[0]) and rows.eta[1] == 1e308
    assert rows.inside.tolist() == [True, False, True] and rows.done.tolist() == [False, False, True]
    assert rows.section_index.tolist() == [3, 4, 79]
    assert rows.route.tolist() == [-1, -1, -1]  # rows without a route: a model of one route
    with_routes = [(*r, k) for r, k in zip(_rows3(), (1, 1, 0), strict=True)]
    routed = record_batches.decode_record_batch(record_batches.encode_record_batch(
        "b", 0, [("pour", "arm1", 3, 3, 0, 0, 0, with_routes)])).streams[0]
    assert rows_of(routed).route.tolist() == [1, 1, 0]
    assert [r.route for r in routed.rows] == [1, 1, 0]
    flat = record_batches.decode_record_batch(record_batches.encode_record_batch(
        "b", 0, [("draw", "pen", 1, 1, 0, 0, 0, _rows2())])).streams[0]
    assert rows_of(flat).position.tolist() == [[0.1, 0.2, 0.0]]  # 2-D in the z=0 plane


def _old_json_batch() -> bytes:
    return orjson.dumps({"v": 1, "bridge": "b", "n": 0, "streams": [
        {"skill": "pour", "robot": "arm1", "poses": 1, "answered": 1, "coalesced": 0,
         "errors": 0, "decimated": 0, "rows": [[1, [0, 0, 0], None, [0, 0, 0], None, 0.0, 0.1,
                                                 0, True, False, "ok"]]}]})


def test_a_bridge_of_another_version_is_named_as_such() -> None:
    with pytest.raises(wire.WireError, match=r"JSON \(version 1\).*older Canal"):
        record_batches.decode_record_batch(_old_json_batch())
    good = record_batches.encode_record_batch("b", 0, [("pour", "arm1", 3, 3, 0, 0, 0, _rows3())])
    for older in (2, 4):  # a version 2 batch has no route column
        with pytest.raises(wire.WireError, match=f"version 3, got version {older}"):
            record_batches.decode_record_batch(good[:3] + bytes([older]) + good[4:])


def _malformed() -> dict[str, bytes]:
    """Batches that are not whole version 3 batches (each must be refused whole)."""
    good = record_batches.encode_record_batch("b", 0, [("pour", "arm1", 3, 3, 0, 0, 0, _rows3()),
                                             ("pour", "arm2", 3, 3, 0, 0, 0, _rows3())])
    size = int.from_bytes(good[4:8], "little")
    header = orjson.loads(good[8:8 + size])

    def with_header(**change: Any) -> bytes:
        h = orjson.dumps({**header, **change})
        return good[:4] + len(h).to_bytes(4, "little") + h + good[8 + size:]

    streams = header["streams"]
    status_at = len(good) - 1 - 2 * 3  # the second stream's last status byte (3 routes after)
    return {
        "empty": b"",
        "no magic": b"XYZ\x02" + good[4:],
        "cut in the header": good[:8 + size // 2],
        "cut in the second stream": good[:-5],
        "no route column": good[:-6],
        "trailing bytes": good + b"\x00",
        "more rows than sent": with_header(streams=[streams[0], [*streams[1][:7], 4, 3]]),
        "a wildcard robot": with_header(streams=[streams[0], ["pour", "*", *streams[1][2:]]]),
        "a negative count": with_header(streams=[streams[0], [*streams[1][:2], -1,
                                                              *streams[1][3:]]]),
        "a dimension of 17": with_header(streams=[streams[0], [*streams[1][:8], 17]]),
        "no bridge": with_header(bridge=None),
        "an unknown status": good[:status_at] + b"\xfe" + good[status_at + 1:],
        "a header that is not JSON": good[:8] + b"\xff" * size + good[8 + size:],
    }


@pytest.mark.parametrize("case", sorted(_malformed()))
def test_a_malformed_batch_is_refused(case: str) -> None:
    with pytest.raises(wire.WireError):
        record_batches.decode_record_batch(_malformed()[case])


def test_a_malformed_batch_is_counted_and_nothing_of_it_is_queued(tmp_path: Path) -> None:
    rec = Recorder(tmp_path / "rec", flush_interval_s=60)
    sub = LiveSubscriber(rec, LiveOptions())  # not started: take() is what the drain calls
    key = keyspace.recorder_key("b", "canal")
    try:
        refused = [*_malformed().values(), _old_json_batch(),
                   # whole but inconsistent: the second stream's counts do not add up
                   record_batches.encode_record_batch("b", 0, [("pour", "arm1", 3, 3, 0, 0, 0, _rows3()),
                                                     ("pour", "arm2", 9, 3, 0, 0, 0, _rows3())]),
                   # a batch of another bridge than the key names
                   record_batches.encode_record_batch("c", 0, [("pour", "arm1", 3, 3, 0, 0, 0, _rows3())])]
        for data in refused:
            assert sub.take(key, data) is False
        assert sub.stats.bad_payload == len(refused)
        assert sub.stats.batches == 0 and not sub.stats.streams and not sub.stats.last_n
        assert rec.health()["queued"] == 0
        ok = record_batches.encode_record_batch("b", 0, [("pour", "arm1", 5, 3, 0, 0, 2, _rows3())])
        assert sub.take(key, ok) is True
        assert rec.health()["queued"] == 6  # three rows: a pose and a target sample each
    finally:
        rec.close()
    assert sub.stream_counts()[("pour", "arm1")] == {
        "poses": 5, "answered": 3, "coalesced": 0, "errors": 0, "decimated": 2, "kept": 3,
        "recorded": 3, "dropped": 0, "stale": 0, "pending": 0}
    path = rec.export_mcap("pour")
    assert [m["pose"]["position"] for m in mcap_messages(path, "/live/arm1/pose")] == [
        {"x": 0.1, "y": 0.2, "z": 0.3}, {"x": 1.0, "y": -2.5, "z": 1e-300},
        {"x": -0.0, "y": 5.0, "z": 6.0}]
    states = mcap_messages(path, "/live/arm1/state")
    assert [(s["eta"], s["inside"], s["done"]) for s in states] == [
        (None, True, False), (1e308, False, False), (0.0, True, True)]
    assert mcap_counts(path).get("/live/arm2/pose", 0) == 0



def test_a_stream_whose_dimension_changes_is_sent_in_runs_and_counted_as_one() -> None:
    # Its skill deleted and created again with another dimension: the stream's rows of both
    # could not share one entry, and the whole batch (every robot's rows) failed.
    rows = [*_rows3(), *_rows2(), *_rows3()[:1]]
    data = record_batches.encode_record_batch("b", 0, [("pour", "arm1", 7, 6, 1, 0, 2, rows),
                                                       ("pour", "arm2", 3, 3, 0, 0, 0, _rows3())])
    batch = record_batches.decode_record_batch(data)
    assert [(st.robot, st.dim, len(st)) for st in batch.streams] == [
        ("arm1", 3, 3), ("arm1", 2, 1), ("arm1", 3, 1), ("arm2", 3, 3)]
    assert all(len(st) + st.decimated == st.poses for st in batch.streams)
    got = [row for st in batch.streams[:3] for row in st.rows]
    assert _same([list(r) for r in rows], [
        [b.t_ns, b.position, b.orientation, b.target, b.target_orientation, b.progress, b.eta,
         b.section, b.inside, b.done, b.status] for b in got])
    rec = Recorder(Path("/nonexistent"), enabled=False)
    sub = LiveSubscriber(rec, LiveOptions())  # not started: take() is what the drain calls
    assert sub.take(keyspace.recorder_key("b", "canal"), data) is True
    assert sub.stream_counts()[("pour", "arm1")] | {"recorded": 0} == {
        "poses": 7, "answered": 6, "coalesced": 1, "errors": 0, "decimated": 2, "kept": 5,
        "recorded": 0, "dropped": 0, "stale": 0, "pending": 5}


def test_a_stream_that_cannot_be_encoded_is_left_out_and_the_others_are_sent() -> None:
    bad = [(*_rows3()[0][:10], "no_such_status")]
    streams = [("pour", "arm1", 3, 3, 0, 0, 0, _rows3()), ("pour", "arm2", 1, 1, 0, 0, 0, bad),
               ("pour", "arm3", 1, 1, 0, 0, 0, _rows2())]
    with pytest.raises(KeyError):
        record_batches.encode_record_batch("b", 0, streams)
    left_out: list[Any] = []
    batch = record_batches.decode_record_batch(
        record_batches.encode_record_batch("b", 4, streams, left_out=left_out))
    assert [(st.robot, len(st)) for st in batch.streams] == [("arm1", 3), ("arm3", 1)]
    assert [(stream[1], type(exc)) for stream, exc in left_out] == [("arm2", KeyError)]

AWKWARD = np.array([[NAN, np.inf, -0.0], [1e308, 0.0, 1.0], [1 / 3, 2 / 3, 0.1],
                    [-1e-300, 123456789.123, -5e-7]])


def test_the_templates_write_what_the_message_builders_write() -> None:
    rng = np.random.default_rng(3)
    t = np.array([0, 999_999_999, 1_000_000_000, 1_796_179_380_213_893_929], dtype=np.int64)
    q = rng.standard_normal((4, 4))
    eta = np.array([NAN, 1e308, np.inf, 0.5])
    name = 'a%s"b'  # a template's format sign and a JSON escape in a name
    assert fx.pose_in_frame_messages(t, AWKWARD, q) == [
        fx.pose_in_frame(a, p, r) for a, p, r in zip(t.tolist(), AWKWARD.tolist(), q.tolist(),
                                                     strict=True)]
    assert fx.frame_transform_messages(t, fx.CANAL_FRAME, f"robot/{name}", AWKWARD, q) == [
        fx.frame_transform(a, fx.CANAL_FRAME, f"robot/{name}", p, r)
        for a, p, r in zip(t.tolist(), AWKWARD.tolist(), q.tolist(), strict=True)]
    assert fx.pose_and_frame_messages(t, AWKWARD, q, f"robot/{name}") == (
        fx.pose_in_frame_messages(t, AWKWARD, q),
        fx.frame_transform_messages(t, fx.CANAL_FRAME, f"robot/{name}", AWKWARD, q))
    inside, done = np.array([True, False, True, False]), np.array([False, False, True, True])
    assert fx.tracker_state_messages(t, name, AWKWARD[:, 2], eta, np.array([-1, 0, 5, 199]),
                                     inside, done) == [
        fx.plain(a, robot=name, progress=p, eta=None if e != e else e, section_index=s,
                 inside=i, done=d)
        for a, p, e, s, i, d in zip(t.tolist(), AWKWARD[:, 2].tolist(), eta.tolist(),
                                    [-1, 0, 5, 199], inside.tolist(), done.tolist(), strict=True)]


def _chunks(path: Path) -> list[tuple[bytes, list[Message], list[MessageIndex]]]:
    """Each chunk's records (CRC checked, decompressed), its messages and the message
    indexes written after it."""
    out: list[tuple[bytes, list[Message], list[MessageIndex]]] = []
    with open(path, "rb") as f:
        for record in StreamReader(f, emit_chunks=True, validate_crcs=True).records:
            if isinstance(record, Chunk):
                data = zstandard.ZstdDecompressor().decompress(
                    record.data, max_output_size=record.uncompressed_size)
                messages = [r for r in breakup_chunk(record, validate_crc=True)
                            if isinstance(r, Message)]
                out.append((data, messages, []))
            elif isinstance(record, MessageIndex):
                out[-1][2].append(record)
    return out


def test_live_messages_have_exact_message_indexes(tmp_path: Path) -> None:
    """Records added in one write are indexed as the public add_message would index them,
    also when a chunk holds both (the segment's own /tf, then live frames on /tf)."""
    path = tmp_path / "live.mcap"
    t0 = time.time_ns()
    seg = McapSegment(path, t0)  # puts world -> canal on /tf through add_message
    # mcap's Writer internals are there (mcap as pinned): live rows in one write
    assert mcap_writer.writer_internals(seg._writer) is not None
    m = 40
    for k, robot in enumerate(("arm1", "arm2", "arm1")):
        t = t0 + 10_000_000 * (np.arange(m) + k * m)
        seg.live(live_rows("pour", robot, t, AWKWARD[np.arange(m) % 4], None,
                           AWKWARD[::-1][np.arange(m) % 4], np.tile(Q, (m, 1)),
                           np.linspace(0, 1, m), np.full(m, 0.5), np.arange(m),
                           np.arange(m) % 2 == 0, np.zeros(m, bool)))
        if k == 1:
            seg.flush()  # a chunk per flush: its indexes start again
    seg.close()
    chunks = _chunks(path)
    assert len(chunks) == 2
    for data, messages, indexes in chunks:
        by_channel: dict[int, list[Message]] = {}
        for msg in messages:
            by_channel.setdefault(msg.channel_id, []).append(msg)
        assert sorted(ix.channel_id for ix in indexes) == sorted(by_channel)
        for ix in indexes:
            # every entry points at a Message record of its channel with its log time
            pointed = [struct.unpack_from("<BQHIQ", data, offset) for _, offset in ix.records]
            assert [(op, cid, t) for op, _, cid, _, t in pointed] == [
                (0x05, ix.channel_id, msg.log_time) for msg in by_channel[ix.channel_id]]
            assert [t for t, _ in ix.records] == [msg.log_time for msg in by_channel[ix.channel_id]]
    counts = mcap_counts(path)
    assert counts["/live/arm1/pose"] == 2 * m and counts["/live/arm2/state"] == m
    assert counts["/tf"] == 1 + 3 * m
    with open(path, "rb") as f:  # the indexed reader, in log-time order, sees them all
        read = [(c.topic, msg.log_time) for _, c, msg in make_reader(f).iter_messages(
            topics=["/live/arm1/pose"], log_time_order=True)]
    assert [t for _, t in read] == [t0 + 10_000_000 * i for i in [*range(m), *range(2 * m, 3 * m)]]
    tf = mcap_messages(path, "/tf")
    assert tf[0]["child_frame_id"] == fx.CANAL_FRAME
    assert {f["child_frame_id"] for f in tf[1:]} == {"robot/arm1", "robot/arm2"}


def test_the_queue_drops_the_oldest_rows_of_a_chunk(tmp_path: Path) -> None:
    rec = Recorder(tmp_path / "rec", flush_interval_s=60, live_queue_size=10)  # 5 rows
    m = [3, 4]
    t0 = time.time_ns()
    chunks = []
    at = 0
    for n in m:
        t = t0 + 1_000_000 * np.arange(at, at + n)
        at += n
        chunks.append(live_rows("pour", "arm1", t, np.zeros((n, 3)), None, np.zeros((n, 3)),
                                None, np.zeros(n), np.zeros(n), np.zeros(n, int),
                                np.ones(n, bool), np.zeros(n, bool)))
    rec.live_rows(chunks)
    health = rec.health()
    assert health["queued"] == 10 and health["dropped"] == 4  # 2 rows: a pose and target each
    assert rec.live_stream_counts()[1] == {("pour", "arm1"): 2}
    rec.close()
    stamps = [s["timestamp"]["sec"] * 10**9 + s["timestamp"]["nsec"]
              for s in mcap_messages(rec.export_mcap("pour"), "/live/arm1/state")]
    assert stamps == [t0 + 1_000_000 * k for k in range(2, 7)]  # the newest five


def _leaves(array: Any) -> np.ndarray:
    """The values of nested Arrow lists, flat."""
    while hasattr(array, "flatten"):
        array = array.flatten()
    return np.asarray(array.to_numpy(zero_copy_only=False), dtype=np.float64)


@pytest.mark.parametrize("dim", [3, 2])
def test_rerun_chunks_are_what_the_archetype_columns_build(dim: int) -> None:
    """The live Rerun chunks, built from numpy, equal ``rr.<Archetype>.columns`` arrays."""
    m = 6
    rng = np.random.default_rng(dim)
    eta = rng.random(m)
    eta[0], eta[1] = NAN, 1e308
    rows = live_rows("pour", "arm1", time.time_ns() + np.arange(m), rng.random((m, dim)),
                     rng.standard_normal((m, 4)), rng.random((m, dim)), None, rng.random(m),
                     eta, np.arange(m), np.ones(m, bool), np.zeros(m, bool))
    points = rr.Points2D if dim == 2 else rr.Points3D
    pose, target = rows.position[:, :dim], rows.target[:, :dim]
    expected = {
        "live/arm1/pose": points.columns(positions=pose, colors=np.tile((220, 40, 160, 255),
                                                                        (m, 1))),
        "live/arm1/target": points.columns(positions=target, colors=np.tile((40, 200, 220, 255),
                                                                            (m, 1))),
        "live/arm1/progress": rr.Scalars.columns(scalars=rows.progress),
        "live/arm1/eta": rr.Scalars.columns(scalars=rows.eta),
    }
    if dim == 3:
        expected["live/arm1/frame"] = rr.Transform3D.columns(translation=rows.position,
                                                             quaternion=rows.orientation)
    chunks = live_chunks("live/arm1", rows, dim)
    assert sorted(e for e, _, _ in chunks) == sorted(expected)
    time_column = rr.TimeColumn("wall_time", timestamp=rows.t_ns.astype("datetime64[ns]"))
    for entity, timelines, components in chunks:
        assert list(timelines) == ["wall_time"]
        assert timelines["wall_time"].equals(time_column.as_arrow_array())
        want = {str(c.component_descriptor()): c.as_arrow_array() for c in expected[entity]}
        got = {str(d): a for d, a in components.items()}
        assert sorted(got) == sorted(want), entity
        for name, array in got.items():
            assert array.type == want[name].type and array.offsets.equals(want[name].offsets)
            assert np.array_equal(_leaves(array), _leaves(want[name]), equal_nan=True), (
                entity, name)


def test_many_robot_names_are_counted_in_sums_not_one_by_one_for_ever(tmp_path: Path) -> None:
    # Every (skill, robot) ever heard kept its own counters in the service process, and every
    # /healthz copied and sorted them all: robot names are the clients' to choose.
    from canal_service.recording.live import MAX_COUNTED_STREAMS

    n = MAX_COUNTED_STREAMS + 100
    # every robot drawn (the recording's own robot cap is another test's)
    rec = Recorder(tmp_path / "rec", flush_interval_s=0.05, max_robots=2 * n)
    sub = LiveSubscriber(rec, LiveOptions())
    key = keyspace.recorder_key("b", "canal")
    try:
        many = [("pour", f"r{i}", 3, 3, 0, 0, 2, _rows3()[:1]) for i in range(n)]
        assert sub.take(key, record_batches.encode_record_batch("b", 0, many)) is True
        deadline = time.monotonic() + 30
        while sum(rec.live_stream_counts()[0].values()) < n:  # every row written and flushed
            assert time.monotonic() < deadline, "the rows were not flushed"
            time.sleep(0.05)
        one = [("pour", "last", 3, 3, 0, 0, 2, _rows3()[:1])]
        assert sub.take(key, record_batches.encode_record_batch("b", 1, one)) is True
        assert len(sub.stats.streams) <= MAX_COUNTED_STREAMS // 2 + 1
        assert ("pour", "last") in sub.stats.streams  # the stream heard last keeps its own
        assert len(rec.live_stream_counts()[0]) <= MAX_COUNTED_STREAMS // 2 + 1
        live = sub.health()
        # the totals are exact: the retired streams' counts are in them
        assert (live["poses"], live["kept"], live["decimated"]) == (3 * (n + 1), n + 1, 2 * (n + 1))
        assert live["recorded"] + live["pending"] == n + 1 and live["dropped"] == 0
        assert live["complete"] is True and len(live["streams"]) <= 64
    finally:
        rec.close()
    live = sub.health()
    assert live["recorded"] == n + 1 and live["pending"] == 0
