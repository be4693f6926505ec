"""One door, one key: with --token the live path is closed too. A stranger's Zenoh session
(no credentials) can neither read a model, capture a demo nor get targets; a robot that
holds the token can; /healthz names no stream or skill without the token; --zenoh-open
leaves the path open on purpose, and a config file that leaves it open is refused."""

from __future__ import annotations

import time
import warnings
from pathlib import Path

import numpy as np
import pytest
import zenoh
from canal_client.live import LiveError, NoBridgeError, PoseStreamer, client_config, query_json

with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    from fastapi.testclient import TestClient

from canal_service.app import create_app
from canal_service.core.config import Settings
from canal_testing import free_port
from live_helpers import make_skill

from canal_protocol.credentials import LIVE_USER, live_password
from canal_protocol.keys import model_key

pytestmark = pytest.mark.timeout(120)

TOKEN = "s3cret-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


def _app(tmp: Path, **settings) -> tuple[TestClient, str]:  # type: ignore[no-untyped-def]
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    client = TestClient(create_app(Settings(
        data_dir=tmp, recordings_enabled=False, zenoh_listen=[endpoint], token=TOKEN,
        **settings)), headers=AUTH)
    return client, endpoint


def _stranger_reads_nothing(endpoint: str, skill: str) -> None:
    """A session with no credentials: no model, no demo capture, no targets."""
    with zenoh.open(client_config(endpoint)) as stranger:
        time.sleep(0.3)
        replies = [r for r in stranger.get(model_key(skill), timeout=1.0) if r.ok is not None]
        assert replies == [], "a stranger read the model"
        with pytest.raises(LiveError):
            query_json(stranger, f"canal/{skill}/thief/demo/start", {}, timeout=1.0)
    with pytest.raises(NoBridgeError, match="no Canal bridge") as refused:  # no targets either
        PoseStreamer(skill, "thief", endpoint=endpoint, connect_timeout=1.0)
    # refused at connection: the session reached no node, and the error says a token may be why
    assert not refused.value.reached and "--token" in str(refused.value)


@pytest.mark.parametrize("processes", [0, 1])
def test_the_token_closes_the_live_path(tmp_path: Path, processes: int) -> None:
    client, endpoint = _app(tmp_path, zenoh_processes=processes)
    with client:
        make_skill(client, "sec", 3)
        _stranger_reads_nothing(endpoint, "sec")
        directrix = np.array(client.get("/skills/sec/models/latest").json()["directrix"])
        # the robot with the token: model, targets, demo capture
        with PoseStreamer("sec", "arm1", endpoint=endpoint, token=TOKEN) as ps:
            assert ps.model() is not None
            got = ps.wait_for(ps.send(directrix[3], restart=True), 3.0)
            assert got is not None and got.status == "ok"
            assert query_json(ps.session, "canal/sec/arm1/demo/start", {})["capturing"]
        # a wrong password is a stranger too
        config = client_config(endpoint)
        config.insert_json5("transport/auth/usrpwd/user", f'"{LIVE_USER}"')
        config.insert_json5("transport/auth/usrpwd/password", '"guess"')
        with zenoh.open(config) as guesser:
            time.sleep(0.3)
            assert [r for r in guesser.get(model_key("sec"), timeout=1.0) if r.ok] == []
        health = client.get("/healthz").json()["bridge"]
        assert health["status"] == "ok"
        if processes == 0:
            assert health["access"] == "authenticated"
        # the users file holds the derived password, never the token, for this user only
        users = tmp_path / "zenoh-users.txt"
        assert users.read_text() == f"{LIVE_USER}:{live_password(TOKEN)}\n"
        assert TOKEN not in users.read_text() and users.stat().st_mode & 0o077 == 0


def test_healthz_names_no_stream_or_skill_without_the_token(tmp_path: Path) -> None:
    client, endpoint = _app(tmp_path, zenoh_processes=0)
    anonymous = TestClient(client.app)  # the same app, no header (and no second lifespan)
    with client:
        make_skill(client, "secretskill", 3)
        directrix = np.array(client.get("/skills/secretskill/models/latest").json()["directrix"])
        with PoseStreamer("secretskill", "secretrobot", endpoint=endpoint, token=TOKEN) as ps:
            assert ps.wait_for(ps.send(directrix[3], restart=True), 3.0) is not None
            time.sleep(0.5)  # the live recorder hears of the stream
            public = anonymous.get("/healthz")
            assert public.status_code in (200, 503)
            assert "secretskill" not in public.text and "secretrobot" not in public.text
            assert public.json()["bridge"]["streams"] == 1
            full = client.get("/healthz").json()
            assert full["bridge"]["streams"] == 1


def test_zenoh_open_leaves_the_path_open_on_purpose(tmp_path: Path) -> None:
    client, endpoint = _app(tmp_path, zenoh_processes=0, zenoh_open=True)
    with client:
        make_skill(client, "pub", 3)
        with zenoh.open(client_config(endpoint)) as anyone:
            body = query_json(anyone, model_key("pub"))
        assert body["directrix"]
        assert client.get("/healthz").json()["bridge"]["access"] == "open"


def test_an_open_config_file_with_a_token_keeps_the_bridge_down(tmp_path: Path) -> None:
    port = free_port()
    config = tmp_path / "open.json5"
    config.write_text(f'{{mode: "peer", listen: {{endpoints: ["tcp/127.0.0.1:{port}"]}}, '
                      'scouting: {multicast: {enabled: false}}}')
    client, _ = _app(tmp_path, zenoh_processes=0, zenoh_config=config)
    with client:
        bridge = client.get("/healthz").json()["bridge"]
        assert bridge["status"] == "down"
        assert "--zenoh-open" in bridge["detail"] and "open" in bridge["detail"]


def test_the_startup_line_says_how_the_live_path_is_closed() -> None:
    from canal_service.core.cli import endpoints_line, settings_from_args

    assert endpoints_line(settings_from_args(["--token", "t"])).endswith(
        "live path closed by the token")
    assert endpoints_line(settings_from_args(["--token", "t", "--zenoh-open"])).endswith(
        "live path OPEN to anyone (--zenoh-open)")
