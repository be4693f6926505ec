"""CanalClient and AsyncCanalClient against a real service over loopback HTTP."""

from __future__ import annotations

import asyncio
import hashlib
import json
from collections.abc import Callable
from pathlib import Path

import canal_client
import canal_client.rest
import numpy as np
import pytest
from canal_client import (
    ArgumentError,
    AsyncCanalClient,
    CanalClient,
    InvalidInputError,
    Reproduction,
)
from canal_live import RRD_MAGIC, LiveService, demo_positions, write_demo_files
from mcap.reader import make_reader

import canal_core


def sha(positions: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(positions, dtype="<f8").tobytes()).hexdigest()


def test_skills_demos_models_round_trip(client: CanalClient,
                                        unique_name: Callable[[str], str]) -> None:
    assert client.health().status == "ok"
    name = unique_name("pour")
    skill = client.create_skill(name, dim=3, description="pour water")
    assert (skill.name, skill.dim, skill.description) == (name, 3, "pour water")
    assert skill.latest_model_version is None and skill.created_at is not None

    # numpy in: positions, timestamps and orientations
    p0 = demo_positions(0)
    t0 = np.linspace(0.0, 1.0, len(p0))
    q0 = np.tile([0.0, 0.0, 0.0, 1.0], (len(p0), 1))
    created = client.add_demo(name, p0, timestamps=t0, orientations=q0, label="first")
    assert created.n_points == len(p0) and created.checksum == sha(p0)
    # nested lists in
    created_list = client.add_demo(name, demo_positions(1).tolist())
    assert created_list.checksum == sha(demo_positions(1))

    # numpy out
    back = client.get_demo(name, created.id)
    assert isinstance(back.positions, np.ndarray) and back.positions.dtype == np.float64
    assert np.array_equal(back.positions, p0) and np.array_equal(back.timestamps, t0)
    assert np.array_equal(back.orientations, q0)
    assert back.label == "first" and back.source == "json" and back.has_orientations

    summaries = client.list_demos(name)
    assert [d.id for d in summaries] == [created.id, created_list.id]
    assert client.get_skill(name).n_demonstrations == 2

    model = client.fit(name, cross_section="mec", n_samples=25)
    assert model.version == 1 and model.section_kind == "mec"
    assert model.options["n_samples"] == 25 and model.options["frames"] == "rmf"
    client.add_demo(name, demo_positions(2))
    model2 = client.fit(name, demo_ids=[created.id, created_list.id])
    assert model2.version == 2 and model2.demo_ids == [created.id, created_list.id]
    assert [m.version for m in client.list_models(name)] == [2, 1]

    full = client.get_model(name, 1)
    assert full.directrix.shape == (25, 3) and full.radii.shape == (25,)
    assert full.bounds.shape == (2, 3) and full.tangents.shape == (25, 3)
    assert full.serialized is None
    assert client.get_model(name, serialized=True).serialized is not None

    client.delete_demo(name, created.id)
    assert [d.id for d in client.list_demos(name)] != [] and \
        created.id not in [d.id for d in client.list_demos(name)]
    client.delete_skill(name)
    assert name not in [s.name for s in client.list_skills()]


def test_list_skills_reads_every_page(client: CanalClient, unique_name: Callable[[str], str],
                                      monkeypatch: pytest.MonkeyPatch) -> None:
    names = [unique_name("paged") for _ in range(5)]
    for n in names:
        client.create_skill(n, dim=2)
    monkeypatch.setattr(canal_client.rest, "PAGE_SIZE", 2)
    listed = [s.name for s in client.list_skills()]
    assert set(names) <= set(listed) and len(listed) == len(set(listed))
    assert listed == sorted(listed)


def test_upload_every_file_format(client: CanalClient, unique_name: Callable[[str], str],
                                  tmp_path: Path) -> None:
    name = unique_name("files")
    client.create_skill(name)
    files = write_demo_files(tmp_path)
    sources = {}
    for fmt, path in files.items():
        created = client.upload_demo_file(name, path, label=f"from {fmt}",
                                          topic="/ee_pose" if fmt == "mcap" else None)
        demo = client.get_demo(name, created.id)
        sources[fmt] = demo.source
        assert demo.label == f"from {fmt}" and demo.positions.shape == (40, 3)
    assert sources == {"csv": "csv", "npy": "npy", "json": "json", "mcap": "mcap"}
    # format= overrides the suffix
    odd = tmp_path / "demo.dat"
    odd.write_bytes(files["npy"].read_bytes())
    assert client.upload_demo_file(name, odd, format="npy").n_points == 40
    with pytest.raises(ArgumentError, match=r"path: expected a \.csv, .*got 'demo\.dat'"):
        client.upload_demo_file(name, odd)
    with pytest.raises(ArgumentError, match="format: expected 'csv', 'npy', 'mcap' or 'json', got 'xls'"):
        client.upload_demo_file(name, odd, format="xls")


def test_untimed_model_gives_times_only_for_a_duration(client: CanalClient, fitted: str) -> None:
    start = client.get_canal(fitted).directrix[0]
    r = client.reproduce(fitted, start)
    assert r.times is None and r.velocities is None and r.notes == []
    d = client.reproduce(fitted, start, duration=3.0)
    assert d.times is not None and d.velocities is not None and abs(d.times[-1] - 3.0) < 1e-9
    # Evenly sampled demonstrations: their index is a clock, and it paces the reproduction.
    assert any("sample index" in n for n in d.notes)


def test_canal_mesh_and_reproductions(client: CanalClient, fitted: str) -> None:
    canal = client.get_canal(fitted)
    assert isinstance(canal, canal_core.Canal)
    start = np.array([0.0, 0.01, 0.0])
    r = client.reproduce(fitted, start)
    assert isinstance(r, Reproduction) and r.model_version == 1
    assert r.positions.shape[1] == 3 and r.inside and not r.projected
    # the local canal gives the same trajectory as the service
    assert np.allclose(canal.reproduce(start), r.positions)
    assert client.get_canal(fitted, 1).to_dict() == canal.to_dict()

    far = client.reproduce(fitted, [0.0, 5.0, 0.0], model=1)
    assert not far.inside and far.projected
    many = client.reproduce_many(fitted, np.array([[0.0, 0.0, 0.0], [0.0, 0.02, 0.0]]))
    assert len(many) == 2 and all(m.positions.shape[1] == 3 for m in many)
    for persistence in ("constant", "learned+end"):
        r = client.reproduce(fitted, start, persistence=persistence)
        assert np.allclose(canal.reproduce_detailed(start, persistence=persistence).positions,
                           r.positions), persistence
        m = client.reproduce_many(fitted, [start], persistence=persistence)
        assert np.allclose(m[0].positions, r.positions), persistence

    ply = client.mesh(fitted, format="ply", n_angles=8)
    assert ply.startswith(b"ply")
    assert client.mesh(fitted, 1, format="obj", caps=True).lstrip().startswith((b"v ", b"#"))


def test_recordings_download(client: CanalClient, fitted: str, tmp_path: Path) -> None:
    client.reproduce(fitted, [0.0, 0.0, 0.0])
    rrd = client.download_recording(fitted, "rrd", tmp_path / "out" / "skill.rrd")
    assert rrd == tmp_path / "out" / "skill.rrd" and rrd.read_bytes().startswith(RRD_MAGIC)
    mcap = client.download_recording(fitted, "mcap", tmp_path / "skill.mcap")
    with mcap.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.channels and summary.statistics.message_count > 0
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["out", "skill.mcap", "skill.rrd"]


def test_async_client(service: LiveService, unique_name: Callable[[str], str],
                      tmp_path: Path) -> None:
    name = unique_name("async")
    files = write_demo_files(tmp_path)

    async def scenario() -> None:
        async with AsyncCanalClient(service.url) as c:
            assert (await c.health()).status == "ok"
            await c.create_skill(name, dim=3)
            ids = [(await c.add_demo(name, demo_positions(j))).id for j in range(2)]
            ids.append((await c.upload_demo_file(name, files["csv"])).id)
            ids.append((await c.upload_demo_file(name, files["json"], label="j")).id)
            assert [d.id for d in await c.list_demos(name)] == ids
            assert np.array_equal((await c.get_demo(name, ids[0])).positions, demo_positions(0))
            model = await c.fit(name, cross_section="ellipse", n_samples=20)
            assert model.section_kind == "ellipse"
            assert [m.version for m in await c.list_models(name)] == [1]
            assert (await c.get_model(name)).directrix.shape == (20, 3)
            canal = await c.get_canal(name)
            r = await c.reproduce(name, [0.0, 0.0, 0.0])
            assert np.allclose(canal.reproduce(np.zeros(3)), r.positions)
            assert len(await c.reproduce_many(name, [[0, 0, 0], [0, 0.01, 0]])) == 2
            assert (await c.mesh(name)).startswith(b"ply")
            path = await c.download_recording(name, "mcap", tmp_path / "a.mcap")
            assert path.stat().st_size > 0
            with pytest.raises(canal_client.NotFoundError):
                await c.get_skill(name + "-missing")
            await c.delete_demo(name, ids[0])
            assert name in [s.name for s in await c.list_skills()]
            await c.delete_skill(name)

    asyncio.run(scenario())


def test_lazy_robot_side_names_do_not_break_import() -> None:
    assert "PoseStreamer" in canal_client.__all__ and "run_sim" in dir(canal_client)
    with pytest.raises(AttributeError):
        _ = canal_client.no_such_name  # type: ignore[attr-defined]


def test_reproduction_with_goal_duration_and_timing(client: CanalClient,
                                                    unique_name: Callable[[str], str]) -> None:
    name = unique_name("timed")
    client.create_skill(name, dim=3)
    for j in range(4):
        positions = demo_positions(j)
        # slow first half, fast second half: the reproduction keeps that profile
        t = np.concatenate([np.linspace(0.0, 3.0, 25), np.linspace(3.0, 4.0, positions.shape[0] - 24)[1:]])
        client.add_demo(name, positions, timestamps=t)
    client.fit(name, n_samples=40)
    canal = client.get_canal(name)
    start = canal.directrix[0]
    r = client.reproduce(name, start)
    assert r.times is not None and r.velocities is not None and r.notes == []
    assert r.times.shape == (r.positions.shape[0],) and r.velocities.shape == r.positions.shape
    np.testing.assert_allclose(r.times[-1], 4.0, rtol=0.05)
    local = canal.reproduce_detailed(start)
    assert local.times is not None
    np.testing.assert_allclose(r.times, local.times)
    goal = canal.directrix[-1] + np.array([0.05, -0.05, 0.1])
    g = client.reproduce(name, start, goal=goal, duration=2.0)
    np.testing.assert_allclose(g.positions[-1], goal, atol=1e-9)
    assert g.goal is not None and np.allclose(g.goal, goal)
    assert g.times is not None and abs(g.times[-1] - 2.0) < 1e-9
    many = client.reproduce_many(name, [start, start + 0.001], duration=1.0)
    assert all(m.times is not None and abs(m.times[-1] - 1.0) < 1e-9 for m in many)
    noted = client.reproduce(name, start, start_orientation=[0.0, 0.0, 0.0, 1.0])
    assert any("orientation" in n for n in noted.notes) or noted.orientations is not None


def test_numpy_numbers_are_sent_as_json_numbers(client: CanalClient, fitted: str) -> None:
    # Options and indices computed with numpy (np.int64 from argmin, a shape) used to fail in
    # json.dumps with "Object of type int64 is not JSON serializable", before any request.
    model = client.fit(fitted, n_samples=np.int64(60), routes=np.int64(1),
                       frame_smoothing=np.float32(0.02))
    assert model.n_sections == 60 and model.routes == 1
    rep = client.reproduce(fitted, start=np.zeros(3, dtype=np.float32), route=np.int64(0),
                           duration=np.float32(2.0), model=np.int64(model.version))
    assert rep.route == 0 and rep.times is not None and abs(rep.times[-1] - 2.0) < 1e-6
    # A numpy boolean is a JSON boolean, which the service refuses where a number is due.
    with pytest.raises(InvalidInputError) as info:
        client.reproduce(fitted, start=[0.0, 0.0, 0.0], route=np.bool_(True))
    assert info.value.field == "route"


def test_a_correction_from_a_file(client: CanalClient, service: LiveService, fitted: str,
                                  tmp_path: Path) -> None:
    canal = client.get_canal(fitted)
    idx = np.arange(8, 20)
    wider = canal.directrix[idx] + 1.2 * canal.radii[idx, None] * canal.normals[idx]
    csv = tmp_path / "wider.csv"
    csv.write_text("x;y;z\n" + "".join(";".join(map(repr, row)) + "\n" for row in wider.tolist()))
    made = client.correct_file(fitted, csv, weight=2.0, model=1)
    assert made.correction.label == "wider.csv" and made.correction.n_points == len(wider)
    assert made.correction.weight == 2.0 and made.parent_version == 1
    # a model version names its corrections by id; the path is the correction's own
    stored = client.get_correction(fitted, made.correction.id)
    assert stored.id == made.correction.id and stored.label == "wider.csv"
    np.testing.assert_array_equal(np.array(stored.samples), wider)
    doc = tmp_path / "wider.json"
    doc.write_text(json.dumps({"samples": wider.tolist()}))
    by_json = client.correct_file(fitted, doc, "include", label="by json", model=1, weight=2.0)
    assert by_json.correction.label == "by json" and by_json.correction.n_points == len(wider)
    np.testing.assert_allclose(client.get_canal(fitted, by_json.version).radii,
                               client.get_canal(fitted, made.version).radii)

    async def by_async() -> int:
        async with AsyncCanalClient(service.url) as ac:
            return (await ac.correct_file(fitted, csv, model=1)).correction.n_points

    assert asyncio.run(by_async()) == len(wider)
    with pytest.raises(ArgumentError, match=r"expected a \.csv, \.npy, \.mcap or \.json file"):
        client.correct_file(fitted, tmp_path / "wider.xls")
