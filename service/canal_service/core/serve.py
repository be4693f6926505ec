"""Serving the API: the port bound at once, the application loaded behind it.

``/healthz`` answers at once (503 ``{"status": "starting"}``) while the application loads
behind it (:class:`Bootstrap`): the scientific stack, migrations, the recorder and the Zenoh
bridge take seconds; then ``/healthz`` says ``ok`` and every route is served. Requests that
arrive meanwhile wait for it. One log line says where REST and Zenoh listen.
"""

from __future__ import annotations

import asyncio
import json
import logging
import logging.handlers
import sys
import time
from collections.abc import Awaitable, Callable, MutableMapping, Sequence
from contextlib import AbstractAsyncContextManager
from queue import SimpleQueue
from typing import TYPE_CHECKING, Any

from .cli import endpoints_line, settings_from_args
from .config import Settings

if TYPE_CHECKING:  # both take seconds to import; the port is bound before they load
    import uvicorn
    from fastapi import FastAPI

log = logging.getLogger("uvicorn.error")  # configured by uvicorn: our lines beside its own
READY_WAIT_S = 300.0

Scope = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[MutableMapping[str, Any]]]
Send = Callable[[MutableMapping[str, Any]], Awaitable[None]]


class Bootstrap:
    """The ASGI app uvicorn serves: answers ``/healthz`` while the real app loads, then hands
    every request to it (its lifespan, middleware and routes unchanged)."""

    def __init__(self, settings: Settings,
                 build: Callable[[Settings], FastAPI] | None = None) -> None:
        self.settings = settings
        self.build = build
        self.app: FastAPI | None = None
        self.error: BaseException | None = None
        self.server: uvicorn.Server | None = None  # told to exit when loading fails
        self._ready: asyncio.Event | None = None
        self._lifespan: AbstractAsyncContextManager[Any] | None = None
        self._stopping = False  # lifespan shutdown asked for
        self._t0 = time.perf_counter()

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "lifespan":
            await self._run_lifespan(receive, send)
            return
        if self.app is None:
            if scope["type"] == "http" and scope.get("path") == "/healthz":
                await self._send_json(send, 503, self.starting_health())
                return
            if self._ready is not None:
                try:
                    await asyncio.wait_for(self._ready.wait(), READY_WAIT_S)
                except TimeoutError:
                    pass
            if self.app is None:
                if scope["type"] == "http":
                    await self._send_json(send, 503, {"error": {
                        "type": "unavailable", "field": None,
                        "message": "the service is still starting or failed to start; "
                                   "see GET /healthz and its log"}})
                return
        await self.app(scope, receive, send)

    def starting_health(self) -> dict[str, Any]:
        """/healthz while loading: what is known already (the bridge's endpoints, for clients
        that discover them there)."""
        from .. import __version__

        s = self.settings
        bridge: dict[str, Any] = {"status": "disabled"}
        if s.zenoh_enabled:
            bridge = {"status": "starting", "prefix": s.zenoh_prefix,
                      "listen": [] if s.zenoh_config is not None else list(s.zenoh_listen)}
        status = "failed" if self.error is not None else "starting"
        return {"status": status, "database": status, "recorder": {"status": status},
                "bridge": bridge, "version": __version__,
                "detail": None if self.error is None else f"{type(self.error).__name__}: "
                                                          f"{self.error}"}

    @staticmethod
    async def _send_json(send: Send, status: int, body: dict[str, Any]) -> None:
        data = json.dumps(body).encode()
        await send({"type": "http.response.start", "status": status,
                    "headers": [(b"content-type", b"application/json"),
                                (b"content-length", str(len(data)).encode()),
                                (b"cache-control", b"no-store")]})
        await send({"type": "http.response.body", "body": data})

    async def _run_lifespan(self, receive: Receive, send: Send) -> None:
        message = await receive()
        assert message["type"] == "lifespan.startup"
        self._ready = asyncio.Event()
        loading = asyncio.create_task(self._load())
        await send({"type": "lifespan.startup.complete"})
        message = await receive()  # lifespan.shutdown
        # Uvicorn shuts down without ever starting when it cannot bind (port in use): the
        # load, still waiting for the bind, must stop waiting or neither ends.
        self._stopping = True
        await loading
        if self._lifespan is not None:
            try:
                await self._lifespan.__aexit__(None, None, None)
            except Exception:  # shutting down: report, do not mask the exit
                log.exception("error while stopping the service")
        await send({"type": "lifespan.shutdown.complete"})

    async def _load(self) -> None:
        assert self._ready is not None
        try:
            # Bind first, import after: the imports hold the GIL for seconds.
            while self.server is not None and not self.server.started and \
                    not self.server.should_exit:
                if self._stopping:
                    return
                await asyncio.sleep(0.005)
            app = await asyncio.to_thread(self.build or _create_app, self.settings)
            lifespan = app.router.lifespan_context(app)
            await lifespan.__aenter__()
            self._lifespan, self.app = lifespan, app
            log.info("canal service ready in %.1f s (GET /healthz: ok)",
                     time.perf_counter() - self._t0)
        except Exception as exc:
            self.error = exc
            log.error("canal service failed to start: %s: %s", type(exc).__name__, exc,
                      exc_info=exc)
            if self.server is not None:
                self.server.should_exit = True
        finally:
            self._ready.set()


def _create_app(settings: Settings) -> FastAPI:
    """``create_app`` imported here, in the loading thread: its imports take seconds."""
    from ..app import create_app

    return create_app(settings)


class _Handoff(logging.handlers.QueueHandler):
    """Queues each record as it is: the writer thread's handlers format it (uvicorn's access
    formatter needs the record's ``args``, which the stock ``prepare`` flattens)."""

    def prepare(self, record: logging.LogRecord) -> logging.LogRecord:
        return record


def write_logs_off_the_loop(names: Sequence[str] = ("uvicorn", "uvicorn.access")
                            ) -> list[logging.handlers.QueueListener]:
    """Give the handlers of the loggers ``names`` to writer threads; the loggers queue.

    Uvicorn logs every request (``INFO ... "POST ... 201"``) from the event loop, and a
    stream handler formats the line and writes it there, one system call per line: on a
    terminal or a pipe that is slow, every request in flight waits for it (measured: up
    to 0.5 ms per line into a pipe, the access log alone ~1/3 of the loop's time per
    upload). Records keep their order (one queue per logger, one writer each). The
    caller stops the listeners, which writes what is queued.
    """
    listeners = []
    for name in names:
        logger = logging.getLogger(name)
        handlers = list(logger.handlers)
        if not handlers:
            continue
        queue: SimpleQueue[logging.LogRecord] = SimpleQueue()
        listener = logging.handlers.QueueListener(queue, *handlers, respect_handler_level=True)
        for handler in handlers:
            logger.removeHandler(handler)
        logger.addHandler(_Handoff(queue))
        listener.start()
        listeners.append(listener)
    return listeners


def main(argv: Sequence[str] | None = None) -> None:
    """Build the app from flags and environment and serve it until interrupted."""
    import uvicorn

    settings = settings_from_args(argv)
    try:
        settings.data_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:  # a file of that name, no permission, a read-only disk
        sys.exit(f"canal service: cannot use --data-dir {settings.data_dir}: "
                 f"{exc.strerror or exc}")
    bootstrap = Bootstrap(settings)
    server = uvicorn.Server(uvicorn.Config(bootstrap, host=settings.host, port=settings.port,
                                           log_level=settings.log_level, proxy_headers=False))
    bootstrap.server = server
    log.setLevel(logging.INFO)
    print(endpoints_line(settings), file=sys.stderr, flush=True)
    listeners = write_logs_off_the_loop()  # uvicorn.Config configured the loggers
    try:
        server.run()
    except SystemExit:
        # uvicorn exits this way when it cannot listen (the port is taken, the address is
        # not this machine's); its log line says why, not what to do.
        if server.started or bootstrap.error is not None:
            raise
        sys.exit(f"canal service: could not listen on http://{settings.host}:{settings.port} "
                 "(the error above says why): stop what uses that port, or pass --port")
    finally:
        for listener in listeners:
            listener.stop()
    if bootstrap.error is not None:
        sys.exit(f"canal service: failed to start: {type(bootstrap.error).__name__}: "
                 f"{bootstrap.error}")
