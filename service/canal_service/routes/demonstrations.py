"""/skills/{name}/demonstrations: JSON bodies and file uploads (CSV, NPY, MCAP)."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query, Request, Response, status
from fastapi.exceptions import RequestValidationError
from pydantic import ValidationError

from canal_protocol.options import MAX_DEMO_LABEL
from canal_protocol.schemas import (
    DemonstrationCreated,
    DemonstrationIn,
    DemonstrationOut,
    DemonstrationSummary,
    ErrorResponse,
    Page,
    demonstration_from_json,
)

from ..deps import DemoId, Limit, Offset, ServiceDep, SkillName
from ..errors import InvalidInput, TooLarge, unreadable_body
from ..service import CanalService
from ..uploads import UploadLimits, detect_format
from .file_bodies import (
    Format,
    TimeUnit,
    Topic,
    file_body,
    file_content,
    upload_lane,
    upload_limits,
)

router = APIRouter(prefix="/skills/{name}/demonstrations", tags=["demonstrations"])

_REQUEST_BODY: dict[str, Any] = {
    "required": True,
    "description": (
        "One demonstration, as JSON, as a multipart upload (field `file`, optional field "
        "`label`), or as a raw file body. Files: CSV, NumPy .npy or MCAP (one demonstration "
        "per file, see the service docs); format from ?format=, the file name, the content "
        "type or the file's magic bytes."
    ),
    "content": {
        "application/json": {"schema": DemonstrationIn.model_json_schema()},
        **file_content(MAX_DEMO_LABEL),
    },
}
_ERRORS: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorResponse} for code in (400, 404, 413, 415, 422, 503)
}

Label = Annotated[str | None, Query(max_length=MAX_DEMO_LABEL, pattern=r"^[^\x00]*$",
                                    description="Label for a file upload.")]


@router.post("", status_code=status.HTTP_201_CREATED, response_model=DemonstrationCreated,
             responses=_ERRORS, openapi_extra={"requestBody": _REQUEST_BODY})
async def add_demonstration(
    name: SkillName,
    request: Request,
    service: ServiceDep,
    format: Format = None,
    topic: Topic = None,
    label: Label = None,
    time_unit: TimeUnit = None,
) -> Response:
    """Store one demonstration; nothing is stored unless every check passes."""
    content_type = request.headers.get("content-type", "")
    base = content_type.split(";", 1)[0].strip().lower()
    lane = upload_lane(request)
    limits = upload_limits(request)
    if base == "application/json" or base.endswith("+json"):
        if topic is not None:
            raise InvalidInput("expected topic only with an MCAP file, got a JSON body", field="topic")
        raw = await request.body()
        # Parsing too runs on the lane: on the event loop it would hold every other
        # request (and the bytes of the next upload) for its millisecond.
        return _created(await lane.run(_add_json, service, name, raw, limits, time_unit))
    upload = await file_body(request, "application/json, ")
    if label is None:
        label = upload.label
    fmt = detect_format(format, upload.filename, upload.content_type, upload.data)
    return _created(await lane.run(service.add_file_demonstration, name, fmt, upload.data, topic,
                                   label, limits, time_unit))


def _created(created: DemonstrationCreated) -> Response:
    # The answer as FastAPI would write it, without validating the model it was built as
    # once more on the event loop.
    return Response(created.model_dump_json(), status_code=status.HTTP_201_CREATED,
                    media_type="application/json")


def _add_json(service: CanalService, name: str, raw: bytes, limits: UploadLimits,
              time_unit: str | None = None) -> DemonstrationCreated:
    """Parse, check and store a JSON upload: the whole of it, on the upload lane."""
    if not raw.strip():
        raise InvalidInput("expected a JSON body with 'positions', got an empty body",
                           field="body")
    # Each row is one '[' (positions and orientations; a label adds at most MAX_DEMO_LABEL):
    # refuse an oversized demo before parsing builds its objects.
    if raw.count(b"[") > 2 * limits.max_points + 300:
        raise _too_many_points(limits)
    try:
        body = demonstration_from_json(raw)
    except ValidationError as exc:
        errors = exc.errors(include_url=False)
        refused = unreadable_body(raw, errors)
        if refused is not None:
            raise refused from exc
        raise RequestValidationError(errors) from exc
    if len(body.positions) > limits.max_points:
        raise _too_many_points(limits)
    return service.add_json_demonstration(name, body, time_unit)


def _too_many_points(limits: UploadLimits) -> TooLarge:
    return TooLarge(f"a demonstration may have at most {limits.max_points} samples (limit "
                    "CANAL_UPLOAD_MAX_POINTS); downsample it or split it", field="positions")


@router.get("", response_model=Page[DemonstrationSummary], responses=_ERRORS)
def list_demonstrations(name: SkillName, service: ServiceDep, offset: Offset = 0,
                        limit: Limit = 100) -> Page[DemonstrationSummary]:
    """Demonstration summaries (no arrays), oldest first."""
    return service.list_demonstrations(name, offset, limit)


@router.get("/{id}", response_model=DemonstrationOut, responses=_ERRORS)
def get_demonstration(name: SkillName, demo_id: DemoId, service: ServiceDep) -> DemonstrationOut:
    """One demonstration with its full arrays."""
    return service.get_demonstration(name, demo_id)


@router.delete("/{id}", status_code=status.HTTP_204_NO_CONTENT, response_class=Response,
               responses=_ERRORS)
def delete_demonstration(name: SkillName, demo_id: DemoId, service: ServiceDep) -> Response:
    """Delete a demonstration; model versions that used it keep their record of its id."""
    service.delete_demonstration(name, demo_id)
    return Response(status_code=status.HTTP_204_NO_CONTENT)
