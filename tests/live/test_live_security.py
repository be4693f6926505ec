"""Attacks on the open live path: each of these was possible on an earlier bridge."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
import zenoh
from canal_client.live import PoseStreamer, client_config, query_json
from live_helpers import make_skill

from canal_protocol import wire

pytestmark = pytest.mark.timeout(60)

JSON = zenoh.Encoding.APPLICATION_JSON


class Listener:
    """A robot's view of its target key: every sample that arrives there."""

    def __init__(self, session, key):
        self.got: list[bytes] = []
        self._lock = threading.Lock()
        self._sub = session.declare_subscriber(key, self._on)

    def _on(self, sample):
        with self._lock:
            self.got.append(sample.payload.to_bytes())

    def close(self):
        self._sub.undeclare()


def _directrix(live, skill="arc3"):
    return np.array(live.client.get(f"/skills/{skill}/models/latest").json()["directrix"])


@pytest.mark.parametrize("key", ["canal/arc3/*/pose", "canal/*/arm1/pose", "canal/*/*/pose",
                                 "canal/arc3/arm$*/pose", "canal/**/pose", "canal/arc3/**/pose"])
def test_wildcard_put_never_reaches_another_robots_target(live, key):
    before = live.metric("canal_live_errors_total", 'status="bad_key"')
    with zenoh.open(client_config(live.endpoint)) as session:
        arm1 = Listener(session, "canal/arc3/arm1/target")
        other = Listener(session, "canal/arc2/arm1/target")
        # arm1 is a real stream (so the bridge has a publisher on its target key)
        with PoseStreamer("arc3", "arm1", endpoint=live.endpoint, session=session) as ps:
            x = _directrix(live)[3]
            assert ps.wait_for(ps.send(x, restart=True), 1.0) is not None
            time.sleep(0.1)
            n = len(arm1.got)
            session.put(key, wire.encode_pose_json(10**12, x), encoding=JSON)
            time.sleep(0.5)
            assert len(arm1.got) == n, f"a put on {key} was answered on arm1's target"
            assert other.got == []
            assert ps.latest().seq == 0  # arm1's client still sees its own answer
        arm1.close()
        other.close()
    assert live.metric("canal_live_errors_total", 'status="bad_key"') >= before + 1


@pytest.mark.parametrize("key", ["canal/*/arm1/demo/start", "canal/arc3/*/demo/start",
                                 "canal/**"])
def test_wildcard_demo_queries_are_refused(live, key):
    with zenoh.open(client_config(live.endpoint)) as session:
        replies = list(session.get(key, payload=b"{}", timeout=1.0))
    assert [r for r in replies if r.ok is not None] == []
    with zenoh.open(client_config(live.endpoint)) as session:  # the plain key still works
        body = query_json(session, "canal/arc3/arm9/demo/start", {})
    assert body["capturing"] is True


def test_a_strangers_high_seq_does_not_hijack_the_robots_client(live):
    x = _directrix(live)[4]
    with PoseStreamer("arc3", "victim", endpoint=live.endpoint) as ps:
        assert ps.wait_for(ps.send(x, restart=True), 1.0).seq == 0
        with zenoh.open(client_config(live.endpoint)) as stranger:
            far = [0.5, 40.0, -30.0]
            stranger.put("canal/arc3/victim/pose", wire.encode_pose_json(2**62, far),
                         encoding=JSON)
            time.sleep(0.3)
        # the stranger's answer (seq 2**62) is not "latest" and does not shadow ours
        assert ps.latest().seq == 0
        # (the stranger's pose did move this stream's tracker: on an open network anyone may
        # put on any key; the secure config's ACL is what stops that, see test_live_acl.py)
        answer = ps.wait_for(ps.send(x, restart=True), 1.0)
        assert answer is not None and answer.seq == 1 and answer.status == "ok"


def test_junk_skills_leave_nothing_running(live):
    import dataclasses

    bridge = live.client.app.state.bridge
    before = live.metric("canal_live_errors_total", 'status="unknown_skill"')
    loads = []
    table = bridge.models
    original, options = table.load, table.options
    table.load = lambda skill: (loads.append(skill), original(skill))[1]
    # a negative entry lives 10 s; a slow machine must not see it expire mid-test
    table.options = dataclasses.replace(options, negative_ttl_s=300.0)
    try:
        with zenoh.open(client_config(live.endpoint)) as session:
            for i in range(3000):
                session.put(f"canal/junk{i}/r/pose", wire.encode_pose(0, [0.0, 0.0, 0.0]))
            for i in range(100):  # the same names again: answered from the negative cache
                session.put(f"canal/junk{i}/r/pose", wire.encode_pose(1, [0.0, 0.0, 0.0]))
            deadline = time.monotonic() + 20
            while (live.metric("canal_live_errors_total", 'status="unknown_skill"')
                   < before + 3100 and time.monotonic() < deadline):
                time.sleep(0.1)
    finally:
        table.load, table.options = original, options
    assert live.metric("canal_live_errors_total", 'status="unknown_skill"') == before + 3100
    junk = [s for s in loads if s.startswith("junk")]
    assert len(junk) == 3000 == len(set(junk))  # one read per name, none for the repeats
    # and afterwards the service is idle: nothing re-reads 3,000 names
    cpu = time.process_time()
    time.sleep(1.0)
    assert time.process_time() - cpu < 0.3
    assert not any(k.startswith("canal/junk") for k in bridge.streams)  # no publishers
    assert len(table.unknown) <= table.options.negative_max
    assert not any(s.startswith("junk") for s in table.models)  # nothing to refresh


@pytest.mark.parametrize("position", [[50.0, 50.0, 50.0], [1e15, 1e15, 1e15],
                                      [-1e15, 1e15, 0.0]])
@pytest.mark.parametrize("encoding", ["json", "binary"])
def test_far_poses_are_outside_never_ok_or_done(live, position, encoding):
    with PoseStreamer("arc3", f"far-{encoding}", endpoint=live.endpoint,
                      encoding=encoding) as ps:
        for restart in (True, False):
            answer = ps.wait_for(ps.send(position, restart=restart), 1.0)
            assert answer is not None
            assert answer.status == "outside_canal" and not answer.done
            assert not answer.inside and answer.progress < 1.0
            assert np.isfinite(answer.target).all()  # a usable way back in


def test_coalesced_poses_are_counted_per_robot(tmp_path):
    """A burst beyond the backlog: only the newest pose is answered, and the target says how
    many were skipped."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        from fastapi.testclient import TestClient

    from canal_service.app import create_app
    from canal_service.core.config import Settings
    from canal_testing import free_port

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    settings = Settings(data_dir=tmp_path, recordings_enabled=False, zenoh_listen=[endpoint],
                        zenoh_processes=0, zenoh_coalesce_backlog=1)
    with TestClient(create_app(settings)) as client:
        make_skill(client, "s", 3)
        bridge = client.app.state.bridge
        x = np.array(client.get("/skills/s/models/latest").json()["directrix"])[5]
        with PoseStreamer("s", "burst", endpoint=endpoint, encoding="json") as ps:
            assert ps.wait_for(ps.send(x, restart=True), 1.0) is not None
            # hold the worker so the burst queues up (the worker takes this lock per batch)
            gate = threading.Event()
            original = bridge.path._handle

            def held(batch):
                gate.wait(5.0)
                return original(batch)

            bridge.path._handle = held
            ps.send(x)  # this one is taken by the held worker
            time.sleep(0.1)
            seqs = [ps.send(x) for _ in range(30)]
            time.sleep(1.3)
            # the worker is stuck with a queue behind it: the service says so
            r = client.get("/healthz")
            assert r.status_code == 503 and r.json()["status"] == "degraded"
            assert r.json()["bridge"]["status"] == "behind"
            gate.set()
            answer = ps.wait_for(seqs[-1], 2.0)
            bridge.path._handle = original
        assert answer is not None and answer.seq == seqs[-1]
        assert answer.coalesced >= 20
        time.sleep(1.5)  # idle again, and idle is not behind
        assert client.get("/healthz").json()["bridge"]["status"] == "ok"
        bridge.flush_metrics()
        text = client.get("/metrics").text
        line = next(v for v in text.splitlines()
                    if v.startswith("canal_live_poses_coalesced_total "))
        assert float(line.split()[-1]) >= 20
