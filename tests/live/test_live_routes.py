"""Live streams on a model of several routes: each stream takes the route whose entry holds
its first pose and follows it; answers and /healthz say which."""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
import orjson
import pytest
from canal_client.live import LiveError, PoseStreamer
from canal_client.sim import run_sim
from canal_service.app import create_app
from canal_service.bridge.bridge import shard_of
from canal_service.core.config import Settings
from canal_testing import (
    ROUTE_STARTS,
    fit_two_route_skill,
    free_port,
    path_distance,
    two_route_demo,
)
from live_helpers import wait_until

import canal_core
from canal_core import bounds
from canal_protocol import wire

with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    from fastapi.testclient import TestClient

pytestmark = pytest.mark.timeout(90)


@pytest.fixture(scope="module")
def reach(live: Any) -> str:
    """'reach': eight demonstrations, four each way round the middle, fitted as two routes."""
    fit_two_route_skill(live.client, "reach", 80)
    return "reach"


@pytest.mark.parametrize("encoding", ["json", "binary"])
def test_a_stream_from_each_start_follows_its_route(live: Any, reach: str, encoding: str) -> None:
    demos = [two_route_demo(j) for j in range(8)]
    for k, start in enumerate(ROUTE_STARTS):
        r = run_sim(reach, robot=f"r{k}-{encoding}", start=start, rate_hz=500.0, timeout_s=20.0,
                    endpoint=live.endpoint, encoding=encoding)
        assert r.reached_end, (k, r.n_steps, r.statuses)
        own = min(path_distance(r.positions, d) for d in demos[4 * k: 4 * k + 4])
        other = min(path_distance(r.positions, d) for d in demos[4 * (1 - k): 4 * (1 - k) + 4])
        assert own < 0.05 < other, (k, own, other)
        middle = r.positions[len(r.positions) // 2]
        assert np.sign(middle[1]) == (1.0 if k == 0 else -1.0)
        assert {t.route for t in r.targets} == {k}


def test_healthz_counts_streams_by_route_and_one_route_answers_without_it(
        live: Any, reach: str) -> None:
    with PoseStreamer(reach, "h0", endpoint=live.endpoint, encoding="json") as a, \
            PoseStreamer(reach, "h1", endpoint=live.endpoint, encoding="json") as b:
        first = a.wait_for(a.send(ROUTE_STARTS[0]), timeout=10.0)
        second = b.wait_for(b.send(ROUTE_STARTS[1]), timeout=10.0)
        assert first is not None and second is not None
        assert (first.route, second.route) == (0, 1)
        # the stream keeps its route though its next pose is in the other's entry
        again = a.wait_for(a.send(ROUTE_STARTS[1]), timeout=10.0)
        assert again is not None and again.route == 0
        counts = wait_until(lambda: live.client.get("/healthz").json()["bridge"]["routes"]
                            .get(reach), timeout=5.0)
        assert counts["0"] >= 1 and counts["1"] >= 1, counts
        assert "arc3" not in live.client.get("/healthz").json()["bridge"]["routes"]
    with PoseStreamer("arc3", "h2", endpoint=live.endpoint, encoding="json") as c:
        answer = c.wait_for(c.send([0.0, 0.0, 0.0]), timeout=10.0)
        assert answer is not None and answer.model_version == 1 and answer.route is None


def test_a_live_correction_refines_the_route_its_stream_follows(live: Any, reach: str) -> None:
    body = live.client.get(f"/skills/{reach}/models/latest", params={"serialized": True}).json()
    routes = canal_core.routes.routes_from_dict(body["serialized"])
    canal = routes.canals[1]
    idx = np.arange(25, 46)
    wider = canal.directrix[idx] + 1.5 * canal.radii[idx, None] * canal.normals[idx]
    with PoseStreamer(reach, "corrector", endpoint=live.endpoint, encoding="json") as ps:
        first = ps.wait_for(ps.send(ROUTE_STARTS[1]), timeout=10.0)
        assert first is not None and first.route == 1
        ps.start_correction("include", label="wider below")
        for point in wider:
            ps.send(point.tolist())
        made = ps.stop_correction()
    assert made["version"] == body["version"] + 1 and made["correction"]["route"] == 1
    after = canal_core.routes.routes_from_dict(live.client.get(
        f"/skills/{reach}/models/latest", params={"serialized": True}).json()["serialized"])
    assert len(after.canals[1].corrections) == 1 and not after.canals[0].corrections


def test_a_pose_beyond_the_followed_routes_reach_is_left_out_of_its_correction(
        live: Any) -> None:
    # The bridge measured a captured pose's reach against the canal of all routes, the
    # service against the route the stream follows: a pose within the first and beyond the
    # second was kept, and the service refused the whole push for it.
    fit_two_route_skill(live.client, "reachfar", 80)
    body = live.client.get("/skills/reachfar/models/latest", params={"serialized": True}).json()
    routes = canal_core.routes.routes_from_dict(body["serialized"])
    canal = routes.canals[1]
    pooled, pooled_size = bounds.canal_extent(routes.pooled.directrix, routes.pooled.radii)
    own, own_size = bounds.canal_extent(canal.directrix, canal.radii)
    far = pooled + 0.9999 * bounds.MAX_REACH * pooled_size * np.array([0.0, 0.0, 1.0])
    assert np.linalg.norm(far - own) > bounds.MAX_REACH * own_size  # beyond the route's reach
    idx = np.arange(25, 46)
    wider = canal.directrix[idx] + 1.5 * canal.radii[idx, None] * canal.normals[idx]
    with PoseStreamer("reachfar", "spiked", endpoint=live.endpoint, encoding="json") as ps:
        first = ps.wait_for(ps.send(ROUTE_STARTS[1]), timeout=10.0)
        assert first is not None and first.route == 1
        ps.start_correction("include", label="one pose far off")
        for k, point in enumerate(wider):
            ps.send((far if k == 10 else point).tolist())
        made = ps.stop_correction()
    assert made["correction"]["route"] == 1 and made["correction"]["n_points"] == len(idx) - 1
    assert any("beyond the canal's reach" in n for n in made["notes"]), made["notes"]


def test_a_json_answer_says_the_route_only_for_a_model_of_several() -> None:
    plain = orjson.loads(wire.pack_target_json(1, "ok", [0.0, 0.0], 0.1, 0.2, 3, True, False, 1))
    assert "route" not in plain
    for route in (0, 1, None):
        body = orjson.loads(wire.pack_target_json(1, "ok", [0.0, 0.0], 0.1, 0.2, 3, True, False,
                                                  1, None, None, 0, route))
        assert body["route"] == route
        assert wire.decode_target_json(orjson.dumps(body)).route == route


def test_bridge_processes_serve_routes_and_healthz_sums_them(tmp_path: Any) -> None:
    """The default deployment (bridges in processes of their own, here two shards): each
    stream follows its route, and /healthz adds up every shard's streams by route."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    settings = Settings(data_dir=tmp_path, recordings_enabled=False, zenoh_listen=[endpoint],
                        zenoh_processes=2)
    robots = [f"r{i}" for i in range(6)]
    assert {shard_of("reach", r, 2) for r in robots} == {0, 1}
    with TestClient(create_app(settings)) as client:
        assert client.post("/skills", json={"name": "reach", "dim": 3}).status_code == 201
        for j in range(8):
            assert client.post("/skills/reach/demonstrations",
                               json={"positions": two_route_demo(j).tolist()}).status_code == 201
        assert client.post("/skills/reach/fit", json={"n_samples": 60}).json()["routes"] == 2
        streamers = [PoseStreamer("reach", r, endpoint=endpoint, encoding="json") for r in robots]
        try:
            for i, ps in enumerate(streamers):
                answer = ps.wait_for(ps.send(ROUTE_STARTS[i % 2]), timeout=10.0)
                assert answer is not None and answer.route == i % 2, (robots[i], answer)

            def by_route() -> Any:
                counts = client.get("/healthz").json()["bridge"]["routes"].get("reach", {})
                return counts if sum(counts.values()) == len(robots) else None

            assert wait_until(by_route, 5.0) == {"0": 3, "1": 3}
        finally:
            for ps in streamers:
                ps.close()


def test_the_recording_says_which_route_each_stream_followed(live: Any, reach: str) -> None:
    import io

    from mcap.reader import make_reader

    for k, start in enumerate(ROUTE_STARTS):
        r = run_sim(reach, robot=f"rec{k}", start=start, rate_hz=200.0, timeout_s=20.0,
                    endpoint=live.endpoint, encoding="binary")
        assert r.reached_end, (k, r.statuses)

    def states() -> dict[str, set[int | None]]:
        mcap = live.client.get(f"/skills/{reach}/recording.mcap").content
        out: dict[str, set[int | None]] = {}
        for _s, channel, message in make_reader(io.BytesIO(mcap)).iter_messages():
            if channel.topic in ("/live/rec0/state", "/live/rec1/state"):
                out.setdefault(channel.topic, set()).add(orjson.loads(message.data).get("route"))
        return out

    seen = wait_until(lambda: (lambda s: s if len(s) == 2 else None)(states()), timeout=10.0)
    assert seen == {"/live/rec0/state": {0}, "/live/rec1/state": {1}}, seen


def _follow(ps: PoseStreamer, x: np.ndarray, steps: int) -> tuple[np.ndarray, list[wire.Target]]:
    answers = []
    for _ in range(steps):
        t = ps.wait_for(ps.send(x.tolist()), timeout=5.0)
        assert t is not None and t.target is not None, t
        answers.append(t)
        x = x + 0.5 * (np.asarray(t.target) - x)
    return x, answers


def test_a_stream_keeps_its_way_when_a_refit_numbers_the_routes_afresh(live: Any) -> None:
    # A refit numbers routes afresh (route 0 is the first demonstration's: upload the first
    # way's demonstrations again and the other way becomes route 0). A stream kept its route *number*: the robot on the -y way was given
    # targets on the +y way, 0.7 m across, pose after pose. Through a version of one route
    # it kept a stale number too, and on a route it was moved to it was placed at the share
    # of the canal it had reached on the old one.
    client = live.client
    fit_two_route_skill(client, "renum", 80)
    ids = [d["id"] for d in client.get("/skills/renum/demonstrations").json()["items"]]

    def minus_y_route() -> int:
        model = client.get("/skills/renum/models/latest").json()
        middles = [np.asarray(r["directrix"])[len(r["directrix"]) // 2, 1] for r in model["route_canals"]]
        return int(np.argmin(middles))

    before = minus_y_route()
    with PoseStreamer("renum", "arm", endpoint=live.endpoint, encoding="json") as ps:
        x, answers = _follow(ps, np.array(ROUTE_STARTS[1]), 25)
        assert answers[-1].route == before and x[1] < -0.2, (answers[-1], x)
        for fit, routes in (({"n_samples": 80, "routes": 1}, None),  # one route between
                            ({"n_samples": 80}, "renumbered")):
            if routes == "renumbered":  # the +y demonstrations again, after the -y ones
                for j, demo_id in enumerate(ids[:4]):
                    assert client.delete(f"/skills/renum/demonstrations/{demo_id}").status_code == 204
                    client.post("/skills/renum/demonstrations",
                                json={"positions": two_route_demo(j).tolist()})
            assert client.post("/skills/renum/fit", json=fit).status_code == 201
            x, answers = _follow(ps, x, 8)
            assert all(t.target[1] < -0.1 for t in answers), answers  # the same way
            assert answers[-1].status == "ok", answers
        after = minus_y_route()
        assert after != before, "the refit was to number the routes afresh"
        assert answers[-1].route == after
        # and the robot goes on along its way to the end
        x, answers = _follow(ps, x, 200)
        assert answers[-1].done and all(t.target[1] < 0.05 for t in answers), answers[-1]


def test_a_glitch_sent_as_a_restart_does_not_switch_the_route(live: Any, reach: str) -> None:
    # A restart pose chose the route again wherever it was: one glitch at the other way's
    # start, sent with the flag, put the robot on the other route.
    with PoseStreamer(reach, "restart-glitch", endpoint=live.endpoint, encoding="json") as ps:
        x, answers = _follow(ps, np.array(ROUTE_STARTS[1]), 10)
        route = answers[-1].route
        held = ps.wait_for(ps.send(list(ROUTE_STARTS[0]), restart=True), timeout=5.0)
        assert held is not None and held.status == "restart_pending", held
        assert held.target is None, held
        x, answers = _follow(ps, x, 5)
        assert all(t.route == route and t.target[1] < 0.0 for t in answers), answers


def _steered(ps: PoseStreamer, x: np.ndarray, steps: int, u: float, restart: bool = False
             ) -> tuple[np.ndarray, list[wire.Target]]:
    """``steps`` poses along the stream's plan with the steering input ``u`` held; the first
    pose asks for a restart when ``restart``: held poses (``restart_pending``) stay put."""
    answers = []
    for k in range(steps):
        # an input with every pose: a loaded machine may take longer than the steering's
        # 0.5 s timeout over two round trips, which ends the run
        ps.steer(u, 0.0)
        t = ps.wait_for(ps.send(x.tolist(), restart=restart and k == 0), timeout=5.0)
        assert t is not None, k
        answers.append(t)
        if t.target is not None:
            x = x + 0.3 * (np.asarray(t.target) - x)
    return x, answers


def test_a_steered_run_is_kept_as_a_correction_of_the_one_route_it_was_steered_on(
        live: Any) -> None:
    # A restart onto the other route with the steering still held went on with the same
    # steered run: steer/keep stored the poses of both routes as one correction of the second.
    client = live.client
    fit_two_route_skill(client, "steerways", 80)
    with PoseStreamer("steerways", "joy", endpoint=live.endpoint, encoding="json") as ps:
        x, answers = _follow(ps, np.array(ROUTE_STARTS[0]), 5)
        x, first = _steered(ps, x, 40, 1.0)
        assert {t.route for t in first} == {0}, first
        _, second = _steered(ps, np.array(ROUTE_STARTS[1]), 30, -1.0, restart=True)
        assert second[-1].route == 1 and second[-1].status == "ok", second[-1]
        kept = ps.keep_steered(label="below")
        assert kept["correction"]["route"] == 1
        # the poses from the restart pose on (held ones included), none of the first route's
        assert kept["correction"]["n_points"] <= len(second), kept["correction"]
        assert kept["correction"]["n_points"] >= len(second) - 2, kept["correction"]
        # the run on the first route is the last steered run, a correction of that route
        earlier = ps.keep_steered(label="above")
        assert earlier["correction"]["route"] == 0
        # (its first poses may go by before the first input reaches the bridge)
        assert len(first) // 2 < earlier["correction"]["n_points"] <= len(first)
        with pytest.raises(LiveError, match="no steered run"):
            ps.keep_steered()
    # a refit keeping the corrections places each on the route its poses lie along: its own
    refit = client.post("/skills/steerways/fit", json={"n_samples": 80, "keep_corrections": True})
    assert refit.status_code == 201, refit.text
    items = client.get("/skills/steerways/corrections").json()["items"]
    latest = client.get("/skills/steerways/models/latest").json()
    routes_of = {c["label"]: c["route"] for c in items if c["id"] in latest["corrections"]}
    assert routes_of == {"below": 1, "above": 0}, (routes_of, items)
