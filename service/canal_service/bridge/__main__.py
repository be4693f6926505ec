"""``python -m canal_service.bridge``: the live Zenoh bridge alone, against the service's database.

Takes the service's flags and ``CANAL_*`` variables (``--data-dir``, ``--database-url``,
``--zenoh-*``; ``--host``/``--port`` are ignored). Live steps are recorded into
``DATA_DIR/recordings-bridge`` unless ``--recordings-dir`` says otherwise (not the service's
folder: two processes must not write the same recording), or not at all with
``--no-recordings``. ``--metrics-port`` serves Prometheus metrics on 127.0.0.1.
Stops on SIGINT/SIGTERM, closing the Zenoh session.
"""

from __future__ import annotations

import logging
import signal
import sys
import threading
from collections.abc import Sequence

from ..__main__ import build_parser, settings_from_args
from ..app import make_recorder
from ..metrics import Metrics
from ..service import CanalService
from ..storage import Database
from .bridge import Bridge, BridgeOptions


def main(argv: Sequence[str] | None = None) -> int:
    """Run the bridge until interrupted; 1 when Zenoh cannot start."""
    argv = list(sys.argv[1:] if argv is None else argv)
    metrics_port = 0
    if "--metrics-port" in argv:
        i = argv.index("--metrics-port")
        metrics_port = int(argv[i + 1])
        del argv[i : i + 2]
    if "-h" in argv or "--help" in argv:
        parser = build_parser()
        parser.prog = "python -m canal_service.bridge"
        parser.description = __doc__
        parser.print_help()
        print("\n  --metrics-port PORT   serve Prometheus metrics on 127.0.0.1:PORT")
        return 0
    settings = settings_from_args(argv)
    if settings.recordings_dir is None:
        settings = settings.model_copy(
            update={"recordings_dir": settings.data_dir / "recordings-bridge"})
    logging.basicConfig(level=settings.log_level.upper(),
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    db = Database(settings.resolved_database_url)
    db.migrate()
    metrics = Metrics()
    service = CanalService(db, metrics, cache_size=settings.model_cache_size)
    service.recorder = make_recorder(settings)
    bridge = Bridge(service, BridgeOptions.from_settings(settings))
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    try:
        if not bridge.start():
            return 1
        if metrics_port:
            from prometheus_client import start_http_server

            start_http_server(metrics_port, addr="127.0.0.1", registry=metrics.registry)
        print(f"canal bridge ready on {', '.join(bridge.listen) or '(config file)'}",
              flush=True)
        while not stop.wait(0.5):
            pass
        return 0
    finally:
        bridge.close()
        if service.recorder is not None:
            service.recorder.close()
        db.dispose()


if __name__ == "__main__":
    raise SystemExit(main())
