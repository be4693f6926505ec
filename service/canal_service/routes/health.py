"""Liveness and metrics."""

from __future__ import annotations

from fastapi import APIRouter, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from canal_protocol.schemas import HealthOut

from ..deps import HealthDep
from ..metrics import Metrics

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=HealthOut, summary="Health (no token needed)")
async def healthz(check: HealthDep) -> JSONResponse:
    """200 when the database answers and the recorder is ok or disabled, 503 when degraded."""
    health = await run_in_threadpool(check)
    return JSONResponse(health.model_dump(), status_code=200 if health.status == "ok" else 503)


@router.get("/metrics", summary="Prometheus metrics", response_class=Response,
            responses={200: {"content": {"text/plain": {}}}})
async def metrics(request: Request) -> Response:
    """Prometheus text exposition of this app's registry."""
    metrics: Metrics = request.app.state.metrics
    return Response(generate_latest(metrics.registry), media_type=CONTENT_TYPE_LATEST)
