"""Every code block of README.md and docs/*.md runs as written, on a fresh copy of the files.

How a document is checked (README, "Every block here runs"):

* its fenced blocks are taken in order; ``sh``/``bash``/``shell``/``zsh`` blocks run with
  ``bash -e``, ``python`` blocks with this interpreter, each as its own process;
* the working folder is a temporary copy of the repository's files (``git ls-files``, as a
  fresh clone has them) with ``.venv`` linked in, so ``examples/demos/`` and
  ``.venv/bin/python`` resolve as they do for a newcomer in the repository root;
* a real service runs for the document (``python -m canal_service`` in its own process: uvicorn
  and the Zenoh bridge on free loopback ports, recordings on, its own data folder);
* the only change made to a block is the address: ``127.0.0.1:8000`` (and ``localhost:8000``)
  become the service's REST port, ``127.0.0.1:7447`` its Zenoh port; ``CANAL_URL`` points at it;
* a block fails on a non-zero exit status, a Python traceback, or an ``{"error": ...}`` answer
  printed by a shell block;
* blocks that cannot run are marked, and counted: an info string that names data (``text``,
  ``json``, ``yaml``, ...), or a ``<!-- norun: why -->`` comment on the line before the fence.
  A fence with no language at all is an error: say what it is.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
SHELL = {"sh", "bash", "shell", "zsh"}
PYTHON = {"python", "py", "python3"}
DATA = {"text", "txt", "plain", "json", "json5", "jsonl", "yaml", "yml", "toml", "ini", "csv",
        "markdown", "md", "output", "http", "diff", "console", "sql", "dockerfile"}
NORUN = re.compile(r"^\s*<!--\s*norun\b(?::\s*(?P<why>.*?))?\s*-->\s*$")
FENCE = re.compile(r"^(?P<indent> {0,3})(?P<fence>`{3,}|~{3,})\s*(?P<info>[^`\s]*)")
BLOCK_TIMEOUT_S = 180


@dataclass
class Block:
    path: Path
    line: int  # 1-based line of the opening fence
    lang: str
    code: str
    norun: str | None  # the reason, when marked not runnable

    @property
    def where(self) -> str:
        return f"{self.path.name}:{self.line}"

    @property
    def kind(self) -> str:
        """'shell', 'python', 'skip' (marked or data), or 'unlabeled'."""
        if self.norun is not None:
            return "skip"
        if self.lang in SHELL:
            return "shell"
        if self.lang in PYTHON:
            return "python"
        if not self.lang:
            return "unlabeled"
        return "skip"


def extract_blocks(path: Path, text: str | None = None) -> list[Block]:
    """The fenced code blocks of a markdown file, in order, with their norun markers."""
    lines = (path.read_text(encoding="utf-8") if text is None else text).splitlines()
    blocks: list[Block] = []
    i = 0
    previous = ""  # the last non-blank line before the current one
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            if lines[i].strip():
                previous = lines[i]
            i += 1
            continue
        fence, start = m.group("fence"), i
        lang = m.group("info").lower().split(",")[0].strip("{}.")
        body: list[str] = []
        i += 1
        while i < len(lines) and not lines[i].lstrip().startswith(fence):
            body.append(lines[i][len(m.group("indent")):] if lines[i].startswith(
                m.group("indent")) else lines[i])
            i += 1
        marker = NORUN.match(previous)
        blocks.append(Block(path, start + 1, lang, "\n".join(body) + "\n",
                            None if marker is None else (marker.group("why") or "marked")))
        previous = ""
        i += 1
    return blocks


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def fresh_copy(dest: Path) -> Path:
    """The repository's files as a fresh clone has them, plus a link to the working venv."""
    try:
        listed = subprocess.run(["git", "ls-files", "-z", "--cached", "--others",
                                 "--exclude-standard"], cwd=ROOT, capture_output=True,
                                check=True, timeout=60).stdout.decode().split("\0")
        files = [f for f in listed if f and (ROOT / f).is_file()]
    except (OSError, subprocess.SubprocessError):
        files = [str(p.relative_to(ROOT)) for p in ROOT.rglob("*") if p.is_file()
                 and not {".venv", ".git", "data", "__pycache__", ".pytest_cache",
                          ".mypy_cache", ".ruff_cache"} & set(p.relative_to(ROOT).parts)]
    for f in files:
        target = dest / f
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / f, target)
    venv = Path(sys.prefix)
    if venv != Path(sys.base_prefix):
        (dest / ".venv").symlink_to(venv, target_is_directory=True)
    return dest


@dataclass
class LiveService:
    url: str
    rest_port: int
    zenoh_port: int
    env: dict[str, str]

    def substitute(self, code: str) -> str:
        return (code.replace("127.0.0.1:8000", f"127.0.0.1:{self.rest_port}")
                .replace("localhost:8000", f"localhost:{self.rest_port}")
                .replace("127.0.0.1:7447", f"127.0.0.1:{self.zenoh_port}"))


def base_env(tmp: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items()
           if not k.startswith("CANAL_") and k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    bin_dir = str(Path(sys.executable).parent)
    env.update(PATH=bin_dir + os.pathsep + env.get("PATH", ""), RERUN_TELEMETRY_ENABLED="false",
               MPLBACKEND="Agg", CANAL_CACHE_DIR=str(tmp / "cache"), COLUMNS="120",
               PYTHONUNBUFFERED="1")
    return env


@contextlib.contextmanager
def start_service(tmp: Path, env: dict[str, str]) -> Iterator[LiveService]:
    rest, zenoh = free_port(), free_port()
    log = (tmp / "service.log").open("w")
    proc = subprocess.Popen(
        [sys.executable, "-m", "canal_service", "--port", str(rest), "--data-dir",
         str(tmp / "service-data"), "--zenoh-listen", f"tcp/127.0.0.1:{zenoh}"],
        cwd=tmp, env=env, stdout=log, stderr=subprocess.STDOUT)
    url = f"http://127.0.0.1:{rest}"
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                if httpx.get(f"{url}/healthz", timeout=2).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            if proc.poll() is not None or time.monotonic() > deadline:
                raise AssertionError("the service did not start:\n"
                                     + (tmp / "service.log").read_text())
            time.sleep(0.1)
        yield LiveService(url, rest, zenoh, {**env, "CANAL_URL": url})
    finally:
        proc.terminate()
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)
        log.close()


def run_block(block: Block, service: LiveService, cwd: Path, n: int) -> None:
    code = service.substitute(block.code)
    script = cwd.parent / f"block-{n:02d}.{'py' if block.kind == 'python' else 'sh'}"
    script.write_text(code)
    cmd = [sys.executable, str(script)] if block.kind == "python" else ["bash", "-e", str(script)]
    # A block in its own session, so that on a timeout everything it started (a `canal serve`
    # left in a block once kept port 8000 busy long after the test) goes with it.
    with subprocess.Popen(cmd, cwd=cwd, env=service.env, stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE, text=True, start_new_session=True) as running:
        try:
            stdout, stderr = running.communicate(timeout=BLOCK_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            os.killpg(running.pid, signal.SIGKILL)
            stdout, stderr = running.communicate()
            pytest.fail(f"{block.where}: still running after {BLOCK_TIMEOUT_S} s\n{code}\n"
                        f"{stdout}{stderr}")
    proc = subprocess.CompletedProcess(cmd, running.returncode, stdout, stderr)
    report = (f"{block.where} ({block.lang}) as run:\n{code}\n--- exit {proc.returncode}\n"
              f"--- stdout\n{proc.stdout}\n--- stderr\n{proc.stderr}")
    assert proc.returncode == 0, report
    assert "Traceback (most recent call last)" not in proc.stderr, report
    if block.kind == "shell":
        assert '{"error":' not in proc.stdout.replace(" ", "").replace("\n", ""), report
    print(report)  # shown with pytest -s or on a later failure


@pytest.mark.parametrize("doc", DOCS, ids=[p.name for p in DOCS])
def test_every_block_runs(doc: Path, tmp_path: Path) -> None:
    blocks = extract_blocks(doc)
    unlabeled = [b.where for b in blocks if b.kind == "unlabeled"]
    assert not unlabeled, (f"fences without a language at {', '.join(unlabeled)}: write "
                           f"```sh / ```python for commands, ```text for output or layouts, "
                           f"or put <!-- norun: why --> on the line before")
    runnable = [b for b in blocks if b.kind in ("shell", "python")]
    skipped = [b for b in blocks if b.kind == "skip"]
    print(f"{doc.name}: {len(runnable)} blocks run, {len(skipped)} not runnable: "
          + "; ".join(f"{b.where} {b.norun or b.lang}" for b in skipped))
    if not runnable:
        return
    cwd = fresh_copy(tmp_path / "clone")
    env = base_env(tmp_path)
    with start_service(tmp_path, env) as service:
        for n, block in enumerate(runnable):
            run_block(block, service, cwd, n)


def test_readme_is_mostly_runnable() -> None:
    """The README's commands are checked, not waved through: the only blocks not run are the
    ones that serve until Ctrl-C and example answers."""
    blocks = extract_blocks(ROOT / "README.md")
    kinds = [b.kind for b in blocks]
    assert kinds.count("shell") >= 3 and kinds.count("python") >= 4, kinds
    assert kinds.count("skip") <= 4, [(b.where, b.norun or b.lang) for b in blocks
                                      if b.kind == "skip"]
    # The two newcomer commands stay at the top.
    first = blocks[0]
    assert first.code.split()[:2] == ["make", "run"] and "make test" in first.code


def test_extractor_reads_markers_languages_and_fences() -> None:
    text = "\n".join([
        "# t", "", "```sh", "echo one", "```", "",
        "<!-- norun: serves forever -->", "", "```bash", "sleep 1000", "```",
        "```text", "layout", "```",
        "~~~python", "print('```')", "~~~",
        "```", "no language", "```",
        "  ```python", "  x = 1", "  ```",
    ])
    blocks = extract_blocks(Path("x.md"), text)
    assert [(b.line, b.lang, b.kind) for b in blocks] == [
        (3, "sh", "shell"), (9, "bash", "skip"), (12, "text", "skip"),
        (15, "python", "python"), (18, "", "unlabeled"), (21, "python", "python")]
    assert blocks[1].norun == "serves forever"
    assert blocks[3].code == "print('```')\n"
    assert blocks[5].code == "x = 1\n"


def test_substitution_changes_only_the_addresses() -> None:
    service = LiveService("http://127.0.0.1:5555", 5555, 6666, {})
    code = "B=http://127.0.0.1:8000\ncurl localhost:8000/x\nep='tcp/127.0.0.1:7447'\n18000\n"
    assert service.substitute(code) == ("B=http://127.0.0.1:5555\ncurl localhost:5555/x\n"
                                        "ep='tcp/127.0.0.1:6666'\n18000\n")
