"""Review recordings of skills: Rerun ``.rrd`` and Foxglove-ready ``.mcap`` (docs/recording.md)."""

from .recorder import Recorder

__all__ = ["Recorder"]
