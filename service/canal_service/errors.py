"""The service's domain errors, and the one table that turns every error into HTTP.

Below the HTTP layer (repository, service, validation, bridge) code raises the domain errors
defined here: they say what went wrong (``SkillNotFound``, ``NoModelYet``, ...) and carry a
message and the request ``field`` at fault, never a status code. :data:`HTTP_STATUS` maps
them, and canal_core's :class:`~canal_core.errors.CanalError` hierarchy, to a status and a
stable machine-readable ``type`` word; :func:`install_error_handlers` is the only user of it.
The bridge replies over Zenoh with the same words (:func:`error_type`).

Body shape, for every 4xx the service sends::

    {"error": {"type": "invalid_input", "field": "positions", "message": "...",
               "details": [...]}}   # details only for request validation errors

``type`` is a stable machine-readable word; ``field`` names the request part at fault
(a JSON path like ``positions[3]``, a query parameter, a header, ``body``); ``message`` is for
humans.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from sqlalchemy.exc import IntegrityError, OperationalError
from sqlalchemy.exc import TimeoutError as PoolTimeout
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import Match

from canal_core.errors import (
    CanalError,
    DegenerateCanalError,
    InvalidInputError,
    ModelFormatError,
    OutsideCanalError,
)
from canal_protocol.schemas import SKILL_NAME_PATTERN, SKILL_NAME_WORDS, shown_value

log = logging.getLogger("canal_service")


# ---- domain errors (no HTTP in them) -----------------------------------------------------------


class ServiceError(Exception):
    """Base of every error the service raises on purpose: a message and the field at fault."""

    def __init__(self, message: str, *, field: str | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.field = field


class InvalidInput(ServiceError):
    """A well-formed request whose content is wrong (NaN, ragged, wrong dimension, ...)."""


class BadUpload(ServiceError):
    """An uploaded file that cannot be parsed as the format it claims to be."""


class UnsupportedMediaType(ServiceError):
    """A body in a content type the route does not take."""


class TooLarge(ServiceError):
    """An upload whose content exceeds a resource limit (points, decompressed bytes, ...)."""


class FitTooSlow(ServiceError):
    """A fit estimated to need, or found needing, more server time than one fit may take."""


class FitCancelled(ServiceError):
    """A fit stopped before its end: its skill was deleted, or its client went away."""


class ReproductionTooSlow(ServiceError):
    """A batch of reproductions that outlived the server time one request may take."""


class ReproductionCancelled(ServiceError):
    """A batch of reproductions stopped because its client went away (nobody reads the answer)."""


class NotFound(ServiceError):
    """Something the request names does not exist (base of the specific kinds below)."""


class SkillNotFound(NotFound):
    """No skill of that name."""


class DemoNotFound(NotFound):
    """The skill has no demonstration of that id."""


class ModelVersionNotFound(NotFound):
    """The skill has models, but not the version asked for (or it was deleted meanwhile)."""


class CorrectionNotFound(NotFound):
    """The skill has no correction of that id."""


class Conflict(ServiceError):
    """The request clashes with stored state (base of the specific kinds below)."""


class SkillExists(Conflict):
    """A skill of that name exists already."""


class NoModelYet(Conflict):
    """The skill exists but has no fitted model; fit one first.

    Carries the skill's ``dim``: a live client is told what to send once a model exists.
    """

    def __init__(self, skill: str, dim: int, *, field: str | None = "model") -> None:
        super().__init__(f"skill {skill!r} has no fitted model yet; POST "
                         f"/skills/{skill}/fit first", field=field)
        self.skill = skill
        self.dim = dim


class NotEnoughDemonstrations(Conflict):
    """Fitting needs at least two demonstrations."""


class VersionConflict(Conflict):
    """Concurrent fits kept taking the model version number this fit tried to store."""


class CorrectionNotInLatest(Conflict):
    """An undo of a correction the latest model version does not have."""


class SkillReplaced(Conflict):
    """What was captured on a skill is stored only into that skill: the one under its name
    was deleted (and perhaps created again) since the capture began."""

    def __init__(self, skill: str, what: str, *, exists: bool, field: str = "skill",
                 when: str | None = None) -> None:
        got = ("another skill: it was deleted and created again under its name" if exists
               else "no skill: it was deleted")
        if when is None:
            super().__init__(f"expected the skill '{skill}' this {what} was captured on, got "
                             f"{got} since the capture began; nothing is stored, start the "
                             "capture again", field=field)
        else:
            super().__init__(f"expected the skill '{skill}' this {what} was sent to, got {got} "
                             f"since {when}; nothing is stored", field=field)


class RecordingFailed(Conflict):
    """The recorder could not produce the recording asked for (e.g. a rebuild failed)."""


class Disabled(ServiceError):
    """A feature switched off in this deployment (e.g. recordings)."""


class Busy(ServiceError):
    """A clash with a concurrent request that a retry will resolve."""

    def __init__(self, message: str, *, field: str | None = None, retry_after: int = 1) -> None:
        super().__init__(message, field=field)
        self.retry_after = retry_after


class CanalRejected(ServiceError):
    """canal_core refused the request's data; ``cause`` is its error, unchanged.

    The service wraps core errors in this (``raise CanalRejected(...) from exc``) to name
    the field as the client knows it (a stored demonstration id rather than a list index):
    the core error itself is never altered. It answers with the cause's status and type.
    """

    def __init__(self, cause: CanalError, message: str, *, field: str | None = None) -> None:
        super().__init__(message, field=field)
        self.cause = cause


class PayloadTooLarge(StarletteHTTPException):
    """Raised from the size-limited ``receive`` (an HTTP-layer error: middleware only).

    An HTTPException so that FastAPI's body reader re-raises it as is instead of
    turning it into a generic 400.
    """

    def __init__(self, limit: int) -> None:
        super().__init__(413, f"request body larger than the limit of {limit} bytes")
        self.limit = limit


# ---- the one table -----------------------------------------------------------------------------

#: Every error class the service answers on purpose -> (HTTP status, ``type`` word). An error
#: takes the entry of the nearest class in its MRO, so a subclass without its own entry
#: answers as its base.
HTTP_STATUS: Mapping[type[Exception], tuple[int, str]] = {
    ServiceError: (400, "bad_request"),
    InvalidInput: (422, "invalid_input"),
    BadUpload: (400, "bad_upload"),
    UnsupportedMediaType: (415, "unsupported_media_type"),
    TooLarge: (413, "payload_too_large"),
    FitTooSlow: (422, "fit_too_slow"),
    FitCancelled: (409, "conflict"),
    ReproductionTooSlow: (422, "reproduction_too_slow"),
    ReproductionCancelled: (409, "conflict"),
    NotFound: (404, "not_found"),
    Conflict: (409, "conflict"),
    # 404, not 503: the resource does not exist here, and retrying will not make it appear.
    Disabled: (404, "disabled"),
    Busy: (503, "busy"),
    CanalError: (422, "canal_error"),
    InvalidInputError: (422, "invalid_input"),
    DegenerateCanalError: (422, "degenerate_canal"),
    OutsideCanalError: (422, "outside_canal"),
    ModelFormatError: (400, "model_format"),
}

_HTTP_TYPES = {
    400: "bad_request",
    401: "unauthorized",
    404: "not_found",
    405: "method_not_allowed",
    413: "payload_too_large",
    415: "unsupported_media_type",
}


def http_status(exc: ServiceError | CanalError) -> tuple[int, str]:
    """(HTTP status, ``type`` word) of a domain or canal_core error, from :data:`HTTP_STATUS`.

    A :class:`CanalRejected` answers as the core error it wraps.
    """
    target: Exception = exc.cause if isinstance(exc, CanalRejected) else exc
    for cls in type(target).__mro__:
        entry = HTTP_STATUS.get(cls)
        if entry is not None:
            return entry
    raise TypeError(f"no HTTP status for {type(exc).__name__}")  # unreachable: bases are listed


def error_type(exc: ServiceError | CanalError) -> str:
    """The stable ``type`` word of an error (the HTTP body's, and the bridge's Zenoh replies')."""
    return http_status(exc)[1]


def error_body(
    kind: str, message: str, field: str | None = None, details: list[Any] | None = None
) -> dict[str, Any]:
    """The JSON error envelope every failure uses (``kind`` is the ``type`` word)."""
    error: dict[str, Any] = {"type": kind, "field": field, "message": message}
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


def _unreadable_json(error: dict[str, Any]) -> dict[str, Any]:
    """A body FastAPI could not decode as JSON: its loc is ('body', character), which is no
    field, and its message ("JSON decode error") does not say where or what."""
    loc = list(error.get("loc", ()))
    at = loc[-1] if loc and isinstance(loc[-1], int) else None
    why = str((error.get("ctx") or {}).get("error", "")).strip()
    where = "" if at is None else f" at character {at}"
    return {"field": "body", "message": f"expected a JSON object, got invalid JSON{where}"
            + (f" ({why})" if why else ""), "type": "json_invalid"}


# Errors whose input is not the value at fault: a missing key has none, an unknown key's
# value is not what was wrong with it.
_NO_VALUE_SHOWN = frozenset({"missing", "extra_forbidden"})


def _query_number(error: Mapping[str, Any]) -> str | None:
    """A number sent in a query or path as it was typed (``got 2``, not ``got "2"``: every
    query value is text, and the quotes would read as if a string had been sent)."""
    value = error.get("input")
    loc = error.get("loc", ())
    if not (loc and loc[0] in ("query", "path") and isinstance(value, str) and value.strip()):
        return None
    try:
        float(value)
    except ValueError:
        return None
    return value[:40]


def pydantic_detail(error: Mapping[str, Any]) -> dict[str, Any]:
    """One pydantic error as {field, message, type}: the message says what was expected and,
    when it does not already, what came (pydantic's own messages leave the value out)."""
    if error.get("type") == "json_invalid":
        return _unreadable_json(dict(error))
    field = loc_to_field(error.get("loc", ()))
    message = str(error.get("msg", ""))
    kind = str(error.get("type", ""))
    if kind == "value_error":
        message = message.removeprefix("Value error, ")  # how the check was written
    ctx = error.get("ctx") or {}
    if kind == "string_pattern_mismatch" and ctx.get("pattern") == SKILL_NAME_PATTERN:
        message = SKILL_NAME_WORDS  # not the regular expression
    if kind in ("too_short", "too_long") and "actual_length" in ctx:
        # pydantic's "List should have at least 2 items after validation, not 1"
        bound = ("at least", ctx.get("min_length")) if kind == "too_short" else (
            "at most", ctx.get("max_length"))
        message = f"expected {bound[0]} {bound[1]} items, got {ctx['actual_length']}"
    value = error.get("input")
    if ("input" in error and kind not in _NO_VALUE_SHOWN and " got " not in f" {message} "
            and not (field == "body" and isinstance(value, dict))):
        message = f"{message}, got {_query_number(error) or shown_value(value)}"
    return {"field": field, "message": message, "type": kind}


def is_json_content_type(content_type: str | None) -> bool:
    """Whether a request's Content-Type lets FastAPI read its body as JSON: ``application/json``
    or an ``application/...+json`` type, with any parameters (``; charset=utf-8``). None at
    all is not JSON (FastAPI's strict content type, as the upload routes take it)."""
    base = (content_type or "").split(";", 1)[0].strip().lower()
    return base == "application/json" or (base.startswith("application/") and base.endswith("+json"))


def unsupported_json_body(content_type: str | None) -> UnsupportedMediaType:
    """A JSON route's body sent in another content type, or with none: FastAPI hands such a
    body over as bytes, which every body model refuses (a 422 "a valid dictionary, got bytes"
    of a body that may well be valid JSON). The content type is what is wrong: 415."""
    came = content_type[:100] if content_type else "none"
    return UnsupportedMediaType(f"expected Content-Type application/json, got {came!r}",
                                field="Content-Type")


def validation_error_body(errors: list[dict[str, Any]]) -> dict[str, Any]:
    """Envelope for pydantic errors: the first one names the field, all are in details."""
    details = [pydantic_detail(e) for e in errors]
    if not details:
        return error_body("invalid_input", "invalid request", "body", [])
    first = details[0]
    return error_body("invalid_input", f"{first['field']}: {first['message']}", first["field"],
                      details)


def unparsable_body(cause: BaseException) -> str:
    """What was wrong with a JSON body the parser could not read (FastAPI says only "There
    was an error parsing the body")."""
    if isinstance(cause, UnicodeDecodeError):
        got = f"bytes that are not UTF-8 ({cause.reason} at byte {cause.start})"
    elif isinstance(cause, RecursionError):
        got = "arrays or objects nested too deep to parse"
    elif isinstance(cause, ValueError) and "digits" in str(cause):
        got = "an integer with too many digits to parse"
    else:
        got = f"{type(cause).__name__}: {str(cause)[:200]}"
    return f"expected a JSON body in UTF-8, got {got}"


def unreadable_body(raw: bytes, errors: Sequence[Mapping[str, Any]]) -> ServiceError | None:
    """The 400 every JSON route gives a body that is no JSON in UTF-8 at all, for ``raw``
    that pydantic's own JSON parser refused with ``errors`` (its messages differ from
    Python's); None for JSON with a syntax error or a wrong value (422)."""
    if not errors or errors[0].get("type") != "json_invalid":
        return None
    cause: BaseException
    try:
        raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        cause = exc
    else:
        message = str(errors[0].get("msg", ""))
        if "recursion limit" in message:
            cause = RecursionError()
        elif "number out of range" in message:  # an integer past the 4,300 digits Python reads
            cause = ValueError("too many digits")
        else:
            return None
    return ServiceError(unparsable_body(cause), field="body")


#: The methods a 405 answer may name.
_METHODS = ("DELETE", "GET", "HEAD", "PATCH", "POST", "PUT")


def _allowed_methods(request: Request) -> str:
    """Every method the request's path takes, sorted and comma separated: the router's own
    405 names only the first route that matched the path (GET of a path also deleted).
    Asked of the routes one method at a time through their public ``matches``: included
    routers keep their routes to themselves."""
    allowed = []
    for method in _METHODS:
        scope = {**request.scope, "method": method}
        if any(route.matches(scope)[0] == Match.FULL for route in request.app.router.routes):
            allowed.append(method)
    return ", ".join(allowed)


def install_error_handlers(app: FastAPI) -> None:
    """Register the handlers; after this no expected error leaves as HTML or a 500."""

    @app.exception_handler(ServiceError)
    async def _service_error(_request: Request, exc: ServiceError) -> JSONResponse:
        status, kind = http_status(exc)
        headers = {"Retry-After": str(exc.retry_after)} if isinstance(exc, Busy) else None
        return JSONResponse(error_body(kind, exc.message, exc.field), status, headers=headers)

    @app.exception_handler(CanalError)
    async def _canal_error(_request: Request, exc: CanalError) -> JSONResponse:
        status, kind = http_status(exc)
        return JSONResponse(error_body(kind, exc.message, exc.field), status)

    @app.exception_handler(RequestValidationError)
    async def _validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = list(exc.errors())
        content_type = request.headers.get("content-type")
        if not is_json_content_type(content_type) and any(
                tuple(e.get("loc", ()))[:1] == ("body",) for e in errors):
            return await _service_error(request, unsupported_json_body(content_type))
        return JSONResponse(validation_error_body(errors), 422)

    @app.exception_handler(StarletteHTTPException)
    async def _http_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        field = "body" if exc.status_code in (400, 413) else None
        if exc.status_code == 401:
            field = "Authorization"
        message = str(exc.detail)
        if exc.status_code == 400 and exc.__cause__ is not None:
            message = unparsable_body(exc.__cause__)
        # The router's own 404 and 405 say only "Not Found" / "Method Not Allowed": name the
        # request's method and path, and what the path takes.
        path = request.url.path[:200]
        if exc.status_code == 404 and exc.detail == "Not Found":
            field, message = "path", f"no route {request.method} {path} (the routes are listed at /docs)"
        elif exc.status_code == 405:
            allow = _allowed_methods(request) or (exc.headers or {}).get("Allow", "")
            field = "method"
            message = f"{request.method} is not allowed on {path}" + (f"; allowed: {allow}" if allow else "")
            if allow:
                exc.headers = {**(exc.headers or {}), "Allow": allow}
        body = error_body(_HTTP_TYPES.get(exc.status_code, "http_error"), message, field)
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
