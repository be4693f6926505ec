"""MCAP uploads: a bounded reader of its own.

The ``mcap`` package's reader decompresses a chunk whole, to the size the chunk declares;
this one decompresses in pieces of a fixed size and counts the bytes produced against the
upload's limit, scanning records as a stream and keeping only the pose topic's messages.
ROS 2 PoseStamped messages are read with the live bridge's CDR codec
(:mod:`canal_protocol.codecs`).
"""

from __future__ import annotations

import io
import struct
import zlib
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import orjson

from canal_core.errors import InvalidInputError
from canal_core.validation import check_int
from canal_protocol import codecs

from ..errors import BadUpload, InvalidInput, TooLarge
from ..validation import FloatArray
from .common import MCAP_MAGIC, Budget, ParsedUpload, UploadLimits

# Decompressed output is produced and scanned in pieces of this size, never more at once.
_PIECE = 1 << 20
# Bytes of pose payload kept per allowed sample (a JSON PoseInFrame is ~250 bytes).
_POSE_BYTES_PER_POINT = 1024

ROS2_POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
FOXGLOVE_POSE = "foxglove.PoseInFrame"
FOXGLOVE_POSES = "foxglove.PosesInFrame"
POSE_SCHEMAS = (ROS2_POSE_STAMPED, FOXGLOVE_POSE, FOXGLOVE_POSES)

_OP_HEADER = 0x01
_OP_FOOTER = 0x02
_OP_SCHEMA = 0x03
_OP_CHANNEL = 0x04
_OP_MESSAGE = 0x05
_OP_CHUNK = 0x06
_OP_DATA_END = 0x0F
_OP_MAX = 0x0F  # opcodes above are reserved for extensions and skipped; 0x00 is invalid

_U8 = struct.Struct("<B")
_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")
_RECORD = struct.Struct("<BQ")
_MESSAGE = struct.Struct("<HIQQ")
_CHUNK_HEAD = struct.Struct("<QQQI")


@dataclass(frozen=True)
class _Schema:
    id: int
    name: str
    encoding: str
    data: bytes


@dataclass(frozen=True)
class _Channel:
    id: int
    schema_id: int
    topic: str
    message_encoding: str


class _McapScan:
    """One pass over an MCAP's records, keeping only what the pose topic needs.

    Records are read from a buffer that grows by bounded decompressed pieces; a message on
    any other channel costs one header unpack and is dropped at once.
    """

    def __init__(self, topic: str | None, budget: Budget) -> None:
        self.topic = topic
        self.budget = budget
        self.schemas: dict[int, _Schema] = {}
        self.channels: dict[int, _Channel] = {}
        self.pose_topics: set[str] = set()
        self.keep: set[int] = set()  # channel ids whose messages are kept
        self.messages: dict[int, list[tuple[int, bytes]]] = {}
        self.kept = 0
        self.kept_bytes = 0
        self.max_kept_bytes = max(budget.limits.max_points, 1) * _POSE_BYTES_PER_POINT
        self.records = 0
        self.data_end = False
        self.skip = 0  # bytes still to drop of a skipped record that spans pieces

    # -- records ---------------------------------------------------------------------------

    def records_in(self, buf: bytes | bytearray | memoryview, pos: int, end: int, in_chunk: bool) -> int:
        """Handle the whole records in ``buf[pos:end]``; return where the first partial one
        starts (``end`` when none is left over)."""
        unpack_record = _RECORD.unpack_from
        last_skipped = b""  # opcode, length and channel of the last skipped message
        while pos + 9 <= end:
            op, length = unpack_record(buf, pos)
            body = pos + 9
            stop = body + length
            if stop > end:
                if in_chunk and not self._needed(op, buf, body, end, length):
                    # Skipped without being buffered, however long it claims to be.
                    self.skip = stop - end
                    return end
                return pos
            if op == _OP_MESSAGE:
                if length < _MESSAGE.size:
                    raise BadUpload("MCAP message record too short", field="file")
                channel_id = _U16.unpack_from(buf, body)[0]
                if channel_id in self.keep:
                    self._keep(channel_id, buf, body, stop)
                elif channel_id not in self.channels:
                    raise BadUpload(f"MCAP message on undeclared channel {channel_id}",
                                    field="file")
                else:
                    head = bytes(buf[pos:body + 2])
                    if head == last_skipped:
                        # A run of same-size messages on a skipped channel (a flood of
                        # empty messages, a high-rate sensor): jump over it in numpy.
                        pos = _skip_run(buf, pos, end, head, stop - pos)
                        self.records += 1
                        self.budget.tick()
                        continue
                    last_skipped = head
            elif op == _OP_SCHEMA:
                self._schema(bytes(buf[body:stop]))
            elif op == _OP_CHANNEL:
                self._channel(bytes(buf[body:stop]))
            elif op == 0 or (in_chunk and op in (_OP_CHUNK, _OP_HEADER, _OP_FOOTER, _OP_DATA_END)):
                raise BadUpload(f"invalid MCAP record opcode {op:#04x}"
                                + (" inside a chunk" if op else ""), field="file")
            elif not in_chunk and op == _OP_CHUNK:
                self._chunk(buf, body, stop)
            elif op == _OP_DATA_END:
                self.data_end = True
                return stop
            # every other record (indexes, attachments, metadata, statistics) is skipped
            pos = stop
            self.records += 1
            if not self.records & 0xFFF:
                self.budget.tick()
        return pos

    def _needed(self, op: int, buf: bytes | bytearray | memoryview, body: int, end: int,
                length: int) -> bool:
        """Whether a record cut by a piece's end must be buffered whole (else it is skipped)."""
        if op == _OP_MESSAGE:
            if body + 2 > end:
                return True  # cannot tell the channel yet: wait for two more bytes
            if _U16.unpack_from(buf, body)[0] not in self.keep:
                return False
        elif op not in (_OP_SCHEMA, _OP_CHANNEL):
            return False
        if length > self.max_kept_bytes:
            raise TooLarge(f"an MCAP record of {length} bytes is larger than a pose upload "
                           f"may keep ({self.max_kept_bytes} bytes)", field="file")
        return True

    def _keep(self, channel_id: int, buf: bytes | bytearray | memoryview, body: int, stop: int) -> None:
        _cid, _seq, log_time, _pub = _MESSAGE.unpack_from(buf, body)
        data = bytes(buf[body + _MESSAGE.size:stop])
        self.kept += 1
        self.kept_bytes += len(data)
        topic = self.channels[channel_id].topic
        self.budget.points(self.kept, f"pose topic {topic!r}")
        if self.kept_bytes > self.max_kept_bytes:
            raise TooLarge(f"pose messages on {topic!r} are larger than "
                           f"{self.max_kept_bytes} bytes in total", field="file")
        self.messages.setdefault(channel_id, []).append((log_time, data))

    def _schema(self, body: bytes) -> None:
        try:
            schema_id = _U16.unpack_from(body, 0)[0]
            name, pos = _string(body, 2)
            encoding, pos = _string(body, pos)
            size = _U32.unpack_from(body, pos)[0]
            data = body[pos + 4:pos + 4 + size]
        except (struct.error, UnicodeDecodeError) as exc:
            raise BadUpload(f"malformed MCAP schema record: {exc}", field="file") from exc
        self.schemas[schema_id] = _Schema(schema_id, name, encoding, data)

    def _channel(self, body: bytes) -> None:
        try:
            channel_id, schema_id = struct.unpack_from("<HH", body, 0)
            topic, pos = _string(body, 4)
            encoding, pos = _string(body, pos)
        except (struct.error, UnicodeDecodeError) as exc:
            raise BadUpload(f"malformed MCAP channel record: {exc}", field="file") from exc
        channel = _Channel(channel_id, schema_id, topic, encoding)
        self.channels[channel_id] = channel
        schema = self.schemas.get(schema_id)
        if schema is None or schema.name not in POSE_SCHEMAS:
            return
        self.pose_topics.add(topic)
        if self.topic is not None:
            if topic == self.topic:
                self.keep.add(channel_id)
        elif len(self.pose_topics) == 1:
            self.keep.add(channel_id)
        else:
            # Two pose topics and none chosen: the answer will be "pass ?topic=", so keep
            # scanning channels only.
            self.keep.clear()
            self.messages.clear()

    def _chunk(self, buf: bytes | bytearray | memoryview, body: int, stop: int) -> None:
        try:
            _start, _end, _declared, crc = _CHUNK_HEAD.unpack_from(buf, body)
            compression, pos = _string(buf, body + _CHUNK_HEAD.size)
            size = _U64.unpack_from(buf, pos)[0]
        except (struct.error, UnicodeDecodeError) as exc:
            raise BadUpload(f"malformed MCAP chunk record: {exc}", field="file") from exc
        start = pos + 8
        if start + size > stop:
            raise BadUpload("MCAP chunk records overrun the chunk", field="file")
        compressed = memoryview(buf)[start:start + size]
        # The declared uncompressed size is not trusted: bytes are counted as produced.
        pending = bytearray()  # the record cut by the last piece's end, and nothing else
        running_crc = 0
        for piece in _decompressed_pieces(compression, compressed):
            self.budget.produced(len(piece))
            self.budget.tick()
            if crc:
                running_crc = zlib.crc32(piece, running_crc)
            if self.skip:
                dropped = min(self.skip, len(piece))
                self.skip -= dropped
                piece = piece[dropped:]
                if not piece:
                    continue
            if pending:
                pending += piece
                left = self.records_in(pending, 0, len(pending), in_chunk=True)
                del pending[:left]
            else:
                left = self.records_in(piece, 0, len(piece), in_chunk=True)
                pending += piece[left:]
        if pending or self.skip:
            raise BadUpload("MCAP chunk ends inside a record", field="file")
        if crc and running_crc != crc:
            raise BadUpload("MCAP chunk CRC mismatch (corrupt or tampered file)", field="file")


_RUN_WINDOW = 8192  # records compared per numpy step: bounded work when a run is short


def _skip_run(buf: bytes | bytearray | memoryview, pos: int, end: int, head: bytes,
              size: int) -> int:
    """Where the run of whole records of ``size`` bytes starting with ``head`` ends.

    Each of them is a message record on the same skipped channel, exactly what the record
    loop would drop one by one.
    """
    while True:
        count = min((end - pos) // size, _RUN_WINDOW)
        if count == 0:
            return pos
        block = np.frombuffer(buf, dtype=np.uint8, count=count * size, offset=pos)
        same = (block.reshape(count, size)[:, :len(head)]
                == np.frombuffer(head, dtype=np.uint8)).all(axis=1)
        run = count if same.all() else int(np.argmin(same))
        pos += run * size
        if run < count:
            return pos


def _string(buf: bytes | bytearray | memoryview, pos: int) -> tuple[str, int]:
    size = _U32.unpack_from(buf, pos)[0]
    end = pos + 4 + size
    if end > len(buf):
        raise struct.error("string runs past the record")
    return bytes(buf[pos + 4:end]).decode("utf-8"), end


def _decompressed_pieces(compression: str, data: memoryview) -> Iterator[bytes]:
    """The chunk's bytes, decompressed at most ``_PIECE`` bytes at a time."""
    if compression == "":
        for i in range(0, len(data), _PIECE):
            yield bytes(data[i:i + _PIECE])
        return
    try:
        if compression == "zstd":
            import zstandard

            reader: Any = zstandard.ZstdDecompressor().stream_reader(
                io.BytesIO(data), read_across_frames=True)
        elif compression == "lz4":
            import lz4.frame  # type: ignore[import-untyped]

            reader = lz4.frame.LZ4FrameFile(io.BytesIO(data), mode="rb")
        else:
            raise BadUpload(f"unsupported MCAP chunk compression {compression!r} "
                            "(expected zstd, lz4 or none)", field="file")
        with reader:
            while True:
                piece = reader.read(_PIECE)
                if not piece:
                    return
                yield piece
    except BadUpload:
        raise
    except Exception as exc:  # a corrupt stream: any decompressor failure is a bad upload
        raise BadUpload(f"cannot decompress an MCAP chunk ({compression}): "
                        f"{type(exc).__name__}: {exc}", field="file") from exc


def parse_mcap(data: bytes, dim: int, topic: str | None,
               budget: Budget | None = None) -> ParsedUpload:
    """Poses from one topic of an MCAP file (see module docstring)."""
    budget = budget or Budget(UploadLimits())
    if not data.startswith(MCAP_MAGIC):
        raise BadUpload("not an MCAP file (missing the MCAP magic)", field="file")
    scan = _McapScan(topic, budget)
    view = memoryview(data)
    left = scan.records_in(view, len(MCAP_MAGIC), len(data), in_chunk=False)
    if not scan.data_end and left < len(data) and len(data) - left > 8:
        raise BadUpload("MCAP file ends inside a record (truncated?)", field="file")
    return _poses_of(scan, dim, topic)


def _poses_of(scan: _McapScan, dim: int, topic: str | None) -> ParsedUpload:
    pose_channels = [c for c in scan.channels.values()
                     if c.schema_id in scan.schemas
                     and scan.schemas[c.schema_id].name in POSE_SCHEMAS]
    if topic is None:
        topics = sorted(scan.pose_topics)
        if len(topics) != 1:
            raise InvalidInput(
                "pass ?topic= to choose the pose topic; pose topics in this file: "
                f"{', '.join(topics) or 'none'} (supported types: {', '.join(POSE_SCHEMAS)})",
                field="topic",
            )
        topic = topics[0]
    chosen = [c for c in pose_channels if c.topic == topic]
    if not chosen:
        available = sorted(
            f"{c.topic} ({scan.schemas[c.schema_id].name if c.schema_id in scan.schemas else '?'})"
            for c in scan.channels.values())
        raise InvalidInput(
            f"no pose topic {topic!r} in this MCAP file (supported types: "
            f"{', '.join(POSE_SCHEMAS)}); channels: {', '.join(available) or 'none'}",
            field="topic",
        )
    channel = chosen[0]
    schema = scan.schemas[channel.schema_id]
    messages = sorted(scan.messages.get(channel.id, []), key=lambda m: m[0])
    if not messages:
        raise InvalidInput(f"topic {topic!r} has no messages", field="topic")
    try:
        if schema.name == ROS2_POSE_STAMPED:
            columns = codecs.pose_stamped_columns([m[1] for m in messages])
            if columns is not None:
                scan.budget.tick()
                fast_positions, fast_quats, stamps = columns
                if np.any(stamps == 0):  # unset stamps: the log time (unsigned 64-bit)
                    ns = [int(s) or int(m[0]) for s, m in zip(stamps.tolist(), messages, strict=True)]
                    fast_times = np.array([v - ns[0] for v in ns], dtype=np.float64) * 1e-9
                else:
                    fast_times = (stamps - stamps[0]).astype(np.float64) * 1e-9
                return ParsedUpload(np.ascontiguousarray(fast_positions[:, :dim]), fast_times,
                                    fast_quats)
            samples = list(_ros2_poses(schema, channel, messages, scan.budget))
        elif schema.name == FOXGLOVE_POSE:
            samples = []
            for i, (log_time, payload) in enumerate(messages):
                samples.append(_foxglove_pose(orjson.loads(payload), log_time, f"messages[{i}]"))
                if not i & 0xFFF:
                    scan.budget.tick()
        else:
            if len(messages) != 1:
                raise InvalidInput(
                    f"a {FOXGLOVE_POSES} topic must hold one message (the whole trajectory), "
                    f"got {len(messages)}",
                    field="topic",
                )
            payload = messages[0][1]
            # Count before decoding: the JSON objects cost ~10x the bytes.
            scan.budget.points(payload.count(b'"position"'), f"the {FOXGLOVE_POSES} message")
            poses = orjson.loads(payload)["poses"]
            samples = [(None, pos, quat)
                       for pos, quat in (_pose_fields(p, f"poses[{i}]")
                                         for i, p in enumerate(poses))]
    except (InvalidInput, TooLarge):
        raise
    except Exception as exc:  # malformed message payloads
        raise BadUpload(f"cannot decode {schema.name} messages on {topic!r}: "
                        f"{type(exc).__name__}: {exc}", field="file") from exc
    scan.budget.tick()
    positions = np.array([s[1] for s in samples], dtype=np.float64).reshape(-1, 3)
    quats = np.array([s[2] for s in samples], dtype=np.float64).reshape(-1, 4)
    stamps = [s[0] for s in samples]
    times: FloatArray | None = None
    if stamps and all(s is not None for s in stamps):
        # differences of Python integers: MCAP log times are unsigned 64-bit
        first = stamps[0]
        assert first is not None
        times = np.array([s - first for s in stamps], dtype=np.float64) * 1e-9
    return ParsedUpload(np.ascontiguousarray(positions[:, :dim]), times, quats)


_Sample = tuple[int | None, list[float], list[float]]


def _ros2_poses(schema: _Schema, channel: _Channel, messages: Iterable[tuple[int, bytes]],
                budget: Budget) -> Iterable[_Sample]:
    """PoseStamped messages one by one (big-endian, or frame ids that differ), read by the
    live bridge's CDR codec."""
    # The channel's encoding alone decides (an empty payload leaves nothing to sniff).
    if codecs.pose_format(channel.message_encoding, b"") != codecs.FORMAT_CDR:
        raise BadUpload(f"cannot decode message encoding {channel.message_encoding!r} with "
                        f"schema encoding {schema.encoding!r}", field="file")
    for i, (log_time, payload) in enumerate(messages):
        _, pose, ros = codecs.decode_pose_by_encoding(channel.message_encoding, payload)
        assert ros is not None
        stamp = int(ros.sec) * 1_000_000_000 + int(ros.nanosec)
        if not i & 0xFFF:
            budget.tick()
        yield (stamp or int(log_time), list(pose.position), list(pose.orientation or ()))


#: Largest whole seconds of a stamp: its nanoseconds still fit a signed 64-bit integer.
MAX_STAMP_SEC = (2**63 - 1) // 1_000_000_000 - 1


def _coordinates(values: dict[str, Any], keys: str, defaults: tuple[float, ...],
                 where: str) -> list[float]:
    """The numbers at ``keys`` of ``values`` (the ``defaults`` where absent), else an
    :class:`InvalidInput` naming ``where.key`` (a string or a boolean is not a coordinate)."""
    out = []
    for key, default in zip(keys, defaults, strict=True):
        value = values.get(key, default)
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise InvalidInput(f"expected {where}.{key} as a number, got {value!r}",
                               field=f"{where}.{key}")
        out.append(float(value))
    return out


def _foxglove_pose(payload: dict[str, Any], log_time: int, where: str) -> _Sample:
    """One foxglove pose (a PoseInFrame message, or one pose of a PosesInFrame as
    ``{"pose": ...}``) at ``where`` (what an error names): its stamp in nanoseconds (the
    ``log_time`` when it has none), position and orientation."""
    stamp = payload.get("timestamp") or {}
    if not isinstance(stamp, dict):
        raise InvalidInput(f"expected {where}.timestamp as an object, got {stamp!r}",
                           field=f"{where}.timestamp")
    # canal_core's integer check: a fraction is not truncated, a string or a boolean is not
    # a count (raised as the upload's InvalidInput, not as a message it cannot decode)
    try:
        ns = (check_int(stamp.get("sec", 0), 0, f"{where}.timestamp.sec", MAX_STAMP_SEC)
              * 1_000_000_000
              + check_int(stamp.get("nsec", 0), 0, f"{where}.timestamp.nsec", 999_999_999))
    except InvalidInputError as exc:
        raise InvalidInput(exc.message, field=exc.field) from exc
    return (ns or int(log_time), *_pose_fields(payload["pose"], f"{where}.pose"))


def _pose_fields(pose: dict[str, Any], where: str) -> tuple[list[float], list[float]]:
    """A foxglove Pose's position and orientation (at ``where``, what an error names)."""
    p = pose.get("position") or {}
    q = pose.get("orientation") or {}
    return (_coordinates(p, "xyz", (0.0, 0.0, 0.0), f"{where}.position"),
            _coordinates(q, "xyzw", (0.0, 0.0, 0.0, 1.0), f"{where}.orientation"))
