"""Turn uploaded files into demonstration arrays. One file holds one demonstration.

Formats (chosen by ``?format=``, else by the part's file name, else by content type):

``csv``
    UTF-8 text. With a header, columns are found by name: ``t`` (or ``time``/``timestamp``/
    ``stamp``/``__time``, seconds) optional, then ``x, y`` (2-D skills) or ``x, y, z`` (3-D),
    and optionally ``qx, qy, qz, qw``. ROS exports are read as they are: a column whose name
    ends in ``position.x`` (``.`` or ``/`` separated, as ``rostopic echo -p`` and PlotJuggler
    write them) is x, ``orientation.x`` .. ``.w`` the quaternion, and without a seconds column
    ``field.header.stamp`` (else ``%time``) is the time, in nanoseconds. Other columns
    (frame ids, sequence numbers) are not read. UR's RTDE recorder files read as they are
    too: ``actual_TCP_pose_0..2`` are x, y, z and ``_3..5`` the rotation vector (turned into
    a quaternion), ``timestamp`` the time. Comma-separated, or tab, ``;`` or space separated
    when the first line has no comma. Without a header, D columns are positions and D + 1
    columns are ``t`` followed by positions.
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

Resource limits (:class:`UploadLimits`, from the ``CANAL_UPLOAD_*`` settings) hold while
parsing, not after: at most ``max_points`` samples per demonstration, MCAP chunks decompressed
in bounded pieces with the bytes *produced* counted against ``max_decompressed_bytes`` (the
size a chunk declares is not trusted), and ``max_seconds`` of server time per upload. MCAP
records are scanned in a stream and only the pose topic's messages are kept; CSV is parsed by
numpy's C reader, stopping one row past the cap. Each limit is a 413 naming it.
"""

from __future__ import annotations

import io
import struct
import time
import zlib
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import orjson

from canal_protocol import codecs

from .errors import BadUpload, InvalidInput, TooLarge
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

# A demonstration is a few minutes of a robot at up to 1 kHz: 200,000 samples is 6.7 min at
# 500 Hz. The other two defaults follow: a ROS 2 PoseStamped record is ~100 bytes, so 200,000
# samples need ~20 MB decompressed; 64 MiB leaves room for other topics in the same file.
DEFAULT_MAX_POINTS = 200_000
DEFAULT_MAX_DECOMPRESSED_BYTES = 64 * 1024 * 1024
DEFAULT_MAX_SECONDS = 10.0
# Decompressed output is produced and scanned in pieces of this size, never more at once.
_PIECE = 1 << 20
# Bytes of pose payload kept per allowed sample (a JSON PoseInFrame is ~250 bytes).
_POSE_BYTES_PER_POINT = 1024

ROS2_POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
FOXGLOVE_POSE = "foxglove.PoseInFrame"
FOXGLOVE_POSES = "foxglove.PosesInFrame"
POSE_SCHEMAS = (ROS2_POSE_STAMPED, FOXGLOVE_POSE, FOXGLOVE_POSES)


@dataclass(frozen=True)
class UploadLimits:
    """What one upload may cost the server (see the module docstring)."""

    max_points: int = DEFAULT_MAX_POINTS
    max_decompressed_bytes: int = DEFAULT_MAX_DECOMPRESSED_BYTES
    max_seconds: float = DEFAULT_MAX_SECONDS


class _Budget:
    """The running account of one upload against its limits."""

    def __init__(self, limits: UploadLimits) -> None:
        self.limits = limits
        self.deadline = time.monotonic() + limits.max_seconds
        self.decompressed = 0

    def tick(self) -> None:
        """Raise once the upload has used its server time."""
        if time.monotonic() > self.deadline:
            raise TooLarge(
                f"parsing this upload took more than {self.limits.max_seconds:g} s of server "
                "time (limit CANAL_UPLOAD_MAX_SECONDS); send fewer samples or a smaller file",
                field="file",
            )

    def produced(self, n_bytes: int) -> None:
        """Count decompressed bytes as they come out of the decompressor."""
        self.decompressed += n_bytes
        if self.decompressed > self.limits.max_decompressed_bytes:
            raise TooLarge(
                f"MCAP decompresses to more than {self.limits.max_decompressed_bytes} bytes "
                "(limit CANAL_UPLOAD_MAX_DECOMPRESSED_BYTES)",
                field="file",
            )

    def points(self, n_points: int, what: str) -> None:
        """Refuse more samples than one demonstration may have."""
        if n_points > self.limits.max_points:
            raise TooLarge(
                f"{what} has more than {self.limits.max_points} samples (limit "
                "CANAL_UPLOAD_MAX_POINTS); downsample it or split it",
                field="file",
            )


@dataclass(frozen=True)
class ParsedUpload:
    """Raw arrays from a file, not yet checked (see ``validation.check_demonstration``)."""

    positions: FloatArray
    timestamps: FloatArray | None = None
    orientations: FloatArray | None = None
    #: the timestamps' unit when the file says it (a ROS CSV's nanosecond stamp columns)
    time_unit: str | None = None


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


def parse_upload(fmt: UploadFormat, data: bytes, dim: int, topic: str | None = None,
                 limits: UploadLimits | None = None) -> ParsedUpload:
    """Parse ``data`` in format ``fmt`` for a ``dim``-D skill, within ``limits``."""
    if not data:
        raise BadUpload("the uploaded file is empty", field="file")
    budget = _Budget(limits or UploadLimits())
    if fmt == "csv":
        return parse_csv(data, dim, budget)
    if fmt == "npy":
        return parse_npy(data, dim, budget)
    return parse_mcap(data, dim, topic, budget)


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


#: Time columns in seconds (``__time``: PlotJuggler's CSV export)
_TIME_NAMES = ("t", "time", "timestamp", "stamp", "__time")


# ---- CSV ---------------------------------------------------------------------------------------


def parse_csv(data: bytes, dim: int, budget: _Budget | None = None) -> ParsedUpload:
    """CSV with or without a header (see module docstring).

    numpy's C reader parses the rows straight from the bytes into one float array (no text
    copy, no Python object per cell) and stops one row past the points limit, so a huge file
    costs at most that much.
    """
    budget = budget or _Budget(UploadLimits())
    if b"\x00" in data:
        raise BadUpload("CSV must be text; found NUL bytes", field="file")
    start = 3 if data.startswith(b"\xef\xbb\xbf") else 0  # a BOM from spreadsheet exports
    lines = _lines(data, start)
    first = next(lines, None)
    if first is None:
        raise BadUpload("the CSV file has no rows", field="file")
    first_number, first_text = first
    delimiter = _delimiter(first_text)
    cells = [c.strip().strip('"').strip() for c in _split(first_text, delimiter)]
    header: list[str] | None = None
    skip = first_number
    if not all(_is_number(c) for c in cells):
        header = [c.lower() for c in cells]
        skip = first_number + 1
        seen: set[str] = set()
        for name in header:
            if name in seen:
                raise InvalidInput(f"CSV header names column {name!r} twice; expected each "
                                   "column once", field="file:header")
            seen.add(name)
        if next(lines, None) is None:
            raise BadUpload("the CSV file has a header but no data rows", field="file")
    width = len(cells)
    columns = None if header is None else _csv_columns(header, dim)
    # Only the columns named are read when the file has others (a ROS export's frame_id
    # text, sequence numbers): they are neither parsed nor required to be numbers.
    usecols = None
    if columns is not None and len(columns.used) < width:
        usecols = columns.used
    stream = io.BytesIO(data)  # shares the bytes, no copy
    stream.seek(start)
    try:
        table = np.loadtxt(stream, delimiter=delimiter, dtype=np.float64, ndmin=2, comments=None,
                           quotechar='"', skiprows=skip, max_rows=budget.limits.max_points + 1,
                           encoding="utf-8", usecols=usecols)
    except UnicodeDecodeError as exc:
        raise BadUpload(f"CSV must be UTF-8 text ({exc.reason})", field="file") from exc
    except ValueError:
        raise _csv_error(data, start, skip, width, usecols, delimiter) from None
    budget.tick()
    budget.points(table.shape[0], "the CSV file")
    if table.shape[0] == 0:
        raise BadUpload("the CSV file has no data rows", field="file")
    if usecols is None and table.shape[1] != width:
        raise InvalidInput(f"expected {width} columns on every CSV line (as on line "
                           f"{first_number + 1}), got {table.shape[1]}", field="file:line 2")
    if usecols is not None and delimiter is not None and b'"' not in data:
        # Reading some columns does not see a row with extra cells: its delimiters do.
        mark = delimiter.encode()
        if data.count(mark) - first_text.count(delimiter) != table.shape[0] * (width - 1):
            raise _csv_error(data, start, skip, width, usecols, delimiter)
    if columns is None:
        return _split_time(table, dim, "file")
    return columns.read(table, usecols)


def _lines(data: bytes, start: int) -> Iterator[tuple[int, str]]:
    """(0-based line number, text) of the non-blank lines, decoded one at a time, lazily."""
    number = 0
    while start < len(data):
        end = data.find(b"\n", start)
        if end < 0:
            end = len(data)
        raw = data[start:end]
        if raw.strip():
            try:
                yield number, raw.decode("utf-8").rstrip("\r")
            except UnicodeDecodeError as exc:
                raise BadUpload(f"CSV must be UTF-8 text ({exc.reason} on line {number + 1})",
                                field="file") from exc
        start = end + 1
        number += 1


def _delimiter(line: str) -> str | None:
    """The file's delimiter, from its first line: a comma, else a tab, else ``;``, else runs
    of spaces (None: numpy's whitespace split; UR's RTDE recorder writes space-separated)."""
    for delimiter in (",", "\t", ";"):
        if delimiter in line:
            return delimiter
    return None if " " in line.strip() else ","


def _split(line: str, delimiter: str | None) -> list[str]:
    return line.split(delimiter) if delimiter is not None else line.split()


def _csv_error(data: bytes, start: int, skip: int, width: int,
               usecols: list[int] | None = None, delimiter: str | None = ",") -> InvalidInput:
    """Find the first bad data line (the error path only) and say what is wrong with it."""
    for number, line in _lines(data, start):
        if number < skip:
            continue
        cells = _split(line, delimiter)
        if len(cells) != width:
            return InvalidInput(f"expected {width} columns on every CSV line, got {len(cells)} "
                                f"on line {number + 1}", field=f"file:line {number + 1}")
        for cell in cells if usecols is None else [cells[i] for i in usecols]:
            if not _is_number(cell.strip().strip('"').strip()):
                return InvalidInput(f"expected numbers on CSV line {number + 1}, got "
                                    f"{cell.strip()[:40]!r}", field=f"file:line {number + 1}")
    return InvalidInput("unreadable CSV rows", field="file")


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


#: Time columns in nanoseconds, in order of preference: a ROS 1 ``rostopic echo -p``
#: export's message stamp and its record time
_TIME_NAMES_NS = ("field.header.stamp", "%time")


@dataclass(frozen=True)
class _CsvColumns:
    """Which header columns hold the positions, time and quaternion (indices into the row)."""

    positions: list[int]
    time: int | None
    time_unit: str | None
    quaternion: list[int] | None
    rotation_vector: list[int] | None = None  # UR's axis-angle (rx, ry, rz), radians

    @property
    def used(self) -> list[int]:
        return sorted({*self.positions, *([] if self.time is None else [self.time]),
                       *(self.quaternion or []), *(self.rotation_vector or [])})

    def read(self, table: FloatArray, usecols: list[int] | None) -> ParsedUpload:
        """The arrays out of ``table`` (read with ``usecols``, or every column)."""
        at = {c: k for k, c in enumerate(usecols)} if usecols is not None else None

        def cols(indices: list[int]) -> FloatArray:
            return np.ascontiguousarray(table[:, [i if at is None else at[i] for i in indices]])

        quats = None if self.quaternion is None else cols(self.quaternion)
        if self.rotation_vector is not None:
            quats = _quaternions_of_rotation_vectors(cols(self.rotation_vector))
        return ParsedUpload(cols(self.positions),
                            None if self.time is None else cols([self.time])[:, 0],
                            quats, self.time_unit)


def _quaternions_of_rotation_vectors(rotvec: FloatArray) -> FloatArray:
    """(T, 4) quaternions x, y, z, w of (T, 3) rotation vectors (axis times angle)."""
    from scipy.spatial.transform import Rotation

    bad = ~np.isfinite(rotvec)
    if bad.any():
        row = int(np.argwhere(bad)[0][0])
        raise InvalidInput(f"expected finite rotation vectors (actual_TCP_pose_3..5), got NaN "
                           f"or Inf at row {row}", field=f"orientations[{row}]")
    return np.ascontiguousarray(Rotation.from_rotvec(rotvec).as_quat())


#: Columns of UR's RTDE recorder (``record.py``: the tool pose in the base frame, metres and
#: an axis-angle rotation vector), lower-cased like every header name
_RTDE_POSE = [f"actual_tcp_pose_{k}" for k in range(6)]


def _named(header: list[str], exact: str, suffix: str) -> list[int]:
    """Columns called ``exact``, or whose name ends in ``suffix`` as its last parts (``.`` or
    ``/`` separated: ROS ``field.pose.position.x``, PlotJuggler ``/ee_pose/pose/position/x``)."""
    return [i for i, name in enumerate(header)
            if name == exact or ("." + name.replace("/", ".")).endswith("." + suffix)]


def _csv_columns(header: list[str], dim: int) -> _CsvColumns:
    """The columns of a CSV header by name (see the module docstring)."""
    axes = ["x", "y", "z"][:dim]
    found = {a: _named(header, a, f"position.{a}") for a in ["x", "y", "z"]}
    rtde = all(name in header for name in _RTDE_POSE) and not any(found.values())
    if rtde:
        found = {a: [header.index(_RTDE_POSE[k])] for k, a in enumerate(["x", "y", "z"])}
    missing = [a for a in axes if not found[a]]
    if missing:
        raise InvalidInput(
            f"expected CSV header columns {', '.join(axes)} (or ROS-style "
            f"...position.x) for a {dim}-D skill (optional t), got {', '.join(header)}",
            field="file:header",
        )
    for a in axes:
        if len(found[a]) > 1:
            raise InvalidInput(f"CSV header has several {a} columns "
                               f"({', '.join(header[i] for i in found[a])}); expected one",
                               field="file:header")
    if dim == 2 and found["z"]:
        raise InvalidInput("CSV has a z column but the skill is 2-D", field="file:header")
    times_named = [n for n in _TIME_NAMES if n in header]
    if len(times_named) > 1:
        raise InvalidInput(f"CSV header has several time columns ({', '.join(times_named)}); "
                           "expected one", field="file:header")
    time_col, unit = None, None
    if times_named:
        time_col = header.index(times_named[0])
    else:
        ns = [n for n in _TIME_NAMES_NS if n in header]
        if ns:
            time_col, unit = header.index(ns[0]), "ns"
    quats = {c: _named(header, f"q{c}", f"orientation.{c}") for c in "xyzw"}
    if rtde and not any(quats.values()):
        return _CsvColumns([found[a][0] for a in axes], time_col, unit, None,
                           [header.index(name) for name in _RTDE_POSE[3:]])
    quaternion = None
    if any(quats.values()):
        if not all(len(q) == 1 for q in quats.values()):
            raise InvalidInput("expected all of qx, qy, qz, qw (or ROS-style ...orientation.x "
                               "to .w) once each in the CSV header, or none",
                               field="file:header")
        quaternion = [quats[c][0] for c in "xyzw"]
    return _CsvColumns([found[a][0] for a in axes], time_col, unit, quaternion)


# ---- NPY ---------------------------------------------------------------------------------------


def parse_npy(data: bytes, dim: int, budget: _Budget | None = None) -> ParsedUpload:
    """A ``.npy`` array of real numbers; never unpickles, never allocates more than the data."""
    from numpy.lib import format as npformat

    budget = budget or _Budget(UploadLimits())
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
    if shape:
        budget.points(int(shape[0]), "the .npy array")
    try:
        array = np.load(io.BytesIO(data), allow_pickle=False)
    except Exception as exc:  # same reason as above
        raise BadUpload(f"unreadable .npy data: {exc}", field="file") from exc
    return _split_time(np.asarray(array, dtype=np.float64), dim, "file")


# ---- MCAP --------------------------------------------------------------------------------------

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

    def __init__(self, topic: str | None, budget: _Budget) -> None:
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
               budget: _Budget | None = None) -> ParsedUpload:
    """Poses from one topic of an MCAP file (see module docstring)."""
    budget = budget or _Budget(UploadLimits())
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
                log_times = np.array([m[0] for m in messages], dtype=np.int64)
                stamps = np.where(stamps == 0, log_times, stamps)  # unset stamps: the log time
                fast_times = (stamps - stamps[0]).astype(np.float64) * 1e-9
                return ParsedUpload(np.ascontiguousarray(fast_positions[:, :dim]), fast_times,
                                    fast_quats)
            samples = list(_ros2_poses(schema, channel, messages, scan.budget))
        elif schema.name == FOXGLOVE_POSE:
            samples = []
            for i, (log_time, payload) in enumerate(messages):
                samples.append(_foxglove_pose(orjson.loads(payload), log_time))
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
                       for _, pos, quat in (_foxglove_pose({"pose": p}, 0) for p in poses)]
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
        t = np.array(stamps, dtype=np.int64)
        times = (t - t[0]).astype(np.float64) * 1e-9
    return ParsedUpload(np.ascontiguousarray(positions[:, :dim]), times, quats)


_Sample = tuple[int | None, list[float], list[float]]


def _ros2_poses(schema: _Schema, channel: _Channel, messages: Iterable[tuple[int, bytes]],
                budget: _Budget) -> Iterable[_Sample]:
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
