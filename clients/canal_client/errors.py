"""Errors raised by the Canal client.

Everything raised on purpose is a :class:`CanalClientError`:

- :class:`ApiError` (and one subclass per HTTP status) when the service answered with an error.
  It carries the service's JSON error fields ``type``, ``field`` and ``message``
  (``{"error": {"type", "field", "message"}}``) and the HTTP ``status``;
- :class:`ConnectionFailedError` when the service cannot be reached (the message names the URL);
- :class:`RequestTimeoutError` when it was reached but did not answer in time;
- :class:`ArgumentError` (also a ``ValueError``) when an argument is refused before anything
  is sent (the message names it, what was expected and what came).

``str(error)`` is the service's message, followed by ``(field: ...)`` when a field is named.
"""

from __future__ import annotations

import contextlib
import json
from typing import Any

from pydantic import ValidationError

from canal_protocol.schemas import ErrorDetail, ErrorResponse

__all__ = [
    "ApiError",
    "ArgumentError",
    "BadRequestError",
    "CanalClientError",
    "ConflictError",
    "ConnectionFailedError",
    "DegenerateCanalError",
    "InvalidInputError",
    "NotFoundError",
    "OutsideCanalError",
    "PayloadTooLargeError",
    "RequestTimeoutError",
    "ServerError",
    "UnauthorizedError",
    "UnsupportedMediaTypeError",
    "error_from_response",
]


class CanalClientError(Exception):
    """Base of every error the client raises on purpose."""


class ArgumentError(CanalClientError, ValueError):
    """An argument refused before anything is sent: not numbers where numbers go, the wrong
    shape, a choice that does not exist. ``argument`` names it."""

    def __init__(self, argument: str, expected: str, got: str) -> None:
        self.argument = argument
        self.expected = expected
        self.got = got
        super().__init__(f"{argument}: expected {expected}, got {got}")


class ConnectionFailedError(CanalClientError):
    """The service could not be reached (refused, unknown host, connect timeout, ...)."""

    def __init__(self, url: str, reason: str = "") -> None:
        self.url = url
        self.reason = reason
        message = f"cannot reach the Canal service at {url}"
        super().__init__(f"{message}: {reason}" if reason else message)


class RequestTimeoutError(CanalClientError):
    """The service was reached but did not answer within the client's timeout."""

    def __init__(self, url: str, timeout: float | None) -> None:
        self.url = url
        self.timeout = timeout
        super().__init__(f"the Canal service at {url} did not answer within {timeout} s")


class ApiError(CanalClientError):
    """The service answered with an error status.

    Attributes:
        status: HTTP status code.
        type: the service's machine-readable kind (``not_found``, ``invalid_input``, ...), or
            ``http_<status>`` when the body was not the service's JSON error shape.
        field: the request part at fault (``positions[3]``, ``name``, ...) or ``None``.
        message: the service's human-readable message (or the raw body text).
        details: per-field problems for request validation errors, else ``None``.
    """

    def __init__(self, status: int, type: str, message: str, field: str | None = None,
                 details: list[dict[str, Any]] | None = None) -> None:
        self.status = status
        self.type = type
        self.message = message
        self.field = field
        self.details = details
        super().__init__(status, type, message, field)

    def __str__(self) -> str:
        if self.field:
            return f"{self.message} (field: {self.field})"
        return self.message

    def __repr__(self) -> str:
        return (f"{type(self).__name__}(status={self.status}, type={self.type!r}, "
                f"field={self.field!r}, message={self.message!r})")


class BadRequestError(ApiError):
    """400: e.g. ``bad_upload``, bytes that are not the claimed CSV/NPY/MCAP."""


class UnauthorizedError(ApiError):
    """401: the service needs a token and got none or a wrong one."""


class NotFoundError(ApiError):
    """404: unknown skill, demonstration or model version; ``disabled`` recordings."""


class ConflictError(ApiError):
    """409: duplicate skill name, fit with too few demonstrations, nothing fitted yet."""


class PayloadTooLargeError(ApiError):
    """413: the body is over the service's ``max_body_bytes``."""


class UnsupportedMediaTypeError(ApiError):
    """415: a body in a content type the route does not take."""


class InvalidInputError(ApiError):
    """422: content errors (``invalid_input``), and canal_core refusing the data
    (``degenerate_canal``, ``outside_canal``; see the two subclasses)."""


class DegenerateCanalError(InvalidInputError):
    """422 ``degenerate_canal``: the demonstrations do not span a usable canal."""


class OutsideCanalError(InvalidInputError):
    """422 ``outside_canal``: a start outside the canal with ``outside="raise"``."""


class ServerError(ApiError):
    """5xx: a failure inside the service (or a proxy in front of it)."""


_BY_STATUS: dict[int, type[ApiError]] = {
    400: BadRequestError,
    401: UnauthorizedError,
    404: NotFoundError,
    409: ConflictError,
    413: PayloadTooLargeError,
    415: UnsupportedMediaTypeError,
    422: InvalidInputError,
}
_BY_TYPE: dict[str, type[ApiError]] = {
    "degenerate_canal": DegenerateCanalError,
    "outside_canal": OutsideCanalError,
}


def error_from_response(status: int, body: bytes | str) -> ApiError:
    """The :class:`ApiError` subclass for an error answer, read as the protocol's
    :class:`~canal_protocol.schemas.ErrorResponse`; any other body (a proxy's HTML page, plain
    text, a bare FastAPI ``detail``) becomes the message."""
    text = body.decode("utf-8", "replace") if isinstance(body, bytes) else body
    error_type, field, details = f"http_{status}", None, None
    message = text.strip() or f"HTTP {status}"
    try:
        error: ErrorDetail | None = ErrorResponse.model_validate_json(text).error
    except ValidationError:
        error = None
    if error is not None:
        message, error_type, field, details = (error.message, error.type or error_type,
                                               error.field, error.details)
    else:
        with contextlib.suppress(ValueError):
            parsed = json.loads(text)
            if isinstance(parsed, dict) and isinstance(parsed.get("detail"), str):
                message = parsed["detail"]  # a plain FastAPI/Starlette error
    if len(message) > 2000:
        message = message[:2000] + "..."
    cls: type[ApiError]
    if status >= 500:
        cls = ServerError
    else:
        cls = _BY_TYPE.get(error_type) or _BY_STATUS.get(status, ApiError)
    return cls(status, error_type, message, field, details)
