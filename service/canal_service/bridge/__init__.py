"""The live bridge: robot poses in over Zenoh, ratio-rule targets out (see docs/live.md)."""

from __future__ import annotations

from .bridge import Bridge, BridgeOptions, zenoh_config

__all__ = ["Bridge", "BridgeOptions", "zenoh_config"]
