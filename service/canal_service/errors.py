"""One place that turns every error into HTTP.

Body shape, for every 4xx the service sends::

    {"error": {"type": "invalid_input", "field": "positions", "message": "...",
               "details": [...]}}   # details only for request validation errors

``type`` is a stable machine-readable word; ``field`` names the request part at fault
(a JSON path like ``positions[3]``, a query parameter, a header, ``body``); ``message`` is for
humans. canal_core's errors are mapped here and nowhere else.
"""

from __future__ import annotations

import logging
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from sqlalchemy.exc import IntegrityError, OperationalError
from sqlalchemy.exc import TimeoutError as PoolTimeout
from starlette.exceptions import HTTPException as StarletteHTTPException

from canal_core.errors import (
    CanalError,
    DegenerateCanalError,
    InvalidInputError,
    ModelFormatError,
    OutsideCanalError,
)

log = logging.getLogger("canal_service")


class ServiceError(Exception):
    """An error the service raises on purpose; carries its HTTP status and JSON fields."""

    status_code = 400
    error_type = "bad_request"

    def __init__(self, message: str, *, field: str | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.field = field


class InvalidInput(ServiceError):
    """A well-formed request whose content is wrong (NaN, ragged, wrong dimension, ...)."""

    status_code = 422
    error_type = "invalid_input"


class BadUpload(ServiceError):
    """An uploaded file that cannot be parsed as the format it claims to be."""

    status_code = 400
    error_type = "bad_upload"


class NotFound(ServiceError):
    """An unknown skill, demonstration or model version."""

    status_code = 404
    error_type = "not_found"


class Conflict(ServiceError):
    """The request clashes with stored state (duplicate name, nothing fitted yet, ...)."""

    status_code = 409
    error_type = "conflict"


class UnsupportedMediaType(ServiceError):
    """A body in a content type the route does not take."""

    status_code = 415
    error_type = "unsupported_media_type"


class Disabled(ServiceError):
    """A feature switched off in this deployment (e.g. recordings).

    404, not 503: the resource does not exist here, and retrying will not make it appear.
    """

    status_code = 404
    error_type = "disabled"


class PayloadTooLarge(StarletteHTTPException):
    """Raised from the size-limited ``receive``.

    An HTTPException so that FastAPI's body reader re-raises it as is instead of
    turning it into a generic 400.
    """

    def __init__(self, limit: int) -> None:
        super().__init__(413, f"request body larger than the limit of {limit} bytes")
        self.limit = limit


class TooLarge(ServiceError):
    """An upload whose content exceeds a resource limit (points, decompressed bytes, ...)."""

    status_code = 413
    error_type = "payload_too_large"


class TooSlow(ServiceError):
    """An upload that needs more server time to parse than one upload may take."""

    status_code = 422
    error_type = "upload_too_slow"


class Busy(ServiceError):
    """A clash with a concurrent request that a retry will resolve (503 + Retry-After)."""

    status_code = 503
    error_type = "busy"

    def __init__(self, message: str, *, field: str | None = None, retry_after: int = 1) -> None:
        super().__init__(message, field=field)
        self.retry_after = retry_after


_CANAL_STATUS: list[tuple[type[CanalError], int, str]] = [
    (InvalidInputError, 422, "invalid_input"),
    (DegenerateCanalError, 422, "degenerate_canal"),
    (OutsideCanalError, 422, "outside_canal"),
    (ModelFormatError, 400, "model_format"),
]

_HTTP_TYPES = {
    401: "unauthorized",
    404: "not_found",
    405: "method_not_allowed",
    413: "payload_too_large",
    415: "unsupported_media_type",
}


def error_body(
    error_type: str, message: str, field: str | None = None, details: list[Any] | None = None
) -> dict[str, Any]:
    """The JSON error envelope every failure uses."""
    error: dict[str, Any] = {"type": error_type, "field": field, "message": message}
    if details is not None:
        error["details"] = details
    return {"error": error}


def loc_to_field(loc: tuple[Any, ...] | list[Any]) -> str:
    """Turn a pydantic location like ('body', 'positions', 3, 1) into 'positions[3][1]'."""
    parts = list(loc)
    if parts and parts[0] in ("body", "query", "path", "header") and len(parts) > 1:
        parts = parts[1:]
    field = ""
    for part in parts:
        if isinstance(part, int):
            field += f"[{part}]"
        elif not field:
            field = str(part)
        elif str(part).startswith(("function-", "list[", "tagged-union", "json-")):
            # pydantic adds validator names to the loc; they are not fields
            continue
        else:
            field += f".{part}"
    return field or "body"


def validation_error_body(errors: list[dict[str, Any]]) -> dict[str, Any]:
    """Envelope for pydantic errors: the first one names the field, all are in details."""
    details = [
        {"field": loc_to_field(e.get("loc", ())), "message": str(e.get("msg", "")),
         "type": str(e.get("type", ""))}
        for e in errors
    ]
    if not details:
        return error_body("invalid_input", "invalid request", "body", [])
    first = details[0]
    return error_body("invalid_input", f"{first['field']}: {first['message']}", first["field"],
                      details)


def canal_error_status(exc: CanalError) -> tuple[int, str]:
    """HTTP status and error type for a canal_core error."""
    for cls, status, error_type in _CANAL_STATUS:
        if isinstance(exc, cls):
            return status, error_type
    return 422, "canal_error"


def install_error_handlers(app: FastAPI) -> None:
    """Register the handlers; after this no expected error leaves as HTML or a 500."""

    @app.exception_handler(ServiceError)
    async def _service_error(_request: Request, exc: ServiceError) -> JSONResponse:
        headers = None
        if isinstance(exc, Busy):
            headers = {"Retry-After": str(exc.retry_after)}
        return JSONResponse(error_body(exc.error_type, exc.message, exc.field), exc.status_code,
                            headers=headers)

    @app.exception_handler(CanalError)
    async def _canal_error(_request: Request, exc: CanalError) -> JSONResponse:
        status, error_type = canal_error_status(exc)
        return JSONResponse(error_body(error_type, exc.message, exc.field), status)

    @app.exception_handler(RequestValidationError)
    async def _validation_error(_request: Request, exc: RequestValidationError) -> JSONResponse:
        return JSONResponse(validation_error_body(list(exc.errors())), 422)

    @app.exception_handler(StarletteHTTPException)
    async def _http_error(_request: Request, exc: StarletteHTTPException) -> JSONResponse:
        field = "body" if exc.status_code == 413 else None
        if exc.status_code == 401:
            field = "Authorization"
        body = error_body(_HTTP_TYPES.get(exc.status_code, "http_error"), str(exc.detail), field)
        return JSONResponse(body, exc.status_code, headers=getattr(exc, "headers", None))

    @app.exception_handler(IntegrityError)
    async def _integrity_error(_request: Request, exc: IntegrityError) -> JSONResponse:
        # Expected clashes (names, versions) are caught where they happen; one reaching here
        # is a race with a concurrent change (e.g. the skill deleted meanwhile): retryable.
        log.warning("integrity error answered 409: %s", exc.orig)
        body = error_body("conflict", "the request clashed with a concurrent change; retry it")
        return JSONResponse(body, 409, headers={"Retry-After": "1"})

    @app.exception_handler(OperationalError)
    @app.exception_handler(PoolTimeout)
    async def _database_busy(_request: Request, exc: Exception) -> JSONResponse:
        # Lock or pool timeouts, a database restarting: the request may well succeed later.
        log.warning("database unavailable, answered 503: %s", exc)
        body = error_body("busy", "the database is busy or unavailable; retry shortly")
        return JSONResponse(body, 503, headers={"Retry-After": "1"})

    # Unexpected exceptions are not handled here: Starlette re-raises them after calling an
    # ``Exception`` handler, and uvicorn then closes the keep-alive connection. The
    # ``CatchUnexpected`` middleware answers them with a JSON 500 and swallows them instead.
