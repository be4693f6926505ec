"""Installable faces: the core, the protocol and the client work without the service's
dependencies, and the package metadata promises exactly that.

Each face is imported in a fresh interpreter whose import system refuses the packages it must
not need (a meta-path finder that raises on them), then used: a fit with canal_core alone,
models read by the client, a real request to a closed port. The metadata test walks the
installed requirement closure of ``canal-lfd[client]`` (and of the bare ``canal-lfd``).
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from importlib.metadata import PackageNotFoundError, distribution

import pytest
from packaging.requirements import Requirement

PROJECT = "canal-lfd"
# Import names (first component) and distribution names of what only the service needs.
SERVICE_IMPORTS = ("fastapi", "starlette", "sqlalchemy", "alembic", "psycopg", "uvicorn",
                   "rerun", "mcap", "mcap_ros2", "pydantic_settings", "prometheus_client",
                   "trimesh", "multipart", "canal_service")
SERVICE_DISTRIBUTIONS = {"fastapi", "starlette", "sqlalchemy", "alembic", "psycopg",
                         "psycopg-binary", "uvicorn", "rerun-sdk", "mcap", "mcap-ros2-support",
                         "pydantic-settings", "prometheus-client", "trimesh",
                         "python-multipart", "eclipse-zenoh", "pyarrow"}
CLIENT_IMPORTS = ("pydantic", "orjson", "httpx", "typer", "rich", "zenoh", "canal_protocol",
                  "canal_client")

_REFUSE = """
import importlib.abc, sys
REFUSED = {refused!r}
class Refuse(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in REFUSED:
            raise ImportError(f"refused in this face: {{name}}")
        return None
sys.meta_path.insert(0, Refuse())
"""
_LOADED = """
loaded = sorted({{m.split(".")[0] for m in sys.modules}} & REFUSED)
assert not loaded, loaded
print("face ok")
"""


def run_face(refused: tuple[str, ...], body: str) -> subprocess.CompletedProcess[str]:
    code = (_REFUSE.format(refused=set(refused)) + textwrap.dedent(body)
            + _LOADED.format())
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)


def test_the_refusing_finder_refuses() -> None:
    """The harness can fail: importing a refused package dies in the subprocess."""
    result = run_face(("fastapi",), "import fastapi\n")
    assert result.returncode != 0 and "refused in this face: fastapi" in result.stderr


def test_core_face_fits_without_protocol_client_or_service() -> None:
    result = run_face(SERVICE_IMPORTS + CLIENT_IMPORTS, """
        import numpy as np
        import canal_core
        t = np.linspace(0.0, 1.0, 50)
        demos = [np.c_[t, np.sin(3 * t) + 0.02 * j, 0.01 * j * t] for j in range(3)]
        canal = canal_core.fit(demos, n_samples=30)
        assert canal.reproduce(demos[0][0]).shape[1] == 3
        """)
    assert result.returncode == 0, result.stderr
    assert "face ok" in result.stdout


def test_client_face_works_without_the_service() -> None:
    result = run_face(SERVICE_IMPORTS + ("zenoh",), """
        import numpy as np
        import canal_client, canal_client.rest
        from canal_client import (CanalClient, ConnectionFailedError, Health, Model,
                                  Reproduction)
        from canal_protocol.schemas import FitRequest, HealthOut, ReproductionOut
        assert issubclass(Reproduction, ReproductionOut) and Health is HealthOut
        r = Reproduction.model_validate_json(
            b'{"positions": [[0, 0, 0], [1, 0, 0]], "start": [0, 0, 0], "inside": true, '
            b'"eta": 0.1, "section_index": 0, "projected": false, "model_version": 1}')
        assert isinstance(r.positions, np.ndarray) and r.positions.shape == (2, 3)
        assert r.model_dump(mode="json")["positions"] == [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]
        assert FitRequest().n_samples == 200
        import socket
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        with CanalClient(f"http://127.0.0.1:{port}", timeout=5.0) as c:
            try:
                c.health()
            except ConnectionFailedError as exc:
                assert str(port) in str(exc)
            else:
                raise AssertionError("a closed port answered")
        """)
    assert result.returncode == 0, result.stderr
    assert "face ok" in result.stdout


def test_protocol_face_needs_only_core_pydantic_and_orjson() -> None:
    result = run_face(SERVICE_IMPORTS + ("httpx", "typer", "rich", "zenoh", "canal_client"), """
        from canal_protocol import schemas, wire, options
        assert schemas.FitRequest().cross_section in options.CROSS_SECTIONS
        assert wire is not None
        """)
    assert result.returncode == 0, result.stderr


def requirement_closure(extras: set[str]) -> set[str]:
    """Distribution names ``canal-lfd[extras]`` installs, from the installed metadata."""
    seen: set[str] = set()
    todo: list[tuple[str, frozenset[str]]] = [(PROJECT, frozenset(extras))]
    done: set[tuple[str, frozenset[str]]] = set()
    while todo:
        name, wanted = todo.pop()
        if (name, wanted) in done:
            continue
        done.add((name, wanted))
        seen.add(name)
        try:
            requires = distribution(name).requires or []
        except PackageNotFoundError:
            continue
        for text in requires:
            req = Requirement(text)
            markers = [{"extra": e} for e in wanted] or [{"extra": ""}]
            if req.marker is not None and not any(req.marker.evaluate(m) for m in markers):
                continue
            todo.append((req.name.lower().replace("_", "-"), frozenset(req.extras)))
    return seen


@pytest.mark.parametrize("extras", [set(), {"protocol"}, {"client"}])
def test_metadata_keeps_service_dependencies_out_of_the_faces(extras: set[str]) -> None:
    closure = requirement_closure(extras)
    assert not closure & SERVICE_DISTRIBUTIONS, sorted(closure & SERVICE_DISTRIBUTIONS)
    assert "numpy" in closure and "scipy" in closure
    if "client" in extras:
        assert {"httpx", "pydantic", "orjson", "typer"} <= closure
    if not extras:
        assert not closure & {"pydantic", "orjson", "httpx", "typer", "rich"}


def test_metadata_service_face_has_what_the_service_imports() -> None:
    """The walk sees the service's dependencies where they belong (so the test above can
    fail)."""
    closure = requirement_closure({"service"})
    assert SERVICE_DISTRIBUTIONS - {"psycopg-binary"} <= closure
    assert {"httpx", "pydantic", "eclipse-zenoh"} <= closure


def test_client_and_cli_load_no_scipy() -> None:
    """The client and the ``canal`` command start without the fitting code's scipy (about
    half of the CLI's start-up): the options they validate against are numpy only."""
    result = run_face(("scipy",), """
        import canal_client, canal_client.cli
        from canal_protocol import options
        from canal_core.options import fit_options
        assert fit_options(cross_section="ellipse").cross_section in options.CROSS_SECTIONS
        """)
    assert result.returncode == 0, result.stderr
    assert "face ok" in result.stdout
