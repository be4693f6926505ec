"""The recording batch: what a live bridge sends the service's recorder, and how it is read.

Every ``interval`` (0.1 s by default) a bridge puts one message on
``{prefix}/@recorder/live/{bridge}`` (:func:`canal_protocol.keys.recorder_key`): what each
stream kept for the recording since its last batch, as columns (no per-row parsing on the
recorder's side), and the stream's count deltas. Binary, version 3, little-endian:

====== ============ =========================================================================
offset type         field
====== ============ =========================================================================
0      3 bytes      magic ``CRB`` (a version 1 batch was a JSON object: it starts with ``{``)
3      uint8        version (3)
4      uint32       header length H
8      H bytes      header, JSON: ``{"bridge": str, "n": int, "streams": [[skill, robot,
                    poses, answered, coalesced, errors, decimated, rows, dim], ...]}``
8+H    ...          each stream's columns in header order, ``rows`` = M entries each:
                    ``t_ns`` int64[M], ``position`` float64[M*dim], ``orientation``
                    float64[M*4], ``target`` float64[M*dim], ``target_orientation``
                    float64[M*4], ``progress`` float64[M], ``eta`` float64[M], ``section``
                    int32[M], ``flags`` uint8[M], ``status`` uint8[M] (:data:`STATUS_CODES`),
                    ``route`` int16[M] (the route of a model of several routes the stream
                    followed; -1 for a model of one route)
====== ============ =========================================================================

``flags``: :data:`RECORD_ORIENTATION` (the pose had an orientation), :data:`RECORD_TARGET_
ORIENTATION`, :data:`RECORD_INSIDE`, :data:`RECORD_DONE`; a missing orientation is sent as
the identity with its flag clear. ``n`` counts the bridge's batches from 0 (a gap is a lost
batch). The counts are *deltas* since the stream's previous batch: ``poses`` received
(coalesced included), ``answered`` (ok or outside_canal), ``coalesced``, ``errors``
(answered with an error status) and ``decimated`` (not kept for the recording). Each row is
one kept pose and its target, so ``poses == rows + decimated`` in every batch. A stream may
have several entries in one batch, each of one dimension (its skill was deleted and created
again with another): the recorder sums them. The message is exactly as long as its header
says: anything else is refused whole.
"""

from __future__ import annotations

import struct
import sys
from array import array
from dataclasses import dataclass
from itertools import chain
from typing import Any

import orjson

from canal_protocol.codecs.messages import MAX_DIM, STATUS_CODES, STATUS_KEYS, WireError
from canal_protocol.keys import is_plain_chunk

RECORD_BATCH_MAGIC = b"CRB"
RECORD_BATCH_VERSION = 3
#: Fields of a row handed to :func:`encode_record_batch`; the route (the 12th) may be left out.
RECORD_ROW_FIELDS = 12
RECORD_ORIENTATION = 0x01
RECORD_TARGET_ORIENTATION = 0x02
RECORD_INSIDE = 0x04
RECORD_DONE = 0x08
_RECORD_PREFIX = struct.Struct("<3sBI")
_IDENTITY_Q = (0.0, 0.0, 0.0, 1.0)
_NAN = float("nan")
_SWAP = sys.byteorder != "little"


@dataclass(frozen=True, slots=True)
class RecordRow:
    """One pose the bridge kept for the recording, with the target it answered."""

    t_ns: int
    position: tuple[float, ...]
    orientation: tuple[float, ...] | None
    target: tuple[float, ...]
    target_orientation: tuple[float, ...] | None
    progress: float
    eta: float
    section: int
    inside: bool
    done: bool
    status: str
    #: the route of a model of several routes the stream followed; None: one route
    route: int | None = None


@dataclass(frozen=True, slots=True)
class RecordStream:
    """One stream's part of a batch: its count deltas and its kept rows, as columns.

    Columns are :class:`array.array` (native byte order; ``numpy.frombuffer`` reads them
    without a copy): ``position`` and ``target`` hold ``dim`` values per row, the
    orientations 4 (identity where ``flags`` says there was none).
    """

    skill: str
    robot: str
    poses: int
    answered: int
    coalesced: int
    errors: int
    decimated: int
    dim: int
    t_ns: array[int]
    position: array[float]
    orientation: array[float]
    target: array[float]
    target_orientation: array[float]
    progress: array[float]
    eta: array[float]
    section: array[int]
    flags: bytes
    status: bytes
    route: array[int]

    def __len__(self) -> int:
        return len(self.t_ns)

    @property
    def rows(self) -> tuple[RecordRow, ...]:
        """The columns as rows (tests, debugging: the recorder reads the columns)."""
        d = self.dim
        out = []
        for i, t in enumerate(self.t_ns):
            f = self.flags[i]
            out.append(RecordRow(
                t, tuple(self.position[i * d:(i + 1) * d]),
                tuple(self.orientation[4 * i:4 * i + 4]) if f & RECORD_ORIENTATION else None,
                tuple(self.target[i * d:(i + 1) * d]),
                tuple(self.target_orientation[4 * i:4 * i + 4])
                if f & RECORD_TARGET_ORIENTATION else None,
                self.progress[i], self.eta[i], self.section[i], bool(f & RECORD_INSIDE),
                bool(f & RECORD_DONE), STATUS_KEYS[self.status[i]],
                None if self.route[i] < 0 else self.route[i]))
        return tuple(out)


@dataclass(frozen=True, slots=True)
class RecordBatch:
    """What one bridge hands the recorder in one message."""

    bridge: str
    n: int
    streams: tuple[RecordStream, ...]


def _column(typecode: str, values: Any) -> bytes:
    col = array(typecode, values)
    if _SWAP:
        col.byteswap()
    return col.tobytes()


def _vectors(values: tuple[Any, ...], dim: int, field: str) -> bytes:
    flat = array("d", chain.from_iterable(values))
    if len(flat) != dim * len(values):
        raise WireError("bad_payload", f"expected every {field} of a stream with {dim} values")
    if _SWAP:
        flat.byteswap()
    return flat.tobytes()


def _quaternions(values: tuple[Any, ...]) -> bytes:
    return _column("d", chain.from_iterable(_IDENTITY_Q if q is None else q for q in values))


def _dimension_runs(rows: list[tuple[Any, ...]]) -> list[list[tuple[Any, ...]]]:
    """The rows in runs of one position dimension, in order."""
    runs: list[list[tuple[Any, ...]]] = []
    dim = -1
    for row in rows:
        if len(row[1]) != dim:
            dim = len(row[1])
            runs.append([])
        runs[-1].append(row)
    return runs


def _stream_body(rows: list[tuple[Any, ...]], dim: int) -> list[bytes]:
    m = len(rows)
    cols = tuple(zip(*rows, strict=True))
    if len(cols) == RECORD_ROW_FIELDS - 1:
        cols = (*cols, (-1,) * m)
    if len(cols) != RECORD_ROW_FIELDS:
        raise WireError("bad_payload", f"expected rows of {RECORD_ROW_FIELDS - 1} or "
                        f"{RECORD_ROW_FIELDS} fields")
    t, pos, q, target, tq, progress, eta, section, inside, done, status, route = cols
    return [
        _column("q", t), _vectors(pos, dim, "position"), _quaternions(q),
        _vectors(target, dim, "target"), _quaternions(tq),
        _column("d", [_NAN if v is None else v for v in progress]),
        _column("d", [_NAN if v is None else v for v in eta]), _column("i", section),
        bytes([(RECORD_ORIENTATION if a is not None else 0)
               | (RECORD_TARGET_ORIENTATION if b is not None else 0)
               | (RECORD_INSIDE if c else 0) | (RECORD_DONE if d else 0)
               for a, b, c, d in zip(q, tq, inside, done, strict=True)]),
        bytes([STATUS_CODES[s] for s in status]),
        _column("h", [-1 if r is None else r for r in route])]


def encode_record_batch(bridge: str, n: int, streams: list[tuple[Any, ...]], *,
                        left_out: list[tuple[tuple[Any, ...], Exception]] | None = None) -> bytes:
    """A recording batch (binary, version 3); ``streams`` holds ``(skill, robot, poses,
    answered, coalesced, errors, decimated, rows)`` with rows as tuples ``(t_ns, position,
    orientation|None, target, target_orientation|None, progress, eta, section, inside,
    done, status[, route])`` (route -1 or left out: a model of one route). A row's position
    and target share one dimension.

    Rows of a stream whose dimension changes (its skill was deleted and created again with
    another) are sent as one entry per run of a dimension, the later ones with ``poses ==
    answered == rows`` and no other counts (the recorder sums a stream's entries).

    A stream that cannot be encoded raises WireError, or, with ``left_out`` given, is left
    out of the batch and appended there with its error (the other streams are sent)."""
    heads: list[list[Any]] = []
    body: list[bytes] = []
    for stream in streams:
        skill, robot, poses, answered, coalesced, errors, decimated, rows = stream
        runs = _dimension_runs(rows)
        later = sum(len(run) for run in runs[1:])
        parts = [(poses - later, answered - later, coalesced, errors, decimated,
                  runs[0] if runs else []),
                 *((len(run), len(run), 0, 0, 0, run) for run in runs[1:])]
        try:
            encoded = [([skill, robot, p, a, c, e, dec, len(run), len(run[0][1]) if run else 0],
                        _stream_body(run, len(run[0][1])) if run else [])
                       for p, a, c, e, dec, run in parts]
        except Exception as exc:
            if left_out is None:
                raise
            left_out.append((stream, exc))
            continue
        for head, columns in encoded:
            heads.append(head)
            body += columns
    header = orjson.dumps({"bridge": bridge, "n": n, "streams": heads})
    return b"".join([_RECORD_PREFIX.pack(RECORD_BATCH_MAGIC, RECORD_BATCH_VERSION, len(header)),
                     header, *body])


def _count(value: Any, name: str) -> int:
    if not isinstance(value, int) or isinstance(value, bool) or value < 0:
        raise WireError("bad_payload", f"expected {name} as an integer >= 0, got {value!r}")
    return value


def _take(data: memoryview, at: int, typecode: str, count: int) -> tuple[array[Any], int]:
    col: array[Any] = array(typecode)
    end = at + col.itemsize * count
    if end > len(data):
        raise WireError("bad_payload", "expected the columns the header announces: "
                        f"the batch ends at byte {len(data)}")
    col.frombytes(data[at:end])
    if _SWAP:
        col.byteswap()
    return col, end


_STREAM_COUNTS = ("poses", "answered", "coalesced", "errors", "decimated", "rows", "dim")


def decode_record_batch(data: bytes) -> RecordBatch:
    """A recording batch; WireError (``bad_payload``) when it is not a whole version 3 batch
    (a bridge of another Canal version is named as such)."""
    if data[:1] == b"{":
        raise WireError("bad_payload", "expected a binary recording batch of version "
                        f"{RECORD_BATCH_VERSION}, got a JSON (version 1) batch: the bridge "
                        "runs an older Canal than the service")
    if len(data) < _RECORD_PREFIX.size:
        raise WireError("bad_payload", "expected a recording batch, got "
                        f"{len(data)} bytes")
    magic, version, size = _RECORD_PREFIX.unpack_from(data)
    if magic != RECORD_BATCH_MAGIC:
        raise WireError("bad_payload", f"expected a recording batch (magic {RECORD_BATCH_MAGIC!r}),"
                        f" got {magic!r}")
    if version != RECORD_BATCH_VERSION:
        raise WireError("bad_payload", f"expected a recording batch of version "
                        f"{RECORD_BATCH_VERSION}, got version {version}: the bridge and the "
                        "service run different Canal versions")
    at = _RECORD_PREFIX.size + size
    try:
        body = orjson.loads(data[_RECORD_PREFIX.size:at])
    except orjson.JSONDecodeError as exc:
        raise WireError("bad_payload", f"expected a JSON batch header: {exc}") from None
    if not isinstance(body, dict):
        raise WireError("bad_payload", "expected the batch header as an object")
    bridge, streams = body.get("bridge"), body.get("streams")
    if not isinstance(bridge, str) or not isinstance(streams, list):
        raise WireError("bad_payload", "expected 'bridge' (string) and 'streams' (list)")
    n = _count(body.get("n"), "n")
    view = memoryview(data)
    out = []
    for head in streams:
        if not isinstance(head, list) or len(head) != 2 + len(_STREAM_COUNTS):
            raise WireError("bad_payload", "expected each stream as [skill, robot, poses, "
                            "answered, coalesced, errors, decimated, rows, dim]")
        skill, robot = head[0], head[1]
        if not (isinstance(skill, str) and is_plain_chunk(skill) and isinstance(robot, str)
                and is_plain_chunk(robot)):
            raise WireError("bad_payload", "expected plain skill and robot names")
        poses, answered, coalesced, errors, decimated, m, dim = (
            _count(v, k) for v, k in zip(head[2:], _STREAM_COUNTS, strict=True))
        if m and not 1 <= dim <= MAX_DIM:
            raise WireError("bad_payload", f"expected dim in 1..{MAX_DIM}, got {dim}")
        t, at = _take(view, at, "q", m)
        pos, at = _take(view, at, "d", m * dim)
        q, at = _take(view, at, "d", m * 4)
        target, at = _take(view, at, "d", m * dim)
        tq, at = _take(view, at, "d", m * 4)
        progress, at = _take(view, at, "d", m)
        eta, at = _take(view, at, "d", m)
        section, at = _take(view, at, "i", m)
        flags, at = _take(view, at, "B", m)
        status, at = _take(view, at, "B", m)
        route, at = _take(view, at, "h", m)
        if any(code not in STATUS_KEYS for code in set(status)):
            raise WireError("bad_payload", "expected known status codes in the rows")
        out.append(RecordStream(skill, robot, poses, answered, coalesced, errors, decimated,
                                dim, t, pos, q, target, tq, progress, eta, section,
                                flags.tobytes(), status.tobytes(), route))
    if at != len(data):
        raise WireError("bad_payload", f"expected {at} bytes as the header announces, got "
                        f"{len(data)}")
    return RecordBatch(bridge, n, tuple(out))
