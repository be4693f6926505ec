"""The dependency arrows of the README's layout, checked on the source: every import points
inward to canal_core (service -> protocol -> core, client -> protocol -> core), never
service <-> client, never outward from the core or the protocol."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = {
    "canal_core": ROOT / "canal_core",
    "canal_protocol": ROOT / "canal_protocol",
    "canal_service": ROOT / "service" / "canal_service",
    "canal_client": ROOT / "clients" / "canal_client",
}
# What each package may import among ours (besides itself).
ALLOWED = {
    "canal_core": set(),
    "canal_protocol": {"canal_core"},
    "canal_service": {"canal_core", "canal_protocol"},
    "canal_client": {"canal_core", "canal_protocol"},
}


def ours_imported(path: Path) -> set[str]:
    """Top-level names of our packages that ``path`` imports (absolute imports only: a
    relative import stays inside its own package)."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        else:
            continue
        found.update(n.split(".")[0] for n in names if n.split(".")[0] in PACKAGES)
    return found


@pytest.mark.parametrize("package", sorted(PACKAGES))
def test_imports_point_inward(package: str) -> None:
    files = sorted(PACKAGES[package].rglob("*.py"))
    assert files, f"no source found for {package} at {PACKAGES[package]}"
    outward = {
        str(f.relative_to(ROOT)): sorted(ours_imported(f) - ALLOWED[package] - {package})
        for f in files
    }
    assert {f: names for f, names in outward.items() if names} == {}


def test_the_checker_sees_an_outward_import(tmp_path: Path) -> None:
    bad = tmp_path / "bad.py"
    bad.write_text("import numpy\nfrom canal_service.app import create_app\n"
                   "def f():\n    import canal_client.rest\n")
    assert ours_imported(bad) == {"canal_service", "canal_client"}
