"""Shared helpers of the benchmarks: what a script hands to its section of BENCHMARKS.md.

Sections
--------
``python -m bench`` (bench/__main__.py) runs every script as a subprocess and writes one
section of BENCHMARKS.md per script from that run. A script hands over two things, both
optional, both no-ops when the script runs on its own:

- headline rows, :func:`write_summary` (to the JSON-lines file named by
  ``CANAL_BENCH_SUMMARY``): each figure beside the yardstick measured in the same run; the
  section shows them as a table and :mod:`bench.plots` draws its pictures from them;
- its tables as markdown, :func:`write_section` (to the file named by ``CANAL_BENCH_SECTION``):
  the section's body (a script without it gets the tail of what it printed instead).

A new benchmark is ``bench/NAME.py`` listed in ``bench/__main__.py``'s SCRIPTS; its section is
``python -m bench --only NAME --write``.

Row fields: ``source`` (script name), ``name``, ``value``, ``unit``, optional ``peer_name`` and
``peer_value`` (the same figure for a peer or a target measured/stated in the same run; the
table shows ours / peer), ``better`` ("lower" or "higher").

To add rows from a script (e.g. ``bench/live.py``), three lines::

    if __package__:
        from bench.common import summary_row, write_summary  # python -m bench.live
    else:
        from common import summary_row, write_summary  # python bench/live.py
    ...
    write_summary("live", [summary_row("live round trip p50", p50_ms, "ms",
                                       peer_name="bare Zenoh echo", peer_value=echo_p50_ms)])

or without importing this module::

    if os.environ.get("CANAL_BENCH_SUMMARY"):
        with open(os.environ["CANAL_BENCH_SUMMARY"], "a") as f:
            f.write(json.dumps({"source": "live", "name": "...", "value": 1.0, "unit": "ms",
                                "peer_name": "bare Zenoh echo", "peer_value": 0.5}) + "\\n")
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

SUMMARY_ENV = "CANAL_BENCH_SUMMARY"
SECTION_ENV = "CANAL_BENCH_SECTION"
ROOT = Path(__file__).resolve().parent.parent
BENCHMARKS = ROOT / "BENCHMARKS.md"


def summary_row(
    name: str,
    value: float,
    unit: str,
    peer_name: str | None = None,
    peer_value: float | None = None,
    better: str = "lower",
) -> dict[str, Any]:
    """One headline figure (see the module docstring)."""
    return {
        "name": name,
        "value": float(value),
        "unit": unit,
        "peer_name": peer_name,
        "peer_value": None if peer_value is None else float(peer_value),
        "better": better,
    }


def write_summary(source: str, rows: Iterable[dict[str, Any]]) -> None:
    """Append rows to the file named by ``CANAL_BENCH_SUMMARY``; no-op when it is unset."""
    path = os.environ.get(SUMMARY_ENV)
    if not path:
        return
    with open(path, "a", encoding="utf-8") as f:
        for row in rows:
            f.write(json.dumps({"source": source, **row}) + "\n")


def write_section(markdown: str) -> None:
    """The script's tables (markdown) for its section of BENCHMARKS.md; appended, so a script
    may call it once per table. A no-op outside ``python -m bench``."""
    path = os.environ.get(SECTION_ENV)
    if not path:
        return
    with open(path, "a", encoding="utf-8") as f:
        f.write(markdown.strip() + "\n\n")


def read_summary(path: str | Path) -> list[dict[str, Any]]:
    """Rows written by :func:`write_summary` (malformed lines are skipped)."""
    rows = []
    p = Path(path)
    if not p.exists():
        return rows
    for line in p.read_text(encoding="utf-8").splitlines():
        try:
            row = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(row, dict) and "name" in row and "value" in row:
            rows.append(row)
    return rows


def fmt(value: float | None) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    a = abs(value)
    if a == 0 or 0.01 <= a < 1e5:
        return f"{value:.3g}" if a < 10 else f"{value:.1f}" if a < 1000 else f"{value:.0f}"
    return f"{value:.2e}"


def summary_markdown(rows: list[dict[str, Any]]) -> str:
    """One markdown table: figure, ours, peer, peer's figure, ours / peer."""
    lines = [
        "| source | figure | ours | unit | peer (same run) | peer | ours / peer | better |",
        "|---|---|---:|---|---|---:|---:|---|",
    ]
    for r in rows:
        peer = r.get("peer_value")
        ratio = "-"
        if peer not in (None, 0) and math.isfinite(peer) and math.isfinite(r["value"]):
            ratio = f"{r['value'] / peer:.3g}"
        lines.append(
            f"| {r.get('source', '')} | {r['name']} | {fmt(r['value'])} | {r.get('unit', '')} | "
            f"{r.get('peer_name') or '-'} | {fmt(peer)} | {ratio} | {r.get('better', 'lower')} |"
        )
    return "\n".join(lines)


def section_table(rows: list[dict[str, Any]]) -> str:
    """A section's headline rows: figure, ours, yardstick and ours / yardstick."""
    lines = [
        "| figure | ours | unit | yardstick (same run) | yardstick | ours / yardstick | better |",
        "|---|---:|---|---|---:|---:|---|",
    ]
    for r in rows:
        peer = r.get("peer_value")
        ratio = "-"
        if peer not in (None, 0) and math.isfinite(peer) and math.isfinite(r["value"]):
            ratio = f"{r['value'] / peer:.3g}"
        lines.append(
            f"| {r['name']} | {fmt(r['value'])} | {r.get('unit', '')} | "
            f"{r.get('peer_name') or '-'} | {fmt(peer)} | {ratio} | {r.get('better', 'lower')} |"
        )
    return "\n".join(lines)


def write_block(block: str, start: str, end: str, heading: str, path: Path = BENCHMARKS) -> None:
    """Replace the text between the ``start`` and ``end`` markers of ``path`` by ``block``.

    Without the markers the block goes right under ``heading`` (or a new heading at the end),
    so prose written around a block survives a rerun.
    """
    text = path.read_text() if path.exists() else "# Benchmarks\n"
    wrapped = f"{start}\n{block}\n{end}"
    if start in text and end in text:
        head, rest = text.split(start, 1)
        text = head + wrapped + rest.split(end, 1)[1]
    elif heading in text:
        text = text.replace(heading, f"{heading}\n\n{wrapped}\n", 1)
    else:
        text = text.rstrip("\n") + f"\n\n{heading}\n\n{wrapped}\n"
    path.write_text(text)


def timed(fn: Callable[..., Any], *args: Any) -> tuple[Any, float]:
    """(fn(*args), milliseconds)."""
    t0 = time.perf_counter()
    out = fn(*args)
    return out, 1e3 * (time.perf_counter() - t0)


def best_of(fn: Callable[[], Any], repeats: int) -> float:
    """Smallest wall time of ``repeats`` calls, in seconds."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)
