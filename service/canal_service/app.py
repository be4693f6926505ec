"""``create_app(settings)``: the FastAPI application, its storage, recorder and middleware.

Every part is built here, in dependency order, and handed to the constructors of the parts
that use it: nothing is attached afterwards. Recording and the live bridge are off only when
the settings say so (``--no-recordings``, ``--no-zenoh``); ``/healthz`` then says "disabled".
"""

from __future__ import annotations

import logging
import os
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import TYPE_CHECKING, Any

from fastapi import FastAPI
from fastapi.concurrency import run_in_threadpool
from fastapi.middleware.cors import CORSMiddleware

from . import __version__
from .core.config import Settings
from .errors import install_error_handlers
from .fitting import FitRunner
from .health import ServiceHealth
from .lanes import Lane
from .listeners import FitListeners
from .memory import MemoryReleaser, ReleaseMemoryWhenIdle
from .metrics import Metrics
from .middleware import (
    BearerAuth,
    BodySizeLimit,
    CatchUnexpected,
    EncodedSlash,
    JsonNewline,
    RequestMetrics,
)
from .routes import api_router, docs, health, view
from .service import CanalService, RecorderLike
from .storage import Database
from .uploads import UploadLimits

if TYPE_CHECKING:
    from .bridge import Bridge, BridgeProcesses

log = logging.getLogger("canal_service")

OPEN_PATHS = frozenset({"/healthz"})

DESCRIPTION = """
Learn robot skills from demonstrations with canal surfaces (Ahmadzadeh & Chernova).

Create a skill, post demonstrations (JSON, CSV, NPY or MCAP), fit a canal, look at it
(geometry, mesh), remove a bad demonstration and refit, and ask for reproductions.
Every error is JSON: `{"error": {"type", "field", "message"}}`.
"""


def make_recorder(settings: Settings, db: Database | None = None) -> RecorderLike | None:
    """The recorder from config (its writer thread started), or None when switched off.

    With ``db`` the recorder reads what it logs from the database (the request path queues
    only ids) and fills in what a crash kept out of the recordings; it records live poses
    from its own Zenoh session when the bridge is enabled.
    """
    if not settings.recordings_enabled:
        return None
    # Imported only when wanted (rerun-sdk takes a second to import); a failure is an error.
    from .recording import recorder_from_settings

    # Rerun phones home on first use unless told not to; a lab service should not.
    os.environ.setdefault("RERUN_TELEMETRY_ENABLED", "false")
    recorder: RecorderLike = recorder_from_settings(settings, db)
    return recorder


def make_bridge(settings: Settings, service: CanalService) -> Bridge | BridgeProcesses | None:
    """The live Zenoh bridge (not started yet), or None when disabled: bridge processes of
    their own (``zenoh_processes``, default 1), or a bridge in this process when 0."""
    if not settings.zenoh_enabled:
        return None
    from .bridge import Bridge, BridgeOptions, BridgeProcesses

    if settings.zenoh_processes > 0:
        return BridgeProcesses(settings, service)
    return Bridge(service, BridgeOptions.from_settings(settings))


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the app: migrate the database and open the recorder now; the lifespan starts the
    bridge and closes everything."""
    settings = settings or Settings()
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    db = Database(settings.resolved_database_url)
    db.migrate()
    metrics = Metrics()
    recorder = make_recorder(settings, db)
    try:
        service = CanalService(db, metrics, cache_size=settings.model_cache_size,
                               recorder=recorder, fit_listeners=FitListeners(),
                               reproductions_kept=settings.recordings_reproductions_kept,
                               fits=FitRunner(settings.fit_max_seconds),
                               reproduce_max_seconds=settings.reproduce_max_seconds)
        bridge = make_bridge(settings, service)
    except BaseException:
        # No lifespan will run to close what was opened: close it here.
        if recorder is not None:
            recorder.close()
        db.dispose()
        raise
    health_check = ServiceHealth(db, recorder, bridge)
    # Uploads run on a lane of their own, not on AnyIO's shared pool (see lanes.py).
    upload_lane = Lane("upload", settings.upload_workers)
    releaser = MemoryReleaser(settings.memory_trim_idle_s)

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        if bridge is not None:
            # A bridge that cannot start (port taken) leaves the REST API up; /healthz says so.
            await run_in_threadpool(bridge.start)
        releaser.start()
        try:
            yield
        finally:
            releaser.close()
            if bridge is not None:
                await run_in_threadpool(bridge.close)
            await run_in_threadpool(upload_lane.close)
            if recorder is not None:
                await run_in_threadpool(recorder.close)
            db.dispose()

    app = FastAPI(
        title="Canal",
        version=__version__,
        description=DESCRIPTION,
        lifespan=lifespan,
        # /docs and /redoc come from routes/docs.py: the same pages without a CDN
        docs_url=None,
        redoc_url=None,
        responses={401: {"description": "Missing or wrong bearer token (when one is set)"}},
    )
    app.state.settings = settings
    app.state.service = service
    app.state.health = health_check
    app.state.metrics = metrics
    app.state.bridge = bridge
    app.state.upload_lane = upload_lane
    app.state.memory = releaser
    app.state.upload_limits = UploadLimits(
        max_points=settings.upload_max_points,
        max_decompressed_bytes=settings.upload_max_decompressed_bytes,
        max_seconds=settings.upload_max_seconds)
    install_error_handlers(app)
    app.include_router(health.router)
    app.include_router(api_router)
    app.include_router(view.router)
    app.include_router(docs.router)

    # Added innermost first: auth runs before the body is read, the size limit wraps
    # everything that reads a body, the error net wraps them all but the metrics (which then
    # count its 500s).
    if settings.cors_origins:
        app.add_middleware(CORSMiddleware, allow_origins=settings.cors_origins,
                           allow_methods=["*"], allow_headers=["*"])
    app.add_middleware(EncodedSlash)
    app.add_middleware(BodySizeLimit, limit=settings.max_body_bytes)
    if settings.token is not None:
        app.add_middleware(BearerAuth, token=settings.token.get_secret_value(),
                           open_paths=OPEN_PATHS)
        _declare_bearer(app)
    app.add_middleware(CatchUnexpected)
    app.add_middleware(JsonNewline)  # outside the error net: its 500s end in a newline too
    app.add_middleware(ReleaseMemoryWhenIdle, releaser=releaser)
    app.add_middleware(RequestMetrics, metrics=metrics)
    return app


def _declare_bearer(app: FastAPI) -> None:
    """Show the bearer scheme in the OpenAPI document so /docs offers 'Authorize'."""
    original = app.openapi

    def openapi() -> dict[str, Any]:
        schema = original()
        components = schema.setdefault("components", {})
        components.setdefault("securitySchemes", {})["bearer"] = {"type": "http",
                                                                   "scheme": "bearer"}
        schema["security"] = [{"bearer": []}]
        return schema

    app.openapi = openapi  # type: ignore[method-assign]
