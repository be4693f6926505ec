"""``python -m canal_service``: serve the API with uvicorn.

Flags override ``CANAL_*`` environment variables, which override the embedded defaults
(127.0.0.1:8000, SQLite and recordings under ./data).

The port is bound and ``/healthz`` answers at once (503 ``{"status": "starting"}``) while the
application loads behind it: the scientific stack, migrations, the recorder and the Zenoh
bridge take seconds; then ``/healthz`` says ``ok`` and every route is served. Requests that
arrive meanwhile wait for it. One log line says where REST and Zenoh listen.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import sys
import time
from collections.abc import Awaitable, Callable, MutableMapping, Sequence
from contextlib import AbstractAsyncContextManager
from pathlib import Path
from typing import Any

from .core.config import Settings

log = logging.getLogger("uvicorn.error")  # configured by uvicorn: our lines beside its own
READY_WAIT_S = 300.0

Scope = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[MutableMapping[str, Any]]]
Send = Callable[[MutableMapping[str, Any]], Awaitable[None]]


def build_parser() -> argparse.ArgumentParser:
    """The command line; every flag also exists as a CANAL_* variable."""
    p = argparse.ArgumentParser(prog="python -m canal_service", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--host", help="interface to bind (CANAL_HOST, default 127.0.0.1)")
    p.add_argument("--port", type=int, help="port (CANAL_PORT, default 8000)")
    p.add_argument("--data-dir", type=Path, help="data folder (CANAL_DATA_DIR, default ./data)")
    p.add_argument("--database-url",
                   help="SQLAlchemy URL, e.g. postgresql+psycopg://user@host/db "
                        "(CANAL_DATABASE_URL, default SQLite in the data folder)")
    p.add_argument("--recordings-dir", type=Path,
                   help="recordings folder (CANAL_RECORDINGS_DIR, default DATA_DIR/recordings)")
    p.add_argument("--no-recordings", action="store_true",
                   help="turn the recorder off (CANAL_RECORDINGS_ENABLED=false)")
    p.add_argument("--token", help="require 'Authorization: Bearer TOKEN' (CANAL_TOKEN)")
    p.add_argument("--cors-origin", action="append", dest="cors_origins",
                   help="allow this CORS origin; repeatable (CANAL_CORS_ORIGINS, JSON list)")
    p.add_argument("--max-body-bytes", type=int,
                   help="request size limit (CANAL_MAX_BODY_BYTES, default 64 MiB)")
    p.add_argument("--log-level", help="uvicorn log level (CANAL_LOG_LEVEL, default info)")
    add_zenoh_arguments(p)
    return p


def add_zenoh_arguments(p: argparse.ArgumentParser) -> None:
    """The live bridge's flags (shared with ``python -m canal_service.bridge``)."""
    g = p.add_argument_group("live bridge (Zenoh)")
    g.add_argument("--zenoh-config", type=Path, metavar="FILE",
                   help="a standard Zenoh JSON5 config file, used unchanged (CANAL_ZENOH_CONFIG)")
    g.add_argument("--zenoh-listen", action="append", metavar="ENDPOINT",
                   help="listen endpoint; repeatable (CANAL_ZENOH_LISTEN, JSON list, "
                        "default tcp/127.0.0.1:7447)")
    g.add_argument("--zenoh-connect", action="append", metavar="ENDPOINT",
                   help="connect endpoint, e.g. a zenohd router; repeatable (CANAL_ZENOH_CONNECT)")
    g.add_argument("--zenoh-prefix", help="key expression prefix (CANAL_ZENOH_PREFIX, default canal)")
    g.add_argument("--zenoh-processes", type=int, metavar="N",
                   help="bridge processes to start, sharing the robots (CANAL_ZENOH_PROCESSES, "
                        "default 1; 0 = inside the service process)")
    g.add_argument("--no-zenoh", action="store_true",
                   help="do not run the live bridge (CANAL_ZENOH_ENABLED=false)")


def settings_from_args(argv: Sequence[str] | None = None) -> Settings:
    """Settings from the environment, with the given flags on top."""
    args = build_parser().parse_args(argv)
    overrides: dict[str, Any] = {
        key: value for key, value in vars(args).items()
        if value is not None and key not in ("no_recordings", "no_zenoh")
    }
    if args.no_recordings:
        overrides["recordings_enabled"] = False
    if args.no_zenoh:
        overrides["zenoh_enabled"] = False
    return Settings(**overrides)


def endpoints_line(settings: Settings) -> str:
    """One line: where REST and Zenoh listen."""
    host = f"[{settings.host}]" if ":" in settings.host else settings.host
    rest = f"REST http://{host}:{settings.port}"
    if not settings.zenoh_enabled:
        zenoh = "Zenoh off (--no-zenoh)"
    elif settings.zenoh_config is not None:
        zenoh = f"Zenoh as configured in {settings.zenoh_config} (prefix {settings.zenoh_prefix})"
    else:
        where = ", ".join(settings.zenoh_listen) or "no listen endpoint"
        if settings.zenoh_connect:
            where += f"; connects to {', '.join(settings.zenoh_connect)}"
        zenoh = f"Zenoh {where} (prefix {settings.zenoh_prefix})"
    return f"canal service: {rest}, {zenoh}"


class Bootstrap:
    """The ASGI app uvicorn serves: answers ``/healthz`` while the real app loads, then hands
    every request to it (its lifespan, middleware and routes unchanged)."""

    def __init__(self, settings: Settings, build: Callable[[Settings], Any] | None = None) -> None:
        self.settings = settings
        self.build = build
        self.app: Any = None
        self.error: BaseException | None = None
        self.server: Any = None  # uvicorn.Server, told to exit when loading fails
        self._ready: asyncio.Event | None = None
        self._lifespan: AbstractAsyncContextManager[Any] | None = None
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
        from . import __version__

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


def _create_app(settings: Settings) -> Any:
    """``create_app`` imported here, in the loading thread: its imports take seconds."""
    from .app import create_app

    return create_app(settings)


def main(argv: Sequence[str] | None = None) -> None:
    """Build the app from flags and environment and serve it until interrupted."""
    import uvicorn

    settings = settings_from_args(argv)
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    bootstrap = Bootstrap(settings)
    server = uvicorn.Server(uvicorn.Config(bootstrap, host=settings.host, port=settings.port,
                                           log_level=settings.log_level, proxy_headers=False))
    bootstrap.server = server
    log.setLevel(logging.INFO)
    print(endpoints_line(settings), file=sys.stderr, flush=True)
    server.run()
    if bootstrap.error is not None:
        sys.exit(f"canal service: failed to start: {type(bootstrap.error).__name__}: "
                 f"{bootstrap.error}")


if __name__ == "__main__":
    main()
