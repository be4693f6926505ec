"""Everything shipped speaks of the product and its users, not of how it was made.

No numbered or "this/last" sessions or rounds, no issue numbers, no engineers, no "the lead"
in README, docs, BENCHMARKS, CHANGELOG, code, tests, bench or examples. A Zenoh or database
session, a retry round and a round trip are the product's own words and stay.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SUFFIXES = {".md", ".py", ".toml", ".yaml", ".yml", ".txt", ".cfg", ".ini", ".json5", ".sh",
            ".mako", ".cff"}
NAMES = {"Makefile", "Dockerfile", "run"}
ORDINAL = (r"(?:first|second|third|fourth|fifth|sixth|seventh|eighth|ninth|tenth|\d+(?:st|nd|rd|th)"
           r"|this|last|previous|next|earlier|later)")
#: An issue number is never a product word, whatever stands beside it.
ISSUE = re.compile(r"\bissues?\s+#?[0-9]+\b", re.IGNORECASE)
HISTORY = re.compile("|".join([
    rf"\b{ORDINAL}\s+(?:work\s+)?sessions?(?:'s)?\b(?!\s+(?:of|per)\s+(?:zenoh|the\s+database))",
    r"\bsessions?\s+[0-9]+\b",
    rf"\b{ORDINAL}\s+rounds?\b(?![-\s]+(?:of\s+retr|trip))",
    r"\bround\s+[0-9]+\b",
    r"\bissues?\s+#?[0-9]+\b",
    r"\b(?:[0-9]+|two|three|four|five|six|seven|eight|nine)\s+engineers\b",
    r"\bengineers?\s+[\"'`]\w",
    r"\bthe\s+lead\b",
]), re.IGNORECASE)
#: Product words the patterns would take: Zenoh and database sessions, retry rounds.
ALLOWED = re.compile(r"zenoh|database|sqlalchemy|\bdb\b|postgres|retr(y|ies)|\btries\b|"
                     r"\bpeer\b|\bopen(?:s|ed|ing)?\b|\bsession\s*[=(.:\[]|_session",
                     re.IGNORECASE)


def shipped_files() -> list[Path]:
    names = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True,
                           check=True).stdout.splitlines()
    return [ROOT / n for n in names
            if (Path(n).suffix in SUFFIXES or Path(n).name in NAMES)
            and not n.startswith("tests/data/") and (ROOT / n).is_file()]


def history_lines(text: str) -> list[tuple[int, str]]:
    """(line number, line) of every line that speaks of how the project was made."""
    found = []
    for number, line in enumerate(text.splitlines(), 1):
        for match in HISTORY.finditer(line):
            window = line[max(0, match.start() - 40):match.end() + 40]
            if ISSUE.fullmatch(match.group(0)) or not ALLOWED.search(window):
                found.append((number, line.strip()))
                break
    return found


def test_the_patterns_tell_history_from_product_words() -> None:
    history = ["as measured in the seventh session", "this round's figures",
               "issue 12's 20x target", "409/503 with Retry-After (issue 12, item 3)",
               "Attacks on the open live path (issue 15)", "Issue 12: on PostgreSQL", "seven engineers' test suites", "the lead re-runs",
               "(bench/quality.py, engineer \"method\")", "in session 4", "last session's machine"]
    product = ["a Zenoh session per bridge", "the database session is closed",
               "the pose round trip", "a retry round of three", "one session of the database",
               "the client opens its own Zenoh session", "around 15 rounds of retries",
               "a robotics engineer using this every day", "that round-trips exactly",
               "use this session instead of opening one", "the next round tries again"]
    assert [s for s in history if not history_lines(s)] == []
    assert [s for s in product if history_lines(s)] == []


def test_no_shipped_file_speaks_of_how_the_project_was_made() -> None:
    me = Path(__file__).resolve()
    offenders = [f"{path.relative_to(ROOT)}:{number}: {line[:120]}"
                 for path in shipped_files() if path.resolve() != me
                 for number, line in history_lines(path.read_text(encoding="utf-8",
                                                                  errors="replace"))]
    assert offenders == [], "\n".join(offenders)
