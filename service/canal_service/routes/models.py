"""/skills/{name}/fit and /skills/{name}/models: fitted canal versions and their meshes."""

from __future__ import annotations

import asyncio
import threading
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Body, Depends, Query, Request, Response, status
from fastapi.concurrency import run_in_threadpool

from canal_protocol.schemas import ErrorResponse, FitRequest, ModelOut, ModelSummary, Page

from ..deps import Limit, Offset, ServiceDep, SkillName, VersionRef, parse_version
from ..errors import InvalidInput, is_json_content_type
from ..mesh import MESH_MEDIA_TYPES, export_mesh

router = APIRouter(prefix="/skills/{name}", tags=["models"])
_ERRORS: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorResponse} for code in (404, 409, 422)
}
#: How often a running fit looks whether its client is still there.
_DISCONNECT_POLL_SECONDS = 0.25


async def _not_null(request: Request) -> None:
    # No body means every default; a JSON null is not "no body" but a client bug. A body in
    # another content type is not JSON at all: the 415 of the error handlers.
    if (is_json_content_type(request.headers.get("content-type"))
            and (await request.body()).strip() == b"null"):
        raise InvalidInput("expected a JSON object of fit options (or no body), got null",
                           field="body")


@router.post("/fit", status_code=status.HTTP_201_CREATED, response_model=ModelSummary,
             responses=_ERRORS, dependencies=[Depends(_not_null)])
async def fit(name: SkillName, service: ServiceDep, request: Request,
              body: Annotated[FitRequest | None, Body()] = None) -> ModelSummary:
    """Fit a new model version from the skill's demonstrations (all, or ``demo_ids``).

    Runs in a worker process (waited for on a worker thread, so a long fit does not hold
    up other requests), within ``CANAL_FIT_MAX_SECONDS``; stopped when the client leaves.
    """
    cancel = threading.Event()
    work = asyncio.ensure_future(run_in_threadpool(service.fit, name, body or FitRequest(),
                                                   cancel))
    while not work.done():
        await asyncio.wait({work}, timeout=_DISCONNECT_POLL_SECONDS)
        if not work.done() and await request.is_disconnected():
            cancel.set()  # the worker process is killed; nobody waits for the answer
    return work.result()


@router.get("/models", response_model=Page[ModelSummary], responses=_ERRORS)
def list_models(name: SkillName, service: ServiceDep, offset: Offset = 0,
                limit: Limit = 100) -> Page[ModelSummary]:
    """Model versions, newest first."""
    return service.list_models(name, offset, limit)


@router.get("/models/{version}", response_model=ModelOut, responses=_ERRORS)
def get_model(
    name: SkillName, version: VersionRef, service: ServiceDep,
    serialized: Annotated[bool, Query(description="Include the full canal_core model.")] = False,
) -> ModelOut:
    """A model version (or ``latest``): directrix, radii, section parameters, frames, bounds."""
    return service.get_model(name, parse_version(version), serialized)


@router.get(
    "/models/{version}/mesh", response_class=Response, responses={
        **_ERRORS,
        200: {"content": {t: {} for t in MESH_MEDIA_TYPES.values()},
              "description": "The mesh in the requested format."},
    },
)
async def get_mesh(
    name: SkillName, version: VersionRef, service: ServiceDep,
    format: Annotated[Literal["ply", "obj", "glb", "json"], Query()] = "ply",
    n_angles: Annotated[int, Query(ge=3, le=256)] = 32,
    caps: bool = False,
    envelope: bool = False,
) -> Response:
    """The canal surface as a triangle mesh: PLY, OBJ, GLB (via trimesh) or JSON arrays."""
    mesh = await run_in_threadpool(service.mesh, name, parse_version(version), n_angles, caps,
                                   envelope)
    payload = await run_in_threadpool(export_mesh, mesh, format)
    filename = f"{name}-{version}.{format}"
    return Response(payload, media_type=MESH_MEDIA_TYPES[format],
                    headers={"content-disposition": f'attachment; filename="{filename}"'})
