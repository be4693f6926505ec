"""``canal scene set|show|clear`` and ``canal reproduce --obstacle`` against a real service, and
the client's scene calls underneath."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
from canal_client import CanalClient
from canal_live import LiveService
from click.testing import Result

from canal_core.obstacles import scene_from_list, segment_free_distances


def wavy(j: int, n: int = 80) -> np.ndarray:
    """A straight reach whose demonstrators wander sideways (room to swerve)."""
    x = np.linspace(0.0, 1.0, n)
    a = 2.0 * np.pi * j / 5
    return np.column_stack([x, 0.06 * np.cos(a) + 0.012 * np.sin(7.0 * x + j),
                            0.06 * np.sin(a) + 0.012 * np.cos(9.0 * x + 2 * j)])


def test_scene_commands_and_reproduce_with_an_obstacle(run: Callable[..., Result], service: LiveService,
                                                       unique_name: Callable[[str], str],
                                                       tmp_path: Path) -> None:
    name = unique_name("scene")
    with CanalClient(service.url) as c:
        c.create_skill(name)
        for j in range(5):
            c.add_demo(name, wavy(j))
        c.fit(name, n_samples=80)
        plain = c.reproduce(name, [0.0, 0.01, 0.0]).positions
    scene_file = tmp_path / "scene.json"
    cup = {"kind": "sphere", "center": [0.5, 0.01, 0.0], "radius": 0.02, "clearance": 0.005}
    scene_file.write_text(json.dumps({"obstacles": [cup]}))

    r = run("scene", "set", name, str(scene_file), "--obstacle", "box:0.8,0,0,0.01,0.5,0.5")
    assert r.exit_code == 0, r.output
    assert "version 1: 1 box, 1 sphere" in r.stdout
    r = run("--json", "scene", "show", name)
    shown = json.loads(r.stdout)
    assert shown["version"] == 1 and shown["obstacles"][0]["radius"] == 0.02

    # The wall closes the canal: the reproduction says so and stops before it.
    out = tmp_path / "t.json"
    r = run("reproduce", name, "--start", "0,0.01,0", "--out", str(out))
    assert r.exit_code == 0, r.output
    assert "blocked at section" in r.stdout and "(closed" in r.stdout
    assert np.asarray(json.loads(out.read_text())["positions"])[:, 0].max() < 0.79

    r = run("scene", "clear", name)
    assert r.exit_code == 0 and "version 2: no obstacles" in r.stdout
    r = run("--json", "reproduce", name, "--start", "0,0.01,0", "--obstacle", "sphere:0.5,0.01,0,0.02,0.005")
    assert r.exit_code == 0, r.output
    answer = json.loads(r.stdout)
    assert answer["obstacles"] == 1 and answer["blocked"] is None
    p = np.asarray(answer["positions"])
    scene = scene_from_list([cup], 3)
    assert segment_free_distances(p[1:-1], p[2:], scene).min() >= 0.0
    assert segment_free_distances(plain[1:-1], plain[2:], scene).min() < 0.0

    for bad in ("sphere:1,2,3", "cube:1,2,3,4", "sphere:1,2,3,nan"):
        r = run("reproduce", name, "--start", "0,0.01,0", "--obstacle", bad)
        assert r.exit_code == 2 and "--obstacle" in r.output, (bad, r.output)
    r = run("scene", "set", name, "--obstacle", "sphere:0.5,0,0,-1")
    assert r.exit_code == 1 and "obstacles[0].radius" in r.output
    with CanalClient(service.url) as c:
        assert c.get_scene(name).version == 2  # the refused one stored nothing


def test_scene_set_with_nothing_to_set_is_a_usage_error_and_keeps_the_scene(
        run: Callable[..., Result], service: LiveService, tmp_path: Path,
        unique_name: Callable[[str], str]) -> None:
    # `canal scene set SKILL` with the file forgotten used to replace the scene with an empty
    # one: every obstacle gone without a word. Removing them all is `scene clear`.
    name = unique_name("scene-keep")
    with CanalClient(service.url) as c:
        c.create_skill(name)
        c.set_scene(name, [{"kind": "sphere", "center": [0.5, 0.0, 0.0], "radius": 0.05}])
    r = run("scene", "set", name)
    assert r.exit_code == 2, r.output
    assert "scene clear" in r.output and "--obstacle" in r.output
    empty = tmp_path / "empty.json"
    empty.write_text(json.dumps({"obstacles": []}))
    with CanalClient(service.url) as c:
        scene = c.get_scene(name)
        assert scene.version == 1 and len(scene.obstacles) == 1
    # An empty scene file says so on purpose: it is kept as the explicit way too.
    r = run("scene", "set", name, str(empty))
    assert r.exit_code == 0, r.output
    with CanalClient(service.url) as c:
        assert c.get_scene(name).obstacles == []


def test_a_box_of_the_wrong_dimension_is_a_usage_error_naming_what_it_takes(
        run: Callable[..., Result], service: LiveService, unique_name: Callable[[str], str]) -> None:
    # box:cx,cy,cz,hx,hy (hz forgotten) on a 3-D skill was read as a 2-D box with a clearance
    # and refused by the service as a centre of 2 values. The box's numbers are read by the
    # skill's dimension: a usage error saying what a box of that skill takes.
    solid, flat = unique_name("box3"), unique_name("box2")
    with CanalClient(service.url) as c:
        c.create_skill(solid, dim=3)
        c.create_skill(flat, dim=2)
    for args in (["scene", "set", solid], ["reproduce", solid, "--start", "0,0,0"]):
        r = run(*args, "--obstacle", "box:0.5,0,0,0.01,0.5")
        assert r.exit_code == 2, r.output
        said = " ".join(r.output.split())
        assert "--obstacle" in said and "box:cx,cy,cz,hx,hy,hz[,clearance]" in said, said
        assert "3-D" in said and "got 5 numbers" in said, said
    r = run("scene", "set", flat, "--obstacle", "box:0.5,0,0,0.01,0.5,0.5")
    assert r.exit_code == 2 and "box:cx,cy,hx,hy[,clearance]" in " ".join(r.output.split()), r.output
    # The same five numbers on a 2-D skill are a box and its clearance.
    r = run("--json", "scene", "set", flat, "--obstacle", "box:0.5,0,0.01,0.5,0.002")
    assert r.exit_code == 0, r.output
    box = json.loads(r.stdout)["obstacles"][0]
    assert box["center"] == [0.5, 0.0] and box["half_extents"] == [0.01, 0.5] and box["clearance"] == 0.002
    with CanalClient(service.url) as c:
        assert not c.get_scene(solid).obstacles  # nothing was stored
