"""BENCHMARKS.md is one section per benchmark: a run rewrites its own sections only."""

from __future__ import annotations

import datetime as dt
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from bench.__main__ import (  # noqa: E402
    SCRIPTS,
    markers,
    printed_tables,
    replace_section,
    title,
    write_sections,
)
from bench.common import summary_row  # noqa: E402


def run(name: str, value: float, rc: int = 0) -> dict:
    return {"name": name, "rc": rc, "seconds": 3.0, "quick": False,
            "started": dt.datetime(2026, 12, 2, 18, 0, tzinfo=dt.UTC), "load": (0.5, 0.7),
            "rows": [{"source": name, **summary_row("fit, circle, 10 x 1000 pts, N=200", value,
                                                     "ms", "naive Python loop", 2 * value)}],
            "output": ["warming up", "fit time", "| a | b |", "|---|---:|", "| x | 1 |", "done"],
            "text": ""}


def test_a_run_rewrites_its_own_section_and_keeps_the_others(tmp_path: Path) -> None:
    md = tmp_path / "BENCHMARKS.md"
    write_sections([run("scale", 5.0), run("core", 4.0)], md, tmp_path / "img")
    text = md.read_text()
    assert text.index(markers("core")[0]) < text.index(markers("scale")[0])  # SCRIPTS order
    assert "| fit, circle, 10 x 1000 pts, N=200 | 5 | ms | naive Python loop | 10.0 | 0.5 |" in text
    assert "fit time\n\n| a | b |\n|---|---:|\n| x | 1 |" in text  # the printed table
    assert "`python -m bench --only core --write`" in text
    assert "(img/core/fit_time.png)" in text  # its picture, from its own rows
    assert (tmp_path / "img" / "core" / "fit_time.png").is_file()

    write_sections([run("core", 7.0), run("scale", 9.0, rc=1)], md, tmp_path / "img")
    again = md.read_text()
    core = again.split(markers("core")[0])[1].split(markers("core")[1])[0]
    scale = again.split(markers("scale")[0])[1].split(markers("scale")[1])[0]
    assert "| 7 | ms |" in core and "| 5 | ms |" not in core
    assert "| 5 | ms |" in scale  # a failed run leaves its section as it was
    assert again.count("# Benchmarks") == 1 and again.count(markers("core")[0]) == 1
    assert again.count("](#core)") == 1 and again.count("](#scale)") == 1
    assert "\n## core\n" in again  # a short heading: BENCHMARKS.md#core stays a valid link


def test_sections_go_where_the_script_order_puts_them() -> None:
    text = replace_section("intro\n", SCRIPTS[-1], "last")
    text = replace_section(text, SCRIPTS[0], "first")
    assert text.index("first") < text.index("last")
    assert printed_tables(["no table here", "| not | a table"]) == ""
    assert title("core") and not title("core").startswith("`")
