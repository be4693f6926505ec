"""/skills/{name}/corrections: a person refines a skill's canal; each change is a model version."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Path, Query, Request, status
from fastapi.exceptions import RequestValidationError
from pydantic import ValidationError

from canal_protocol.options import (
    MAX_CORRECTION_LABEL,
    MAX_CORRECTION_WEIGHT,
    MAX_ROUTES,
    CorrectionKind,
)
from canal_protocol.schemas import (
    MAX_ID,
    CorrectedModel,
    CorrectionIn,
    CorrectionOut,
    CorrectionPath,
    ErrorResponse,
    Page,
)

from ..deps import Limit, Offset, ServiceDep, SkillName, parse_version
from ..service import CanalService
from ..uploads import UploadFormat, UploadLimits, detect_format
from .file_bodies import (
    Format,
    TimeUnit,
    Topic,
    file_body,
    file_content,
    upload_lane,
    upload_limits,
)

router = APIRouter(prefix="/skills/{name}/corrections", tags=["corrections"])
_ERRORS: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorResponse} for code in (404, 409, 422)
}
#: ``{id}`` in the path (docs/rest.md), the name its refusals and 404s give.
CorrectionId = Annotated[int, Path(ge=1, le=MAX_ID, alias="id", description="Correction id")]
_FILE_ERRORS: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorResponse} for code in (400, 404, 409, 413, 415, 422, 503)
}
_FILE_BODY: dict[str, Any] = {
    "required": True,
    "description": (
        "The corrected path as a file, read as a demonstration upload is (CSV by column "
        "names, NumPy .npy, MCAP with ?topic=): as a multipart upload (field `file`, "
        "optional field `label`) or as the raw body. Its positions are the samples; time "
        "stamps and orientations, when the file has them, are kept with the correction."
    ),
    "content": file_content(MAX_CORRECTION_LABEL),
}


@router.post("", status_code=status.HTTP_201_CREATED, response_model=CorrectedModel,
             responses=_ERRORS)
def correct(name: SkillName, body: CorrectionIn, service: ServiceDep,
            time_unit: TimeUnit = None) -> CorrectedModel:
    """Refine the latest model version (or ``model``) by a correction: ``include`` grows the
    canal locally to hold the path, ``exclude`` narrows it on the side the robot was pushed
    from. Answers the new latest version, with ``parent_version`` and ``corrections``."""
    return service.correct(name, body, time_unit=time_unit)


@router.get("", response_model=Page[CorrectionOut], responses=_ERRORS)
def list_corrections(name: SkillName, service: ServiceDep, offset: Offset = 0,
                     limit: Limit = 100) -> Page[CorrectionOut]:
    """The skill's corrections, oldest first; undone ones stay listed and say so."""
    return service.list_corrections(name, offset, limit)


@router.get("/{id}", response_model=CorrectionPath, responses=_ERRORS)
def get_correction(name: SkillName, correction_id: CorrectionId,
                   service: ServiceDep) -> CorrectionPath:
    """One correction with its path (samples, and timestamps, orientations and plan when
    sent): a model version's corrections name it by ``correction_id``."""
    return service.get_correction(name, correction_id)


@router.delete("/{id}", response_model=CorrectedModel, responses=_ERRORS)
def undo_correction(name: SkillName, correction_id: CorrectionId,
                    service: ServiceDep) -> CorrectedModel:
    """Undo one correction: a new latest version with the skill's other corrections
    re-applied to the fit they were made on."""
    return service.undo_correction(name, correction_id)


@router.post("/file", status_code=status.HTTP_201_CREATED, response_model=CorrectedModel,
             responses=_FILE_ERRORS, openapi_extra={"requestBody": _FILE_BODY})
async def correct_from_file(
    name: SkillName,
    request: Request,
    service: ServiceDep,
    kind: Annotated[CorrectionKind, Query(description="include or exclude (as in the JSON body).")],
    weight: Annotated[float, Query(gt=0.0, le=MAX_CORRECTION_WEIGHT, allow_inf_nan=False,
                                   description="How much an include counts against one "
                                               "demonstration.")] = 1.0,
    label: Annotated[str | None, Query(max_length=MAX_CORRECTION_LABEL, pattern=r"^[^\x00]*$",
                                       description="Default: the uploaded file's name.")] = None,
    model: Annotated[str, Query(max_length=12, description="A version number or 'latest'.")
                     ] = "latest",
    route: Annotated[int | None, Query(ge=0, le=MAX_ROUTES - 1,
                                       description="The route whose canal is corrected.")] = None,
    format: Format = None,
    topic: Topic = None,
    time_unit: TimeUnit = None,
) -> CorrectedModel:
    """The same correction as ``POST /corrections``, its path sent as a file (a logger's CSV,
    a ROS 2 bag) and read as a demonstration upload is; the other fields are query
    parameters. Nothing is stored unless every check passes."""
    version = parse_version(model, "model")
    upload = await file_body(request, hint=f"; a JSON correction goes to POST /skills/{name}/corrections",
                             max_label=MAX_CORRECTION_LABEL)
    fmt = detect_format(format, upload.filename, upload.content_type, upload.data)
    fields = {"kind": kind, "weight": weight, "route": route,
              "model": "latest" if version is None else version,
              "label": label if label is not None else upload.label or ""}
    return await upload_lane(request).run(_correct_from_file, service, name, fmt, upload.data,
                                          topic, upload_limits(request), fields, time_unit)


def _correct_from_file(service: CanalService, name: str, fmt: UploadFormat, data: bytes,
                       topic: str | None, limits: UploadLimits, fields: dict[str, Any],
                       time_unit: str | None) -> CorrectedModel:
    """Parse the file (on the upload lane, as a demonstration upload) and correct by it."""
    path = service.read_file(name, fmt, data, topic, limits, time_unit, fittable=False)
    try:
        body = CorrectionIn(
            samples=path.positions.tolist(),
            timestamps=None if path.timestamps is None else path.timestamps.tolist(),
            orientations=None if path.orientations is None else path.orientations.tolist(),
            **fields)
    except ValidationError as exc:
        raise RequestValidationError(exc.errors(include_url=False)) from exc
    return service.correct(name, body)
