"""/skills/{name}/reproductions"""

from __future__ import annotations

import asyncio
import threading
from typing import Any

from fastapi import APIRouter, Request, Response
from fastapi.concurrency import run_in_threadpool

from canal_protocol.schemas import (
    ErrorResponse,
    ReproductionBatchOut,
    ReproductionOut,
    ReproductionRequest,
)

from ..deps import ServiceDep, SkillName
from ..service import CanalService

router = APIRouter(prefix="/skills/{name}", tags=["reproductions"])
_ERRORS: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorResponse} for code in (404, 409, 422)
}
_DISCONNECT_POLL_SECONDS = 0.25


@router.post("/reproductions", response_model=ReproductionOut | ReproductionBatchOut,
             responses=_ERRORS)
async def reproduce(name: SkillName, body: ReproductionRequest, service: ServiceDep,
                    request: Request) -> Response:
    """Reproduce from ``start`` (one result) or ``starts`` (``{"reproductions": [...]}``).

    A start outside the canal is projected onto it and reported with ``inside=false,
    projected=true``; send ``"outside": "raise"`` to get a 422 instead. A batch runs within
    ``CANAL_REPRODUCE_MAX_SECONDS`` (422 reproduction_too_slow after) and stops when the
    client leaves.
    """
    cancel = threading.Event()
    work = asyncio.ensure_future(run_in_threadpool(_answer, service, name, body, cancel))
    while not work.done():
        await asyncio.wait({work}, timeout=_DISCONNECT_POLL_SECONDS)
        if not work.done() and await request.is_disconnected():
            cancel.set()  # the batch stops before its next start; nobody reads the answer
    return work.result()


def _answer(service: CanalService, name: str, body: ReproductionRequest,
            cancel: threading.Event) -> Response:
    # Serialised here, on the worker thread: returned as a model, FastAPI would validate it
    # again (thousands of floats) in a second trip through the thread pool.
    result = service.reproduce(name, body, cancel)
    return Response(result.model_dump_json(), media_type="application/json")
