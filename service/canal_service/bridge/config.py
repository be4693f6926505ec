"""How a bridge joins Zenoh and behaves under load: options, the session config, access report."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import orjson
import zenoh

from canal_protocol.credentials import insert_credentials, users_file_text
from canal_protocol.keys import shard_of

#: From this many shards on, ``shard_subscribe="auto"`` subscribes by key (see BridgeOptions).
AUTO_KEYS_FROM = 4


@dataclass(frozen=True)
class BridgeOptions:
    """How the bridge joins Zenoh and how it behaves under load.

    ``shard``/``shards``: this bridge answers the streams :func:`canal_protocol.keys.shard_of`
    gives to ``shard`` (``shards`` = 1: every stream). ``shard_subscribe`` says what a sharded
    bridge subscribes to: ``"keys"``, only its robots' pose keys
    (:func:`canal_protocol.keys.shard_pose_keys`, Zenoh filters; the several subscribers feed
    the worker through a Python callback, ~3.5x the CPU per received pose of a FIFO channel
    with zenoh-python 1.10, measured); ``"all"``, every pose through one FIFO channel,
    others' poses dropped after a set lookup; ``"auto"``, keys from 4 shards on (where
    receiving 1/K of the poses at the callback's cost beats receiving all of them).

    ``record_hz``: None, the bridge sends nothing to record; else every ``record_interval_s``
    it puts the poses the recording wants (at most ``record_hz`` per stream and second, 0:
    all; plus every status/inside/done flip) and per-stream counts on
    :func:`canal_protocol.keys.recorder_key` (see :mod:`.posepath`).

    ``preload_max``: how many skills without live streams the model table holds ready, so
    that a skill's first pose finds its model built instead of loading it on the worker: at
    start the most recently fitted skills (in a background thread), and each skill whose fit
    notice arrives; 0: a model is loaded at its skill's first pose. ``preload_keep_s``: how
    long such a model stays after it was loaded or its skill's last stream went away (the
    housekeeper re-checks its version every ``refresh_s`` meanwhile).

    ``token``: the service's bearer token. Unless ``zenoh_open``, it closes the live path
    too: the session built here admits only Zenoh sessions that present the token's
    credentials (:mod:`canal_protocol.credentials`; the users file is written to
    ``users_file``), and a ``config_file`` that leaves the path open is refused
    (:class:`LivePathOpenError`).
    """

    prefix: str = "canal"
    listen: tuple[str, ...] = ("tcp/127.0.0.1:7447",)
    connect: tuple[str, ...] = ()
    config_file: Path | None = None
    queue_capacity: int = 4096
    coalesce_backlog: int = 16
    idle_s: float = 30.0
    max_streams: int = 4096
    refresh_s: float = 2.0
    lookahead: int = 2
    shard: int = 0
    shards: int = 1
    negative_ttl_s: float = 10.0
    negative_max: int = 16384
    shard_subscribe: str = "auto"  # "auto" | "keys" | "all"
    record_hz: float | None = None  # None: no recording batches; 0: every pose
    record_interval_s: float = 0.1
    preload_max: int = 64
    preload_keep_s: float = 600.0
    #: the most poses a capture (a demonstration, a correction, a steered run) holds: a
    #: demonstration the REST API would refuse is not stored live either
    #: (``CANAL_UPLOAD_MAX_POINTS``), and a capture left open while poses come stays bounded
    capture_max: int = 200_000
    token: str | None = field(default=None, repr=False)
    zenoh_open: bool = False
    users_file: Path | None = None

    @property
    def closed_by_token(self) -> bool:
        """Whether the token closes the live path (a token, and not ``zenoh_open``)."""
        return bool(self.token) and not self.zenoh_open

    def subscribes_by_key(self) -> bool:
        """Whether this bridge subscribes only to its own robots' pose keys."""
        if self.shards <= 1:
            return False
        if self.shard_subscribe not in ("auto", "keys", "all"):
            raise ValueError("expected shard_subscribe 'auto', 'keys' or 'all', "
                             f"got {self.shard_subscribe!r}")
        return self.shard_subscribe == "keys" or (self.shard_subscribe == "auto"
                                                  and self.shards >= AUTO_KEYS_FROM)

    @classmethod
    def from_settings(cls, settings: Any, **overrides: Any) -> BridgeOptions:
        """Options from the service's Settings (``zenoh_*`` fields)."""
        values: dict[str, Any] = dict(
            prefix=settings.zenoh_prefix, listen=tuple(settings.zenoh_listen),
            connect=tuple(settings.zenoh_connect), config_file=settings.zenoh_config,
            queue_capacity=settings.zenoh_queue_capacity,
            coalesce_backlog=settings.zenoh_coalesce_backlog, idle_s=settings.zenoh_idle_s,
            max_streams=settings.zenoh_max_streams,
            refresh_s=settings.zenoh_refresh_s, lookahead=settings.zenoh_lookahead,
            preload_max=settings.zenoh_preload_max,
            preload_keep_s=settings.zenoh_preload_keep_s,
            capture_max=settings.upload_max_points,
            record_hz=float(settings.recordings_live_hz) if settings.recordings_enabled
            else None,
            token=None if settings.token is None else settings.token.get_secret_value(),
            zenoh_open=settings.zenoh_open,
            users_file=Path(settings.data_dir) / USERS_FILE,
        )
        values.update(overrides)
        return cls(**values)


class LivePathOpenError(ValueError):
    """The service has a token but its Zenoh config file leaves the live path open."""


def zenoh_config(options: BridgeOptions) -> zenoh.Config:
    """The session config: the user's file unchanged, else peer mode on the given endpoints
    with multicast scouting off, closed by the token's credentials when there is one (see
    :class:`BridgeOptions`)."""
    if options.config_file is not None:
        config = zenoh.Config.from_file(str(options.config_file))
        if options.closed_by_token and access_of(config)["access"] == "open":
            raise LivePathOpenError(
                f"the service has a token but {options.config_file} leaves the live path open "
                "to anyone who reaches its port (no user/password, no mutual TLS): add "
                "authentication to it (docker/zenoh/canal-secure.json5), or pass --zenoh-open "
                "(CANAL_ZENOH_OPEN=true) to leave it open on purpose")
        return config
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("listen/endpoints", orjson.dumps(list(options.listen)).decode())
    config.insert_json5("connect/endpoints", orjson.dumps(list(options.connect)).decode())
    if options.closed_by_token:
        assert options.token is not None and options.users_file is not None
        insert_credentials(config, options.token,
                           str(written_users_file(options.users_file, options.token)))
    return config


#: The users file a token-closed live path admits (in the data folder, mode 0600).
USERS_FILE = "zenoh-users.txt"


def written_users_file(path: Path, token: str) -> Path:
    """``path`` holding the token's Zenoh users dictionary, readable by this user only
    (written whole under a temporary name, then renamed: bridges start side by side)."""
    text = users_file_text(token).encode()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    try:
        os.write(fd, text)
    finally:
        os.close(fd)
    os.replace(tmp, path)
    return path


def access_of(config: zenoh.Config) -> dict[str, Any]:
    """How the live path is closed: ``open`` or ``authenticated`` (user/password or mutual
    TLS), with TLS and the access-control policy reported beside it."""
    user = config_value(config, "transport/auth/usrpwd/user")
    users = config_value(config, "transport/auth/usrpwd/dictionary_file")
    mtls = config_value(config, "transport/link/tls/enable_mtls")
    acl = config_value(config, "access_control/enabled")
    default = config_value(config, "access_control/default_permission")
    mode = config_value(config, "mode")
    endpoints = [*per_mode(config_value(config, "listen/endpoints"), mode),
                 *per_mode(config_value(config, "connect/endpoints"), mode)]
    tls = bool(endpoints) and all(str(e).startswith(("tls/", "quic/")) for e in endpoints)
    authenticated = bool(users or user or (mtls and tls))
    return {"access": "authenticated" if authenticated else "open", "tls": tls,
            "acl": bool(acl), "acl_default": default if acl else None}


def config_value(config: zenoh.Config, key: str) -> Any:
    """A value of the config as Python (``get_json`` answers JSON text)."""
    try:
        return orjson.loads(config.get_json(key))
    except Exception:
        return None


def per_mode(endpoints: Any, mode: Any) -> list[str]:
    """Endpoints as a list: Zenoh configs may give one list or a list per mode."""
    if isinstance(endpoints, dict):
        endpoints = endpoints.get(str(mode) if mode else "peer", [])
    return [str(e) for e in endpoints] if isinstance(endpoints, list) else []


__all__ = ["USERS_FILE", "BridgeOptions", "LivePathOpenError", "access_of", "config_value",
           "per_mode", "shard_of", "written_users_file", "zenoh_config"]
