"""``python -m canal_service``: serve the API with uvicorn.

Flags override ``CANAL_*`` environment variables, which override the embedded defaults
(127.0.0.1:8000, SQLite and recordings under ./data).

The port is bound and ``/healthz`` answers at once (503 ``{"status": "starting"}``) while the
application loads behind it: the scientific stack, migrations, the recorder and the Zenoh
bridge take seconds; then ``/healthz`` says ``ok`` and every route is served. Requests that
arrive meanwhile wait for it. One log line says where REST and Zenoh listen.
"""

from __future__ import annotations

from .core.serve import main

if __name__ == "__main__":
    main()
