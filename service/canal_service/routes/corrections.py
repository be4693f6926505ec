"""/skills/{name}/corrections: a person refines a skill's canal; each change is a model version."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Path, status

from canal_protocol.schemas import (
    MAX_ID,
    CorrectedModel,
    CorrectionIn,
    CorrectionOut,
    ErrorResponse,
    Page,
)

from ..deps import Limit, Offset, ServiceDep, SkillName

router = APIRouter(prefix="/skills/{name}/corrections", tags=["corrections"])
_ERRORS: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorResponse} for code in (404, 409, 422)
}
CorrectionId = Annotated[int, Path(ge=1, le=MAX_ID)]


@router.post("", status_code=status.HTTP_201_CREATED, response_model=CorrectedModel,
             responses=_ERRORS)
def correct(name: SkillName, body: CorrectionIn, service: ServiceDep) -> CorrectedModel:
    """Refine the latest model version (or ``model``) by a correction: ``include`` grows the
    canal locally to hold the path, ``exclude`` narrows it on the side the robot was pushed
    from. Answers the new latest version, with ``parent_version`` and ``corrections``."""
    return service.correct(name, body)


@router.get("", response_model=Page[CorrectionOut], responses=_ERRORS)
def list_corrections(name: SkillName, service: ServiceDep, offset: Offset = 0,
                     limit: Limit = 100) -> Page[CorrectionOut]:
    """The skill's corrections, oldest first; undone ones stay listed and say so."""
    return service.list_corrections(name, offset, limit)


@router.delete("/{correction_id}", response_model=CorrectedModel, responses=_ERRORS)
def undo_correction(name: SkillName, correction_id: CorrectionId,
                    service: ServiceDep) -> CorrectedModel:
    """Undo one correction: a new latest version with the skill's other corrections
    re-applied to the fit they were made on."""
    return service.undo_correction(name, correction_id)
