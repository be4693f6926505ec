"""Liveness and metrics."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from canal_protocol.schemas import HealthOut

from ..deps import HealthDep
from ..metrics import Metrics

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=HealthOut, summary="Health (no token needed)")
async def healthz(check: HealthDep, request: Request) -> JSONResponse:
    """200 when the database answers and the recorder is ok or disabled, 503 when degraded.
    When the service has a token, a request without it gets the states and counts only: no
    stream, skill or robot names, no details."""
    health = await run_in_threadpool(check)
    body = health.model_dump()
    if not getattr(request.state, "authorized", True):
        body = without_names(body)
    return JSONResponse(body, status_code=200 if health.status == "ok" else 503)


_HIDDEN = "given with the token"


def without_names(body: dict[str, Any]) -> dict[str, Any]:
    """``/healthz``'s body for a caller without the token: the live recorder's per-stream
    table (keyed by skill/robot) becomes its length, every ``detail`` text (which may name
    a skill, a robot or a file) is replaced by a note."""
    def strip(value: Any) -> Any:
        if isinstance(value, dict):
            out: dict[str, Any] = {}
            for key, item in value.items():
                if key == "streams" and isinstance(item, dict):
                    out[key] = len(item)
                elif key == "detail" and item is not None:
                    out[key] = _HIDDEN
                else:
                    out[key] = strip(item)
            return out
        if isinstance(value, list):
            return [strip(v) for v in value]
        return value

    return strip(body)  # type: ignore[no-any-return]


@router.get("/metrics", summary="Prometheus metrics", response_class=Response,
            responses={200: {"content": {"text/plain": {}}}})
async def metrics(request: Request) -> Response:
    """Prometheus text exposition of this app's registry."""
    metrics: Metrics = request.app.state.metrics
    return Response(generate_latest(metrics.registry), media_type=CONTENT_TYPE_LATEST)
