"""``python -m canal_service``: serve the API with uvicorn.

Flags override ``CANAL_*`` environment variables, which override the embedded defaults
(127.0.0.1:8000, SQLite and recordings under ./data).
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import uvicorn

from .app import create_app
from .core.config import Settings


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


def main(argv: Sequence[str] | None = None) -> None:
    """Build the app from flags and environment and serve it until interrupted."""
    settings = settings_from_args(argv)
    app = create_app(settings)
    uvicorn.run(app, host=settings.host, port=settings.port, log_level=settings.log_level,
                proxy_headers=False)


if __name__ == "__main__":
    main()
