"""A recording records one skill instance (its id and creation time), not a name.

One SQLite file shared by a recorder and a service that does not tell it anything (another
replica, as far as the recorder knows): a skill deleted there has its files collected by the
writer, and an event computed for the deleted skill never reaches the new one's recording.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
from canal_service.metrics import Metrics
from canal_service.recording import Recorder
from canal_service.recording.events import live_rows
from canal_service.recording.source import DbSource
from canal_service.service import CanalService
from canal_service.storage import Database
from recording_helpers import helix_demo, mcap_messages, rrd_rows

import canal_core
from canal_protocol.schemas import DemonstrationIn, SkillCreate


def test_a_deleted_skills_files_are_collected_and_its_late_events_dropped(tmp_path: Path) -> None:
    db = Database(f"sqlite:///{tmp_path / 'canal.sqlite3'}")
    db.migrate()
    elsewhere = CanalService(db, Metrics())  # another replica: the recorder hears nothing
    source = DbSource(db)
    rec = Recorder(tmp_path / "rec", flush_interval_s=0.1, idle_close_s=0.3, source=source)
    try:
        elsewhere.create_skill(SkillCreate(name="pour", description="", dim=3))
        ids = [elsewhere.add_json_demonstration("pour", DemonstrationIn(
            positions=helix_demo(k).tolist())).id for k in range(2)]
        old = source.instance("pour")
        rec.export_mcap("pour").unlink()  # the export logs both demos from the database
        folder = tmp_path / "rec" / "pour"
        assert (folder / "instance").exists()

        elsewhere.delete_skill("pour")
        deadline = time.monotonic() + 30
        while folder.exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not folder.exists()  # collected without any request on this replica

        elsewhere.create_skill(SkillCreate(name="pour", description="", dim=3))
        new = source.instance("pour")
        assert new is not None and new != old
        canal = canal_core.fit([helix_demo(k) for k in range(3)], n_samples=30)
        rec.model_fitted("pour", 1, canal, instance=old)  # queued before the delete
        rec.reproduction("pour", 1, canal.reproduce_detailed(helix_demo(0)[0]), number=1,
                         instance=old)
        path = rec.export_mcap("pour")
        assert rec.health()["stale"] == 2  # both dropped, and counted
    finally:
        rec.close()
        db.dispose()
    assert mcap_messages(path, "/canal/model") == []
    assert mcap_messages(path, "/canal/reproductions") == []
    assert [e["id"] for m in mcap_messages(path, "/canal/demos") for e in m["entities"]] == []
    assert ids  # the old skill's demos were stored and are gone with it


def _rows(t0: int, pts: np.ndarray) -> Any:
    m = len(pts)
    return live_rows("pour", "arm1", t0 + 1_000_000 * np.arange(m), pts, None, pts, None,
                     np.linspace(0, 0.2, m), np.ones(m), np.arange(m), np.ones(m, bool),
                     np.zeros(m, bool))


def test_live_rows_of_a_skill_created_again_outlive_the_delete_of_the_old_one(
        tmp_path: Path) -> None:
    # A robot streaming at once on a skill deleted and created again under its name: its
    # rows reached the new skill's recording before the writer handled the delete, which
    # then deleted them with the old skill's files (counted as recorded, missing from the
    # export). quiet_s keeps the delete queued (the writer yields to requests) while they come.
    db = Database(f"sqlite:///{tmp_path / 'canal.sqlite3'}")
    db.migrate()
    source = DbSource(db)
    rec = Recorder(tmp_path / "rec", flush_interval_s=0.05, quiet_s=2.0, source=source)
    service = CanalService(db, Metrics(), recorder=rec)
    try:
        service.create_skill(SkillCreate(name="pour", description="", dim=3))
        service.add_json_demonstration("pour", DemonstrationIn(positions=helix_demo(0).tolist()))
        rec.export_mcap("pour").unlink()  # the old skill's files, with its instance
        before = time.time_ns() - 10_000_000

        service.delete_skill("pour")
        service.create_skill(SkillCreate(name="pour", description="", dim=3))
        pts = helix_demo(1)[:9]
        # the old skill's last rows, still on their way, then the new skill's
        rec.live_rows([_rows(before, helix_demo(2)[:4]), _rows(time.time_ns(), pts)])
        path = rec.export_mcap("pour")
        recorded, dropped, stale = rec.live_stream_counts()
    finally:
        rec.close()
        db.dispose()
    poses = mcap_messages(path, "/live/arm1/pose")
    assert len(poses) == len(pts) == recorded[("pour", "arm1")]  # in the export, as counted
    # the deleted skill's, not drawn in the new one's, and not lost: its recording is gone
    assert stale[("pour", "arm1")] == 4 and ("pour", "arm1") not in dropped
    xs = [[p["pose"]["position"][c] for c in "xyz"] for p in poses]
    assert np.allclose(xs, pts)
    assert mcap_messages(path, "/canal/demos") == []  # the old skill's demo went with it


def test_a_deleted_skills_scene_and_demo_removal_stay_out_of_the_new_skills_recording(
        tmp_path: Path, rerun_env: dict[str, str]) -> None:
    # A scene put and a demonstration deleted just before the skill is deleted, then a skill
    # created again under its name: those events, still queued (quiet_s keeps them waiting
    # while requests come), belong to the deleted skill and its recording, never the new one's.
    db = Database(f"sqlite:///{tmp_path / 'canal.sqlite3'}")
    db.migrate()
    rec = Recorder(tmp_path / "rec", flush_interval_s=0.05, quiet_s=2.0, source=DbSource(db))
    service = CanalService(db, Metrics(), recorder=rec)
    try:
        service.create_skill(SkillCreate(name="pour", description="", dim=3))
        old = [service.add_json_demonstration("pour", DemonstrationIn(
            positions=helix_demo(k).tolist())).id for k in range(3)]
        rec.export_mcap("pour").unlink()  # the old skill's files, with its instance
        service.put_scene("pour", [{"kind": "sphere", "center": [0.5, 0.1, 0.02], "radius": 0.01}])
        service.delete_demonstration("pour", old[0])
        service.delete_skill("pour")
        service.create_skill(SkillCreate(name="pour", description="", dim=2))
        new = [service.add_json_demonstration("pour", DemonstrationIn(
            positions=helix_demo(10 + k, dim=2).tolist())).id for k in range(2)]
        mcap = rec.export_mcap("pour")
        rrd = rec.export_rrd("pour")
    finally:
        rec.close()
        db.dispose()
    assert mcap_messages(mcap, "/canal/scene") == []
    demos = mcap_messages(mcap, "/canal/demos")
    assert sorted(e["id"] for m in demos for e in m["entities"]) == [f"demo/{i}" for i in new]
    assert [d for m in demos for d in m["deletions"]] == []
    entities = {e for e, _ in rrd_rows(rrd, rerun_env)}
    assert not {e for e in entities if e.startswith("/scene")}
    assert {e.split("/")[2] for e in entities if e.startswith("/demos/")} == {str(i) for i in new}
