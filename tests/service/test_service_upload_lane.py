"""Uploads run on their own lane (``upload_workers`` threads), over real HTTP.

What the lane promises: every upload (parse, checks, preparation, insert) runs on a
``canal-upload-*`` thread, not on the shared pool; fits in flight do not hold uploads or
reads up; concurrent uploads to one skill all land, each with the checksum of what was sent,
on SQLite (whose writers queue on a lock) and on PostgreSQL (no lock); a bad upload among
good ones changes nothing.
"""

from __future__ import annotations

import hashlib
import sys
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from canal_service.app import create_app
from canal_service.core.config import Settings
from service_helpers import LiveServer, demo_positions

WAIT_S = 120.0  # generous: a loaded 2-core machine; reached only when something is broken


def checksum(positions: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(positions, dtype="<f8").tobytes()).hexdigest()


def post_demo(http: httpx.Client, skill: str, positions: np.ndarray, **extra: Any) -> httpx.Response:
    return http.post(f"/skills/{skill}/demonstrations",
                     json={"positions": positions.tolist(), **extra})


def stored_checksums(http: httpx.Client, skill: str) -> list[str]:
    page = http.get(f"/skills/{skill}/demonstrations", params={"limit": 1000}).json()
    assert page["total"] == len(page["items"])
    return [item["checksum"] for item in page["items"]]


@pytest.fixture
def lane_server(settings: Settings) -> Iterator[tuple[LiveServer, Any]]:
    app = create_app(settings.model_copy(update={"upload_workers": 2}))
    with LiveServer(app) as server:
        yield server, app


class ThreadNotingRecorder:
    """Stands in for the recorder (the service calls it right after each insert, on the
    thread that stored the demo) and notes that thread's name."""

    def __init__(self) -> None:
        self.threads: list[str] = []

    def demo_added(self, *_args: Any, **_kwargs: Any) -> None:
        self.threads.append(threading.current_thread().name)


def test_uploads_run_on_the_upload_lane(lane_server: tuple[LiveServer, Any]) -> None:
    server, app = lane_server
    noting = ThreadNotingRecorder()
    app.state.service.recorder = noting
    lane = app.state.upload_lane
    with httpx.Client(base_url=server.url, timeout=WAIT_S) as http:
        assert http.post("/skills", json={"name": "pour", "dim": 3}).status_code == 201
        before = lane.stats()["completed"]
        with ThreadPoolExecutor(8) as pool:
            codes = list(pool.map(lambda j: post_demo(http, "pour", demo_positions(j)).status_code,
                                  range(8)))
        assert codes == [201] * 8
        assert lane.stats()["completed"] == before + 8
        # A body that fails to parse was parsed on the lane too: the lane counts it.
        bad = http.post("/skills/pour/demonstrations", content=b'{"positions": [[1, 2, "x"]]}',
                        headers={"content-type": "application/json"})
        assert bad.status_code == 422
        assert lane.stats()["completed"] == before + 9
        # Files too (CSV here).
        csv = "x,y,z\n" + "\n".join(",".join(map(str, row)) for row in demo_positions(9))
        r = http.post("/skills/pour/demonstrations", content=csv,
                      headers={"content-type": "text/csv"})
        assert r.status_code == 201, r.text
        assert lane.stats()["completed"] == before + 10
        assert http.get("/skills/pour").json()["n_demonstrations"] == 9
    assert len(noting.threads) == 9
    assert all(name.startswith("canal-upload-") for name in noting.threads), noting.threads
    assert lane.stats()["workers"] == 2 and lane.stats()["cpu_s"] > 0
    if sys.platform.startswith("linux"):  # the name reaches the OS, for top -H and /proc readers
        names = {p.read_text().strip() for p in Path("/proc/self/task").glob("*/comm")}
        assert names & {"canal-upload-0", "canal-upload-1"}, names


def test_fits_in_flight_do_not_hold_up_uploads_or_reads(
        lane_server: tuple[LiveServer, Any]) -> None:
    """Three fits held inside the service (more than the lane has threads) while uploads
    and reads complete: fits must not share the upload lane, nor uploads wait for them."""
    server, app = lane_server
    n_fits = 3
    release = threading.Event()
    inside = threading.Semaphore(0)

    def hold_fit(_skill: str, _version: int, _canal: Any) -> None:
        inside.release()
        release.wait(WAIT_S)

    app.state.service.fit_listeners.append(hold_fit)
    try:
        with httpx.Client(base_url=server.url, timeout=WAIT_S) as http:
            assert http.post("/skills", json={"name": "pour", "dim": 3}).status_code == 201
            for j in range(3):
                assert post_demo(http, "pour", demo_positions(j)).status_code == 201
            with ThreadPoolExecutor(n_fits) as fitters:
                fits = [fitters.submit(http.post, "/skills/pour/fit", json={"n_samples": 30})
                        for _ in range(n_fits)]
                for _ in range(n_fits):
                    assert inside.acquire(timeout=WAIT_S), "a fit never reached its listener"
                with ThreadPoolExecutor(4) as pool:
                    codes = list(pool.map(
                        lambda j: post_demo(http, "pour", demo_positions(j)).status_code,
                        range(3, 11)))
                read = http.get("/skills/pour")
                assert not any(f.done() for f in fits), "a fit answered before it was released"
                release.set()
                fitted = [f.result(WAIT_S) for f in fits]
            assert codes == [201] * 8
            assert read.status_code == 200 and read.json()["n_demonstrations"] == 11
            assert [r.status_code for r in fitted] == [201] * n_fits
            assert sorted(r.json()["version"] for r in fitted) == [1, 2, 3]
    finally:
        release.set()
        app.state.service.fit_listeners.remove(hold_fit)


def test_concurrent_uploads_to_one_skill_all_land_with_their_checksums(
        any_db_settings: Settings) -> None:
    app = create_app(any_db_settings.model_copy(update={"upload_workers": 2}))
    demos = [demo_positions(j, n=200, seed=j) for j in range(40)]
    with LiveServer(app) as server, httpx.Client(base_url=server.url, timeout=WAIT_S) as http:
        assert http.post("/skills", json={"name": "pour", "dim": 3}).status_code == 201
        with ThreadPoolExecutor(8) as pool:
            answers = list(pool.map(lambda d: post_demo(http, "pour", d), demos))
        assert [a.status_code for a in answers] == [201] * len(demos)
        created = [a.json() for a in answers]
        assert [c["checksum"] for c in created] == [checksum(d) for d in demos]
        assert len({c["id"] for c in created}) == len(demos)
        assert sorted(stored_checksums(http, "pour")) == sorted(checksum(d) for d in demos)
        # read back exactly, whichever thread stored it
        for c, d in list(zip(created, demos, strict=True))[::13]:
            back = http.get(f"/skills/pour/demonstrations/{c['id']}").json()
            np.testing.assert_array_equal(np.asarray(back["positions"]), d)


def _bad_bodies() -> list[tuple[str, dict[str, Any] | bytes]]:
    good = demo_positions(0)
    nan = good.copy()
    nan[7, 1] = np.nan
    return [
        ("positions[7][1]", {"positions": [[float(v) if v == v else None for v in row] for row in nan]}),
        ("positions[3]", {"positions": [*good[:3].tolist(), [1.0, 2.0], *good[4:].tolist()]}),
        ("positions", {"positions": [[1.0, 2.0, 3.0]] * 10}),
        ("positions[0]", {"positions": demo_positions(0, dim=2).tolist()}),
        ("body", b""),
        ("body", b'{"positions": [[1, 2, 3]'),
        # time going back for good (an isolated jump is a raw log's, repaired at fit)
        ("timestamps", {"positions": good[:5].tolist(), "timestamps": [0, 1, 2, 0.1, 0.2]}),
    ]


def test_bad_uploads_among_good_ones_change_nothing(live_server: LiveServer) -> None:
    good = [demo_positions(j, seed=j) for j in range(8)]
    bad = _bad_bodies()
    with httpx.Client(base_url=live_server.url, timeout=WAIT_S) as http:
        assert http.post("/skills", json={"name": "pour", "dim": 3}).status_code == 201

        def send(item: tuple[str, Any]) -> httpx.Response:
            kind, payload = item
            if kind == "good":
                return post_demo(http, "pour", payload)
            content = payload if isinstance(payload, bytes) else None
            return http.post("/skills/pour/demonstrations", content=content,
                             json=None if content is not None else payload,
                             headers={"content-type": "application/json"})

        work: list[tuple[str, Any]] = []
        for j in range(max(len(good), len(bad))):
            if j < len(good):
                work.append(("good", good[j]))
            if j < len(bad):
                work.append(("bad", bad[j][1]))
        with ThreadPoolExecutor(8) as pool:
            answers = list(pool.map(send, work))
        goods = [a for (kind, _), a in zip(work, answers, strict=True) if kind == "good"]
        bads = [a for (kind, _), a in zip(work, answers, strict=True) if kind == "bad"]
        assert [a.status_code for a in goods] == [201] * len(good)
        for (field, _), answer in zip(bad, bads, strict=True):
            assert 400 <= answer.status_code < 500, answer.text
            error = answer.json()["error"]
            assert error["field"] == field or any(
                d.get("field") == field for d in error.get("details", [])), (field, error)
        assert sorted(stored_checksums(http, "pour")) == sorted(checksum(d) for d in good)


def test_write_one_commits_alone_and_fails_as_sqlalchemy_does(any_db_settings: Settings) -> None:
    """The upload's one-statement write (its own connection on SQLite): a failed statement
    leaves nothing behind, raises SQLAlchemy's error, and the next write works."""
    from canal_service.storage import Database, Skill
    from sqlalchemy import func, insert, select
    from sqlalchemy.exc import IntegrityError

    db = Database(any_db_settings.resolved_database_url)
    db.migrate()
    try:
        add = insert(Skill).values(name=bindparam_name(), description="", dim=3).returning(Skill.id)
        first = db.write_one(add, {"name": "a"})
        assert first is not None and first[0] >= 1
        with pytest.raises(IntegrityError):
            db.write_one(add, {"name": "a"})  # unique name
        second = db.write_one(add, {"name": "b"})
        assert second is not None and second[0] > first[0]
        with db.read() as session:
            assert session.scalar(select(func.count()).select_from(Skill)) == 2
    finally:
        db.dispose()


def bindparam_name() -> Any:
    from sqlalchemy import bindparam

    return bindparam("name")


def test_a_lane_runs_on_its_named_threads_raises_what_they_raise_and_restarts() -> None:
    import asyncio

    from canal_service.lanes import Lane

    lane = Lane("probe", 1)

    def where(x: int) -> tuple[str, int]:
        return threading.current_thread().name, x * 2

    def fail() -> None:
        raise LookupError("from the lane")

    async def use() -> tuple[str, int]:
        with pytest.raises(LookupError, match="from the lane"):
            await lane.run(fail)
        return await lane.run(where, 21)

    try:
        assert asyncio.run(use()) == ("canal-probe-0", 42)
        lane.close()  # an app's lifespan may end and start again
        name, value = asyncio.run(use())
        assert name.startswith("canal-probe-") and value == 42
        assert lane.stats()["completed"] == 4
    finally:
        lane.close()


def test_wal_checkpoints_run_off_the_upload_path(tmp_path: Path) -> None:
    """Uploads' inserts leave checkpoints to a thread of their own: the rows still reach the
    database file (not only the WAL) while nobody else writes."""
    from canal_service.storage import Database
    from canal_service.storage import repository as repo

    def checkpointers() -> set[threading.Thread]:
        return {t for t in threading.enumerate() if t.name == "canal-checkpoint"}

    others = checkpointers()  # of databases other tests left open
    path = tmp_path / "canal.sqlite3"
    db = Database(f"sqlite:///{path}")
    db.migrate()
    try:
        with db.write() as session:
            repo.create_skill(session, "pour", "", 3)
        size_before = path.stat().st_size
        demos = [demo_positions(j, n=1000, seed=j) for j in range(60)]  # ~1.4 MB of rows
        stored = [repo.insert_demonstration(db, "pour", d, None, None, None, "json") for d in demos]
        assert [s.checksum for s in stored] == [checksum(d) for d in demos]
        ours = checkpointers() - others
        assert len(ours) == 1
        deadline = time.monotonic() + WAIT_S
        while path.stat().st_size < size_before + 1_000_000 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert path.stat().st_size >= size_before + 1_000_000, "the WAL was never checkpointed"
    finally:
        db.dispose()
    assert not any(t.is_alive() for t in ours)
