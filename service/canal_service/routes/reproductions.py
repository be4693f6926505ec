"""/skills/{name}/reproductions"""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Response

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
def reproduce(name: SkillName, body: ReproductionRequest, service: ServiceDep) -> Response:
    """Reproduce from ``start`` (one result) or ``starts`` (``{"reproductions": [...]}``).

    A start outside the canal is projected onto it and reported with ``inside=false,
    projected=true``; send ``"outside": "raise"`` to get a 422 instead.
    """
    # Serialised here, on this worker thread: returned as a model, FastAPI would validate
    # it again (thousands of floats) in a second trip through the thread pool.
    result = service.reproduce(name, body)
    return Response(result.model_dump_json(), media_type="application/json")
