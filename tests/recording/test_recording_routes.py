"""A model of several routes in the recordings: each route its own entity in the .rrd and in
the MCAP (Foxglove and ros2 profiles), read back by their readers; and through the service,
fitted over HTTP and rebuilt from the database."""

from __future__ import annotations

import io
import json
import shutil
from pathlib import Path
from typing import Any

import httpx
import jsonschema_rs
import numpy as np
import pytest
from canal_service.app import create_app
from canal_service.core.config import Settings
from canal_service.recording import Recorder
from canal_service.recording.foxglove import SCHEMAS
from canal_testing import LiveServer, fit_two_route_skill, two_route_demo
from mcap.reader import make_reader
from recording_helpers import mcap_messages, rrd_rows, rrd_verify
from rosbags import highlevel

import canal_core


@pytest.fixture(scope="module")
def routes() -> canal_core.Routes:
    fitted = canal_core.fit_routes([two_route_demo(j) for j in range(8)], n_samples=40)
    assert fitted.n_routes == 2
    return fitted


def test_each_route_is_its_own_entity_in_the_rrd(recorder: Recorder, routes: Any,
                                                 rerun_env: dict[str, str]) -> None:
    recorder.model_fitted("reach", 1, routes)
    path = recorder.export_rrd("reach")
    assert rrd_verify(path, rerun_env).returncode == 0
    rows = rrd_rows(path, rerun_env)
    for k in range(routes.n_routes):
        base = f"/model/v1/route_{k}"
        assert rows[(f"{base}/mesh", "Mesh3D:vertex_positions")] == 1, base
        assert rows[(f"{base}/directrix", "LineStrips3D:strips")] == 1, base
        assert rows[(f"{base}/rings", "LineStrips3D:strips")] == 1, base
        assert rows[(f"{base}/radius", "BarChart:values")] == 1, base
        assert rows[(f"{base}/info", "route")] == 1, base
    assert not any("route_2" in entity for entity, _ in rows)
    # The canal of all the demonstrations is not drawn: no reproduction follows it, and its
    # wide tube between the routes would hide them.
    for part in ("mesh", "directrix", "rings"):
        assert not any(entity == f"/model/v1/{part}" for entity, _ in rows), part
    assert rows[("/model/v1/info", "routes")] == 1


def test_a_model_of_one_route_after_one_of_two_is_drawn_alone(
        recorder: Recorder, routes: Any, rerun_env: dict[str, str]) -> None:
    one = canal_core.fit_routes([two_route_demo(j) for j in range(4)], n_samples=40)
    assert one.n_routes == 1
    recorder.model_fitted("reach", 1, routes)
    recorder.model_fitted("reach", 2, one)
    rows = rrd_rows(recorder.export_rrd("reach"), rerun_env)
    assert rows[("/model/v2/mesh", "Mesh3D:vertex_positions")] == 1
    assert not any(entity.startswith("/model/v2/route_") for entity, _ in rows)
    # Foxglove: the second update deletes every entity first, then draws the one canal.
    first, second = mcap_messages(recorder.export_mcap("reach"), "/canal/model")
    assert {e["id"] for e in first["entities"]} >= {"canal/route_0/mesh", "canal/route_1/mesh"}
    assert [d["type"] for d in second["deletions"]] == [1]  # DELETE_ALL
    assert {e["id"] for e in second["entities"]} == {
        "canal/mesh", "canal/directrix", "canal/rings", "canal/frames"}


def test_the_canal_of_all_is_not_meshed_for_a_model_of_several_routes(routes: Any) -> None:
    from canal_service.recording.geometry import model_geometry

    geo = model_geometry(3, routes)
    assert geo.vertices.shape == (0, 3) and geo.rings.shape[0] == 0 and geo.frame_origins.size == 0
    np.testing.assert_allclose(geo.radii, routes.pooled.radii)  # what the model info says
    assert geo.n_sections == routes.pooled.n_sections
    assert all(r.vertices.shape[0] > 0 and r.frame_origins.shape[0] > 0 for r in geo.routes)


def test_each_route_is_its_own_entity_in_the_mcap(recorder: Recorder, routes: Any) -> None:
    recorder.model_fitted("reach", 1, routes)
    path = recorder.export_mcap("reach")
    (update,) = mcap_messages(path, "/canal/model")
    entities = {e["id"]: e for e in update["entities"]}
    for k, canal in enumerate(routes.canals):
        assert {f"canal/route_{k}/{part}" for part in ("mesh", "directrix", "rings")} <= set(entities)
        (line,) = entities[f"canal/route_{k}/directrix"]["lines"]
        points = np.array([[p["x"], p["y"], p["z"]] for p in line["points"]])
        np.testing.assert_allclose(points, canal.directrix)
        meta = {m["key"]: m["value"] for m in entities[f"canal/route_{k}/mesh"]["metadata"]}
        assert meta["route"] == str(k)
    assert not {"canal/mesh", "canal/directrix", "canal/rings"} & set(entities)
    (info,) = mcap_messages(path, "/canal/model_info")
    assert info["routes"] == 2
    validator = jsonschema_rs.validator_for(SCHEMAS["canal.ModelInfo"])
    validator.validate(info)

    ros2 = recorder.export_mcap("reach", profile="ros2")
    topics: dict[str, int] = {}
    with highlevel.AnyReader([ros2]) as reader:
        for conn, _t, raw in reader.messages():
            message = reader.deserialize(raw, conn.msgtype)
            topics[conn.topic] = topics.get(conn.topic, 0) + 1
            if conn.topic == "/canal/model/route_1/directrix":
                got = np.array([[p.pose.position.x, p.pose.position.y, p.pose.position.z]
                                for p in message.poses])
                np.testing.assert_allclose(got, routes.canals[1].directrix)
            if conn.topic == "/canal/model/mesh":
                assert message.markers[0].action == 3  # DELETEALL: the previous model goes
                namespaces = {m.ns for m in message.markers[1:]}
                assert namespaces == {f"canal/route_{k}/{part}" for k in (0, 1)
                                      for part in ("mesh", "rings")} | {"canal/frames"}
    assert topics["/canal/model/route_0/directrix"] == 1
    assert topics["/canal/model/route_1/directrix"] == 1
    assert "/canal/model/directrix" not in topics


def test_a_fit_of_two_routes_over_http_is_recorded_and_rebuilt(tmp_path: Path) -> None:
    settings = Settings(data_dir=tmp_path / "data", recordings_enabled=True, zenoh_enabled=False)
    with LiveServer(create_app(settings)) as server, \
            httpx.Client(base_url=server.url, timeout=60) as c:
        fit_two_route_skill(c, "reach", 40)
        for rebuilt in (False, True):
            if rebuilt:  # lost, then regenerated from the database
                shutil.rmtree(settings.resolved_recordings_dir / "reach")
                assert c.post("/skills/reach/recording/rebuild").status_code == 200
            mcap = c.get("/skills/reach/recording.mcap").content
            reader = make_reader(io.BytesIO(mcap))
            ids = {e["id"] for _, _, m in reader.iter_messages(topics=["/canal/model"])
                   for e in json.loads(m.data)["entities"]}
            assert {"canal/route_0/mesh", "canal/route_1/mesh"} <= ids, rebuilt
            assert "canal/mesh" not in ids, rebuilt


def test_live_rows_say_which_route_their_stream_followed(recorder: Recorder, routes: Any) -> None:
    from canal_service.recording.events import live_rows

    recorder.model_fitted("reach", 1, routes)
    m = 5
    t0 = 1_700_000_000_000_000_000

    def rows(robot: str, route: Any) -> Any:
        return live_rows("reach", robot, t0 + np.arange(m), np.zeros((m, 3)), None,
                         np.zeros((m, 3)), None, np.linspace(0, 1, m), np.ones(m), np.arange(m),
                         np.ones(m, bool), np.zeros(m, bool), route)

    recorder.live_rows([rows("arm", np.ones(m, int)), rows("solo", None)])
    path = recorder.export_mcap("reach")
    states = {topic: [msg.get("route") for msg in mcap_messages(path, topic)]
              for topic in ("/live/arm/state", "/live/solo/state")}
    assert states == {"/live/arm/state": [1] * m, "/live/solo/state": [None] * m}
    validator = jsonschema_rs.validator_for(SCHEMAS["canal.TrackerState"])
    for msg in mcap_messages(path, "/live/arm/state"):
        validator.validate(msg)
