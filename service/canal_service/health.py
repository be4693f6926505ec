"""What ``GET /healthz`` reports: the database, the recorder and the live bridge."""

from __future__ import annotations

from typing import Any, Literal, Protocol

from canal_protocol import schemas

from . import __version__
from .storage import Database


class HealthSource(Protocol):
    """A part that reports its own state: the recorder, or the live bridge (in this process or
    supervising bridge processes)."""

    def health(self) -> dict[str, Any]: ...


class ServiceHealth:
    """What ``GET /healthz`` reports: database, recorder and live bridge.

    Separate from :class:`CanalService` because the bridge is built from the service: both
    exist before this is, so every part is given to the constructor.
    """

    def __init__(self, db: Database, recorder: HealthSource | None,
                 bridge: HealthSource | None) -> None:
        self.db = db
        self.recorder = recorder
        self.bridge = bridge

    def __call__(self) -> schemas.HealthOut:
        """Database, recorder and bridge state; degraded when any is unwell."""
        status: Literal["ok", "degraded"] = "ok"
        try:
            self.db.ping()
            database = "ok"
        except Exception as exc:  # health must report, not raise
            database = f"error: {type(exc).__name__}"
            status = "degraded"
        if self.recorder is None:
            recorder: dict[str, Any] = {"status": "disabled", "detail": None}
        else:
            try:
                recorder = dict(self.recorder.health())
            except Exception as exc:
                recorder = {"status": "degraded", "detail": f"health() failed: {exc}"}
            if recorder.get("status") != "ok":
                status = "degraded"
        bridge: dict[str, Any] = {"status": "disabled"}
        if self.bridge is not None:
            try:
                bridge = dict(self.bridge.health())
            except Exception as exc:
                bridge = {"status": "down", "detail": f"health() failed: {exc}"}
            # The REST API still serves without the live path, but the service is not whole:
            # a bridge that is down or behind its queue makes the service "degraded".
            if bridge.get("status") in ("down", "behind"):
                status = "degraded"
        return schemas.HealthOut(status=status, database=database, recorder=recorder,
                                 bridge=bridge, version=__version__)
