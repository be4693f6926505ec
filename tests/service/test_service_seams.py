"""The joins inside the service: domain errors without HTTP, one status table, collaborators
given to constructors, no silent fallbacks."""

from __future__ import annotations

import ast
import inspect
from pathlib import Path
from typing import Any

import canal_service
import numpy as np
import pytest
from canal_service import errors
from canal_service.app import create_app
from canal_service.core.config import Settings
from canal_service.errors import (
    CanalRejected,
    DemoNotFound,
    ModelVersionNotFound,
    NoModelYet,
    NotEnoughDemonstrations,
    ServiceError,
    SkillExists,
    SkillNotFound,
    http_status,
)
from canal_service.listeners import FitListeners
from canal_service.metrics import Metrics
from canal_service.service import CanalService
from canal_service.storage import Database
from canal_service.validation import check_demonstration
from fastapi.testclient import TestClient
from service_helpers import demo_positions

import canal_core
from canal_protocol import schemas

SERVICE_DIR = Path(canal_service.__file__).parent


@pytest.fixture
def service(tmp_path: Path) -> Any:
    db = Database(f"sqlite:///{tmp_path / 'canal.sqlite3'}")
    db.migrate()
    heard: list[tuple[str, int]] = []

    def broken(_skill: str, _version: int, _canal: canal_core.Canal) -> None:
        raise RuntimeError("a listener that fails")

    def listener(skill: str, version: int, canal: canal_core.Canal) -> None:
        assert isinstance(canal, canal_core.Canal)
        heard.append((skill, version))

    svc = CanalService(db, Metrics(), fit_listeners=FitListeners([broken, listener]))
    svc.heard = heard  # type: ignore[attr-defined]
    yield svc
    db.dispose()


def _add(svc: CanalService, name: str, positions: np.ndarray) -> int:
    return svc.add_demonstration(name, check_demonstration(positions, 3), None, "json").id


def test_repository_and_service_raise_what_went_wrong(service: CanalService) -> None:
    with pytest.raises(SkillNotFound):
        service.get_skill("nope")
    service.create_skill(schemas.SkillCreate(name="s", dim=3))
    with pytest.raises(SkillExists):
        service.create_skill(schemas.SkillCreate(name="s", dim=3))
    with pytest.raises(NoModelYet) as no_model:
        service.load_canal("s", None)
    assert no_model.value.dim == 3 and no_model.value.field == "model"
    with pytest.raises(ModelVersionNotFound):
        service.load_canal("s", 1)
    with pytest.raises(DemoNotFound):
        service.get_demonstration("s", 42)
    _add(service, "s", demo_positions(0))
    with pytest.raises(NotEnoughDemonstrations):
        service.fit("s", schemas.FitRequest())
    _add(service, "s", demo_positions(1))
    _add(service, "s", demo_positions(2))
    assert service.fit("s", schemas.FitRequest(n_samples=20)).version == 1
    # the listener given to the constructor heard the fit; the broken one before it did not
    # stop it, nor fail the request
    assert service.heard == [("s", 1)]  # type: ignore[attr-defined]
    assert service.load_canal("s", None)[2] == 1
    with pytest.raises(ModelVersionNotFound):
        service.load_canal("s", 2)


def test_core_errors_are_wrapped_not_mutated(service: CanalService) -> None:
    service.create_skill(schemas.SkillCreate(name="same", dim=3))
    for _ in range(3):
        _add(service, "same", demo_positions(0))
    with pytest.raises(CanalRejected) as rejected:
        service.fit("same", schemas.FitRequest(n_samples=20))
    cause = rejected.value.__cause__
    assert cause is rejected.value.cause and isinstance(cause, canal_core.CanalError)
    assert rejected.value.field == "demonstrations"
    assert cause.field != "demonstrations"  # canal_core's own error is left as it raised it
    assert http_status(rejected.value) == http_status(cause)

    service.create_skill(schemas.SkillCreate(name="ok", dim=3))
    for j in range(3):
        _add(service, "ok", demo_positions(j))
    service.fit("ok", schemas.FitRequest(n_samples=20))
    far = [0.0, 5.0, 0.0]
    body = schemas.ReproductionRequest(starts=[[0.0, 0.0, 0.0], far], outside="raise")
    with pytest.raises(CanalRejected) as outside:
        service.reproduce("ok", body)
    assert isinstance(outside.value.cause, canal_core.OutsideCanalError)
    assert outside.value.field == "starts[1]" and outside.value.cause.field == "start"
    assert http_status(outside.value) == (422, "outside_canal")


def test_one_table_gives_every_domain_error_a_status() -> None:
    domain = [c for c in vars(errors).values()
              if inspect.isclass(c) and issubclass(c, ServiceError)]
    assert len(domain) > 15
    for cls in domain:
        # no HTTP below the HTTP layer: the classes carry no status of their own
        assert not hasattr(cls, "status_code"), cls
    expected = {errors.SkillNotFound: 404, errors.DemoNotFound: 404,
                errors.ModelVersionNotFound: 404, errors.SkillExists: 409,
                errors.NotEnoughDemonstrations: 409, errors.VersionConflict: 409,
                errors.InvalidInput: 422, errors.BadUpload: 400, errors.TooLarge: 413,
                errors.UnsupportedMediaType: 415, errors.Disabled: 404, errors.Busy: 503}
    for cls, status in expected.items():
        assert http_status(cls("m"))[0] == status, cls
    assert http_status(NoModelYet("s", 3)) == (409, "conflict")
    assert http_status(canal_core.DegenerateCanalError("m")) == (422, "degenerate_canal")
    assert http_status(canal_core.ModelFormatError("m")) == (400, "model_format")


def test_http_answers_come_from_the_table(tmp_path: Path) -> None:
    settings = Settings(data_dir=tmp_path, recordings_enabled=False, zenoh_enabled=False)
    with TestClient(create_app(settings)) as c:
        assert c.post("/skills", json={"name": "s", "dim": 3}).status_code == 201
        r = c.post("/skills", json={"name": "s", "dim": 3})
        assert r.status_code == 409 and r.json()["error"]["field"] == "name"
        r = c.get("/skills/s/models/latest")
        assert r.status_code == 409 and r.json()["error"]["type"] == "conflict"
        assert r.json()["error"]["field"] == "model"
        r = c.get("/skills/s/models/3")
        assert r.status_code == 404 and r.json()["error"]["type"] == "not_found"
        r = c.get("/skills/s/recording.rrd")
        assert r.status_code == 404 and r.json()["error"]["type"] == "disabled"
        health = c.get("/healthz").json()
        assert health["recorder"]["status"] == "disabled"
        assert health["bridge"]["status"] == "disabled"


def _import_guards(path: Path) -> list[int]:
    lines = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ExceptHandler) and node.type is not None:
            caught = node.type.elts if isinstance(node.type, ast.Tuple) else [node.type]
            if any(isinstance(c, ast.Name) and c.id in ("ImportError", "ModuleNotFoundError")
                   for c in caught):
                lines.append(node.lineno)
    return lines


def test_no_import_guards_in_the_service() -> None:
    found = {str(p.relative_to(SERVICE_DIR)): _import_guards(p)
             for p in SERVICE_DIR.rglob("*.py")}
    assert {p: lines for p, lines in found.items() if lines} == {}


def test_recordings_that_cannot_open_fail_the_start(tmp_path: Path) -> None:
    """Asked for recordings that cannot be made, the service refuses to start rather than
    serve without them while /healthz says ok."""
    not_a_folder = tmp_path / "recordings"
    not_a_folder.write_text("a file where the recordings folder should be")
    settings = Settings(data_dir=tmp_path, recordings_dir=not_a_folder, zenoh_enabled=False)
    with pytest.raises(OSError):
        create_app(settings)


def test_a_capture_stores_only_into_the_skill_it_began_on(service: CanalService) -> None:
    # The live path read the skill's instance, then stored the captured poses in a second
    # transaction: a skill deleted and created again under its name in between got the old
    # skill's poses. The instance is now checked by the store itself.
    from canal_service.errors import SkillReplaced
    from canal_service.storage import repository as repo

    def instance() -> str:
        with service.db.read() as s:
            return repo.skill_instances(s, "s")["s"]

    service.create_skill(schemas.SkillCreate(name="s", dim=3))
    for seed in range(3):
        _add(service, "s", demo_positions(seed))
    service.fit("s", schemas.FitRequest(n_samples=20))
    old = instance()
    demo = check_demonstration(demo_positions(5), 3)
    assert service.add_demonstration("s", demo, None, "zenoh", instance=old).id > 0
    service.delete_skill("s")
    service.create_skill(schemas.SkillCreate(name="s", dim=3))
    for seed in range(3):
        _add(service, "s", demo_positions(seed))
    service.fit("s", schemas.FitRequest(n_samples=20))
    with pytest.raises(SkillReplaced) as replaced:
        service.add_demonstration("s", demo, None, "zenoh", instance=old)
    assert replaced.value.field == "skill" and "created again" in replaced.value.message
    assert http_status(replaced.value) == (409, "conflict")
    include = schemas.CorrectionIn.model_validate(
        {"kind": "include", "samples": demo_positions(1).tolist()})
    with pytest.raises(SkillReplaced):
        service.correct("s", include, instance=old)
    skill = service.get_skill("s")
    assert skill.n_demonstrations == 3 and skill.latest_model_version == 1, skill
    # the skill it began on is gone: said so, not "created again"
    service.delete_skill("s")
    with pytest.raises(SkillReplaced) as gone:
        service.add_demonstration("s", demo, None, "zenoh", instance=old)
    assert "deleted" in gone.value.message and "created again" not in gone.value.message
    # the instance it began on stores as before
    service.create_skill(schemas.SkillCreate(name="s", dim=3))
    for seed in range(3):
        _add(service, "s", demo_positions(seed))
    service.fit("s", schemas.FitRequest(n_samples=20))
    assert service.correct("s", include, instance=instance()).version == 2
