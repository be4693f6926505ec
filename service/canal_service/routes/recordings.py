"""/skills/{name}/recording.rrd and .mcap: snapshots of the skill's recording."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from fastapi import APIRouter
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse
from starlette.background import BackgroundTask

from ..deps import ServiceDep, SkillName
from ..errors import Disabled
from ..schemas import ErrorResponse

router = APIRouter(prefix="/skills/{name}", tags=["recordings"])
_RESPONSES: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorResponse} for code in (404, 422)
}
_MEDIA = {"rrd": "application/octet-stream", "mcap": "application/octet-stream"}


async def _export(service: Any, name: str, kind: str) -> FileResponse:
    if service.recorder is None:
        raise Disabled("recordings are disabled on this service", field="recordings")
    path = Path(await run_in_threadpool(service.export_recording, name, kind))
    # The snapshot is ours to delete once sent (Recorder contract).
    return FileResponse(path, media_type=_MEDIA[kind], filename=f"{name}.{kind}",
                        background=BackgroundTask(path.unlink, missing_ok=True))


@router.get("/recording.rrd", response_class=FileResponse, responses={
    **_RESPONSES, 200: {"content": {"application/octet-stream": {}}}})
async def recording_rrd(name: SkillName, service: ServiceDep) -> FileResponse:
    """A Rerun .rrd snapshot of the skill's demonstrations, fits and reproductions."""
    return await _export(service, name, "rrd")


@router.get("/recording.mcap", response_class=FileResponse, responses={
    **_RESPONSES, 200: {"content": {"application/octet-stream": {}}}})
async def recording_mcap(name: SkillName, service: ServiceDep) -> FileResponse:
    """An MCAP snapshot of the same recording."""
    return await _export(service, name, "mcap")
