"""Pure ASGI middleware: unexpected-error net, body size limit, bearer token, request metrics,
a newline after every JSON answer.

Pure ASGI rather than ``BaseHTTPMiddleware`` because the size limit has to wrap
``receive`` (to stop a chunked upload mid-stream) and because it costs less per request.
"""

from __future__ import annotations

import hmac
import json
import logging
import time
from typing import Any

from starlette.requests import ClientDisconnect
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from .errors import PayloadTooLarge, error_body
from .metrics import Metrics

log = logging.getLogger("canal_service")


async def _send_json(send: Send, status: int, body: dict[str, Any],
                     headers: list[tuple[bytes, bytes]] | None = None) -> None:
    payload = json.dumps(body).encode()
    await send({
        "type": "http.response.start",
        "status": status,
        "headers": [(b"content-type", b"application/json"),
                    (b"content-length", str(len(payload)).encode()), *(headers or [])],
    })
    await send({"type": "http.response.body", "body": payload})


class JsonNewline:
    """End every ``application/json`` answer with a newline, as a terminal expects.

    ``curl URL`` otherwise leaves the shell prompt glued to the closing brace. JSON allows
    trailing whitespace, so every parser reads the same document; the Content-Length is
    grown by the one byte.
    """

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        is_json = False

        async def newline_send(message: Message) -> None:
            nonlocal is_json
            if message["type"] == "http.response.start":
                headers = list(message.get("headers", []))
                is_json = any(k.lower() == b"content-type"
                              and v.split(b";")[0].strip().lower() == b"application/json"
                              for k, v in headers)
                if is_json:
                    message = {**message, "headers": [
                        (k, str(int(v) + 1).encode()) if k.lower() == b"content-length" else (k, v)
                        for k, v in headers]}
            elif (message["type"] == "http.response.body" and is_json
                  and not message.get("more_body", False)):
                message = {**message, "body": message.get("body", b"") + b"\n"}
                is_json = False
            await send(message)

        await self.app(scope, receive, newline_send)


class CatchUnexpected:
    """Answer any exception that escaped the routes with a JSON 500, and swallow it.

    Starlette's own ``Exception`` handler re-raises after answering, and uvicorn then closes
    the connection ("Exception in ASGI application"); a client on keep-alive sees a reset.
    Here the traceback is logged once and the connection stays usable.
    """

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        started = False

        async def tracking_send(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, receive, tracking_send)
        except ClientDisconnect:
            # Not a fault of the service: the client left before its request was read.
            # Nobody is listening for an answer.
            log.info("client went away during %s %s", scope.get("method"), scope.get("path"))
        except Exception as exc:
            log.exception("unhandled error on %s %s", scope.get("method"), scope.get("path"),
                          exc_info=exc)
            if started:
                # Half a response is on the wire: only closing the connection is honest.
                raise
            await _send_json(send, 500, error_body("internal", "internal server error"))


class BodySizeLimit:
    """Answer 413 when a body is, or turns out to be, larger than ``limit`` bytes."""

    def __init__(self, app: ASGIApp, limit: int) -> None:
        self.app = app
        self.limit = limit

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        for name, value in scope["headers"]:
            if name == b"content-length":
                try:
                    declared = int(value)
                except ValueError:
                    declared = -1
                if declared > self.limit:
                    await _send_json(send, 413, self._body())
                    return
        received = 0
        started = False

        async def limited_receive() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.limit:
                    raise PayloadTooLarge(self.limit)
            return message

        async def tracking_send(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, limited_receive, tracking_send)
        except PayloadTooLarge:
            # Reached only when the body was read outside a route (the routes' handler
            # turns it into the same 413 itself).
            if not started:
                await _send_json(send, 413, self._body())

    def _body(self) -> dict[str, Any]:
        return error_body("payload_too_large",
                          f"request body larger than the limit of {self.limit} bytes", "body")


class EncodedSlash:
    """Answer 422 to a path holding an encoded '/' (``%2F``).

    Routing sees the decoded path, so a skill named ``a%2Fdemonstrations%2F7`` would reach
    demonstration 7 of skill ``a`` (and ``DELETE`` it) instead of being refused as a name. No
    path segment of the API holds a '/', so such a path is nobody's.
    """

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        raw = scope.get("raw_path") if scope["type"] == "http" else None
        if raw is not None:
            at = raw.lower().find(b"%2f")
            if at >= 0:
                shown = raw[:200].decode("latin-1")
                await _send_json(send, 422, error_body(
                    "invalid_input", "expected a path whose parts hold no '/' (a skill name has "
                    f"none), got {raw[at:at + 3].decode('latin-1')} (an encoded '/') in {shown!r}",
                    "path"))
                return
        await self.app(scope, receive, send)


class BearerAuth:
    """Require ``Authorization: Bearer <token>`` everywhere except the open paths. The scheme
    is taken in any case (``bearer``, RFC 9110 section 11.1), the token exactly."""

    def __init__(self, app: ASGIApp, token: str, open_paths: frozenset[str]) -> None:
        self.app = app
        self.expected = token.encode()
        self.open_paths = open_paths

    def _authorized(self, given: bytes) -> bool:
        scheme, _, credentials = given.partition(b" ")
        # compared even under another scheme: the time taken says nothing about the token
        same = hmac.compare_digest(credentials.lstrip(b" "), self.expected)
        return same and scheme.lower() == b"bearer"

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        given = next((v for k, v in scope["headers"] if k == b"authorization"), b"")
        authorized = self._authorized(given)
        if scope["path"] in self.open_paths:
            # an open path answers everyone, and says less to who has no token
            scope.setdefault("state", {})["authorized"] = authorized
            await self.app(scope, receive, send)
            return
        if not authorized:
            await _send_json(
                send, 401,
                error_body("unauthorized", "missing or wrong bearer token", "Authorization"),
                [(b"www-authenticate", b"Bearer")],
            )
            return
        await self.app(scope, receive, send)


class RequestMetrics:
    """Count and time requests by route template (not raw path, to bound label cardinality)."""

    def __init__(self, app: ASGIApp, metrics: Metrics) -> None:
        self.app = app
        self.metrics = metrics

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        status = 500
        start = time.perf_counter()

        async def recording_send(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
            await send(message)

        self.metrics.in_flight.inc()
        try:
            await self.app(scope, receive, recording_send)
        finally:
            self.metrics.in_flight.dec()
            route = scope.get("route")
            template = getattr(route, "path", None) or "unmatched"
            method = scope.get("method", "")
            self.metrics.latency.labels(method, template).observe(time.perf_counter() - start)
            self.metrics.requests.labels(method, template, str(status)).inc()
