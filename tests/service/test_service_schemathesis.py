"""Property-based run over the OpenAPI spec: no input may produce a server error.

Bounded (examples per operation, no deadline) so it stays a few seconds; the database is
seeded with a fitted skill so generated requests also reach the fit/reproduce/mesh code.
"""

from __future__ import annotations

import atexit
import shutil
import tempfile
from pathlib import Path

import schemathesis
from canal_service.app import create_app
from canal_service.core.config import Settings
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, settings
from service_helpers import demo_positions

MAX_EXAMPLES = 25

# Random bytes for the binary upload types, exactly like application/octet-stream.
schemathesis.serializer.alias("application/x-npy", "application/octet-stream")
schemathesis.serializer.alias("application/x-mcap", "application/octet-stream")


def _seeded_app() -> object:
    # Built at import: the schemathesis pytest plugin needs the schema before fixtures run
    # (its from_fixture loader does not work with pytest 9).
    data_dir = Path(tempfile.mkdtemp(prefix="canal-schemathesis-"))
    atexit.register(shutil.rmtree, data_dir, ignore_errors=True)
    app = create_app(Settings(data_dir=data_dir, recordings_enabled=False, zenoh_enabled=False))
    with TestClient(app) as c:
        c.post("/skills", json={"name": "pour", "dim": 3})
        for j in range(3):
            c.post("/skills/pour/demonstrations", json={"positions": demo_positions(j).tolist()})
        assert c.post("/skills/pour/fit", json={"n_samples": 20}).status_code == 201
    return app


schema = schemathesis.openapi.from_asgi("/openapi.json", _seeded_app())


@schema.parametrize()
@settings(max_examples=MAX_EXAMPLES, deadline=None,
          suppress_health_check=list(HealthCheck))
def test_no_server_errors(case: schemathesis.Case) -> None:
    case.call_and_validate(checks=[schemathesis.checks.not_a_server_error])
