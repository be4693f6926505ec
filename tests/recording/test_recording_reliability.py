"""Recording never fails a caller: bounded queues, counted drops, degraded health on disk errors."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from canal_service.recording import Recorder
from recording_helpers import helix_demo, mcap_counts, mcap_messages

HERE = Path(__file__).parent


def _live(rec: Recorder, canal: Any, path: np.ndarray, n: int, t0: int) -> list[Any]:
    tracker = canal.tracker()
    targets = []
    for k in range(n):
        position = path[k * len(path) // n]
        target = tracker.step(position)
        targets.append(target)
        rec.live("pour", "ur5", position, target, t_ns=t0 + k * 1_000_000)
    return targets


def test_live_queue_is_bounded_and_drops_the_oldest(tmp_path: Path, demos3: list[np.ndarray],
                                                    canal3: Any) -> None:
    # A long flush interval keeps the writer from draining during the burst: a stalled disk.
    rec = Recorder(tmp_path / "rec", flush_interval_s=60, live_max_hz=None, live_queue_size=100)
    t0 = time.time_ns()
    _live(rec, canal3, demos3[0], 5000, t0)  # a pose and a target sample per step
    health = rec.health()
    assert health["queued"] == 100
    assert health["dropped"] == 9900
    rec.close()
    assert rec.written_live == 100
    path = rec.export_mcap("pour")
    assert mcap_counts(path)["/live/ur5/pose"] == 50
    assert mcap_counts(path)["/live/ur5/target"] == 50
    first = mcap_messages(path, "/live/ur5/pose")[0]["timestamp"]
    assert first["sec"] * 10**9 + first["nsec"] == t0 + 4950 * 1_000_000  # the newest were kept


def test_live_decimation_keeps_the_rate_and_every_transition(
        tmp_path: Path, demos3: list[np.ndarray], canal3: Any) -> None:
    rec = Recorder(tmp_path / "rec", flush_interval_s=0.1, live_max_hz=100.0)
    t0 = time.time_ns()
    far = demos3[0] + np.where(np.arange(len(demos3[0]))[:, None] % 20 < 10, 0.0, 5.0)
    targets = _live(rec, canal3, far, 1000, t0)
    rec.close()
    path = rec.export_mcap("pour")
    states = mcap_messages(path, "/live/ur5/state")
    poses = mcap_messages(path, "/live/ur5/pose")
    assert len(states) + len(poses) == rec.written_live
    assert rec.written_live + rec.decimated_live == 2000
    assert len(poses) == len(states)  # a row is kept whole: the pose and its target
    t = np.array([s["timestamp"]["sec"] * 10**9 + s["timestamp"]["nsec"] for s in states])
    flags = np.array([(s["inside"], s["done"]) for s in states])
    flips = int(np.count_nonzero(np.diff([(x.inside, x.done) for x in targets], axis=0).any(axis=1)))
    assert flips > 0
    assert 100 <= len(states) <= 100 + flips + 1
    kept_gaps = np.diff(t)[(flags[1:] == flags[:-1]).all(axis=1)]
    assert kept_gaps.min() >= 10_000_000  # 100 Hz between samples that changed nothing


def test_bad_calls_never_raise_and_are_counted(recorder: Recorder) -> None:
    recorder.live("pour", "ur5", None, object())
    recorder.demo_added("pour", 3, "not-an-id", [[0, 0, 0]], None, None)
    recorder.model_fitted("pour", 1, object())  # fails on the writer thread
    recorder.export_mcap("pour")  # waits for the writer
    health = recorder.health()
    assert health["dropped"] == 3
    assert health["status"] == "degraded" and "pour" in health["detail"]


def test_a_broken_root_degrades_health_and_callers_go_on(tmp_path: Path,
                                                         demos3: list[np.ndarray]) -> None:
    root = tmp_path / "not-a-folder"
    root.write_text("a file where the recordings folder should be")
    rec = Recorder(root, flush_interval_s=0.1)
    try:
        for j in range(5):
            rec.demo_added("pour", 3, j, demos3[0], None, None)
        deadline = time.monotonic() + 10
        while rec.health()["dropped"] < 5 and time.monotonic() < deadline:
            time.sleep(0.02)
        health = rec.health()
    finally:
        rec.close()
    assert health["status"] == "degraded"
    assert health["dropped"] == 5 and "pour" in health["detail"]


@pytest.mark.skipif(not hasattr(os, "setrlimit") and sys.platform != "linux",
                    reason="needs RLIMIT_FSIZE")
def test_disk_full_degrades_health_and_never_fails_a_call(tmp_path: Path) -> None:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(HERE), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.run([sys.executable, str(HERE / "disk_full_child.py"), str(tmp_path / "rec")],
                          capture_output=True, text=True, timeout=120, env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    assert report["raised"] == 0
    assert report["health"]["status"] == "degraded"
    assert "File too large" in report["health"]["detail"]
    assert report["health"]["dropped"] > 0


def test_a_disabled_recorder_records_nothing(tmp_path: Path, demos3: list[np.ndarray]) -> None:
    rec = Recorder(tmp_path / "rec", enabled=False)
    rec.demo_added("pour", 3, 1, demos3[0], None, None)
    health = rec.health()
    assert {k: health[k] for k in ("status", "detail", "queued", "dropped", "decimated",
                                   "live_written")} == {
        "status": "ok", "detail": "recording disabled", "queued": 0, "dropped": 0,
        "decimated": 0, "live_written": 0}
    with pytest.raises(RuntimeError):
        rec.export_mcap("pour")
    rec.close()
    assert not (tmp_path / "rec").exists()


def test_a_demo_queued_while_the_start_reconcile_runs_is_logged_once(tmp_path: Path) -> None:
    from canal_service.metrics import Metrics
    from canal_service.recording.source import DbSource
    from canal_service.service import CanalService
    from canal_service.storage import Database

    from canal_protocol.schemas import DemonstrationIn, SkillCreate

    db = Database(f"sqlite:///{tmp_path / 'canal.sqlite3'}")
    db.migrate()
    service = CanalService(db, Metrics())
    service.create_skill(SkillCreate(name="pour", description="", dim=3))
    ids = [service.add_json_demonstration("pour", DemonstrationIn(
        positions=helix_demo(k).tolist())).id for k in range(3)]
    # The recorder starts (its reconcile finds the 3 demos) while their own events are queued.
    rec = Recorder(tmp_path / "rec", flush_interval_s=0.1, source=DbSource(db))
    for demo_id in ids:
        rec.demo_added("pour", 3, demo_id, None, None, None)
    try:
        path = rec.export_mcap("pour")
    finally:
        rec.close()
    logged = [e["id"] for m in mcap_messages(path, "/canal/demos") for e in m["entities"]]
    assert sorted(logged) == sorted(f"demo/{i}" for i in ids)
    db.dispose()


def test_the_writer_logs_stored_demos_in_bounded_batches(tmp_path: Path) -> None:
    """A burst that starts while the writer catches up waits for one batch of demos, not for
    everything queued; the rest is still logged, and the writer's CPU is accounted."""
    from canal_service.metrics import Metrics
    from canal_service.recording.recorder import DEMO_BATCH
    from canal_service.recording.source import DbSource
    from canal_service.service import CanalService
    from canal_service.storage import Database

    from canal_protocol.schemas import DemonstrationIn, SkillCreate

    db = Database(f"sqlite:///{tmp_path / 'canal.sqlite3'}")
    db.migrate()
    service = CanalService(db, Metrics())
    service.create_skill(SkillCreate(name="pour", description="", dim=3))
    n = 2 * DEMO_BATCH + 3
    ids = [service.add_json_demonstration("pour", DemonstrationIn(
        positions=helix_demo(k % 5).tolist())).id for k in range(n)]
    # A writer that considers the request path busy (quiet_s never elapses) leaves the queue
    # alone; the batch below is taken by hand, as the writer would after a lull.
    rec = Recorder(tmp_path / "rec", flush_interval_s=600, quiet_s=600, max_lag_s=600,
                   source=DbSource(db))
    try:
        rec.reconcile()  # the start-up pass (the demos are stored): then clear the ledger
        rec.rebuild("pour")
        before = rec.health()["writer_cpu_s"]
        assert before > 0  # the rebuild wrote n demos on the writer thread
        for demo_id in ids:
            rec._state("pour").demos.discard(demo_id)
            rec.demo_added("pour", 3, demo_id, None, None, None)
        assert len(rec._events) == n
        rec._demo_refs(rec._events.popleft())  # type: ignore[arg-type]
        assert len(rec._events) == n - DEMO_BATCH
    finally:
        rec.close()  # writes everything still queued
    path = rec.export_mcap("pour")
    logged = [e["id"] for m in mcap_messages(path, "/canal/demos") for e in m["entities"]]
    # rebuilt once, then logged again from the refs: every demo twice, none lost
    assert sorted(logged) == sorted(2 * [f"demo/{i}" for i in ids])
    assert rec.health()["writer_cpu_s"] > before
    db.dispose()


def test_an_export_the_writer_did_not_answer_in_time_degrades_health_until_it_catches_up(
        tmp_path: Path, demos3: list[np.ndarray]) -> None:
    # export_timeout_s=0: the export never waits, as after a burst the writer is still behind.
    rec = Recorder(tmp_path / "rec", flush_interval_s=0.1, export_timeout_s=0)
    try:
        rec.demo_added("pour", 3, 1, demos3[0], None, None)
        rec.export_mcap("pour")
        health = rec.health()
        assert health["status"] == "degraded" and health["detail"].startswith("export: ")
        # An export that gets the writer's answer: the writer is no longer behind.
        rec.export_timeout_s = 30
        path = rec.export_mcap("pour")
        assert mcap_counts(path)["/canal/demos"] == 1
        assert rec.health()["status"] == "ok", rec.health()["detail"]
        # Without another export: the writer catching up (its queue drained) is enough.
        rec.export_timeout_s = 0
        rec.demo_added("pour", 3, 2, demos3[1], None, None)
        rec.export_mcap("pour")
        deadline = time.monotonic() + 60
        while rec.health()["status"] != "ok" and time.monotonic() < deadline:
            time.sleep(0.02)
        health = rec.health()
        assert health["status"] == "ok" and health["queued"] == 0, health["detail"]
        assert health["dropped"] == 0
    finally:
        rec.close()
    assert mcap_counts(rec.export_mcap("pour"))["/canal/demos"] == 2


def _service_with_recorder(tmp_path: Path) -> tuple[Any, Any, Recorder]:
    from canal_service.metrics import Metrics
    from canal_service.recording.source import DbSource
    from canal_service.service import CanalService
    from canal_service.storage import Database

    db = Database(f"sqlite:///{tmp_path / 'canal.sqlite3'}")
    db.migrate()
    # A flush interval longer than the test: what the writer wrote is still unflushed when
    # the rebuild or the delete comes, as right after a burst of requests.
    rec = Recorder(tmp_path / "rec", flush_interval_s=600, source=DbSource(db))
    return db, CanalService(db, Metrics(), recorder=rec), rec


def test_a_rebuild_right_after_uploads_drops_nothing(
        tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    from canal_protocol.schemas import DemonstrationIn, FitRequest, SkillCreate

    db, service, rec = _service_with_recorder(tmp_path)
    try:
        service.create_skill(SkillCreate(name="pour", description="", dim=3))
        ids = [service.add_json_demonstration("pour", DemonstrationIn(
            positions=helix_demo(k).tolist())).id for k in range(3)]
        service.fit("pour", FitRequest(n_samples=30))
        assert rec.rebuild("pour") == {"demos": 3, "models": 1, "removed": 0,
                                       "reproductions": 0}
        health = rec.health()
        path = rec.export_mcap("pour")
    finally:
        rec.close()
        db.dispose()
    # What the rebuild replaced was superseded, not lost: the export holds all of it.
    assert health["dropped"] == 0 and health["status"] == "ok", health
    logged = [e["id"] for m in mcap_messages(path, "/canal/demos") for e in m["entities"]]
    assert sorted(logged) == sorted(f"demo/{i}" for i in ids)
    assert len(mcap_messages(path, "/canal/model_info")) == 1
    assert "Dropping data" not in capfd.readouterr().err


def test_deleting_a_skill_right_after_uploads_drops_nothing(
        tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    from canal_protocol.schemas import DemonstrationIn, FitRequest, SkillCreate

    db, service, rec = _service_with_recorder(tmp_path)
    try:
        service.create_skill(SkillCreate(name="pour", description="", dim=3))
        for k in range(3):
            service.add_json_demonstration("pour", DemonstrationIn(
                positions=helix_demo(k).tolist()))
        service.fit("pour", FitRequest(n_samples=30))
        rec.export_mcap("pour").unlink()  # written, closed: then more, left unflushed
        service.add_json_demonstration("pour", DemonstrationIn(positions=helix_demo(4).tolist()))
        rec.reconcile("pour")  # the writer has logged it (the reconcile waits for it)
        service.delete_skill("pour")
        rec.reconcile()  # the delete is handled before it
        health = rec.health()
    finally:
        rec.close()
        db.dispose()
    assert health["dropped"] == 0 and health["status"] == "ok", health
    assert not (tmp_path / "rec" / "pour").exists()
    assert "Dropping data" not in capfd.readouterr().err


def _add_demos(service: Any, n: int, *, create: bool = False) -> list[int]:
    """``n`` demonstrations uploaded to skill 'pour' (created first with ``create``): the
    writer has them queued, and takes what comes next behind them."""
    from canal_protocol.schemas import DemonstrationIn, SkillCreate

    if create:
        service.create_skill(SkillCreate(name="pour", description="", dim=3))
    return [service.add_json_demonstration("pour", DemonstrationIn(
        positions=helix_demo(k).tolist())).id for k in range(n)]


def test_an_export_overlapping_a_rebuild_holds_the_whole_recording(tmp_path: Path) -> None:
    # A download answered while a rebuild ran was a valid, empty file (200): the export's
    # segment was closed, then the rebuild wiped the files before the export listed them.
    # Here the export's request and the rebuild's wait behind the same uploads, so the
    # writer takes them one right after the other.
    from canal_protocol.schemas import FitRequest

    db, service, rec = _service_with_recorder(tmp_path)
    try:
        _add_demos(service, 3, create=True)
        service.fit("pour", FitRequest(n_samples=30))
        held = []
        for attempt in range(4):
            ids = _add_demos(service, 12)
            paths: list[Path] = []
            export = threading.Thread(target=lambda out=paths: out.append(rec.export_mcap("pour")))
            export.start()
            time.sleep(0.005)  # the export's rotate queued behind the uploads, then the rebuild
            rec.rebuild("pour")
            export.join()
            demos = {e["id"] for m in mcap_messages(paths[0], "/canal/demos")
                     for e in m["entities"]}
            held.append((attempt, {f"demo/{i}" for i in ids} <= demos,
                         len(mcap_messages(paths[0], "/canal/model_info"))))
            paths[0].unlink()
    finally:
        rec.close()
        db.dispose()
    assert all(full and models == 1 for _, full, models in held), held


def test_a_rebuild_of_a_skill_deleted_meanwhile_says_it_is_gone(tmp_path: Path) -> None:
    # It answered 200 with every count 0, as if the skill had nothing to record.
    from canal_service.errors import SkillNotFound

    db, service, rec = _service_with_recorder(tmp_path)
    try:
        _add_demos(service, 12, create=True)
        outcome: list[object] = []

        def rebuild() -> None:
            try:
                outcome.append(service.rebuild_recording("pour"))
            except SkillNotFound as exc:
                outcome.append(exc)

        thread = threading.Thread(target=rebuild)
        thread.start()
        time.sleep(0.005)  # the rebuild queued behind the uploads, then the delete
        service.delete_skill("pour")
        thread.join()
    finally:
        rec.close()
        db.dispose()
    assert isinstance(outcome[0], SkillNotFound), outcome
    assert "deleted while its recording was being rebuilt" in outcome[0].message
    assert outcome[0].field == "name"
