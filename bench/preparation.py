"""`python bench/preparation.py [--against REV] [--quick]`: the preparation stage's time, one
demo at a time and a fit's demos at once, beside the same stage at another git revision.

The preparation stage (``canal_core.preprocess``) runs on every upload and every fit; its
glitch test is the part that grows with the samples. This script times, in one process:

- one raw log of 20,000 rows, none of them a repeat (all reach the glitch test, its worst
  case): the whole stage (``prepared_samples``) and its glitch test alone;
- a fit's demos (``prepared_samples_many``): the generated raw sets and the UR5e demos of
  tests/data at 1,000 rows each, and 60 generated demos of 1,000 rows.

The ``canal_core`` package as of ``--against REV`` (default ``main``) is loaded beside the
working tree's, every workload checked to give the same rows bit for bit, and
both timed in turn (best CPU time of the same number of interleaved runs), so a change to
the stage is measured against what it replaces under the same load. It writes no section
of BENCHMARKS.md: it is a yardstick for changes to the stage, not a figure of the product.
"""

from __future__ import annotations

import argparse
import importlib
import io
import math
import subprocess
import sys
import tarfile
import tempfile
import time
import types
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import numpy as np

from canal_core import glitches, preprocess

ROOT = Path(__file__).resolve().parents[1]


class Stage(NamedTuple):
    """One version of the preparation stage: its module and its glitch test."""

    preprocess: types.ModuleType
    glitch_mask: Callable[[np.ndarray], np.ndarray]


def stage_at(revision: str, into: Path) -> Stage:
    """The ``canal_core`` package as of ``revision``, extracted into ``into`` and imported as
    ``canal_core_at_revision`` (its imports are relative, so it uses its own modules)."""
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", revision, "canal_core"],
                             check=True, capture_output=True).stdout
    with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
        tar.extractall(into, filter="data")
    (into / "canal_core").rename(into / "canal_core_at_revision")
    sys.path.insert(0, str(into))
    module = importlib.import_module("canal_core_at_revision.preprocess")
    if (into / "canal_core_at_revision" / "glitches.py").is_file():
        return Stage(module, importlib.import_module("canal_core_at_revision.glitches").glitch_mask)
    return Stage(module, module._glitch_mask)  # before the glitch test had its own module


def resampled_rows(positions: np.ndarray, rows: int) -> np.ndarray:
    """Linear interpolation over the row index (what a resampling logger does)."""
    x = np.linspace(0.0, positions.shape[0] - 1.0, rows)
    return np.column_stack([np.interp(x, np.arange(positions.shape[0]), positions[:, d]) for d in range(3)])


def workloads() -> list[tuple[str, Callable[[Stage], object]]]:
    """(name, run(stage)) of every workload; run returns what must match across stages."""
    sys.path.insert(0, str(ROOT / "tests"))
    from raw_logs import raw_demo_set, raw_log, shape_curves, ur5e_demos

    # A 2 kHz log without repeats: all 20,000 rows reach the glitch test, 6 glitches among them.
    rng = np.random.default_rng(5)
    long = raw_log(shape_curves("helix", 1, rng)[0], rng, rate_hz=2000.0, repeat_fraction=0.0,
                   still_seconds=(1.0, 1.0), move_seconds=8.0, n_glitches=6).positions
    # The glitch test alone sees what steps 1-3 leave (the same in both versions).
    long_head = preprocess._prepared_head(long, None, "d", None).positions

    def one(stage: Stage) -> object:
        return stage.preprocess.prepared_samples(long, None, field="d").rows

    def glitch_test(stage: Stage) -> object:
        return stage.glitch_mask(long_head)

    jobs: list[tuple[str, Callable[[Stage], object]]] = [
        ("1 demo x 20,000 rows: prepared_samples", one),
        ("1 demo x 20,000 rows: glitch test only", glitch_test),
    ]
    sets = [(f"raw {shape}, 6 x 1,000 rows", [resampled_rows(g.positions, 1000) for g in raw_demo_set(shape, 0)])
            for shape in ("task1", "helix")]
    sets.append(("UR5e, 5 x 1,000 rows", [resampled_rows(p, 1000) for p in ur5e_demos()[0]]))
    many = [resampled_rows(g.positions, 1000) for seed in range(10) for g in raw_demo_set("task1", 100 + seed)]
    sets.append((f"raw task1, {len(many)} x 1,000 rows", many))
    for name, demos in sets:
        names = [f"demos[{j}]" for j in range(len(demos))]

        def fit_stage(stage: Stage, demos: list[np.ndarray] = demos, names: list[str] = names) -> object:
            return [p.rows for p in stage.preprocess.prepared_samples_many(demos, [None] * len(demos), names, names)]

        jobs.append((f"{name}: prepared_samples_many", fit_stage))
    return jobs


def best_cpu(calls: list[Callable[[], object]], repeats: int) -> list[float]:
    """Best CPU seconds of each call, the calls run in turn ``repeats`` times (a shared machine
    loads them alike)."""
    best = [math.inf] * len(calls)
    for _ in range(repeats):
        for k, call in enumerate(calls):
            c0 = time.process_time()
            call()
            best[k] = min(best[k], time.process_time() - c0)
    return best


def same(a: object, b: object) -> bool:
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    return bool(np.array_equal(np.asarray(a), np.asarray(b)))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--against", default="main", help="git revision to time beside the working tree")
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    repeats = 5 if args.quick else 30
    ours = Stage(preprocess, glitches.glitch_mask)
    with tempfile.TemporaryDirectory() as tmp:
        before = stage_at(args.against, Path(tmp))
        print(f"preparation stage: CPU ms, best of {repeats} interleaved runs; "
              f"{args.against} beside the working tree")
        print(f"| workload | {args.against} ms | working tree ms | tree / {args.against} |")
        print("|---|---:|---:|---:|")
        for name, run in workloads():
            if not same(run(before), run(ours)):
                raise SystemExit(f"{name}: the working tree's rows differ from {args.against}'s")
            old, new = best_cpu([lambda run=run: run(before), lambda run=run: run(ours)], repeats)
            print(f"| {name} | {1e3 * old:.2f} | {1e3 * new:.2f} | {new / old:.3f} |")

if __name__ == "__main__":
    main()
