"""/skills/{name}/recording.rrd and .mcap: snapshots of the skill's recording; rebuild."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Literal

from fastapi import APIRouter, Query
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse, JSONResponse
from starlette.types import Receive, Scope, Send

from canal_protocol.options import RecordingKind
from canal_protocol.schemas import ErrorResponse

from ..deps import ServiceDep, SkillName
from ..errors import error_body
from ..service import CanalService

router = APIRouter(prefix="/skills/{name}", tags=["recordings"])
_RESPONSES: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorResponse} for code in (404, 422)
}
_MEDIA = {"rrd": "application/octet-stream", "mcap": "application/octet-stream"}


#: A byte-range set (RFC 9110, 14.1.2): "bytes=0-9", "bytes=100-", "bytes=-500", several by commas.
_BYTE_RANGES = re.compile(r"\s*bytes\s*=\s*(\d+-\d*|-\d+)(\s*,\s*(\d+-\d*|-\d+))*\s*", re.IGNORECASE)


def _answerable(value: str) -> bool:
    """Whether a Range header is byte ranges that each start at or before their end."""
    if not _BYTE_RANGES.fullmatch(value):
        return False
    for part in value.split("=", 1)[1].split(","):
        first, _, last = part.strip().partition("-")
        if first and last and int(first) > int(last):
            return False
    return True


def _satisfiable(value: str, size: int) -> list[str]:
    """The ranges of an answerable Range header (:func:`_answerable`) that a file of ``size``
    bytes can serve (RFC 9110, 14.1.1): a first byte before the end, or a suffix of at
    least one byte of a file that has one."""
    kept = []
    for part in value.split("=", 1)[1].split(","):
        first, _, last = part.strip().partition("-")
        if (int(first) < size) if first else (int(last) > 0 and size > 0):
            kept.append(part.strip())
    return kept


def _without(headers: list[tuple[bytes, bytes]], *names: bytes) -> list[tuple[bytes, bytes]]:
    return [(k, v) for k, v in headers if k not in names]


class _Download(FileResponse):
    """A snapshot file, with a Range header it cannot answer ignored (RFC 9110, 14.2 lets a
    server do so) instead of Starlette's plain-text 400: a download tool that sent one gets
    the whole file, as from a server without ranges. The snapshot is deleted once answered,
    whatever the answer."""

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        headers = scope.get("headers", [])
        asked = next((v for k, v in headers if k == b"range"), None)
        text = None if asked is None else asked.decode("latin-1")
        if_range = next((v for k, v in headers if k == b"if-range"), None)
        if text is not None and (not _answerable(text) or (
                if_range is not None and not if_range.lstrip().startswith((b'"', b'W/')))):
            # An If-Range date is not a strong validator here (RFC 9110, 13.1.5): a snapshot
            # made within the second it names would be spliced onto another one.
            scope = {**scope, "headers": _without(headers, b"range", b"if-range")}
            text = None
        try:
            size = Path(self.path).stat().st_size
            kept = [] if text is None else _satisfiable(text, size)
            if text is not None and not kept:
                # Starlette's own 416 is an empty text/plain: every error here is JSON
                refused = JSONResponse(error_body(
                    "range_not_satisfiable", f"expected a Range within the file's {size} bytes, "
                    f"got {text[:80]!r}", "Range"), 416, headers={"Content-Range": f"bytes */{size}"})
                await refused(scope, receive, send)
                return
            if text is not None and len(kept) <= text.count(","):
                # a set is satisfiable when one of its ranges is: the others are left out,
                # where Starlette refuses the whole set
                scope = {**scope, "headers": [*_without(headers, b"range"),
                                              (b"range", ("bytes=" + ",".join(kept)).encode())]}
            await super().__call__(scope, receive, send)
        finally:
            # Not a background task: Starlette runs those only after a complete send, not
            # after its own 416 for a range past the end, nor when sending fails or is
            # cancelled, and every snapshot left behind stays on disk until a restart. Done
            # here without awaiting, so a cancelled request cannot skip it either.
            Path(self.path).unlink(missing_ok=True)


async def _export(service: CanalService, name: str, kind: RecordingKind,
                  profile: Literal["foxglove", "ros2"] = "foxglove") -> FileResponse:
    # The snapshot is ours to delete once answered (Recorder contract): _Download does.
    path = await run_in_threadpool(service.export_recording, name, kind, profile)
    return _Download(path, media_type=_MEDIA[kind], filename=f"{name}.{kind}",
                     headers=service.recording_provenance())


@router.get("/recording.rrd", response_class=FileResponse, responses={
    **_RESPONSES, 200: {"content": {"application/octet-stream": {}}}})
async def recording_rrd(name: SkillName, service: ServiceDep) -> FileResponse:
    """A Rerun .rrd snapshot of the skill's demonstrations, fits and reproductions.

    Every replica answers the same for the same database; live poses are the part recorded
    per replica: the headers ``Canal-Recording-Shared``, ``Canal-Recording-Per-Replica`` and
    ``Canal-Replica`` say which parts are which and which replica answered."""
    return await _export(service, name, "rrd")


@router.get("/recording.mcap", response_class=FileResponse, responses={
    **_RESPONSES, 200: {"content": {"application/octet-stream": {}}}})
async def recording_mcap(
    name: SkillName, service: ServiceDep,
    profile: Literal["foxglove", "ros2"] = Query(
        "foxglove", description="foxglove: JSON messages with Foxglove schemas; ros2: a "
        "rosbag2-compatible MCAP (CDR: tf2_msgs/TFMessage, geometry_msgs/PoseStamped, "
        "nav_msgs/Path, visualization_msgs/MarkerArray)"),
) -> FileResponse:
    """An MCAP snapshot of the same recording (Foxglove JSON, or ROS 2 with ?profile=ros2)."""
    return await _export(service, name, "mcap", profile)


# HEAD as GET: download tools ask a file's size before fetching or resuming it. Left out of
# the schema, where it would repeat GET's operation (HTTP gives every GET a HEAD).
router.add_api_route("/recording.rrd", recording_rrd, methods=["HEAD"], include_in_schema=False)
router.add_api_route("/recording.mcap", recording_mcap, methods=["HEAD"], include_in_schema=False)


@router.post("/recording/rebuild", responses={**_RESPONSES, 409: {"model": ErrorResponse}})
async def rebuild_recording(name: SkillName, service: ServiceDep) -> dict[str, Any]:
    """Regenerate the skill's .rrd and .mcap from the database: every stored demonstration and
    model version, and the reproductions the database keeps. Live poses are not stored, so a
    rebuilt recording does not have them. Answers how many of each were logged."""
    return await run_in_threadpool(service.rebuild_recording, name)
