"""The default deployment: ``canal serve`` starts the bridge in processes of its own."""

from __future__ import annotations

import os
import signal
import sys
import warnings

import numpy as np
import pytest

with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    from fastapi.testclient import TestClient

from canal_client.live import PoseStreamer
from canal_client.sim import run_sim
from canal_service.app import create_app
from canal_service.bridge.bridge import shard_of
from canal_service.core.config import Settings
from canal_testing import free_port
from live_helpers import make_skill, metric, wait_until

pytestmark = pytest.mark.timeout(90)


def test_bridge_process_serves_reports_hears_fits_and_its_death_degrades(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    # refresh every 60 s: a model switch within a second can only come from the fit push
    settings = Settings(data_dir=tmp_path, recordings_enabled=False, zenoh_listen=[endpoint],
                        zenoh_refresh_s=60.0)
    assert settings.zenoh_processes == 1  # the default
    with TestClient(create_app(settings)) as client:
        health = client.get("/healthz").json()
        bridge = health["bridge"]
        assert health["status"] == "ok" and bridge["status"] == "ok"
        assert bridge["processes"] == 1 and bridge["listen"] == [endpoint]
        assert bridge["access"] == "open" and bridge["acl"] is False
        make_skill(client, "s", 3)
        result = run_sim("s", rate_hz=1000.0, seed=2, endpoint=endpoint, timeout_s=10)
        assert result.reached_end and result.all_inside and result.model_version == 1
        # the bridge process's counts reach the service's /metrics
        assert wait_until(lambda: metric(client, "canal_live_poses_total") >= result.n_steps,
                          5.0)
        assert metric(client, "canal_live_targets_total") >= result.n_steps
        # its step times too: the histogram stayed at zero, "no pose stepped" on a dashboard
        poses = metric(client, "canal_live_poses_total")
        assert wait_until(lambda: metric(client, "canal_live_step_seconds_count") >= poses, 5.0)
        assert metric(client, "canal_live_step_seconds_bucket", 'le="+Inf"') == \
            metric(client, "canal_live_step_seconds_count")
        assert 0.0 < metric(client, "canal_live_step_seconds_sum") < 10.0
        # every count, steering inputs too (a bridge process's were never added)
        with PoseStreamer("s", "joy", endpoint=endpoint) as ps:
            ps.wait_for(ps.send(result.start.tolist(), restart=True), timeout=5.0)
            for _ in range(5):
                ps.steer(1.0, 0.0)
                ps.wait_for(ps.send(result.start.tolist()), timeout=5.0)
        assert wait_until(lambda: metric(client, "canal_live_steer_inputs_total") >= 5, 5.0)
        # and its drain count to /healthz (one pose at a time: about a drain per pose)
        def reported():
            b = client.get("/healthz").json()["bridge"]["bridges"][0]
            return b if b["poses"] >= result.n_steps else None

        reported_bridge = wait_until(reported, 5.0)
        assert 0 < reported_bridge["drains"] <= reported_bridge["poses"]
        # poses that waited for a model load (the fit notice usually loads it first)
        assert 0 <= reported_bridge["parked"] <= reported_bridge["poses"]
        # the bridge compiles its tracker kernel off the pose path and says when it steps
        # with it (numpy meanwhile; a cold numba cache takes seconds)
        assert reported_bridge["tracker"] in ("compiling", "compiled")
        def tracker():
            return client.get("/healthz").json()["bridge"]["bridges"][0]["tracker"]

        assert wait_until(lambda: tracker() == "compiled", 60.0)
        # a fit through REST reaches the bridge process at once (pushed, not polled)
        directrix = np.array(client.get("/skills/s/models/latest").json()["directrix"])
        with PoseStreamer("s", "after-fit", endpoint=endpoint) as ps:
            first = ps.wait_for(ps.send(directrix[5], restart=True), 2.0)
            assert first is not None and first.model_version == 1
            assert client.post("/skills/s/fit", json={"n_samples": 90}).status_code == 201

            def version():
                answer = ps.wait_for(ps.send(directrix[5]), 1.0)
                return answer is not None and answer.model_version == 2

            assert wait_until(version, 3.0)
        # what a bridge process stores (a demonstration, a correction captured live) is
        # counted too: the process's own counters never reached /metrics
        with PoseStreamer("s", "teacher", endpoint=endpoint) as ps:
            ps.wait_for(ps.send(directrix[0].tolist(), restart=True), timeout=5.0)
            ps.start_demo()
            for point in directrix[::3]:
                ps.wait_for(ps.send(point.tolist()), timeout=5.0)
            ps.stop_demo()
            ps.start_correction("include")
            for point in directrix[20:40]:
                ps.send((point + [0.0, 0.0, 0.002]).tolist())
            ps.stop_correction()
        assert wait_until(lambda: metric(client, "canal_demonstrations_stored_total",
                                         'source="zenoh"') == 1, 5.0)
        assert wait_until(lambda: metric(client, "canal_corrections_total",
                                         'kind="include"') == 1, 5.0)
        # the bridge process dies: /healthz says the service is degraded
        bridges = client.app.state.bridge  # type: ignore[attr-defined]
        bridges.children[0].proc.send_signal(signal.SIGKILL)
        bridges.children[0].proc.wait(5)
        r = client.get("/healthz")
        assert r.status_code == 503 and r.json()["status"] == "degraded"
        assert r.json()["bridge"]["status"] == "down"


def test_two_bridge_processes_share_the_robots(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    settings = Settings(data_dir=tmp_path, recordings_enabled=False, zenoh_listen=[endpoint],
                        zenoh_processes=2)
    robots = [f"r{i}" for i in range(6)]
    assert {shard_of("s", r, 2) for r in robots} == {0, 1}  # both shards have robots
    with TestClient(create_app(settings)) as client:
        make_skill(client, "s", 3)
        directrix = np.array(client.get("/skills/s/models/latest").json()["directrix"])
        streamers = [PoseStreamer("s", r, endpoint=endpoint) for r in robots]
        try:
            answers = {}
            for r, ps in zip(robots, streamers, strict=True):
                for k in range(20):
                    answer = ps.wait_for(ps.send(directrix[10 + k], restart=k == 0), 2.0)
                    assert answer is not None and answer.status == "ok", (r, k)
                answers[r] = answer
        finally:
            for ps in streamers:
                ps.close()

        def per_shard():
            bridges = client.get("/healthz").json()["bridge"]["bridges"]
            streams = [b["streams"] for b in bridges]
            # status lines come every 0.5 s: wait for both to report every stream
            return streams if all(streams) and sum(streams) == len(robots) else None

        streams = wait_until(per_shard, 5.0)
        assert streams is not None and sum(streams) == len(robots)  # one answer per pose
        assert client.get("/healthz").json()["bridge"]["processes"] == 2


def test_canal_serve_passes_every_bridge_setting_to_its_bridge_processes(tmp_path, monkeypatch):
    """``canal serve --zenoh-coalesce-backlog 32`` must reach the bridge processes: their
    argv, parsed as the bridge parses it, gives the same bridge options as the service's
    settings. Before, only the preload flags were passed; backlog, idle, refresh, lookahead,
    queue capacity and the model cache silently took their defaults in the bridges."""
    from canal_service.bridge.__main__ import _take
    from canal_service.bridge.config import BridgeOptions
    from canal_service.bridge.processes import PASSED_SETTINGS, BridgeProcesses
    from canal_service.core.cli import settings_from_args

    for name in [k for k in os.environ if k.startswith("CANAL_")]:
        monkeypatch.delenv(name)
    # every numeric zenoh setting but the process count itself is a bridge's concern
    numeric = {name for name, f in Settings.model_fields.items()
               if name.startswith("zenoh_") and f.annotation in (int, float)}
    assert numeric - {"zenoh_processes"} <= set(PASSED_SETTINGS)
    changed = {"zenoh_prefix": "fleet", "log_level": "warning", "recordings_live_hz": 25.0,
               "zenoh_queue_capacity": 999, "zenoh_coalesce_backlog": 32, "zenoh_idle_s": 7.5, "zenoh_max_streams": 77,
               "zenoh_refresh_s": 0.25, "zenoh_lookahead": 3, "zenoh_preload_max": 0,
               "zenoh_preload_keep_s": 12.5, "model_cache_size": 9}
    assert set(changed) == set(PASSED_SETTINGS)
    for name, value in changed.items():
        assert getattr(Settings(data_dir=tmp_path), name) != value, name  # not a default
    parent = Settings(data_dir=tmp_path, recordings_enabled=False, **changed)
    argv = BridgeProcesses(parent, None)._argv(1, 2)  # type: ignore[arg-type]
    assert argv[:3] == [sys.executable, "-m", "canal_service.bridge"]
    # what the bridge's main() does with its argv
    flags = argv[3:]
    assert _take(flags, "--shard") == "1/2"
    assert _take(flags, "--supervised", has_value=False) == ""
    child = settings_from_args(flags)
    for name in (*PASSED_SETTINGS, "data_dir", "recordings_enabled"):
        assert getattr(child, name) == getattr(parent, name), name
    assert child.resolved_database_url == parent.resolved_database_url
    ours, theirs = (BridgeOptions.from_settings(s) for s in (parent, child))
    for name in BridgeOptions.__dataclass_fields__:
        if name not in ("listen", "connect"):  # passed as CANAL_ZENOH_LISTEN/CONNECT
            assert getattr(theirs, name) == getattr(ours, name), name
