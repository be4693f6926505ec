"""What can be checked of docker/ without a Docker engine.

No engine runs on these machines, so the images are never built here. Instead: the compose file
parses and says what docs/deployment.md promises (services, volumes, healthchecks, ports bound to
127.0.0.1 only); the exact environment it passes to ``canal`` builds valid Settings, and — with
only the database swapped for SQLite and the Zenoh router's address for a loopback one, served by
a real Zenoh router session configured from docker/zenoh-router.json5 — the service starts under
uvicorn and answers /healthz 200, also to the Dockerfile's own HEALTHCHECK command; the
Dockerfile keeps its promises (non-root, healthcheck, no editable install); the Zenoh JSON5 files
load in Zenoh.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
import yaml
import zenoh
from canal_service.app import create_app
from canal_service.core.config import Settings
from canal_testing import LiveServer, free_port

ROOT = Path(__file__).resolve().parents[2]
DOCKER = ROOT / "docker"
COMPOSE = DOCKER / "compose.yaml"
DOCKERFILE = DOCKER / "Dockerfile"
ROUTER_CONF = DOCKER / "zenoh-router.json5"
CANAL_ZENOH_CONF = DOCKER / "canal-zenoh.json5"
TEST_PASSWORD = "test-only-5f2c9a"


# ---- helpers ----------------------------------------------------------------------------------


def compose() -> dict[str, Any]:
    return yaml.safe_load(COMPOSE.read_text())


_VAR = re.compile(r"\$\{(?P<name>[A-Za-z_][A-Za-z0-9_]*)(?:(?P<op>:?[-?])(?P<arg>[^}]*))?\}")


def interpolate(value: str, env: dict[str, str]) -> str:
    """Compose's ${VAR}, ${VAR:-default}, ${VAR-default}, ${VAR:?error}, ${VAR?error}."""

    def sub(m: re.Match[str]) -> str:
        name, op, arg = m["name"], m["op"], m["arg"]
        present = name in env
        value = env.get(name, "")
        if op in (":-", "-"):
            return value if (value if op == ":-" else present) else arg
        if op in (":?", "?"):
            if not (value if op == ":?" else present):
                raise KeyError(f"{name}: {arg}")
            return value
        return value

    return _VAR.sub(sub, value)


def canal_environment(env: dict[str, str]) -> dict[str, str]:
    """The ``canal`` service's environment block as compose would pass it."""
    block = compose()["services"]["canal"]["environment"]
    if isinstance(block, list):
        block = dict(item.split("=", 1) for item in block)
    return {k: interpolate(str(v), env) for k, v in block.items()}


def dockerfile_instructions() -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) with continuation lines joined and comments dropped."""
    text = re.sub(r"\\\n", " ", DOCKERFILE.read_text())
    out = []
    for line in text.splitlines():
        line = line.strip()
        if line and not line.startswith("#"):
            word, _, rest = line.partition(" ")
            out.append((word.upper(), rest.strip()))
    return out


# ---- compose.yaml -----------------------------------------------------------------------------


def test_compose_services_volumes_and_images() -> None:
    doc = compose()
    services = doc["services"]
    assert set(services) == {"canal", "zenoh", "postgres"}
    assert set(doc["volumes"]) == {"canal-data", "postgres-data"}

    canal = services["canal"]
    assert canal["build"]["dockerfile"] == "docker/Dockerfile"
    assert (DOCKER / canal["build"]["context"] / canal["build"]["dockerfile"]).resolve() == DOCKERFILE
    assert canal["depends_on"]["postgres"]["condition"] == "service_healthy"
    assert "zenoh" in canal["depends_on"]
    assert "canal-data:/data" in canal["volumes"]

    # Pinned images: the Zenoh router of the same release as the Python SDK the service runs
    # (mixed 1.x patch releases interoperate, but a matching pair is what was tested), a
    # major version of PostgreSQL.
    from importlib.metadata import version

    assert services["zenoh"]["image"] == f"eclipse/zenoh:{version('eclipse-zenoh')}"
    assert "eclipse-zenoh==" + version("eclipse-zenoh") in pyproject_dependencies()
    assert re.fullmatch(r"postgres:1[5-9](\.\d+)?-alpine|postgres:1[5-9](\.\d+)?",
                        services["postgres"]["image"])
    assert "postgres-data:/var/lib/postgresql/data" in services["postgres"]["volumes"]


def test_compose_publishes_ports_on_loopback_only() -> None:
    services = compose()["services"]
    published = {name: s.get("ports", []) for name, s in services.items()}
    assert published["canal"] and published["zenoh"]
    assert not published["postgres"], "the database is reached inside the compose network only"
    for name, ports in published.items():
        for port in ports:
            assert isinstance(port, str) and port.startswith("127.0.0.1:"), (name, port)


def test_compose_healthchecks() -> None:
    services = compose()["services"]
    test = services["postgres"]["healthcheck"]["test"]
    assert "pg_isready" in " ".join(test)
    # canal's healthcheck comes from its image (Dockerfile HEALTHCHECK), not overridden here.
    assert "healthcheck" not in services["canal"]
    assert any(i == "HEALTHCHECK" for i, _ in dockerfile_instructions())
    # zenohd: a TCP connect to the port its config listens on, inside its own container;
    # canal starts once the router accepts connections.
    zenoh_check = " ".join(services["zenoh"]["healthcheck"]["test"])
    router = zenoh.Config.from_file(str(ROUTER_CONF))
    listen = json.loads(router.get_json("listen/endpoints"))
    port = listen[0].rsplit(":", 1)[1]
    assert f"nc -z 127.0.0.1 {port}" in zenoh_check
    assert services["canal"]["depends_on"]["zenoh"]["condition"] == "service_healthy"


def pyproject_dependencies(extra: str = "service") -> list[str]:
    """What the image installs: the core's dependencies and the ``service`` extra's, with the
    project's own extras it names (``canal-lfd[client,live]``) expanded."""
    import tomllib

    from packaging.requirements import Requirement

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras, todo, deps = project["optional-dependencies"], [extra], list(project["dependencies"])
    done: set[str] = set()
    while todo:
        name = todo.pop()
        if name in done:
            continue
        done.add(name)
        for dep in extras[name]:
            req = Requirement(dep)
            if req.name == project["name"]:
                todo.extend(req.extras)
            else:
                deps.append(dep)
    return [d.replace(" ", "") for d in deps]


def constraints() -> dict[str, str]:
    pins = {}
    for line in (DOCKER / "constraints.txt").read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            name, sep, ver = line.partition("==")
            assert sep, f"constraints.txt: expected name==version, got {line!r}"
            pins[name.lower().replace("_", "-")] = ver
    return pins


def test_constraints_pin_every_runtime_dependency_as_tested() -> None:
    """docker/constraints.txt is the working venv frozen: every runtime dependency (and what
    they pull in) is pinned to the version this test suite runs with."""
    from importlib.metadata import PackageNotFoundError, distribution, version

    from packaging.requirements import Requirement

    pins = constraints()
    assert "canal-lfd" not in pins, "the project itself is built from the context, not pinned"
    seen: set[str] = set()
    todo = [Requirement(d) for d in pyproject_dependencies()]
    while todo:  # the runtime closure, as installed here
        req = todo.pop()
        name = req.name.lower().replace("_", "-")
        if name in seen or (req.marker is not None and not req.marker.evaluate()):
            continue
        seen.add(name)
        try:
            installed = version(name)
        except PackageNotFoundError:
            continue
        assert pins.get(name) == installed, (name, pins.get(name), installed)
        assert req.specifier.contains(installed, prereleases=True), (name, installed)
        todo.extend(Requirement(r) for r in distribution(name).requires or []
                    if "extra ==" not in r)
    assert {"numpy", "scipy", "fastapi", "rerun-sdk", "eclipse-zenoh"} <= seen

def test_compose_secrets_are_required_not_written_down() -> None:
    env = canal_environment({"CANAL_DB_PASSWORD": TEST_PASSWORD})
    assert env["CANAL_DATABASE_URL"] == (
        f"postgresql+psycopg://canal:{TEST_PASSWORD}@postgres:5432/canal"
    )
    assert env["CANAL_TOKEN"] == ""  # unset token -> empty -> Settings.token None
    with pytest.raises(KeyError, match="CANAL_DB_PASSWORD"):
        canal_environment({})
    postgres_env = compose()["services"]["postgres"]["environment"]
    assert interpolate(postgres_env["POSTGRES_PASSWORD"],
                       {"CANAL_DB_PASSWORD": TEST_PASSWORD}) == TEST_PASSWORD
    assert TEST_PASSWORD not in COMPOSE.read_text()
    example = (DOCKER / ".env.example").read_text()
    assert re.search(r"^CANAL_DB_PASSWORD=$", example, re.MULTILINE)


def test_compose_mounts_the_zenoh_configs_it_names() -> None:
    services = compose()["services"]
    env = canal_environment({"CANAL_DB_PASSWORD": TEST_PASSWORD})
    mounts = {v.split(":")[1]: v for v in services["canal"]["volumes"]}
    target = env["CANAL_ZENOH_CONFIG"]
    assert mounts[target] == f"./{CANAL_ZENOH_CONF.name}:{target}:ro"
    router = services["zenoh"]
    command = router["command"]
    router_target = command[command.index("-c") + 1]
    assert f"./{ROUTER_CONF.name}:{router_target}:ro" in router["volumes"]


def test_compose_environment_names_are_settings() -> None:
    """Every CANAL_* variable the compose file sets is a Settings field (no silent typos)."""
    env = canal_environment({"CANAL_DB_PASSWORD": TEST_PASSWORD})
    fields = set(Settings.model_fields)
    unknown = sorted(k for k in env if k.startswith("CANAL_")
                     and k.removeprefix("CANAL_").lower() not in fields)
    assert not unknown, f"compose sets variables Settings does not read: {unknown}"


def test_compose_environment_builds_valid_settings(monkeypatch: pytest.MonkeyPatch) -> None:
    for key in [k for k in os.environ if k.startswith("CANAL_")]:
        monkeypatch.delenv(key)
    env = canal_environment({"CANAL_DB_PASSWORD": TEST_PASSWORD})
    for key, value in env.items():
        monkeypatch.setenv(key, value)
    settings = Settings()
    assert settings.host == "0.0.0.0"
    assert settings.port == 8000
    assert settings.data_dir == Path("/data")
    assert settings.resolved_recordings_dir == Path("/data/recordings")
    assert settings.resolved_database_url.startswith("postgresql+psycopg://canal:")
    assert settings.token is None
    assert settings.zenoh_enabled is True
    assert settings.zenoh_config == Path("/etc/canal/zenoh.json5")


@pytest.mark.skipif(shutil.which("docker") is None, reason="needs the docker CLI")
def test_docker_compose_config_when_the_plugin_exists() -> None:
    """`docker compose config` validates offline; the plugin is missing on these machines."""
    probe = subprocess.run(["docker", "compose", "version"], capture_output=True, text=True)
    if probe.returncode != 0:
        pytest.skip("needs the docker compose plugin (the docker CLI here has none)")
    env = {**os.environ, "CANAL_DB_PASSWORD": TEST_PASSWORD}
    result = subprocess.run(["docker", "compose", "-f", str(COMPOSE), "config", "--quiet"],
                            capture_output=True, text=True, env=env, timeout=60)
    assert result.returncode == 0, result.stderr


# ---- the service starts with what compose passes it -----------------------------------------


@pytest.fixture
def zenoh_router() -> Iterator[str]:
    """A real Zenoh router session from docker/zenoh-router.json5, listening on loopback."""
    config = zenoh.Config.from_file(str(ROUTER_CONF))
    port = free_port()
    config.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    session = zenoh.open(config)
    try:
        yield f"tcp/127.0.0.1:{port}"
    finally:
        session.close()


def compose_env_for_loopback(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                             router: str, timeout_ms: int | None = None) -> Settings:
    """compose's canal environment, except: SQLite for PostgreSQL, temp dirs for /data, and
    docker/canal-zenoh.json5 with only the router address (and maybe its timeout) changed."""
    for key in [k for k in os.environ if k.startswith("CANAL_")]:
        monkeypatch.delenv(key)
    env = canal_environment({"CANAL_DB_PASSWORD": TEST_PASSWORD})
    zenoh_conf = tmp_path / "zenoh.json5"
    text = CANAL_ZENOH_CONF.read_text()
    assert "tcp/zenoh:7447" in text
    text = text.replace("tcp/zenoh:7447", router)
    if timeout_ms is not None:
        text, n = re.subn(r"timeout_ms: \d+", f"timeout_ms: {timeout_ms}", text)
        assert n == 1
    zenoh_conf.write_text(text)
    env.update({
        "CANAL_DATABASE_URL": f"sqlite:///{tmp_path / 'canal.sqlite3'}",
        "CANAL_DATA_DIR": str(tmp_path / "data"),
        "CANAL_RECORDINGS_DIR": str(tmp_path / "data" / "recordings"),
        "CANAL_ZENOH_CONFIG": str(zenoh_conf),
    })
    for key, value in env.items():
        monkeypatch.setenv(key, value)
    settings = Settings()
    assert settings.host == "0.0.0.0"  # what the container binds; the tests bind loopback
    return settings


def image_healthcheck(port: int) -> subprocess.CompletedProcess[str]:
    """The image's own HEALTHCHECK command, run as Docker would run it (CANAL_PORT=port)."""
    healthcheck = dict(dockerfile_instructions())["HEALTHCHECK"]
    argv = json.loads(healthcheck[healthcheck.index("CMD") + 3:].strip())
    assert argv[:2] == ["python", "-c"]
    return subprocess.run([sys.executable, "-c", argv[2]], capture_output=True, text=True,
                          env={**os.environ, "CANAL_PORT": str(port)}, timeout=30)


def test_service_starts_with_the_compose_environment(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, zenoh_router: str) -> None:
    settings = compose_env_for_loopback(tmp_path, monkeypatch, zenoh_router)
    with LiveServer(create_app(settings)) as server:
        r = httpx.get(f"{server.url}/healthz", timeout=10)
        assert r.status_code == 200, r.text
        health = r.json()
        assert health["status"] == "ok"
        assert health["recorder"]["status"] == "ok"
        assert health["bridge"]["status"] == "ok", health  # connected to the router
        assert health["bridge"]["mode"] == "client"
        # a client listens nowhere; the per-mode defaults of the config must not leak through
        assert health["bridge"]["listen"] == [], health["bridge"]
        assert image_healthcheck(server.port).returncode == 0
    # ... and the healthcheck fails when nothing answers.
    assert image_healthcheck(free_port()).returncode != 0


def test_service_without_its_router_keeps_the_api_and_says_so(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """No router within the connect timeout: REST still serves, /healthz and /metrics report
    the bridge down, and the image's healthcheck agrees with /healthz's status code."""
    settings = compose_env_for_loopback(tmp_path, monkeypatch, f"tcp/127.0.0.1:{free_port()}",
                                        timeout_ms=300)
    with LiveServer(create_app(settings)) as server:
        r = httpx.get(f"{server.url}/healthz", timeout=10)
        assert r.status_code in (200, 503), r.text
        assert r.json()["bridge"]["status"] == "down"
        assert httpx.get(f"{server.url}/skills", timeout=10).status_code == 200
        metrics = httpx.get(f"{server.url}/metrics", timeout=10).text
        assert re.search(r"^canal_live_bridge_up 0(\.0)?$", metrics, re.MULTILINE), metrics
        healthy = image_healthcheck(server.port).returncode == 0
        assert healthy == (r.status_code == 200)


# ---- Dockerfile and build context --------------------------------------------------------------


def test_dockerfile_promises() -> None:
    instructions = dockerfile_instructions()
    text = DOCKERFILE.read_text()
    froms = [a for i, a in instructions if i == "FROM"]
    args = dict(a.split("=", 1) for i, a in instructions if i == "ARG" and "=" in a)
    # The tag for readers, the digest for Docker (which uses the digest when both are given).
    assert re.fullmatch(r"python:3\.11-slim@sha256:[0-9a-f]{64}", args["PYTHON_IMAGE"])
    assert all(f.startswith("${PYTHON_IMAGE}") for f in froms)

    users = [a for i, a in instructions if i == "USER"]
    assert users, "the image must not run as root"
    assert users[-1].split(":")[0] not in ("root", "0")
    final_stage = text[text.rindex("\nFROM "):]
    assert final_stage.index("USER") < final_stage.index("ENTRYPOINT")

    assert re.search(r"pip install\b[^\n]*\s-e\b|--editable", text) is None
    assert "[dev]" not in text
    assert re.search(r"pip install -c constraints\.txt '\.\[service\]'(\s|$)", text)
    assert re.search(r"COPY docker/constraints\.txt \./constraints\.txt", text)
    assert re.search(r'pip install --upgrade "pip==[0-9.]+"', text)  # pip pinned too

    exposed = " ".join(a for i, a in instructions if i == "EXPOSE").split()
    assert {"8000", "7447"} <= set(exposed)
    health = dict(instructions)["HEALTHCHECK"]
    assert "urllib.request" in health and "/healthz" in health and "curl" not in health
    assert json.loads(dict(instructions)["ENTRYPOINT"]) == ["python", "-m", "canal_service"]
    env = " ".join(a for i, a in instructions if i == "ENV")
    assert "CANAL_HOST=0.0.0.0" in env and "CANAL_DATA_DIR=/data" in env
    assert "OPENBLAS_NUM_THREADS=1" in env
    assert compose()["services"]["canal"]["environment"]["OPENBLAS_NUM_THREADS"] == "1"
    assert '"/data"' in dict(instructions)["VOLUME"]


def test_dockerignore_lets_in_only_what_the_build_copies() -> None:
    lines = [ln.strip() for ln in (ROOT / ".dockerignore").read_text().splitlines()
             if ln.strip() and not ln.startswith("#")]
    assert lines[0] == "*", "allow-list: everything is excluded first"
    allowed = {ln[1:].rstrip("/") for ln in lines if ln.startswith("!")}
    copied = set()
    for i, a in dockerfile_instructions():
        if i == "COPY" and not a.startswith("--from"):
            copied.update(a.split()[:-1])
    assert copied == allowed
    for src in copied:
        assert (ROOT / src).exists(), src
    for secret_or_bulk in (".venv", ".env", "data", ".git", "docker"):
        assert secret_or_bulk not in allowed


# ---- Zenoh configuration files -----------------------------------------------------------------


def test_zenoh_router_config_loads() -> None:
    config = zenoh.Config.from_file(str(ROUTER_CONF))
    assert json.loads(config.get_json("mode")) == "router"
    assert json.loads(config.get_json("listen/endpoints")) == ["tcp/0.0.0.0:7447"]
    assert json.loads(config.get_json("scouting/multicast/enabled")) is False


def test_canal_zenoh_config_loads() -> None:
    config = zenoh.Config.from_file(str(CANAL_ZENOH_CONF))
    assert json.loads(config.get_json("mode")) == "client"
    router_port = compose()["services"]["zenoh"]["ports"][0].rsplit(":", 1)[1]
    assert json.loads(config.get_json("connect/endpoints")) == [f"tcp/zenoh:{router_port}"]
    assert json.loads(config.get_json("scouting/multicast/enabled")) is False
