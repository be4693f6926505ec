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


# ---- no import cycles ----------------------------------------------------------------------


def _modules() -> dict[str, tuple[Path, bool]]:
    """Every module of our packages: dotted name -> (file, is a package's __init__)."""
    found = {}
    for package, root in PACKAGES.items():
        for f in root.rglob("*.py"):
            parts = [package, *f.relative_to(root).with_suffix("").parts]
            is_package = parts[-1] == "__init__"
            found[".".join(parts[:-1] if is_package else parts)] = (f, is_package)
    return found


def imported_modules(name: str, path: Path, is_package: bool, known: set[str]) -> set[str]:
    """Our modules that module ``name`` imports, at any depth of its code (a function's
    import runs too, later); imports under ``if TYPE_CHECKING:`` never run and do not count."""
    tree = ast.parse(path.read_text(), filename=str(path))
    typing_only = {id(m) for n in ast.walk(tree) if isinstance(n, ast.If)
                   and "TYPE_CHECKING" in ast.unparse(n.test) for m in ast.walk(n)}
    here = name.split(".") if is_package else name.split(".")[:-1]
    out: set[str] = set()
    for node in ast.walk(tree):
        if id(node) in typing_only:
            continue
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name in known)
        elif isinstance(node, ast.ImportFrom):
            base = here[: len(here) - node.level + 1] if node.level else []
            module = ".".join([*base, *([node.module] if node.module else [])])
            for alias in node.names:
                sub = f"{module}.{alias.name}"
                out.add(sub if sub in known else module)
    return (out & known) - {name}


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected groups of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    groups: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                groups.append(sorted(group))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return groups


def test_no_package_has_an_import_cycle() -> None:
    modules = _modules()
    graph = {name: imported_modules(name, f, is_package, set(modules))
             for name, (f, is_package) in modules.items()}
    assert sum(map(len, graph.values())) > 100  # the graph was read
    assert import_cycles(graph) == []


def test_the_cycle_checker_sees_a_cycle_through_a_function_import(tmp_path: Path) -> None:
    a, b = tmp_path / "a.py", tmp_path / "b.py"
    a.write_text("from typing import TYPE_CHECKING\nfrom .b import run\n"
                 "if TYPE_CHECKING:\n    from .c import T\n")
    b.write_text("def run():\n    from .a import main\n")
    known = {"p.a", "p.b", "p.c"}
    graph = {"p.a": imported_modules("p.a", a, False, known),
             "p.b": imported_modules("p.b", b, False, known), "p.c": set()}
    assert graph["p.a"] == {"p.b"}  # the TYPE_CHECKING import does not count
    assert import_cycles(graph) == [["p.a", "p.b"]]
