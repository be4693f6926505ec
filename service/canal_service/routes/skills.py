"""/skills"""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Response, status

from canal_protocol.schemas import ErrorResponse, Page, SkillCreate, SkillOut

from ..deps import Limit, Offset, ServiceDep, SkillName

router = APIRouter(prefix="/skills", tags=["skills"])
_ERRORS: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorResponse} for code in (404, 422)
}


@router.post("", status_code=status.HTTP_201_CREATED, response_model=SkillOut,
             responses={409: {"model": ErrorResponse}, 422: {"model": ErrorResponse}})
def create_skill(body: SkillCreate, service: ServiceDep) -> SkillOut:
    """Create a skill; its dimension (2 or 3) is fixed for life."""
    return service.create_skill(body)


@router.get("", response_model=Page[SkillOut])
def list_skills(service: ServiceDep, offset: Offset = 0, limit: Limit = 100) -> Page[SkillOut]:
    """Skills by name, with counts and latest model version."""
    return service.list_skills(offset, limit)


@router.get("/{name}", response_model=SkillOut, responses=_ERRORS)
def get_skill(name: SkillName, service: ServiceDep) -> SkillOut:
    """One skill with its counts and latest model version."""
    return service.get_skill(name)


@router.delete("/{name}", status_code=status.HTTP_204_NO_CONTENT, response_class=Response,
               responses=_ERRORS)
def delete_skill(name: SkillName, service: ServiceDep) -> Response:
    """Delete a skill with all its demonstrations and model versions."""
    service.delete_skill(name)
    return Response(status_code=status.HTTP_204_NO_CONTENT)
