"""Live recording: batches from the bridges, heard on the recorder's own Zenoh session.

The bridges answer poses; the recorder does not listen to poses or targets. Each bridge keeps
per stream the poses the recording wants (``recordings_live_hz`` per stream, plus every
status/inside/done flip) with the targets it answered, and every ~0.1 s puts one batch with
them and the stream's count deltas on ``{prefix}/@recorder/live/{bridge}``
(:func:`canal_protocol.keys.recorder_key`, format in :mod:`canal_service.record_batches`). This
subscriber hears ~10 small messages a second per bridge instead of every pose and target:

- The batches wait in a Zenoh FIFO channel; a thread drains it every ``interval_s`` (0.2 s).
- Each stream's rows arrive as columns (:func:`canal_service.record_batches.decode_record_batch`) and
  go to the recorder as :class:`~.events.LiveRows` (numpy views of those columns, no
  per-row Python) without a second rate limit (:meth:`~.recorder.Recorder.live_rows`).
- The counts make the recording checkable: per stream, every pose a bridge handled is in
  the recording (``recorded``), on its way (``pending``), ``decimated`` by the bridge,
  ``stale`` (its skill was deleted since, and its recording with it) or ``dropped`` by the
  recorder (lost, counted); a batch that never arrived is a gap in the bridge's batch
  numbers (``lost_batches``). ROS 2 (CDR) streams are recorded like the others: the
  bridge has decoded them already.

Configured from the service settings the bridge uses (see :meth:`LiveOptions.from_settings`).
"""

from __future__ import annotations

import logging
import threading
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import orjson
import zenoh

from canal_protocol import keys as keyspace
from canal_protocol import wire
from canal_protocol.credentials import insert_credentials

from .. import record_batches
from .events import LiveRows, live_rows

log = logging.getLogger("canal_service.recording")

#: Streams listed one by one in /healthz (all of them are counted in the totals).
HEALTH_STREAMS = 64
#: Streams whose counts are kept one by one. Beyond it the settled streams (every row kept
#: recorded, dropped or stale) heard from least recently are summed into ``LiveStats.retired``:
#: totals stay exact, and robot names, which clients choose, cannot grow the table (and the
#: work of every /healthz) without bound.
MAX_COUNTED_STREAMS = 1024
_COUNTS = ("poses", "answered", "coalesced", "errors", "decimated", "kept")


@dataclass(frozen=True)
class LiveOptions:
    """Where the recorder's session connects and which keys it hears."""

    prefix: str = "canal"
    listen: tuple[str, ...] = ("tcp/127.0.0.1:7447",)
    connect: tuple[str, ...] = ()
    config_file: Path | None = None
    capacity: int = 4096  # batches waiting in the channel
    interval_s: float = 0.2  # the bridges send every 0.1 s; the writer flushes every 1 s
    #: the service's token when it closes the live path (the session presents it)
    token: str | None = field(default=None, repr=False)

    @classmethod
    def from_settings(cls, settings: Any) -> LiveOptions:
        """The bridge's Zenoh settings (``CANAL_ZENOH_*``)."""
        token = None if settings.token is None or settings.zenoh_open \
            else settings.token.get_secret_value()
        return cls(prefix=settings.zenoh_prefix, listen=tuple(settings.zenoh_listen),
                   connect=tuple(settings.zenoh_connect), config_file=settings.zenoh_config,
                   token=token)


def _local(endpoint: str) -> str:
    """A listen endpoint as a connect endpoint (any-address -> loopback)."""
    return endpoint.replace("/0.0.0.0:", "/127.0.0.1:").replace("/[::]:", "/[::1]:")


def zenoh_config(options: LiveOptions) -> zenoh.Config:
    """The recorder session's config: the bridge's, but connecting instead of listening.

    With a config file (TLS, credentials, routers) the file is used as is, except that the
    session listens nowhere and also connects to whatever the file listens on. Without one,
    a peer that connects to the bridge's listen endpoints (and its routers).
    """
    if options.config_file is not None:
        config = zenoh.Config.from_file(str(options.config_file))
        try:
            listen = orjson.loads(config.get_json("listen/endpoints"))
        except Exception:
            listen = []
        if isinstance(listen, dict):  # per-mode endpoints
            listen = [e for v in listen.values() for e in (v or [])]
        connect = orjson.loads(config.get_json("connect/endpoints") or "[]")
        if isinstance(connect, dict):
            connect = [e for v in connect.values() for e in (v or [])]
        endpoints = list(dict.fromkeys([*connect, *(_local(e) for e in listen or [])]))
        config.insert_json5("listen/endpoints", "[]")
        config.insert_json5("connect/endpoints", orjson.dumps(endpoints).decode())
    else:
        config = zenoh.Config()
        config.insert_json5("mode", '"peer"')
        config.insert_json5("scouting/multicast/enabled", "false")
        config.insert_json5("listen/endpoints", "[]")
        endpoints = list(dict.fromkeys([*options.connect, *(_local(e) for e in options.listen)]))
        config.insert_json5("connect/endpoints", orjson.dumps(endpoints).decode())
        if options.token:  # the bridge admits only the token's credentials
            insert_credentials(config, options.token)
    # The bridge may start after us: retry soon and often rather than Zenoh's 1 s -> 4 s.
    config.insert_json5("connect/retry", '{"period_init_ms": 100, "period_max_ms": 1000, '
                                         '"period_increase_factor": 2}')
    return config


def rows_of(stream: record_batches.RecordStream) -> LiveRows:
    """A batch's stream as :class:`~.events.LiveRows` (its columns read in place)."""
    m = len(stream)
    flags = np.frombuffer(stream.flags, dtype=np.uint8)
    return live_rows(stream.skill, stream.robot, np.frombuffer(stream.t_ns, dtype=np.int64),
                     np.frombuffer(stream.position, dtype=np.float64).reshape(m, stream.dim),
                     np.frombuffer(stream.orientation, dtype=np.float64).reshape(m, 4),
                     np.frombuffer(stream.target, dtype=np.float64).reshape(m, stream.dim),
                     np.frombuffer(stream.target_orientation, dtype=np.float64).reshape(m, 4),
                     np.frombuffer(stream.progress, dtype=np.float64),
                     np.frombuffer(stream.eta, dtype=np.float64),
                     np.frombuffer(stream.section, dtype=np.int32),
                     (flags & record_batches.RECORD_INSIDE) != 0, (flags & record_batches.RECORD_DONE) != 0,
                     np.frombuffer(stream.route, dtype=np.int16))


@dataclass
class LiveStats:
    """Counters of the subscriber (read by ``Recorder.health``).

    ``streams`` holds, per (skill, robot), the sums of the bridges' count deltas: ``poses``
    handled, ``answered``, ``coalesced``, ``errors``, ``decimated`` (not kept for the
    recording) and ``kept`` (rows received; ``poses == kept + decimated``).
    """

    batches: int = 0
    lost_batches: int = 0  # gaps in a bridge's batch numbers
    bad_payload: int = 0
    status: str = "starting"
    detail: str | None = None
    streams: dict[tuple[str, str], dict[str, int]] = field(
        default_factory=lambda: defaultdict(lambda: dict.fromkeys(_COUNTS, 0)))
    last_n: dict[str, int] = field(default_factory=dict)
    #: per stream, the batch it was last heard in
    heard: dict[tuple[str, str], int] = field(default_factory=dict)
    #: the summed counts (and ``recorded``, ``dropped``, ``stale``) of the streams no longer counted
    #: one by one (:data:`MAX_COUNTED_STREAMS`)
    retired: dict[str, int] = field(
        default_factory=lambda: dict.fromkeys((*_COUNTS, "recorded", "dropped", "stale"), 0))


class LiveSubscriber:
    """Feeds a :class:`~.recorder.Recorder` from the bridges' batches (module docstring)."""

    def __init__(self, recorder: Any, options: LiveOptions) -> None:
        self.recorder = recorder
        self.options = options
        self.stats = LiveStats()
        self._session: Any = None
        self._sub: Any = None
        self._stop = threading.Event()
        self._lock = threading.Lock()  # drain vs health
        self._thread: threading.Thread | None = None
        self._prefix = options.prefix.rstrip("/")

    def start(self) -> None:
        """Open the session, subscribe and start draining (errors go to ``stats``)."""
        try:
            self._session = zenoh.open(zenoh_config(self.options))
            self._sub = self._session.declare_subscriber(
                keyspace.recorder_wildcard(self._prefix),
                zenoh.handlers.FifoChannel(self.options.capacity))
        except Exception as exc:
            self.stats.status, self.stats.detail = "down", f"{type(exc).__name__}: {exc}"
            log.warning("live recording is off: %s", self.stats.detail)
            self.close()
            return
        self.stats.status = "ok"
        self._thread = threading.Thread(target=self._run, name="canal-recorder-live",
                                        daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Stop draining (what is queued is drained once more) and close the session."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10)
            self._thread = None
        if self._sub is not None:
            try:
                self._sub.undeclare()
            except Exception:
                pass
            self._sub = None
        if self._session is not None:
            try:
                self._session.close()
            except Exception:
                pass
            self._session = None

    # ---- drain thread -------------------------------------------------------------------------

    def _run(self) -> None:
        while not self._stop.wait(self.options.interval_s):
            self.drain()
        self.drain()

    def drain(self) -> int:
        """Hand every batch waiting in the channel to the recorder; the number of batches."""
        sub = self._sub
        if sub is None:
            return 0
        n = 0
        with self._lock:
            while True:
                try:
                    sample = sub.try_recv()
                except Exception:
                    break  # undeclared
                if sample is None:
                    break
                n += 1
                try:
                    self.take(str(sample.key_expr), sample.payload.to_bytes())
                except Exception:
                    log.exception("live recording batch")
                    self.stats.bad_payload += 1
        return n

    def take(self, key: str, data: bytes) -> bool:
        """One batch from ``key``: rows to the recorder, counts to the tallies; False (and
        counted as ``bad_payload``) when it is not a batch of the bridge its key names."""
        stats = self.stats
        bridge = keyspace.bridge_of_batch(key, self._prefix)
        try:
            batch = record_batches.decode_record_batch(data)
        except wire.WireError:
            stats.bad_payload += 1
            return False
        if bridge is None or batch.bridge != bridge or any(
                len(st) + st.decimated != st.poses for st in batch.streams):
            stats.bad_payload += 1
            return False
        last = stats.last_n.get(bridge)
        if last is not None and batch.n > last + 1:
            stats.lost_batches += batch.n - last - 1
        if last is None or batch.n > last:
            stats.last_n[bridge] = batch.n
        if last is None and batch.n > 0:
            stats.lost_batches += batch.n  # heard from the middle: the bridge's first ones
        stats.batches += 1
        chunks: list[LiveRows] = []
        for st in batch.streams:
            stats.heard[(st.skill, st.robot)] = stats.batches
            tally = stats.streams[(st.skill, st.robot)]
            tally["poses"] += st.poses
            tally["answered"] += st.answered
            tally["coalesced"] += st.coalesced
            tally["errors"] += st.errors
            tally["decimated"] += st.decimated
            tally["kept"] += len(st)
            if len(st):
                chunks.append(rows_of(st))
        if chunks:
            self.recorder.live_rows(chunks)
        if len(stats.streams) > MAX_COUNTED_STREAMS:
            self._retire()
        return True

    def _retire(self) -> None:
        """Sum the settled streams heard from least recently into ``stats.retired`` until
        half of :data:`MAX_COUNTED_STREAMS` are counted one by one (fewer are retired when
        fewer are settled: a stream with rows on their way keeps its own counts)."""
        stats = self.stats
        recorded, dropped, stale = self.recorder.live_stream_counts()
        settled = [key for key, t in stats.streams.items()
                   if t["kept"] == recorded.get(key, 0) + dropped.get(key, 0) + stale.get(key, 0)]
        settled.sort(key=lambda key: stats.heard.get(key, 0))
        gone = settled[:max(len(stats.streams) - MAX_COUNTED_STREAMS // 2, 0)]
        retired = stats.retired
        for key in gone:
            tally = stats.streams.pop(key)
            stats.heard.pop(key, None)
            for k in _COUNTS:
                retired[k] += tally[k]
            retired["recorded"] += recorded.get(key, 0)
            retired["dropped"] += dropped.get(key, 0)
            retired["stale"] += stale.get(key, 0)
        if gone:
            self.recorder.forget_live_streams(gone)

    # ---- state --------------------------------------------------------------------------------

    def stream_counts(self) -> dict[tuple[str, str], dict[str, int]]:
        """Per stream: the bridges' counts and the recorder's ``recorded`` (written and
        flushed), ``dropped`` (lost), ``stale`` (of a skill deleted since: not lost) and
        ``pending`` (kept, none of these yet)."""
        return self._counts()[0]

    def _counts(self) -> tuple[dict[tuple[str, str], dict[str, int]], dict[str, int]]:
        """:meth:`stream_counts` and the retired streams' sums, read together (no stream is
        retired between the two)."""
        with self._lock:
            tallies = {k: dict(v) for k, v in self.stats.streams.items()}
            retired = dict(self.stats.retired)
            recorded, dropped, stale = self.recorder.live_stream_counts()
        for key, t in tallies.items():
            t["recorded"] = recorded.get(key, 0)
            t["dropped"] = dropped.get(key, 0)
            t["stale"] = stale.get(key, 0)
            t["pending"] = t["kept"] - t["recorded"] - t["dropped"] - t["stale"]
        return tallies, retired

    def health(self) -> dict[str, Any]:
        """Status, totals and (up to :data:`HEALTH_STREAMS`) streams. ``complete``: nothing
        lost on the way (no lost batch, nothing dropped; rows of a skill deleted since are
        ``stale``, not lost); when ``pending`` is 0 as well, ``recorded + stale + decimated
        == poses`` for every stream."""
        per, retired = self._counts()
        stats = self.stats
        totals = {**retired, "pending": 0}
        for t in per.values():
            for k in totals:
                totals[k] += t[k]
        return {"status": stats.status, "detail": stats.detail, "batches": stats.batches,
                "lost_batches": stats.lost_batches, "bad_payload": stats.bad_payload,
                "bridges": len(stats.last_n), **totals,
                "complete": stats.lost_batches == 0 and totals["dropped"] == 0,
                "streams": {f"{s}/{r}": t for (s, r), t in sorted(per.items())[:HEALTH_STREAMS]}}
