"""Building the service raises no pydantic warning of its own (the suite ignores one kind,
see pyproject.toml, because FastAPI's own silencing of it is not thread-safe)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

CODE = """
import warnings
from pydantic.warnings import UnsupportedFieldAttributeWarning
warnings.simplefilter("error", UnsupportedFieldAttributeWarning)
from canal_service.app import create_app
from canal_service.core.config import Settings
app = create_app(Settings(data_dir={data!r}, recordings_enabled=False, zenoh_enabled=False))
app.openapi()
print("built", len(app.routes))
"""


def test_building_the_app_and_its_schema_raises_no_unsupported_field_warning(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-c", CODE.format(data=str(tmp_path))],
                          capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.startswith("built")
