"""How canal_core's cost grows: fit time, peak memory, model size, reproduce and tracker time.

Run: ``.venv/bin/python bench/scale.py`` (prints the tables) or ``--quick`` (a subset);
``python -m bench --only scale --write`` puts them in BENCHMARKS.md's scale section.

Curves, for circle and ellipse cross-sections, on noisy shifted 3-D helix demos:

* demos per skill n = 2 ... 200, 200 points each, N = 200 sections (the default);
* points per demo T = 100 ... 10,000, n = 10 demos, N = 200 sections (the default);
* points per demo T = 100 ... 5,000, n = 10 demos, N = T sections (the finest canal the
  service accepts; N = 10,000 now takes ~1.2 s and 68 MB, but stays out of the run to keep it short).

fit ms: best of up to 3 fits (fewer when one takes seconds); peak MB: ``tracemalloc`` peak
during one more fit (numpy allocations included; measured apart from the timing, which
tracing slows); model KB: ``json.dumps(canal.to_dict())`` (what the
database stores per model version); decoded KB: the arrays of the decoded canal (what a model
cache holds); reproduce ms: best of 5 from a
start inside the first section; tracker us: mean ``Tracker.step`` over the reproduced path.
Each table ends with the exponent k of a least-squares fit time ~ x^k on log-log axes.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import tracemalloc

import numpy as np

import canal_core
from canal_core import datasets

if __package__:
    from bench.common import best_of, summary_row, write_section, write_summary
else:  # run as a file (python bench/x.py): bench/ is sys.path[0]
    from common import best_of, summary_row, write_section, write_summary

KINDS = ("circle", "ellipse")
DEMOS = (2, 5, 10, 20, 50, 100, 200)
POINTS = (100, 300, 1000, 3000, 10000)
#: N = T sections: up to the service's n_samples cap (5,000).
FINE_POINTS = (100, 300, 1000, 3000, 5000)
QUICK_DEMOS = (2, 10, 50)
QUICK_POINTS = (100, 1000)


def helix_demos(n: int, points: int, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    base = datasets.helix(points, turns=2.0)
    return [base + rng.normal(scale=0.05, size=3) + 0.002 * rng.standard_normal(base.shape)
            for _ in range(n)]


def decoded_bytes(canal: canal_core.Canal) -> int:
    """Array bytes a decoded canal holds in a model cache (its fields, sections, basis)."""
    arrays = [canal.directrix, canal.tangents, canal.normals, canal.arclength,
              canal.section_points, canal.end_depths, canal.basis,
              *canal.sections.params.values()]
    if canal.binormals is not None:
        arrays.append(canal.binormals)
    return int(sum(a.nbytes for a in arrays))


def measure(demos: list[np.ndarray], kind: str, n_samples: int) -> dict[str, float]:
    t0 = time.perf_counter()
    canal = canal_core.fit(demos, cross_section=kind, n_samples=n_samples)
    first = time.perf_counter() - t0
    repeats = 1 if first > 2.0 else 2 if first > 0.5 else 3
    fit_s = min(first, best_of(lambda: canal_core.fit(demos, cross_section=kind,
                                                      n_samples=n_samples), repeats - 1)
                ) if repeats > 1 else first
    tracemalloc.start()
    canal_core.fit(demos, cross_section=kind, n_samples=n_samples)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    size = len(json.dumps(canal.to_dict()))
    decoded = decoded_bytes(canal_core.Canal.from_dict(json.loads(json.dumps(canal.to_dict()))))
    start = canal.directrix[0] + 0.5 * canal.radii[0] * canal.normals[0]
    rep_s = best_of(lambda: canal.reproduce(start), 5)
    path = canal.reproduce(start)
    tracker = canal.tracker()
    t0 = time.perf_counter()
    for x in path:
        tracker.step(x)
    track_us = 1e6 * (time.perf_counter() - t0) / len(path)
    return {"fit_ms": 1e3 * fit_s, "peak_mb": peak / 1e6, "model_kb": size / 1e3, "decoded_kb": decoded / 1e3,
            "repro_ms": 1e3 * rep_s, "tracker_us": track_us}


def exponent(xs, ys) -> float:
    if len(xs) < 2:  # fewer than two measured points
        return float("nan")
    return float(np.polyfit(np.log(xs), np.log(ys), 1)[0])


def curve(label: str, xs, make, kinds=KINDS) -> tuple[str, dict]:
    """Measure every x for every kind; return a markdown table and the raw results."""
    results: dict = {}
    lines = [f"| kind | {label} | fit ms | peak MB | model KB | decoded KB | reproduce ms | tracker us |",
             "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for kind in kinds:
        for x in xs:
            demos, n_samples = make(x)
            try:
                r = measure(demos, kind, n_samples)
            except Exception as exc:  # reported in the table, not hidden
                lines.append(f"| {kind} | {x} | {type(exc).__name__}: {exc} | | | | | |")
                print(lines[-1], flush=True)
                continue
            results[(kind, x)] = r
            lines.append(f"| {kind} | {x} | {r['fit_ms']:.1f} | {r['peak_mb']:.1f} | "
                         f"{r['model_kb']:.0f} | {r['decoded_kb']:.0f} | {r['repro_ms']:.2f} | {r['tracker_us']:.1f} |")
            print(lines[-1], flush=True)
    fits = []
    for kind in kinds:
        ok = [x for x in xs if (kind, x) in results]
        ks = {key: exponent(ok, [results[(kind, x)][key] for x in ok])
              for key in ("fit_ms", "peak_mb", "model_kb", "repro_ms", "tracker_us")}
        fits.append(f"{kind}: fit ~ x^{ks['fit_ms']:.2f}, peak memory ~ x^{ks['peak_mb']:.2f}, "
                    f"model size ~ x^{ks['model_kb']:.2f}, reproduce ~ x^{ks['repro_ms']:.2f}, "
                    f"tracker ~ x^{ks['tracker_us']:.2f}")
    table = "\n".join(lines) + "\n\nLog-log slopes (x = " + label + "): " + "; ".join(fits) + "."
    return table, results


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true", help="a subset of the sizes")
    args = parser.parse_args(argv)
    demos_xs = QUICK_DEMOS if args.quick else DEMOS
    points_xs = QUICK_POINTS if args.quick else POINTS
    fine_xs = QUICK_POINTS if args.quick else FINE_POINTS
    t_all = time.perf_counter()
    blocks = []
    print("fit cost by demos per skill (200 points each, N = 200)")
    t1, r_demos = curve("demos", demos_xs, lambda n: (helix_demos(n, 200), 200))
    blocks.append("Demos per skill n (200 points each, N = 200 sections):\n\n" + t1)
    print("\nfit cost by points per demo (10 demos, N = 200)")
    t2, r_points = curve("points", points_xs, lambda t: (helix_demos(10, t), 200))
    blocks.append("Points per demo T (10 demos, N = 200 sections, the default):\n\n" + t2)
    print("\nfit cost by points per demo with N = T sections (10 demos)")
    t3, r_fine = curve("points = N", fine_xs, lambda t: (helix_demos(10, t), t))
    blocks.append("Points per demo T with N = T sections (10 demos):\n\n" + t3)
    total = time.perf_counter() - t_all
    head = (f"Measured by `.venv/bin/python bench/scale.py{' --quick' if args.quick else ''}` "
            f"({total:.0f} s, one process, 2-core machine).")
    print("\n" + head + "\n\n" + "\n\n".join(blocks))

    rows = []
    n_max, t_max, f_max = demos_xs[-1], points_xs[-1], fine_xs[-1]
    rows.append(summary_row(f"fit, circle, {n_max} demos x 200 pts", r_demos[("circle", n_max)]["fit_ms"], "ms"))
    rows.append(summary_row(f"fit, circle, 10 x {t_max} pts, N=200", r_points[("circle", t_max)]["fit_ms"], "ms"))
    rows.append(summary_row(f"fit, circle, 10 x {f_max} pts, N={f_max}", r_fine[("circle", f_max)]["fit_ms"], "ms"))
    rows.append(summary_row(f"peak fit memory, circle, 10 x {f_max} pts, N={f_max}",
                            r_fine[("circle", f_max)]["peak_mb"], "MB"))
    rows.append(summary_row("model size (JSON), circle, N=200", r_points[("circle", t_max)]["model_kb"], "KB"))
    rows.append(summary_row("model size (JSON), ellipse, N=200", r_points[("ellipse", t_max)]["model_kb"], "KB"))
    write_summary("scale", rows)
    write_section("\n\n".join(blocks))
    return 0


if __name__ == "__main__":
    sys.exit(main())
