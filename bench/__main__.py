"""`python -m bench [--quick]`: every benchmark, one after the other, then one summary table.

Each script runs as its own subprocess (``--quick`` passes through) with ``CANAL_BENCH_SUMMARY``
pointing at a JSON-lines file; scripts append their headline figures there (see
:mod:`bench.common`), a script that writes none is fine. The summary table (figure, ours,
peer in the same run, ours / peer) is printed and, on a full run (or ``--write``), written into
BENCHMARKS.md between the summary-table markers, with the pictures :mod:`bench.plots` draws from
the same rows (quality against the peers, fit time against N, live latency against the echo):
into docs/img/bench/ on a full run, else into ``--plots DIR`` or a temporary folder whose path
is printed (``--no-plots`` skips them). ``--only core,quality`` runs a subset.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

if __package__:
    from bench.common import BENCHMARKS, SUMMARY_ENV, read_summary, summary_markdown, write_block
    from bench.plots import markdown_images, write_plots
else:  # run as a file (python bench/x.py): bench/ is sys.path[0]
    from common import BENCHMARKS, SUMMARY_ENV, read_summary, summary_markdown, write_block
    from plots import markdown_images, write_plots

HERE = Path(__file__).parent
SCRIPTS = ["core", "service", "recording", "replicas", "live", "quality", "scale", "orientation",
           "startup"]
PLOTS_DIR = HERE.parent / "docs" / "img" / "bench"
START, END = "<!-- summary-table:start -->", "<!-- summary-table:end -->"
HEADING = "## Summary (`python -m bench`)"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench", description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smoke-run sizes in every script")
    parser.add_argument("--only", default="", help="comma-separated subset of " + ",".join(SCRIPTS))
    parser.add_argument("--write", action="store_true",
                        help="write the summary into BENCHMARKS.md even with --quick")
    parser.add_argument("--plots", type=Path, default=None,
                        help="folder for the PNGs (default: docs/img/bench/ when BENCHMARKS.md "
                             "is written, else a temporary folder)")
    parser.add_argument("--no-plots", action="store_true", help="draw no PNGs")
    args = parser.parse_args(argv)
    names = [n for n in args.only.split(",") if n] or SCRIPTS
    unknown = set(names) - set(SCRIPTS)
    if unknown:
        parser.error(f"unknown benchmark(s): {', '.join(sorted(unknown))}")
    status = []
    with tempfile.TemporaryDirectory(prefix="canal-bench-summary-") as tmp:
        summary = Path(tmp) / "summary.jsonl"
        env = {**os.environ, SUMMARY_ENV: str(summary)}
        t_all = time.perf_counter()
        for name in names:
            script = HERE / f"{name}.py"
            if not script.exists():
                status.append(f"{name}: not present, skipped")
                continue
            print(f"\n== bench/{name}.py ==", flush=True)
            t0 = time.perf_counter()
            rc = subprocess.run(
                [sys.executable, str(script), *(["--quick"] if args.quick else [])], env=env
            ).returncode
            status.append(f"{name}: exit {rc}, {time.perf_counter() - t0:.0f} s")
        total = time.perf_counter() - t_all
        rows = read_summary(summary)
    table = summary_markdown(rows)
    caption = (
        f"`python -m bench{' --quick' if args.quick else ''}`: {len(names)} benchmark(s), "
        f"{total:.0f} s wall time on {os.cpu_count()} CPUs ({'; '.join(status)}). Peers are "
        "measured in the same run on the same data (or are the issue's targets); ours / peer < 1 "
        "is better where `better` is lower."
    )
    print(f"\n== summary ==\n{caption}\n\n{table}")
    write_md = args.write or (not args.quick and not args.only)
    images = ""
    if not args.no_plots:
        out = args.plots or (PLOTS_DIR if write_md else
                             Path(tempfile.mkdtemp(prefix="canal-bench-plots-")))
        written = write_plots(rows, out)
        for path, _ in written:
            print(f"wrote {path}")
        if written and write_md and out.resolve().is_relative_to(BENCHMARKS.parent.resolve()):
            images = "\n\n" + markdown_images(written, BENCHMARKS.parent)
    if write_md:
        write_block(caption + "\n\n" + table + images, START, END, HEADING)
        print("wrote BENCHMARKS.md")
    return 1 if any("exit 0" not in s and "skipped" not in s for s in status) else 0


if __name__ == "__main__":
    sys.exit(main())
