"""Live targets around a skill's scene, over a real Zenoh session on 127.0.0.1: a scene put in
flight, a blocked section, an obstacle on the robot itself, and the REST scene's twin."""

from __future__ import annotations

import random
import threading
import time

import numpy as np
import orjson
import pytest
import zenoh
from canal_client.live import PoseStreamer
from live_helpers import make_skill, wait_until

import canal_core
from canal_core.obstacles import free_distances, scene_from_list
from canal_protocol import wire

# Scene puts wait for room rather than being dropped when the link is busy (a 100 kB put can
# fill it), as the product's own pose publishers do.
BLOCK = zenoh.CongestionControl.BLOCK

pytestmark = pytest.mark.timeout(90)


def canal_of(live, skill: str) -> canal_core.Canal:
    body = live.client.get(f"/skills/{skill}/models/latest", params={"serialized": True}).json()
    return canal_core.Canal.from_dict(body["serialized"])


def drive(ps: PoseStreamer, x: np.ndarray, steps: int, gain: float = 0.6,
          on_step=None) -> tuple[np.ndarray, list[tuple[np.ndarray, wire.Target]]]:
    """A first-order robot: each pose moves ``gain`` of the way to its answer."""
    seen: list[tuple[np.ndarray, wire.Target]] = []
    for k in range(steps):
        if on_step is not None:
            on_step(k)
        seq = ps.send(x.tolist(), restart=k == 0 and not seen)
        answer = ps.wait_for(seq, 5.0)
        assert answer is not None and answer.usable and answer.target is not None, answer
        seen.append((x.copy(), answer))
        x = x + gain * (np.asarray(answer.target) - x)
        if answer.done:
            break
    return x, seen


@pytest.fixture(scope="module")
def scn(live) -> str:
    make_skill(live.client, "scn", 3)
    return "scn"


def test_a_scene_put_in_flight_is_gone_around_from_the_next_pose(live, scn) -> None:
    canal = canal_of(live, scn)
    k = canal.n_sections // 2
    ball = {"kind": "sphere", "center": canal.directrix[k].tolist(),
            "radius": 0.5 * float(canal.radii[k]), "clearance": 0.002, "name": "hand"}
    scene = scene_from_list([ball], 3)
    step = canal.largest_step
    with PoseStreamer(scn, "flight", endpoint=live.endpoint) as ps:
        put_at = 5

        def put(i: int) -> None:
            if i == put_at:
                ps.session.put(f"canal/{scn}/scene", orjson.dumps({"obstacles": [ball]}), congestion_control=BLOCK)
                # the bridge measures it against the canal as it arrives (tens of ms) and
                # stores it (shard 0): wait until it is served, then go on moving
                bank = live.client.app.state.bridge.models.models[scn].bank
                assert wait_until(lambda: bank.scene is not None)
                assert live.client.get(f"/skills/{scn}/scene").json()["version"] >= 1

        _, seen = drive(ps, canal.directrix[0].copy(), 400, on_step=put)
    after = seen[put_at + 1:]
    statuses = {a.status for _, a in after}
    assert "detour" in statuses and seen[-1][1].done
    poses = np.array([p for p, _ in after])
    targets = np.array([a.target for _, a in after])
    # The robot moves along pose -> target: every such move keeps the clearance.
    assert free_distances(poses, scene).min() >= -1e-9
    assert free_distances(targets, scene).min() >= -1e-9
    # A detour's target moves on from the previous one by no more than a step (plus the
    # tracker's own advance of lookahead sections): no jump around the obstacle.
    detour = np.array([a.status == "detour" for _, a in after])
    jumps = np.linalg.norm(np.diff(targets, axis=0), axis=1)[detour[1:]]
    print("largest target jump on a detour", jumps.max(), "step", step)
    assert jumps.max() <= 2.0 * step
    stored = live.client.get(f"/skills/{scn}/scene").json()
    assert stored["obstacles"][0]["name"] == "hand"
    assert live.client.delete(f"/skills/{scn}/scene").status_code == 204


def test_a_closed_section_holds_the_stream_before_it(live, scn) -> None:
    canal = canal_of(live, scn)
    k = int(0.6 * canal.n_sections)
    t = canal.tangents[k]
    # a slab across the canal at section k, oriented with the section's plane
    axes = np.stack([t, canal.normals[k], canal.binormals[k]], axis=1)
    q = canal_core.obstacles.rotation_parameters(axes)
    wall = {"kind": "box", "center": canal.directrix[k].tolist(), "half_extents": [0.005, 1.0, 1.0],
            "rotation": q}
    r = live.client.put(f"/skills/{scn}/scene", json={"obstacles": [wall]})
    assert r.status_code == 200, r.text
    with PoseStreamer(scn, "walled", endpoint=live.endpoint) as ps:
        wait_until(lambda: ps.session is not None)
        time.sleep(0.1)
        x, seen = drive(ps, canal.directrix[0].copy(), 300)
    last = [a for _, a in seen[-20:]]
    assert all(a.status == "blocked" for a in last), [a.status for a in last]
    assert not seen[-1][1].done
    along = np.array([(p - canal.directrix[k]) @ t for p, _ in seen])
    assert along.max() < 0.0  # never in or past the wall
    assert live.client.delete(f"/skills/{scn}/scene").status_code == 204


def test_an_obstacle_on_the_robot_says_so_and_backs_it_away(live, scn) -> None:
    canal = canal_of(live, scn)
    x = canal.directrix[10].copy()
    ball = {"kind": "sphere", "center": x.tolist(), "radius": 0.4 * float(canal.radii[10])}
    assert live.client.put(f"/skills/{scn}/scene", json={"obstacles": [ball]}).status_code == 200
    with PoseStreamer(scn, "inside", endpoint=live.endpoint) as ps:
        time.sleep(0.1)
        seq = ps.send((x + 1e-4).tolist(), restart=True)
        answer = ps.wait_for(seq, 5.0)
    assert answer is not None and answer.status == "in_obstacle", answer
    target = np.asarray(answer.target)
    assert np.linalg.norm(target - x) > 1e-4  # away from the centre
    assert np.linalg.norm(target - (x + 1e-4)) <= canal.largest_step + 1e-9
    assert live.client.delete(f"/skills/{scn}/scene").status_code == 204


def test_a_scene_put_over_zenoh_is_held_to_the_rest_scene_s_rules(live, scn) -> None:
    # A scene put on the Zenoh key skipped the REST scene's schema: a field it does not take
    # and a 100,000-character obstacle name were stored as a new scene version; a bare list
    # (REST refuses it) was taken as the obstacles: `[]` removed every obstacle.
    canal = canal_of(live, scn)
    ball = {"kind": "sphere", "center": canal.directrix[5].tolist(), "radius": 0.01}
    before = live.client.get(f"/skills/{scn}/scene").json()["version"]
    with PoseStreamer(scn, "putter", endpoint=live.endpoint) as ps:
        for body in ({"obstacles": [ball], "bogus": 1},
                     {"obstacles": [{**ball, "name": "x" * 100_000}]},
                     {"obstacles": [{**ball, "colour": "red"}]}, [], [ball]):
            ps.session.put(f"canal/{scn}/scene", orjson.dumps(body), congestion_control=BLOCK)
        # a good one after them: once it is stored, the bad ones had their turn
        ps.session.put(f"canal/{scn}/scene", orjson.dumps({"obstacles": [{**ball, "name": "ok"}]}), congestion_control=BLOCK)
        # a loaded machine measures four scenes in turn: time enough for all of them
        assert wait_until(lambda: live.client.get(f"/skills/{scn}/scene").json()["version"] > before,
                          timeout=30.0), (before, live.client.get(f"/skills/{scn}/scene").json())
    stored = live.client.get(f"/skills/{scn}/scene").json()
    assert stored["version"] == before + 1, (before, stored)
    assert [o.get("name") for o in stored["obstacles"]] == ["ok"]
    assert live.client.delete(f"/skills/{scn}/scene").status_code == 204


def test_a_skill_created_again_is_gone_around_its_own_scene(live) -> None:
    # The bridge kept a deleted skill's scene under its name, with its version: the skill
    # created again stored its first scene as version 1, which the bridge took for older
    # than the deleted one's 4 and ignored, so robots went through its obstacle.
    make_skill(live.client, "again", 3)
    canal = canal_of(live, "again")
    k = canal.n_sections // 2
    ball = {"kind": "sphere", "center": canal.directrix[k].tolist(),
            "radius": 0.5 * float(canal.radii[k])}
    for _ in range(3):
        assert live.client.put("/skills/again/scene", json={"obstacles": [ball]}).status_code == 200
    assert live.client.delete("/skills/again/scene").status_code == 204  # version 4: none
    with PoseStreamer("again", "before", endpoint=live.endpoint) as ps:
        drive(ps, canal.directrix[0].copy(), 5)  # the bridge serves the skill and its scene
    assert live.client.delete("/skills/again").status_code == 204
    make_skill(live.client, "again", 3)
    assert live.client.put("/skills/again/scene", json={"obstacles": [ball]}).json()["version"] == 1
    with PoseStreamer("again", "after", endpoint=live.endpoint) as ps:
        _, seen = drive(ps, canal.directrix[0].copy(), 400)
    scene = scene_from_list([ball], 3)
    targets = np.array([a.target for _, a in seen])
    assert "detour" in {a.status for _, a in seen}
    assert free_distances(targets, scene).min() >= -1e-9


def slab_across(canal: canal_core.Canal, k: int) -> dict:
    """A thin box across the canal at section ``k``, in the section's plane: it closes the canal."""
    axes = np.stack([canal.tangents[k], canal.normals[k], canal.binormals[k]], axis=1)
    return {"kind": "box", "center": canal.directrix[k].tolist(), "half_extents": [0.005, 1.0, 1.0],
            "rotation": canal_core.obstacles.rotation_parameters(axes)}


def test_a_new_model_is_served_with_the_skill_s_scene_from_its_first_pose(live) -> None:
    # A new model version (a refit, a correction) was published to the streams before its
    # bank had the skill's scene: for tens of milliseconds a robot held before a wall was
    # answered `ok`, with targets inside the wall.
    make_skill(live.client, "switch", 3, n_samples=400)
    canal = canal_of(live, "switch")
    k = int(0.6 * canal.n_sections)
    wall = slab_across(canal, k)
    assert live.client.put("/skills/switch/scene", json={"obstacles": [wall]}).status_code == 200
    scene = scene_from_list([wall], 3)
    include = (canal.directrix[k // 4: k // 4 + 20] + 0.2 * float(canal.radii[k // 4])
               * canal.normals[k // 4: k // 4 + 20]).tolist()
    changes = [lambda: live.client.post("/skills/switch/fit", json={"n_samples": 401}),
               lambda: live.client.post("/skills/switch/corrections",
                                        json={"kind": "include", "samples": include}),
               lambda: live.client.post("/skills/switch/fit", json={"n_samples": 402})]
    with PoseStreamer("switch", "held", endpoint=live.endpoint) as ps:
        x, seen = drive(ps, canal.directrix[0].copy(), 300)
        assert seen[-1][1].status == "blocked", seen[-1][1]
        versions = []

        def land() -> None:
            for change in changes:
                r = change()
                assert r.status_code == 201, r.text
                versions.append(r.json().get("version"))

        lander = threading.Thread(target=land)
        lander.start()
        answers = []
        # The robot holds where it is and keeps asking, in lock-step, while the models land.
        while lander.is_alive() or len(answers) < 50:
            seq = ps.send(x.tolist())
            answer = ps.wait_for(seq, 5.0)
            assert answer is not None and answer.target is not None, answer
            answers.append(answer)
        lander.join()
    assert len(versions) == 3
    targets = np.array([a.target for a in answers])
    inside = free_distances(targets, scene) < 0.0
    statuses = [a.status for a in answers]
    assert not inside.any(), (int(inside.sum()), len(answers), sorted(set(statuses)))
    assert "ok" not in statuses, (statuses.count("ok"), len(answers))


def test_a_scene_put_on_zenoh_while_a_model_lands_is_the_one_served(live) -> None:
    # A scene put on Zenoh while a refit landed could be lost by the bridge for good: the
    # refit's thread and the put's thread each measured a scene for the new model, and the
    # older one, slower to measure, was written last. GET /scene held the wall; live robots
    # were answered `ok` through it.
    make_skill(live.client, "race", 3, n_samples=300)
    canal = canal_of(live, "race")
    k = int(0.6 * canal.n_sections)
    wall = slab_across(canal, k)
    scene = scene_from_list([wall], 3)
    # Many small spheres beside the canal, off the robot's path: slow to measure, close nothing.
    idx = np.linspace(5, canal.n_sections - 5, 63).astype(int)
    clutter = [{"kind": "sphere", "radius": 0.004,
                "center": (canal.directrix[i] + (float(canal.radii[i]) + 0.03) * canal.normals[i]).tolist()}
               for i in idx]
    # 5 mm before the wall's face, on the canal's centre line
    before = canal.directrix[k] - 0.010 * canal.tangents[k]
    models = live.client.app.state.bridge.models
    rng = random.Random(7)
    with PoseStreamer("race", "probe", endpoint=live.endpoint) as ps:
        # the robot stands still before the wall: it asks from there at every check
        got = ps.wait_for(ps.send(before.tolist(), restart=True), 5.0)
        assert got is not None and got.target is not None, got

        def answer() -> wire.Target:
            for _ in range(3):
                got = ps.wait_for(ps.send(before.tolist()), 5.0)
            assert got is not None and got.target is not None, got
            return got

        def held() -> bool:
            got = answer()
            return got.status != "ok" and free_distances(np.array([got.target]), scene)[0] >= 0.0

        for trial in range(6):
            r = live.client.put("/skills/race/scene", json={"obstacles": clutter})
            assert r.status_code == 200, r.text
            version = r.json()["version"]
            # the bridge serves the clutter before the race starts
            assert wait_until(lambda v=version: (e := models.models.get("race")) is not None
                              and e.bank.scene is not None and e.bank.scene.version == v)
            fitted: list[int] = []

            def refit(n: int = 300 + trial % 2, out: list[int] = fitted) -> None:
                out.append(live.client.post("/skills/race/fit", json={"n_samples": n}).status_code)

            fit = threading.Thread(target=refit)
            fit.start()
            time.sleep(rng.uniform(0.0, 0.1))
            ps.session.put("canal/race/scene", orjson.dumps({"obstacles": [wall]}), congestion_control=BLOCK)
            fit.join()
            assert fitted == [201]
            assert wait_until(lambda: any(o["kind"] == "box" for o in
                                          live.client.get("/skills/race/scene").json()["obstacles"]))
            assert wait_until(held, timeout=2.0), (trial, answer())
