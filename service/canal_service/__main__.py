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
    return p


def settings_from_args(argv: Sequence[str] | None = None) -> Settings:
    """Settings from the environment, with the given flags on top."""
    args = build_parser().parse_args(argv)
    overrides: dict[str, Any] = {
        key: value for key, value in vars(args).items()
        if value is not None and key != "no_recordings"
    }
    if args.no_recordings:
        overrides["recordings_enabled"] = False
    return Settings(**overrides)


def main(argv: Sequence[str] | None = None) -> None:
    """Build the app from flags and environment and serve it until interrupted."""
    settings = settings_from_args(argv)
    app = create_app(settings)
    uvicorn.run(app, host=settings.host, port=settings.port, log_level=settings.log_level,
                proxy_headers=False)


if __name__ == "__main__":
    main()
