"""How the bridge starts and stops: defaults, flags, a taken port, its own process."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import warnings

import pytest
import zenoh

with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    from fastapi.testclient import TestClient

from canal_client.sim import run_sim
from canal_service.app import create_app
from canal_service.bridge import BridgeOptions, zenoh_config
from canal_service.core.cli import settings_from_args
from canal_service.core.config import Settings
from canal_testing import free_port
from live_helpers import make_skill

pytestmark = pytest.mark.timeout(60)


def _value(config: zenoh.Config, key: str):
    import json

    return json.loads(config.get_json(key))


def test_defaults_are_loopback_peer_without_multicast_scouting(tmp_path):
    settings = Settings(data_dir=tmp_path)
    assert settings.zenoh_enabled and settings.zenoh_listen == ["tcp/127.0.0.1:7447"]
    config = zenoh_config(BridgeOptions.from_settings(settings))
    assert _value(config, "mode") == "peer"
    assert _value(config, "listen/endpoints") == ["tcp/127.0.0.1:7447"]
    assert _value(config, "scouting/multicast/enabled") is False
    # the service started with those defaults (only the port moved off 7447) reports them
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with TestClient(create_app(Settings(data_dir=tmp_path, recordings_enabled=False,
                                        zenoh_listen=[endpoint]))) as client:
        health = client.get("/healthz").json()
    assert health["status"] == "ok"
    assert health["bridge"]["status"] == "ok"
    assert health["bridge"]["listen"] == [endpoint]
    assert health["bridge"]["multicast_scouting"] is False and health["bridge"]["mode"] == "peer"


def test_command_line_flags():
    s = settings_from_args([])
    assert s.zenoh_enabled and s.zenoh_config is None and s.zenoh_prefix == "canal"
    s = settings_from_args(["--no-zenoh", "--zenoh-listen", "tcp/127.0.0.1:1234",
                            "--zenoh-listen", "tcp/127.0.0.1:1235", "--zenoh-config", "z.json5",
                            "--zenoh-connect", "tcp/10.0.0.1:7447", "--zenoh-prefix", "lab"])
    assert not s.zenoh_enabled and s.zenoh_listen == ["tcp/127.0.0.1:1234", "tcp/127.0.0.1:1235"]
    assert str(s.zenoh_config) == "z.json5" and s.zenoh_connect == ["tcp/10.0.0.1:7447"]
    assert s.zenoh_prefix == "lab"


def test_config_file_is_used_unchanged(tmp_path):
    port = free_port()
    path = tmp_path / "zenoh.json5"
    path.write_text('{ mode: "peer", listen: { endpoints: ["tcp/127.0.0.1:' + str(port)
                    + '"] }, scouting: { multicast: { enabled: false } } }')
    config = zenoh_config(BridgeOptions(config_file=path, listen=("tcp/127.0.0.1:1",)))
    assert _value(config, "listen/endpoints") == [f"tcp/127.0.0.1:{port}"]


def test_disabled_bridge(tmp_path):
    with TestClient(create_app(Settings(data_dir=tmp_path, recordings_enabled=False,
                                        zenoh_enabled=False))) as client:
        assert client.get("/healthz").json()["bridge"] == {"status": "disabled"}


def test_taken_port_leaves_rest_up_and_bridge_down(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    config = zenoh.Config()
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("listen/endpoints", f'["{endpoint}"]')
    with zenoh.open(config):
        started = time.monotonic()
        with TestClient(create_app(Settings(data_dir=tmp_path, recordings_enabled=False,
                                            zenoh_listen=[endpoint]))) as client:
            r = client.get("/healthz")
            # the REST API serves, but the service is not whole without its live path
            assert r.status_code == 503 and r.json()["status"] == "degraded"
            bridge = r.json()["bridge"]
            assert bridge["status"] == "down" and bridge["detail"]
            assert client.post("/skills", json={"name": "s", "dim": 3}).status_code == 201
            assert "canal_live_bridge_up 0.0" in client.get("/metrics").text
        # the supervisor learns of the failure from the process's exit, not by waiting out
        # its 60 s ready timeout (a generous bound: the machine may be loaded)
        assert time.monotonic() - started < 45


def test_app_exit_closes_the_session(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with TestClient(create_app(Settings(data_dir=tmp_path, recordings_enabled=False,
                                        zenoh_listen=[endpoint], zenoh_processes=0))) as client:
        make_skill(client, "s", 3)
        assert run_sim("s", rate_hz=1000.0, seed=0, endpoint=endpoint, timeout_s=10).reached_end
        bridge = client.app.state.bridge
        started = time.monotonic()
    assert time.monotonic() - started < 5
    assert bridge.session is None and not any(t.is_alive() for t in bridge._threads)


def test_standalone_bridge_process(tmp_path):
    """``python -m canal_service.bridge`` against a database the REST app filled."""
    with TestClient(create_app(Settings(data_dir=tmp_path, recordings_enabled=False,
                                        zenoh_enabled=False))) as client:
        make_skill(client, "s", 3)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    env = dict(os.environ, RERUN_TELEMETRY_ENABLED="false", CANAL_LOG_LEVEL="warning")
    proc = subprocess.Popen(
        [sys.executable, "-m", "canal_service.bridge", "--data-dir", str(tmp_path),
         "--zenoh-listen", endpoint, "--no-recordings"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        line = proc.stdout.readline()
        assert "ready" in line, proc.stderr.read() if proc.poll() is not None else line
        result = run_sim("s", rate_hz=1000.0, seed=4, endpoint=endpoint, timeout_s=10)
        assert result.reached_end and result.all_inside
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_a_program_that_never_closes_its_streamer_exits_cleanly(live) -> None:
    # A PoseStreamer left open at exit aborted the process (SIGABRT, "FATAL: exception not
    # rethrown"): its receiving thread was torn down while blocked in Zenoh.
    script = ("import sys\nfrom canal_client.live import PoseStreamer\n"
              f"ps = PoseStreamer('arc3', 'forgotten', endpoint={live.endpoint!r})\n"
              "ps.wait_for(ps.send([0.1, 0.05, 0.01]), 5.0)\nprint('sent')\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          env=env, timeout=60)
    assert done.returncode == 0 and "sent" in done.stdout, (done.returncode, done.stderr[-2000:])
    assert "FATAL" not in done.stderr, done.stderr[-2000:]
