"""A correction in the recordings: its path and the canal before and after, under its own
entity in the .rrd and as topics in both MCAP profiles (read back by their own readers)."""

from __future__ import annotations

from typing import Any

import numpy as np
from canal_service.recording import Recorder
from recording_helpers import mcap_messages, rrd_rows, rrd_verify
from rosbags import highlevel


def corrected(canal: Any) -> tuple[Any, np.ndarray]:
    """``canal`` refined by an include over a third of its sections, and the path."""
    n = canal.n_sections
    idx = np.arange(n // 3, 2 * n // 3)
    path = canal.directrix[idx] + 1.3 * canal.radii[idx, None] * canal.normals[idx]
    return canal.corrected("include", path, label="wider"), path


def test_a_correction_has_its_own_entities_in_the_rrd(
        recorder: Recorder, canal3: Any, rerun_env: dict[str, str]) -> None:
    refined, path = corrected(canal3)
    recorder.model_fitted("pour", 1, canal3)
    recorder.model_fitted("pour", 2, refined)
    rrd = recorder.export_rrd("pour")
    assert rrd_verify(rrd, rerun_env).returncode == 0
    rows = rrd_rows(rrd, rerun_env)
    for part in ("samples", "before", "after"):
        assert rows[(f"/corrections/v2/{part}", "LineStrips3D:strips")] == 1, part
    assert rows[("/corrections/v2/info", "kind")] == 1
    assert not any(entity.startswith("/corrections/v1") for entity, _ in rows)


def test_a_correction_is_a_topic_in_both_mcap_profiles(recorder: Recorder, canal3: Any) -> None:
    refined, path = corrected(canal3)
    recorder.model_fitted("pour", 1, canal3)
    recorder.model_fitted("pour", 2, refined)
    scene = mcap_messages(recorder.export_mcap("pour"), "/canal/corrections")
    assert len(scene) == 1
    entity = scene[0]["entities"][0]
    assert entity["id"] == "correction/v2"
    samples = np.array([[p["x"], p["y"], p["z"]] for p in entity["lines"][0]["points"]])
    np.testing.assert_allclose(samples, path)
    info = mcap_messages(recorder.export_mcap("pour"), "/canal/correction_info")
    assert info[0]["kind"] == "include" and info[0]["label"] == "wider"
    assert info[0]["first_section"] < info[0]["last_section"]
    topics: dict[str, Any] = {}
    with highlevel.AnyReader([recorder.export_mcap("pour", profile="ros2")]) as reader:
        for conn, _t, raw in reader.messages():
            topics.setdefault(conn.topic, reader.deserialize(raw, conn.msgtype))
    assert len(topics["/canal/corrections/samples"].poses) == len(path)
    assert len(topics["/canal/corrections/sections"].markers) == 2  # before and after
