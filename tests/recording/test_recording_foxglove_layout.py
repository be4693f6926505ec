"""docs/foxglove-layout.json opens on what the recorder writes: its panels exist, and every
topic it names is a topic of a recorded skill's MCAP (read back with the mcap reader)."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np
from canal_service.recording import Recorder
from recording_helpers import mcap_counts, record_session

LAYOUT = Path(__file__).resolve().parents[2] / "docs" / "foxglove-layout.json"


def panel_ids(node: Any) -> list[str]:
    if isinstance(node, str):
        return [node]
    return panel_ids(node["first"]) + panel_ids(node["second"])


def test_layout_names_only_recorded_topics(recorder: Recorder, demos3: list[np.ndarray],
                                           canal3: Any) -> None:
    layout = json.loads(LAYOUT.read_text())
    configs = layout["configById"]
    shown = panel_ids(layout["layout"])
    for config in configs.values():
        shown += [tab["layout"] for tab in config.get("tabs", [])]
    assert sorted(shown) == sorted(configs)  # every panel placed, none missing
    record_session(recorder, "pour", demos3, canal3, n_live=20, robot="sim")
    path = recorder.export_mcap("pour")
    try:
        topics = set(mcap_counts(path))
    finally:
        path.unlink()
    topics.add("/canal/scene")  # obstacles: written once a skill has some
    named = set(configs["3D!canal"]["topics"])
    for config in configs.values():
        named |= {re.split(r"[.\[]", p["value"])[0] for p in config.get("paths", [])}
    assert named <= topics, named - topics
    assert {"/canal/demos", "/canal/model", "/canal/reproductions"} <= named
