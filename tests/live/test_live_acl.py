"""The shipped secure deployment (docker/zenoh/*-secure.json5): TLS, user/password, ACL with
default deny, enforced by a real Zenoh router; the service's bridge process behind it."""

from __future__ import annotations

import datetime
import ipaddress
import threading
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
import zenoh

with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    from fastapi.testclient import TestClient

from canal_client.live import PoseStreamer
from canal_service.app import create_app
from canal_service.core.config import Settings
from canal_testing import free_port
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID
from live_helpers import make_skill

pytestmark = pytest.mark.timeout(90)

SECURE = Path(__file__).resolve().parents[2] / "docker" / "zenoh"
PASSWORDS = {"canal-service": "svc-secret", "arm1": "arm1-secret", "arm2": "arm2-secret",
             "operator": "op-secret"}


def _certificates(folder: Path) -> None:
    """A throw-away CA and a certificate for localhost / 127.0.0.1 signed by it."""
    now = datetime.datetime.now(datetime.UTC)

    def name(cn):
        return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)])

    def build(subject, issuer, key, signer, extensions):
        b = (x509.CertificateBuilder().subject_name(subject).issuer_name(issuer)
             .public_key(key.public_key()).serial_number(x509.random_serial_number())
             .not_valid_before(now - datetime.timedelta(minutes=5))
             .not_valid_after(now + datetime.timedelta(days=1)))
        for ext, critical in extensions:
            b = b.add_extension(ext, critical=critical)
        return b.sign(signer, hashes.SHA256())

    ca_key, key = ec.generate_private_key(ec.SECP256R1()), ec.generate_private_key(ec.SECP256R1())
    ca = build(name("canal-test-ca"), name("canal-test-ca"), ca_key, ca_key,
               [(x509.BasicConstraints(ca=True, path_length=None), True)])
    cert = build(name("localhost"), ca.subject, key, ca_key, [
        (x509.SubjectAlternativeName([x509.DNSName("localhost"),
                                      x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]), False),
        (x509.BasicConstraints(ca=False, path_length=None), True)])
    (folder / "ca.pem").write_bytes(ca.public_bytes(serialization.Encoding.PEM))
    (folder / "router.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    (folder / "router.key").write_bytes(key.private_bytes(
        serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption()))


def _quote(value) -> str:
    import json

    return json.dumps(value)


def _client_file(tmp: Path, shipped: str, endpoint: str, user: str | None,
                 password: str | None) -> Path:
    """A shipped client config with only the router address, CA path and password changed."""
    config = zenoh.Config.from_file(str(SECURE / shipped))
    config.insert_json5("connect/endpoints", _quote([endpoint]))
    config.insert_json5("transport/link/tls/root_ca_certificate", _quote(str(tmp / "ca.pem")))
    if user is None:
        config.insert_json5("transport/auth/usrpwd", "{}")
    else:
        config.insert_json5("transport/auth/usrpwd/user", _quote(user))
        config.insert_json5("transport/auth/usrpwd/password", _quote(password))
    path = tmp / f"{shipped}-{user}-{password}.json"
    path.write_text(str(config))
    return path


@pytest.fixture(scope="module")
def secure(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("secure")
    _certificates(tmp)
    (tmp / "users.txt").write_text("".join(f"{u}:{p}\n" for u, p in PASSWORDS.items()))
    port = free_port()
    config = zenoh.Config.from_file(str(SECURE / "router-secure.json5"))
    config.insert_json5("listen/endpoints", _quote([f"tls/127.0.0.1:{port}"]))
    for key, file in (("root_ca_certificate", "ca.pem"), ("listen_certificate", "router.pem"),
                      ("listen_private_key", "router.key")):
        config.insert_json5(f"transport/link/tls/{key}", _quote(str(tmp / file)))
    config.insert_json5("transport/auth/usrpwd/dictionary_file", _quote(str(tmp / "users.txt")))
    endpoint = f"tls/localhost:{port}"
    with zenoh.open(config):
        service_conf = _client_file(tmp, "canal-secure.json5", endpoint, "canal-service",
                                    PASSWORDS["canal-service"])
        # recordings on: the bridge process hands its batches to the service's recorder
        # through the router, on a key only the service may use
        settings = Settings(data_dir=tmp, recordings_enabled=True, zenoh_config=service_conf)
        with TestClient(create_app(settings)) as client:
            make_skill(client, "s", 3)
            yield tmp, endpoint, client


def _robot(secure, user, password=None) -> Path:
    tmp, endpoint, _ = secure
    return _client_file(tmp, "robot-secure.json5", endpoint, user,
                        PASSWORDS.get(user, "") if password is None else password)


def test_health_says_the_live_path_is_authenticated(secure):
    health = secure[2].get("/healthz").json()["bridge"]
    assert health["status"] == "ok"
    assert health["access"] == "authenticated" and health["tls"] is True


def test_robot_streams_over_tls_with_its_password(secure):
    directrix = np.array(secure[2].get("/skills/s/models/latest").json()["directrix"])
    with PoseStreamer("s", "arm1", zenoh_config=_robot(secure, "arm1")) as ps:
        for k in range(10):
            answer = ps.wait_for(ps.send(directrix[10 + k], restart=k == 0), 2.0)
            assert answer is not None and answer.status == "ok"


@pytest.mark.parametrize("user,password", [(None, None), ("arm1", "wrong"),
                                           ("stranger", "whatever")])
def test_unauthenticated_peers_are_refused(secure, user, password):
    path = _robot(secure, user, password)
    with pytest.raises(zenoh.ZError):
        zenoh.open(zenoh.Config.from_file(str(path)))


def test_a_robot_cannot_read_or_write_another_robots_stream(secure):
    directrix = np.array(secure[2].get("/skills/s/models/latest").json()["directrix"])
    seen: list[str] = []
    lock = threading.Lock()

    def spy(sample):
        with lock:
            seen.append(str(sample.key_expr))

    arm1 = zenoh.open(zenoh.Config.from_file(str(_robot(secure, "arm1"))))
    try:
        arm1.declare_subscriber("canal/s/arm2/target", spy)
        arm1.declare_subscriber("canal/**", spy)
        with PoseStreamer("s", "arm2", zenoh_config=_robot(secure, "arm2")) as arm2:
            time.sleep(0.3)
            for k in range(10):
                answer = arm2.wait_for(arm2.send(directrix[10 + k], restart=k == 0), 2.0)
                assert answer is not None and answer.status == "ok"
            n = len(arm2._answers)
            # arm1 puts on arm2's pose key: the router drops it, arm2 gets no extra answer
            from canal_protocol import wire

            arm1.put("canal/s/arm2/pose", wire.encode_pose(10**9, directrix[40]))
            time.sleep(0.5)
            assert all(a.seq != 10**9 for a in arm2._answers.values())
            assert len(arm2._answers) == n
            # and arm1's model query is refused too (no rule lets it query canal/s/model)
            replies = list(arm1.get("canal/s/model", timeout=1.0))
            assert [r for r in replies if r.ok is not None] == []
        time.sleep(0.2)
    finally:
        arm1.close()
    # arm1 saw nothing of arm2's stream: no target, and no pose but its own put (which its
    # own session delivers to its own subscriber locally)
    assert [k for k in seen if "arm2/target" in k] == []
    assert [k for k in seen if "arm2" in k] == ["canal/s/arm2/pose"]


def test_recording_batches_flow_between_service_sessions_only(secure):
    """The bridge's batches reach the recorder through the router; a robot can neither put
    a forged batch on the recorder key nor hear the real ones."""
    client = secure[2]
    directrix = np.array(client.get("/skills/s/models/latest").json()["directrix"])
    heard: list[str] = []
    time.sleep(0.3)  # the earlier tests' last batches
    before = client.get("/healthz").json()["recorder"]["live"]["streams"].get(
        "s/arm1", {}).get("poses", 0)
    arm1 = zenoh.open(zenoh.Config.from_file(str(_robot(secure, "arm1"))))
    # another robot listens (a session hears its own puts locally, whatever the router says)
    arm2 = zenoh.open(zenoh.Config.from_file(str(_robot(secure, "arm2"))))
    try:
        arm2.declare_subscriber("canal/@recorder/live/*", lambda s: heard.append(str(s.key_expr)))
        time.sleep(0.3)
        from canal_service import record_batches

        from canal_protocol import keys as keyspace

        row = [1, [0.0, 0.0, 0.0], None, [0.0, 0.0, 0.0], None, 0.0, 0.1, 0, True, False, "ok"]
        arm1.put(keyspace.recorder_key("x1"), record_batches.encode_record_batch(
            "x1", 0, [("s", "forged", 1, 1, 0, 0, 0, [row])]))
        with PoseStreamer("s", "arm1", zenoh_config=_robot(secure, "arm1")) as ps:
            for k in range(20):
                answer = ps.wait_for(ps.send(directrix[10 + k], restart=k == 0), 2.0)
                assert answer is not None and answer.status == "ok"
        deadline = time.monotonic() + 10
        streams: dict = {}
        while time.monotonic() < deadline:
            streams = client.get("/healthz").json()["recorder"]["live"]["streams"]
            if streams.get("s/arm1", {}).get("poses", 0) >= before + 20:
                break
            time.sleep(0.1)
        arm1.put(keyspace.recorder_key("x1"), record_batches.encode_record_batch(
            "x1", 1, [("s", "forged", 1, 1, 0, 0, 0, [row])]))
        time.sleep(0.5)
    finally:
        arm1.close()
        arm2.close()
    live = client.get("/healthz").json()["recorder"]["live"]
    assert live["streams"]["s/arm1"]["poses"] == before + 20  # the real batches went through
    assert "s/forged" not in live["streams"] and live["bad_payload"] == 0
    assert heard == []  # and the robot heard none of them


def test_only_the_service_and_an_operator_write_scenes(secure):
    """A robot's scene put is dropped by the router; an operator's reaches the bridge, which
    stores it as the skill's next scene version."""
    import orjson

    client = secure[2]
    centre = client.get("/skills/s/models/latest").json()["directrix"][20]
    body = orjson.dumps({"obstacles": [{"kind": "sphere", "center": centre, "radius": 0.01}]})
    before = client.get("/skills/s/scene").json()["version"]
    arm1 = zenoh.open(zenoh.Config.from_file(str(_robot(secure, "arm1"))))
    try:
        arm1.put("canal/s/scene", body)
        time.sleep(1.0)
    finally:
        arm1.close()
    assert client.get("/skills/s/scene").json()["version"] == before
    operator = zenoh.open(zenoh.Config.from_file(str(_robot(secure, "operator"))))
    try:
        deadline = time.monotonic() + 10.0
        while client.get("/skills/s/scene").json()["version"] == before:
            assert time.monotonic() < deadline, "the operator's scene never arrived"
            operator.put("canal/s/scene", body)
            time.sleep(0.3)
    finally:
        operator.close()
    scene = client.get("/skills/s/scene").json()
    assert scene["obstacles"][0]["radius"] == 0.01
    assert client.delete("/skills/s/scene").status_code == 204


def test_a_robot_steers_and_corrects_on_its_own_keys_only(secure):
    """arm1 may capture a correction and steer on its own stream; on arm2's keys the router
    refuses both."""
    from canal_client.live import LiveError

    with PoseStreamer("s", "arm1", zenoh_config=_robot(secure, "arm1")) as arm1:
        assert arm1.start_correction("include")["capturing"] is True
        with pytest.raises(LiveError, match="samples"):
            arm1.stop_correction()  # reached the bridge: refused for its content, not its key
        arm1.steer(0.5, 0.0)
        mine = zenoh.open(zenoh.Config.from_file(str(_robot(secure, "arm1"))))
        try:
            replies = list(mine.get("canal/s/arm2/correction/start", payload=b'{"kind": "include"}',
                                    timeout=1.0))
            assert [r for r in replies if r.ok is not None] == []
        finally:
            mine.close()
