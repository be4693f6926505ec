"""Sharded bridges: Zenoh delivers each pose to the one bridge that answers it.

The key layout (``canal_protocol.keys``) says which shard owns a robot; these tests check
that the key expressions a shard subscribes to say the same thing, and that two real
bridges sharing robots receive, decode and answer only their own streams.
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
import zenoh
from canal_client.live import client_config
from canal_service.bridge import Bridge, BridgeOptions
from canal_testing import free_port

from canal_protocol import keys as keyspace
from canal_protocol import wire

pytestmark = pytest.mark.timeout(60)

NAMES = [f"r{i}" for i in range(40)] + ["arm_a", "UR5e-left", "x.y", "Z", "robot~", "a(b)"]


@pytest.mark.parametrize("shards", [2, 3, 5])
def test_each_robot_is_in_exactly_the_shard_its_keys_name(shards):
    exprs = [[zenoh.KeyExpr(e) for e in keyspace.shard_pose_keys(i, shards, "canal")]
             for i in range(shards)]
    for robot in NAMES:
        key = zenoh.KeyExpr(keyspace.keys("pour", robot).pose)
        owners = [i for i in range(shards) if any(e.intersects(key) for e in exprs[i])]
        assert owners == [keyspace.shard_of("pour", robot, shards)], robot


def test_numbered_robots_spread_evenly_and_one_shard_is_everything():
    robots = [f"r{i}" for i in range(16)]
    counts = [sum(keyspace.shard_of("s", r, 2) == k for r in robots) for k in range(2)]
    assert counts == [8, 8]
    assert keyspace.shard_pose_keys(0, 1, "canal/") == ["canal/*/*/pose"]
    assert not BridgeOptions(shards=2).subscribes_by_key()  # "auto": by key from 4 shards
    assert BridgeOptions(shards=4).subscribes_by_key()
    assert BridgeOptions(shards=2, shard_subscribe="keys").subscribes_by_key()
    assert not BridgeOptions(shards=8, shard_subscribe="all").subscribes_by_key()
    with pytest.raises(ValueError, match="shard_subscribe"):
        BridgeOptions(shards=2, shard_subscribe="some").subscribes_by_key()
    with pytest.raises(ValueError, match=r"shard in 0\.\.1"):
        keyspace.shard_pose_keys(2, 2)


@pytest.mark.parametrize("subscribe", ["keys", "all"])
def test_two_sharded_bridges_answer_each_robot_once(live, subscribe):
    service = live.client.app.state.service
    prefix = "shardtest"  # the module's own bridge serves "canal": it must not answer these
    first = f"tcp/127.0.0.1:{free_port()}"
    second = f"tcp/127.0.0.1:{free_port()}"
    bridges = [
        Bridge(service, BridgeOptions(prefix=prefix, listen=(first,), shard=0, shards=2,
                                      shard_subscribe=subscribe)),
        Bridge(service, BridgeOptions(prefix=prefix, listen=(second,), connect=(first,),
                                      shard=1, shards=2, shard_subscribe=subscribe)),
    ]
    robots = [f"r{i}" for i in range(6)]
    owner = {r: keyspace.shard_of("arc3", r, 2) for r in robots}
    assert set(owner.values()) == {0, 1}
    directrix = np.array(live.client.get("/skills/arc3/models/latest").json()["directrix"])
    got: dict[str, list[int]] = {r: [] for r in robots}
    lock = threading.Lock()

    def on_target(sample):
        found = keyspace.stream_of(str(sample.key_expr), prefix, keyspace.TARGET)
        assert found is not None
        answer = wire.decode_target_json(sample.payload.to_bytes())
        assert answer.status == "ok", answer
        with lock:
            got[found[1]].append(answer.seq)

    try:
        assert all(b.start() for b in bridges)
        with zenoh.open(client_config([first, second])) as session:
            sub = session.declare_subscriber(f"{prefix}/arc3/*/target", on_target)
            pubs = {r: session.declare_publisher(keyspace.keys("arc3", r, prefix).pose,
                                                 encoding=zenoh.Encoding.APPLICATION_JSON)
                    for r in robots}
            deadline = time.monotonic() + 10
            while (not all(p.matching_status.matching for p in pubs.values())
                   and time.monotonic() < deadline):
                time.sleep(0.01)
            for k in range(20):
                for pub in pubs.values():
                    pub.put(wire.encode_pose_json(k, directrix[10 + k], restart=k == 0))
                time.sleep(0.002)
            deadline = time.monotonic() + 10
            while (sum(map(len, got.values())) < 20 * len(robots)
                   and time.monotonic() < deadline):
                time.sleep(0.02)
            time.sleep(0.2)  # a duplicate answer would arrive by now
            sub.undeclare()
        for r in robots:
            assert got[r] == list(range(20)), r  # every pose answered once, in order
        for shard, bridge in enumerate(bridges):
            mine = [r for r in robots if owner[r] == shard]
            # Zenoh delivered only this shard's poses: no stray sample was even decoded
            assert bridge.counts.poses == 20 * len(mine)
            assert sorted(st.robot for st in bridge.streams.values()) == sorted(mine)
            others = {keyspace.keys("arc3", r, prefix).pose for r in robots if r not in mine}
            if subscribe == "keys":  # Zenoh delivered only this shard's poses
                assert bridge.path.others == set()
            else:  # every pose arrived; the others' were dropped before decoding
                assert bridge.path.others == others
    finally:
        for b in bridges:
            b.close()


@pytest.mark.parametrize("key", ["canal/*/model/updated", "canal/**/model/updated",
                                 "canal/a$*/model/updated", "canal/s/model", "other/s/model/updated",
                                 "canal/s/x/model/updated", "canal/@s/model/updated"])
def test_only_a_plain_skill_s_update_notice_names_a_skill(key):
    assert keyspace.skill_of_update(key, "canal") is None
    assert keyspace.skill_of_update("canal/pour/model/updated", "canal/") == "pour"
    assert keyspace.model_updated_key("pour", "canal") == "canal/pour/model/updated"


def test_query_keys_with_wildcards_name_nothing():
    assert keyspace.query_of("canal/pour/arm1/demo/start") == ["pour", "arm1", "demo", "start"]
    for key in ("canal/*/arm1/demo/start", "canal/**", "canal/pour/arm$*/demo/stop", "x/pour"):
        assert keyspace.query_of(key) is None
