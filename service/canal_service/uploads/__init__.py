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

from ..errors import BadUpload, InvalidInput
from .common import (
    DEFAULT_MAX_DECOMPRESSED_BYTES,
    DEFAULT_MAX_POINTS,
    DEFAULT_MAX_SECONDS,
    FORMATS,
    MCAP_MAGIC,
    NPY_MAGIC,
    Budget,
    ParsedUpload,
    UploadFormat,
    UploadLimits,
)
from .csv import parse_csv
from .mcap import parse_mcap
from .npy import parse_npy

__all__ = [
    "DEFAULT_MAX_DECOMPRESSED_BYTES",
    "DEFAULT_MAX_POINTS",
    "DEFAULT_MAX_SECONDS",
    "FORMATS",
    "ParsedUpload",
    "UploadFormat",
    "UploadLimits",
    "detect_format",
    "parse_csv",
    "parse_mcap",
    "parse_npy",
    "parse_upload",
]

_CONTENT_TYPES: dict[str, UploadFormat] = {
    "text/csv": "csv",
    "application/csv": "csv",
    "application/x-npy": "npy",
    "application/npy": "npy",
    "application/x-mcap": "mcap",
    "application/mcap": "mcap",
}


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


_FORMAT_NAMES = {"csv": "CSV", "npy": "NumPy", "mcap": "MCAP"}


def parse_upload(fmt: UploadFormat, data: bytes, dim: int, topic: str | None = None,
                 limits: UploadLimits | None = None) -> ParsedUpload:
    """Parse ``data`` in format ``fmt`` for a ``dim``-D skill, within ``limits``."""
    if topic is not None and fmt != "mcap":
        # a topic names an MCAP file's pose topic: with another file the client meant another
        raise InvalidInput(f"expected topic only with an MCAP file, got a {_FORMAT_NAMES[fmt]} file",
                           field="topic")
    if not data:
        raise BadUpload("the uploaded file is empty", field="file")
    budget = Budget(limits or UploadLimits())
    if fmt == "csv":
        return parse_csv(data, dim, budget)
    if fmt == "npy":
        return parse_npy(data, dim, budget)
    return parse_mcap(data, dim, topic, budget)
