"""Fitting, model versions, meshes and reproductions."""

from __future__ import annotations

import io
import json
import threading
import time

import httpx
import numpy as np
import pytest
import trimesh
from canal_service.app import create_app
from canal_service.core.config import Settings
from fastapi.testclient import TestClient
from service_helpers import LiveServer, demo_positions


def test_model_detail_and_serialized_round_trip(client: TestClient, fitted: str) -> None:
    import canal_core

    model = client.get(f"/skills/{fitted}/models/1?serialized=true").json()
    assert model["version"] == 1 and model["section_kind"] == "circle" and model["dim"] == 3
    assert model["sections"]["kind"] == "circle"
    canal = canal_core.Canal.from_dict(model["serialized"])
    assert np.allclose(canal.directrix, model["directrix"])
    assert np.allclose(canal.radii, model["radii"])
    assert client.get(f"/skills/{fitted}/models/latest").json()["serialized"] is None


@pytest.mark.parametrize("fmt", ["ply", "obj", "glb"])
def test_mesh_file_formats_load_in_trimesh(client: TestClient, fitted: str, fmt: str) -> None:
    r = client.get(f"/skills/{fitted}/models/latest/mesh?format={fmt}&n_angles=12")
    assert r.status_code == 200, r.text
    assert f".{fmt}" in r.headers["content-disposition"]
    loaded = trimesh.load(io.BytesIO(r.content), file_type=fmt, force="mesh", process=False)
    assert len(loaded.vertices) == 50 * 12 and len(loaded.faces) > 0


def test_mesh_json_matches_canal_core(client: TestClient, fitted: str) -> None:
    import canal_core

    r = client.get(f"/skills/{fitted}/models/1/mesh?format=json&caps=true")
    assert r.status_code == 200 and r.headers["content-type"] == "application/json"
    mesh = r.json()
    serialized = client.get(f"/skills/{fitted}/models/1?serialized=true").json()["serialized"]
    expected = canal_core.Canal.from_dict(serialized).mesh(caps=True)
    assert np.allclose(mesh["vertices"], expected.vertices)
    assert np.array_equal(mesh["faces"], expected.faces)


def test_envelope_mesh_only_for_circles_is_a_422(client: TestClient, fitted: str) -> None:
    client.post(f"/skills/{fitted}/fit", json={"cross_section": "ellipse", "n_samples": 30})
    r = client.get(f"/skills/{fitted}/models/2/mesh?envelope=true")
    assert r.status_code == 422 and r.json()["error"]["field"] == "envelope"
    assert client.get(f"/skills/{fitted}/models/1/mesh?envelope=true").status_code == 200


def test_batch_reproductions_and_versions(client: TestClient, fitted: str) -> None:
    model = client.get(f"/skills/{fitted}/models/latest").json()
    d = np.asarray(model["directrix"])
    starts = [d[0].tolist(), d[10].tolist(), [0.0, 3.0, 0.0]]
    r = client.post(f"/skills/{fitted}/reproductions", json={"starts": starts, "model": 1})
    assert r.status_code == 200, r.text
    reps = r.json()["reproductions"]
    assert [x["inside"] for x in reps] == [True, True, False]
    assert [x["projected"] for x in reps] == [False, False, True]
    assert reps[1]["section_index"] >= 5 and all(x["model_version"] == 1 for x in reps)
    single = client.post(f"/skills/{fitted}/reproductions", json={"start": starts[1]}).json()
    assert np.allclose(single["positions"], reps[1]["positions"])
    assert 0.0 <= single["eta"] <= 1.0
    # a second version; reproductions against the old one still work
    client.post(f"/skills/{fitted}/fit", json={"n_samples": 20})
    assert client.post(f"/skills/{fitted}/reproductions",
                       json={"start": starts[0]}).json()["model_version"] == 2
    old = client.post(f"/skills/{fitted}/reproductions", json={"start": starts[0], "model": 1})
    assert old.json()["model_version"] == 1 and len(old.json()["positions"]) <= 50


def test_persistence_chooses_how_the_starts_offset_is_carried(client: TestClient, fitted: str) -> None:
    import canal_core

    # The four demonstrations are one arc shifted by 0.02 each, their ends off the mean as
    # their starts are. From the last one's start, "learned+end" ends off the canal's end,
    # towards its own; the default lands on the canal's end; every choice is canal_core's own
    # reproduction of the model.
    serialized = client.get(f"/skills/{fitted}/models/1?serialized=true").json()["serialized"]
    canal = canal_core.Canal.from_dict(serialized)
    start = demo_positions(3)[0]
    ends = {}
    for persistence in ("learned", "constant", "learned+end"):
        r = client.post(f"/skills/{fitted}/reproductions",
                        json={"start": start.tolist(), "persistence": persistence})
        assert r.status_code == 200, r.text
        path = np.asarray(r.json()["positions"])
        expected = canal.reproduce_detailed(start, persistence=persistence).positions
        assert np.allclose(path, expected), persistence
        ends[persistence] = path[-1]
    default = client.post(f"/skills/{fitted}/reproductions", json={"start": start.tolist()}).json()
    assert np.allclose(default["positions"][-1], ends["learned"])
    assert np.allclose(ends["learned"], canal.directrix[-1], atol=1e-9)
    own_end = demo_positions(3)[-1]
    assert np.linalg.norm(ends["learned+end"] - canal.directrix[-1]) > 0.005
    assert np.linalg.norm(ends["learned+end"] - own_end) < np.linalg.norm(ends["learned"] - own_end)


def test_a_start_behind_the_first_plane_is_answered_with_its_approach(client: TestClient, fitted: str) -> None:
    """A start well behind the canal's first plane: the answer's positions reach the first
    section along a straight line in steps like the demonstrations' first ones (not one
    jump), counted in ``approach``; a start on the first section has none."""
    model = client.get(f"/skills/{fitted}/models/latest").json()
    d = np.asarray(model["directrix"])
    back = d[0] - 8.0 * (d[1] - d[0])
    r = client.post(f"/skills/{fitted}/reproductions", json={"starts": [back.tolist(), d[0].tolist()],
                                                              "duration": 2.0})
    assert r.status_code == 200, r.text
    behind, on = r.json()["reproductions"]
    m = behind["approach"]
    assert m >= 5 and on["approach"] == 0
    # how far out each position is: the start's own ratio first, then one per position
    for answer in (behind, on):
        assert len(answer["ratios"]) == len(answer["positions"]), answer["ratios"]
        assert all(isinstance(x, float) and np.isfinite(x) for x in answer["ratios"])
    assert on["ratios"][0] == pytest.approx(on["eta"]) and on["ratios"][-1] == pytest.approx(0.0, abs=1e-9)
    positions = np.asarray(behind["positions"])
    assert len(positions) == len(on["positions"]) + m and len(behind["times"]) == len(positions)
    steps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    assert steps.max() < 2.0 * np.linalg.norm(np.diff(d, axis=0), axis=1).max()
    line = positions[m + 1] - back
    across = np.cross(positions[1 : m + 1] - back, line) / np.linalg.norm(line)
    assert np.abs(across).max() < 1e-9 * np.linalg.norm(line)


def test_fit_subset_options_and_timestamps(client: TestClient, skill: str) -> None:
    ids = []
    for j in range(3):
        body = {"positions": demo_positions(j).tolist(),
                "timestamps": (np.arange(50) * (0.02 + 0.01 * j)).tolist()}
        ids.append(client.post(f"/skills/{skill}/demonstrations", json=body).json()["id"])
    r = client.post(f"/skills/{skill}/fit", json={
        "demo_ids": ids[:2], "alignment": "dtw", "directrix": "mean", "frames": "frenet",
        "cross_section": "mec", "n_samples": 30, "by_time": True, "frame_smoothing": 0.0})
    assert r.status_code == 201, r.text
    m = r.json()
    assert m["demo_ids"] == ids[:2] and m["n_demos"] == 2 and m["section_kind"] == "mec"
    assert m["options"] == {"cross_section": "mec", "frames": "frenet", "alignment": "dtw",
                            "directrix": "mean", "n_samples": 30, "frame_smoothing": 0.0,
                            "by_time": True, "clock": "time", "orientation": False}
    # By default the fit's timing test chooses: these demos keep one rhythm (each at its own
    # steady rate), so their time share is blended with their arc-length share; the answer
    # says so. by_time=true aligns by time alone, by_time=false by arc length alone.
    default = client.post(f"/skills/{skill}/fit", json={"demo_ids": ids[:2], "n_samples": 30})
    assert default.json()["options"]["clock"] == "time+arc" and default.json()["options"]["by_time"] is True
    by_arc = client.post(f"/skills/{skill}/fit", json={"demo_ids": ids[:2], "n_samples": 30, "by_time": False})
    assert by_arc.json()["options"]["clock"] == "arc" and by_arc.json()["options"]["by_time"] is False
    timed = client.post(f"/skills/{skill}/fit",
                        json={"demo_ids": ids[:2], "n_samples": 30, "by_time": True})
    a = client.get(f"/skills/{skill}/models/{default.json()['version']}").json()["directrix"]
    b = client.get(f"/skills/{skill}/models/{timed.json()['version']}").json()["directrix"]
    assert not np.allclose(a, b)
    assert client.post(f"/skills/{skill}/fit").status_code == 201  # no body: all defaults


def test_by_time_on_demonstrations_without_time_stamps_says_what_it_aligned_by(
        client: TestClient, skill: str) -> None:
    # by_time=true on demonstrations of which one has no time stamps aligns by arc length
    # (time needs every one stamped); the answer said by_time false and nothing else.
    ids = []
    for j in range(3):
        body: dict[str, object] = {"positions": demo_positions(j).tolist()}
        if j:
            body["timestamps"] = (np.arange(50) * 0.02).tolist()
        ids.append(client.post(f"/skills/{skill}/demonstrations", json=body).json()["id"])
    r = client.post(f"/skills/{skill}/fit", json={"n_samples": 30, "by_time": True})
    assert r.status_code == 201, r.text
    m = r.json()
    assert m["options"]["clock"] == "arc" and m["options"]["by_time"] is False
    (note,) = [n for n in m["notes"] if "by_time" in n]
    assert f"demonstration {ids[0]} " in note and "arc length" in note, note
    # every one stamped: aligned by time, no note
    r = client.post(f"/skills/{skill}/fit", json={"n_samples": 30, "by_time": True,
                                                 "demo_ids": ids[1:]})
    assert r.json()["options"]["clock"] == "time" and not any("by_time" in n for n in r.json()["notes"])


def test_two_dimensional_skill(client: TestClient) -> None:
    client.post("/skills", json={"name": "wipe", "dim": 2})
    for j in range(3):
        client.post("/skills/wipe/demonstrations",
                    json={"positions": demo_positions(j, dim=2).tolist()})
    r = client.post("/skills/wipe/fit", json={"n_samples": 25})
    assert r.status_code == 201 and r.json()["dim"] == 2, r.text
    model = client.get("/skills/wipe/models/latest").json()
    assert model["frames"]["binormals"] is None and np.asarray(model["directrix"]).shape == (25, 2)
    rep = client.post("/skills/wipe/reproductions", json={"start": model["directrix"][0]}).json()
    assert np.asarray(rep["positions"]).shape[1] == 2
    assert client.get("/skills/wipe/models/latest/mesh?format=ply").status_code == 200


def test_models_survive_a_restart(settings: Settings) -> None:
    with TestClient(create_app(settings)) as c:
        c.post("/skills", json={"name": "pour", "dim": 3})
        for j in range(3):
            c.post("/skills/pour/demonstrations", json={"positions": demo_positions(j).tolist()})
        c.post("/skills/pour/fit", json={"n_samples": 30})
        before = c.post("/skills/pour/reproductions", json={"start": [0, 0, 0]}).json()
    with TestClient(create_app(settings)) as c:  # new app, same SQLite file, no cache
        after = c.post("/skills/pour/reproductions", json={"start": [0, 0, 0]}).json()
        assert c.get("/skills/pour").json()["n_demonstrations"] == 3
    assert np.allclose(before["positions"], after["positions"])


def test_a_long_fit_does_not_block_other_requests(settings: Settings) -> None:
    with LiveServer(create_app(settings)) as server, httpx.Client(base_url=server.url) as http:
        http.post("/skills", json={"name": "big", "dim": 3})
        for j in range(10):
            body = json.dumps({"positions": demo_positions(j, n=3000).tolist()})
            r = http.post("/skills/big/demonstrations", content=body,
                          headers={"content-type": "application/json"})
            assert r.status_code == 201
        fit_result: dict[str, float] = {}

        def slow_fit() -> None:
            with httpx.Client(base_url=server.url, timeout=60) as c2:
                t0 = time.perf_counter()
                r = c2.post("/skills/big/fit", json={"alignment": "dtw", "n_samples": 1000})
                fit_result["seconds"] = time.perf_counter() - t0
                fit_result["status"] = r.status_code

        thread = threading.Thread(target=slow_fit)
        thread.start()
        time.sleep(0.1)
        latencies = []
        while thread.is_alive():
            t0 = time.perf_counter()
            assert http.get("/skills/big").status_code == 200
            latencies.append(time.perf_counter() - t0)
            time.sleep(0.02)
        thread.join()
    assert fit_result["status"] == 201
    assert fit_result["seconds"] > 0.3, "the fit was too quick to show anything"
    assert len(latencies) >= 3
    # answered while the fit ran, each far quicker than the fit itself
    assert max(latencies) < fit_result["seconds"] / 2, (latencies, fit_result)
