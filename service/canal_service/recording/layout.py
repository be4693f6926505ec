"""Where a skill's recording lives on disk: one folder per skill, a run of segment files.

::

    root/
      .exports/                     snapshots handed to the caller (deleted by the caller)
      .rerun/                       rerun CLI config (analytics off) for our CLI subprocesses
      <skill>/
        recording_id                the Rerun recording id shared by every segment
        instance                    the skill instance recorded (its id and creation time)
        ledger                      ids of the demos/models flushed to the files (reconcile)
        seg-000001-000004.rrd       closed: segments 1..4 merged (footer / summary written)
        seg-000005-000005.mcap      closed: one segment
        seg-000006.open.rrd         the segment being written (at most one per kind)
        seg-000006.open.mcap

A closed file names the range of segments it covers, so a merge that died half-way (merged
file written, inputs not yet deleted) never shows a segment twice: a range covered by a wider
one is ignored and removed at the next compaction.
"""

from __future__ import annotations

import json
import re
import shutil
import uuid
from dataclasses import dataclass, field
from pathlib import Path

SAFE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,127}$")
_CLOSED = re.compile(r"^seg-(\d{6,})-(\d{6,})\.(rrd|mcap)$")
_OPEN = re.compile(r"^seg-(\d{6,})\.open\.(rrd|mcap)$")
KINDS = ("rrd", "mcap")


def skill_dirname(skill: str) -> str:
    """A folder name for ``skill``: the name itself when safe, else ``x-`` plus its hex."""
    if SAFE_NAME.match(skill) and skill not in (".", ".."):
        return skill
    return "x-" + skill.encode("utf-8").hex()


@dataclass
class Ledger:
    """What a skill's recording holds for sure (flushed to the files), from its ledger file."""

    demos: set[int]
    models: set[int]
    reproductions: int  # the highest number
    numbers: set[int] = field(default_factory=set)  # every reproduction's number


@dataclass(frozen=True)
class ClosedSegment:
    """A finished file covering segments ``first..last``."""

    path: Path
    first: int
    last: int


class SkillDir:
    """The files of one skill's recording."""

    def __init__(self, path: Path) -> None:
        self.path = path

    @classmethod
    def of(cls, root: Path, skill: str) -> SkillDir:
        """The folder of ``skill`` under ``root``."""
        return cls(root / skill_dirname(skill))

    def ensure(self) -> None:
        """Create the folder."""
        self.path.mkdir(parents=True, exist_ok=True)

    def recording_id(self) -> str:
        """The Rerun recording id of this skill, created on first use."""
        id_file = self.path / "recording_id"
        try:
            return id_file.read_text().strip()
        except FileNotFoundError:
            rid = str(uuid.uuid4())
            tmp = id_file.with_suffix(".tmp")
            tmp.write_text(rid)
            tmp.replace(id_file)
            return rid

    @property
    def ledger_path(self) -> Path:
        """Lines ``d <id>`` (demo logged), ``x <id>`` (demo removed), ``m <version>``,
        ``p <n>`` (n-th reproduction), ``y <n>`` (reproduction n cleared, no longer kept),
        appended only once their data is flushed."""
        return self.path / "ledger"

    def ledger(self) -> Ledger:
        """What the ledger says the recording holds (empty when there is none)."""
        demos: set[int] = set()
        models: set[int] = set()
        numbers: set[int] = set()
        repro = 0
        try:
            text = self.ledger_path.read_text()
        except FileNotFoundError:
            return Ledger(demos, models, 0)
        for line in text.splitlines():
            kind, _, value = line.partition(" ")
            if not value.strip().isdigit():
                continue  # a line the crash cut short
            n = int(value)
            if kind == "d":
                demos.add(n)
            elif kind == "x":
                demos.discard(n)
            elif kind == "m":
                models.add(n)
            elif kind == "p":
                repro = max(repro, n)
                numbers.add(n)
            elif kind == "y":
                numbers.discard(n)
        return Ledger(demos, models, repro, numbers)

    @property
    def instance_path(self) -> Path:
        """``{"skill": name, "instance": ...}``: which skill instance the files record."""
        return self.path / "instance"

    def instance(self) -> tuple[str, str] | None:
        """(skill name, instance) the files record, or None when not written (a recording
        made without a database, or before instances were recorded)."""
        try:
            data = json.loads(self.instance_path.read_text())
            return str(data["skill"]), str(data["instance"])
        except (FileNotFoundError, ValueError, KeyError, TypeError):
            return None

    def write_instance(self, skill: str, instance: str) -> None:
        """Say which skill instance the files record (atomically)."""
        self.ensure()
        tmp = self.instance_path.with_suffix(".tmp")
        tmp.write_text(json.dumps({"skill": skill, "instance": instance}))
        tmp.replace(self.instance_path)

    def append_ledger(self, lines: list[str]) -> None:
        """Append ``lines`` to the ledger (one write: a crash cuts at most the last line)."""
        if lines:
            self.ensure()
            with open(self.ledger_path, "a") as f:
                f.write("\n".join(lines) + "\n")

    def open_path(self, segment: int, kind: str) -> Path:
        """The file of an open (being written) segment."""
        return self.path / f"seg-{segment:06d}.open.{kind}"

    def closed_path(self, first: int, last: int, kind: str) -> Path:
        """The file of a closed segment range."""
        return self.path / f"seg-{first:06d}-{last:06d}.{kind}"

    def open_segments(self, kind: str) -> list[tuple[int, Path]]:
        """Open segment files of ``kind`` (more than one only after a crash), oldest first."""
        found = []
        for p in self._entries():
            m = _OPEN.match(p.name)
            if m and m.group(2) == kind:
                found.append((int(m.group(1)), p))
        return sorted(found)

    def closed_segments(self, kind: str) -> list[ClosedSegment]:
        """The closed files of ``kind`` to read, oldest first, ignoring covered ranges."""
        ranges = []
        for p in self._entries():
            m = _CLOSED.match(p.name)
            if m and m.group(3) == kind:
                ranges.append(ClosedSegment(p, int(m.group(1)), int(m.group(2))))
        ranges.sort(key=lambda s: (s.first, -s.last))
        kept: list[ClosedSegment] = []
        for seg in ranges:
            if kept and seg.last <= kept[-1].last:
                continue  # covered by a merge whose inputs were not deleted yet
            kept.append(seg)
        return kept

    def covered_segments(self, kind: str) -> list[Path]:
        """Closed files made redundant by a wider merged range (safe to delete)."""
        keep = {s.path for s in self.closed_segments(kind)}
        return [p for p in self._entries()
                if _CLOSED.match(p.name) and p.suffix == f".{kind}" and p not in keep]

    def next_segment(self) -> int:
        """One more than the highest segment number on disk (any kind)."""
        high = 0
        for p in self._entries():
            m = _OPEN.match(p.name)
            if m:
                high = max(high, int(m.group(1)))
            m = _CLOSED.match(p.name)
            if m:
                high = max(high, int(m.group(2)))
        return high + 1

    def remove(self) -> None:
        """Delete the folder and everything in it."""
        shutil.rmtree(self.path, ignore_errors=True)

    def _entries(self) -> list[Path]:
        try:
            return list(self.path.iterdir())
        except FileNotFoundError:
            return []


def skill_dirs(root: Path) -> list[Path]:
    """Skill folders under ``root`` (hidden folders are ours, not skills)."""
    try:
        return sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith("."))
    except FileNotFoundError:
        return []
