"""Demonstrations as text tables: the one CSV reader of the service's uploads, demonstrations
and corrections alike (``canal correct`` sends its file for the service to read), so a file
one takes the other takes too.

A header is read by name (ROS exports, PlotJuggler, UR RTDE files as they are), or the
columns are bare: D columns are positions, D + 1 are ``t`` followed by positions (the
service's upload docs list every name). Comma-separated, or tab, ``;`` or space separated
when the first line has no comma; UTF-8 (with or without a byte-order mark) or UTF-16 with
its mark. numpy's C reader parses the rows straight from the bytes into one float array (no
text copy, no Python object per cell) and stops at ``max_rows``, so a huge file costs at most
that much.

Errors: :class:`UnreadableCsv` for bytes that are not CSV text, :class:`InvalidCsv` for a
table whose content is wrong (a missing column, a word among numbers); both say what was
expected and what came, and which part of the file (``field``).
"""

from __future__ import annotations

import io
import re
import warnings
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from ..options import TIME_UNITS

FloatArray = npt.NDArray[np.float64]

# numpy says, once per read, that a blank line does not count towards max_rows: blank lines
# are allowed here, and max_rows is a memory cap, not a count anything relies on.
warnings.filterwarnings("ignore", message=r"Input line \d+ contained no data", category=UserWarning)

#: Time columns in seconds (``__time``: PlotJuggler's CSV export)
_TIME_NAMES = ("t", "time", "timestamp", "stamp", "__time")
#: The same names with the unit they are in (a key of ``TIME_UNITS``), as loggers write it:
#: ``timestamp_ms``, ``time [ms]``, ``time(ms)``, ``time_usec`` (MAVLink)
_UNIT_SPELLINGS = {**{unit: unit for unit in TIME_UNITS},
                   "sec": "s", "msec": "ms", "usec": "us", "nsec": "ns",
                   "secs": "s", "seconds": "s", "millis": "ms", "milliseconds": "ms",
                   "micros": "us", "microseconds": "us", "nanos": "ns", "nanoseconds": "ns"}
#: Time columns in units no robot clock keeps (a spreadsheet's): refused rather than dropped
_UNREAD_TIME_UNITS = ("min", "mins", "minute", "minutes", "h", "hr", "hrs", "hour", "hours",
                      "d", "day", "days")
_TIME_NAMES_UNREAD = {
    f"{name}{sep}{spelling}{close}"
    for name in _TIME_NAMES for spelling in _UNREAD_TIME_UNITS
    for sep, close in (("_", ""), (" [", "]"), ("[", "]"), (" (", ")"), ("(", ")"))
}
_TIME_NAMES_WITH_UNIT = {
    f"{name}{sep}{spelling}{close}": unit
    for name in _TIME_NAMES for spelling, unit in _UNIT_SPELLINGS.items()
    for sep, close in (("_", ""), (" [", "]"), ("[", "]"), (" (", ")"), ("(", ")"))
}


class CsvError(ValueError):
    """A CSV file that is not a demonstration: a message and the part of the file at fault."""

    def __init__(self, message: str, *, field: str = "file") -> None:
        super().__init__(message)
        self.message = message
        self.field = field


class UnreadableCsv(CsvError):
    """Bytes that cannot be read as CSV text (binary, a bad encoding, no rows)."""


class InvalidCsv(CsvError):
    """CSV text whose table is wrong for the skill (columns, names, a word among numbers)."""


@dataclass(frozen=True)
class CsvTable:
    """The arrays of one demonstration file, not yet checked (the service's NumPy and MCAP
    uploads give the same four)."""

    positions: FloatArray
    timestamps: FloatArray | None = None
    orientations: FloatArray | None = None
    #: the timestamps' unit when the file says it (``timestamp_ms``, a ROS nanosecond stamp)
    time_unit: str | None = None


def table_split_by_time(table: FloatArray, dim: int) -> CsvTable:
    """A (T, D) table as positions, a (T, D + 1) one as times then positions (a headerless
    CSV, a NumPy upload)."""
    if table.ndim != 2 or table.shape[1] not in (dim, dim + 1):
        raise InvalidCsv(
            f"expected {dim} columns (positions) or {dim + 1} (t then positions) for a {dim}-D "
            f"skill, got shape {tuple(table.shape)}")
    if table.shape[1] == dim + 1:
        return CsvTable(np.ascontiguousarray(table[:, 1:]), np.ascontiguousarray(table[:, 0]))
    return CsvTable(np.ascontiguousarray(table))


def _utf8_from_utf16(data: bytes) -> bytes:
    """UTF-16 text with its byte-order mark (spreadsheets' and Windows tools' "Unicode
    text") as UTF-8, which the reader below parses; the mark says the byte order."""
    try:
        return data.decode("utf-16").encode("utf-8")
    except UnicodeDecodeError as exc:
        raise UnreadableCsv(f"expected UTF-16 text after its byte-order mark, got {exc.reason} at byte "
                            f"{exc.start + 2}") from exc


def csv_table(data: bytes, dim: int, max_rows: int | None = None) -> CsvTable:
    """The table of a CSV file with or without a header (see the module docstring).

    Parameters
    ----------
    data : bytes
        The file's bytes.
    dim : int
        The skill's dimension, 2 or 3: which position columns are read.
    max_rows : int, optional
        Read at most this many data rows (a memory cap: the caller refuses a table that
        reaches it); every row when None.
    """
    if data.startswith((b"\xff\xfe", b"\xfe\xff")):
        data = _utf8_from_utf16(data)
    if b"\x00" in data:
        raise UnreadableCsv("CSV must be text; found NUL bytes")
    if b"\n" not in data and b"\r" in data:
        data = data.replace(b"\r", b"\n")  # classic Mac line ends (CR only)
    start = 3 if data.startswith(b"\xef\xbb\xbf") else 0  # a BOM from spreadsheet exports
    lines = _lines(data, start)
    first = next(lines, None)
    comments: list[str] = []
    while first is not None and first[1].lstrip().startswith("#"):
        comments.append(first[1].lstrip()[1:])
        first = next(lines, None)
    if first is None:
        raise UnreadableCsv("the CSV file has no rows" if not comments
                            else "the CSV file has only comment lines (#), no rows")
    first_number, first_text = first
    delimiter = _delimiter(first_text)
    cells = _cells(first_text, delimiter)
    header: list[str] | None = None
    skip = first_number
    # Delimiters on the lines before the data, for the extra-cells check below.
    preamble = sum(text.count(delimiter) for text in comments) if delimiter else 0
    named = _cells(comments[-1], delimiter) if comments else []
    if (len(named) == len(cells) and not any(_is_number(c) for c in named)
            and any(_is_number(c) for c in cells)):
        # numpy.savetxt writes its header as a comment ("# t,x,y,z"): a commented line of
        # names right before the data, with a name per column, names them.
        header = [c.lower() for c in named]
    elif not all(_is_number(c) for c in cells):
        header = [c.lower() for c in cells]
        skip = first_number + 1
        preamble += first_text.count(delimiter) if delimiter else 0
    if header is not None:
        seen: set[str] = set()
        for name in header:
            if name in seen:
                raise InvalidCsv(f"CSV header names column {name!r} twice; expected each "
                                 "column once", field="file:header")
            seen.add(name)
        if skip > first_number and next(lines, None) is None:
            raise UnreadableCsv("the CSV file has a header but no data rows")
    width = len(cells)
    if header is None and width not in (dim, dim + 1):
        # Before any array is made: numpy sizes its table by rows x columns, so a wide
        # line would choose the server's allocation.
        raise InvalidCsv(
            f"expected {dim} columns (positions) or {dim + 1} (t then positions) for a {dim}-D "
            f"skill, got {width} on line {first_number + 1}", field=f"file:line {first_number + 1}")
    columns = None if header is None else _csv_columns(header, dim)
    # Only the columns named are read when the file has others (a ROS export's frame_id
    # text, sequence numbers): they are neither parsed nor required to be numbers.
    usecols = None
    if columns is not None and len(columns.used) < width:
        usecols = columns.used
    stream = io.BytesIO(data)  # shares the bytes, no copy
    stream.seek(start)
    # numpy reserves max_rows rows up front: never more than the body has lines, so the
    # table costs memory in proportion to the bytes received.
    lines_in_body = data.count(b"\n") + 1
    max_rows = lines_in_body if max_rows is None else min(max_rows, lines_in_body)
    try:
        table = np.loadtxt(stream, delimiter=delimiter, dtype=np.float64, ndmin=2, comments=None,
                           quotechar='"', skiprows=skip, max_rows=max_rows,
                           encoding="utf-8", usecols=usecols)
    except UnicodeDecodeError as exc:
        raise UnreadableCsv(f"CSV must be UTF-8 text ({exc.reason})") from exc
    except ValueError:
        raise _csv_error(data, start, skip, width, usecols, delimiter) from None
    if table.shape[0] == 0:
        raise UnreadableCsv("the CSV file has no data rows")
    if usecols is None and table.shape[1] != width:
        raise InvalidCsv(f"expected {width} columns on every CSV line (as on line "
                         f"{first_number + 1}), got {table.shape[1]}", field="file:line 2")
    if usecols is not None and delimiter is not None and b'"' not in data:
        # Reading some columns does not see a row with extra cells: its delimiters do.
        mark = delimiter.encode()
        if data.count(mark) - preamble != table.shape[0] * (width - 1):
            raise _csv_error(data, start, skip, width, usecols, delimiter)
    if columns is None:
        return table_split_by_time(table, dim)
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
                raise UnreadableCsv(f"CSV must be UTF-8 text ({exc.reason} on line {number + 1})",
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


def _cells(line: str, delimiter: str | None) -> list[str]:
    return [c.strip().strip('"').strip() for c in _split(line, delimiter)]


def _csv_error(data: bytes, start: int, skip: int, width: int,
               usecols: list[int] | None = None, delimiter: str | None = ",") -> InvalidCsv:
    """Find the first bad data line (the error path only) and say what is wrong with it."""
    for number, line in _lines(data, start):
        if number < skip:
            continue
        cells = _split(line, delimiter)
        if len(cells) != width:
            return InvalidCsv(f"expected {width} columns on every CSV line, got {len(cells)} "
                              f"on line {number + 1}", field=f"file:line {number + 1}")
        for cell in cells if usecols is None else [cells[i] for i in usecols]:
            if not _is_number(cell.strip().strip('"').strip()):
                return InvalidCsv(f"expected numbers on CSV line {number + 1}, got "
                                  f"{cell.strip()[:40]!r}", field=f"file:line {number + 1}")
    return InvalidCsv("unreadable CSV rows")


#: A number as numpy's CSV reader reads it. Python's float() also takes "1_000" and
#: non-ASCII digits, which numpy refuses: a cell float() takes would go unnamed.
_NUMBER = re.compile(r"[+-]?(?:(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?"
                     r"|inf(?:inity)?|nan)", re.IGNORECASE)


def _is_number(cell: str) -> bool:
    return _NUMBER.fullmatch(cell) is not None


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

    def read(self, table: FloatArray, usecols: list[int] | None) -> CsvTable:
        """The arrays out of ``table`` (read with ``usecols``, or every column)."""
        at = {c: k for k, c in enumerate(usecols)} if usecols is not None else None

        def cols(indices: list[int]) -> FloatArray:
            return np.ascontiguousarray(table[:, [i if at is None else at[i] for i in indices]])

        quats = None if self.quaternion is None else cols(self.quaternion)
        if self.rotation_vector is not None:
            quats = _quaternions_of_rotation_vectors(cols(self.rotation_vector))
        return CsvTable(cols(self.positions),
                            None if self.time is None else cols([self.time])[:, 0],
                            quats, self.time_unit)


def _quaternions_of_rotation_vectors(rotvec: FloatArray) -> FloatArray:
    """(T, 4) quaternions x, y, z, w of (T, 3) rotation vectors (axis times angle)."""
    from scipy.spatial.transform import Rotation

    bad = ~np.isfinite(rotvec)
    if bad.any():
        row = int(np.argwhere(bad)[0][0])
        raise InvalidCsv(f"expected finite rotation vectors (actual_TCP_pose_3..5), got NaN "
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
        raise InvalidCsv(
            f"expected CSV header columns {', '.join(axes)} (or ROS-style "
            f"...position.x) for a {dim}-D skill (optional t), got {', '.join(header)}",
            field="file:header",
        )
    for a in axes:
        if len(found[a]) > 1:
            raise InvalidCsv(f"CSV header has several {a} columns "
                             f"({', '.join(header[i] for i in found[a])}); expected one",
                             field="file:header")
    if dim == 2 and found["z"]:
        raise InvalidCsv("CSV has a z column but the skill is 2-D", field="file:header")
    unread = [n for n in header if n in _TIME_NAMES_UNREAD]
    if unread:
        raise InvalidCsv(f"expected a time column in {', '.join(TIME_UNITS)} (e.g. time, "
                         f"time_ms, time [us]), got {unread[0]!r}: convert it to seconds, or "
                         "rename the column if it is not the samples' time", field="file:header")
    times_named = [n for n in header if n in _TIME_NAMES or n in _TIME_NAMES_WITH_UNIT]
    if len(times_named) > 1:
        raise InvalidCsv(f"CSV header has several time columns ({', '.join(times_named)}); "
                         "expected one", field="file:header")
    time_col, unit = None, None
    if times_named:
        time_col, unit = header.index(times_named[0]), _TIME_NAMES_WITH_UNIT.get(times_named[0])
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
            named = ", ".join(header[i] for c in "xyzw" for i in quats[c])
            wrong = [f"no q{c}" for c in "xyzw" if not quats[c]] + \
                [f"q{c} twice" for c in "xyzw" if len(quats[c]) > 1]
            raise InvalidCsv("expected all of qx, qy, qz, qw (or ROS-style ...orientation.x "
                             f"to .w) once each in the CSV header, or none, got {named} "
                             f"({', '.join(wrong)})", field="file:header")
        quaternion = [quats[c][0] for c in "xyzw"]
    return _CsvColumns([found[a][0] for a in axes], time_col, unit, quaternion)
