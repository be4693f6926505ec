"""A skill's model is ready before its first live pose.

Loading a model (database read, canal decoded, tracker geometry and bank tables built) on
the bridge's one worker thread stalls every robot for milliseconds. These tests check, on a
real SQLite file and real Zenoh sessions on 127.0.0.1, that the bridge loads models ahead
of the first pose: at start (the most recently fitted skills, bounded by ``preload_max``)
and on each fit notice (in-process fit, ``canal serve``'s stdin notice, another bridge's
Zenoh notice); that the housekeeper keeps such models for ``preload_keep_s`` and then
drops them; and that unknown skills still go to the negative cache only.

"Loaded ahead" is checked by identity: the entry the first pose is answered from is the
very object installed before the pose was put (a load on the worker would install another).
"""

from __future__ import annotations

import shutil
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import orjson
import pytest
import zenoh
from canal_client.live import client_config
from canal_service.bridge import Bridge, BridgeOptions
from canal_service.bridge.models import ModelTable
from canal_service.core.config import Settings
from canal_service.metrics import Metrics
from canal_service.service import CanalService
from canal_service.storage import Database
from canal_testing import free_port
from live_helpers import arc, wait_until
from sqlalchemy import event

from canal_protocol import keys as keyspace
from canal_protocol import wire
from canal_protocol.schemas import DemonstrationIn, FitRequest, SkillCreate

pytestmark = pytest.mark.timeout(60)

#: fitted in this order: p1 is the least recently fitted
FITTED = ["p1", "p2", "p3", "p4"]


def add_skill(service: CanalService, name: str, fit: bool = True) -> None:
    service.create_skill(SkillCreate(name=name, description="", dim=3))
    for j in range(3):
        service.add_json_demonstration(name, DemonstrationIn(positions=arc(j).tolist()))
    if fit:
        service.fit(name, FitRequest(n_samples=60))


@pytest.fixture(scope="module")
def seeded(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A SQLite file with skills p1..p4 fitted in that order and 'bare' (never fitted)."""
    path = tmp_path_factory.mktemp("preload") / "canal.sqlite3"
    db = Database(f"sqlite:///{path}")
    db.migrate()
    service = CanalService(db, Metrics())
    for name in FITTED:
        add_skill(service, name)
    add_skill(service, "bare", fit=False)
    db.dispose()
    return path


@pytest.fixture
def database_url(seeded: Path, tmp_path: Path) -> str:
    """A copy of the seeded file for one test (tests fit more skills into theirs)."""
    path = tmp_path / "canal.sqlite3"
    shutil.copyfile(seeded, path)
    return f"sqlite:///{path}"


@pytest.fixture
def service(database_url: str) -> Iterator[CanalService]:
    """A service (empty decoded-canal cache) on the test's database."""
    db = Database(database_url)
    yield CanalService(db, Metrics())
    db.dispose()


@pytest.fixture
def start_bridge(service: CanalService) -> Iterator[Any]:
    """Start bridges on free loopback ports, each under its own key prefix; closed after."""
    bridges: list[Bridge] = []

    def start(**options: Any) -> Bridge:
        prefix = f"pre{len(bridges)}x{free_port()}"
        bridge = Bridge(service, BridgeOptions(prefix=prefix,
                                               listen=(f"tcp/127.0.0.1:{free_port()}",),
                                               **options))
        bridges.append(bridge)
        assert bridge.start(), bridge.detail
        return bridge

    yield start
    for bridge in bridges:
        bridge.close()
    assert not any(t.is_alive() for b in bridges for t in b._threads)


class Robot:
    """A robot's Zenoh session: puts JSON poses, collects the answers by seq."""

    def __init__(self, bridge: Bridge, skill: str, name: str) -> None:
        self.prefix = bridge.prefix
        self.keys = keyspace.keys(skill, name, self.prefix)
        self.session = zenoh.open(client_config(bridge.listen))
        self.answers: dict[int | None, wire.Target] = {}
        self.order: list[int | None] = []  # seqs in the order their answers arrived
        self.got = threading.Condition()
        self.sub = self.session.declare_subscriber(self.keys.target, self._on_target)
        self.pub = self.session.declare_publisher(self.keys.pose,
                                                  encoding=zenoh.Encoding.APPLICATION_JSON)
        deadline = time.monotonic() + 10
        while not self.pub.matching_status.matching and time.monotonic() < deadline:
            time.sleep(0.01)

    def _on_target(self, sample: Any) -> None:
        answer = wire.decode_target_json(sample.payload.to_bytes())
        with self.got:
            self.answers[answer.seq] = answer
            self.order.append(answer.seq)
            self.got.notify_all()

    def ask(self, seq: int, position: Any) -> wire.Target:
        self.pub.put(wire.encode_pose_json(seq, position, restart=seq == 0))
        with self.got:
            assert self.got.wait_for(lambda: seq in self.answers, timeout=10), seq
            return self.answers[seq]

    def close(self) -> None:
        self.sub.undeclare()
        self.pub.undeclare()
        self.session.close()


def start_of(service: CanalService, skill: str) -> Any:
    return service.load_canal(skill, None)[0].directrix[5]


def first_answer(bridge: Bridge, service: CanalService, skill: str, robot: str) -> Any:
    """The answer to a new robot's first pose of ``skill`` (at its canal's 6th section)."""
    session = Robot(bridge, skill, robot)
    try:
        return session.ask(0, start_of(service, skill))
    finally:
        session.close()


# ---- the query --------------------------------------------------------------------------------


def test_skills_are_listed_most_recently_fitted_first(database_url, service):
    assert service.skills_by_latest_fit(10) == [(s, 1) for s in reversed(FITTED)]
    assert service.skills_by_latest_fit(2) == [("p4", 1), ("p3", 1)]
    assert service.skills_by_latest_fit(0) == []
    assert service.latest_revision("p2")[1] == 1


# ---- at start ---------------------------------------------------------------------------------


def test_a_bridge_starts_with_the_most_recently_fitted_skills_loaded(service, start_bridge):
    bridge = start_bridge(preload_max=2)
    assert bridge.preloaded.wait(20)
    models = bridge.models.models
    assert sorted(models) == ["p3", "p4"]  # bounded: p1 and p2 were fitted before
    assert all(models[s].status == "ok" and models[s].version == 1 for s in ("p3", "p4"))
    assert all(models[s].bank is not None for s in ("p3", "p4"))
    entry = models["p4"]
    answer = first_answer(bridge, service, "p4", "arm1")
    assert answer.status == "ok" and answer.model_version == 1
    assert bridge.models.models["p4"] is entry  # answered from the preloaded model
    stream = next(iter(bridge.streams.values()))
    assert stream.bank is entry.bank


def test_the_service_settings_set_the_preload(tmp_path: Path):
    options = BridgeOptions.from_settings(Settings(data_dir=tmp_path, zenoh_preload_max=5,
                                                   zenoh_preload_keep_s=7.5))
    assert (options.preload_max, options.preload_keep_s) == (5, 7.5)
    default = BridgeOptions.from_settings(Settings(data_dir=tmp_path))
    assert (default.preload_max, default.preload_keep_s) == (64, 600.0)


def test_preload_skips_skills_without_a_model_and_can_be_off(service, start_bridge):
    bridge = start_bridge(preload_max=64)
    assert bridge.preloaded.wait(20)
    assert sorted(bridge.models.models) == sorted(FITTED)  # not "bare": it has no model
    off = start_bridge(preload_max=0)
    assert off.preloaded.wait(20)
    assert off.models.models == {}


def test_every_shard_preloads_every_skill(service, start_bridge):
    # shard_of splits streams by robot, not by skill: each shard serves robots of each skill
    assert {keyspace.shard_of("p4", robot, 2) for robot in ("arm0", "arm1")} == {0, 1}
    shards = [start_bridge(shard=i, shards=2) for i in range(2)]
    for bridge in shards:
        assert bridge.preloaded.wait(20)
        assert sorted(bridge.models.models) == sorted(FITTED)
    add_skill(service, "sharded")  # the fit notice reaches both (in-process listeners)
    assert all(b.models.models["sharded"].version == 1 for b in shards)


# ---- fit notices ------------------------------------------------------------------------------


def test_a_skill_fitted_while_the_bridge_runs_is_ready_before_its_first_pose(
        service, start_bridge):
    bridge = start_bridge(preload_max=64)
    assert bridge.preloaded.wait(20)
    add_skill(service, "fresh")  # through the service: the in-process fit notice
    entry = bridge.models.models.get("fresh")
    assert entry is not None and entry.status == "ok" and entry.version == 1
    answer = first_answer(bridge, service, "fresh", "arm1")
    assert answer.status == "ok" and answer.model_version == 1
    assert bridge.models.models["fresh"] is entry


def test_fit_notices_from_canal_serve_and_other_bridges_load_the_model(
        database_url, service, start_bridge):
    bridge = start_bridge(preload_max=64)
    assert bridge.preloaded.wait(20)
    # Fitted by another process on the same database: this bridge hears only the notices.
    other = CanalService(Database(database_url), Metrics())
    try:
        add_skill(other, "bystdin")
        add_skill(other, "byzenoh")
    finally:
        other.db.dispose()
    assert "bystdin" not in bridge.models.models and "byzenoh" not in bridge.models.models
    # ``canal serve``'s stdin line ends in this call, on the thread that read it
    bridge.model_updated("bystdin", 1, announce=False)
    entry = bridge.models.models.get("bystdin")
    assert entry is not None and entry.status == "ok" and entry.version == 1
    # another bridge's notice on Zenoh: the bridge's updates thread loads it
    with zenoh.open(client_config(bridge.listen)) as session:
        session.put(keyspace.model_updated_key("byzenoh", bridge.prefix),
                    orjson.dumps({"version": 1}))
        assert wait_until(lambda: "byzenoh" in bridge.models.models)
    entry = bridge.models.models["byzenoh"]
    assert entry.status == "ok" and entry.version == 1
    answer = first_answer(bridge, service, "byzenoh", "r2")
    assert answer.status == "ok" and answer.model_version == 1
    assert bridge.models.models["byzenoh"] is entry


def test_a_refit_of_a_preloaded_skill_replaces_its_model_before_any_pose(
        service, start_bridge):
    add_skill(service, "refit")
    bridge = start_bridge(preload_max=64)
    assert bridge.preloaded.wait(20)
    assert bridge.models.models["refit"].version == 1
    service.fit("refit", FitRequest(n_samples=80))
    entry = bridge.models.models["refit"]
    assert entry.status == "ok" and entry.version == 2
    # a late or repeated notice of the old version changes nothing
    bridge.model_updated("refit", 1, announce=False)
    assert bridge.models.models["refit"] is entry


# ---- keeping and dropping ---------------------------------------------------------------------


def test_preloaded_models_stay_for_the_grace_period_then_go_unless_in_use(
        service, start_bridge):
    keep_s = 1.5
    bridge = start_bridge(preload_max=64, preload_keep_s=keep_s, refresh_s=0.1, idle_s=60.0)
    assert bridge.preloaded.wait(20)
    loaded = min(entry.used for entry in bridge.models.models.values())
    robot = Robot(bridge, "p2", "arm1")  # p2 is in use: its model must stay
    try:
        assert robot.ask(0, start_of(service, "p2")).status == "ok"
        time.sleep(0.6)  # several refreshes
        if time.monotonic() - loaded < keep_s:  # (a stalled machine proves nothing here)
            assert sorted(bridge.models.models) == sorted(FITTED)
        # after the grace period, the models no stream uses are dropped
        assert wait_until(lambda: sorted(bridge.models.models) == ["p2"])
        assert robot.ask(1, start_of(service, "p2")).status == "ok"
    finally:
        robot.close()


def test_the_refresh_keeps_at_most_preload_max_idle_models_most_recently_used_first(service):
    table = ModelTable(service, BridgeOptions(preload_max=3, preload_keep_s=600.0))
    assert table.preload() == ["p4", "p3", "p2"]
    table.refresh(set())
    assert sorted(table.models) == ["p2", "p3", "p4"]  # within the grace period: kept
    kept = dict(table.models)
    table.refresh(set())
    assert all(table.models[s] is kept[s] for s in kept)  # same versions: nothing rebuilt
    table.updated("p1", None, 1)  # a fit notice: p1 becomes the most recently used
    assert table.models["p1"].status == "ok"
    table.refresh(set())
    # four idle models, three kept: the preloaded skill fitted longest ago (p2) goes
    assert sorted(table.models) == ["p1", "p3", "p4"]
    table.refresh({"p2", "p3"})  # a live skill is not idle (p2 is not loaded: nothing to do)
    assert sorted(table.models) == ["p1", "p3", "p4"]
    off = ModelTable(service, BridgeOptions(preload_max=0))
    off.updated("p1", None, 1)  # not in use, not preloading: nothing loaded
    assert off.models == {} and off.preload() == []


# ---- the negative cache -----------------------------------------------------------------------


def test_unknown_skills_go_to_the_negative_cache_from_notices_and_poses(
        service, start_bridge):
    bridge = start_bridge(preload_max=64, negative_max=2)
    assert bridge.preloaded.wait(20)
    for name in ("junk1", "junk2", "junk3"):
        bridge.model_updated(name, 1, announce=False)
    assert not any(name.startswith("junk") for name in bridge.models.models)
    assert list(bridge.models.unknown) == ["junk2", "junk3"]  # bounded
    robot = Robot(bridge, "nosuch", "arm1")
    try:
        assert robot.ask(0, [0.0, 0.0, 0.0]).status == "unknown_skill"
        entry = bridge.models.unknown["nosuch"]
        assert robot.ask(1, [0.0, 0.0, 0.0]).status == "unknown_skill"
    finally:
        robot.close()
    assert bridge.models.unknown["nosuch"] is entry  # answered from the cache, not reloaded
    assert "nosuch" not in bridge.models.models and not bridge.streams


def test_the_preload_query_runs_on_a_database_path(tmp_path: Path):
    """The listing on a fresh file with no skill at all, and with a skill deleted."""
    db = Database(f"sqlite:///{tmp_path / 'empty.sqlite3'}")
    db.migrate()
    try:
        service = CanalService(db, Metrics())
        assert service.skills_by_latest_fit(64) == []
        add_skill(service, "gone")
        add_skill(service, "kept")
        service.delete_skill("gone")
        assert service.skills_by_latest_fit(64) == [("kept", 1)]
        assert ModelTable(service, BridgeOptions()).preload() == ["kept"]
    finally:
        db.dispose()


# ---- beyond the preload: loaded on the loader thread --------------------------------------------


def test_a_first_pose_beyond_the_preload_waits_for_the_loader_not_the_worker(
        service, start_bridge, monkeypatch):
    """Nothing preloaded (preload_max 0): a skill's first poses are parked, the bridge's
    loader thread loads the model (a spy on the real load records the thread: never the
    worker, which keeps answering other robots meanwhile) and answers them, in order."""
    starts = {skill: start_of(service, skill) for skill in ("p2", "p3")}
    bridge = start_bridge(preload_max=0)
    assert bridge.preloaded.wait(20)
    loaded_on: list[str] = []
    real = service.latest_model

    def spy(*args: Any, **kwargs: Any) -> Any:
        loaded_on.append(threading.current_thread().name)
        return real(*args, **kwargs)

    monkeypatch.setattr(service, "latest_model", spy)
    first, second = Robot(bridge, "p2", "arm1"), Robot(bridge, "p3", "arm2")
    try:
        assert first.ask(0, starts["p2"]).status == "ok"
        # five poses put back to back, before the model of p3 can be there
        for seq in range(5):
            second.pub.put(wire.encode_pose_json(seq, starts["p3"], restart=seq == 0))
        with second.got:
            assert second.got.wait_for(lambda: len(second.answers) == 5, timeout=10)
        assert second.order == [0, 1, 2, 3, 4]
        assert all(a.status == "ok" and a.model_version == 1 for a in second.answers.values())
        assert first.ask(1, starts["p2"]).status == "ok"
    finally:
        first.close()
        second.close()
    assert loaded_on and set(loaded_on) == {"canal-bridge-loader"}, loaded_on
    assert bridge.counts.parked >= 2  # each skill's first pose at least
    assert bridge.health()["parked"] == bridge.counts.parked
    assert bridge.path.parked == {}


def test_skills_without_a_model_or_unknown_are_answered_through_the_loader_too(
        service, start_bridge):
    bridge = start_bridge(preload_max=0)
    assert bridge.preloaded.wait(20)
    assert first_answer(bridge, service, "p1", "arm1").status == "ok"
    for skill, status in (("bare", "no_model"), ("nosuchskill", "unknown_skill")):
        robot = Robot(bridge, skill, "arm1")
        try:
            answers = [robot.ask(seq, [0.1, 0.2, 0.3]) for seq in range(3)]
        finally:
            robot.close()
        assert [a.status for a in answers] == [status] * 3, skill
        assert answers[0].message  # says why
    assert "nosuchskill" in bridge.models.unknown and bridge.path.parked == {}


# ---- a skill deleted while its model is read ---------------------------------------------------


@pytest.mark.parametrize("again", [False, True], ids=["deleted", "created-again"])
def test_a_model_deleted_between_finding_and_reading_it_is_read_afresh(
        database_url, service, again):
    """Another replica deletes the skill (and maybe creates and fits it again) after the
    bridge found the latest model's row and before it read the row: the bridge asks again and
    gets the skill as it now is, and a fit notice neither fails nor logs a traceback."""
    other = CanalService(Database(database_url), Metrics())
    fired: list[str] = []

    def delete_before_the_row_is_read(_conn, _cursor, statement, *_args):
        if fired or not statement.startswith("SELECT models.id") or "models.id = ?" not in statement:
            return
        fired.append(statement)
        other.delete_skill("p3")
        if again:
            add_skill(other, "p3")

    engine = service.db.read_engine
    event.listen(engine, "before_cursor_execute", delete_before_the_row_is_read)
    table = ModelTable(service, BridgeOptions(preload_max=64))
    try:
        entry = table.load("p3")
        assert fired, "the read of the model row was not reached"
        fired.clear()
        assert table.updated("p3", None, 1) == (None if not again else
                                                 other.latest_revision("p3"))
    finally:
        event.remove(engine, "before_cursor_execute", delete_before_the_row_is_read)
        other.db.dispose()
    if again:
        assert entry.status == "ok" and entry.version == 1
        assert table.models["p3"].status == "ok"
    else:
        assert entry.status == "unknown_skill"
        assert "p3" not in table.models and "p3" in table.unknown
