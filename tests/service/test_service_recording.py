"""Recorder wiring: exports stream as files, health shows the recorder.

Needs ``canal_service.recording`` (written separately); skipped with a reason until it exists.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import httpx
from canal_service.app import create_app
from canal_service.core.config import Settings
from fastapi.testclient import TestClient
from service_helpers import demo_positions


def test_recordings_disabled_is_a_clean_404(client: TestClient, skill: str) -> None:
    for kind in ("rrd", "mcap"):
        r = client.get(f"/skills/{skill}/recording.{kind}")
        assert r.status_code == 404 and r.json()["error"]["type"] == "disabled"
    assert client.get("/healthz").json()["recorder"]["status"] == "disabled"


def test_recording_exports(tmp_path: Path) -> None:
    settings = Settings(data_dir=tmp_path / "data", recordings_enabled=True, zenoh_enabled=False)
    with TestClient(create_app(settings)) as c:
        health = c.get("/healthz").json()
        assert health["recorder"]["status"] == "ok"
        c.post("/skills", json={"name": "pour", "dim": 3})
        ids = [c.post("/skills/pour/demonstrations",
                      json={"positions": demo_positions(j).tolist()}).json()["id"]
               for j in range(3)]
        assert c.post("/skills/pour/fit", json={"n_samples": 30}).status_code == 201
        assert c.post("/skills/pour/reproductions", json={"start": [0, 0, 0]}).status_code == 200
        assert c.delete(f"/skills/pour/demonstrations/{ids[0]}").status_code == 204
        rrd = c.get("/skills/pour/recording.rrd")
        assert rrd.status_code == 200 and len(rrd.content) > 0
        mcap = c.get("/skills/pour/recording.mcap")
        assert mcap.status_code == 200 and mcap.content.startswith(b"\x89MCAP0\r\n")
        assert c.get("/skills/nope/recording.rrd").status_code == 404
    assert settings.resolved_recordings_dir.exists()


def test_a_download_tool_can_ask_the_size_and_resume(tmp_path: Path) -> None:
    # HEAD (curl -I, wget --spider, download managers) was 405; a Range header the file
    # cannot answer was a 400 in plain text. A Range in a unit other than bytes, or one
    # that does not parse, is ignored (RFC 9110, 14.2): the whole file comes.
    settings = Settings(data_dir=tmp_path / "data", recordings_enabled=True, zenoh_enabled=False)
    with TestClient(create_app(settings)) as c:
        c.post("/skills", json={"name": "pour", "dim": 3})
        for j in range(3):
            c.post("/skills/pour/demonstrations", json={"positions": demo_positions(j).tolist()})
        for kind in ("rrd", "mcap"):
            url = f"/skills/pour/recording.{kind}"
            head = c.head(url)
            assert head.status_code == 200 and head.content == b"", head.text
            assert int(head.headers["content-length"]) > 0
            assert c.head("/skills/nope/recording.rrd").status_code == 404
            whole = c.get(url).content
            part = c.get(url, headers={"range": "bytes=0-9"})
            assert part.status_code == 206 and part.content == whole[:10]
            for odd in ("bytes=5-2", "bytes=abc", "lines=0-1", "bytes", "bytes=-"):
                r = c.get(url, headers={"range": odd})
                assert r.status_code == 200 and len(r.content) == len(whole), (odd, r.status_code, r.text[:80])


def test_rebuild_regenerates_the_recording_from_the_database(tmp_path: Path) -> None:
    import shutil

    from canal_client.cli import app
    from canal_testing import LiveServer
    from mcap.reader import make_reader
    from typer.testing import CliRunner

    settings = Settings(data_dir=tmp_path / "data", recordings_enabled=True, zenoh_enabled=False)
    with LiveServer(create_app(settings)) as server, httpx.Client(base_url=server.url) as c:
        c.post("/skills", json={"name": "pour", "dim": 3})
        ids = [c.post("/skills/pour/demonstrations",
                      json={"positions": demo_positions(j).tolist()}).json()["id"]
               for j in range(3)]
        assert c.post("/skills/pour/fit", json={"n_samples": 30}).status_code == 201
        assert c.post("/skills/pour/reproductions", json={"start": [0, 0, 0]}).status_code == 200
        assert c.delete(f"/skills/pour/demonstrations/{ids[0]}").status_code == 204
        assert c.get("/skills/pour/recording.mcap").status_code == 200  # written out
        # The recording is lost (a disk swap, a deleted folder): rebuild it from the database.
        shutil.rmtree(settings.resolved_recordings_dir / "pour")
        r = CliRunner().invoke(app, ["--url", server.url, "--json", "recordings", "rebuild",
                                     "pour"])
        assert r.exit_code == 0, r.output
        # the reproduction is kept in the database (SQLite here), so it comes back too
        assert json.loads(r.output) == {"skill": "pour", "demos": 2, "models": 1, "removed": 0,
                                       "reproductions": 1}
        mcap = c.get("/skills/pour/recording.mcap").content
        assert c.post("/skills/nope/recording/rebuild").status_code == 404
        ros2 = tmp_path / "pour-ros2.mcap"
        r = CliRunner().invoke(app, ["--url", server.url, "export", "pour", "--mcap", str(ros2),
                                     "--ros2"])
        assert r.exit_code == 0, r.output
        assert make_reader(io.BytesIO(ros2.read_bytes())).get_header().profile == "ros2"
        assert c.get("/skills/pour/recording.mcap", params={"profile": "bag"}).status_code == 422
    reader = make_reader(io.BytesIO(mcap))
    demos = {e["id"] for _, _, m in reader.iter_messages(topics=["/canal/demos"])
             for e in json.loads(m.data)["entities"]}
    assert demos == {f"demo/{ids[1]}", f"demo/{ids[2]}"}  # the deleted one stays gone
    models = [m for _, _, m in make_reader(io.BytesIO(mcap)).iter_messages(
        topics=["/canal/model_info"])]
    assert len(models) == 1


def test_rebuild_answers_404_when_recordings_are_off(client: TestClient, skill: str) -> None:
    r = client.post(f"/skills/{skill}/recording/rebuild")
    assert r.status_code == 404 and r.json()["error"]["type"] == "disabled"


def test_a_restart_reconciles_the_recording_with_the_database(tmp_path: Path) -> None:
    """Changes made while recordings were off show up once they are on again."""
    from mcap.reader import make_reader

    def settings(recordings: bool) -> Settings:
        return Settings(data_dir=tmp_path / "data", recordings_enabled=recordings,
                        zenoh_enabled=False)

    with TestClient(create_app(settings(True))) as c:
        c.post("/skills", json={"name": "pour", "dim": 3})
        ids = [c.post("/skills/pour/demonstrations",
                      json={"positions": demo_positions(j).tolist()}).json()["id"]
               for j in range(3)]
        assert c.get("/skills/pour/recording.mcap").status_code == 200
    with TestClient(create_app(settings(False))) as c:  # the recorder does not hear these
        assert c.delete(f"/skills/pour/demonstrations/{ids[0]}").status_code == 204
        late = c.post("/skills/pour/demonstrations",
                      json={"positions": demo_positions(7).tolist()}).json()["id"]
        assert c.post("/skills/pour/fit", json={"n_samples": 30}).status_code == 201
    with TestClient(create_app(settings(True))) as c:
        mcap = c.get("/skills/pour/recording.mcap").content
        reconciled = c.get("/healthz").json()["recorder"]["reconciled"]
    assert reconciled == {"demos": 1, "models": 1, "removed": 1, "reproductions": 0}
    shown: set[str] = set()
    for _, _, m in make_reader(io.BytesIO(mcap)).iter_messages(topics=["/canal/demos"],
                                                               log_time_order=False):
        update = json.loads(m.data)
        shown |= {e["id"] for e in update["entities"]}
        shown -= {d["id"] for d in update["deletions"]}
    assert shown == {f"demo/{ids[1]}", f"demo/{ids[2]}", f"demo/{late}"}
    models = list(make_reader(io.BytesIO(mcap)).iter_messages(topics=["/canal/model_info"]))
    assert len(models) == 1


def test_no_snapshot_is_left_behind_whatever_the_answer(tmp_path: Path) -> None:
    # A range past the end is a 416: Starlette answers it without running the response's
    # background task, so each such request used to leave its snapshot in .exports.
    settings = Settings(data_dir=tmp_path / "data", recordings_enabled=True, zenoh_enabled=False)
    exports = settings.resolved_recordings_dir / ".exports"
    with TestClient(create_app(settings)) as c:
        c.post("/skills", json={"name": "pour", "dim": 3})
        for j in range(3):
            c.post("/skills/pour/demonstrations", json={"positions": demo_positions(j).tolist()})
        assert c.post("/skills/pour/fit", json={"n_samples": 30}).status_code == 201
        for url in ("/skills/pour/recording.rrd", "/skills/pour/recording.mcap",
                    "/skills/pour/recording.mcap?profile=ros2"):
            far = c.get(url, headers={"range": "bytes=999999999-"})
            assert far.status_code == 416, (url, far.status_code)
            assert far.headers["content-range"].startswith("bytes */")
            # in the one JSON error shape every 4xx has (it was an empty text/plain)
            assert far.json()["error"]["type"] == "range_not_satisfiable", far.text
            assert far.json()["error"]["field"] == "Range", far.text
            # A suffix of no bytes asks for nothing: refused in the same shape (it was an empty
            # text/plain 416); beside a range that can be served, the range is served
            # (RFC 9110, 15.3.7: a set is satisfiable when one of its ranges is).
            empty = c.get(url, headers={"range": "bytes=-0"})
            assert empty.status_code == 416 and empty.json()["error"]["field"] == "Range"
            for asked in ("bytes=0-3, 999999999-", "bytes=0-3,-0"):
                several = c.get(url, headers={"range": asked})
                assert several.status_code == 206, (asked, several.status_code)
                assert several.headers["content-range"].startswith("bytes 0-3/"), asked
                assert len(several.content) == 4, asked
            # If-Range with a date: the snapshot may change within the second the date names
            # (RFC 9110, 13.1.5: not a strong validator), so the whole file is sent.
            whole = c.get(url)
            dated = c.get(url, headers={"range": "bytes=0-3",
                                        "if-range": whole.headers["last-modified"]})
            assert dated.status_code == 200 and len(dated.content) > 4, url
            tagged = c.get(url, headers={"range": "bytes=0-3", "if-range": whole.headers["etag"]})
            if "ros2" in url:  # converted afresh for every download: never the same file
                assert tagged.status_code == 200, url
            else:
                assert tagged.status_code == 206 and tagged.content == whole.content[:4], url
            assert c.head(url, headers={"range": "bytes=999999999-"}).status_code == 416
            assert c.head(url).status_code == 200
            assert c.get(url, headers={"range": "bytes=0-3"}).status_code == 206
            assert c.get(url).status_code == 200
            assert sorted(p.name for p in exports.iterdir()) == [], url
