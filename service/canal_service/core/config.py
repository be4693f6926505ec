"""Service settings, read from ``CANAL_*`` environment variables or passed in directly.

The defaults are the embedded deployment: loopback only, a SQLite file and a recordings
folder inside one local data folder, no token, no CORS. A multi-instance deployment points
``CANAL_DATABASE_URL`` at PostgreSQL and keeps everything else.

The command line (``python -m canal_service``, ``canal serve``) is generated from these
fields: each is a ``--kebab-case`` flag, its help is the field's description, and a
:class:`Flag` in the annotation spells the few flags that differ. A new setting is one field.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import Field, SecretStr, field_validator
from pydantic_core import PydanticCustomError
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

from canal_protocol import keys as keyspace
from canal_protocol.credentials import token_problem

DEFAULT_MAX_BODY_BYTES = 64 * 1024 * 1024
# Kept equal to canal_service.uploads' defaults (imported there would make config import numpy).
DEFAULT_UPLOAD_MAX_POINTS = 200_000
DEFAULT_UPLOAD_MAX_DECOMPRESSED_BYTES = 64 * 1024 * 1024
DEFAULT_UPLOAD_MAX_SECONDS = 10.0


@dataclass(frozen=True)
class Flag:
    """A setting's command-line spelling, when it is not ``--field-name``.

    ``name`` replaces the flag (a bool flag sets the opposite of the field's default, e.g.
    ``--no-recordings`` for ``recordings_enabled``; a list flag is given once per item, e.g.
    ``--cors-origin``); ``metavar`` names the value in ``--help``.
    """

    name: str | None = None
    metavar: str | None = None


class Settings(BaseSettings):
    """Everything the service can be told at start."""

    model_config = SettingsConfigDict(env_prefix="CANAL_", extra="ignore")

    host: str = Field("127.0.0.1", description="Interface to bind; loopback unless told otherwise.")
    port: int = Field(8000, ge=0, le=65535, description="TCP port of the REST API.")
    data_dir: Path = Field(Path("data"), description="Folder for the SQLite file and recordings.")
    database_url: Annotated[str | None, Flag(metavar="URL")] = Field(
        None, description="SQLAlchemy URL, e.g. postgresql+psycopg://user@host/db; default is "
                          "a SQLite file in the data folder."
    )
    recordings_dir: Path | None = Field(
        None, description="Where the recorder writes; default is data_dir/recordings."
    )
    recordings_enabled: Annotated[bool, Flag("--no-recordings")] = Field(
        True, description="Record demonstrations, fits, reproductions and live poses in .rrd "
                          "and .mcap files; when off, /healthz says the recorder is disabled.")
    recordings_live_hz: float = Field(
        100.0, ge=0.0,
        description="Live poses kept in the recordings per (skill, robot) stream and second; "
                    "changes of the inside/done flags are always kept; 0 keeps every pose.")
    recordings_max_robots: int = Field(
        1024, ge=1,
        description="Robots whose live poses a skill's recording draws; the poses of robots "
                    "past them are counted as dropped (robot names are the clients' choice).")
    recordings_reproductions_kept: int = Field(
        1000, ge=0, le=1_000_000,
        description="Reproductions kept in the database per skill for the recordings (the "
                    "newest; every replica's recording draws them from there); 0 keeps none, "
                    "and each replica's recording then holds only the reproductions it served.")
    recordings_view_coordinates: str = Field(
        "RIGHT_HAND_Z_UP", description="rr.ViewCoordinates of the world in the .rrd recordings.")
    token: Annotated[SecretStr | None, Flag(metavar="TOKEN")] = Field(
        None, description="When set, every route except /healthz needs 'Authorization: Bearer ...' "
                          "(visible ASCII characters, no spaces)."
    )
    cors_origins: Annotated[list[str], NoDecode, Flag("--cors-origin", metavar="ORIGIN")] = Field(
        default_factory=list, description="Allowed CORS origins; CORS stays off when empty."
    )
    max_body_bytes: int = Field(DEFAULT_MAX_BODY_BYTES, gt=0,
                                description="Request size limit in bytes (413 above).")
    upload_max_points: int = Field(
        DEFAULT_UPLOAD_MAX_POINTS, gt=0,
        description="Samples one demonstration may have, in any format (413 above).")
    upload_max_decompressed_bytes: int = Field(
        DEFAULT_UPLOAD_MAX_DECOMPRESSED_BYTES, gt=0,
        description="Bytes an MCAP upload may decompress to, counted as they are produced "
                    "(413 above).")
    upload_max_seconds: float = Field(
        DEFAULT_UPLOAD_MAX_SECONDS, gt=0,
        description="Server time one file upload may take to parse (413 above).")
    fit_max_seconds: float = Field(
        120.0, gt=0,
        description="Server time one fit may take: a fit estimated to need more is refused at "
                    "once, one running longer is stopped (422 fit_too_slow).")
    reproduce_max_seconds: float = Field(
        30.0, gt=0,
        description="Server time one reproduction request may take: one still running then "
                    "is stopped before its next start or inside a start's detour search (422 "
                    "reproduction_too_slow).")
    memory_trim_idle_s: float = Field(
        1.0, ge=0,
        description="Seconds without a request after which freed memory is handed back to "
                    "the OS (glibc malloc_trim); 0 keeps it in the process.")
    upload_workers: Annotated[int, Flag(metavar="N")] = Field(
        2, ge=1, le=64,
        description="Threads that run uploads (parse, checks, preparation, insert), apart from "
                    "the pool that serves fits and reads; uploads hold the GIL, so a few threads "
                    "taking turns beat many contending (docs/deployment.md).")
    model_cache_size: int = Field(64, ge=0, description="Fitted canals kept decoded in memory.")
    log_level: Literal["debug", "info", "warning", "error", "critical"] = Field(
        "info", description="Log level: debug, info, warning, error or critical (any case).")

    # ---- live bridge over Zenoh (docs/live.md) ----
    zenoh_enabled: Annotated[bool, Flag("--no-zenoh")] = Field(
        True, description="Run the live Zenoh bridge beside the REST API; when off, /healthz "
                          "says the bridge is disabled.")
    zenoh_listen: Annotated[list[str], NoDecode, Flag(metavar="ENDPOINT")] = Field(
        default_factory=lambda: ["tcp/127.0.0.1:7447"],
        description="Zenoh endpoints to listen on (ignored when zenoh_config is set).",
    )
    zenoh_connect: Annotated[list[str], NoDecode, Flag(metavar="ENDPOINT")] = Field(
        default_factory=list,
        description="Zenoh endpoints to connect to, e.g. a zenohd router (ignored with zenoh_config).",
    )
    zenoh_config: Annotated[Path | None, Flag(metavar="FILE")] = Field(
        None, description="A standard Zenoh JSON5 config file, used unchanged (TLS, ACL, routers)."
    )
    zenoh_open: Annotated[bool, Flag("--zenoh-open")] = Field(
        False, description="With a token: leave the live path open to anyone who reaches its "
        "port, on purpose. Without this, a token closes the live path too (Zenoh "
        "user/password derived from the token; robots pass the token), and a zenoh_config "
        "that leaves it open keeps the bridge from starting."
    )
    zenoh_prefix: str = Field("canal", min_length=1, description="First chunk of every key.")
    zenoh_queue_capacity: int = Field(4096, ge=16, description="Pose channel capacity (samples).")
    zenoh_coalesce_backlog: int = Field(
        16, ge=1, description="Per stream: above this many queued poses, answer only the newest."
    )
    zenoh_idle_s: float = Field(30.0, gt=0, description="Forget a stream after this long silent.")
    zenoh_max_streams: int = Field(
        4096, ge=1, description="Most live streams (skill, robot) one bridge process serves at "
        "once; a pose from a new robot beyond them is answered too_many_streams."
    )
    zenoh_refresh_s: float = Field(
        2.0, gt=0, description="How often the bridge re-checks each skill's latest model version."
    )
    zenoh_processes: Annotated[int, Flag(metavar="N")] = Field(
        1, ge=0, le=64, description="Bridge processes `canal serve` starts (robots shared by "
        "hash of skill/robot); 0 runs the bridge inside the service process."
    )
    zenoh_preload_max: int = Field(
        64, ge=0, description="Models the bridge holds ready for skills without live streams "
        "(at start the most recently fitted, and each skill whose fit notice arrives), so a "
        "skill's first pose finds its model ready; 0: each model is loaded at its skill's "
        "first pose (on the bridge's loader thread, the pose waits for it)."
    )
    zenoh_preload_keep_s: float = Field(
        600.0, gt=0, description="How long the bridge keeps such a model after it was loaded "
        "or its skill's last live stream went away."
    )
    zenoh_lookahead: int = Field(
        2, ge=1, description="Tracker lookahead in sections (2: the target lies beyond the next "
        "section plane, so a robot that lags behind its target still crosses it)."
    )

    @field_validator("log_level", mode="before")
    @classmethod
    def _log_level_in_any_case(cls, value: Any) -> Any:
        return value.lower() if isinstance(value, str) else value

    @field_validator("cors_origins", "zenoh_listen", "zenoh_connect", mode="before")
    @classmethod
    def _list_from_text(cls, value: Any) -> Any:
        # A variable holds a JSON list, or plain items apart by commas as one flag's value is
        # written (CANAL_ZENOH_LISTEN=tcp/127.0.0.1:7447): both are what a person types.
        if not isinstance(value, str):
            return value
        text = value.strip()
        if text.startswith("["):
            try:
                return json.loads(text)
            except ValueError:
                raise PydanticCustomError(
                    "list_text", "expected a JSON list of texts or items apart by commas, "
                    "got {got}", {"got": repr(value)}) from None
        return [item.strip() for item in text.split(",") if item.strip()]

    @field_validator("cors_origins", "zenoh_listen", "zenoh_connect")
    @classmethod
    def _no_empty_item(cls, value: list[str]) -> list[str]:
        if any(not item.strip() for item in value):
            raise PydanticCustomError("list_item", "expected no empty item, got {got}",
                                      {"got": repr(value)})
        return value

    @field_validator("zenoh_prefix")
    @classmethod
    def _plain_prefix(cls, value: str) -> str:
        return keyspace.check_prefix(value)

    @field_validator("token")
    @classmethod
    def _blank_token_is_none(cls, value: SecretStr | None) -> SecretStr | None:
        # An empty CANAL_TOKEN= in a compose file means "no token", not "the empty token".
        if value is not None and not value.get_secret_value():
            return None
        # One no client can send in a header would leave every route answering 401.
        problem = None if value is None else token_problem(value.get_secret_value())
        if problem is not None:
            raise PydanticCustomError("token", problem)
        return value

    @property
    def resolved_database_url(self) -> str:
        """The database URL, with the embedded SQLite default filled in."""
        if self.database_url:
            return self.database_url
        return f"sqlite:///{(self.data_dir / 'canal.sqlite3').resolve()}"

    @property
    def resolved_recordings_dir(self) -> Path:
        """The recordings folder, beside the database by default."""
        return self.recordings_dir if self.recordings_dir is not None else self.data_dir / "recordings"
