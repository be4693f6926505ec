"""canal_core speed: fit, reproduce and tracker per cross-section kind (prints a table).

Run: ``.venv/bin/python bench/core.py`` (``--quick`` for fewer repeats). The naive baselines
are plain per-point Python loop versions of Alg. 1, measured in the same run on the same data,
to show what vectorisation buys: the ratio rule (lines 12-15) on the same model, and the fit
(lines 1-6 as the paper writes them: resample, mean, Frenet frame, circle radius to the
farthest aligned sample). The naive fit does less than ``canal_core.fit`` (no plane
crossings, no envelope enlargement, no end extrusion), so its ratio flatters the baseline.
"""

from __future__ import annotations

import argparse
import itertools
import math
import time

import numpy as np

import canal_core
from canal_core import datasets
from canal_core.cross_sections import boundary_distance

try:
    from bench.common import best_of, summary_row, write_summary
except ImportError:  # run as a file: bench/ is sys.path[0]
    from common import best_of, summary_row, write_summary


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


def naive_fit(demos: list[np.ndarray], n_samples: int) -> tuple[list, list]:
    """Alg. 1 lines 1-6 as written, one point at a time in Python (3-D): directrix, radii."""
    aligned = []
    for demo in demos:
        pts = demo.tolist()
        s = [0.0]
        for a, b in itertools.pairwise(pts):
            s.append(s[-1] + math.dist(a, b))
        out, j = [], 0
        for i in range(n_samples):
            target = s[-1] * i / (n_samples - 1)
            while j < len(s) - 2 and s[j + 1] < target:
                j += 1
            w = (target - s[j]) / (s[j + 1] - s[j]) if s[j + 1] > s[j] else 0.0
            out.append([(1 - w) * pts[j][k] + w * pts[j + 1][k] for k in range(3)])
        aligned.append(out)
    n = len(aligned)
    centre = [[sum(a[i][k] for a in aligned) / n for k in range(3)] for i in range(n_samples)]

    def unit(v: list[float]) -> list[float]:
        norm = math.sqrt(sum(x * x for x in v))
        return [x / norm for x in v] if norm > 1e-300 else [0.0, 0.0, 0.0]

    tangents = []
    for i in range(n_samples):
        a, b = centre[max(i - 1, 0)], centre[min(i + 1, n_samples - 1)]
        tangents.append(unit([b[k] - a[k] for k in range(3)]))
    radii, normal = [], [0.0, 0.0, 1.0]
    for i in range(n_samples):
        t = tangents[i]
        a, b = tangents[max(i - 1, 0)], tangents[min(i + 1, n_samples - 1)]
        k_vec = [b[k] - a[k] for k in range(3)]
        dot = sum(k_vec[k] * t[k] for k in range(3))
        candidate = unit([k_vec[k] - dot * t[k] for k in range(3)])
        if any(candidate):  # else carry the previous normal (the paper: a random vector)
            normal = candidate
        binormal = [t[1] * normal[2] - t[2] * normal[1], t[2] * normal[0] - t[0] * normal[2],
                    t[0] * normal[1] - t[1] * normal[0]]
        r = 0.0
        for a_j in aligned:
            d = [a_j[i][k] - centre[i][k] for k in range(3)]
            x = sum(d[k] * normal[k] for k in range(3))
            y = sum(d[k] * binormal[k] for k in range(3))
            r = max(r, math.hypot(x, y))
        radii.append(r)
    return centre, radii


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    repeats = 3 if args.quick else 10
    rng = np.random.default_rng(0)
    base = datasets.helix(1000, turns=2.0)
    demos = [base + rng.normal(scale=0.05, size=3) + 0.002 * rng.standard_normal(base.shape) for _ in range(10)]
    print("canal_core benchmark: 10 demos x 1,000 points (3-D helix), best of", repeats)
    rows = []
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
            if (kind, n_samples) in (("circle", 200), ("spline", 1000)):
                rows.append(summary_row(f"reproduce, {kind}, N={n_samples}", 1e3 * rep_s, "ms",
                                        peer_name="naive Python loop", peer_value=1e3 * naive_s))
            if (kind, n_samples) == ("circle", 200):
                rows.append(summary_row(f"tracker step, circle, N={n_samples}", track_us, "us"))
                rows.append(summary_row(f"tracker steps/s per core, circle, N={n_samples}",
                                        1e6 / track_us, "1/s", better="higher"))
    print("\nfit, circle: canal_core.fit (frames=frenet) vs the naive per-point loop of Alg. 1")
    print(f"{'N':>5} {'fit ms':>8} {'naive fit ms':>13} {'speed-up':>9}")
    for n_samples in (200, 1000):
        fit_s = best_of(lambda: canal_core.fit(demos, frames="frenet", n_samples=n_samples), repeats)  # noqa: B023
        naive_s = best_of(lambda: naive_fit(demos, n_samples), max(1, repeats // 3))  # noqa: B023
        print(f"{n_samples:>5} {1e3 * fit_s:>8.2f} {1e3 * naive_s:>13.2f} {naive_s / fit_s:>8.1f}x")
        rows.append(summary_row(f"fit, circle, 10 x 1000 pts, N={n_samples}", 1e3 * fit_s, "ms",
                                peer_name="naive Python loop (less work)", peer_value=1e3 * naive_s))
    write_summary("core", rows)


if __name__ == "__main__":
    main()
