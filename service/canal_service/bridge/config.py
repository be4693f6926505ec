"""How a bridge joins Zenoh and behaves under load: options, the session config, access report."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import orjson
import zenoh

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
    """

    prefix: str = "canal"
    listen: tuple[str, ...] = ("tcp/127.0.0.1:7447",)
    connect: tuple[str, ...] = ()
    config_file: Path | None = None
    queue_capacity: int = 4096
    coalesce_backlog: int = 16
    idle_s: float = 30.0
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
            refresh_s=settings.zenoh_refresh_s, lookahead=settings.zenoh_lookahead,
            preload_max=settings.zenoh_preload_max,
            preload_keep_s=settings.zenoh_preload_keep_s,
            record_hz=float(settings.recordings_live_hz) if settings.recordings_enabled
            else None,
        )
        values.update(overrides)
        return cls(**values)


def zenoh_config(options: BridgeOptions) -> zenoh.Config:
    """The session config: the user's file unchanged, else peer mode on the given endpoints
    with multicast scouting off."""
    if options.config_file is not None:
        return zenoh.Config.from_file(str(options.config_file))
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("listen/endpoints", orjson.dumps(list(options.listen)).decode())
    config.insert_json5("connect/endpoints", orjson.dumps(list(options.connect)).decode())
    return config


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


__all__ = ["BridgeOptions", "access_of", "config_value", "per_mode", "shard_of", "zenoh_config"]
