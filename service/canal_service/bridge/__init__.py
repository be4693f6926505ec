"""The live bridge: robot poses in over Zenoh, ratio-rule targets out (see docs/live.md)."""

from __future__ import annotations

from .bridge import Bridge, BridgeOptions, zenoh_config
from .processes import BridgeProcesses

__all__ = ["Bridge", "BridgeOptions", "BridgeProcesses", "zenoh_config"]
