"""Recordings behind a load balancer: two replicas (two apps, each behind its own uvicorn,
each with its own recordings folder) on one real PostgreSQL.

A recording belongs to the skill it records, not to its name: after a delete and re-create
on one replica, the other never serves the deleted skill's files. And every replica answers
the same recording for the same database, whichever replica served the uploads, fits and
reproductions. Both are read back with mcap's reader and Rerun's own CLI.
"""

from __future__ import annotations

import contextlib
import io
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import orjson
import pytest
from canal_service.app import create_app
from canal_service.core.config import Settings
from canal_service.recording.rerun_log import cli_env
from mcap.reader import make_reader
from service_helpers import LiveServer, PostgresServer, demo_positions

pytestmark = pytest.mark.postgres

WAIT_S = 120.0
LIFT = 5.0  # the re-created skill's demos: the same arcs, 5 up in z


@contextlib.contextmanager
def serve_two(url: str, tmp_path: Path, kept: int
              ) -> Iterator[tuple[httpx.Client, httpx.Client]]:
    """Two replicas on the database at ``url``, each with its own data folder; the database
    keeps a skill's newest ``kept`` reproductions for the recordings."""
    one = Settings(data_dir=tmp_path / "one", database_url=url, zenoh_enabled=False,
                   recordings_reproductions_kept=kept)
    two = Settings(data_dir=tmp_path / "two", database_url=url, zenoh_enabled=False,
                   recordings_reproductions_kept=kept)
    with LiveServer(create_app(one)) as a, LiveServer(create_app(two)) as b, \
            httpx.Client(base_url=a.url, timeout=WAIT_S) as http_a, \
            httpx.Client(base_url=b.url, timeout=WAIT_S) as http_b:
        yield http_a, http_b


@pytest.fixture
def two_replicas(postgres_server: PostgresServer, tmp_path: Path
                 ) -> Iterator[tuple[httpx.Client, httpx.Client]]:
    with serve_two(postgres_server.new_database(), tmp_path, kept=2) as replicas:
        yield replicas


def upload(http: httpx.Client, skill: str, demos: list[np.ndarray]) -> list[int]:
    ids = []
    for positions in demos:
        r = http.post(f"/skills/{skill}/demonstrations", json={"positions": positions.tolist()})
        assert r.status_code == 201, r.text
        ids.append(r.json()["id"])
    return ids


def fit(http: httpx.Client, skill: str) -> int:
    r = http.post(f"/skills/{skill}/fit", json={"n_samples": 30})
    assert r.status_code == 201, r.text
    return int(r.json()["version"])


def reproduce(http: httpx.Client, skill: str, start: list[float]) -> None:
    r = http.post(f"/skills/{skill}/reproductions", json={"start": start})
    assert r.status_code == 200, r.text


def mcap_content(http: httpx.Client, skill: str) -> dict[str, Any]:
    """What an exported MCAP holds: demo ids, model versions with their directrix's end,
    reproduction numbers, each with its log time."""
    r = http.get(f"/skills/{skill}/recording.mcap")
    assert r.status_code == 200, r.text
    demos: dict[int, int] = {}
    models: dict[int, tuple[int, float]] = {}
    reproductions: dict[int, int] = {}
    reader = make_reader(io.BytesIO(r.content))
    for _schema, channel, message in reader.iter_messages(log_time_order=True):
        data = orjson.loads(message.data)
        if channel.topic == "/canal/demos":
            for entity in data["entities"]:
                demos[int(entity["id"].split("/")[1])] = message.log_time
            for deletion in data.get("deletions", []):
                demos.pop(int(deletion["id"].split("/")[1]), None)
        elif channel.topic == "/canal/model":
            for entity in data["entities"]:
                if entity["id"] == "canal/directrix":
                    meta = {kv["key"]: kv["value"] for kv in entity["metadata"]}
                    end_z = float(entity["lines"][0]["points"][-1]["z"])
                    models[int(meta["version"])] = (message.log_time, round(end_z, 6))
        elif channel.topic == "/canal/reproductions":
            for entity in data["entities"]:
                reproductions[int(entity["id"].split("/")[1])] = message.log_time
            for deletion in data.get("deletions", []):
                reproductions.pop(int(deletion["id"].split("/")[1]), None)
    return {"demos": demos, "models": models, "reproductions": reproductions}


def rrd_entities(http: httpx.Client, skill: str, tmp_path: Path) -> set[str]:
    """Top entity paths (``demos/<id>``, ``reproductions/<n>``) of the exported ``.rrd``, as
    ``rerun rrd print`` lists them."""
    import subprocess

    from canal_service.recording.rerun_log import rerun_cli

    r = http.get(f"/skills/{skill}/recording.rrd")
    assert r.status_code == 200, r.text
    path = tmp_path / f"{skill}-{http.base_url.port}.rrd"
    path.write_bytes(r.content)
    proc = subprocess.run([*rerun_cli(), "rrd", "print", str(path)], capture_output=True,
                          text=True, timeout=120, env=cli_env(tmp_path / "rerun-config"))
    assert proc.returncode == 0, proc.stderr[-2000:]
    found = set()
    for line in proc.stdout.splitlines():
        for part in line.split():
            if part.startswith(("/demos/", "/reproductions/")):
                found.add("/".join(part.split("/")[1:3]))
    return found


def test_a_deleted_skill_is_never_served_by_another_replica(
        two_replicas: tuple[httpx.Client, httpx.Client], tmp_path: Path) -> None:
    one, two = two_replicas
    assert one.post("/skills", json={"name": "curve", "dim": 3}).status_code == 201
    old_ids = upload(one, "curve", [demo_positions(j) for j in range(4)])
    assert fit(one, "curve") == 1 and fit(one, "curve") == 2
    reproduce(one, "curve", [0.0, 0.0, 0.0])
    before = mcap_content(one, "curve")  # replica one has written its files
    assert set(before["demos"]) == set(old_ids) and set(before["models"]) == {1, 2}

    assert two.delete("/skills/curve").status_code == 204
    assert one.get("/skills/curve/recording.mcap").status_code == 404
    assert one.get("/skills/curve/recording.rrd").status_code == 404
    assert two.post("/skills", json={"name": "curve", "dim": 3}).status_code == 201
    new_ids = upload(two, "curve", [demo_positions(j) + [0.0, 0.0, LIFT] for j in range(3)])
    assert fit(two, "curve") == 1

    for http in (one, two):
        content = mcap_content(http, "curve")
        assert set(content["demos"]) == set(new_ids)
        assert list(content["models"]) == [1]
        assert content["models"][1][1] == pytest.approx(LIFT + 0.1, abs=0.05)  # the new canal
        assert content["reproductions"] == {}
        entities = rrd_entities(http, "curve", tmp_path)
        assert entities == {f"demos/{i}" for i in new_ids}


def test_every_replica_answers_the_same_recording(
        two_replicas: tuple[httpx.Client, httpx.Client], tmp_path: Path) -> None:
    one, two = two_replicas
    assert one.post("/skills", json={"name": "pour", "dim": 3}).status_code == 201
    ids = upload(one, "pour", [demo_positions(j) for j in range(2)])
    ids += upload(two, "pour", [demo_positions(j) for j in range(2, 4)])
    assert fit(two, "pour") == 1
    reproduce(one, "pour", [0.0, 0.0, 0.0])
    reproduce(two, "pour", [0.0, 0.01, 0.0])
    assert one.delete(f"/skills/pour/demonstrations/{ids[0]}").status_code == 204
    ids += upload(one, "pour", [demo_positions(4)])
    assert fit(one, "pour") == 2
    reproduce(two, "pour", [0.0, 0.02, 0.0])

    first = mcap_content(one, "pour")
    second = mcap_content(two, "pour")
    r = two.get("/skills/pour/recording.rrd")  # the export says what is shared, what is not
    assert r.headers["canal-recording-shared"] == "demonstrations, models, reproductions"
    assert r.headers["canal-recording-per-replica"] == "live"
    assert set(first["demos"]) == set(ids[1:])
    assert set(first["models"]) == {1, 2}
    assert set(first["reproductions"]) == {2, 3}  # the newest 2: the first one is cleared
    # the same things at the same log times (the database's), whichever replica served them
    assert first == second
    assert rrd_entities(one, "pour", tmp_path) >= {f"demos/{i}" for i in ids[1:]} | {
        f"reproductions/{n}" for n in (2, 3)}
    # the demo and the reproduction deleted before replica two first wrote the skill are in
    # replica one's history only (logged, then cleared); what the database holds is in both
    deleted = {f"demos/{ids[0]}", "reproductions/1"}
    assert (rrd_entities(one, "pour", tmp_path) - deleted
            == rrd_entities(two, "pour", tmp_path) - deleted)


def test_reproductions_served_at_once_by_both_replicas_are_all_kept(
        postgres_server: PostgresServer, tmp_path: Path) -> None:
    """Both replicas number a skill's reproductions at once: each gets its own number (a
    collision is taken again under the skill's lock), and both recordings hold them all."""
    with serve_two(postgres_server.new_database(), tmp_path, kept=1000) as (one, two):
        assert one.post("/skills", json={"name": "pour", "dim": 3}).status_code == 201
        upload(one, "pour", [demo_positions(j) for j in range(3)])
        assert fit(two, "pour") == 1

        def burst(http: httpx.Client) -> None:
            for k in range(6):
                reproduce(http, "pour", [0.0, 0.001 * k, 0.0])

        with ThreadPoolExecutor(4) as pool:
            list(pool.map(burst, [one, two, one, two]))
        for http in (one, two):
            assert set(mcap_content(http, "pour")["reproductions"]) == set(range(1, 25))
