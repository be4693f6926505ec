"""``python -m canal_service.bridge``: the live Zenoh bridge alone, against the service's database.

``canal serve`` starts these itself (``--zenoh-processes``, default 1); run one by hand to put
bridges on other machines. Takes the service's flags and ``CANAL_*`` variables
(``--data-dir``, ``--database-url``, ``--zenoh-*``; ``--host``/``--port`` are ignored).
``--no-recordings`` and ``--recordings-live-hz`` say what the bridge keeps for the service's
live recorder, which it hands over in batches on ``{prefix}/@recorder/live/{bridge}``
(docs/recording.md). Extra flags:

  --shard I/K           answer only the streams of robots whose name ends with a character
                        c with ord(c) % K == I, and subscribe only to their pose keys
                        (canal_protocol.keys.shard_pose_keys)
  --metrics-port PORT   serve Prometheus metrics on 127.0.0.1:PORT
  --supervised          (used by ``canal serve``) read fit and scene notices on stdin, print status
                        lines on stdout

Stops on SIGINT/SIGTERM, closing the Zenoh session.
"""

from __future__ import annotations

import logging
import signal
import sys
import threading
from collections.abc import Sequence
from typing import Any

import orjson

from ..core.cli import build_parser, settings_from_args
from ..metrics import Metrics
from ..service import CanalService
from ..storage import Database
from .bridge import Bridge, BridgeOptions
from .processes import STATUS_PERIOD_S


def _take(argv: list[str], flag: str, has_value: bool = True) -> str | None:
    if flag not in argv:
        return None
    i = argv.index(flag)
    if not has_value:
        del argv[i]
        return ""
    value = argv[i + 1]
    del argv[i : i + 2]
    return value


def _shard(text: str | None) -> tuple[int, int]:
    if text is None:
        return 0, 1
    try:
        shard, shards = (int(v) for v in text.split("/"))
    except ValueError:
        raise SystemExit(f"--shard: expected I/K such as 0/2, got {text!r}") from None
    if not 0 <= shard < shards:
        raise SystemExit(f"--shard: expected 0 <= I < K, got {text!r}")
    return shard, shards


def _read_fits(bridge: Bridge, stop: threading.Event, announce: bool) -> None:
    """Fit notices from ``canal serve`` (one JSON line each); stdin closing means the
    service is gone, and so should this bridge be."""
    for raw in sys.stdin.buffer:
        try:
            body = orjson.loads(raw)
            if "scene" in body:
                bridge.scene_updated(str(body["scene"]), int(body["version"]), announce=announce)
            else:
                bridge.model_updated(str(body["fit"]), int(body["version"]), announce=announce)
        except Exception:
            logging.getLogger("canal_service.bridge").exception("bad fit notice %r", raw[:200])
    stop.set()


def _report(bridge: Bridge, stop: threading.Event) -> None:
    out = sys.stdout
    while not stop.is_set():
        body: dict[str, Any] = {"health": bridge.health(), "counts": bridge.counts.snapshot(),
                                "stored": bridge.service.metrics.stored_counts()}
        try:
            out.write(orjson.dumps(body).decode() + "\n")
            out.flush()
        except (OSError, ValueError):
            stop.set()
            return
        stop.wait(STATUS_PERIOD_S)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the bridge until interrupted; 1 when Zenoh cannot start."""
    argv = list(sys.argv[1:] if argv is None else argv)
    metrics_port = int(_take(argv, "--metrics-port") or 0)
    shard, shards = _shard(_take(argv, "--shard"))
    supervised = _take(argv, "--supervised", has_value=False) is not None
    if "-h" in argv or "--help" in argv:
        parser = build_parser()
        parser.prog = "python -m canal_service.bridge"
        parser.description = __doc__
        parser.print_help()
        return 0
    settings = settings_from_args(argv)
    logging.basicConfig(level=settings.log_level.upper(),
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    db = Database(settings.resolved_database_url)
    db.migrate()
    metrics = Metrics()
    service = CanalService(db, metrics, cache_size=settings.model_cache_size)
    bridge = Bridge(service, BridgeOptions.from_settings(settings, shard=shard, shards=shards))
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    try:
        if not bridge.start():
            print(f"canal bridge failed: {bridge.detail}", file=sys.stderr, flush=True)
            return 1
        if metrics_port:
            from prometheus_client import start_http_server

            start_http_server(metrics_port, addr="127.0.0.1", registry=metrics.registry)
        print(f"canal bridge ready on {', '.join(bridge.listen) or '(config file)'} "
              f"(shard {shard}/{shards})", flush=True)
        if supervised:
            for target, args in ((_read_fits, (bridge, stop, shard == 0)),
                                 (_report, (bridge, stop))):
                threading.Thread(target=target, args=args, daemon=True).start()
        while not stop.wait(0.5):
            pass
        return 0
    finally:
        bridge.close()
        db.dispose()


if __name__ == "__main__":
    raise SystemExit(main())
