"""/skills/{name}/reproductions"""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from canal_protocol.schemas import (
    ErrorResponse,
    ReproductionBatchOut,
    ReproductionOut,
    ReproductionRequest,
)

from ..deps import ServiceDep, SkillName

router = APIRouter(prefix="/skills/{name}", tags=["reproductions"])
_ERRORS: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorResponse} for code in (404, 409, 422)
}


@router.post("/reproductions", response_model=ReproductionOut | ReproductionBatchOut,
             responses=_ERRORS)
def reproduce(name: SkillName, body: ReproductionRequest,
              service: ServiceDep) -> ReproductionOut | ReproductionBatchOut:
    """Reproduce from ``start`` (one result) or ``starts`` (``{"reproductions": [...]}``).

    A start outside the canal is projected onto it and reported with ``inside=false,
    projected=true``; send ``"outside": "raise"`` to get a 422 instead.
    """
    return service.reproduce(name, body)
