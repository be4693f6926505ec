"""Orientation through real HTTP: fit learns it when every demo has it, reproductions carry it."""

from __future__ import annotations

from pathlib import Path

import httpx
import numpy as np
import pytest
from canal_client import CanalClient
from canal_client.cli import app
from canal_testing import LiveServer
from scipy.spatial.transform import Rotation
from service_helpers import demo_positions
from typer.testing import CliRunner


def demo_orientations(j: int, n: int = 50) -> np.ndarray:
    """A 60 deg tilt about y with a per-demo tool-frame offset about x; signs mixed."""
    s = np.linspace(0.0, 1.0, n)
    rot = Rotation.from_euler("y", (np.pi / 3) * s[:, None]) * Rotation.from_euler("x", 4.0 * (j - 1.5),
                                                                                    degrees=True)
    q = rot.as_quat()
    q[::4] *= -1.0
    return q


def _upload(http: httpx.Client, skill: str, with_orientations: list[bool]) -> None:
    assert http.post("/skills", json={"name": skill, "dim": 3}).status_code == 201
    for j, has_q in enumerate(with_orientations):
        body = {"positions": demo_positions(j).tolist()}
        if has_q:
            body["orientations"] = demo_orientations(j).tolist()
        r = http.post(f"/skills/{skill}/demonstrations", json=body)
        assert r.status_code == 201, r.text


def test_orientation_is_learned_and_reproduced_over_real_http(live_server: LiveServer) -> None:
    with httpx.Client(base_url=live_server.url) as http:
        _upload(http, "pour", [True] * 4)
        fit = http.post("/skills/pour/fit", json={"n_samples": 40})
        assert fit.status_code == 201, fit.text
        assert fit.json()["has_orientation"] is True
        assert fit.json()["options"]["orientation"] is True
        assert http.get("/skills/pour/models/latest").json()["has_orientation"] is True
        assert http.get("/skills/pour/models").json()["items"][0]["has_orientation"] is True

        start = demo_positions(1)[0].tolist()
        q0 = (-demo_orientations(2)[1]).tolist()  # a demo's own start, in the other sign
        rep = http.post("/skills/pour/reproductions",
                        json={"start": start, "start_orientation": q0})
        assert rep.status_code == 200, rep.text
        body = rep.json()
        quats = np.asarray(body["orientations"])
        assert quats.shape == (len(body["positions"]), 4)
        assert np.allclose(np.linalg.norm(quats, axis=1), 1.0)
        assert np.allclose(quats[0], q0)
        assert body["notes"] == []
        # Demo 2 kept its 2 deg offset all the way: so does the reproduction from its start.
        expected = Rotation.from_quat(demo_orientations(2)[-1])
        carried = np.degrees((Rotation.from_quat(quats[-1]).inv() * expected).magnitude())

        plain = http.post("/skills/pour/reproductions", json={"start": start}).json()
        mean_end = Rotation.from_euler("y", np.pi / 3)
        assert np.degrees((Rotation.from_quat(plain["orientations"][-1]).inv() * mean_end)
                          .magnitude()) < 1.0
        from_mean = np.degrees((Rotation.from_quat(plain["orientations"][-1]).inv() * expected)
                               .magnitude())
        assert carried < 0.7 * from_mean
        assert any("mean orientation" in n for n in plain["notes"])

        batch = http.post("/skills/pour/reproductions",
                          json={"starts": [start, start], "start_orientation": q0}).json()
        assert [np.allclose(r["orientations"], quats) for r in batch["reproductions"]] == [True, True]

        far = Rotation.from_euler("x", 40.0, degrees=True).as_quat().tolist()
        outside = http.post("/skills/pour/reproductions", json={"start": start, "start_orientation": far})
        assert any("times the demonstrations' largest angle" in n for n in outside.json()["notes"])

        for bad, field in (([0, 0, 0, 3], "start_orientation"), ([0, 0, 1], "start_orientation")):
            r = http.post("/skills/pour/reproductions", json={"start": start, "start_orientation": bad})
            assert r.status_code == 422, r.text
            assert field in r.text


def test_model_without_orientation_ignores_start_orientation(live_server: LiveServer) -> None:
    with httpx.Client(base_url=live_server.url) as http:
        _upload(http, "reach", [True, False, True])  # one demo without: positions only
        fit = http.post("/skills/reach/fit", json={"n_samples": 30})
        assert fit.status_code == 201 and fit.json()["has_orientation"] is False
        rep = http.post("/skills/reach/reproductions",
                        json={"start": demo_positions(0)[0].tolist(),
                              "start_orientation": [0, 0, 0, 1]})
        assert rep.status_code == 200, rep.text
        assert rep.json()["orientations"] is None
        assert rep.json()["notes"] == ["model has no orientation: start_orientation ignored"]
        # Ignored, but still checked: a value that is no rotation is refused, as on a model
        # with orientation, not answered as if it were one.
        for bad in ([0, 0, 0, 0], [1e300, 0, 0, 1e300], [0, 0, 0, 3]):
            r = http.post("/skills/reach/reproductions",
                          json={"start": demo_positions(0)[0].tolist(), "start_orientation": bad})
            assert r.status_code == 422, (bad, r.text)
            assert r.json()["error"]["field"] == "start_orientation", r.text
        off = http.post("/skills/reach/fit", json={"n_samples": 30, "orientation": False})
        assert off.json()["options"]["orientation"] is False


def test_client_and_cli_paths(live_server: LiveServer) -> None:
    with httpx.Client(base_url=live_server.url) as http:
        _upload(http, "pour", [True] * 4)
    with CanalClient(live_server.url) as client:
        summary = client.fit("pour", n_samples=40)
        assert summary.has_orientation
        assert client.get_model("pour").has_orientation
        r = client.reproduce("pour", demo_positions(0)[0], start_orientation=demo_orientations(0)[0])
        assert r.orientations is not None and r.orientations.shape == (len(r.positions), 4)
        assert r.notes == []
        many = client.reproduce_many("pour", [demo_positions(0)[0]] * 2,
                                     start_orientation=[0, 0, 0, 1])
        assert all(m.orientations is not None for m in many)
        with pytest.raises(Exception, match="start_orientation"):
            client.reproduce("pour", demo_positions(0)[0], start_orientation=[0, 0, 0, 2])


def test_cli_start_orientation_writes_quaternion_columns(live_server: LiveServer, tmp_path: Path) -> None:
    with httpx.Client(base_url=live_server.url) as http:
        _upload(http, "pour", [True] * 4)
        assert http.post("/skills/pour/fit", json={"n_samples": 30}).status_code == 201
    env = {"CANAL_URL": live_server.url, "CANAL_TOKEN": "", "CANAL_CACHE_DIR": str(tmp_path / "c"),
           "COLUMNS": "200"}
    start = ",".join(str(v) for v in demo_positions(0)[0])
    out = tmp_path / "path.csv"
    result = CliRunner().invoke(app, ["reproduce", "pour", "-s", start, "--start-orientation",
                                      "0,0,0,1", "-o", str(out)], env=env)
    assert result.exit_code == 0, result.output
    assert "with orientations" in result.output
    table = np.loadtxt(out, delimiter=",", skiprows=1)
    assert out.read_text().splitlines()[0] == "x,y,z,qx,qy,qz,qw"
    assert table.shape[1] == 7 and np.allclose(table[0, 3:], [0, 0, 0, 1])
    assert np.allclose(np.linalg.norm(table[:, 3:], axis=1), 1.0)
    bad = CliRunner().invoke(app, ["reproduce", "pour", "-s", start, "--start-orientation", "0,0,1"],
                             env=env)
    assert bad.exit_code != 0 and "qx,qy,qz,qw" in bad.output
