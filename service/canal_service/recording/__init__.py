"""Review recordings of skills: Rerun ``.rrd`` and Foxglove-ready ``.mcap`` (docs/recording.md)."""

from __future__ import annotations

from typing import Any

from .recorder import Recorder


def recorder_from_settings(settings: Any, db: Any = None) -> Recorder:
    """The service's recorder: the database as its source, live poses from the bridges'
    batches (heard on its own Zenoh session) when the live bridge is enabled (``settings`` is ``core.config.Settings``)."""
    from .source import DbSource

    root = settings.resolved_recordings_dir
    root.mkdir(parents=True, exist_ok=True)
    recorder = Recorder(
        root, enabled=True, live_max_hz=settings.recordings_live_hz or None,
        source=None if db is None else DbSource(db),
        max_robots=settings.recordings_max_robots,
        coordinates=getattr(settings, "recordings_view_coordinates", "RIGHT_HAND_Z_UP"))
    if settings.zenoh_enabled:
        from .live import LiveOptions, LiveSubscriber

        subscriber = LiveSubscriber(recorder, LiveOptions.from_settings(settings))
        subscriber.start()
        recorder.live_source = subscriber
    return recorder


__all__ = ["Recorder", "recorder_from_settings"]
