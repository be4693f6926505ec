"""Captures held to their limits: a demonstration no longer than an upload may be, a
correction or steered run thinned to what a correction holds, a steered run kept once and
never thrown away by a capture begun over it."""

from __future__ import annotations

import sqlite3
import threading
import time
import warnings
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from canal_client.live import LiveError, PoseStreamer
from live_helpers import Live, make_skill

from canal_core.options import MAX_CORRECTION_SAMPLES
from canal_core.steering import STEER_TIMEOUT_S

with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    from fastapi.testclient import TestClient

from canal_service.app import create_app
from canal_service.core.config import Settings
from canal_testing import free_port

pytestmark = pytest.mark.timeout(120)

#: the upload limit of the small app: a capture holds at most this many poses
SMALL = 300


@pytest.fixture(scope="module")
def small(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    """An app whose uploads may have at most ``SMALL`` points, skill 'arc3' fitted."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    settings = Settings(data_dir=tmp_path_factory.mktemp("small"), zenoh_listen=[endpoint],
                        zenoh_refresh_s=0.2, zenoh_processes=0, upload_max_points=SMALL)
    with TestClient(create_app(settings)) as client:
        make_skill(client, "arc3", 3)
        yield Live(client, endpoint, settings)


def directrix(live: Live, skill: str) -> np.ndarray:
    body = live.client.get(f"/skills/{skill}/models/latest", params={"serialized": True}).json()
    return np.array(body["serialized"]["directrix"], dtype=np.float64)


def along(dirx: np.ndarray, n: int) -> np.ndarray:
    """``n`` points along the middle of the canal's directrix."""
    s = np.linspace(5.0, dirx.shape[0] - 6.0, n)
    k = np.floor(s).astype(int)
    f = (s - k)[:, None]
    return (1.0 - f) * dirx[k] + f * dirx[k + 1]


def send_all(ps: PoseStreamer, points: np.ndarray, steer: bool = False,
             restart: bool = False) -> int:
    """Send the points as fast as the bridge takes them; the last seq, once answered."""
    seq = -1
    if steer:  # the run begins at the first input: every pose sent after it is the run's
        ps.steer(0.3, 0.0)
        time.sleep(0.1)
    for i, q in enumerate(points):
        if steer and i % 100 == 0:
            ps.steer(0.3, 0.0)
        seq = ps.send(q.tolist(), restart=restart and i == 0)
        if i % 500 == 499:
            time.sleep(0.02)
    assert ps.wait_for(seq, 30.0) is not None
    return seq


def held(live: Live, robot: str) -> int:
    """How many poses the bridge holds in the robot's capture."""
    bridge: Any = live.client.app.state.bridge  # type: ignore[attr-defined]
    st = next(s for s in bridge.path.streams.values() if s.robot == robot)
    return 0 if st.capture is None else len(st.capture)


def test_a_demonstration_longer_than_an_upload_may_be_is_refused_and_its_capture_ends(
        small: Live) -> None:
    points = along(directrix(small, "arc3"), SMALL + 50)
    with PoseStreamer("arc3", "long", endpoint=small.endpoint, encoding="binary") as ps:
        ps.start_demo()
        send_all(ps, points)
        # the poses past the limit are not held while they come
        assert held(small, "long") == SMALL
        with pytest.raises(LiveError) as refused:
            ps.stop_demo()
        error = refused.value.body["error"]
        assert error["type"] == "payload_too_large" and error["field"] == "positions", error
        assert f"at most {SMALL} poses" in error["message"], error
        assert f"got {SMALL + 50}" in error["message"], error
        assert "CANAL_UPLOAD_MAX_POINTS" in error["message"], error
        with pytest.raises(LiveError, match="no demonstration is being captured"):
            ps.stop_demo()
        # a demonstration within the limit is stored as before
        ps.start_demo()
        send_all(ps, points[:SMALL])
        assert ps.stop_demo()["n_points"] == SMALL


def test_a_steered_run_past_the_capture_limit_is_kept_up_to_it(small: Live) -> None:
    points = along(directrix(small, "arc3"), SMALL + 40)
    with PoseStreamer("arc3", "stick", endpoint=small.endpoint, encoding="binary") as ps:
        send_all(ps, points, steer=True, restart=True)
        assert held(small, "stick") == SMALL
        made = ps.keep_steered()
    assert made["correction"]["n_points"] == SMALL, made["correction"]
    assert any(f"40 captured poses after the first {SMALL} were not held" in n
               for n in made["notes"]), made["notes"]


@pytest.mark.parametrize(("skill", "how"), [("longpush", "correction"),
                                            ("longsteer", "steered run")])
def test_a_capture_longer_than_a_correction_holds_is_thinned_evenly(
        live: Live, skill: str, how: str) -> None:
    """A correction capture, and a steered run, which could never be kept before."""
    make_skill(live.client, skill, 3)
    n = MAX_CORRECTION_SAMPLES + 500
    points = along(directrix(live, skill), n)
    with PoseStreamer(skill, "arm", endpoint=live.endpoint, encoding="binary") as ps:
        if how == "correction":
            ps.send(points[0].tolist(), restart=True)
            ps.start_correction("include")
            send_all(ps, points)
            made = ps.stop_correction(timeout=60.0)
        else:
            send_all(ps, points, steer=True, restart=True)
            made = ps.keep_steered(timeout=60.0)
        assert made["correction"]["n_points"] == MAX_CORRECTION_SAMPLES, made["correction"]
        assert any(f"{n} captured poses thinned to {MAX_CORRECTION_SAMPLES}" in note
                   for note in made["notes"]), made["notes"]
        if how == "steered run":
            with pytest.raises(LiveError, match="no steered run"):
                ps.keep_steered()


def test_a_steered_run_that_ends_while_it_is_kept_is_kept_once(live: Live) -> None:
    make_skill(live.client, "keeponce", 3)
    points = along(directrix(live, "keeponce"), 120)
    database = sqlite3.connect(live.settings.data_dir / "canal.sqlite3", timeout=30.0,
                               isolation_level=None)
    with PoseStreamer("keeponce", "arm", endpoint=live.endpoint, encoding="binary") as ps:
        send_all(ps, points[:60], steer=True, restart=True)
        # no pose since the last input: the run is still in progress when the keep takes it
        time.sleep(STEER_TIMEOUT_S + 0.1)
        kept: dict[str, Any] = {}
        # another writer holds the database: the keep waits to store what it took
        database.execute("BEGIN IMMEDIATE")
        keeper = threading.Thread(target=lambda: kept.update(ps.keep_steered(timeout=30.0)))
        keeper.start()
        try:
            time.sleep(0.3)
            # the next pose ends the run (no input for STEER_TIMEOUT_S) while it is stored
            send_all(ps, points[60:])
            time.sleep(0.2)
        finally:
            database.execute("ROLLBACK")
        keeper.join(30.0)
        assert kept["correction"]["n_points"] == 60, kept
        with pytest.raises(LiveError, match="no steered run"):
            ps.keep_steered()
    database.close()
    corrections = live.client.get("/skills/keeponce/corrections").json()
    items = corrections["items"] if isinstance(corrections, dict) else corrections
    assert len(items) == 1, items


@pytest.mark.parametrize("start", ["demo", "correction"])
def test_a_capture_begun_during_a_steered_run_ends_it_keepable(live: Live, start: str) -> None:
    skill = f"over{start}"
    make_skill(live.client, skill, 3)
    points = along(directrix(live, skill), 140)
    with PoseStreamer(skill, "arm", endpoint=live.endpoint, encoding="binary") as ps:
        send_all(ps, points[:80], steer=True, restart=True)
        began = ps.start_demo() if start == "demo" else ps.start_correction("include")
        assert began["discarded"] == 0, began
        send_all(ps, points[80:])
        stored = ps.stop_demo() if start == "demo" else ps.stop_correction()
        assert stored["n_points" if start == "demo" else "correction"]
        made = ps.keep_steered()
    assert made["correction"]["n_points"] == 80, made["correction"]
