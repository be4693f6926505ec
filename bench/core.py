"""canal_core speed: fit, reproduce and tracker per cross-section kind (prints a table).

Run: ``.venv/bin/python bench/core.py`` (``--quick`` for fewer repeats). The naive baseline
is a plain per-point Python loop version of the ratio rule (Alg. 1 lines 12-15), measured in
the same run on the same model, to show what vectorisation buys.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import canal_core
from canal_core import datasets
from canal_core.cross_sections import boundary_distance


def best_of(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def naive_reproduce(canal: canal_core.Canal, start: np.ndarray) -> np.ndarray:
    """Alg. 1 as written: one section at a time, scalars in Python."""
    loc = canal.locate(start[None])
    i, eta, u = int(loc.index[0]), float(loc.eta[0]), loc.direction[0]
    out = [start]
    for k in range(i + 1, canal.n_sections):
        r = boundary_distance(canal.sections, np.array([k]), u[None])[0]
        p = canal.directrix[k].copy()
        for axis in range(canal.dim - 1):
            p = p + eta * r * u[axis] * canal.basis[k, axis]
        out.append(p)
    return np.array(out)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    repeats = 3 if args.quick else 10
    rng = np.random.default_rng(0)
    base = datasets.helix(1000, turns=2.0)
    demos = [base + rng.normal(scale=0.05, size=3) + 0.002 * rng.standard_normal(base.shape) for _ in range(10)]
    print("canal_core benchmark: 10 demos x 1,000 points (3-D helix), best of", repeats)
    print(f"{'kind':<8} {'N':>5} {'fit ms':>8} {'reproduce ms':>13} {'naive loop ms':>14} {'speed-up':>9} {'tracker us/call':>16}")
    for n_samples in (200, 1000):
        for kind in ("circle", "mec", "ellipse", "spline"):
            fit_s = best_of(lambda: canal_core.fit(demos, cross_section=kind, n_samples=n_samples), repeats)  # noqa: B023
            canal = canal_core.fit(demos, cross_section=kind, n_samples=n_samples)
            start = canal.directrix[0] + 0.5 * canal.radii[0] * canal.normals[0]
            rep_s = best_of(lambda: canal.reproduce(start), repeats)  # noqa: B023
            naive_s = best_of(lambda: naive_reproduce(canal, start), max(1, repeats // 3))  # noqa: B023
            tracker = canal.tracker()
            path = canal.reproduce(start)
            t0 = time.perf_counter()
            for x in path:
                tracker.step(x)
            track_us = 1e6 * (time.perf_counter() - t0) / len(path)
            print(
                f"{kind:<8} {n_samples:>5} {1e3 * fit_s:>8.2f} {1e3 * rep_s:>13.3f} {1e3 * naive_s:>14.2f} "
                f"{naive_s / rep_s:>8.0f}x {track_us:>16.1f}"
            )


if __name__ == "__main__":
    main()
