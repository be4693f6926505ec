"""Turn uploaded files into demonstration arrays. One file holds one demonstration.

Formats (chosen by ``?format=``, else by the part's file name, else by content type):

``csv``
    UTF-8 text. With a header, columns are found by name: ``t`` (or ``time``/``timestamp``)
    optional, then ``x, y`` (2-D skills) or ``x, y, z`` (3-D), and optionally
    ``qx, qy, qz, qw``. Without a header, D columns are positions and D + 1 columns are
    ``t`` followed by positions.
``npy``
    A NumPy ``.npy`` array of real numbers, shape (T, D) or (T, D + 1) with time in column 0.
    Read with ``allow_pickle=False``; the header is checked against the data length before
    any allocation.
``mcap``
    An MCAP file with one pose topic (``?topic=``, optional when only one pose topic exists):
    ROS 2 ``geometry_msgs/msg/PoseStamped`` (CDR) or Foxglove ``foxglove.PoseInFrame`` (JSON)
    give one sample per message, timestamped by the message stamp (log time when the stamp is
    zero); ``foxglove.PosesInFrame`` (JSON) must be a single message whose poses are the
    trajectory (no timestamps). Timestamps are seconds relative to the first sample. 2-D skills
    take x and y.

Every parser treats its input as hostile and raises :class:`BadUpload` (400) for bytes that
are not the claimed format; content checks (NaN, dimension, ...) happen afterwards in
:mod:`canal_service.validation` and give 422.
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from .errors import BadUpload, InvalidInput
from .validation import FloatArray

UploadFormat = Literal["csv", "npy", "mcap"]
FORMATS: tuple[str, ...] = ("csv", "npy", "mcap")

_CONTENT_TYPES: dict[str, UploadFormat] = {
    "text/csv": "csv",
    "application/csv": "csv",
    "application/x-npy": "npy",
    "application/npy": "npy",
    "application/x-mcap": "mcap",
    "application/mcap": "mcap",
}
NPY_MAGIC = b"\x93NUMPY"
MCAP_MAGIC = b"\x89MCAP0\r\n"
# A demonstration is at most a few hundred thousand samples; an MCAP chunk claiming more
# decompressed bytes than this is a bomb, not a recording.
MAX_DECOMPRESSED_BYTES = 256 * 1024 * 1024

ROS2_POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
FOXGLOVE_POSE = "foxglove.PoseInFrame"
FOXGLOVE_POSES = "foxglove.PosesInFrame"
POSE_SCHEMAS = (ROS2_POSE_STAMPED, FOXGLOVE_POSE, FOXGLOVE_POSES)


@dataclass(frozen=True)
class ParsedUpload:
    """Raw arrays from a file, not yet checked (see ``validation.check_demonstration``)."""

    positions: FloatArray
    timestamps: FloatArray | None = None
    orientations: FloatArray | None = None


def detect_format(
    explicit: str | None, filename: str | None, content_type: str | None, data: bytes
) -> UploadFormat:
    """Pick the parser: explicit ``format``, then file extension, then content type, then magic."""
    if explicit:
        if explicit not in FORMATS:
            raise InvalidInput(f"expected format to be one of {', '.join(FORMATS)}, got {explicit!r}",
                               field="format")
        return explicit  # type: ignore[return-value]
    if filename and "." in filename:
        ext = filename.rsplit(".", 1)[-1].lower()
        if ext in FORMATS:
            return ext  # type: ignore[return-value]
    if content_type:
        base = content_type.split(";", 1)[0].strip().lower()
        if base in _CONTENT_TYPES:
            return _CONTENT_TYPES[base]
    if data.startswith(NPY_MAGIC):
        return "npy"
    if data.startswith(MCAP_MAGIC):
        return "mcap"
    raise InvalidInput(
        "cannot tell the file format; pass ?format=csv|npy|mcap or a file name ending in one",
        field="format",
    )


def parse_upload(fmt: UploadFormat, data: bytes, dim: int, topic: str | None = None) -> ParsedUpload:
    """Parse ``data`` in format ``fmt`` for a ``dim``-D skill."""
    if not data:
        raise BadUpload("the uploaded file is empty", field="file")
    if fmt == "csv":
        return parse_csv(data, dim)
    if fmt == "npy":
        return parse_npy(data, dim)
    return parse_mcap(data, dim, topic)


def _split_time(table: FloatArray, dim: int, field: str) -> ParsedUpload:
    if table.ndim != 2 or table.shape[1] not in (dim, dim + 1):
        raise InvalidInput(
            f"expected {dim} columns (positions) or {dim + 1} (t then positions) for a {dim}-D "
            f"skill, got shape {tuple(table.shape)}",
            field=field,
        )
    if table.shape[1] == dim + 1:
        return ParsedUpload(np.ascontiguousarray(table[:, 1:]), np.ascontiguousarray(table[:, 0]))
    return ParsedUpload(np.ascontiguousarray(table))


_TIME_NAMES = ("t", "time", "timestamp", "stamp")


def parse_csv(data: bytes, dim: int) -> ParsedUpload:
    """CSV with or without a header (see module docstring)."""
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise BadUpload(f"CSV must be UTF-8 text ({exc.reason} at byte {exc.start})",
                        field="file") from exc
    if "\x00" in text:
        raise BadUpload("CSV must be text; found NUL bytes", field="file")
    try:
        rows = [row for row in csv.reader(io.StringIO(text)) if row and any(c.strip() for c in row)]
    except csv.Error as exc:
        raise BadUpload(f"unreadable CSV: {exc}", field="file") from exc
    if not rows:
        raise BadUpload("the CSV file has no rows", field="file")
    header: list[str] | None = None
    first = [c.strip() for c in rows[0]]
    if not all(_is_number(c) for c in first):
        header = [c.lower() for c in first]
        rows = rows[1:]
    width = len(header) if header else len(rows[0]) if rows else 0
    values: list[list[float]] = []
    for i, row in enumerate(rows):
        line = i + (2 if header else 1)
        if len(row) != width:
            raise InvalidInput(f"expected {width} columns on every CSV line, got {len(row)} on "
                               f"line {line}", field=f"file:line {line}")
        try:
            values.append([float(c) for c in row])
        except ValueError as exc:
            raise InvalidInput(f"expected numbers on CSV line {line}: {exc}",
                               field=f"file:line {line}") from exc
    table = np.asarray(values, dtype=np.float64).reshape(len(values), width)
    if header is None:
        return _split_time(table, dim, "file")
    return _columns_by_name(header, table, dim)


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def _columns_by_name(header: list[str], table: FloatArray, dim: int) -> ParsedUpload:
    axes = ["x", "y", "z"][:dim]
    missing = [a for a in axes if a not in header]
    if missing:
        raise InvalidInput(
            f"expected CSV header columns {', '.join(axes)} for a {dim}-D skill (optional t), "
            f"got {', '.join(header)}",
            field="file:header",
        )
    if dim == 2 and "z" in header:
        raise InvalidInput("CSV has a z column but the skill is 2-D", field="file:header")
    positions = table[:, [header.index(a) for a in axes]]
    time_col = next((header.index(n) for n in _TIME_NAMES if n in header), None)
    times = None if time_col is None else table[:, time_col]
    quats = None
    quat_names = ["qx", "qy", "qz", "qw"]
    if any(q in header for q in quat_names):
        if not all(q in header for q in quat_names):
            raise InvalidInput("expected all of qx, qy, qz, qw in the CSV header, or none",
                               field="file:header")
        quats = table[:, [header.index(q) for q in quat_names]]
    return ParsedUpload(np.ascontiguousarray(positions),
                        None if times is None else np.ascontiguousarray(times),
                        None if quats is None else np.ascontiguousarray(quats))


def parse_npy(data: bytes, dim: int) -> ParsedUpload:
    """A ``.npy`` array of real numbers; never unpickles, never allocates more than the data."""
    from numpy.lib import format as npformat

    if not data.startswith(NPY_MAGIC):
        raise BadUpload("not a .npy file (missing the \\x93NUMPY magic)", field="file")
    stream = io.BytesIO(data)
    try:
        version = npformat.read_magic(stream)
        if version == (1, 0):
            shape, _fortran, dtype = npformat.read_array_header_1_0(stream)
        elif version == (2, 0):
            shape, _fortran, dtype = npformat.read_array_header_2_0(stream)
        else:
            raise BadUpload(f"unsupported .npy format version {version}", field="file")
    except BadUpload:
        raise
    except Exception as exc:  # hostile header: any parser failure is a bad upload
        raise BadUpload(f"unreadable .npy header: {exc}", field="file") from exc
    if dtype.hasobject or dtype.kind not in "fiu" or dtype.fields is not None:
        raise BadUpload(f"expected a .npy array of real numbers, got dtype {dtype}", field="file")
    count = int(np.prod(shape, dtype=np.int64)) if shape else 1
    if count * dtype.itemsize != len(data) - stream.tell():
        raise BadUpload(
            f".npy header promises {count * dtype.itemsize} data bytes, file has "
            f"{len(data) - stream.tell()}",
            field="file",
        )
    try:
        array = np.load(io.BytesIO(data), allow_pickle=False)
    except Exception as exc:  # same reason as above
        raise BadUpload(f"unreadable .npy data: {exc}", field="file") from exc
    return _split_time(np.asarray(array, dtype=np.float64), dim, "file")


def parse_mcap(data: bytes, dim: int, topic: str | None) -> ParsedUpload:
    """Poses from one topic of an MCAP file (see module docstring)."""
    from mcap.records import Channel, Chunk, Schema
    from mcap.stream_reader import StreamReader

    if not data.startswith(MCAP_MAGIC):
        raise BadUpload("not an MCAP file (missing the MCAP magic)", field="file")
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    try:
        # First pass with chunks left compressed: learn the channels and refuse bombs
        # before anything is decompressed.
        total = 0
        for record in StreamReader(io.BytesIO(data), emit_chunks=True, validate_crcs=True,
                                   record_size_limit=len(data)).records:
            if isinstance(record, Chunk):
                total += record.uncompressed_size
                if total > MAX_DECOMPRESSED_BYTES:
                    raise BadUpload(f"MCAP decompresses to more than {MAX_DECOMPRESSED_BYTES} "
                                    "bytes", field="file")
        records = list(StreamReader(io.BytesIO(data), validate_crcs=True,
                                    record_size_limit=len(data)).records)
    except BadUpload:
        raise
    except Exception as exc:  # hostile bytes: every mcap/zstd/struct failure means a bad file
        raise BadUpload(f"unreadable MCAP file: {type(exc).__name__}: {exc}", field="file") from exc
    for record in records:
        if isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel):
            channels[record.id] = record
    pose_channels = {
        c.id: c for c in channels.values()
        if c.schema_id in schemas and schemas[c.schema_id].name in POSE_SCHEMAS
    }
    if topic is None:
        topics = sorted({c.topic for c in pose_channels.values()})
        if len(topics) != 1:
            raise InvalidInput(
                "pass ?topic= to choose the pose topic; pose topics in this file: "
                f"{', '.join(topics) or 'none'} (supported types: {', '.join(POSE_SCHEMAS)})",
                field="topic",
            )
        topic = topics[0]
    chosen = [c for c in pose_channels.values() if c.topic == topic]
    if not chosen:
        available = sorted(f"{c.topic} ({schemas[c.schema_id].name if c.schema_id in schemas else '?'})"
                           for c in channels.values())
        raise InvalidInput(
            f"no pose topic {topic!r} in this MCAP file (supported types: "
            f"{', '.join(POSE_SCHEMAS)}); channels: {', '.join(available) or 'none'}",
            field="topic",
        )
    channel = chosen[0]
    schema = schemas[channel.schema_id]
    from mcap.records import Message

    messages = sorted(
        (r for r in records if isinstance(r, Message) and r.channel_id == channel.id),
        key=lambda m: m.log_time,
    )
    if not messages:
        raise InvalidInput(f"topic {topic!r} has no messages", field="topic")
    try:
        if schema.name == ROS2_POSE_STAMPED:
            samples = list(_ros2_poses(schema, channel, messages))
        elif schema.name == FOXGLOVE_POSE:
            samples = [_foxglove_pose(json.loads(m.data), m.log_time) for m in messages]
        else:
            if len(messages) != 1:
                raise InvalidInput(
                    f"a {FOXGLOVE_POSES} topic must hold one message (the whole trajectory), "
                    f"got {len(messages)}",
                    field="topic",
                )
            payload = json.loads(messages[0].data)
            samples = [_foxglove_pose({"pose": p}, 0) for p in payload["poses"]]
            samples = [(None, pos, quat) for _, pos, quat in samples]
    except InvalidInput:
        raise
    except Exception as exc:  # malformed message payloads
        raise BadUpload(f"cannot decode {schema.name} messages on {topic!r}: "
                        f"{type(exc).__name__}: {exc}", field="file") from exc
    positions = np.array([s[1] for s in samples], dtype=np.float64).reshape(-1, 3)
    quats = np.array([s[2] for s in samples], dtype=np.float64).reshape(-1, 4)
    stamps = [s[0] for s in samples]
    times = None
    if stamps and all(s is not None for s in stamps):
        t = np.array(stamps, dtype=np.int64)
        times = (t - t[0]).astype(np.float64) * 1e-9
    return ParsedUpload(np.ascontiguousarray(positions[:, :dim]), times, quats)


_Sample = tuple[int | None, list[float], list[float]]


def _ros2_poses(schema: Any, channel: Any, messages: Iterable[Any]) -> Iterable[_Sample]:
    from mcap_ros2.decoder import DecoderFactory

    decoder = DecoderFactory().decoder_for(channel.message_encoding, schema)
    if decoder is None:
        raise BadUpload(f"cannot decode message encoding {channel.message_encoding!r} with "
                        f"schema encoding {schema.encoding!r}", field="file")
    for message in messages:
        msg = decoder(message.data)
        stamp = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
        p, q = msg.pose.position, msg.pose.orientation
        yield (stamp or int(message.log_time), [p.x, p.y, p.z], [q.x, q.y, q.z, q.w])


def _foxglove_pose(payload: dict[str, Any], log_time: int) -> _Sample:
    stamp = payload.get("timestamp") or {}
    ns = int(stamp.get("sec", 0)) * 1_000_000_000 + int(stamp.get("nsec", 0))
    pose = payload["pose"]
    p = pose.get("position") or {}
    q = pose.get("orientation") or {}
    return (
        ns or int(log_time),
        [float(p.get("x", 0.0)), float(p.get("y", 0.0)), float(p.get("z", 0.0))],
        [float(q.get("x", 0.0)), float(q.get("y", 0.0)), float(q.get("z", 0.0)),
         float(q.get("w", 1.0))],
    )
